//! Tests of frames with render passes: a multi-layer EXR read back with the
//! `exr` crate's reader (channel names, every value), the files beside a
//! PNG, the same bytes whatever the tiles, and refused tiles.

use super::*;
use crate::aov::{Aov, AovTile, Aovs};
use crate::tile::band_order_tiles;

/// Beauty and the seven pass values of pixel (x, y) of a `w`-wide frame:
/// distinct everywhere, negative normal components, an infinite depth on
/// the diagonal (a miss).
fn values(x: u32, y: u32, w: u32) -> ([f32; 3], [f32; 7]) {
    let (fx, fy) = (x as f32, y as f32);
    let beauty = [fx * 0.07, fy * 0.05, 0.5 + fx * 0.001];
    let n = glam::Vec3::new(fx - 4.0, 1.5 - fy * 0.1, 0.5).normalize();
    let depth = if x == y {
        f32::INFINITY
    } else {
        (y * w + x) as f32 * 0.25
    };
    let aov = [fx / 32.0, fy / 32.0, 0.25, n.x, n.y, n.z, depth];
    (beauty, aov)
}

/// The tile `rect` of passes `aovs`: its beauty and its pass values.
fn tile(rect: Rect, w: u32, aovs: Aovs) -> (Vec<[f32; 3]>, AovTile) {
    let mut pixels = Vec::new();
    let mut t = AovTile {
        aovs,
        values: Vec::new(),
    };
    for y in rect.y..rect.y + rect.h {
        for x in rect.x..rect.x + rect.w {
            let (b, a) = values(x, y, w);
            pixels.push(b);
            for aov in aovs.iter() {
                let at = Aovs::ALL.offset(aov).unwrap();
                t.values.extend_from_slice(&a[at..at + aov.channels()]);
            }
        }
    }
    (pixels, t)
}

fn write(path: &Path, w: u32, h: u32, aovs: Aovs, tile_side: u32) {
    let mut fw = FrameWriter::create_with_aovs(path, w, h, aovs).unwrap();
    let mut tiles = band_order_tiles(w, h, tile_side);
    // Out of band order too: the writer takes any order.
    tiles.reverse();
    for r in tiles {
        let (px, t) = tile(r, w, aovs);
        fw.write_tile_aovs(r, &px, &t).unwrap();
    }
    fw.finish().unwrap();
}

#[test]
fn a_multi_layer_exr_reads_back_with_the_channel_names_and_values() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (21, 35);
    let path = dir.path().join("o.exr");
    write(&path, w, h, Aovs::ALL, 8);
    let (rw, rh, channels) = read_exr_channels(&path).unwrap();
    assert_eq!((rw, rh), (w, h));
    let names: Vec<&str> = channels.iter().map(|c| c.0.as_str()).collect();
    assert_eq!(
        names,
        ["B", "G", "N.X", "N.Y", "N.Z", "R", "Z", "albedo.B", "albedo.G", "albedo.R"]
    );
    // Which value each channel holds: beauty 0..3, passes 3.. (ALL order).
    let source = |name: &str| match name {
        "R" => 0,
        "G" => 1,
        "B" => 2,
        "albedo.R" => 3,
        "albedo.G" => 4,
        "albedo.B" => 5,
        "N.X" => 6,
        "N.Y" => 7,
        "N.Z" => 8,
        "Z" => 9,
        _ => unreachable!(),
    };
    for (name, data) in &channels {
        assert_eq!(data.len(), (w * h) as usize);
        for y in 0..h {
            for x in 0..w {
                let (b, a) = values(x, y, w);
                let all: Vec<f32> = b.iter().chain(&a).copied().collect();
                let got = data[(y * w + x) as usize];
                assert_eq!(
                    got.to_bits(),
                    all[source(name)].to_bits(),
                    "{name} ({x},{y})"
                );
            }
        }
    }
    // The beauty is what an RGB reader finds.
    let (_, _, rgb) = read_exr_rgb(&path).unwrap();
    assert_eq!(rgb[5], values(5, 0, w).0);
    // The same bytes whatever the tiles.
    let again = dir.path().join("p.exr");
    write(&again, w, h, Aovs::ALL, 16);
    assert_eq!(fs::read(&path).unwrap(), fs::read(&again).unwrap());
}

