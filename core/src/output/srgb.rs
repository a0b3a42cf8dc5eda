//! Linear light to 8-bit sRGB, as PNG output stores it.

use std::sync::OnceLock;

/// Converts one linear channel value to an 8-bit sRGB code value.
///
/// The value is clamped to [0, 1] (NaN becomes 0, +inf 1, -inf 0), encoded with
/// the sRGB transfer function (12.92·c for c ≤ 0.0031308, otherwise
/// 1.055·c^(1/2.4) − 0.055) and rounded to nearest as ⌊s·255 + 0.5⌋.
///
/// Why a table: the closed form needs a `powf` per channel, which made PNG
/// stitching the coordinator's bottleneck. The code is a step function of the
/// input, so it is found by a binary search among the 255 smallest `f32`
/// inputs of each code (computed once from the closed form in
/// [`linear_to_srgb8_exact`]): the result is bit-identical to the closed form
/// for every `f32`.
#[inline]
pub fn linear_to_srgb8(v: f32) -> u8 {
    if !(v > 0.0) {
        return 0; // NaN, negative, zero
    }
    thresholds().partition_point(|&t| t <= v) as u8
}

/// `thresholds()[k - 1]` is the smallest `f32` whose code is `k`.
fn thresholds() -> &'static [f32; 255] {
    static TABLE: OnceLock<[f32; 255]> = OnceLock::new();
    TABLE.get_or_init(|| {
        let mut t = [0f32; 255];
        for (k, slot) in t.iter_mut().enumerate() {
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
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    // s is in [0, 1] up to rounding, so the cast cannot wrap; `as` saturates anyway.
    (s * 255.0 + 0.5).floor() as u8
}

#[cfg(test)]
mod tests {
    use super::*;

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
        for (k, &t) in thresholds().iter().enumerate() {
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
    fn every_code_is_reachable() {
        let mut seen = [false; 256];
        for i in 0..=1_000_000u32 {
            seen[linear_to_srgb8(i as f32 / 1_000_000.0) as usize] = true;
        }
        assert!(seen.iter().all(|&s| s));
    }
}
