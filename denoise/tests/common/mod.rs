//! The noisy test frame the denoiser's tests share.
#![allow(dead_code)]

use trevi_denoise::{InMemory, Inputs};

/// A noisy frame with edges, gradients and texture in its auxiliary images:
/// discs and bars of different albedo and normal on a graded floor, the
/// colour their albedo times a shading term plus per-pixel noise from a hash
/// (so the same bits everywhere).
pub fn noisy_frame(width: u32, height: u32) -> InMemory {
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
