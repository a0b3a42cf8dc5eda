//! Tests of [`FrameWriter`]: byte-identical output for any tile order and
//! size, exact read-back, bounded memory, and no file left behind on failure.

use super::*;
use crate::tile::band_order_tiles;
use std::collections::BTreeSet;

/// SplitMix64: a small deterministic generator for test data and shuffles.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [lo, hi).
    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * ((self.next() >> 40) as f32 / (1u64 << 24) as f32)
    }

    fn shuffle<T>(&mut self, v: &mut [T]) {
        for i in (1..v.len()).rev() {
            v.swap(i, (self.next() % (i as u64 + 1)) as usize);
        }
    }
}

/// A frame of linear values in [-0.2, 1.3): exercises both clamps in PNG.
fn frame(width: u32, height: u32, seed: u64) -> Vec<[f32; 3]> {
    let mut rng = Rng(seed);
    (0..width as usize * height as usize)
        .map(|_| {
            [
                rng.range(-0.2, 1.3),
                rng.range(-0.2, 1.3),
                rng.range(-0.2, 1.3),
            ]
        })
        .collect()
}

/// The pixels of `rect` cut out of a full `width`-wide frame.
fn cut(frame: &[[f32; 3]], width: u32, rect: Rect) -> Vec<[f32; 3]> {
    let mut out = Vec::with_capacity(rect.pixel_count());
    for y in rect.y..rect.y + rect.h {
        let start = (y * width + rect.x) as usize;
        out.extend_from_slice(&frame[start..start + rect.w as usize]);
    }
    out
}

fn write_frame(path: &Path, width: u32, height: u32, pixels: &[[f32; 3]], tiles: &[Rect]) {
    let mut writer = FrameWriter::create(path, width, height).unwrap();
    for &rect in tiles {
        writer.write_tile(rect, &cut(pixels, width, rect)).unwrap();
    }
    writer.finish().unwrap();
}

fn dir_entries(dir: &Path) -> BTreeSet<String> {
    fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect()
}

const EXTS: [&str; 2] = ["png", "exr"];

#[test]
fn tile_order_and_size_do_not_change_the_bytes() {
    let (width, height) = (97, 75);
    let pixels = frame(width, height, 1);
    let dir = tempfile::tempdir().unwrap();
    for ext in EXTS {
        let reference = dir.path().join(format!("reference.{ext}"));
        write_frame(
            &reference,
            width,
            height,
            &pixels,
            &[Rect::new(0, 0, width, height)],
        );
        let expected = fs::read(&reference).unwrap();
        for tile in [1, 7, 64, width.max(height)] {
            let band = band_order_tiles(width, height, tile);
            let reverse: Vec<Rect> = band.iter().rev().copied().collect();
            let mut shuffled = band.clone();
            Rng(u64::from(tile)).shuffle(&mut shuffled);
            for (order, tiles) in [
                ("band", &band),
                ("reverse", &reverse),
                ("shuffled", &shuffled),
            ] {
                let path = dir.path().join(format!("t{tile}-{order}.{ext}"));
                write_frame(&path, width, height, &pixels, tiles);
                assert!(
                    fs::read(&path).unwrap() == expected,
                    "{ext}, tile {tile}, {order} order: bytes differ"
                );
            }
        }
    }
}

