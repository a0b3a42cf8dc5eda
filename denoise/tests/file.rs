//! A noisy multi-layer EXR on disk to a denoised PNG or EXR, against the
//! whole frame denoised at once and written by the same writer.
#![cfg(feature = "oidn")]

mod common;

use exr::prelude::*;
use std::path::Path;
use trevi_core::output::{read_exr_channels, read_exr_rgb};
use trevi_core::{Aov, AovTile, Aovs, FrameWriter, Rect};
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

/// The whole denoised frame `px` (with `noisy`, its beauty before
/// denoising) written at once.
fn write_whole(path: &Path, w: u32, h: u32, px: &[[f32; 3]], noisy: &[[f32; 3]]) {
    let mut writer = FrameWriter::create_denoised(path, w, h, Aovs::NONE).unwrap();
    writer
        .write_tile_denoised(Rect { x: 0, y: 0, w, h }, px, &AovTile::default(), noisy)
        .unwrap();
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
        let done = denoise_file(&denoiser, &noisy, &out, 64, DEFAULT_OVERLAP, Aovs::NONE).unwrap();
        assert_eq!(
            (done.width, done.height, done.albedo, done.normal),
            (w, h, true, true)
        );
        assert_eq!(done.exposure, scale);
        let reference = dir.path().join(format!("whole.{ext}"));
        write_whole(&reference, w, h, &whole, &frame.frame.color);
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

/// What the output carries: the passes asked for, as the noisy file has
/// them, and the beauty before denoising (the layer `noisy`) in an EXR;
/// a pass the noisy file lacks is refused before anything is written.
#[test]
fn a_denoised_exr_carries_the_passes_asked_for_and_the_noisy_beauty() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (40u32, 90u32);
    let frame = common::noisy_frame(w, h);
    let noisy = dir.path().join("noisy.exr");
    write_noisy(&noisy, &frame);
    let denoiser = Denoiser::new(1).unwrap();
    let out = dir.path().join("out.exr");
    let carry = Aovs::NONE.with(Aov::Albedo);
    denoise_file(&denoiser, &noisy, &out, 32, DEFAULT_OVERLAP, carry).unwrap();
    let (_, _, channels) = read_exr_channels(&out).unwrap();
    let names: Vec<&str> = channels.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        ["B", "G", "R", "albedo.B", "albedo.G", "albedo.R", "noisy.B", "noisy.G", "noisy.R"]
    );
    let get = |name: &str| &channels.iter().find(|(n, _)| n == name).unwrap().1;
    let albedo = frame.frame.albedo.as_ref().unwrap();
    for (c, name) in ["R", "G", "B"].into_iter().enumerate() {
        let column = |v: &[[f32; 3]]| v.iter().map(|p| p[c]).collect::<Vec<f32>>();
        assert_eq!(get(&format!("noisy.{name}")), &column(&frame.frame.color));
        assert_eq!(get(&format!("albedo.{name}")), &column(albedo));
        assert_ne!(get(name), &column(&frame.frame.color), "{name} is denoised");
    }
    // No depth in the noisy file: refused, nothing written.
    let depth = dir.path().join("depth.exr");
    let e = denoise_file(
        &denoiser,
        &noisy,
        &depth,
        32,
        DEFAULT_OVERLAP,
        Aovs::NONE.with(Aov::Depth),
    )
    .unwrap_err();
    assert!(e.to_string().contains("depth"), "{e}");
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        2,
        "noisy.exr and out.exr only"
    );
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
        Aovs::NONE,
    )
    .unwrap_err();
    assert!(e.to_string().contains("absent.exr"), "{e}");
    std::fs::write(dir.path().join("bad.exr"), b"v/1\x01 not an exr").unwrap();
    assert!(denoise_file(
        &denoiser,
        &dir.path().join("bad.exr"),
        &out,
        64,
        DEFAULT_OVERLAP,
        Aovs::NONE
    )
    .is_err());
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        1,
        "only bad.exr: nothing half-written"
    );
}
