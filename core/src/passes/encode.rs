//! The bytes of a [`TileState`]: what a coordinator keeps on disk between
//! passes, band by band. Little-endian throughout:
//!
//! | offset | bytes | field |
//! |---|---|---|
//! | 0 | 4 | magic `TVPS` |
//! | 4 | 2 | version, [`VERSION`] |
//! | 6 | 2 | reserved, 0 |
//! | 8 | 16 | the rectangle: x, y, w, h (`u32` each) |
//! | 24 | 4 | next: samples `0..next` are rendered (`u32`) |
//! | 28 | 4 | reserved, 0 |
//! | 32 | 64 × w × h | the pixels, row by row |
//!
//! and each pixel, [`PIXEL_BYTES`] = 64:
//!
//! | offset | bytes | field |
//! |---|---|---|
//! | 0 | 12 | the open block's sum, `f32` × 3 |
//! | 12 | 4 | the count (`u32`) |
//! | 16 | 24 | the closed blocks' total (or adaptive sum), `f64` × 3 |
//! | 40 | 24 | the sum of squares, `f64` × 3 |
//!
//! The decoder takes nothing on trust: the header's lengths are checked
//! against [`MAX_STATE_PIXELS`] and the input's length before anything is
//! allocated, and every pixel against the invariants the integrator keeps
//! (no NaN, squares not negative, a count within `next`, an empty block at
//! a block boundary, nothing summed without a sample), so a decoded state
//! is one the integrator could have left.

use super::TileState;
use crate::integrator::{PixelState, SUM_BLOCK};
use crate::tile::Rect;

/// The first four bytes.
pub const MAGIC: [u8; 4] = *b"TVPS";
/// The layout's version; any other is refused.
pub const VERSION: u16 = 1;
/// The header's length.
pub const HEADER_BYTES: usize = 32;
/// One pixel's length.
pub const PIXEL_BYTES: usize = 64;
/// Most pixels in one encoded state (256 MiB of pixels): a band of 64 rows
/// of the widest frame (65536 pixels) is 2²² pixels.
pub const MAX_STATE_PIXELS: u64 = 1 << 22;

/// Why bytes are not a [`TileState`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum StateError {
    /// Fewer bytes than a header.
    #[error("{len} bytes are shorter than the {HEADER_BYTES}-byte header")]
    Short {
        /// The input's length.
        len: usize,
    },
    /// The first four bytes are not [`MAGIC`].
    #[error("not an accumulation state (bad magic)")]
    Magic,
    /// The header's version (given) is not [`VERSION`].
    #[error("version {0} of the accumulation state is not known (expected {VERSION})")]
    Version(u16),
    /// A reserved header field is not zero.
    #[error("reserved header bytes are not zero")]
    Reserved,
    /// The header's rectangle is empty, or its end column or row passes
    /// `u32::MAX`.
    #[error("the rectangle {w}×{h} at ({x}, {y}) is empty or passes 2³² pixels")]
    Rect {
        /// The rectangle's first column.
        x: u32,
        /// Its first row.
        y: u32,
        /// Its width in pixels.
        w: u32,
        /// Its height in pixels.
        h: u32,
    },
    /// The rectangle has more than [`MAX_STATE_PIXELS`] pixels.
    #[error("{pixels} pixels are more than the {MAX_STATE_PIXELS} a state may hold")]
    TooLarge {
        /// Its pixel count.
        pixels: u64,
    },
    /// The input is not exactly a header and the rectangle's pixels long.
    #[error("{got} bytes where the header says {expected}")]
    Length {
        /// The length the header implies.
        expected: u64,
        /// The input's length.
        got: u64,
    },
    /// A pixel breaks an invariant of the integrator's state, so no render
    /// left it.
    #[error("pixel {index}: {what}")]
    Pixel {
        /// The pixel's index, row by row in the rectangle.
        index: usize,
        /// Which invariant it breaks.
        what: &'static str,
    },
}

impl TileState {
    /// The encoded length of a state of rectangle `rect`.
    pub fn encoded_len(rect: Rect) -> usize {
        HEADER_BYTES + PIXEL_BYTES * rect.pixel_count()
    }