#[test]
fn exr_reads_back_bit_for_bit() {
    let (width, height) = (53, 37); // last 16-row block is partial
    let mut pixels = frame(width, height, 2);
    let specials = [
        0.0,
        -0.0,
        f32::MIN_POSITIVE,
        1e-42, // subnormal
        -3.25e38,
        f32::MAX,
        65504.0,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::NAN,
        f32::from_bits(0x7fc0_1234), // NaN with a payload
    ];
    for (i, &v) in specials.iter().enumerate() {
        pixels[i * 7][i % 3] = v;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("frame.exr");
    let mut tiles = band_order_tiles(width, height, 8);
    Rng(9).shuffle(&mut tiles);
    write_frame(&path, width, height, &pixels, &tiles);

    let (w, h, back) = read_exr_rgb(&path).unwrap();
    assert_eq!((w, h), (width, height));
    let bits = |v: &[[f32; 3]]| v.iter().flatten().map(|f| f.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&back), bits(&pixels));

    let meta = ::exr::meta::MetaData::read_from_file(&path, true).unwrap();
    let header = &meta.headers[0];
    assert_eq!(header.compression, ::exr::compression::Compression::ZIP16);
    assert_eq!(
        header.line_order,
        ::exr::meta::attribute::LineOrder::Increasing
    );
    assert_eq!(header.blocks, ::exr::meta::BlockDescription::ScanLines);
    let names: Vec<String> = header
        .channels
        .list
        .iter()
        .map(|c| c.name.to_string())
        .collect();
    assert_eq!(names, ["B", "G", "R"]);
    assert!(header
        .channels
        .list
        .iter()
        .all(|c| c.sample_type == ::exr::meta::attribute::SampleType::F32));
}

#[test]
fn png_reads_back_as_srgb8_of_the_input() {
    let (width, height) = (61, 29);
    let mut pixels = frame(width, height, 3);
    pixels[0] = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY];
    pixels[1] = [0.5, 0.18, 0.0031308];
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("frame.png");
    let mut tiles = band_order_tiles(width, height, 16);
    Rng(4).shuffle(&mut tiles);
    write_frame(&path, width, height, &pixels, &tiles);

    // Decode with the png crate directly to check the format itself.
    let decoder = ::png::Decoder::new(std::io::BufReader::new(File::open(&path).unwrap()));
    let reader = decoder.read_info().unwrap();
    let info = reader.info();
    assert_eq!((info.width, info.height), (width, height));
    assert_eq!(info.color_type, ::png::ColorType::Rgb);
    assert_eq!(info.bit_depth, ::png::BitDepth::Eight);
    assert!(info.srgb.is_some(), "sRGB chunk missing");

    let (w, h, back) = read_png_rgb8(&path).unwrap();
    assert_eq!((w, h), (width, height));
    let expected: Vec<[u8; 3]> = pixels.iter().map(|p| p.map(linear_to_srgb8)).collect();
    assert_eq!(back, expected);
    assert_eq!(back[0], [0, 255, 0]);
    assert_eq!(back[1], [188, 118, 10]);
    // The stream writer writes IEND while being dropped; make sure it got out.
    let bytes = fs::read(&path).unwrap();
    assert!(bytes.ends_with(&[0, 0, 0, 0, b'I', b'E', b'N', b'D', 0xAE, 0x42, 0x60, 0x82]));
}

/// Writes a 4096×2048 frame of 64×64 tiles in `order`, returning the most rows
/// held at once.
fn max_rows_held(path: &Path, tiles: &[Rect]) -> usize {
    let (width, height) = (4096, 2048);
    let mut writer = FrameWriter::create(path, width, height).unwrap();
    let mut max = 0;
    for &rect in tiles {
        // Cheap but position-dependent content.
        let v = (rect.x ^ rect.y) as f32 / 4096.0;
        let pixels = vec![[v, 0.5 * v, 0.25]; rect.pixel_count()];
        writer.write_tile(rect, &pixels).unwrap();
        max = max.max(writer.rows_held());
    }
    assert_eq!(writer.rows_held(), 0);
    writer.finish().unwrap();
    max
}

#[test]
fn band_order_holds_at_most_one_band() {
    let dir = tempfile::tempdir().unwrap();
    let tiles = band_order_tiles(4096, 2048, 64);
    for ext in EXTS {
        let path = dir.path().join(format!("band.{ext}"));
        let max = max_rows_held(&path, &tiles);
        assert!(max <= 64, "{ext}: held {max} rows");
        assert_eq!(max, 64, "{ext}: a band in progress holds its rows");
    }
}

