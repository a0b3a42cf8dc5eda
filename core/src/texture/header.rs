//! What a texture file says about itself before any pixel is decoded: its
//! format and the size of **every** image it holds (an OpenEXR file may
//! hold several parts, each with its own header), read from the headers
//! alone: a PNG's IHDR chunk (and its chunks' lengths, [`super::png_scan`]),
//! a JPEG's frame header and scan count ([`super::jpeg_scan`]), every part
//! header of an OpenEXR file (through `exr`'s meta-data reader, which reads
//! the headers and none of the pixel data).
//!
//! Two users: the decoder checks the header against its budget before it
//! allocates anything for pixels ([`TextureHeader::check`]), and the
//! coordinator admits a job by reading the headers of the scene's textures
//! without decoding them (`scene::aisxml`'s headers-only parse), so that a
//! small file claiming a huge image costs a header read in either place.
//!
//! Bounds checked on every part of an OpenEXR file, not only the first one
//! (the decoder reads the offset tables of every part and may allocate for
//! any of them): each side at most [`super::MAX_TEXTURE_SIDE`], at most
//! [`super::MAX_TEXTURE_TEXELS`] texels, all parts together within the caller's
//! budget; at most [`MAX_EXR_CHANNELS`] channels; one block (a tile, or the
//! scan lines compressed together) at most [`MAX_EXR_BLOCK_BYTES`]
//! uncompressed; and at least 8 bytes of the file for each chunk the
//! headers announce (every chunk has an 8-byte entry in the offset table),
//! so a 1 × 1-tiled header cannot announce a billion chunks. Deep parts are
//! refused (textures are flat images).

use super::{check_size, TextureError};
use std::io::Cursor;

/// The most channels of one part of an OpenEXR texture.
pub const MAX_EXR_CHANNELS: usize = 64;

/// The most bytes one uncompressed block (a tile, or the group of scan
/// lines compressed together) of an OpenEXR texture may hold: 16,384
/// pixels wide × 32 lines × 4 channels of f32 is 8 MiB; this allows 8 times
/// that.
pub const MAX_EXR_BLOCK_BYTES: u64 = 64 << 20;

/// A texture file's format, recognised by its content.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImageFormat {
    /// PNG, 8 or 16 bits, sRGB-encoded.
    Png,
    /// JPEG (baseline or progressive), sRGB-encoded.
    Jpeg,
    /// OpenEXR, linear.
    Exr,
}

/// One image of a texture file (a PNG or JPEG has one; an OpenEXR file one
/// per part).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Part {
    /// The image's width in pixels, as the header says (unchecked).
    pub width: u64,
    /// Its height in pixels, as the header says (unchecked).
    pub height: u64,
    /// Channels of the part (OpenEXR only; 0 for PNG and JPEG).
    pub channels: usize,
    /// Whether the part has channels named R, G and B (what the decoder
    /// reads; always true for PNG and JPEG, which are decoded to RGB).
    pub rgb: bool,
    /// Bytes of one uncompressed block (OpenEXR only).
    pub block_bytes: u64,
    /// Chunks the part's offset table announces (OpenEXR only).
    pub chunks: u64,
    /// A deep-data part (OpenEXR only).
    pub deep: bool,
}

/// What a texture file's headers say.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TextureHeader {
    /// The file's format, from its first bytes.
    pub format: ImageFormat,
    /// Every image of the file, in file order (at least one).
    pub parts: Vec<Part>,
    /// The file's size in bytes.
    pub file_bytes: u64,
}

/// Reads the headers of a PNG, JPEG or OpenEXR file (recognised by
/// content), never its pixel data.
pub fn probe(bytes: &[u8]) -> Result<TextureHeader, TextureError> {
    let file_bytes = bytes.len() as u64;
    if bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
        return Ok(TextureHeader {
            format: ImageFormat::Exr,
            parts: exr_parts(Cursor::new(bytes))?,
            file_bytes,
        });
    }
    let reader = image::io::Reader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| TextureError::Decode(e.to_string()))?;
    let format = match reader.format() {
        Some(image::ImageFormat::Png) => ImageFormat::Png,
        Some(image::ImageFormat::Jpeg) => ImageFormat::Jpeg,
        _ => return Err(TextureError::Format),
    };
    let (w, h) = match format {
        // PNG: straight from IHDR (the decoder reads on to the first data
        // chunk before it says); the image data the chunks hold is bounded
        // by what that image can need (the decoder inflates all of it).
        ImageFormat::Png => {
            let wh = super::png_size(bytes).ok_or_else(|| {
                TextureError::Decode("the PNG does not start with its IHDR chunk".into())
            })?;
            super::png_scan::check(bytes)?;
            wh
        }
        // JPEG: the frame's size and the scan count from the markers; a
        // decode costs a pass over the image per scan.
        _ => {
            let shape = super::jpeg_scan::scan(bytes, super::jpeg_scan::MAX_JPEG_SCANS)?;
            (shape.width, shape.height)
        }
    };
    Ok(TextureHeader {
        format,
        parts: vec![Part {
            width: u64::from(w),
            height: u64::from(h),
            channels: 0,
            rgb: true,
            block_bytes: 0,
            chunks: 0,
            deep: false,
        }],
        file_bytes,
    })
}

