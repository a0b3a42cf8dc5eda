//! Image textures: decoded once when a scene is parsed into linear RGB with
//! a MIP chain, then sampled bilinearly (trilinearly between two levels
//! when minified) at a level of detail the integrator's ray cone chooses.
//!
//! Formats: PNG and JPEG through the `image` crate, OpenEXR through `exr`.
//! 8-bit and 16-bit PNG/JPEG values are sRGB-encoded colour and are decoded
//! to linear once, here (8-bit through a 256-entry table); EXR values are
//! linear already and are taken as they are (non-finite ones become 0,
//! negative ones are kept). Grey images give grey texels; alpha is ignored.
//!
//! Bounds: the image's size is read from its header and checked against
//! [`MAX_TEXTURE_SIDE`] and [`MAX_TEXTURE_TEXELS`] before anything is
//! allocated for its pixels, so a 100,000 × 100,000 PNG header is refused at
//! the cost of reading a header. The MIP chain adds at most a third. A
//! JPEG's markers are read first ([`jpeg_scan`]): its size comes from its
//! frame header, and one of more than [`jpeg_scan::MAX_JPEG_SCANS`] scans
//! (each a pass over every block when decoded) is refused. A PNG whose
//! compressed image data is more than its IHDR's image can need is refused
//! from its chunk headers ([`png_scan`]): the decoder inflates all of it.
//!
//! Coordinates: `u` runs left to right and `v = 0` is the image's bottom row
//! (the OBJ convention); texel `(i, j)` (column, row from the top) has its
//! centre at `u = (i + ½)/W`, `v = 1 − (j + ½)/H`.

pub mod header;
pub mod jpeg_scan;
pub mod png_scan;
mod sample;

pub use sample::Wrap;

use glam::Vec3;
use std::io::Cursor;
use thiserror::Error;

/// The largest width or height of a texture image.
pub const MAX_TEXTURE_SIDE: u32 = 16_384;
/// The most texels (width × height) of a texture image: 4096 × 4096. At 12
/// bytes a texel plus a third for the MIP chain, 256 MiB.
pub const MAX_TEXTURE_TEXELS: u64 = 1 << 24;
/// The most texels of all the textures of one scene together (level 0):
/// 4 × [`MAX_TEXTURE_TEXELS`], 1 GiB with the MIP chains. The compressed
/// files are bounded by the bundle's size, but a small PNG can decode to a
/// large image; this bounds what a worker holds.
pub const MAX_SCENE_TEXELS: u64 = 4 * MAX_TEXTURE_TEXELS;

/// Why a file is not a texture the renderer takes.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum TextureError {
    /// The content is not PNG, JPEG or OpenEXR.
    #[error("unsupported texture format (expected a PNG, JPEG or OpenEXR file)")]
    Format,
    /// An image is over [`MAX_TEXTURE_SIDE`] or [`MAX_TEXTURE_TEXELS`].
    #[error("texture is {width} x {height} (expected each side at most {MAX_TEXTURE_SIDE} and at most {MAX_TEXTURE_TEXELS} texels)")]
    TooLarge {
        /// The image's width in texels, from its header.
        width: u64,
        /// Its height in texels.
        height: u64,
    },
    /// The texture (every part of an OpenEXR file together) needs more
    /// texels than the scene's [`MAX_SCENE_TEXELS`] has left.
    #[error("texture is {width} x {height}, more than the {left} texels left of the scene's {MAX_SCENE_TEXELS} for all its textures")]
    OverBudget {
        /// The (main) image's width in texels.
        width: u64,
        /// Its height in texels.
        height: u64,
        /// The texels the scene's earlier textures left.
        left: u64,
    },
    /// An image with a width or height of 0.
    #[error("texture has no pixels ({width} x {height})")]
    Empty {
        /// The image's width in texels.
        width: u64,
        /// Its height in texels.
        height: u64,
    },
    /// The decoder (or a header reader) refused the file: its message.
    #[error("cannot decode the texture: {0}")]
    Decode(String),
    /// Refused from its markers before decoding (see [`jpeg_scan`]).
    #[error("{0}")]
    Jpeg(#[from] jpeg_scan::JpegScanError),
    /// Refused from its chunks before decoding (see [`png_scan`]).
    #[error("{0}")]
    Png(#[from] png_scan::PngScanError),
}

/// One level of a MIP chain: `width × height` linear RGB texels, rows from
/// the top.
#[derive(Debug, Clone, PartialEq)]
pub struct Level {
    /// The level's width in texels (≥ 1).
    pub width: u32,
    /// Its height in texels (≥ 1).
    pub height: u32,
    /// `width × height` texels, row by row.
    pub texels: Vec<Vec3>,
}

impl Level {
    #[inline]
    fn at(&self, i: u32, j: u32) -> Vec3 {
        self.texels[j as usize * self.width as usize + i as usize]
    }
}

/// A decoded texture: level 0 is the image, each next level half the size
/// (rounded down, at least 1) down to 1 × 1.
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    /// The MIP chain, level 0 first (at least one level).
    pub levels: Vec<Level>,
}

