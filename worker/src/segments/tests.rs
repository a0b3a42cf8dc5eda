use super::*;
use trevi_core::output::{png_from_segments, PngSegment};
use trevi_core::FrameWriter;

/// Deterministic pixels with texture (not constant rows), a few above 1.
fn pixels(rect: Rect, seed: u32) -> Vec<[f32; 3]> {
    let mut out = Vec::with_capacity(rect.pixel_count());
    for y in rect.y..rect.y + rect.h {
        for x in rect.x..rect.x + rect.w {
            let mut h = (x.wrapping_mul(73856093) ^ y.wrapping_mul(19349663) ^ seed)
                .wrapping_mul(2654435761);
            let mut c = [0f32; 3];
            for v in &mut c {
                h ^= h >> 15;
                h = h.wrapping_mul(2246822519);
                let noise = (h >> 20) as f32 / 4096.0;
                // A triangle wave across, a ramp down, and noise.
                let tri = ((x % 50) as f32 / 25.0 - 1.0).abs();
                *v = 0.8 * tri + 0.3 * noise + (y as f32 / 90.0);
            }
            out.push(c);
        }
    }
    out
}

fn to_core(s: &pb::EncodedSegment) -> PngSegment {
    PngSegment {
        deflate: s.deflate.clone(),
        adler32: s.adler32,
        filtered_len: s.filtered_len,
    }
}

/// A frame of `w`×`h` cut into segment leases of `lease_rows` rows
/// (the last one to the bottom), each encoded alone, joined: the file
/// `FrameWriter` writes from the same pixels in tiles.
fn farm_file_equals_writer(w: u32, h: u32, lease_rows: u32) {
    let frame = Rect::new(0, 0, w, h);
    let all = pixels(frame, 7);
    let mut segments = Vec::new();
    let mut y = 0;
    while y < h {
        let rect = Rect::new(0, y, w, lease_rows.min(h - y));
        let px = &all[(y * w) as usize..((y + rect.h) * w) as usize];
        let enc = encode_rect(rect, w, h, 4, px).unwrap();
        assert_eq!(enc.segments.len() as u32, rect.h.div_ceil(SEGMENT_ROWS));
        for (i, s) in enc.segments.iter().enumerate() {
            assert_eq!(s.index, y / SEGMENT_ROWS + i as u32);
        }
        segments.extend(enc.segments.iter().map(to_core));
        y += rect.h;
    }
    let ours = png_from_segments(w, h, &segments).unwrap();

    // The writer's file, from 13×11 tiles (not aligned to segments).
    let dir = std::env::temp_dir().join(format!(
        "trevi-worker-seg-{}-{w}x{h}-{lease_rows}",
        std::process::id()
    ));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("frame.png");
    let mut fw = FrameWriter::create(&path, w, h).unwrap();
    for ty in (0..h).step_by(11) {
        for tx in (0..w).step_by(13) {
            let t = Rect::new(tx, ty, 13.min(w - tx), 11.min(h - ty));
            let px: Vec<[f32; 3]> = (t.y..t.y + t.h)
                .flat_map(|y| {
                    let row = (y * w) as usize;
                    all[row + t.x as usize..row + (t.x + t.w) as usize].to_vec()
                })
                .collect();
            fw.write_tile(t, &px).unwrap();
        }
    }
    fw.finish().unwrap();
    let theirs = std::fs::read(&path).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    assert!(ours == theirs, "{w}x{h} in leases of {lease_rows} rows");
}

#[test]
fn joined_segments_are_the_frame_writers_file() {
    // Heights a multiple of 16 and not; leases of one segment, several,
    // and the whole frame.
    farm_file_equals_writer(61, 64, 16);
    farm_file_equals_writer(61, 64, 32);
    farm_file_equals_writer(40, 53, 16);
    farm_file_equals_writer(40, 53, 48);
    farm_file_equals_writer(33, 7, 16);
    farm_file_equals_writer(1, 40, 64);
}

