//! Point and spot lights: the spec's E, spot falloff and soft-shadow jitter.

use crate::scene::{Light, LightKind};
use glam::Vec3;

/// What a light delivers to a point `p` from (possibly jittered) position
/// `from`: E = color·intensity / (c + l·d + q·d²), times the spot falloff;
/// `l` is the unit direction from `p` to the light; `dist` its distance.
#[derive(Debug, Clone, Copy)]
pub struct Incident {
    /// The irradiance E reaching `p`, linear RGB, before any shadowing.
    pub e: Vec3,
    /// The unit direction from `p` towards the light's position.
    pub l: Vec3,
    /// The distance from `p` to the light's position, in scene units.
    pub dist: f32,
}

/// `None` when `p` sits on the light itself or nothing arrives.
#[inline]
pub fn incident(light: &Light, from: Vec3, p: Vec3) -> Option<Incident> {
    let to_light = from - p;
    let dist = to_light.length();
    if !(dist > 0.0) || !dist.is_finite() {
        return None;
    }
    // One division for the three components (a product by the reciprocal).
    let l = to_light * (1.0 / dist);
    let [c, lin, q] = light.attenuation.to_array();
    let denom = c + lin * dist + q * dist * dist;
    if !(denom > 0.0) {
        return None;
    }
    // Saturated: intensity / denom may overflow (both are valid f32s), and
    // an infinite scalar times a zero color component would be NaN.
    let s = (light.intensity / denom).min(f32::MAX);
    let mut e = (light.color * s).min(Vec3::splat(f32::MAX));
    if let LightKind::Spot {
        direction,
        cos_inner,
        cos_outer,
    } = light.kind
    {
        // θ: between the spot's direction and the light-to-point vector.
        let cos_theta = direction.dot(-l);
        e *= smoothstep(cos_outer, cos_inner, cos_theta);
    }
    if e == Vec3::ZERO {
        return None;
    }
    Some(Incident { e, l, dist })
}

/// The power Φ of a point or spot light (per channel), as the renderer's
/// transport reads it: a surface at distance d facing the light receives
/// irradiance π·E (so a Lambertian one reflects kd·E, the Whitted term), so
/// the light's radiant intensity is π·color·intensity/q and
///
/// - a point light sends Φ = 4π · π·color·intensity/q,
/// - a spot light Φ = 2π·(1 − (cos inner + cos outer)/2) · π·color·intensity/q
///   (the smoothstep between the cones integrates, over cos θ, to half its
///   width).
///
/// Finite only when E falls as 1/d², `attenuation="0 0 q"`; with a constant
/// or linear term the light sends more the farther one looks and `None` is
/// returned. Area lights: [`crate::lights::area::AreaLights::power`].
pub fn power(light: &Light) -> Option<Vec3> {
    let [c, lin, q] = light.attenuation.to_array();
    if c != 0.0 || lin != 0.0 || !(q > 0.0) {
        return None;
    }
    let pi = std::f64::consts::PI;
    let solid = match light.kind {
        LightKind::Point => 4.0 * pi,
        LightKind::Spot {
            cos_inner,
            cos_outer,
            ..
        } => {
            // A hard step (inner = outer) is the same formula.
            let (ci, co) = (f64::from(cos_inner), f64::from(cos_outer));
            2.0 * pi * (1.0 - 0.5 * (ci + co))
        }
    };
    let i = pi * f64::from(light.intensity) / f64::from(q);
    Some((light.color.as_dvec3() * (solid * i)).as_vec3())
}

/// GLSL smoothstep; a hard step at `e1` when the edges coincide.
#[inline]
pub fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    if e1 <= e0 {
        return if x >= e1 { 1.0 } else { 0.0 };
    }
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// The light position jittered over the square of side 2·radius
/// perpendicular to the light-to-point direction (the report's soft
/// shadows): w = normalize(light − p), u = normalize(up × w) with up = y
/// (x when w is parallel to y), v = w × u. `center` is the light's position
/// in the coordinates of `p` (the renderer works relative to the camera, so
/// it is not `light.position`, which is in world space).
///
/// With d = light − p (not normalised), y × d = (d_z, 0, −d_x) and
/// d × (y × d) = (−d_x·d_y, d_x² + d_z², −d_y·d_z), of lengths h and |d|·h
/// (h² = d_x² + d_z²): u and v are those two vectors times 1/h and
/// 1/h · 1/|d|, two square roots and two divisions that do not wait for one
/// another, where normalising w, then u, chained them.
#[inline]
pub fn jittered_position(light: &Light, center: Vec3, p: Vec3, u: [f32; 2]) -> Vec3 {
    if light.radius <= 0.0 {
        return center;
    }
    let d = center - p;
    let l2 = d.length_squared();
    let h2 = d.x * d.x + d.z * d.z;
    // |y × w|² = h²/|d|²: w nearly parallel to y takes x as the up vector.
    // Lengths whose squares leave f32's normal range (overflow, underflow)
    // take the normalising path as well.
    let (uu, vv) = if l2.is_finite() && l2 > 1e-30 && h2 >= 1e-12 * l2 && h2 > 1e-30 {
        let inv_h = 1.0 / h2.sqrt();
        let inv_l = 1.0 / l2.sqrt();
        (
            Vec3::new(d.z, 0.0, -d.x) * inv_h,
            Vec3::new(-d.x * d.y, h2, -d.y * d.z) * (inv_h * inv_l),
        )
    } else {
        let w = d.normalize_or_zero();
        if w == Vec3::ZERO {
            return center;
        }
        let mut uu = Vec3::Y.cross(w);
        if uu.length_squared() < 1e-12 {
            uu = Vec3::X.cross(w);
        }
        let uu = uu.normalize();
        (uu, w.cross(uu))
    };
    let r = light.radius;
    center + uu * ((2.0 * u[0] - 1.0) * r) + vv * ((2.0 * u[1] - 1.0) * r)
}