impl Texture {
    /// A texture from level-0 texels (rows from the top), with its MIP chain.
    pub fn from_texels(width: u32, height: u32, texels: Vec<Vec3>) -> Texture {
        debug_assert_eq!(texels.len(), width as usize * height as usize);
        let mut levels = vec![Level {
            width,
            height,
            texels,
        }];
        while let Some(next) = downsample(levels.last().expect("level 0")) {
            levels.push(next);
        }
        Texture { levels }
    }

    /// Bytes held by the texels of every level.
    pub fn memory_bytes(&self) -> u64 {
        self.levels
            .iter()
            .map(|l| (l.texels.len() * std::mem::size_of::<Vec3>()) as u64)
            .sum()
    }

    /// Decodes `bytes` (PNG, JPEG or OpenEXR, recognised by content).
    pub fn decode(bytes: &[u8]) -> Result<Texture, TextureError> {
        Self::decode_within(bytes, MAX_TEXTURE_TEXELS)
    }

    /// [`Texture::decode`], refusing (from the header, before decoding) an
    /// image of more than `budget` texels.
    pub fn decode_within(bytes: &[u8], budget: u64) -> Result<Texture, TextureError> {
        if bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
            return decode_exr(bytes, budget);
        }
        // Every bound the header allows to check, before anything is
        // decoded (the same rule the coordinator admits a job by).
        let head = header::probe(bytes)?;
        let (w, h) = head.check(budget)?;
        let format = match head.format {
            header::ImageFormat::Png => image::ImageFormat::Png,
            _ => image::ImageFormat::Jpeg,
        };
        let mut reader = image::io::Reader::new(Cursor::new(bytes));
        reader.set_format(format);
        let mut limits = image::io::Limits::default();
        limits.max_image_width = Some(MAX_TEXTURE_SIDE);
        limits.max_image_height = Some(MAX_TEXTURE_SIDE);
        // The decoded image at 16 bits and 4 channels, and some slack.
        limits.max_alloc = Some(MAX_TEXTURE_TEXELS * 8 + (1 << 20));
        reader.limits(limits);
        let img = reader
            .decode()
            .map_err(|e| TextureError::Decode(e.to_string()))?;
        let texels: Vec<Vec3> = match img {
            image::DynamicImage::ImageLuma8(_)
            | image::DynamicImage::ImageLumaA8(_)
            | image::DynamicImage::ImageRgb8(_)
            | image::DynamicImage::ImageRgba8(_) => {
                let lut = srgb8_table();
                img.to_rgb8()
                    .pixels()
                    .map(|p| Vec3::new(lut[p[0] as usize], lut[p[1] as usize], lut[p[2] as usize]))
                    .collect()
            }
            _ => img
                .to_rgb16()
                .pixels()
                .map(|p| {
                    Vec3::from_array(p.0.map(|c| srgb_to_linear(f64::from(c) / 65535.0) as f32))
                })
                .collect(),
        };
        Ok(Texture::from_texels(w, h, texels))
    }
}

