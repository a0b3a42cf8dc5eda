//! Linear light to 8-bit sRGB, as PNG output stores it.

/// Converts one linear channel value to an 8-bit sRGB code value.
///
/// The value is clamped to [0, 1] (NaN becomes 0, +inf 1, -inf 0), encoded with
/// the sRGB transfer function (12.92·c for c ≤ 0.0031308, otherwise
/// 1.055·c^(1/2.4) − 0.055) and rounded to nearest as ⌊s·255 + 0.5⌋.
///
/// The arithmetic is done in `f64` so that the rounding matches the closed form
/// for every `f32` input, not just approximately.
pub fn linear_to_srgb8(v: f32) -> u8 {
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
    fn every_code_is_reachable() {
        let mut seen = [false; 256];
        for i in 0..=1_000_000u32 {
            seen[linear_to_srgb8(i as f32 / 1_000_000.0) as usize] = true;
        }
        assert!(seen.iter().all(|&s| s));
    }
}