// Test scenes and independent quadratures: std's maths feeds no compared pixel.
#[cfg(test)]
#[allow(clippy::disallowed_methods)]
mod tests {
    use super::*;

    fn point(att: Vec3) -> Light {
        Light {
            kind: LightKind::Point,
            position: glam::DVec3::new(0.0, 4.0, 0.0),
            color: Vec3::new(1.0, 0.5, 0.25),
            intensity: 2.0,
            radius: 0.0,
            attenuation: att,
        }
    }

    /// Φ = ∮ π·E dA over a sphere round the light, by the midpoint rule in
    /// (cos θ, φ) about the spot's axis: the closed form of [`power`] for a
    /// point light and for spots (smooth and hard-edged), at two radii (the
    /// power does not depend on where it is measured when E ∝ 1/d²).
    #[test]
    fn a_lights_power_is_the_integral_of_its_irradiance_over_a_sphere() {
        let mut spot = point(Vec3::new(0.0, 0.0, 2.0));
        spot.kind = LightKind::Spot {
            direction: Vec3::new(0.3, -1.0, 0.2).normalize(),
            cos_inner: 20f32.to_radians().cos(),
            cos_outer: 45f32.to_radians().cos(),
        };
        let mut hard = spot.clone();
        hard.kind = LightKind::Spot {
            direction: Vec3::X,
            cos_inner: 30f32.to_radians().cos(),
            cos_outer: 30f32.to_radians().cos(),
        };
        for light in [point(Vec3::new(0.0, 0.0, 2.0)), spot, hard] {
            let axis = match light.kind {
                LightKind::Spot { direction, .. } => direction,
                LightKind::Point => Vec3::Y,
            };
            let (t, b) = crate::sampling::basis(axis);
            let pos = light.position.as_vec3();
            let expect = power(&light).unwrap().as_dvec3();
            for r in [0.5f32, 3.0] {
                let (nz, nphi) = (20000, 8);
                let mut sum = glam::DVec3::ZERO;
                for i in 0..nz {
                    let z = 1.0 - 2.0 * (i as f64 + 0.5) / nz as f64;
                    let s = (1.0 - z * z).sqrt();
                    for j in 0..nphi {
                        let phi = std::f64::consts::TAU * (j as f64 + 0.5) / nphi as f64;
                        let d = t * (s * phi.cos()) as f32
                            + b * (s * phi.sin()) as f32
                            + axis * z as f32;
                        let e = incident(&light, pos, pos + d * r).map_or(Vec3::ZERO, |i| i.e);
                        sum += e.as_dvec3();
                    }
                }
                // dA = r²·dz·dφ, each cell 4π r²/(nz·nphi).
                let area = 4.0 * std::f64::consts::PI * f64::from(r * r);
                let got = sum * std::f64::consts::PI * area / f64::from(nz * nphi);
                let err = ((got - expect) / expect).abs().max_element();
                assert!(err < 2e-3, "{:?} at r = {r}: {got} vs {expect}", light.kind);
            }
        }
        // A constant term: no finite power.
        assert!(power(&point(Vec3::new(1.0, 0.0, 1.0))).is_none());
    }

    #[test]
    fn attenuation_follows_the_spec_formula() {
        let l = point(Vec3::new(1.0, 0.5, 0.25));
        let pos = l.position.as_vec3();
        let inc = incident(&l, pos, Vec3::ZERO).unwrap();
        let expect = 2.0 / (1.0 + 0.5 * 4.0 + 0.25 * 16.0);
        assert!((inc.e - Vec3::new(1.0, 0.5, 0.25) * expect).length() < 1e-6);
        assert!((inc.l - Vec3::Y).length() < 1e-6);
        assert_eq!(inc.dist, 4.0);
        assert!(incident(&l, pos, pos).is_none());
    }

