//! Watertight ray–triangle intersection (Woop, Benthin and Wald, "Watertight
//! Ray/Triangle Intersection", JCGT 2013).
//!
//! Why this method: the edge tests of a ray against two triangles sharing an
//! edge are evaluated on exactly the same numbers, so a ray through a shared
//! edge or vertex hits at least one of them — closed meshes never leak. The
//! ray is sheared so it runs along +z from the origin; each edge test is then
//! a 2D cross product, redone in f64 when it comes out exactly zero.

use glam::Vec3;

/// A ray prepared for many triangle tests (the shear depends only on the ray).
#[derive(Debug, Clone, Copy)]
pub struct ShearedRay {
    /// The ray's origin, subtracted from every vertex tested.
    pub origin: Vec3,
    pub(crate) kx: usize,
    pub(crate) ky: usize,
    pub(crate) kz: usize,
    pub(crate) sx: f32,
    pub(crate) sy: f32,
    pub(crate) sz: f32,
}

impl ShearedRay {
    /// The shear of the ray `origin + t·dir` (`dir` non-zero, any length;
    /// hits come back in units of that `dir`).
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        let ad = dir.abs();
        let kz = if ad.x >= ad.y && ad.x >= ad.z {
            0
        } else if ad.y >= ad.z {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        // Swapping keeps the winding (and so the sign of the determinant)
        // independent of which way the ray points along kz.
        if dir[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        let sz = 1.0 / dir[kz];
        ShearedRay {
            origin,
            kx,
            ky,
            kz,
            sx: dir[kx] * sz,
            sy: dir[ky] * sz,
            sz,
        }
    }
}

/// A hit: the ray parameter, barycentric weights of the three vertices (they
/// sum to 1), and whether the ray met the front (the side the winding
/// `(b−a)×(c−a)` faces).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TriangleHit {
    /// The ray parameter of the hit, in `(0, t_max)`.
    pub t: f32,
    /// The weights of vertices `a`, `b`, `c`, each in `[0, 1]`.
    pub bary: [f32; 3],
    /// Whether the ray met the triangle's front face.
    pub front: bool,
}

/// Margin of the early out in [`intersect`] (1 + 2⁻²⁰).
pub(crate) const T_MARGIN: f32 = 1.0 + 1.0 / (1 << 20) as f32;