#[test]
fn out_of_band_order_holds_more_and_still_finishes() {
    let dir = tempfile::tempdir().unwrap();
    let band = band_order_tiles(4096, 2048, 64);
    // Column by column: every band is in progress at once.
    let mut columns = band.clone();
    columns.sort_by_key(|r| (r.x, r.y));
    for ext in EXTS {
        let reference = dir.path().join(format!("band.{ext}"));
        max_rows_held(&reference, &band);
        let path = dir.path().join(format!("columns.{ext}"));
        let max = max_rows_held(&path, &columns);
        assert!(max > 64, "{ext}: held only {max} rows");
        assert!(
            fs::read(&path).unwrap() == fs::read(&reference).unwrap(),
            "{ext}: bytes differ"
        );
    }
}

#[test]
fn incomplete_frame_leaves_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    for ext in EXTS {
        let path = dir.path().join(format!("frame.{ext}"));
        let (width, height) = (40, 40);
        let pixels = frame(width, height, 5);
        let mut writer = FrameWriter::create(&path, width, height).unwrap();
        for rect in band_order_tiles(width, height, 10) {
            // Leave out one tile in the third band and the whole last band.
            if rect.y >= 30 || (rect.y == 20 && rect.x == 10) {
                continue;
            }
            writer.write_tile(rect, &cut(&pixels, width, rect)).unwrap();
        }
        match writer.finish() {
            Err(OutputError::Incomplete { missing }) => assert_eq!(missing, 20),
            other => panic!("{ext}: expected Incomplete, got {other:?}"),
        }
        assert!(
            dir_entries(dir.path()).is_empty(),
            "{ext}: left {:?}",
            dir_entries(dir.path())
        );
    }
}

#[test]
fn final_name_appears_only_on_finish_and_drop_removes_the_temp_file() {
    let dir = tempfile::tempdir().unwrap();
    for ext in EXTS {
        let name = format!("frame.{ext}");
        let path = dir.path().join(&name);
        let (width, height) = (20, 20);
        let pixels = frame(width, height, 6);

        // Dropped before all tiles are written, and dropped when complete.
        for complete in [false, true] {
            let mut writer = FrameWriter::create(&path, width, height).unwrap();
            let tiles = band_order_tiles(width, height, 10);
            let n = if complete { tiles.len() } else { 1 };
            for &rect in &tiles[..n] {
                writer.write_tile(rect, &cut(&pixels, width, rect)).unwrap();
            }
            let entries = dir_entries(dir.path());
            assert_eq!(entries.len(), 1, "{entries:?}");
            let temp = entries.iter().next().unwrap();
            assert!(temp.starts_with(&format!(".{name}.trevi-tmp-")), "{temp}");
            assert!(!path.exists());
            drop(writer);
            assert!(
                dir_entries(dir.path()).is_empty(),
                "{ext}: temp file left behind"
            );
        }

        // Finished: only the final name remains.
        write_frame(
            &path,
            width,
            height,
            &pixels,
            &band_order_tiles(width, height, 10),
        );
        assert_eq!(dir_entries(dir.path()), BTreeSet::from([name]));
        fs::remove_file(&path).unwrap();
    }
}