impl TextureHeader {
    /// Checks every part against the bounds of the module's documentation,
    /// the texels of all parts together against `budget`, and returns the
    /// size of the image the decoder makes the texture of: the first part
    /// with R, G and B channels.
    pub fn check(&self, budget: u64) -> Result<(u32, u32), TextureError> {
        self.check_blocks()?;
        let mut total = 0u64;
        for p in &self.parts {
            check_size(p.width, p.height, u64::MAX)?;
            total = total.saturating_add(p.width * p.height);
        }
        let Some(main) = self.parts.iter().find(|p| p.rgb) else {
            return Err(TextureError::Decode(
                "no part has R, G and B channels".into(),
            ));
        };
        if total > budget {
            return Err(TextureError::OverBudget {
                width: main.width,
                height: main.height,
                left: budget,
            });
        }
        // Both sides fit in u32: check_size bounds them by MAX_TEXTURE_SIDE.
        Ok((main.width as u32, main.height as u32))
    }

    /// The bounds of an OpenEXR file's layout whatever its image size (the
    /// module's documentation): the offset tables' entries within the file,
    /// no deep part, at most [`MAX_EXR_CHANNELS`] channels and one block at
    /// most [`MAX_EXR_BLOCK_BYTES`] in every part. The denoiser's reader
    /// checks these too, with its own bound on the image size.
    pub fn check_blocks(&self) -> Result<(), TextureError> {
        let chunks = self
            .parts
            .iter()
            .fold(0u64, |n, p| n.saturating_add(p.chunks));
        if chunks.saturating_mul(8) > self.file_bytes {
            return Err(TextureError::Decode(format!(
                "the headers announce {chunks} chunks, more than a file of {} bytes can hold \
                 (each has an 8-byte offset)",
                self.file_bytes
            )));
        }
        for (i, p) in self.parts.iter().enumerate() {
            let at = |what: String| {
                if self.parts.len() > 1 {
                    TextureError::Decode(format!("part {i}: {what}"))
                } else {
                    TextureError::Decode(what)
                }
            };
            if p.deep {
                return Err(at(
                    "deep data is not supported (expected a flat image)".into()
                ));
            }
            if p.channels > MAX_EXR_CHANNELS {
                return Err(at(format!(
                    "{} channels (expected at most {MAX_EXR_CHANNELS})",
                    p.channels
                )));
            }
            if p.block_bytes > MAX_EXR_BLOCK_BYTES {
                return Err(at(format!(
                    "a block of {} bytes (expected at most {MAX_EXR_BLOCK_BYTES})",
                    p.block_bytes
                )));
            }
        }
        Ok(())
    }

    /// The bytes the decoded texture holds (level 0 and its MIP chain, 12
    /// bytes a texel), for the size [`TextureHeader::check`] returns.
    pub fn decoded_bytes(width: u32, height: u32) -> u64 {
        mip_chain_texels(width, height) * std::mem::size_of::<glam::Vec3>() as u64
    }
}

/// Texels of an image of `width × height` and of every level of its MIP
/// chain (each level half the one above, rounded down, at least 1, down to
/// 1 × 1: what [`super::Texture::from_texels`] makes).
pub fn mip_chain_texels(width: u32, height: u32) -> u64 {
    let (mut w, mut h) = (u64::from(width.max(1)), u64::from(height.max(1)));
    let mut sum = w * h;
    while w > 1 || h > 1 {
        w = (w / 2).max(1);
        h = (h / 2).max(1);
        sum += w * h;
    }
    sum
}

/// Reads the headers of the OpenEXR file `read` (of `file_bytes` bytes),
/// never its pixel data nor its offset tables: what [`probe`] does for an
/// OpenEXR file in memory, for one read from disk.
pub fn probe_exr(read: impl std::io::Read, file_bytes: u64) -> Result<TextureHeader, TextureError> {
    Ok(TextureHeader {
        format: ImageFormat::Exr,
        parts: exr_parts(read)?,
        file_bytes,
    })
}

/// The parts of an OpenEXR file, from its headers.
fn exr_parts(read: impl std::io::Read) -> Result<Vec<Part>, TextureError> {
    use exr::meta::BlockDescription;
    let meta = exr::meta::MetaData::read_from_buffered(read, false)
        .map_err(|e| TextureError::Decode(e.to_string()))?;
    if meta.headers.is_empty() {
        return Err(TextureError::Decode("the file has no part".into()));
    }
    Ok(meta
        .headers
        .iter()
        .map(|h| {
            let size = h.layer_size;
            let channels = &h.channels.list;
            let has = |n: &str| channels.iter().any(|c| c.name.eq(n));
            let bytes_per_pixel: u64 = channels
                .iter()
                .map(|c| c.sample_type.bytes_per_sample() as u64)
                .sum();
            let block_pixels = match h.blocks {
                BlockDescription::ScanLines => (h.compression.scan_lines_per_block() as u64)
                    .saturating_mul(size.width() as u64),
                BlockDescription::Tiles(t) => {
                    (t.tile_size.width() as u64).saturating_mul(t.tile_size.height() as u64)
                }
            };
            Part {
                width: size.width() as u64,
                height: size.height() as u64,
                channels: channels.len(),
                rgb: has("R") && has("G") && has("B"),
                block_bytes: block_pixels.saturating_mul(bytes_per_pixel),
                chunks: h.chunk_count as u64,
                deep: h.deep,
            }
        })
        .collect())
}

#[cfg(test)]
pub(crate) mod tests;
