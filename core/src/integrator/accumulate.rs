//! A pixel's samples so far: [`PixelState`], what a render over a range of
//! sample indices leaves and the next range continues from, and
//! [`Running`], the same state while samples are being added.
//!
//! The state holds the running sums exactly as the pixel estimate keeps
//! them (integrator/pixel.rs), so continuing from it is the same arithmetic
//! as never having stopped:
//!
//! - supersampling (the n×n grid): a [`Sum`] — the `f32` sum of the open
//!   block of [`SUM_BLOCK`](super::SUM_BLOCK) samples and the `f64` total of the closed
//!   blocks; how many samples the open block holds is `count mod
//!   SUM_BLOCK`, so it is not stored;
//! - adaptive sampling: the `f64` sum of every sample (the open block stays
//!   zero), as the stopping rule has always summed.
//!
//! Both also keep the `f64` sum of the squared samples (the stopping rule's
//! variance, and the noise estimate of `passes`) and the count.

use super::saturate;
use super::sum::Sum;
use crate::scene::Adaptive;
use glam::{DVec3, Vec3};

/// A pixel's accumulated samples (see the module documentation). The
/// default is a pixel with no samples.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PixelState {
    /// The open block's `f32` sum (supersampling); zero in adaptive mode.
    pub(crate) block: [f32; 3],
    /// The closed blocks' `f64` total (supersampling), or the sum of every
    /// sample (adaptive).
    pub(crate) total: [f64; 3],
    /// The `f64` sum of the squared samples.
    pub(crate) sum_sq: [f64; 3],
    /// Samples taken.
    pub(crate) count: u32,
}

impl PixelState {
    /// Samples taken so far.
    pub fn count(&self) -> u32 {
        self.count
    }

    /// The pixel's linear RGB value: the sum over the count, saturated, with
    /// exactly the arithmetic of the one-shot estimate (`Sum::mean`, which
    /// for adaptive sampling adds a zero block to a total that is never
    /// −0, so it is the plain `f64` quotient). A pixel with no samples is
    /// black.
    pub fn finish(&self) -> [f32; 3] {
        if self.count == 0 {
            return [0.0; 3];
        }
        let sum = Sum::resume(Vec3::from(self.block), DVec3::from(self.total), self.count);
        saturate(sum.mean(u64::from(self.count))).to_array()
    }

    /// The sum of every sample, in `f64`.
    pub(crate) fn sum(&self) -> DVec3 {
        DVec3::from(self.total) + Vec3::from(self.block).as_dvec3()
    }

    /// The sum of the squared samples.
    pub(crate) fn sum_sq(&self) -> DVec3 {
        DVec3::from(self.sum_sq)
    }

    /// This state, to add samples to.
    #[inline]
    pub(super) fn running(&self) -> Running {
        Running {
            sum: Sum::resume(Vec3::from(self.block), DVec3::from(self.total), self.count),
            sum_sq: DVec3::from(self.sum_sq),
            count: self.count,
        }
    }
}

/// A [`PixelState`] while samples are added (the sums in the form the
/// integrator adds to; no allocation, nothing dynamic).
#[derive(Clone, Copy)]
pub(super) struct Running {
    sum: Sum<Vec3>,
    sum_sq: DVec3,
    pub(super) count: u32,
}

impl Running {
    /// Adds a supersampling sample: to the block sum, as the one-shot
    /// estimate always has.
    #[inline(always)]
    pub(super) fn add_grid(&mut self, v: Vec3) {
        self.sum.add(v);
        let w = v.as_dvec3();
        self.sum_sq += w * w;
        self.count += 1;
    }

    /// Adds an adaptive sample: straight to the `f64` total (the open block
    /// stays zero), as the adaptive estimate always has.
    #[inline(always)]
    pub(super) fn add_adaptive(&mut self, v: Vec3) {
        let w = v.as_dvec3();
        self.sum.add_wide(w);
        self.sum_sq += w * w;
        self.count += 1;
    }

    /// Adaptive sampling's stopping rule: at least `max(min-samples, 2)`
    /// samples, and the standard error of the mean, largest over the
    /// channels, at most the threshold. The same expression, on the same
    /// sums, as the one-shot loop evaluated after every sample, so whether
    /// a pixel has stopped is known again from its state alone.
    #[inline]
    pub(super) fn converged(&self, a: &Adaptive) -> bool {
        let n = self.count;
        if n < a.min_samples.max(2) {
            return false;
        }
        let (_, sum) = self.sum.parts();
        let nf = n as f64;
        let var = ((self.sum_sq - sum * sum / nf) / (nf - 1.0)).max(DVec3::ZERO);
        let err = (var / nf).max_element().sqrt();
        err <= a.threshold as f64
    }

    /// The state to store.
    #[inline]
    pub(super) fn state(&self) -> PixelState {
        let (block, total) = self.sum.parts();
        PixelState {
            block: block.to_array(),
            total: total.to_array(),
            sum_sq: self.sum_sq.to_array(),
            count: self.count,
        }
    }
}

#[cfg(test)]
impl PixelState {
    /// The state of `samples` added by supersampling (`adaptive` false) or
    /// adaptive sampling: synthetic pixels for the tests.
    pub(crate) fn of_samples(samples: &[[f32; 3]], adaptive: bool) -> PixelState {
        let mut r = PixelState::default().running();
        for &v in samples {
            if adaptive {
                r.add_adaptive(Vec3::from(v));
            } else {
                r.add_grid(Vec3::from(v));
            }
        }
        r.state()
    }
}