/// A PNG's width and height from its IHDR chunk, which must come first.
fn png_size(b: &[u8]) -> Option<(u32, u32)> {
    if b.len() < 24 || &b[..8] != b"\x89PNG\r\n\x1a\n" || &b[12..16] != b"IHDR" {
        return None;
    }
    let be = |i: usize| u32::from_be_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
    Some((be(16), be(20)))
}

fn check_size(width: u64, height: u64, budget: u64) -> Result<(), TextureError> {
    if width == 0 || height == 0 {
        return Err(TextureError::Empty { width, height });
    }
    if width > u64::from(MAX_TEXTURE_SIDE)
        || height > u64::from(MAX_TEXTURE_SIDE)
        || width * height > MAX_TEXTURE_TEXELS
    {
        return Err(TextureError::TooLarge { width, height });
    }
    if width * height > budget {
        return Err(TextureError::OverBudget {
            width,
            height,
            left: budget,
        });
    }
    Ok(())
}

/// The sRGB transfer function's inverse (IEC 61966-2-1), in f64.
pub fn srgb_to_linear(c: f64) -> f64 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        crate::math::pow((c + 0.055) / 1.055, 2.4)
    }
}

/// Linear values of the 256 8-bit sRGB codes.
fn srgb8_table() -> [f32; 256] {
    std::array::from_fn(|i| srgb_to_linear(i as f64 / 255.0) as f32)
}

/// The next MIP level: each texel the mean of the (up to) 2 × 2 texels it
/// covers (a box filter; an odd last row or column is folded into the last
/// texel of the level below, which then averages 2 × 3, 3 × 2 or 3 × 3, so
/// no texel is dropped). `None` at 1 × 1.
fn downsample(l: &Level) -> Option<Level> {
    if l.width == 1 && l.height == 1 {
        return None;
    }
    let (w, h) = ((l.width / 2).max(1), (l.height / 2).max(1));
    let mut texels = Vec::with_capacity(w as usize * h as usize);
    for j in 0..h {
        let rows = span(j, h, l.height);
        for i in 0..w {
            let cols = span(i, w, l.width);
            let mut sum = glam::DVec3::ZERO;
            for y in rows.clone() {
                for x in cols.clone() {
                    sum += l.at(x, y).as_dvec3();
                }
            }
            let n = (rows.len() * cols.len()) as f64;
            texels.push((sum / n).as_vec3());
        }
    }
    Some(Level {
        width: w,
        height: h,
        texels,
    })
}

/// The source texels of target texel `k` of `n` along a side of `src`
/// texels: `2k, 2k+1`, and the last one also takes an odd leftover.
fn span(k: u32, n: u32, src: u32) -> std::ops::Range<u32> {
    if src == 1 {
        return 0..1;
    }
    let end = if k + 1 == n { src } else { 2 * k + 2 };
    2 * k..end
}

fn decode_exr(bytes: &[u8], budget: u64) -> Result<Texture, TextureError> {
    use exr::prelude::*;
    let err = |e: exr::error::Error| TextureError::Decode(e.to_string());
    // Every part's header first (the reader may allocate for any part, not
    // only the one it keeps): checked before any pixel is allocated.
    header::probe(bytes)?.check(budget)?;
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .specific_channels()
        .required("R")
        .required("G")
        .required("B")
        .collect_pixels(
            |res, _| (res.width(), vec![Vec3::ZERO; res.width() * res.height()]),
            |(w, texels): &mut (usize, Vec<Vec3>), pos, (r, g, b): (f32, f32, f32)| {
                let finite = |x: f32| if x.is_finite() { x } else { 0.0 };
                texels[pos.y() * *w + pos.x()] = Vec3::new(finite(r), finite(g), finite(b));
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .map_err(err)?;
    let layer = image.layer_data;
    let (w, h) = (layer.size.width(), layer.size.height());
    check_size(w as u64, h as u64, budget)?;
    Ok(Texture::from_texels(
        w as u32,
        h as u32,
        layer.channel_data.pixels.1,
    ))
}

#[cfg(test)]
pub(crate) mod tests;