#[test]
fn bad_tiles_are_rejected_and_the_writer_still_completes() {
    let dir = tempfile::tempdir().unwrap();
    for ext in EXTS {
        let (width, height) = (48, 40);
        let pixels = frame(width, height, 7);
        let reference = dir.path().join(format!("reference.{ext}"));
        write_frame(
            &reference,
            width,
            height,
            &pixels,
            &band_order_tiles(width, height, 16),
        );

        let path = dir.path().join(format!("frame.{ext}"));
        let mut writer = FrameWriter::create(&path, width, height).unwrap();
        let write =
            |w: &mut FrameWriter, rect: Rect| w.write_tile(rect, &cut(&pixels, width, rect));
        let is_bad_tile =
            |r: Result<(), OutputError>| matches!(r, Err(OutputError::BadTile { .. }));

        write(&mut writer, Rect::new(0, 0, 48, 16)).unwrap(); // rows 0..16 complete and written
        write(&mut writer, Rect::new(16, 16, 16, 16)).unwrap(); // pending
        let held = writer.rows_held();
        // Overlaps pixels written and already encoded.
        assert!(is_bad_tile(write(&mut writer, Rect::new(40, 15, 8, 2))));
        // Overlaps pending pixels, by a single pixel.
        assert!(is_bad_tile(write(&mut writer, Rect::new(0, 31, 17, 9))));
        assert!(is_bad_tile(write(&mut writer, Rect::new(16, 16, 16, 16))));
        // Does not fit, or is empty.
        assert!(is_bad_tile(
            writer.write_tile(Rect::new(40, 32, 9, 8), &[[0.0; 3]; 72])
        ));
        assert!(is_bad_tile(
            writer.write_tile(Rect::new(0, 39, 1, 2), &[[0.0; 3]; 2])
        ));
        assert!(is_bad_tile(writer.write_tile(Rect::new(0, 16, 0, 4), &[])));
        assert!(is_bad_tile(
            writer.write_tile(Rect::new(u32::MAX, 0, 2, 1), &[[0.0; 3]; 2])
        ));
        // Wrong pixel count.
        assert!(matches!(
            writer.write_tile(Rect::new(0, 16, 16, 16), &[[0.0; 3]; 255]),
            Err(OutputError::TilePixelCount {
                expected: 256,
                got: 255,
                ..
            })
        ));
        assert_eq!(
            writer.rows_held(),
            held,
            "a rejected tile changed the pending rows"
        );

        for rect in [
            Rect::new(0, 16, 16, 16),
            Rect::new(32, 16, 16, 16),
            Rect::new(0, 32, 48, 8),
        ] {
            write(&mut writer, rect).unwrap();
        }
        writer.finish().unwrap();
        assert!(
            fs::read(&path).unwrap() == fs::read(&reference).unwrap(),
            "{ext}: bytes differ"
        );
    }
}

#[test]
fn format_comes_from_the_extension() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["a.jpg", "a", "a.png.tmp", ".png", "a.tiff", "sub/a.ex"] {
        let path = dir.path().join(name);
        assert!(
            matches!(
                FrameWriter::create(&path, 4, 4),
                Err(OutputError::UnsupportedFormat { .. })
            ),
            "{name}"
        );
    }
    assert!(
        dir_entries(dir.path()).is_empty(),
        "rejected formats created files"
    );

    for (name, format) in [
        ("a.PNG", Format::Png),
        ("b.Png", Format::Png),
        ("c.EXR", Format::Exr),
        ("deep/er/d.exr", Format::Exr),
    ] {
        let path = dir.path().join(name);
        let mut writer = FrameWriter::create(&path, 2, 1).unwrap();
        assert_eq!(writer.format(), format);
        writer
            .write_tile(Rect::new(0, 0, 2, 1), &[[0.5; 3], [1.0; 3]])
            .unwrap();
        writer.finish().unwrap();
        assert!(path.is_file(), "{name}");
    }
}

#[test]
fn the_bytes_written_carry_the_signature_of_the_extension() {
    let dir = tempfile::tempdir().unwrap();
    for (name, format) in [("a.png", Format::Png), ("a.exr", Format::Exr)] {
        let path = dir.path().join(name);
        write_frame(&path, 2, 1, &[[0.5; 3]; 2], &[Rect::new(0, 0, 2, 1)]);
        assert_eq!(Format::sniff(&fs::read(&path).unwrap()), Some(format));
        assert_eq!(check_output(&path).unwrap(), format);
        assert_eq!(format.extension(), name.rsplit('.').next().unwrap());
    }
    assert_eq!(Format::sniff(b"GIF89a"), None);
    assert_eq!(Format::sniff(b""), None);
}

