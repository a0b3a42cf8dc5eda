//! Analytic infinite planes (two-sided; the front is the side `normal` faces).

use glam::Vec3;

/// `t` in `(0, t_max)` where the ray meets the plane, and whether it meets
/// the front. Rays parallel to the plane never hit.
#[inline]
pub fn intersect(
    origin: Vec3,
    dir: Vec3,
    point: Vec3,
    normal: Vec3,
    t_max: f32,
) -> Option<(f32, bool)> {
    let denom = dir.dot(normal);
    if denom == 0.0 || !denom.is_finite() {
        return None;
    }
    let t = (point - origin).dot(normal) / denom;
    if t > 0.0 && t < t_max {
        Some((t, denom < 0.0))
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plane_hits_both_sides_and_ignores_parallel_rays() {
        let (p, n) = (Vec3::ZERO, Vec3::Y);
        assert_eq!(
            intersect(Vec3::Y * 2.0, -Vec3::Y, p, n, f32::INFINITY),
            Some((2.0, true))
        );
        assert_eq!(
            intersect(-Vec3::Y * 3.0, Vec3::Y, p, n, f32::INFINITY),
            Some((3.0, false))
        );
        assert_eq!(intersect(Vec3::Y, Vec3::X, p, n, f32::INFINITY), None);
        assert_eq!(intersect(Vec3::Y, Vec3::Y, p, n, f32::INFINITY), None);
    }
}
