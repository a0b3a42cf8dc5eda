//! Progressive renders: a tile's pixels rendered over a range of sample
//! indices at a time, their sums kept in between ([`TileState`]), finished
//! into the very bytes of a one-shot render whatever the split
//! (docs/progressive.md).
//!
//! | file | what |
//! |---|---|
//! | `passes.rs` | [`TileState`]: a rectangle's accumulated samples, rendered on by ranges |
//! | `passes/encode.rs` | its bytes: a versioned, bounded encoding, decoded with every length checked first |
//! | `passes/noise.rs` | [`Noise`]: the relative error of a frame from its pixels' variances |
//! | `passes/samples.rs` | [`Scene::set_samples`]: a job's own sample count, on the sequence that extends |
//!
//! The per-pixel state and the arithmetic that continues it are the
//! integrator's ([`PixelState`], integrator/accumulate.rs); this module only
//! keeps a rectangle of them and checks the ranges.

mod encode;
mod noise;
mod samples;

pub use encode::{StateError, HEADER_BYTES, MAGIC, MAX_STATE_PIXELS, PIXEL_BYTES, VERSION};
pub use noise::Noise;
pub use samples::MAX_SAMPLES;

use crate::integrator::{samples_per_pixel, Cancelled, PixelState};
use crate::tile::{finish_tile, render_tile_samples, Rect};
use crate::world::Scene;
use std::ops::Range;
use std::sync::atomic::AtomicBool;

/// Why a range of samples was not rendered into a [`TileState`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PassError {
    /// The range does not start where the state stopped, or ends before it
    /// starts.
    #[error(
        "the samples {start}..{end} do not continue the state, which has its samples 0..{next}"
    )]
    NotNext {
        /// The range's first sample index.
        start: u32,
        /// The index after the range's last.
        end: u32,
        /// The state's [`TileState::next`].
        next: u32,
    },
    /// The range goes past the camera's samples per pixel.
    #[error("the samples {start}..{end} go past the camera's {samples} samples per pixel")]
    PastEnd {
        /// The range's first sample index.
        start: u32,
        /// The index after the range's last.
        end: u32,
        /// The camera's samples per pixel: the most a range may reach.
        samples: u32,
    },
    /// The render was cancelled; the state is as it was.
    #[error(transparent)]
    Cancelled(#[from] Cancelled),
}

/// The accumulated samples of every pixel of a rectangle of one camera's
/// frame: every pixel has taken its samples `0..next()` (fewer where
/// adaptive sampling stopped it). `PIXEL_BYTES` a pixel in memory and
/// encoded.
#[derive(Debug, Clone, PartialEq)]
pub struct TileState {
    rect: Rect,
    next: u32,
    pixels: Vec<PixelState>,
}

impl TileState {
    /// The state of `rect` before any sample (allocates
    /// `rect.pixel_count()` states: the caller bounds the rectangle, as it
    /// does for [`crate::render_tile`]'s pixels).
    pub fn new(rect: Rect) -> Self {
        TileState {
            rect,
            next: 0,
            pixels: vec![PixelState::default(); rect.pixel_count()],
        }
    }

    /// The rectangle.
    pub fn rect(&self) -> Rect {
        self.rect
    }

    /// The first sample index not yet rendered: samples `0..next()` are.
    pub fn next(&self) -> u32 {
        self.next
    }

    /// The pixels' states, row by row.
    pub fn pixels(&self) -> &[PixelState] {
        &self.pixels
    }

    /// Renders samples `samples` of every pixel of the rectangle, of camera
    /// `camera` of `scene` (the scene and camera the state was started
    /// with: the state does not record them), on the current rayon pool,
    /// and returns the rays traced. `samples` must start at [`next`] and end
    /// at most at the camera's samples per pixel (`supersample²`, or
    /// `max-samples` with adaptive sampling); an empty range does nothing.
    /// Soon after `cancel` turns true it gives up with the state unchanged.
    ///
    /// [`next`]: TileState::next
    pub fn render(
        &mut self,
        scene: &Scene,
        camera: usize,
        samples: Range<u32>,
        cancel: &AtomicBool,
    ) -> Result<u64, PassError> {
        let Range { start, end } = samples;
        if start != self.next || end < start {
            return Err(PassError::NotNext {
                start,
                end,
                next: self.next,
            });
        }
        let total = samples_per_pixel(&scene.desc.cameras[camera].render);
        if end > total {
            return Err(PassError::PastEnd {
                start,
                end,
                samples: total,
            });
        }
        if start == end {
            return Ok(0);
        }
        // Rendered on a copy: a cancelled render leaves some pixels moved on.
        let mut pixels = self.pixels.clone();
        let rays = render_tile_samples(scene, camera, self.rect, end, &mut pixels, cancel)?;
        self.pixels = pixels;
        self.next = end;
        Ok(rays)
    }

    /// The rectangle's linear RGB pixels, row by row: after samples
    /// `0..supersample²` (or `max-samples`) in any split, exactly
    /// [`crate::render_tile`]'s; before, the mean of the samples so far.
    pub fn finish(&self) -> Vec<[f32; 3]> {
        finish_tile(&self.pixels)
    }

    /// The noise of the rectangle's pixels (add those of a frame's tiles
    /// for the frame's).
    pub fn noise(&self) -> Noise {
        Noise::of_pixels(&self.pixels)
    }
}

#[cfg(test)]
mod tests;
