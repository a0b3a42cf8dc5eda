//! Denoising a stitched frame band by band, without seams.
//!
//! The farm stitches every frame in one place, so it can denoise the whole
//! frame rather than each tile (which leaves seams: a tile's denoiser sees
//! nothing past its border). The frame is never whole in memory either:
//! [`denoise_frame`] reads it band by band from a [`Source`] (the stitched
//! noisy beauty with its albedo and normal), gives Intel Open Image Denoise
//! each band with enough rows of context above and below ([`plan`]) and one
//! exposure for the whole frame ([`exposure`]), and hands on only the
//! band's own rows. The result equals denoising the whole frame at once to
//! within the bound measured in docs/denoise.md.
//!
//! Steps: noisy frame → [`exposure`] (one pass over it) → [`plan`] (bands
//! with context) → [`filter`] (the library, one band at a time) → sink.
//!
//! # Cost
//! Memory: one band's inputs and output, `(band_rows + 2·overlap) × width ×
//! 48` bytes (colour, albedo, normal, output as three f32s each) plus the
//! library's own working memory for that block; CPU: the library's time for
//! `(band_rows + 2·overlap) / band_rows` times the frame's pixels.
//!
//! Without the `oidn` feature the crate builds and every request is refused
//! with [`filter::HOW_TO_GET`].

#![cfg_attr(not(test), deny(clippy::unwrap_used))]

mod error;
pub mod exposure;
pub mod exr_source;
pub mod file;
pub mod filter;
pub mod plan;

pub use error::DenoiseError;
pub use exr_source::ExrSource;
pub use file::{denoise_file, Denoised};
pub use filter::{Denoiser, BUILT_IN, HOW_TO_GET};
pub use plan::{Band, BandPlan, ALIGNMENT, DEFAULT_BAND_ROWS, DEFAULT_OVERLAP};

use std::ops::Range;

/// One block of rows of the noisy frame: colour, and the auxiliary images
/// the filter uses when present (normals only with albedo).
#[derive(Debug, Default, Clone)]
pub struct Inputs {
    /// Linear HDR colour, row-major.
    pub color: Vec<[f32; 3]>,
    /// Albedo in [0, 1], when rendered.
    pub albedo: Option<Vec<[f32; 3]>>,
    /// Shading normals in [-1, 1], when rendered.
    pub normal: Option<Vec<[f32; 3]>>,
}

/// Where the noisy frame is read from: any rows, any number of times.
pub trait Source {
    /// Frame width in pixels.
    fn width(&self) -> u32;
    /// Frame height in pixels.
    fn height(&self) -> u32;
    /// Fills `into` with rows `rows` (its vectors resized to them).
    fn read(&mut self, rows: Range<u32>, into: &mut Inputs) -> Result<(), DenoiseError>;
}

/// Where denoised rows go: each band's kept rows and their colour.
pub type Sink<'a> = dyn FnMut(Range<u32>, &[[f32; 3]]) -> Result<(), DenoiseError> + 'a;

/// Denoises the frame of `source` band by band as `plan` cuts it, calling
/// `sink` with each band's kept rows and their denoised colour, top to
/// bottom. Returns the exposure used.
pub fn denoise_frame(
    denoiser: &Denoiser,
    source: &mut dyn Source,
    plan: BandPlan,
    sink: &mut Sink<'_>,
) -> Result<f32, DenoiseError> {
    let (width, height) = (source.width(), source.height());
    if plan.height != height {
        return Err(DenoiseError::Band {
            start: 0,
            end: plan.height,
            width,
            height,
            what: "the plan is for another frame height",
        });
    }
    let scale = frame_exposure(source)?;
    let mut inputs = Inputs::default();
    let mut out = Vec::new();
    for band in plan.bands() {
        source.read(band.read.clone(), &mut inputs)?;
        denoiser.filter(width, band.read_rows(), &inputs, scale, &mut out)?;
        let skip = (band.keep.start - band.read.start) as usize * width as usize;
        let keep = (band.keep.end - band.keep.start) as usize * width as usize;
        sink(band.keep.clone(), &out[skip..skip + keep])?;
    }
    Ok(scale)
}

/// The frame's exposure ([`exposure`]), read 16 rows at a time.
pub fn frame_exposure(source: &mut dyn Source) -> Result<f32, DenoiseError> {
    let (width, height) = (source.width(), source.height());
    let mut exposure = exposure::Exposure::new(width);
    let mut block = Inputs::default();
    for y in (0..height).step_by(ALIGNMENT as usize) {
        let end = (y + ALIGNMENT).min(height);
        source.read(y..end, &mut block)?;
        exposure.add_block(end - y, &block.color);
    }
    Ok(exposure.scale())
}

/// Refuses a read of `rows` that is empty or runs past a `width` ×
/// `height` frame: the one check every [`Source`] makes first.
pub fn check_rows(rows: &Range<u32>, width: u32, height: u32) -> Result<(), DenoiseError> {
    if rows.start >= rows.end || rows.end > height {
        return Err(DenoiseError::Band {
            start: rows.start,
            end: rows.end,
            width,
            height,
            what: "rows outside the frame",
        });
    }
    Ok(())
}

/// A frame held in memory: for tests, benchmarks and small previews.
#[derive(Debug, Clone)]
pub struct InMemory {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// The whole frame's inputs.
    pub frame: Inputs,
}

impl Source for InMemory {
    fn width(&self) -> u32 {
        self.width
    }
    fn height(&self) -> u32 {
        self.height
    }
    fn read(&mut self, rows: Range<u32>, into: &mut Inputs) -> Result<(), DenoiseError> {
        check_rows(&rows, self.width, self.height)?;
        let w = self.width as usize;
        let span = rows.start as usize * w..rows.end as usize * w;
        let pick = |v: &Option<Vec<[f32; 3]>>| v.as_ref().map(|v| v[span.clone()].to_vec());
        into.color = self.frame.color[span.clone()].to_vec();
        into.albedo = pick(&self.frame.albedo);
        into.normal = pick(&self.frame.normal);
        Ok(())
    }
}
