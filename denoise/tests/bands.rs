//! Banded denoising against whole-frame denoising, with the library itself
//! (only with the `oidn` feature: `cargo test -p trevi-denoise --features oidn`,
//! which `.ci/run` runs).
#![cfg(feature = "oidn")]

mod common;

use common::noisy_frame;
use trevi_denoise::{denoise_frame, BandPlan, Denoiser, InMemory, Source, DEFAULT_OVERLAP};

/// Denoises with `plan`, collecting the rows.
fn banded(denoiser: &Denoiser, frame: &InMemory, plan: BandPlan) -> (Vec<[f32; 3]>, f32) {
    let mut src = frame.clone();
    let mut out = Vec::new();
    let mut next = 0;
    let scale = denoise_frame(denoiser, &mut src, plan, &mut |rows, px| {
        assert_eq!(rows.start, next, "bands in order");
        next = rows.end;
        out.extend_from_slice(px);
        Ok(())
    })
    .unwrap();
    (out, scale)
}

/// The whole frame in one call, with the same exposure.
fn whole(denoiser: &Denoiser, frame: &InMemory, scale: f32) -> Vec<[f32; 3]> {
    let mut out = Vec::new();
    denoiser
        .filter(frame.width, frame.height, &frame.frame, scale, &mut out)
        .unwrap();
    out
}

/// Largest difference relative to the whole frame's value (floored at 1e-2,
/// so near-black pixels are compared absolutely).
fn max_relative(a: &[[f32; 3]], b: &[[f32; 3]]) -> f32 {
    a.iter()
        .zip(b)
        .flat_map(|(p, q)| (0..3).map(move |c| (p[c] - q[c]).abs() / q[c].abs().max(1e-2)))
        .fold(0.0, f32::max)
}

#[test]
fn a_frame_of_many_bands_equals_the_whole_frame_denoised_at_once() {
    let denoiser = Denoiser::new(0).unwrap();
    let frame = noisy_frame(160, 600);
    let plan = BandPlan::new(600, 64, DEFAULT_OVERLAP).unwrap();
    let (bands, scale) = banded(&denoiser, &frame, plan);
    let all = whole(&denoiser, &frame, scale);
    let diff = max_relative(&bands, &all);
    eprintln!("10 bands of 64 rows, overlap {DEFAULT_OVERLAP}: max relative difference {diff:e}");
    assert!(diff < 1e-4, "banded differs from whole by {diff:e}");
    // The denoiser did something: the output is far from the noisy input.
    assert!(max_relative(&all, &frame.frame.color) > 0.1);
}

#[test]
fn denoising_tiles_alone_leaves_seams_that_bands_with_context_do_not() {
    let denoiser = Denoiser::new(0).unwrap();
    let frame = noisy_frame(128, 256);
    let (bands, scale) = banded(
        &denoiser,
        &frame,
        BandPlan::new(256, 64, DEFAULT_OVERLAP).unwrap(),
    );
    let all = whole(&denoiser, &frame, scale);
    // Without context (overlap 0) every band is denoised alone, as a farm
    // that denoises tiles does: its rows at the cuts differ from the whole.
    let (alone, _) = banded(&denoiser, &frame, BandPlan::new(256, 64, 0).unwrap());
    let seam_rows = |img: &[[f32; 3]]| -> f32 {
        let w = 128;
        [63usize, 64, 127, 128, 191, 192]
            .iter()
            .map(|&y| max_relative(&img[y * w..(y + 1) * w], &all[y * w..(y + 1) * w]))
            .fold(0.0, f32::max)
    };
    let with_context = seam_rows(&bands);
    let without = seam_rows(&alone);
    eprintln!("rows at the cuts: {with_context:e} with context, {without:e} without");
    assert!(with_context < 1e-4);
    assert!(
        without > 1e-2,
        "tiles denoised alone should show seams ({without:e})"
    );
}

#[test]
fn the_result_does_not_depend_on_the_thread_count() {
    let frame = noisy_frame(96, 160);
    let plan = BandPlan::new(160, 64, 64).unwrap();
    let (one, _) = banded(&Denoiser::new(1).unwrap(), &frame, plan);
    let (two, _) = banded(&Denoiser::new(2).unwrap(), &frame, plan);
    let bits = |v: &[[f32; 3]]| v.iter().flatten().map(|f| f.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&one), bits(&two));
}

#[test]
fn a_source_of_another_height_is_refused() {
    let denoiser = Denoiser::new(1).unwrap();
    let mut frame = noisy_frame(32, 48);
    let plan = BandPlan::new(64, 16, 16).unwrap();
    assert!(denoise_frame(&denoiser, &mut frame, plan, &mut |_, _| Ok(())).is_err());
    assert_eq!(frame.height(), 48);
}
