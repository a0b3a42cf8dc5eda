//! Deterministic maths: the transcendental functions every pixel goes through.
//!
//! `f32::powf`, `sin`, `cos`, `tan`, `exp`, `ln`, ... in `std` call the
//! system C library, and glibc picks its implementation at load time by CPU
//! (`__powf_fma`, `__sincosf_fma`, ... when the CPU has FMA). The results may
//! differ in the last bit between two workers with different instruction
//! sets, and a pixel must be byte-identical on every worker. The
//! functions here are the pure-Rust `libm` crate (a port of musl's libm): the
//! same Rust source on every target, compiled without fused multiply-adds
//! unless the target always has them, so the same bits everywhere.
//!
//! Everything that feeds pixels calls these (glam's own rotations and slerps
//! too: its `libm` feature routes them through the same crate).
//! `clippy.toml` disallows the `std` methods, so a new call fails
//! `cargo clippy -- -D warnings`. `sqrt`, `abs`, `floor`, `ceil`, `round`,
//! `mul_add` and `powi` stay in `std`: IEEE 754 defines the first ones exactly,
//! and `powi` is plain multiplications (LLVM's `powi` intrinsic or
//! compiler-builtins' `__powisf2`, not the system library).
//!
//! Two functions here are not `libm`'s but cheaper arithmetic for the
//! per-hit path, as deterministic (products and sums only):
//! [`pow_shading`] (whole Phong exponents by square and multiply) and
//! [`sin_cos_turns`] (the sine and cosine of a sampled angle 2π·u by
//! polynomial).

/// `x` to the power `y` (f32).
#[inline]
pub fn powf(x: f32, y: f32) -> f32 {
    libm::powf(x, y)
}

/// `x` to the power `y` for a shading exponent (Phong's `shininess`): a
/// whole `y` in `0..=2¹⁶` (the common case: the spec's examples write 32,
/// 40, 300) by [`powi_whole`], others by [`powf`]. The whole-exponent path
/// is multiplications only, about an order of magnitude cheaper than
/// `libm`'s `powf` (`docs/performance.md`), and as deterministic: IEEE 754
/// rounds every product exactly one way on every target.
#[inline]
pub fn pow_shading(x: f32, y: f32) -> f32 {
    // Whole: the conversion to u32 and back is exact (no `floor`: on
    // x86-64 without SSE4.1 it is a call into the C library).
    if (0.0..=65536.0).contains(&y) && (y as u32) as f32 == y {
        powi_whole(x, y as u32)
    } else {
        powf(x, y)
    }
}

/// `x` to the whole power `n` (f32): square and multiply in f64, then one
/// rounding to f32. Each squaring doubles the relative error so far and adds
/// half an f64 ulp, so the f64 result is within about n·2⁻⁵² of `xⁿ`
/// (2⁻³⁶ at n = 2¹⁶, far below an f32 ulp, 2⁻²⁴), and the f32 result is
/// the correctly rounded one except when `xⁿ` lies that close to a midpoint
/// of two f32s (then one ulp off). `0⁰ = 1`, as `powf` has it.
#[inline]
pub fn powi_whole(x: f32, n: u32) -> f32 {
    let (mut base, mut n, mut r) = (f64::from(x), n, 1.0f64);
    while n != 0 {
        if n & 1 != 0 {
            r *= base;
        }
        base *= base;
        n >>= 1;
    }
    r as f32
}

/// `(sin 2πt, cos 2πt)` for `t` in turns (f32), without `libm`: `t`'s
/// fraction is split exactly into eighths of a turn, and each octant is an
/// angle `a ∈ [0, π/4]` from one of its edges, where the Taylor
/// polynomials of degree 11 (sine) and 10 (cosine) are within 2·10⁻¹⁰ of
/// the functions, below a quarter of an f32 ulp of 1; the symmetries of the
/// octants give the rest (swaps and signs, no rounding). Plain products and
/// sums, no fused multiply-add: the same bits on every target. Within
/// 1.5·10⁻⁷ of `sin`/`cos` (f64) everywhere (`math::tests`). What the
/// cosine-hemisphere and sphere samplers call: their angle is `2π·u`.
#[inline]
pub fn sin_cos_turns(t: f32) -> (f32, f32) {
    // Exact: a product by 8, its floor k (by truncation and a correction:
    // `floor` is a C library call on x86-64 without SSE4.1), and the
    // fraction f = q − k, for |t| < 2²¹; k mod 8 is the octant.
    let q = t * 8.0;
    let k = q as i64;
    let k = if k as f32 > q { k - 1 } else { k };
    let f = q - k as f32;
    let k = (k as u32) & 7;
    // Odd octants are measured back from their far edge. The choices below
    // are bit masks, not branches: the octant of a random angle is random,
    // and a branch on it was mispredicted every other call.
    let odd = 0u32.wrapping_sub(k & 1);
    let a = f32::from_bits((f.to_bits() & !odd) | ((1.0 - f).to_bits() & odd))
        * std::f32::consts::FRAC_PI_4;
    let a2 = a * a;
    let s = a + a
        * a2
        * (-1.0 / 6.0
            + a2 * (1.0 / 120.0
                + a2 * (-1.0 / 5040.0 + a2 * (1.0 / 362_880.0 - a2 * (1.0 / 39_916_800.0)))));
    let c = 1.0
        + a2 * (-0.5
            + a2 * (1.0 / 24.0
                + a2 * (-1.0 / 720.0 + a2 * (1.0 / 40_320.0 - a2 * (1.0 / 3_628_800.0)))));
    // Octant k: the angle is kπ/4 + a (k even) or (k+1)π/4 − a (k odd):
    // sine and cosine swap in octants 1, 2, 5, 6; the sine is negative in
    // the lower half turn, the cosine in octants 2 to 5.
    let swap = 0u32.wrapping_sub(((k + 1) >> 1) & 1);
    let (sb, cb) = (s.to_bits(), c.to_bits());
    let (sb, cb) = ((sb & !swap) | (cb & swap), (cb & !swap) | (sb & swap));
    let s_neg = (k >> 2) & 1; // k in 4..8
    let c_neg = ((k + 2) >> 2) & 1; // k in 2..6
    (
        f32::from_bits(sb ^ (s_neg << 31)),
        f32::from_bits(cb ^ (c_neg << 31)),
    )
}

