//! [`Noise`]: how far a frame's pixels may still be from their converged
//! values, from the per-pixel variances of the samples so far.
//!
//! For a pixel with n ≥ 2 samples of sum S₁ and sum of squares S₂ (each
//! channel), the mean is μ = S₁/n, the sample variance
//! s² = (S₂ − S₁²/n)/(n − 1), and the variance of the mean s²/n. The
//! frame's relative error is the root of the summed variances of the means
//! over the root of the summed squared means (over every pixel and
//! channel):
//!
//! ```text
//! E = √(Σ s²/n) / √(Σ μ²)
//! ```
//!
//! the RMS error over the RMS value, so dark pixels do not blow it up. Both
//! sums add over tiles and bands, so a coordinator folds a frame's estimate
//! band by band. Stratified samples (the jittered grid, Sobol) vary less
//! than independent ones, so the estimate errs on the noisy side. A pixel
//! with fewer than two samples has no variance: while any is left the
//! error is unknown (+∞).

use crate::integrator::PixelState;

/// The additive parts of a frame's relative error (see the module).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Noise {
    /// Σ s²/n over pixels and channels.
    pub error_sq: f64,
    /// Σ μ² over pixels and channels.
    pub signal_sq: f64,
    /// Pixels with fewer than two samples.
    pub unknown: u64,
}

impl Noise {
    /// The parts of `pixels`.
    pub fn of_pixels(pixels: &[PixelState]) -> Noise {
        let mut noise = Noise::default();
        for p in pixels {
            let n = p.count();
            if n < 2 {
                noise.unknown += 1;
                continue;
            }
            let nf = f64::from(n);
            let (s1, s2) = (p.sum(), p.sum_sq());
            let var = ((s2 - s1 * s1 / nf) / (nf - 1.0)).max(glam::DVec3::ZERO);
            let mean = s1 / nf;
            noise.error_sq += (var / nf).element_sum();
            noise.signal_sq += (mean * mean).element_sum();
        }
        noise
    }

    /// The relative error E: +∞ while any pixel has fewer than two samples
    /// or the estimate is not finite, 0 for a black frame without noise.
    pub fn relative_error(&self) -> f64 {
        if self.unknown > 0 {
            return f64::INFINITY;
        }
        if self.error_sq == 0.0 {
            return 0.0;
        }
        let e = (self.error_sq / self.signal_sq).sqrt();
        if e.is_finite() {
            e
        } else {
            f64::INFINITY
        }
    }
}

impl std::ops::AddAssign for Noise {
    fn add_assign(&mut self, o: Noise) {
        self.error_sq += o.error_sq;
        self.signal_sq += o.signal_sq;
        self.unknown += o.unknown;
    }
}

impl std::ops::Add for Noise {
    type Output = Noise;
    fn add(mut self, o: Noise) -> Noise {
        self += o;
        self
    }
}
