//! Linear light to 8-bit sRGB, as PNG output stores it.

use std::sync::OnceLock;

/// Converts one linear channel value to an 8-bit sRGB code value.
///
/// The value is clamped to [0, 1] (NaN becomes 0, +inf 1, -inf 0), encoded with
/// the sRGB transfer function (12.92·c for c ≤ 0.0031308, otherwise
/// 1.055·c^(1/2.4) − 0.055) and rounded to nearest as ⌊s·255 + 0.5⌋.
///
/// Why tables: the closed form needs a `powf` per channel, which made PNG
/// stitching the coordinator's bottleneck. The code is a step function of the
/// input, so it is exact to compare the input with the 255 smallest `f32`
/// inputs of each code (computed once from the closed form in
/// `linear_to_srgb8_exact`). Positive `f32`s sort like their bit patterns,
/// so a second table indexed by the top bits of the input gives the code at
/// the start of its bucket of 2^16 neighbouring floats; a bucket never spans
/// more than one step of the curve, so at most one or two comparisons finish
/// the job. The result is bit-identical to the closed form for every `f32`.
#[inline]
pub fn linear_to_srgb8(v: f32) -> u8 {
    Srgb8::new().encode(v)
}

/// [`linear_to_srgb8`] with its tables fetched once, for loops over many
/// pixels (the per-call `OnceLock` checks showed in the coordinator's
/// profile).
#[derive(Debug, Clone, Copy)]
pub struct Srgb8 {
    /// `steps[k]` is the smallest `f32` whose code is `k + 1`; `steps[255]`
    /// is +inf, so the comparison below needs no bounds branch.
    steps: &'static [f32; 256],
    starts: &'static [u8; BUCKETS],
}

impl Default for Srgb8 {
    fn default() -> Self {
        Self::new()
    }
}

impl Srgb8 {
    /// The encoder, its tables built on first use in the process.
    pub fn new() -> Srgb8 {
        Srgb8 {
            steps: thresholds(),
            starts: buckets(),
        }
    }

    /// The code of `v`: the code at the start of its bucket, plus one if
    /// the bucket's single step (if any) lies at or below `v`. Branch-free
    /// apart from the clamping, which is predictable for image data.
    #[inline]
    pub fn encode(self, v: f32) -> u8 {
        if !(v > 0.0) {
            return 0; // NaN, negative, zero
        }
        if v >= 1.0 {
            return 255;
        }
        let code = self.starts[(v.to_bits() >> BUCKET_SHIFT) as usize];
        code + (v >= self.steps[code as usize]) as u8
    }
}

/// Floats per bucket of [`buckets`]: 2^16.
const BUCKET_SHIFT: u32 = 16;
/// Buckets from 0 up to (not including) 1.0's.
const BUCKETS: usize = (0x3F80_0000 >> BUCKET_SHIFT) as usize;

/// `buckets()[b]` is the code of the smallest `f32` whose bits are `b << 16`.
fn buckets() -> &'static [u8; BUCKETS] {
    static TABLE: OnceLock<Box<[u8; BUCKETS]>> = OnceLock::new();
    TABLE.get_or_init(|| {
        let t = thresholds();
        let mut b = Box::new([0u8; BUCKETS]);
        for (i, slot) in b.iter_mut().enumerate() {
            let v = f32::from_bits((i as u32) << BUCKET_SHIFT);
            *slot = t[..255].partition_point(|&x| x <= v) as u8;
        }
        b
    })
}

/// `thresholds()[k - 1]` is the smallest `f32` whose code is `k`
/// (k = 1..=255); the last entry is +inf.
fn thresholds() -> &'static [f32; 256] {
    static TABLE: OnceLock<[f32; 256]> = OnceLock::new();
    TABLE.get_or_init(|| {
        let mut t = [f32::INFINITY; 256];
        for (k, slot) in t.iter_mut().take(255).enumerate() {
            let code = k as u8 + 1;
            // Positive f32 order is bit-pattern order: binary search the bits.
            let (mut lo, mut hi) = (0u32, 1.0f32.to_bits());
            while lo < hi {
                let mid = lo + (hi - lo) / 2;
                if linear_to_srgb8_exact(f32::from_bits(mid)) >= code {
                    hi = mid;
                } else {
                    lo = mid + 1;
                }
            }
            *slot = f32::from_bits(lo);
        }
        t
    })
}

