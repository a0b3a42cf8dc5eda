//! Measures banded against whole-frame denoising for each overlap: the
//! figures in docs/denoise.md. Run:
//! `OIDN_DIR=/opt/oidn cargo run --release -p trevi-denoise --features oidn --example overlap`
use std::time::Instant;
use trevi_denoise::{denoise_frame, BandPlan, Denoiser, InMemory, Inputs};

/// A noisy frame with edges, gradients and texture in its auxiliary images:
/// discs and bars of different albedo and normal on a graded floor, the
/// colour their albedo times a shading term plus per-pixel noise from a hash
/// (so the same bits everywhere).
fn noisy_frame(width: u32, height: u32) -> InMemory {
    let hash = |x: u32, y: u32, c: u32| {
        let mut h =
            x.wrapping_mul(0x9E37_79B9) ^ y.wrapping_mul(0x85EB_CA6B) ^ c.wrapping_mul(0xC2B2_AE35);
        h ^= h >> 16;
        h = h.wrapping_mul(0x7FEB_352D);
        h ^= h >> 15;
        h = h.wrapping_mul(0x846C_A68B);
        h ^= h >> 16;
        (h >> 8) as f32 / (1u32 << 24) as f32
    };
    let n = (width * height) as usize;
    let (mut color, mut albedo, mut normal) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    for y in 0..height {
        for x in 0..width {
            let (fx, fy) = (x as f32 / width as f32, y as f32 / height as f32);
            let discs = [
                (0.3f32, 0.2f32, 0.15f32, [0.8f32, 0.2, 0.2]),
                (0.7, 0.5, 0.2, [0.2, 0.7, 0.3]),
                (0.4, 0.8, 0.12, [0.9, 0.9, 0.2]),
            ];
            let mut a = [0.5 + 0.3 * fx, 0.5, 0.5 - 0.3 * fy];
            let mut nrm = [0.0f32, 1.0, 0.0];
            for (cx, cy, r, col) in discs {
                let (dx, dy) = (fx - cx, (fy - cy) * height as f32 / width as f32);
                let d2 = dx * dx + dy * dy;
                if d2 < r * r {
                    a = col;
                    let z = (1.0 - d2 / (r * r)).sqrt();
                    nrm = [dx / r, dy / r, z];
                }
            }
            if (x / 24) % 5 == 0 && y % 97 < 40 {
                a = [0.1, 0.1, 0.8];
                nrm = [1.0, 0.0, 0.0];
            }
            let light = 0.2 + 0.8 * nrm[1].max(0.0) + 0.5 * nrm[2].max(0.0);
            let noise = |c| (hash(x, y, c) - 0.5) * 1.6;
            color.push([0, 1, 2].map(|c| (a[c] * light * (1.0 + noise(c as u32))).max(0.0)));
            albedo.push(a);
            normal.push(nrm);
        }
    }
    InMemory {
        width,
        height,
        frame: Inputs {
            color,
            albedo: Some(albedo),
            normal: Some(normal),
        },
    }
}

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
