//! Measures banded against whole-frame denoising for each overlap: the
//! figures in docs/denoise.md. Run:
//! `OIDN_DIR=/opt/oidn cargo run --release -p trevi-denoise --features oidn --example overlap`
use std::time::Instant;
use trevi_denoise::{denoise_frame, BandPlan, Denoiser};

// The tests' noisy frame, so the figures are of the frame the tests check.
#[path = "../tests/common/mod.rs"]
mod common;
use common::noisy_frame;

fn main() {
    let denoiser = Denoiser::new(1).expect("a denoiser");
    let (w, h) = (512u32, 1024u32);
    let frame = noisy_frame(w, h);
    let mut src = frame.clone();
    let scale = trevi_denoise::frame_exposure(&mut src).expect("exposure");
    let t = Instant::now();
    let mut whole = Vec::new();
    denoiser
        .filter(w, h, &frame.frame, scale, &mut whole)
        .expect("whole frame");
    let whole_s = t.elapsed().as_secs_f64();
    println!("frame {w}x{h}, 1 thread: whole frame {whole_s:.2} s");
    println!("band_rows overlap  max_rel_diff  time_s  time/whole");
    for band_rows in [64u32, 256] {
        for overlap in [0u32, 16, 32, 48, 64, 80, 96, 112, 128] {
            let plan = BandPlan::new(h, band_rows, overlap).expect("plan");
            let mut out = Vec::new();
            let mut src = frame.clone();
            let t = Instant::now();
            denoise_frame(&denoiser, &mut src, plan, &mut |_, px| {
                out.extend_from_slice(px);
                Ok(())
            })
            .expect("banded");
            let s = t.elapsed().as_secs_f64();
            let diff = out
                .iter()
                .zip(&whole)
                .flat_map(|(p, q)| (0..3).map(move |c| (p[c] - q[c]).abs() / q[c].abs().max(1e-2)))
                .fold(0.0f32, f32::max);
            println!(
                "{band_rows:9} {overlap:7}  {diff:12.3e}  {s:6.2}  {:10.2}",
                s / whole_s
            );
        }
    }
}
