//! A lease's pixels as encoded PNG segments (`Lease.png_segments`).
//!
//! When the coordinator asks for segments, the lease's `rect` is full-width
//! rows from a multiple of [`SEGMENT_ROWS`] to a multiple of it or the
//! frame's bottom. The worker then does what the coordinator did with the
//! floats: it checks them ([`check_pixels`]: finite, not negative; a bad
//! pixel fails the lease), encodes each 16-row segment of the rect with
//! [`encode_segment`] (the same encoder as the coordinator's and
//! `trevi-submit`'s `FrameWriter`, so the file's bytes do not depend on who
//! encoded which segment), and sums the pixels for the monitor's preview
//! ([`preview_sums`]). [`encode_rect`] does all three; [`segment_messages`]
//! makes the upload.
//!
//! Memory: the rect's floats (held already), one segment's sRGB and
//! filtered bytes per render thread while it is encoded, the encoded
//! segments (smaller than the floats), and the preview sums (12 bytes a
//! cell).

use crate::Rendered;
use rayon::prelude::*;
use trevi_core::output::{encode_segment, SEGMENT_ROWS};
use trevi_core::Rect;
use trevi_proto::pb;

/// A pixel whose value is not finite and non-negative: the render is wrong,
/// and the lease is given back with this as its error.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("pixel ({x}, {y}) is ({}, {}, {}): not finite and non-negative", .value[0], .value[1], .value[2])]
pub struct BadPixel {
    /// Frame coordinates.
    pub x: u32,
    pub y: u32,
    pub value: [f32; 3],
}

/// Why a lease's pixels cannot be uploaded as segments.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SegmentError {
    #[error(transparent)]
    BadPixel(#[from] BadPixel),
    /// The coordinator broke the contract: the rect is not whole segments
    /// of full-width rows.
    #[error(
        "a segment lease's rect {}x{} at ({}, {}) is not full-width rows of a {width}x{height} frame \
         from a multiple of {SEGMENT_ROWS} to a multiple of it or the bottom",
        .rect.w, .rect.h, .rect.x, .rect.y
    )]
    NotSegments { rect: Rect, width: u32, height: u32 },
    /// The coordinator sent a segment lease without a preview cell size.
    #[error("a segment lease with preview_scale 0")]
    NoPreviewScale,
    /// The render gave a different number of pixels than the rect holds.
    #[error("{got} pixels for a rect of {want}")]
    PixelCount { got: usize, want: usize },
}

/// A lease's upload on the segment path: its segments in order, and its
/// preview sums.
#[derive(Debug, Clone, PartialEq)]
pub struct EncodedRect {
    pub segments: Vec<pb::EncodedSegment>,
    pub preview: Vec<f32>,
}

impl EncodedRect {
    /// Bytes of encoded segments.
    pub fn deflate_bytes(&self) -> usize {
        self.segments.iter().map(|s| s.deflate.len()).sum()
    }
}

/// The first pixel of `rect` (row by row) that is not finite and
/// non-negative in every channel, as an error.
pub fn check_pixels(rect: Rect, pixels: &[[f32; 3]]) -> Result<(), BadPixel> {
    match trevi_core::tile::first_invalid_pixel(pixels) {
        None => Ok(()),
        Some(i) => {
            let w = rect.w.max(1) as usize;
            Err(BadPixel {
                x: rect.x + (i % w) as u32,
                y: rect.y + (i / w) as u32,
                value: pixels[i],
            })
        }
    }
}

/// Whether `rect` is what a segment lease of a `width`×`height` frame must
/// be: full-width rows from a multiple of [`SEGMENT_ROWS`] to a multiple of
/// it or the frame's bottom.
pub fn is_segment_rect(rect: Rect, width: u32, height: u32) -> bool {
    let end = u64::from(rect.y) + u64::from(rect.h);
    rect.x == 0
        && rect.w == width
        && rect.w > 0
        && rect.h > 0
        && rect.y % SEGMENT_ROWS == 0
        && end <= u64::from(height)
        && (rect.h % SEGMENT_ROWS == 0 || end == u64::from(height))
}