/// Renaming the finished file over `-o /dev/full` would replace the device
/// node. A target that exists and is not a regular file is refused, before
/// anything is written and again before the rename.
#[cfg(unix)]
#[test]
fn a_target_that_is_not_a_regular_file_is_refused_and_left_alone() {
    use std::os::unix::fs::FileTypeExt;
    let dir = tempfile::tempdir().unwrap();
    // A link named like an image to a device node, and a directory.
    let device = dir.path().join("full.png");
    std::os::unix::fs::symlink("/dev/null", &device).unwrap();
    let folder = dir.path().join("folder.exr");
    fs::create_dir(&folder).unwrap();
    for (path, what) in [(&device, "a character device"), (&folder, "a directory")] {
        match FrameWriter::create(path, 2, 1) {
            Err(OutputError::NotARegularFile { what: w, .. }) => assert_eq!(w, what),
            other => panic!("{}: {:?}", path.display(), other.map(|_| ())),
        }
        assert!(check_target(path).is_err());
    }
    assert!(fs::symlink_metadata(&device)
        .unwrap()
        .file_type()
        .is_symlink());
    assert!(fs::metadata("/dev/null")
        .unwrap()
        .file_type()
        .is_char_device());
    assert!(folder.is_dir());
    assert_eq!(
        dir_entries(dir.path()),
        ["folder.exr", "full.png"].map(String::from).into()
    );

    // A directory that appears under the name while the frame renders.
    let late = dir.path().join("late.png");
    let mut writer = FrameWriter::create(&late, 2, 1).unwrap();
    writer
        .write_tile(Rect::new(0, 0, 2, 1), &[[0.5; 3]; 2])
        .unwrap();
    fs::create_dir(&late).unwrap();
    assert!(matches!(
        writer.finish(),
        Err(OutputError::NotARegularFile { .. })
    ));
    assert!(late.is_dir());
    assert_eq!(
        dir_entries(dir.path()),
        ["folder.exr", "full.png", "late.png"]
            .map(String::from)
            .into()
    );

    // A regular file is replaced as before.
    let old = dir.path().join("old.exr");
    fs::write(&old, b"old").unwrap();
    write_frame(&old, 2, 1, &[[0.5; 3]; 2], &[Rect::new(0, 0, 2, 1)]);
    assert_eq!(Format::sniff(&fs::read(&old).unwrap()), Some(Format::Exr));
}

#[test]
fn zero_sized_frames_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    for (w, h) in [(0, 4), (4, 0)] {
        assert!(FrameWriter::create(&dir.path().join("a.png"), w, h).is_err());
    }
    assert!(dir_entries(dir.path()).is_empty());
}

#[test]
fn non_finite_values_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let weird = [
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        -0.0,
        f32::MAX,
        -f32::MAX,
    ];
    let pixels: Vec<[f32; 3]> = (0..36)
        .map(|i| [weird[i % 6], weird[(i + 1) % 6], weird[(i + 2) % 6]])
        .collect();
    for ext in EXTS {
        let path = dir.path().join(format!("weird.{ext}"));
        write_frame(&path, 6, 6, &pixels, &band_order_tiles(6, 6, 4));
    }
    let (_, _, png) = read_png_rgb8(&dir.path().join("weird.png")).unwrap();
    assert_eq!(png[0], [0, 255, 0]);
    let (_, _, exr) = read_exr_rgb(&dir.path().join("weird.exr")).unwrap();
    assert!(exr[0][0].is_nan() && exr[0][1] == f32::INFINITY);
}

#[test]
fn frame_writer_is_send() {
    fn assert_send<T: Send>() {}
    assert_send::<FrameWriter>();
}

/// What a frame is fed: an encoded segment, or a float tile.
enum Piece {
    Segment(u32, PngSegment),
    Tile(Rect),
}

/// Cuts a `width` × `height` frame into pieces: each segment either encoded
/// (as a worker would) or as float tiles (some split in x and y), chosen
/// by `rng`.
fn pieces(pixels: &[[f32; 3]], width: u32, height: u32, rng: &mut Rng) -> Vec<Piece> {
    let mut out = Vec::new();
    for index in 0..segment_count(height) {
        let rows = segment_rows(height, index);
        let (y0, h) = (rows.start, rows.end - rows.start);
        match rng.next() % 3 {
            0 => {
                let rect = Rect::new(0, y0, width, h);
                out.push(Piece::Segment(
                    index,
                    encode_segment(width, &cut(pixels, width, rect)),
                ));
            }
            1 => out.push(Piece::Tile(Rect::new(0, y0, width, h))),
            _ => {
                // Four tiles: split at a column and at a row.
                let sx = 1 + (rng.next() % u64::from(width.max(2) - 1)) as u32;
                let sx = sx.min(width - 1).max(1);
                let sy = (h / 2).max(1);
                for (x, w) in [(0, sx), (sx, width - sx)] {
                    for (y, hh) in [(y0, sy), (y0 + sy, h - sy)] {
                        if w > 0 && hh > 0 {
                            out.push(Piece::Tile(Rect::new(x, y, w, hh)));
                        }
                    }
                }
            }
        }
    }
    out
}

