//! A noisy multi-layer EXR on disk to a denoised PNG or EXR, against the
//! whole frame denoised at once and written by the same writer.
#![cfg(feature = "oidn")]

mod common;

use exr::prelude::*;
use std::path::Path;
use trevi_core::output::read_exr_rgb;
use trevi_core::{FrameWriter, Rect};
use trevi_denoise::{denoise_file, frame_exposure, Denoiser, DEFAULT_OVERLAP};

fn write_noisy(path: &Path, frame: &trevi_denoise::InMemory) {
    let (w, h) = (frame.width as usize, frame.height as usize);
    let layer = |v: &[[f32; 3]], names: [&str; 3]| -> Vec<AnyChannel<FlatSamples>> {
        (0..3)
            .map(|c| AnyChannel::new(names[c], FlatSamples::F32(v.iter().map(|p| p[c]).collect())))
            .collect()
    };
    let mut all = layer(&frame.frame.color, ["R", "G", "B"]);
    all.extend(layer(
        frame.frame.albedo.as_ref().unwrap(),
        ["albedo.R", "albedo.G", "albedo.B"],
    ));
    all.extend(layer(
        frame.frame.normal.as_ref().unwrap(),
        ["N.X", "N.Y", "N.Z"],
    ));
    let part = Layer::new(
        (w, h),
        LayerAttributes::default(),
        Encoding::FAST_LOSSLESS,
        AnyChannels::sort(all.into()),
    );
    Image::from_layer(part).write().to_file(path).unwrap();
}

fn write_whole(path: &Path, w: u32, h: u32, px: &[[f32; 3]]) {
    let mut writer = FrameWriter::create(path, w, h).unwrap();
    writer.write_tile(Rect { x: 0, y: 0, w, h }, px).unwrap();
    writer.finish().unwrap();
}

#[test]
fn a_noisy_exr_denoised_in_bands_equals_the_whole_frame_in_exr_and_png() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (120u32, 400u32);
    let frame = common::noisy_frame(w, h);
    let noisy = dir.path().join("noisy.exr");
    write_noisy(&noisy, &frame);
    let denoiser = Denoiser::new(0).unwrap();

    let mut src = frame.clone();
    let scale = frame_exposure(&mut src).unwrap();
    let mut whole = Vec::new();
    denoiser
        .filter(w, h, &frame.frame, scale, &mut whole)
        .unwrap();

    for ext in ["exr", "png"] {
        let out = dir.path().join(format!("out.{ext}"));
        let done = denoise_file(&denoiser, &noisy, &out, 64, DEFAULT_OVERLAP).unwrap();
        assert_eq!(
            (done.width, done.height, done.albedo, done.normal),
            (w, h, true, true)
        );
        assert_eq!(done.exposure, scale);
        let reference = dir.path().join(format!("whole.{ext}"));
        write_whole(&reference, w, h, &whole);
        assert_eq!(
            std::fs::read(&out).unwrap(),
            std::fs::read(&reference).unwrap(),
            "{ext}: banded file differs from the whole frame's"
        );
    }
    // And the EXR holds the denoised values (not, say, the noisy ones).
    let (_, _, back) = read_exr_rgb(&dir.path().join("out.exr")).unwrap();
    assert_eq!(back, whole);
    assert_ne!(back, frame.frame.color);
}

#[test]
fn a_missing_or_beauty_less_input_leaves_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let denoiser = Denoiser::new(1).unwrap();
    let out = dir.path().join("out.png");
    let e = denoise_file(
        &denoiser,
        &dir.path().join("absent.exr"),
        &out,
        64,
        DEFAULT_OVERLAP,
    )
    .unwrap_err();
    assert!(e.to_string().contains("absent.exr"), "{e}");
    std::fs::write(dir.path().join("bad.exr"), b"v/1\x01 not an exr").unwrap();
    assert!(denoise_file(
        &denoiser,
        &dir.path().join("bad.exr"),
        &out,
        64,
        DEFAULT_OVERLAP
    )
    .is_err());
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        1,
        "only bad.exr: nothing half-written"
    );
}
