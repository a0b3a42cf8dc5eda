//! Optics of a smooth surface: the mirror direction and Snell refraction,
//! shared by the Whitted and the path integrators.

use glam::Vec3;

/// Mirror direction of `d` about unit `n`.
#[inline]
pub fn reflect(d: Vec3, n: Vec3) -> Vec3 {
    d - 2.0 * d.dot(n) * n
}

/// Snell refraction of the ray with view vector `v` (pointing back along the
/// ray) through unit normal `n` facing `v`, with η = n1/n2; the mirror
/// direction under total internal reflection.
#[inline]
pub fn refract(v: Vec3, n: Vec3, eta: f32) -> Vec3 {
    if eta == 1.0 {
        return -v;
    }
    let cos_i = n.dot(v).clamp(0.0, 1.0);
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i);
    if sin2_t > 1.0 {
        return reflect(-v, n);
    }
    (-eta * v + (eta * cos_i - (1.0 - sin2_t).sqrt()) * n).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;

    // An independent closed form: std is fine here (clippy.toml).
    #[allow(clippy::disallowed_methods)]
    #[test]
    fn refraction_obeys_snell_and_total_internal_reflection_starts_at_the_critical_angle() {
        let n = Vec3::Y;
        for deg in [0.0f32, 10.0, 30.0, 60.0, 85.0] {
            let a = deg.to_radians();
            let v = Vec3::new(-a.sin(), a.cos(), 0.0); // pointing back up the ray
            let t = refract(v, n, 1.0 / 1.5);
            let sin_t = t.x.abs();
            assert!((sin_t - a.sin() / 1.5).abs() < 1e-5, "{deg}");
            assert!(t.y < 0.0);
        }
        // Inside glass (η = 1.5): critical angle asin(1/1.5).
        let crit = (1.0f32 / 1.5).asin();
        for (a, tir) in [(crit - 1e-3, false), (crit + 1e-3, true)] {
            let v = Vec3::new(-a.sin(), a.cos(), 0.0);
            let t = refract(v, n, 1.5);
            assert_eq!(t.y > 0.0, tir, "angle {a}");
        }
        let v = Vec3::new(0.3, 0.9, 0.1).normalize();
        assert_eq!(refract(v, n, 1.0), -v);
    }
}