#[test]
fn segments_mixed_with_floats_in_any_order_give_the_float_only_bytes() {
    let dir = tempfile::tempdir().unwrap();
    for (width, height) in [(37, 70), (5, 16), (64, 33), (1, 40), (130, 48)] {
        let pixels = frame(width, height, u64::from(width * 1000 + height));
        let reference = dir.path().join("ref.png");
        write_frame(
            &reference,
            width,
            height,
            &pixels,
            &[Rect::new(0, 0, width, height)],
        );
        let expected = fs::read(&reference).unwrap();
        for seed in 0..12u64 {
            let mut rng = Rng(seed);
            let mut list = pieces(&pixels, width, height, &mut rng);
            if seed > 0 {
                rng.shuffle(&mut list);
            }
            let path = dir.path().join(format!("mixed-{seed}.png"));
            let mut writer = FrameWriter::create(&path, width, height).unwrap();
            for piece in &list {
                match piece {
                    Piece::Segment(i, s) => writer.write_segment(*i, s).unwrap(),
                    Piece::Tile(r) => writer.write_tile(*r, &cut(&pixels, width, *r)).unwrap(),
                }
            }
            assert_eq!(writer.segments_held(), (0, 0));
            writer.finish().unwrap();
            assert_eq!(
                fs::read(&path).unwrap(),
                expected,
                "{width}x{height}, seed {seed}"
            );
        }
    }
}

#[test]
fn segments_in_order_are_written_at_once_and_out_of_order_are_held() {
    let dir = tempfile::tempdir().unwrap();
    let (width, height) = (40, 100); // 7 segments, the last of 4 rows.
    let pixels = frame(width, height, 9);
    let segs: Vec<PngSegment> = (0..segment_count(height))
        .map(|i| {
            let r = segment_rows(height, i);
            encode_segment(
                width,
                &cut(&pixels, width, Rect::new(0, r.start, width, r.len() as u32)),
            )
        })
        .collect();
    let expected = png_from_segments(width, height, &segs).unwrap();

    let path = dir.path().join("in-order.png");
    let mut w = FrameWriter::create(&path, width, height).unwrap();
    for (i, s) in segs.iter().enumerate() {
        w.write_segment(i as u32, s).unwrap();
        assert_eq!(w.segments_held(), (0, 0), "segment {i} written as it came");
        assert_eq!(w.rows_held(), 0);
    }
    w.finish().unwrap();
    assert_eq!(fs::read(&path).unwrap(), expected);

    // Bottom up: every segment but the first waits, then all go at once.
    let path = dir.path().join("reversed.png");
    let mut w = FrameWriter::create(&path, width, height).unwrap();
    let mut most = (0, 0);
    for (i, s) in segs.iter().enumerate().rev() {
        w.write_segment(i as u32, s).unwrap();
        most = most.max(w.segments_held());
    }
    let tail: usize = segs[1..].iter().map(|s| s.deflate.len()).sum();
    assert_eq!(
        most,
        (segs.len() - 1, tail),
        "at most every segment after the missing one"
    );
    assert_eq!(w.segments_held(), (0, 0));
    w.finish().unwrap();
    assert_eq!(fs::read(&path).unwrap(), expected);
}

