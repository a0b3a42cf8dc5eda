//! Deterministic maths: the transcendental functions every pixel goes through.
//!
//! `f32::powf`, `sin`, `cos`, `tan`, `exp`, `ln`, ... in `std` call the
//! system C library, and glibc picks its implementation at load time by CPU
//! (`__powf_fma`, `__sincosf_fma`, ... when the CPU has FMA). The results may
//! differ in the last bit between two workers with different instruction
//! sets, and a pixel must be byte-identical on every worker (issue 17). The
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

/// `x` to the power `y` (f32).
#[inline]
pub fn powf(x: f32, y: f32) -> f32 {
    libm::powf(x, y)
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