/// The preview's box sums of `rect`'s pixels (row by row), as the proto's
/// `PreviewSums` says: the frame is cut into `scale`-pixel square cells from
/// (0, 0); for every cell the rect overlaps, row-major, the sums of the
/// linear R, G, B values of the rect's pixels in that cell. Summed in f64,
/// rounded to f32 once. `scale` must be at least 1 and `pixels` hold the
/// rect's pixels.
pub fn preview_sums(rect: Rect, scale: u32, pixels: &[[f32; 3]]) -> Vec<f32> {
    debug_assert!(scale >= 1);
    debug_assert_eq!(pixels.len(), rect.pixel_count());
    if rect.w == 0 || rect.h == 0 {
        return Vec::new();
    }
    let s = scale.max(1);
    let (c0, c1) = (rect.x / s, (rect.x + rect.w - 1) / s);
    let (r0, r1) = (rect.y / s, (rect.y + rect.h - 1) / s);
    let cols = (c1 - c0 + 1) as usize;
    let mut out = Vec::with_capacity(3 * cols * (r1 - r0 + 1) as usize);
    // One cell row at a time.
    let mut row = vec![[0f64; 3]; cols];
    let w = rect.w as usize;
    for cr in r0..=r1 {
        let y0 = (cr * s).max(rect.y);
        let y1 = (cr.saturating_add(1).saturating_mul(s)).min(rect.y + rect.h);
        row.fill([0.0; 3]);
        for y in y0..y1 {
            let line = &pixels[(y - rect.y) as usize * w..][..w];
            for (i, p) in line.iter().enumerate() {
                let cell = &mut row[((rect.x + i as u32) / s - c0) as usize];
                for (acc, &c) in cell.iter_mut().zip(p) {
                    *acc += f64::from(c);
                }
            }
        }
        out.extend(row.iter().flat_map(|c| c.map(|v| v as f32)));
    }
    out
}

/// Checks `pixels` (the lease's `rect` of a `width`×`height` frame, row by
/// row), encodes the rect's segments, in parallel on the current rayon
/// pool, and sums its preview cells of `scale` pixels.
pub fn encode_rect(
    rect: Rect,
    width: u32,
    height: u32,
    scale: u32,
    pixels: &[[f32; 3]],
) -> Result<EncodedRect, SegmentError> {
    if !is_segment_rect(rect, width, height) {
        return Err(SegmentError::NotSegments {
            rect,
            width,
            height,
        });
    }
    if scale == 0 {
        return Err(SegmentError::NoPreviewScale);
    }
    if pixels.len() != rect.pixel_count() {
        return Err(SegmentError::PixelCount {
            got: pixels.len(),
            want: rect.pixel_count(),
        });
    }
    check_pixels(rect, pixels)?;
    let first = rect.y / SEGMENT_ROWS;
    let per_segment = SEGMENT_ROWS as usize * rect.w as usize;
    let segments = pixels
        .par_chunks(per_segment)
        .enumerate()
        .map(|(i, px)| {
            let s = encode_segment(rect.w, px);
            pb::EncodedSegment {
                index: first + i as u32,
                deflate: s.deflate,
                adler32: s.adler32,
                filtered_len: s.filtered_len,
            }
        })
        .collect();
    Ok(EncodedRect {
        segments,
        preview: preview_sums(rect, scale, pixels),
    })
}

/// The messages of a segment upload: the header (as for floats), the
/// segments in order, one message each, then the preview sums.
pub fn segment_messages(
    worker: u64,
    session: &[u8],
    lease: &pb::Lease,
    rect: Rect,
    rendered: Rendered,
    encoded: EncodedRect,
) -> Vec<pb::TileUpload> {
    use pb::tile_upload::Part;
    let mut msgs = Vec::with_capacity(encoded.segments.len() + 2);
    msgs.push(crate::header_message(
        worker, session, lease, rect, rendered,
    ));
    msgs.extend(encoded.segments.into_iter().map(|s| pb::TileUpload {
        part: Some(Part::Segment(s)),
    }));
    msgs.push(pb::TileUpload {
        part: Some(Part::Preview(pb::PreviewSums {
            sums: encoded.preview,
        })),
    });
    msgs
}

#[cfg(test)]
mod tests {
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
                        let inside = x >= rect.x
                            && x < rect.x + rect.w
                            && y >= rect.y
                            && y < rect.y + rect.h;
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

    #[test]
    fn the_upload_is_header_segments_preview() {
        let rect = Rect::new(0, 16, 8, 40);
        let enc = encode_rect(rect, 8, 56, 4, &pixels(rect, 2)).unwrap();
        let lease = pb::Lease {
            lease_id: 9,
            job_id: 3,
            png_segments: true,
            preview_scale: 4,
            ..Default::default()
        };
        let rendered = Rendered {
            rays: 5,
            took: std::time::Duration::from_micros(77),
        };
        let msgs = segment_messages(1, b"s", &lease, rect, rendered, enc.clone());
        use pb::tile_upload::Part;
        assert_eq!(msgs.len(), 2 + 3);
        let Some(Part::Header(h)) = &msgs[0].part else {
            panic!()
        };
        assert_eq!((h.lease_id, h.job_id, h.render_micros), (9, 3, Some(77)));
        assert_eq!(h.rect, Some(rect.into()));
        for (m, s) in msgs[1..4].iter().zip(&enc.segments) {
            assert_eq!(m.part, Some(Part::Segment(s.clone())));
        }
        assert_eq!(
            msgs[4].part,
            Some(Part::Preview(pb::PreviewSums { sums: enc.preview }))
        );
    }
}