/// Any subset of passes: only its channels, each with its values.
#[test]
fn an_exr_with_some_passes_holds_only_their_channels() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("o.exr");
    let aovs = Aovs::parse("depth normal").unwrap();
    write(&path, 9, 5, aovs, 4);
    let (_, _, channels) = read_exr_channels(&path).unwrap();
    let names: Vec<&str> = channels.iter().map(|c| c.0.as_str()).collect();
    assert_eq!(names, ["B", "G", "N.X", "N.Y", "N.Z", "R", "Z"]);
    assert_eq!(channels[6].1[9 + 2], values(2, 1, 9).1[6]);
    assert_eq!(channels[3].1[3], values(3, 0, 9).1[4]);
    // No file beside an EXR.
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
}

/// A PNG frame writes its passes beside it: albedo through the sRGB curve,
/// normals as round(255·(n+1)/2), depth as a one-channel EXR; the frame's
/// own PNG is the one written without passes.
#[test]
fn a_png_frame_writes_each_pass_to_a_file_beside_it() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (19, 23);
    let path = dir.path().join("shot.png");
    write(&path, w, h, Aovs::ALL, 7);
    let plain = dir.path().join("plain.png");
    write(&plain, w, h, Aovs::NONE, 5);
    assert_eq!(fs::read(&path).unwrap(), fs::read(&plain).unwrap());
    let albedo = aov_path(&path, Aov::Albedo).unwrap();
    let normal = aov_path(&path, Aov::Normal).unwrap();
    let depth = aov_path(&path, Aov::Depth).unwrap();
    assert_eq!(
        [&albedo, &normal, &depth].map(|p| p.file_name().unwrap().to_str().unwrap().to_string()),
        ["shot.albedo.png", "shot.normal.png", "shot.depth.exr"]
    );
    let (_, _, a) = read_png_rgb8(&albedo).unwrap();
    let (_, _, n) = read_png_rgb8(&normal).unwrap();
    let (dw, dh, z) = read_exr_channels(&depth).unwrap();
    assert_eq!((dw, dh, z.len(), z[0].0.as_str()), (w, h, 1, "Z"));
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let v = values(x, y, w).1;
            assert_eq!(a[i], [v[0], v[1], v[2]].map(linear_to_srgb8), "({x},{y})");
            let unit = |c: f32| ((c as f64 + 1.0) / 2.0 * 255.0).round() as u8;
            assert_eq!(n[i], [unit(v[3]), unit(v[4]), unit(v[5])], "({x},{y})");
            assert_eq!(z[0].1[i].to_bits(), v[6].to_bits());
        }
    }
    // No passes beside an EXR output, none beside an unknown one.
    assert_eq!(aov_path(Path::new("o.exr"), Aov::Albedo), None);
    assert_eq!(aov_path(Path::new("o.tif"), Aov::Albedo), None);
}

/// A tile without the frame's passes, with other passes, or with the
/// wrong number of values is refused and changes nothing; an unfinished
/// frame leaves no file, beside it or not.
#[test]
fn tiles_with_the_wrong_passes_are_refused_and_nothing_is_left_behind() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("o.png");
    let (w, h) = (8, 4);
    let rect = Rect::new(0, 0, w, h);
    let mut fw = FrameWriter::create_with_aovs(&path, w, h, Aovs::ALL).unwrap();
    assert_eq!(fw.aovs(), Aovs::ALL);
    let (px, t) = tile(rect, w, Aovs::ALL);
    let e = fw.write_tile(rect, &px).unwrap_err();
    assert!(matches!(e, OutputError::AovMismatch { .. }), "{e}");
    let (_, other) = tile(rect, w, Aovs::parse("depth").unwrap());
    assert!(matches!(
        fw.write_tile_aovs(rect, &px, &other),
        Err(OutputError::AovMismatch { .. })
    ));
    let mut short = t.clone();
    short.values.pop();
    let e = fw.write_tile_aovs(rect, &px, &short).unwrap_err();
    assert!(e.to_string().contains("223 values"), "{e}");
    assert_eq!(fw.rows_held(), 0, "a refused tile wrote nothing");
    // The frame still takes the right tile, then drops unfinished.
    fw.write_tile_aovs(
        Rect::new(0, 0, w, 2),
        &px[..16],
        &AovTile {
            aovs: Aovs::ALL,
            values: t.values[..16 * 7].to_vec(),
        },
    )
    .unwrap();
    drop(fw);
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
    // A plain frame refuses passes too.
    let mut plain = FrameWriter::create(&path, w, h).unwrap();
    assert!(matches!(
        plain.write_tile_aovs(rect, &px, &t),
        Err(OutputError::AovMismatch { .. })
    ));
    // And a frame with passes takes no encoded PNG segments.
    let mut fw = FrameWriter::create_with_aovs(&path, w, h, Aovs::ALL).unwrap();
    let seg = encode_segment(w, &px);
    assert!(matches!(
        fw.write_segment(0, &seg),
        Err(OutputError::BadSegment { .. })
    ));
}