#[test]
fn overlapping_and_badly_framed_segments_are_refused_and_change_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let (width, height) = (20, 48); // 3 segments.
    let pixels = frame(width, height, 5);
    let seg = |i: u32| {
        let r = segment_rows(height, i);
        encode_segment(
            width,
            &cut(&pixels, width, Rect::new(0, r.start, width, r.len() as u32)),
        )
    };
    let reference = dir.path().join("ref.png");
    write_frame(
        &reference,
        width,
        height,
        &pixels,
        &[Rect::new(0, 0, width, height)],
    );
    let path = dir.path().join("out.png");
    let mut w = FrameWriter::create(&path, width, height).unwrap();

    // Badly framed: refused before it is held.
    let good = seg(1);
    let mut short = good.clone();
    short.filtered_len -= 1;
    let mut unflushed = good.clone();
    unflushed.deflate.truncate(good.deflate.len() - 1);
    let mut huge = good.clone();
    huge.deflate = vec![0; max_segment_deflate_len(good.filtered_len) as usize - 3];
    huge.deflate.extend_from_slice(&SYNC_FLUSH);
    for (i, bad, what) in [
        (1, &short, "filtered bytes, not"),
        (1, &unflushed, "sync flush"),
        (1, &huge, "deflate bytes, more than"),
        (3, &good, "not one of the image's 3 segments"),
    ] {
        let e = w.write_segment(i, bad).unwrap_err();
        assert!(
            matches!(&e, OutputError::BadSegment { index, message } if *index == i && message.contains(what)),
            "{what}: {e}"
        );
        assert_eq!(w.segments_held(), (0, 0));
    }

    // A float pixel in segment 1's rows, then segment 1: overlap.
    let dot = Rect::new(7, 20, 1, 1);
    w.write_tile(dot, &cut(&pixels, width, dot)).unwrap();
    let e = w.write_segment(1, &good).unwrap_err();
    assert!(
        matches!(
            e,
            OutputError::BadTile {
                x: 0,
                y: 16,
                w: 20,
                h: 16,
                ..
            }
        ),
        "{e}"
    );
    assert_eq!(w.segments_held(), (0, 0));
    // Segment 2 held; again, and a float tile into its rows: overlaps.
    w.write_segment(2, &seg(2)).unwrap();
    assert_eq!(w.segments_held().0, 1);
    assert!(matches!(
        w.write_segment(2, &seg(2)),
        Err(OutputError::BadTile { .. })
    ));
    let into = Rect::new(3, 40, 2, 2);
    assert!(matches!(
        w.write_tile(into, &cut(&pixels, width, into)),
        Err(OutputError::BadTile { .. })
    ));
    // Segment 0 goes through; then segment 0 again is below what is written.
    w.write_segment(0, &seg(0)).unwrap();
    assert!(matches!(
        w.write_segment(0, &seg(0)),
        Err(OutputError::BadTile { .. })
    ));
    // The rest of segment 1 as floats completes the frame, as if nothing
    // had been refused.
    let incomplete = w.segments_held();
    assert_eq!(incomplete.0, 1, "segment 2 waits for segment 1's floats");
    for r in [
        Rect::new(0, 16, 20, 4),
        Rect::new(0, 20, 7, 1),
        Rect::new(8, 20, 12, 1),
        Rect::new(0, 21, 20, 11),
    ] {
        w.write_tile(r, &cut(&pixels, width, r)).unwrap();
    }
    assert_eq!(w.segments_held(), (0, 0));
    w.finish().unwrap();
    assert_eq!(fs::read(&path).unwrap(), fs::read(&reference).unwrap());
}

#[test]
fn an_incomplete_frame_counts_held_segments_as_written_rows() {
    let dir = tempfile::tempdir().unwrap();
    let (width, height) = (8, 40);
    let pixels = frame(width, height, 2);
    let mut w = FrameWriter::create(&dir.path().join("x.png"), width, height).unwrap();
    let r = Rect::new(0, 32, 8, 8);
    w.write_segment(2, &encode_segment(width, &cut(&pixels, width, r)))
        .unwrap();
    assert!(matches!(
        w.finish(),
        Err(OutputError::Incomplete { missing: 32 })
    ));
}

