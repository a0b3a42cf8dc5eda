//! A progressive render's `--preview`, denoised after each pass: with
//! `--denoise`, the preview file shows the last finished pass denoised
//! (the beauty alone: a progressive job renders no guides), rather than the
//! noisy image filling in tile by tile.
//!
//! Cheap by construction: the coordinator's preview is at most
//! [`Preview::MAX_EDGE`] (512) pixels a side, so a pass costs the denoiser
//! at most 0.26 megapixels whatever the frame's size (measured in
//! docs/denoise.md), once a pass, on the machine that asked for it.
//!
//! Bound: the PNG comes over the network, so its header's size is checked
//! against [`Preview::MAX_EDGE`] and its colour type against 8-bit RGBA
//! (what the coordinator writes) before any pixel is decoded: at most
//! 1 MiB of pixels and 3 MiB of floats.

use anyhow::{bail, Context, Result};
use trevi_coordinator::preview::{encode_png, Preview};
use trevi_denoise::{
    denoise_frame, BandPlan, Denoiser, InMemory, Inputs, DEFAULT_BAND_ROWS, DEFAULT_OVERLAP,
};

/// The preview `png` (8-bit sRGB RGBA) with its colour denoised by OIDN
/// with `threads` threads (0: every core); alpha kept. A new device each
/// call: OIDN's device stays on the thread that made it.
pub fn denoise_preview(png: &[u8], threads: u32) -> Result<Vec<u8>> {
    let (width, height, mut rgba) = decode(png)?;
    let linear = srgb8_to_linear_table();
    let color = rgba
        .chunks_exact(4)
        .map(|p| [0, 1, 2].map(|c| linear[usize::from(p[c])]))
        .collect();
    let mut source = InMemory {
        width,
        height,
        frame: Inputs {
            color,
            albedo: None,
            normal: None,
        },
    };
    let denoiser = Denoiser::new(threads).context("starting the denoiser")?;
    let plan = BandPlan::new(height, DEFAULT_BAND_ROWS, DEFAULT_OVERLAP)?;
    let w = width as usize;
    denoise_frame(&denoiser, &mut source, plan, &mut |rows, pixels| {
        let start = rows.start as usize * w * 4;
        for (i, p) in pixels.iter().enumerate() {
            for (c, v) in p.iter().enumerate() {
                rgba[start + 4 * i + c] = trevi_core::output::linear_to_srgb8(*v);
            }
        }
        Ok(())
    })
    .context("denoising the preview")?;
    encode_png(width, height, &rgba).context("encoding the denoised preview")
}

/// Width, height and 8-bit RGBA pixels of a preview PNG, refused before
/// decoding when it is larger than a preview can be or not 8-bit RGBA.
fn decode(png: &[u8]) -> Result<(u32, u32, Vec<u8>)> {
    let mut reader = png::Decoder::new(std::io::Cursor::new(png))
        .read_info()
        .context("the preview is not a PNG")?;
    let info = reader.info();
    let (width, height) = (info.width, info.height);
    if width > Preview::MAX_EDGE || height > Preview::MAX_EDGE {
        bail!(
            "the preview is {width}x{height}, larger than a preview's {0}x{0}",
            Preview::MAX_EDGE
        );
    }
    if (info.color_type, info.bit_depth) != (png::ColorType::Rgba, png::BitDepth::Eight) {
        bail!(
            "the preview is {:?} {:?}, not 8-bit RGBA",
            info.color_type,
            info.bit_depth
        );
    }
    let mut rgba = vec![0; width as usize * height as usize * 4];
    reader
        .next_frame(&mut rgba)
        .context("decoding the preview")?;
    Ok((width, height, rgba))
}

/// sRGB byte → linear value (the inverse of the output's curve).
fn srgb8_to_linear_table() -> [f32; 256] {
    std::array::from_fn(|i| trevi_core::texture::srgb_to_linear(i as f64 / 255.0) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png_of(width: u32, height: u32, color: png::ColorType) -> Vec<u8> {
        let mut bytes = Vec::new();
        let mut enc = png::Encoder::new(&mut bytes, width, height);
        enc.set_color(color);
        enc.set_depth(png::BitDepth::Eight);
        let samples = color.samples();
        enc.write_header()
            .unwrap()
            .write_image_data(&vec![128; width as usize * height as usize * samples])
            .unwrap();
        bytes
    }

    #[test]
    fn a_preview_too_large_or_not_rgba_is_refused_before_decoding() {
        let e = format!(
            "{:#}",
            denoise_preview(&png_of(513, 8, png::ColorType::Rgba), 1).unwrap_err()
        );
        assert!(e.contains("513x8") && e.contains("512x512"), "{e}");
        let e = format!(
            "{:#}",
            denoise_preview(&png_of(8, 8, png::ColorType::Rgb), 1).unwrap_err()
        );
        assert!(e.contains("not 8-bit RGBA"), "{e}");
        let e = format!("{:#}", denoise_preview(b"not a png", 1).unwrap_err());
        assert!(e.contains("not a PNG"), "{e}");
    }

    #[test]
    fn the_curves_are_inverse_on_every_byte() {
        let t = srgb8_to_linear_table();
        for (b, v) in t.iter().enumerate() {
            assert_eq!(usize::from(trevi_core::output::linear_to_srgb8(*v)), b);
        }
    }

    /// A flat grey preview under noise, the preview's largest height (many
    /// bands): denoised, its pixels spread far less around the grey.
    #[cfg(feature = "denoise")]
    #[test]
    fn a_noisy_flat_preview_comes_out_flat() {
        let (w, h) = (512u32, 384u32);
        let mut state = 1u32;
        let mut rgba = Vec::new();
        for _ in 0..w * h {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let v = 100 + (state >> 24) as u8 / 4;
            rgba.extend([v, v, v, 255]);
        }
        let spread = |px: &[u8]| {
            let v: Vec<f64> = px.chunks(4).map(|p| f64::from(p[0])).collect();
            let mean = v.iter().sum::<f64>() / v.len() as f64;
            (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
        };
        let png = encode_png(w, h, &rgba).unwrap();
        let (_, _, out) = decode(&denoise_preview(&png, 1).unwrap()).unwrap();
        let (before, after) = (spread(&rgba), spread(&out));
        assert!(after < 0.25 * before, "spread {before} -> {after}");
    }

    #[cfg(not(feature = "denoise"))]
    #[test]
    fn a_build_without_the_feature_refuses_a_preview_it_could_decode() {
        let e = format!(
            "{:#}",
            denoise_preview(&png_of(8, 8, png::ColorType::Rgba), 1).unwrap_err()
        );
        assert!(e.contains("`denoise` cargo feature"), "{e}");
    }
}
