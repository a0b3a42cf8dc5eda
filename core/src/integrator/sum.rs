//! `Sum`: the mean of many `f32` (or `Vec3`) samples, kept right however
//! many there are; every estimate of the integrators averages with it.

use glam::Vec3;

/// How many samples `Sum` adds in `f32` before moving them to its `f64`
/// total.
pub const SUM_BLOCK: u32 = 1024;

/// A sum of many `f32` samples that stays right however many there are.
///
/// Summed in plain `f32`, 8000² camera samples stall (the running sum grows
/// until each new sample is below half its ULP: 140 where 188 is right),
/// 65536² overflow the count into NaN. Here samples are added in `f32`
/// within blocks of [`SUM_BLOCK`] and the blocks in `f64`, so the relative
/// error is at most about `SUM_BLOCK`·2⁻²⁴ ≈ 6·10⁻⁵ whatever the count.
/// Up to `SUM_BLOCK` samples the mean is bit for bit the plain `f32` sum
/// divided in `f32` as before (adding the block to a zero `f64` is exact,
/// and an `f32` quotient computed in `f64` and rounded is the correctly
/// rounded `f32` quotient), so images with ordinary sample counts keep
/// their bytes.
#[derive(Clone, Copy, Default)]
pub(super) struct Sum<T: Wide> {
    block: T,
    in_block: u32,
    total: T::Wide,
}

/// `f32` and `Vec3`, with their `f64` counterparts.
pub(super) trait Wide: Copy + Default + std::ops::AddAssign {
    type Wide: Copy + Default + std::ops::AddAssign;
    fn widen(self) -> Self::Wide;
    /// `(total + self) / n`, rounded back.
    fn mean(self, total: Self::Wide, n: u64) -> Self;
}

impl Wide for f32 {
    type Wide = f64;
    #[inline]
    fn widen(self) -> f64 {
        f64::from(self)
    }
    #[inline]
    fn mean(self, total: f64, n: u64) -> f32 {
        ((total + f64::from(self)) / n as f64) as f32
    }
}

impl Wide for Vec3 {
    type Wide = glam::DVec3;
    #[inline]
    fn widen(self) -> glam::DVec3 {
        self.as_dvec3()
    }
    #[inline]
    fn mean(self, total: glam::DVec3, n: u64) -> Vec3 {
        ((total + self.as_dvec3()) / n as f64).as_vec3()
    }
}

impl<T: Wide> Sum<T> {
    #[inline]
    pub(super) fn add(&mut self, v: T) {
        self.block += v;
        self.in_block += 1;
        if self.in_block == SUM_BLOCK {
            self.total += self.block.widen();
            self.block = T::default();
            self.in_block = 0;
        }
    }

    /// Adds `w` straight to the `f64` total, past the blocks (adaptive
    /// sampling's sum, which has always been plain `f64`).
    #[inline]
    pub(super) fn add_wide(&mut self, w: T::Wide) {
        self.total += w;
    }

    /// The sum that has taken `count` samples (`count mod SUM_BLOCK` of
    /// them in the open block `block`, the rest in `total`): exactly the
    /// `Sum` those `add`s left, so adding goes on where it stopped.
    #[inline]
    pub(super) fn resume(block: T, total: T::Wide, count: u32) -> Self {
        Sum {
            block,
            in_block: count % SUM_BLOCK,
            total,
        }
    }

    /// The open block's sum and the closed blocks' total (see
    /// [`Sum::resume`]).
    #[inline]
    pub(super) fn parts(&self) -> (T, T::Wide) {
        (self.block, self.total)
    }

    /// The sum divided by `n` (the number of samples, counting those that
    /// added nothing).
    #[inline]
    pub(super) fn mean(&self, n: u64) -> T {
        self.block.mean(self.total, n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 8000² samples of one value, summed in plain f32, stall far below the
    /// right mean (the sum stops growing once a sample is below half its
    /// ULP); `Sum` gets it.
    #[test]
    fn sums_of_64_million_samples_keep_their_mean() {
        let n = 8000u64 * 8000;
        let v = Vec3::new(0.737, 0.25, 1.0 / 3.0);
        let mut sum = Sum::<Vec3>::default();
        let mut plain = Vec3::ZERO;
        for _ in 0..n {
            sum.add(v);
            plain += v;
        }
        let mean = sum.mean(n);
        assert!(((mean - v) / v).abs().max_element() < 1e-5, "{mean} vs {v}");
        // The plain f32 mean is far off: the test would catch a plain sum.
        let plain_mean = plain / n as f32;
        assert!(
            ((plain_mean - v) / v).abs().max_element() > 0.1,
            "{plain_mean}"
        );
        let mut sum = Sum::<f32>::default();
        for _ in 0..n {
            sum.add(0.737);
        }
        assert!((sum.mean(n) - 0.737).abs() < 1e-5, "{}", sum.mean(n));
    }

    /// Up to SUM_BLOCK samples a mean is bit for bit the plain f32 sum
    /// divided in f32, so images with ordinary sample counts keep their
    /// bytes.
    #[test]
    fn small_sums_are_bit_identical_to_plain_f32() {
        let mut x = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            x = crate::sampling::mix64(x);
            // Radiance-like values over many magnitudes, some zero.
            let m = (x >> 40) as f32 / (1u64 << 24) as f32;
            m * [0.0, 1e-3, 1.0, 37.0, 1e6][(x & 3) as usize + usize::from(x & 4 != 0)]
        };
        for n in [1u32, 2, 4, 9, 16, 25, 64, 100, 256, 1000, SUM_BLOCK] {
            for _ in 0..50 {
                let mut sum = Sum::<Vec3>::default();
                let mut plain = Vec3::ZERO;
                let mut sum1 = Sum::<f32>::default();
                let mut plain1 = 0.0f32;
                for _ in 0..n {
                    let v = Vec3::new(next(), next(), next());
                    sum.add(v);
                    plain += v;
                    sum1.add(v.x);
                    plain1 += v.x;
                }
                let (a, b) = (sum.mean(u64::from(n)), plain / n as f32);
                assert_eq!(
                    a.to_array().map(f32::to_bits),
                    b.to_array().map(f32::to_bits),
                    "{n}"
                );
                assert_eq!(
                    sum1.mean(u64::from(n)).to_bits(),
                    (plain1 / n as f32).to_bits()
                );
            }
        }
    }
}