#[test]
fn an_exr_frame_refuses_segments() {
    let dir = tempfile::tempdir().unwrap();
    let mut w = FrameWriter::create(&dir.path().join("x.exr"), 4, 16).unwrap();
    let seg = encode_segment(4, &[[0.5; 3]; 64]);
    let e = w.write_segment(0, &seg).unwrap_err();
    assert!(
        matches!(&e, OutputError::BadSegment { index: 0, message } if message.contains("EXR")),
        "{e}"
    );
}

#[test]
fn noise_deflates_under_the_stated_bound() {
    // Random bytes are the worst case for the compressor: almost every
    // byte a literal, many with its longest codes.
    let mut rng = Rng(77);
    for width in [1u32, 3, 50, 700] {
        let rows: Vec<Vec<u8>> = (0..16)
            .map(|_| (0..3 * width).map(|_| rng.next() as u8).collect())
            .collect();
        let seg = encode_segment_srgb(width, &rows);
        let most = max_segment_deflate_len(seg.filtered_len);
        assert!(
            seg.deflate.len() as u64 <= most,
            "{width}: {} > {most}",
            seg.deflate.len()
        );
        assert!(check_segment(width, 16, 0, &seg).is_ok());
    }
}

#[test]
fn a_badly_framed_segment_is_refused_with_what_is_wrong() {
    let px = vec![[0.25f32, 0.5, 0.75]; 5 * 16];
    let seg = encode_segment(5, &px);
    assert_eq!(check_segment(5, 20, 0, &seg), Ok(()));
    assert_eq!(
        check_segment(5, 20, 2, &seg),
        Err(SegmentError::NotInImage { index: 2, count: 2 })
    );
    // Segment 1 of a 20-row frame has 4 rows.
    assert_eq!(
        check_segment(5, 20, 1, &seg),
        Err(SegmentError::FilteredLen {
            index: 1,
            got: 16 * 16,
            expected: 4 * 16
        })
    );
    let mut long = seg.clone();
    long.deflate = vec![0; 16 * 16 * 2];
    assert!(matches!(
        check_segment(5, 20, 0, &long),
        Err(SegmentError::TooLong {
            index: 0,
            len: 512,
            most: 448,
            filtered: 256
        })
    ));
    let mut cut = seg.clone();
    cut.deflate.pop();
    let e = check_segment(5, 20, 0, &cut).unwrap_err();
    assert_eq!(e, SegmentError::NoSyncFlush { index: 0 });
    assert_eq!(e.to_string(), "segment 0 does not end in a sync flush");
}

#[test]
fn only_whole_segments_of_full_rows_are_whole_segments() {
    assert_eq!(whole_segments(Rect::new(0, 0, 10, 16), 10, 40), Ok((0, 1)));
    assert_eq!(whole_segments(Rect::new(0, 16, 10, 24), 10, 40), Ok((1, 2)));
    assert_eq!(whole_segments(Rect::new(0, 32, 10, 8), 10, 40), Ok((2, 1)));
    use SegmentRectError::*;
    for (r, want) in [
        (
            Rect::new(1, 0, 9, 16),
            NotFullWidth {
                x: 1,
                end: 10,
                width: 10,
            },
        ),
        (
            Rect::new(0, 0, 9, 16),
            NotFullWidth {
                x: 0,
                end: 9,
                width: 10,
            },
        ),
        (Rect::new(0, 8, 10, 16), NotWholeSegments { y: 8, end: 24 }),
        (Rect::new(0, 0, 10, 8), NotWholeSegments { y: 0, end: 8 }),
        (Rect::new(0, 0, 10, 0), NotWholeSegments { y: 0, end: 0 }),
        (
            Rect::new(0, 32, 10, 16),
            OutsideFrame {
                y: 32,
                h: 16,
                width: 10,
                height: 40,
            },
        ),
        (
            Rect::new(0, u32::MAX, 10, 16),
            OutsideFrame {
                y: u32::MAX,
                h: 16,
                width: 10,
                height: 40,
            },
        ),
    ] {
        assert_eq!(whole_segments(r, 10, 40), Err(want), "{r:?}");
    }
    assert_eq!(
        NotWholeSegments { y: 8, end: 24 }.to_string(),
        "rows 8..24 are not whole 16-row segments"
    );
}