/// The sums by their definition: for each overlapped cell, every pixel
/// of the frame tested for being in the rect and the cell.
fn direct_sums(rect: Rect, s: u32, all: &[[f32; 3]], w: u32) -> Vec<f32> {
    let mut out = Vec::new();
    for cy in rect.y / s..=(rect.y + rect.h - 1) / s {
        for cx in rect.x / s..=(rect.x + rect.w - 1) / s {
            let mut sum = [0f64; 3];
            for y in cy * s..(cy + 1) * s {
                for x in cx * s..(cx + 1) * s {
                    let inside =
                        x >= rect.x && x < rect.x + rect.w && y >= rect.y && y < rect.y + rect.h;
                    if inside {
                        let p = all[(y * w + x) as usize];
                        for c in 0..3 {
                            sum[c] += f64::from(p[c]);
                        }
                    }
                }
            }
            out.extend(sum.map(|v| v as f32));
        }
    }
    out
}

#[test]
fn preview_sums_match_a_direct_computation() {
    let (w, h) = (50, 47);
    let all = pixels(Rect::new(0, 0, w, h), 3);
    for (rect, s) in [
        (Rect::new(3, 5, 17, 11), 4),
        (Rect::new(0, 16, 50, 31), 3),
        (Rect::new(7, 0, 1, 1), 5),
        (Rect::new(0, 0, 50, 47), 1),
        (Rect::new(0, 0, 50, 47), 64),
        (Rect::new(11, 13, 29, 30), 7),
    ] {
        let px: Vec<[f32; 3]> = (rect.y..rect.y + rect.h)
            .flat_map(|y| {
                let row = (y * w) as usize;
                all[row + rect.x as usize..row + (rect.x + rect.w) as usize].to_vec()
            })
            .collect();
        let got = preview_sums(rect, s, &px);
        let want = direct_sums(rect, s, &all, w);
        assert_eq!(got.len(), want.len(), "{rect:?} / {s}");
        for (i, (a, b)) in got.iter().zip(&want).enumerate() {
            assert!(
                (a - b).abs() <= 1e-5 * b.abs().max(1.0),
                "{rect:?} / {s}: sum {i}: {a} against {b}"
            );
        }
    }
}

#[test]
fn a_bad_pixel_is_named() {
    let rect = Rect::new(0, 32, 10, 20);
    for bad in [f32::NAN, f32::INFINITY, -0.5, f32::NEG_INFINITY] {
        let mut px = pixels(rect, 1);
        px[3 * 10 + 4][1] = bad;
        px[5 * 10 + 2][0] = f32::NAN;
        let e = encode_rect(rect, 10, 52, 4, &px).unwrap_err();
        let SegmentError::BadPixel(b) = e.clone() else {
            panic!("{e:?}")
        };
        assert_eq!((b.x, b.y), (4, 35));
        assert!(e.to_string().contains("pixel (4, 35)"), "{e}");
    }
    // Negative zero is not negative.
    let mut px = pixels(rect, 1);
    px[0] = [-0.0, 0.0, 0.0];
    assert!(check_pixels(rect, &px).is_ok());
}

#[test]
fn rects_that_are_not_segments_are_refused() {
    let px = |r: Rect| vec![[0.5f32; 3]; r.pixel_count()];
    let (w, h) = (20, 50);
    for r in [
        Rect::new(1, 0, 19, 16),  // not from the left
        Rect::new(0, 0, 19, 16),  // not full width
        Rect::new(0, 8, 20, 16),  // not from a segment's first row
        Rect::new(0, 16, 20, 20), // ends inside a segment, not the bottom
        Rect::new(0, 48, 20, 16), // past the bottom
    ] {
        assert!(
            matches!(
                encode_rect(r, w, h, 4, &px(r)),
                Err(SegmentError::NotSegments { .. })
            ),
            "{r:?}"
        );
    }
    let r = Rect::new(0, 48, 20, 2); // the bottom
    assert!(encode_rect(r, w, h, 4, &px(r)).is_ok());
    assert_eq!(
        encode_rect(r, w, h, 0, &px(r)),
        Err(SegmentError::NoPreviewScale)
    );
    assert!(matches!(
        encode_rect(r, w, h, 4, &px(Rect::new(0, 0, 20, 1))),
        Err(SegmentError::PixelCount { .. })
    ));
}