/// Sine of `x` radians (f32).
#[inline]
pub fn sinf(x: f32) -> f32 {
    libm::sinf(x)
}

/// Cosine of `x` radians (f32).
#[inline]
pub fn cosf(x: f32) -> f32 {
    libm::cosf(x)
}

/// Sine and cosine of `x` radians (f32), bit-identical to [`sinf`] and [`cosf`].
#[inline]
pub fn sin_cosf(x: f32) -> (f32, f32) {
    libm::sincosf(x)
}

/// Tangent of `x` radians (f32).
#[inline]
pub fn tanf(x: f32) -> f32 {
    libm::tanf(x)
}

/// Arc sine of `x` in radians (f32).
#[inline]
pub fn asinf(x: f32) -> f32 {
    libm::asinf(x)
}

/// `x` to the power `y` (f64).
#[inline]
pub fn pow(x: f64, y: f64) -> f64 {
    libm::pow(x, y)
}

/// Sine of `x` radians (f64).
#[inline]
pub fn sin(x: f64) -> f64 {
    libm::sin(x)
}

/// Cosine of `x` radians (f64).
#[inline]
pub fn cos(x: f64) -> f64 {
    libm::cos(x)
}

/// Tangent of `x` radians (f64).
#[inline]
pub fn tan(x: f64) -> f64 {
    libm::tan(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The f32 functions against the f64 ones (an independent, 29 bits more
    /// precise computation) over a few hundred arguments: within 1 ulp.
    #[test]
    fn f32_functions_are_within_one_ulp_of_f64() {
        let ulp = |a: f32, b: f64| {
            let r = b as f32;
            (a.to_bits() as i64 - r.to_bits() as i64).abs()
        };
        for i in 0..400 {
            let x = -6.0 + i as f32 * 0.03125; // exact in f32 and f64
            let xd = f64::from(x);
            assert!(ulp(sinf(x), sin(xd)) <= 1, "sin {x}");
            assert!(ulp(cosf(x), cos(xd)) <= 1, "cos {x}");
            let (s, c) = sin_cosf(x);
            assert_eq!(
                (s.to_bits(), c.to_bits()),
                (sinf(x).to_bits(), cosf(x).to_bits())
            );
            if cos(xd).abs() > 1e-3 {
                assert!(ulp(tanf(x), tan(xd)) <= 1, "tan {x}");
            }
            let b = i as f32 / 400.0 + 0.001; // a base in (0, 1], as in shading
            let e = 1.0 + (i % 37) as f32 * 3.5; // an exponent up to 127
            let want = libm::pow(f64::from(b), f64::from(e));
            if want > 1e-30 {
                assert!(ulp(powf(b, e), want) <= 1, "pow {b} {e}");
            }
        }
    }

    /// The whole-power path against f64 `pow` (a different algorithm, 29
    /// bits more precise) rounded to f32: within 1 ulp, for the exponents
    /// of shading (up to 2¹⁶) and bases over (0, 1] and beyond; a
    /// fractional exponent is `powf`'s own bits.
    #[test]
    fn whole_powers_are_within_one_ulp_of_f64_pow() {
        for n in (0..=64u32).chain([100, 127, 255, 300, 1000, 4097, 65536]) {
            for i in 1..=500 {
                let b = i as f32 / 400.0; // up to 1.25
                let want = pow(f64::from(b), f64::from(n));
                if !(1e-37..=1e37).contains(&want) {
                    continue; // outside normal f32 range: both underflow or overflow
                }
                let got = pow_shading(b, n as f32);
                let r = want as f32;
                let ulps = (got.to_bits() as i64 - r.to_bits() as i64).abs();
                assert!(ulps <= 1, "{b}^{n}: {got} vs {want}");
            }
        }
        assert_eq!(pow_shading(0.0, 0.0), 1.0);
        assert_eq!(pow_shading(0.0, 40.0), 0.0);
        assert_eq!(pow_shading(0.5, 10.0), 1.0 / 1024.0);
        assert_eq!(pow_shading(1.0, 300.0), 1.0);
        assert_eq!(pow_shading(0.9, 1e-30), 1.0);
        for y in [0.5f32, 2.5, 39.9, 1e5, 65537.0] {
            assert_eq!(pow_shading(0.7, y).to_bits(), powf(0.7, y).to_bits(), "{y}");
        }
        assert!(pow_shading(f32::NAN, 3.0).is_nan());
    }

    /// `sin_cos_turns(t)` against f64 `sin`/`cos` of 2πt over many turns,
    /// both signs, and the octant edges.
    #[test]
    fn sine_and_cosine_of_turns_are_within_1_5e_7_of_f64() {
        let tau = std::f64::consts::TAU;
        let mut worst = 0.0f64;
        for i in -20_000..=20_000 {
            let t = i as f32 / 16_384.0 + 0.000_037 * (i % 7) as f32;
            let (s, c) = sin_cos_turns(t);
            let a = tau * f64::from(t);
            let e = (f64::from(s) - sin(a))
                .abs()
                .max((f64::from(c) - cos(a)).abs());
            worst = worst.max(e);
        }
        assert!(worst < 1.5e-7, "{worst}");
        // Octant edges are exact.
        for k in 0..8 {
            let (s, c) = sin_cos_turns(k as f32 / 8.0);
            let h = std::f32::consts::FRAC_1_SQRT_2;
            let want = [
                (0.0, 1.0),
                (h, h),
                (1.0, 0.0),
                (h, -h),
                (0.0, -1.0),
                (-h, -h),
                (-1.0, 0.0),
                (-h, h),
            ][k];
            assert!(
                (s - want.0).abs() <= 6e-8 && (c - want.1).abs() <= 6e-8,
                "{k}"
            );
        }
        assert_eq!(sin_cos_turns(0.0), (0.0, 1.0));
        assert_eq!(sin_cos_turns(0.25).0, 1.0);
        assert_eq!(sin_cos_turns(0.5).1, -1.0);
    }

    /// Values the functions must give exactly.
    #[test]
    fn exact_values() {
        for k in -20..20 {
            assert_eq!(powf(2.0, k as f32), 2f32.powi(k), "2^{k}");
        }
        assert_eq!(powf(0.25, 0.5), 0.5);
        assert_eq!(powf(0.7, 1.0), 0.7);
        assert_eq!(powf(0.7, 0.0), 1.0);
        assert_eq!(powf(0.0, 2.4), 0.0);
        assert_eq!(powf(1.0, 1.0 / 2.4), 1.0);
        assert_eq!((sinf(0.0), cosf(0.0), tanf(0.0)), (0.0, 1.0, 0.0));
        assert_eq!((sin(0.0), cos(0.0), tan(0.0)), (0.0, 1.0, 0.0));
        assert_eq!(asinf(1.0), std::f32::consts::FRAC_PI_2);
        assert_eq!(cos(std::f64::consts::PI), -1.0);
        assert_eq!(pow(0.25, 0.5), 0.5);
        assert_eq!(pow(2.0, -3.0), 0.125);
    }

    /// The bits of a few thousand results, folded into one FNV-1a hash. The
    /// `libm` crate is the same source on every target, so this value is the
    /// same on every machine and instruction set; a change means pixels
    /// change (a new `libm` release, or a function routed elsewhere).
    #[test]
    fn results_are_the_pinned_bits() {
        let mut h = 0xcbf2_9ce4_8422_2325u64;
        let mut eat = |bits: u64| {
            for b in bits.to_le_bytes() {
                h = (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3);
            }
        };
        for i in 0..1000 {
            let x = (i as f32 - 500.0) * 0.0137;
            let xd = f64::from(x) * 1.0001;
            eat(u64::from(sinf(x).to_bits()));
            eat(u64::from(cosf(x).to_bits()));
            eat(u64::from(tanf(x).to_bits()));
            eat(u64::from(asinf(x / 7.0).to_bits()));
            eat(u64::from(powf(i as f32 / 1000.0, x.abs() * 10.0).to_bits()));
            eat(sin(xd).to_bits());
            eat(cos(xd).to_bits());
            eat(tan(xd).to_bits());
            eat(pow(f64::from(i) / 1000.0, 1.0 / 2.4).to_bits());
        }
        assert_eq!(h, 0xdd17_bc03_033a_ca98, "{h:#018x}");
    }
}