/// A denoised frame's EXR holds the noisy beauty as `noisy.R G B` after
/// the passes, each pixel's own (tiles in any order); a PNG holds the
/// denoised beauty alone, its passes beside it. Tiles without their noisy
/// beauty, or with one for a frame that keeps none, or of the wrong size,
/// are refused and change nothing.
#[test]
fn a_denoised_frame_keeps_its_noisy_beauty_as_a_layer() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (13, 22);
    let aovs = Aovs::NONE.with(Aov::Depth);
    // The "noisy" beauty of a pixel: its beauty, reversed and halved.
    let noisy_of = |px: &[[f32; 3]]| -> Vec<[f32; 3]> {
        px.iter()
            .map(|p| [p[2] * 0.5, p[1] * 0.5, p[0] * 0.5])
            .collect()
    };
    for ext in ["exr", "png"] {
        let path = dir.path().join(format!("d.{ext}"));
        let mut fw = FrameWriter::create_denoised(&path, w, h, aovs).unwrap();
        let mut tiles = band_order_tiles(w, h, 8);
        tiles.reverse();
        for (i, r) in tiles.into_iter().enumerate() {
            let (px, t) = tile(r, w, aovs);
            if i == 0 {
                let e = fw.write_tile_aovs(r, &px, &t).unwrap_err();
                assert!(matches!(e, OutputError::NoisyMismatch { .. }), "{e}");
                let short = &noisy_of(&px)[1..];
                let e = fw.write_tile_denoised(r, &px, &t, short).unwrap_err();
                assert!(matches!(e, OutputError::NoisyMismatch { .. }), "{e}");
            }
            fw.write_tile_denoised(r, &px, &t, &noisy_of(&px)).unwrap();
        }
        fw.finish().unwrap();
    }
    let (_, _, channels) = read_exr_channels(&dir.path().join("d.exr")).unwrap();
    let names: Vec<&str> = channels.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["B", "G", "R", "Z", "noisy.B", "noisy.G", "noisy.R"]);
    let get = |name: &str| &channels.iter().find(|(n, _)| n == name).unwrap().1;
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let (b, a) = values(x, y, w);
            assert_eq!(
                [get("R")[i], get("G")[i], get("B")[i]],
                b,
                "denoised beauty at {x},{y}"
            );
            assert_eq!(
                [get("noisy.R")[i], get("noisy.G")[i], get("noisy.B")[i]],
                [b[2] * 0.5, b[1] * 0.5, b[0] * 0.5],
                "noisy beauty at {x},{y}"
            );
            assert!(get("Z")[i] == a[6] || (get("Z")[i].is_infinite() && a[6].is_infinite()));
        }
    }
    // The PNG is what a plain frame of the same beauty writes.
    let plain = dir.path().join("plain.png");
    write(&plain, w, h, aovs, 8);
    assert_eq!(
        std::fs::read(dir.path().join("d.png")).unwrap(),
        std::fs::read(&plain).unwrap()
    );
    assert!(dir.path().join("d.depth.exr").exists());
    // A plain frame takes no noisy beauty.
    let mut fw = FrameWriter::create(&dir.path().join("p.exr"), 4, 4).unwrap();
    let r = Rect::new(0, 0, 4, 4);
    let px = vec![[0.5; 3]; 16];
    let e = fw
        .write_tile_denoised(r, &px, &AovTile::default(), &px)
        .unwrap_err();
    assert!(matches!(e, OutputError::NoisyMismatch { .. }), "{e}");
    fw.write_tile(r, &px).unwrap();
    fw.finish().unwrap();
}
