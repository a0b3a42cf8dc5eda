//! Which rows each band denoises and which it only reads.
//!
//! A convolutional denoiser's output at a pixel depends on the input within
//! its receptive field, so a band denoised alone is exact in its middle and
//! wrong near its cut edges. Each band therefore reads `overlap` rows of
//! context above and below the rows it keeps (clipped at the frame's edges)
//! and keeps only its own rows. Bands start at multiples of
//! [`ALIGNMENT`] rows, the factor by which the U-Net's pooling levels shrink
//! the image, so every band's pooling grid lines up with the whole frame's:
//! with the context at least half the receptive field, a band's kept rows
//! see what the whole frame's would. The measured difference, band against
//! whole, is in docs/denoise.md.

use crate::DenoiseError;
use std::ops::Range;

/// Rows by which a band's start and its context are aligned: 2^4 for the
/// four 2×2 poolings of Open Image Denoise's U-Net (its own tile alignment).
pub const ALIGNMENT: u32 = 16;

/// Rows of context read above and below a band by default: the library's
/// own tile overlap (half its receptive field rounded up to [`ALIGNMENT`]).
/// Measured (docs/denoise.md): 80 rows and more give bands bit-identical to
/// the whole frame, 64 differ by up to 1.2e-2.
pub const DEFAULT_OVERLAP: u32 = 96;

/// Rows a band keeps by default: with 96 rows of context on each side a band
/// of 256 reads 1.75 times its rows; the cost of context falls as bands grow
/// and the memory grows (see [`Band::read_rows`]).
pub const DEFAULT_BAND_ROWS: u32 = 256;

/// One band: the rows it writes and the rows it reads.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Band {
    /// Rows whose denoised values this band writes.
    pub keep: Range<u32>,
    /// Rows it reads: `keep` with up to `overlap` rows each side.
    pub read: Range<u32>,
}

impl Band {
    /// Rows read (context included): memory for the band's inputs is
    /// `read_rows × width × 36` bytes (colour, albedo, normal as three f32s).
    pub fn read_rows(&self) -> u32 {
        self.read.end - self.read.start
    }
}

/// How a frame of `height` rows is cut: bands of `band_rows` (a multiple
/// of [`ALIGNMENT`], at least one) each reading `overlap` rows around it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BandPlan {
    /// Frame height in rows.
    pub height: u32,
    /// Rows each band keeps (the last may keep fewer).
    pub band_rows: u32,
    /// Rows of context each side.
    pub overlap: u32,
}

impl BandPlan {
    /// A plan, refused when `band_rows` is zero or not aligned, or the
    /// overlap is not aligned.
    pub fn new(height: u32, band_rows: u32, overlap: u32) -> Result<BandPlan, DenoiseError> {
        if band_rows == 0
            || !band_rows.is_multiple_of(ALIGNMENT)
            || !overlap.is_multiple_of(ALIGNMENT)
        {
            return Err(DenoiseError::Band {
                start: 0,
                end: band_rows,
                width: 0,
                height,
                what: "bands and their overlap must be positive multiples of 16 rows",
            });
        }
        Ok(BandPlan {
            height,
            band_rows,
            overlap,
        })
    }

    /// The bands, top to bottom: their `keep` ranges cover every row once.
    pub fn bands(&self) -> impl Iterator<Item = Band> + '_ {
        let step = self.band_rows as usize;
        (0..self.height).step_by(step).map(move |start| {
            let end = start.saturating_add(self.band_rows).min(self.height);
            Band {
                keep: start..end,
                read: start.saturating_sub(self.overlap)
                    ..end.saturating_add(self.overlap).min(self.height),
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bands_cover_every_row_once_and_read_aligned_context() {
        for height in [1u32, 15, 16, 17, 255, 256, 257, 1000, 4097] {
            for (band_rows, overlap) in [(16, 0), (16, 16), (64, 32), (256, 128)] {
                let plan = BandPlan::new(height, band_rows, overlap).unwrap();
                let mut next = 0;
                for band in plan.bands() {
                    assert_eq!(band.keep.start, next, "height {height}");
                    assert!(band.keep.end > band.keep.start);
                    assert_eq!(band.keep.start % ALIGNMENT, 0);
                    assert_eq!(band.read.start % ALIGNMENT, 0);
                    assert!(band.read.start <= band.keep.start && band.read.end >= band.keep.end);
                    assert!(band.read.end <= height);
                    let above = band.keep.start - band.read.start;
                    assert_eq!(above, overlap.min(band.keep.start));
                    let below = band.read.end - band.keep.end;
                    assert_eq!(below, overlap.min(height - band.keep.end));
                    next = band.keep.end;
                }
                assert_eq!(next, height);
            }
        }
    }

    #[test]
    fn unaligned_plans_are_refused() {
        assert!(BandPlan::new(100, 0, 16).is_err());
        assert!(BandPlan::new(100, 24, 16).is_err());
        assert!(BandPlan::new(100, 32, 8).is_err());
    }
}