/// Intersects the ray with triangle `a b c` for `t` in `(0, t_max)`: a hit
/// is reported exactly when its computed `t` satisfies `0 < t < t_max`.
/// Zero-area triangles and rays in the triangle's plane never hit.
///
/// `bvh/simd.rs` (`triangles_sse`) performs these very operations on four
/// triangles at once; a change here must be made there too (the tests in
/// `bvh/tests.rs` compare the two bit for bit).
#[inline(always)]
pub fn intersect(r: &ShearedRay, a: Vec3, b: Vec3, c: Vec3, t_max: f32) -> Option<TriangleHit> {
    // Plain arrays: indexing one by the ray's axes is a load, where indexing
    // a `Vec3` is a three-way match per component.
    let (kx, ky, kz) = (r.kx, r.ky, r.kz);
    let aa = (a - r.origin).to_array();
    let bb = (b - r.origin).to_array();
    let cc = (c - r.origin).to_array();
    let ax = aa[kx] - r.sx * aa[kz];
    let ay = aa[ky] - r.sy * aa[kz];
    let bx = bb[kx] - r.sx * bb[kz];
    let by = bb[ky] - r.sy * bb[kz];
    let cx = cc[kx] - r.sx * cc[kz];
    let cy = cc[ky] - r.sy * cc[kz];
    let mut u = cx * by - cy * bx;
    let mut v = ax * cy - ay * cx;
    let mut w = bx * ay - by * ax;
    if u == 0.0 || v == 0.0 || w == 0.0 {
        // Exactly on an edge in f32: decide in f64 so neighbours agree.
        let (ax, ay, bx, by, cx, cy) = (
            ax as f64, ay as f64, bx as f64, by as f64, cx as f64, cy as f64,
        );
        u = (cx * by - cy * bx) as f32;
        v = (ax * cy - ay * cx) as f32;
        w = (bx * ay - by * ax) as f32;
    }
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
        return None;
    }
    let det = u + v + w;
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let az = r.sz * aa[kz];
    let bz = r.sz * bb[kz];
    let cz = r.sz * cc[kz];
    let t_scaled = u * az + v * bz + w * cz;
    // Early out before dividing, with the determinant's sign folded in and
    // a margin (2⁻²⁰, far above the two roundings of `t_scaled · (1/det)`)
    // so that it never rejects a hit whose computed `t` is below `t_max`:
    // whether a triangle is hit must depend on its computed `t` alone, not
    // on how the bound was reached, or a closest-hit query's tie rule
    // (`world::View::precedes`) would depend on the visit order.
    if det > 0.0 {
        if t_scaled <= 0.0 || t_scaled > t_max * det * T_MARGIN {
            return None;
        }
    } else if t_scaled >= 0.0 || t_scaled < t_max * det * T_MARGIN {
        return None;
    }
    let inv = 1.0 / det;
    let t = t_scaled * inv;
    // The exact test, on the computed `t`.
    if !(t > 0.0 && t < t_max) {
        return None;
    }
    Some(TriangleHit {
        t,
        bary: [u * inv, v * inv, w * inv],
        // With this shear a counter-clockwise triangle seen from the ray's
        // side has a positive determinant (checked in the tests below).
        front: det > 0.0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hit(o: Vec3, d: Vec3, a: Vec3, b: Vec3, c: Vec3) -> Option<TriangleHit> {
        intersect(&ShearedRay::new(o, d), a, b, c, f32::INFINITY)
    }

    // The report's own test: triangle <0,0,0> <0,0,1> <1,0,1>, rays straight down.
    #[test]
    fn report_triangle_centre_edges_corners_and_outside() {
        let (a, b, c) = (
            Vec3::ZERO,
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::new(1.0, 0.0, 1.0),
        );
        let d = Vec3::new(0.0, -1.0, 0.0);
        let centre = (a + b + c) / 3.0;
        let h = hit(centre + Vec3::Y * 2.0, d, a, b, c).expect("centre hits");
        assert!((h.t - 2.0).abs() < 1e-6);
        for w in h.bary {
            assert!((w - 1.0 / 3.0).abs() < 1e-6);
        }
        for p in [a, b, c, (a + b) * 0.5, (b + c) * 0.5, (a + c) * 0.5] {
            assert!(hit(p + Vec3::Y, d, a, b, c).is_some(), "{p}");
        }
        for p in [
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(-0.1, 0.0, 0.5),
            Vec3::new(0.5, 0.0, 1.1),
        ] {
            assert!(hit(p + Vec3::Y, d, a, b, c).is_none(), "{p}");
        }
        // Behind the origin: no hit.
        assert!(hit(centre - Vec3::Y, d, a, b, c).is_none());
    }

    #[test]
    fn front_is_the_side_the_winding_faces_for_every_axis_and_direction() {
        let tris = [
            (Vec3::ZERO, Vec3::X, Vec3::Y),
            (Vec3::ZERO, Vec3::Y, Vec3::Z),
            (Vec3::ZERO, Vec3::Z, Vec3::X),
            (
                Vec3::ZERO,
                Vec3::new(1.0, 0.2, 0.1),
                Vec3::new(0.3, 1.0, 0.4),
            ),
        ];
        for (a, b, c) in tris {
            let n = (b - a).cross(c - a).normalize();
            let p = (a + b + c) / 3.0;
            let front = hit(p + n * 3.0, -n, a, b, c).unwrap();
            assert!(front.front);
            let back = hit(p - n * 3.0, n, a, b, c).unwrap();
            assert!(!back.front);
            // Oblique rays agree too.
            let d = (-n + Vec3::new(0.3, -0.2, 0.1)).normalize();
            assert!(hit(p - d * 2.0, d, a, b, c).unwrap().front);
        }
    }

    #[test]
    fn barycentrics_reconstruct_the_hit_point() {
        let (a, b, c) = (
            Vec3::new(-1.0, -0.5, 2.0),
            Vec3::new(2.0, 0.1, 1.0),
            Vec3::new(0.2, 2.0, 1.5),
        );
        let o = Vec3::new(0.1, 0.3, -4.0);
        let target = a * 0.2 + b * 0.3 + c * 0.5;
        let d = target - o;
        let h = hit(o, d, a, b, c).unwrap();
        let p = a * h.bary[0] + b * h.bary[1] + c * h.bary[2];
        assert!((p - target).length() < 1e-5);
        assert!((o + d * h.t - target).length() < 1e-5);
    }

    #[test]
    fn degenerate_and_parallel_cases_never_hit_or_produce_nan() {
        let d = Vec3::new(0.0, -1.0, 0.0);
        // Zero-area (collinear) triangle.
        assert!(hit(Vec3::Y, d, Vec3::ZERO, Vec3::X, Vec3::X * 2.0).is_none());
        // Coincident vertices.
        assert!(hit(Vec3::Y, d, Vec3::ZERO, Vec3::ZERO, Vec3::ZERO).is_none());
        // Ray in the triangle's plane.
        let (a, b, c) = (Vec3::ZERO, Vec3::X, Vec3::Z);
        assert!(hit(Vec3::new(-1.0, 0.0, 0.1), Vec3::X, a, b, c).is_none());
    }

    #[test]
    fn a_ray_through_a_shared_edge_hits_one_of_the_two_triangles() {
        // Quad split along its diagonal; rays through diagonal points.
        let (p0, p1, p2, p3) = (
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 1.0),
            Vec3::new(0.0, 0.0, 1.0),
        );
        for i in 0..=1000 {
            let s = i as f32 / 1000.0;
            let target = p0 + (p2 - p0) * s;
            let o = Vec3::new(0.37, 1.3, -0.21);
            let d = target - o;
            let r = ShearedRay::new(o, d);
            let h1 = intersect(&r, p0, p1, p2, f32::INFINITY);
            let h2 = intersect(&r, p0, p2, p3, f32::INFINITY);
            assert!(h1.is_some() || h2.is_some(), "leak at s = {s}");
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(20000))]
        /// A hit is reported exactly when its computed `t` is below `t_max`,
        /// whatever the bound: with `t_max` the next float above `t` it is
        /// found with the same `t` and barycentrics, with `t_max = t` it is
        /// not. (The closest-hit tie rule relies on this.)
        #[test]
        fn the_bound_decides_on_the_computed_t_alone(
            o in proptest::array::uniform3(-10.0f32..10.0),
            d in proptest::array::uniform3(-1.0f32..1.0),
            a in proptest::array::uniform3(-5.0f32..5.0),
            b in proptest::array::uniform3(-5.0f32..5.0),
            c in proptest::array::uniform3(-5.0f32..5.0),
        ) {
            let r = ShearedRay::new(Vec3::from(o), Vec3::from(d));
            let (a, b, c) = (Vec3::from(a), Vec3::from(b), Vec3::from(c));
            if let Some(h) = intersect(&r, a, b, c, f32::INFINITY) {
                let above = f32::from_bits(h.t.to_bits() + 1);
                proptest::prop_assert_eq!(intersect(&r, a, b, c, above), Some(h));
                proptest::prop_assert_eq!(intersect(&r, a, b, c, h.t), None);
            }
        }
    }

    /// Reference in f64 (Möller–Trumbore): t and barycentrics, or None when
    /// the ray is parallel to the plane.
    fn reference(
        o: [f64; 3],
        d: [f64; 3],
        a: [f64; 3],
        b: [f64; 3],
        c: [f64; 3],
    ) -> Option<(f64, [f64; 3])> {
        let sub = |x: [f64; 3], y: [f64; 3]| [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
        let cross = |x: [f64; 3], y: [f64; 3]| {
            [
                x[1] * y[2] - x[2] * y[1],
                x[2] * y[0] - x[0] * y[2],
                x[0] * y[1] - x[1] * y[0],
            ]
        };
        let dot = |x: [f64; 3], y: [f64; 3]| x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
        let (e1, e2) = (sub(b, a), sub(c, a));
        let p = cross(d, e2);
        let det = dot(e1, p);
        if det.abs() < 1e-300 {
            return None;
        }
        let s = sub(o, a);
        let u = dot(s, p) / det;
        let q = cross(s, e1);
        let v = dot(d, q) / det;
        let t = dot(e2, q) / det;
        Some((t, [1.0 - u - v, u, v]))
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(20000))]
        /// Wherever the f64 reference is clear (every barycentric at least
        /// 1e-4 inside or one 1e-4 outside, t not tiny), the watertight f32
        /// test agrees on hit or miss, and on t and the barycentrics.
        #[test]
        fn agrees_with_an_f64_reference(
            o in proptest::array::uniform3(-10.0f32..10.0),
            d in proptest::array::uniform3(-1.0f32..1.0),
            a in proptest::array::uniform3(-5.0f32..5.0),
            b in proptest::array::uniform3(-5.0f32..5.0),
            c in proptest::array::uniform3(-5.0f32..5.0),
            scale_pow in -3i32..4,
        ) {
            let k = 10f32.powi(scale_pow);
            let (o, a, b, c) = (Vec3::from(o) * k, Vec3::from(a) * k, Vec3::from(b) * k, Vec3::from(c) * k);
            let d = Vec3::from(d);
            proptest::prop_assume!(d.length() > 1e-3);
            let f64v = |v: Vec3| [v.x as f64, v.y as f64, v.z as f64];
            let got = intersect(&ShearedRay::new(o, d), a, b, c, f32::INFINITY);
            let n = (b - a).cross(c - a);
            // Skip near-degenerate and near-parallel configurations.
            proptest::prop_assume!(n.length() > 1e-3 * k * k);
            proptest::prop_assume!(n.normalize().dot(d.normalize()).abs() > 1e-2);
            if let Some((t, bary)) = reference(f64v(o), f64v(d), f64v(a), f64v(b), f64v(c)) {
                let inside = bary.iter().all(|&w| w > 1e-4);
                let outside = bary.iter().any(|&w| w < -1e-4);
                if inside && t > 1e-3 * k as f64 {
                    let h = got.expect("f64 says hit, f32 missed");
                    proptest::prop_assert!(((h.t as f64) - t).abs() <= 1e-4 * t.abs().max(k as f64));
                    for (hb, b) in h.bary.iter().zip(bary) {
                        proptest::prop_assert!(((*hb as f64) - b).abs() < 1e-4);
                    }
                } else if outside || t < -1e-3 * k as f64 {
                    proptest::prop_assert!(got.is_none(), "f64 says miss (t {t}, bary {bary:?}), f32 hit {got:?}");
                }
            }
        }
    }
}