/// The closed form, evaluated in `f64` so that the rounding is right for every
/// `f32` input.
pub fn linear_to_srgb8_exact(v: f32) -> u8 {
    // `f32::clamp` keeps NaN, so handle it first; infinities clamp normally.
    let c = if v.is_nan() {
        0.0
    } else {
        f64::from(v.clamp(0.0, 1.0))
    };
    let s = if c <= 0.0031308 {
        12.92 * c
    } else {
        1.055 * crate::math::pow(c, 1.0 / 2.4) - 0.055
    };
    // s is in [0, 1] up to rounding, so the cast cannot wrap; `as` saturates anyway.
    (s * 255.0 + 0.5).floor() as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    // An independent closed form: std is fine here (clippy.toml).
    #[allow(clippy::disallowed_methods)]
    /// The closed form written out independently of the implementation.
    fn closed_form(c: f64) -> u8 {
        let s = if c <= 0.0031308 {
            12.92 * c
        } else {
            1.055 * c.powf(1.0 / 2.4) - 0.055
        };
        (s * 255.0 + 0.5).floor() as u8
    }

    #[test]
    fn known_values() {
        assert_eq!(linear_to_srgb8(0.0), 0);
        assert_eq!(linear_to_srgb8(-0.0), 0);
        assert_eq!(linear_to_srgb8(1.0), 255);
        // Linear segment end: 12.92 · 0.0031308 = 0.04045 → 10.31 → 10.
        assert_eq!(linear_to_srgb8(0.0031308), 10);
        // 1.055 · 0.5^(1/2.4) − 0.055 = 0.7354 → 187.53 → 188.
        assert_eq!(linear_to_srgb8(0.5), 188);
        // 1.055 · 0.18^(1/2.4) − 0.055 = 0.4614 → 117.65 → 118 (18 % grey).
        assert_eq!(linear_to_srgb8(0.18), 118);
        assert_eq!(linear_to_srgb8(1.5), 255);
        assert_eq!(linear_to_srgb8(1e30), 255);
        assert_eq!(linear_to_srgb8(-0.25), 0);
        assert_eq!(linear_to_srgb8(-1e30), 0);
        assert_eq!(linear_to_srgb8(f32::NAN), 0);
        assert_eq!(linear_to_srgb8(-f32::NAN), 0);
        assert_eq!(linear_to_srgb8(f32::INFINITY), 255);
        assert_eq!(linear_to_srgb8(f32::NEG_INFINITY), 0);
        assert_eq!(linear_to_srgb8(f32::MIN_POSITIVE), 0);
    }

    #[test]
    fn matches_closed_form_and_is_monotonic() {
        let mut prev = 0u8;
        for i in 0..=100_000u32 {
            let v = i as f32 / 100_000.0;
            let got = linear_to_srgb8(v);
            assert_eq!(got, closed_form(f64::from(v)), "v = {v}");
            assert!(got >= prev, "not monotonic at {v}");
            prev = got;
        }
        assert_eq!(prev, 255);
    }

    #[test]
    fn the_table_agrees_with_the_closed_form_at_every_step_and_between() {
        for (k, &t) in thresholds()[..255].iter().enumerate() {
            let code = k as u8 + 1;
            let below = f32::from_bits(t.to_bits() - 1);
            assert_eq!(linear_to_srgb8_exact(t), code);
            assert_eq!(linear_to_srgb8(t), code);
            assert_eq!(linear_to_srgb8(below), linear_to_srgb8_exact(below));
            assert_eq!(linear_to_srgb8(below), code - 1);
        }
        // A dense sweep of bit patterns across [0, 1] (every 997th f32).
        let mut bits = 0u32;
        while bits <= 1.0f32.to_bits() {
            let v = f32::from_bits(bits);
            assert_eq!(linear_to_srgb8(v), linear_to_srgb8_exact(v), "v = {v:e}");
            bits += 997;
        }
    }

    #[test]
    fn every_bucket_start_and_end_agrees_with_the_closed_form() {
        // The two ends of each bucket, where the table lookup starts and
        // where the comparisons must have carried it.
        for b in 0..BUCKETS as u32 {
            for bits in [b << BUCKET_SHIFT, ((b + 1) << BUCKET_SHIFT) - 1] {
                let v = f32::from_bits(bits);
                assert_eq!(linear_to_srgb8(v), linear_to_srgb8_exact(v), "v = {v:e}");
            }
        }
        // No bucket holds two steps: the loop compares at most twice.
        let mut per_bucket = std::collections::HashMap::new();
        for t in &thresholds()[..255] {
            *per_bucket.entry(t.to_bits() >> BUCKET_SHIFT).or_insert(0) += 1;
        }
        assert!(per_bucket.values().all(|&n| n == 1), "{per_bucket:?}");
    }

    #[test]
    fn every_code_is_reachable() {
        let mut seen = [false; 256];
        for i in 0..=1_000_000u32 {
            seen[linear_to_srgb8(i as f32 / 1_000_000.0) as usize] = true;
        }
        assert!(seen.iter().all(|&s| s));
    }
}
