//! Analytic spheres.

use glam::Vec3;

/// Nearest `t` in `(0, t_max)` where the ray meets the sphere, and whether it
/// meets it from outside (the front). The quadratic is solved in the form of
/// Haines et al., "Precision Improvements for Ray/Sphere Intersection" (Ray
/// Tracing Gems, 2019), which keeps small or distant spheres accurate.
#[inline]
pub fn intersect(
    origin: Vec3,
    dir: Vec3,
    center: Vec3,
    radius: f32,
    t_max: f32,
) -> Option<(f32, bool)> {
    crossings(origin, dir, center, radius, t_max)[0]
}

/// Every `t` in `(0, t_max)` where the ray crosses the sphere, nearest
/// first, each with whether it enters there (meets the front): a ray
/// through a sphere crosses it twice, one starting inside once. (A shadow
/// ray's transmittance counts every crossing; the spec says so.)
#[inline]
pub fn crossings(
    origin: Vec3,
    dir: Vec3,
    center: Vec3,
    radius: f32,
    t_max: f32,
) -> [Option<(f32, bool)>; 2] {
    let f = origin - center;
    let a = dir.dot(dir);
    let b = -f.dot(dir);
    let l = f + dir * (b / a);
    let r2 = radius * radius;
    let disc = r2 - l.dot(l);
    if !(disc >= 0.0) {
        return [None, None];
    }
    let c = f.dot(f) - r2;
    // √a·√disc rather than √(a·disc): a shadow ray's direction spans the
    // whole segment to the light, and a·disc would overflow f32 for
    // scenes 10¹⁰ units across.
    let q = b + b.signum() * (a.sqrt() * disc.sqrt());
    let (mut t0, mut t1) = (c / q, q / a);
    if q == 0.0 {
        t0 = 0.0;
        t1 = 0.0;
    }
    if t0 > t1 {
        std::mem::swap(&mut t0, &mut t1);
    }
    let at = |t: f32| {
        (t > 0.0 && t < t_max).then(|| {
            let n = origin + dir * t - center;
            (t, n.dot(dir) < 0.0)
        })
    };
    match (at(t0), at(t1)) {
        (None, second) => [second, None],
        // A tangent ray (one double root) touches once.
        (Some(first), _) if t1 == t0 => [Some(first), None],
        (first, second) => [first, second],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hits_from_outside_and_inside() {
        let c = Vec3::new(0.0, 0.0, -5.0);
        let (t, front) = intersect(Vec3::ZERO, -Vec3::Z, c, 1.0, f32::INFINITY).unwrap();
        assert!((t - 4.0).abs() < 1e-6 && front);
        let (t, front) = intersect(c, Vec3::X, c, 1.0, f32::INFINITY).unwrap();
        assert!((t - 1.0).abs() < 1e-6 && !front);
        assert!(intersect(Vec3::ZERO, Vec3::Z, c, 1.0, f32::INFINITY).is_none());
        assert!(intersect(Vec3::ZERO, -Vec3::Z, c, 1.0, 3.0).is_none());
        // Tangent ray at distance r: hits (disc = 0) or misses, but no NaN.
        let r = intersect(Vec3::new(1.0, 0.0, 0.0), -Vec3::Z, c, 1.0, f32::INFINITY);
        assert!(r.is_none_or(|(t, _)| t.is_finite()));
    }

    #[test]
    fn a_ray_through_a_sphere_crosses_it_twice_and_from_inside_once() {
        let c = Vec3::new(0.0, 0.0, -5.0);
        let [a, b] = crossings(Vec3::ZERO, -Vec3::Z, c, 1.0, f32::INFINITY);
        let (a, b) = (a.unwrap(), b.unwrap());
        assert!((a.0 - 4.0).abs() < 1e-6 && a.1, "{a:?}");
        assert!((b.0 - 6.0).abs() < 1e-6 && !b.1, "{b:?}");
        assert_eq!(crossings(c, Vec3::X, c, 1.0, f32::INFINITY)[1], None);
        assert!(crossings(c, Vec3::X, c, 1.0, f32::INFINITY)[0].is_some());
        // The segment ends inside: one crossing.
        let [a, b] = crossings(Vec3::ZERO, -Vec3::Z, c, 1.0, 5.0);
        assert!(a.is_some() && b.is_none());
        // Behind the origin: none.
        assert_eq!(
            crossings(Vec3::ZERO, Vec3::Z, c, 1.0, f32::INFINITY),
            [None, None]
        );
    }

    #[test]
    fn huge_spheres_and_long_directions_do_not_overflow() {
        let c = Vec3::new(0.0, 0.0, -5.0e10);
        let o = Vec3::ZERO;
        let d = Vec3::new(0.0, 0.0, -1.0e11);
        let (t, front) = intersect(o, d, c, 1.0e10, f32::INFINITY).unwrap();
        assert!(front && (t - 0.4).abs() < 1e-6, "{t}");
    }

    #[test]
    fn tiny_and_far_spheres_stay_accurate() {
        let c = Vec3::new(0.0, 0.0, -1.0e4);
        let (t, _) = intersect(Vec3::ZERO, -Vec3::Z, c, 0.01, f32::INFINITY).unwrap();
        assert!((t - (1.0e4 - 0.01)).abs() < 1e-3, "{t}");
    }
}