    // An independent closed form: std is fine here (clippy.toml).
    #[allow(clippy::disallowed_methods)]
    #[test]
    fn spot_falloff_is_smoothstep_between_outer_and_inner() {
        let mut l = point(Vec3::new(1.0, 0.0, 0.0));
        l.kind = LightKind::Spot {
            direction: -Vec3::Y,
            cos_inner: 20f32.to_radians().cos(),
            cos_outer: 30f32.to_radians().cos(),
        };
        let at = |deg: f32| {
            let a = deg.to_radians();
            let pos = l.position.as_vec3();
            let p = pos + Vec3::new(a.sin(), -a.cos(), 0.0) * 4.0;
            incident(&l, pos, p).map_or(0.0, |i| i.e.x / 2.0)
        };
        assert!((at(0.0) - 1.0).abs() < 1e-6);
        assert!((at(19.9) - 1.0).abs() < 1e-6);
        assert_eq!(at(30.1), 0.0);
        let c = 25f32.to_radians().cos();
        let (c0, c1) = (30f32.to_radians().cos(), 20f32.to_radians().cos());
        let t = (c - c0) / (c1 - c0);
        assert!((at(25.0) - t * t * (3.0 - 2.0 * t)).abs() < 1e-5);
    }

    /// The jitter square's axes as first written (normalise w, then y × w,
    /// then w × u), against the unnormalised form `jittered_position` uses:
    /// the same points to within rounding, in every direction, including
    /// near ±y (where x is the up vector) and at tiny and huge distances.
    #[test]
    fn the_jitter_axes_are_the_normalised_cross_products() {
        let reference = |center: Vec3, p: Vec3, u: [f32; 2], r: f32| {
            let w = (center - p).normalize_or_zero();
            if w == Vec3::ZERO {
                return center;
            }
            let mut uu = Vec3::Y.cross(w);
            if uu.length_squared() < 1e-12 {
                uu = Vec3::X.cross(w);
            }
            let uu = uu.normalize();
            let vv = w.cross(uu);
            center + uu * ((2.0 * u[0] - 1.0) * r) + vv * ((2.0 * u[1] - 1.0) * r)
        };
        let mut l = point(Vec3::new(1.0, 0.0, 0.0));
        let mut x = 0x1234_5678_9abc_def0u64;
        let mut next = || {
            x = crate::sampling::mix64(x);
            (x >> 40) as f32 / (1u64 << 24) as f32
        };
        for i in 0..2000 {
            let scale = [1e-12f32, 1e-3, 1.0, 1e4, 1e15][i % 5];
            let mut d = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5);
            if i % 7 == 0 {
                d = Vec3::new(d.x * 1e-7, 1.0, d.z * 1e-7); // about the y axis
            }
            // At the origin half the time: the offsets are then compared
            // relative to the radius, not to the ulp of the centre.
            let center = if i % 2 == 0 {
                Vec3::ZERO
            } else {
                Vec3::new(0.3, 2.0, -1.0)
            };
            let p = center - d * scale;
            l.radius = 0.1 * scale;
            let u = [next(), next()];
            let (a, b) = (
                jittered_position(&l, center, p, u),
                reference(center, p, u, l.radius),
            );
            let tol = 1e-5 * l.radius + 1e-6 * center.length();
            assert!((a - b).length() <= tol, "{d} × {scale}: {a} vs {b}");
        }
        // On the light itself: the light's centre.
        l.radius = 0.5;
        let c = Vec3::new(1.0, 2.0, 3.0);
        assert_eq!(jittered_position(&l, c, c, [0.9, 0.1]), c);
    }

    #[test]
    fn jitter_stays_on_the_square_perpendicular_to_the_light_direction() {
        let mut l = point(Vec3::new(1.0, 0.0, 0.0));
        l.radius = 0.5;
        let pos = l.position.as_vec3();
        for p in [Vec3::new(3.0, 0.0, 1.0), Vec3::ZERO] {
            let w = (pos - p).normalize();
            for u in [[0.0, 0.0], [1.0, 1.0], [0.3, 0.8]] {
                let q = jittered_position(&l, pos, p, u) - pos;
                assert!(q.dot(w).abs() < 1e-5);
                assert!(q.x.abs().max(q.y.abs()).max(q.z.abs()) <= 0.5 * 2f32.sqrt() + 1e-5);
            }
            let corner = jittered_position(&l, pos, p, [1.0, 1.0]) - pos;
            assert!((corner.length() - 0.5 * 2f32.sqrt()).abs() < 1e-5);
        }
    }
}
