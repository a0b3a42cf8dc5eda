//! Reading bands of a multi-layer EXR, written here by the `exr` crate's own
//! writer in both layouts (one part with prefixed channels, one part per layer).

use exr::prelude::*;
use trevi_denoise::{ExrSource, Inputs, Source};

const W: usize = 37;
const H: usize = 70;

/// A distinct value for every pixel, channel and layer.
fn value(layer: usize, c: usize, x: usize, y: usize) -> f32 {
    (layer * 1_000_000 + c * 100_000 + y * 1000 + x) as f32 * 0.25
}

fn channels(layer: usize, names: [&str; 3], prefix: &str) -> Vec<AnyChannel<FlatSamples>> {
    names
        .iter()
        .enumerate()
        .map(|(c, name)| {
            let samples = (0..H)
                .flat_map(|y| (0..W).map(move |x| value(layer, c, x, y)))
                .collect();
            AnyChannel::new(
                format!("{prefix}{name}").as_str(),
                FlatSamples::F32(samples),
            )
        })
        .collect()
}

fn one_part(path: &std::path::Path, with_normal: bool) {
    one_part_as(path, with_normal, Encoding::FAST_LOSSLESS)
}

fn one_part_as(path: &std::path::Path, with_normal: bool, encoding: Encoding) {
    let mut all = channels(0, ["R", "G", "B"], "");
    all.extend(channels(1, ["R", "G", "B"], "albedo."));
    if with_normal {
        all.extend(channels(2, ["X", "Y", "Z"], "N."));
    }
    let layer = Layer::new(
        (W, H),
        LayerAttributes::default(),
        encoding,
        AnyChannels::sort(all.into()),
    );
    Image::from_layer(layer).write().to_file(path).unwrap();
}

fn parts(path: &std::path::Path) {
    let layer = |name: Option<&str>, i, names| {
        let attrs = match name {
            Some(n) => LayerAttributes::named(n),
            None => LayerAttributes::default(),
        };
        Layer::new(
            (W, H),
            attrs,
            Encoding::FAST_LOSSLESS,
            AnyChannels::sort(channels(i, names, "").into()),
        )
    };
    let layers = smallvec::smallvec![
        layer(Some("rgba"), 0, ["R", "G", "B"]),
        layer(Some("albedo"), 1, ["R", "G", "B"]),
        layer(Some("N"), 2, ["X", "Y", "Z"]),
    ];
    Image::from_layers(
        ImageAttributes::new(IntegerBounds::from_dimensions((W, H))),
        layers,
    )
    .write()
    .to_file(path)
    .unwrap();
}

fn check_band(src: &mut ExrSource, rows: std::ops::Range<u32>, normal: bool) {
    let mut got = Inputs::default();
    src.read(rows.clone(), &mut got).unwrap();
    let n = W * (rows.end - rows.start) as usize;
    assert_eq!(got.color.len(), n);
    for (i, px) in got.color.iter().enumerate() {
        let (x, y) = (i % W, rows.start as usize + i / W);
        assert_eq!(
            *px,
            [0, 1, 2].map(|c| value(0, c, x, y)),
            "colour at {x},{y}"
        );
        assert_eq!(
            got.albedo.as_ref().unwrap()[i],
            [0, 1, 2].map(|c| value(1, c, x, y))
        );
        match &got.normal {
            Some(nrm) => {
                assert!(normal);
                assert_eq!(nrm[i], [0, 1, 2].map(|c| value(2, c, x, y)));
            }
            None => assert!(!normal),
        }
    }
}

#[test]
fn bands_of_one_part_with_prefixed_channels_read_back_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("frame.exr");
    one_part(&path, true);
    let mut src = ExrSource::open(&path).unwrap();
    assert_eq!((src.width(), src.height()), (W as u32, H as u32));
    assert!(src.has_albedo() && src.has_normal());
    for rows in [0..16, 5..9, 13..50, 60..70, 0..70] {
        check_band(&mut src, rows, true);
    }
    one_part(&path, false);
    let mut src = ExrSource::open(&path).unwrap();
    assert!(!src.has_normal());
    check_band(&mut src, 10..40, false);
}

#[test]
fn bands_of_a_tiled_file_read_back_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("frame.exr");
    let tiled = Encoding {
        compression: Compression::ZIP1,
        blocks: Blocks::Tiles(Vec2(16, 8)),
        line_order: LineOrder::Increasing,
    };
    one_part_as(&path, true, tiled);
    let mut src = ExrSource::open(&path).unwrap();
    for rows in [0..8, 3..20, 31..70] {
        check_band(&mut src, rows, true);
    }
}

#[test]
fn bands_of_one_part_per_layer_read_back_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("frame.exr");
    parts(&path);
    let mut src = ExrSource::open(&path).unwrap();
    for rows in [0..1, 17..33, 31..70] {
        check_band(&mut src, rows, true);
    }
}

#[test]
fn files_without_the_beauty_or_with_half_a_layer_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("frame.exr");
    let mut some = channels(0, ["R", "G", "B"], "");
    some.extend(channels(1, ["R", "G", "B"], "albedo.").into_iter().take(2));
    let layer = Layer::new(
        (W, H),
        LayerAttributes::default(),
        Encoding::FAST_LOSSLESS,
        AnyChannels::sort(some.into()),
    );
    Image::from_layer(layer).write().to_file(&path).unwrap();
    let e = ExrSource::open(&path).err().unwrap().to_string();
    assert!(e.contains("frame.exr") && e.contains("albedo.B"), "{e}");

    let layer = Layer::new(
        (W, H),
        LayerAttributes::default(),
        Encoding::FAST_LOSSLESS,
        AnyChannels::sort(channels(1, ["X", "Y", "Z"], "N.").into()),
    );
    Image::from_layer(layer).write().to_file(&path).unwrap();
    let e = ExrSource::open(&path).err().unwrap().to_string();
    assert!(e.contains("no R G B"), "{e}");

    std::fs::write(&path, b"not an exr").unwrap();
    assert!(ExrSource::open(&path).is_err());
    let mut src = {
        parts(&path);
        ExrSource::open(&path).unwrap()
    };
    assert!(src.read(60..71, &mut Inputs::default()).is_err());
}

/// Replaces the `i32` at `at` of the little-endian file `bytes`.
fn patch_i32(bytes: &mut [u8], at: usize, v: i32) {
    bytes[at..at + 4].copy_from_slice(&v.to_le_bytes());
}

#[test]
fn a_header_claiming_a_frame_wider_than_any_scene_is_refused_before_a_band_is_read() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("wide.exr");
    let layer = Layer::new(
        (W, H),
        LayerAttributes::default(),
        Encoding::UNCOMPRESSED,
        AnyChannels::sort(channels(0, ["R", "G", "B"], "").into()),
    );
    Image::from_layer(layer).write().to_file(&path).unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    // The data window: "dataWindow\0box2i\0", its size (16), then xMin,
    // yMin, xMax, yMax. One line a block uncompressed: 70 chunks, blocks of
    // 70 000 × 12 bytes, within every other bound: only the side is over.
    let name = b"dataWindow\0box2i\0";
    let at = bytes.windows(name.len()).position(|w| w == name).unwrap() + name.len() + 4;
    patch_i32(&mut bytes, at + 8, 70_000 - 1);
    std::fs::write(&path, &bytes).unwrap();
    let e = ExrSource::open(&path).err().expect("refused").to_string();
    assert!(
        e.contains("wide.exr") && e.contains("70000x70") && e.contains("65536"),
        "{e}"
    );
}