    /// The header of the encoding of a state of `rect` rendered up to
    /// sample `next`: what a keeper of the pixels' bytes alone (a
    /// coordinator's state file, row by row) puts before them to make an
    /// encoded state again.
    pub fn encode_header(rect: Rect, next: u32) -> [u8; HEADER_BYTES] {
        let mut out = [0u8; HEADER_BYTES];
        out[..4].copy_from_slice(&MAGIC);
        out[4..6].copy_from_slice(&VERSION.to_le_bytes());
        for (i, v) in [rect.x, rect.y, rect.w, rect.h, next]
            .into_iter()
            .enumerate()
        {
            out[8 + 4 * i..12 + 4 * i].copy_from_slice(&v.to_le_bytes());
        }
        out
    }

    /// The state's bytes (see the module documentation).
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(Self::encoded_len(self.rect));
        out.extend_from_slice(&Self::encode_header(self.rect, self.next));
        for p in &self.pixels {
            for c in p.block {
                out.extend_from_slice(&c.to_le_bytes());
            }
            out.extend_from_slice(&p.count.to_le_bytes());
            for c in p.total.iter().chain(&p.sum_sq) {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
        out
    }

    /// The state encoded in `bytes`, or why it is not one.
    pub fn decode(bytes: &[u8]) -> Result<TileState, StateError> {
        let Some(header) = bytes.get(..HEADER_BYTES) else {
            return Err(StateError::Short { len: bytes.len() });
        };
        if header[..4] != MAGIC {
            return Err(StateError::Magic);
        }
        let version = u16::from_le_bytes([header[4], header[5]]);
        if version != VERSION {
            return Err(StateError::Version(version));
        }
        let word = |i: usize| u32::from_le_bytes(header[i..i + 4].try_into().expect("4 bytes"));
        if header[6..8] != [0, 0] || word(28) != 0 {
            return Err(StateError::Reserved);
        }
        let (x, y, w, h, next) = (word(8), word(12), word(16), word(20), word(24));
        let fits = |o: u32, l: u32| o.checked_add(l).is_some();
        if w == 0 || h == 0 || !fits(x, w) || !fits(y, h) {
            return Err(StateError::Rect { x, y, w, h });
        }
        let pixels = u64::from(w) * u64::from(h);
        if pixels > MAX_STATE_PIXELS {
            return Err(StateError::TooLarge { pixels });
        }
        let expected = HEADER_BYTES as u64 + PIXEL_BYTES as u64 * pixels;
        if bytes.len() as u64 != expected {
            return Err(StateError::Length {
                expected,
                got: bytes.len() as u64,
            });
        }
        // Bounded by MAX_STATE_PIXELS and by the input's own length.
        let mut states = Vec::with_capacity(pixels as usize);
        for (index, b) in bytes[HEADER_BYTES..].chunks_exact(PIXEL_BYTES).enumerate() {
            let f32_at = |i: usize| f32::from_le_bytes(b[i..i + 4].try_into().expect("4 bytes"));
            let f64_at = |i: usize| f64::from_le_bytes(b[i..i + 8].try_into().expect("8 bytes"));
            let p = PixelState {
                block: [f32_at(0), f32_at(4), f32_at(8)],
                count: u32::from_le_bytes(b[12..16].try_into().expect("4 bytes")),
                total: [f64_at(16), f64_at(24), f64_at(32)],
                sum_sq: [f64_at(40), f64_at(48), f64_at(56)],
            };
            check_pixel(&p, next).map_err(|what| StateError::Pixel { index, what })?;
            states.push(p);
        }
        Ok(TileState {
            rect: Rect { x, y, w, h },
            next,
            pixels: states,
        })
    }
}

/// The invariants every state the integrator leaves keeps.
fn check_pixel(p: &PixelState, next: u32) -> Result<(), &'static str> {
    if p.count > next {
        return Err("more samples than the state has rendered");
    }
    if p.block.iter().any(|c| c.is_nan()) || p.total.iter().any(|c| c.is_nan()) {
        return Err("a sum is NaN");
    }
    // Squares are at least +0, so their sum is too (this also refuses NaN).
    if !p.sum_sq.iter().all(|&c| c >= 0.0) {
        return Err("a sum of squares is negative or NaN");
    }
    let zero3 = |v: &[f32; 3]| v.iter().all(|&c| c == 0.0);
    if p.count.is_multiple_of(SUM_BLOCK) && !zero3(&p.block) {
        return Err("the open block has a sum at a block boundary");
    }
    if p.count == 0 && !(p.total.iter().chain(&p.sum_sq).all(|&c| c == 0.0)) {
        return Err("sums without a sample");
    }
    Ok(())
}
