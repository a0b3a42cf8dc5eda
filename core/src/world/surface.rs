//! Surface points: the position, geometric and shading normals and surface
//! at a hit, computed accurately whatever the scene's scale, and the
//! texture looked up there.

use super::texture_lod::texture_lod;
use super::{Hit, HitKind, SurfacePoint, View};
use crate::geometry::offset_from_surface;
use crate::scene::Surface;
use glam::{Mat3, Vec3};

impl SurfacePoint<'_> {
    /// The origin for a new ray leaving this point in direction `dir`: the
    /// point moved off the surface, to the side `dir` goes to (see
    /// [`offset_from_surface`]).
    #[inline]
    pub fn spawn(&self, dir: Vec3) -> Vec3 {
        let side = if dir.dot(self.ng) >= 0.0 {
            self.ng
        } else {
            -self.ng
        };
        offset_from_surface(self.p, side, self.scale)
    }
}

impl<'a> View<'a> {
    pub(super) fn surface_of(&self, kind: HitKind) -> &'a Surface {
        let scene = self.scene;
        match kind {
            HitKind::Triangle {
                instance, triangle, ..
            } => {
                let m = &scene.desc.models[self.world.instances[instance as usize].model as usize];
                let s = if m.triangle_surface.is_empty() {
                    0
                } else {
                    m.triangle_surface[triangle as usize] as usize
                };
                &m.surfaces[s]
            }
            HitKind::Sphere(i) => &scene.desc.spheres[i as usize].surface,
            HitKind::Plane(i) => &scene.desc.planes[i as usize].surface,
        }
    }

    /// Position, normals and surface at a hit of ray `origin + t·dir`.
    pub fn surface_point(&self, origin: Vec3, dir: Vec3, hit: &Hit) -> SurfacePoint<'a> {
        let (scene, world) = (self.scene, self.world);
        let surface = self.surface_of(hit.kind);
        let (p, ng, ns, scale) = match hit.kind {
            HitKind::Triangle {
                instance,
                triangle,
                bary,
            } => {
                let inst = &world.instances[instance as usize];
                let mesh = &scene.desc.meshes[inst.mesh as usize];
                let [i0, i1, i2] = mesh.triangles[triangle as usize].map(|i| i as usize);
                let (a, b, c) = (mesh.positions[i0], mesh.positions[i1], mesh.positions[i2]);
                let obj_mag = a.abs().max(b.abs()).max(c.abs()).max_element();
                let scale = inst.trans_mag.max(inst.lin_norm * obj_mag);
                // Barycentric interpolation is more accurate than o + t·d.
                let p_obj = a * bary[0] + b * bary[1] + c * bary[2];
                let p = inst.to_world.transform_point3(p_obj);
                let ng = geometric_normal(inst.normal_matrix, a, b, c);
                let ns = if surface.smooth {
                    let n = mesh.normals[i0] * bary[0]
                        + mesh.normals[i1] * bary[1]
                        + mesh.normals[i2] * bary[2];
                    // The normal matrix is linear: one normalisation after
                    // it gives the direction two (before and after) gave.
                    unit_shading(inst.normal_matrix * n)
                } else {
                    ng
                };
                (p, ng, if ns == Vec3::ZERO { ng } else { ns }, scale)
            }
            HitKind::Sphere(i) => {
                let s = &scene.desc.spheres[i as usize];
                let center = world.sphere_centers[i as usize];
                let p = origin + dir * hit.t;
                // The direction of p − centre, whatever the radius's scale.
                let n = unit_shading(p - center);
                // Project onto the surface to remove the error of o + t·d.
                let scale = center.abs().max_element() + s.radius;
                (center + n * s.radius, n, n, scale)
            }
            HitKind::Plane(i) => {
                let pl = &scene.desc.planes[i as usize];
                let point = world.plane_points[i as usize];
                let p = origin + dir * hit.t;
                // Project onto the plane.
                let p = p - pl.normal * (p - point).dot(pl.normal);
                (p, pl.normal, pl.normal, point.abs().max_element())
            }
        };
        let ng = if ng.dot(dir) > 0.0 { -ng } else { ng };
        let ns = if ns.dot(dir) > 0.0 { -ns } else { ns };
        SurfacePoint {
            p,
            ng,
            ns,
            front: hit.front,
            surface,
            kd: surface.diffuse,
            ka: surface.ambient,
            cone: 0.0,
            scale,
        }
    }

    /// Multiplies `sp.kd` and `sp.ka` by the surface's texture, if it has
    /// one, at the hit's texture coordinates. `dir` is the ray's direction
    /// and `sp.cone` the width of its ray cone at the hit (see
    /// [`texture_lod`]). One branch and nothing else for an untextured
    /// surface.
    #[inline]
    pub fn apply_texture(&self, sp: &mut SurfacePoint<'a>, hit: &Hit, dir: Vec3) {
        let Some(tm) = sp.surface.texture else {
            return;
        };
        let HitKind::Triangle {
            instance,
            triangle,
            bary,
        } = hit.kind
        else {
            return;
        };
        let inst = &self.world.instances[instance as usize];
        let mesh = &self.scene.desc.meshes[inst.mesh as usize];
        if mesh.uvs.is_empty() {
            return;
        }
        let [i0, i1, i2] = mesh.triangles[triangle as usize].map(|i| i as usize);
        let [t0, t1, t2] = [i0, i1, i2].map(|i| mesh.uvs[i] * tm.scale);
        let uv = t0 * bary[0] + t1 * bary[1] + t2 * bary[2];
        let texture = &self.scene.desc.textures[tm.texture as usize];
        let l0 = &texture.levels[0];
        // Twice the triangle's area in texels and in the view's space.
        let texel_area = ((t1 - t0).perp_dot(t2 - t0) * (l0.width as f32 * l0.height as f32)).abs();
        let (a, b, c) = (mesh.positions[i0], mesh.positions[i1], mesh.positions[i2]);
        let world_area = inst
            .to_world
            .transform_vector3(b - a)
            .cross(inst.to_world.transform_vector3(c - a))
            .length();
        let cos = sp.ng.dot(dir).abs() / dir.length();
        let lod = texture_lod(texel_area, world_area, sp.cone, cos);
        let t = texture.sample(uv, lod, tm.wrap);
        sp.kd *= t;
        sp.ka *= t;
    }
}

/// `v` normalised whatever its magnitude (zero for zero or non-finite
/// input). Plain normalisation squares the length: a triangle 10¹⁰ units
/// across has a cross product of 10²⁰ whose square overflows f32, one of
/// 10⁻¹² a square that underflows, and either way the normal came out zero.
#[inline]
fn unit(v: Vec3) -> Vec3 {
    let m = v.abs().max_element();
    if m > 0.0 && m.is_finite() {
        (v / m).normalize_or_zero()
    } else {
        Vec3::ZERO
    }
}

/// [`unit()`] for the normals of a hit (`View::surface_point`, once or twice a
/// hit): `v · (1/|v|)`, one square root and one division, when `|v|²` is a
/// normal f32 far from overflow and underflow (every normal of an ordinary
/// scene); otherwise [`unit()`]'s scaled form, which is right at every
/// magnitude. Two to four divisions fewer on the hit's critical path.
#[inline]
fn unit_shading(v: Vec3) -> Vec3 {
    let l2 = v.length_squared();
    if l2 > 1e-30 && l2 < 1e30 {
        v * (1.0 / l2.sqrt())
    } else {
        unit(v)
    }
}

/// The unit world-space geometric normal of triangle `a b c` (winding
/// order) under `normal_matrix`, zero for a degenerate one: the one formula
/// of a triangle hit's geometric normal (recomputed per hit: the leaves'
/// copies of the vertices leave no room in the memory goal for 12 more
/// bytes a triangle; see docs/performance.md).
///
/// One normalisation on the hit's critical path: the raw cross product of
/// the edges goes through the (linear) normal matrix and is normalised once
/// there, when both its squared length and the transformed one's are normal
/// f32 far from overflow and underflow (every triangle of an ordinary scene:
/// edges between about 10⁻⁷ and 10⁷ units). Otherwise, a triangle 10¹⁰
/// units across (a cross product whose square overflows) or 10⁻¹² across
/// (one that underflows), the edges are normalised first as before
/// ([`face_normal_scaled`]), which is right at every magnitude. Plain IEEE
/// arithmetic either way: the same bits on every target.
#[inline]
fn geometric_normal(normal_matrix: Mat3, a: Vec3, b: Vec3, c: Vec3) -> Vec3 {
    let n = (b - a).cross(c - a);
    let l2 = n.length_squared();
    if l2 > 1e-30 && l2 < 1e30 {
        let m = normal_matrix * n;
        let m2 = m.length_squared();
        if m2 > 1e-30 && m2 < 1e30 {
            return m * (1.0 / m2.sqrt());
        }
    }
    // Degenerate (zero or non-finite cross product) lands here too, and
    // comes out zero.
    unit_shading(normal_matrix * face_normal_scaled(a, b, c))
}

/// The unit object-space normal of triangle `a b c` with the edges
/// normalised before the cross product: no overflow or underflow at any
/// magnitude (three normalisations; [`geometric_normal`]'s fallback).
#[inline]
fn face_normal_scaled(a: Vec3, b: Vec3, c: Vec3) -> Vec3 {
    unit(unit(b - a).cross(unit(c - a)))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The one-normalisation geometric normal against the same normal in
    /// f64 (cross product of the edges, normal matrix, normalisation), for
    /// triangles from 10⁻¹⁵ to 10¹⁵ units across (the fast path and both
    /// sides of its fallback) under a non-uniform scale and shear: within a
    /// few f32 ulps of the exact direction, unit length; degenerate and
    /// non-finite triangles give zero, never NaN.
    #[test]
    fn the_geometric_normal_is_the_exact_direction_at_every_magnitude() {
        let nm = Mat3::from_cols_array(&[2.0, 0.3, 0.0, 0.0, 0.5, -0.2, 0.1, 0.0, 3.0]);
        let shapes = [
            [
                Vec3::ZERO,
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(0.0, 1.0, 0.0),
            ],
            [
                Vec3::new(0.3, -0.7, 1.1),
                Vec3::new(1.9, 0.2, -0.4),
                Vec3::new(-0.6, 1.3, 0.8),
            ],
            // A sliver: two edges 10⁻³ apart in direction.
            [
                Vec3::new(1.0, 1.0, 1.0),
                Vec3::new(2.0, 1.0, 1.0),
                Vec3::new(2.0, 1.001, 1.0),
            ],
        ];
        let nm64 = nm.as_dmat3();
        for e in -15..=15 {
            let s: f32 = format!("1e{e}").parse().unwrap();
            for [a, b, c] in shapes {
                let (a, b, c) = (a * s, b * s, c * s);
                let got = geometric_normal(nm, a, b, c);
                let (a64, b64, c64) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
                let want = (nm64 * (b64 - a64).cross(c64 - a64)).normalize();
                let err = (got.as_dvec3() - want).length();
                // The sliver's edges carry f32 rounding of their own.
                assert!(err < 1e-4, "scale 1e{e}: {got} against {want}");
                assert!((got.length() - 1.0).abs() < 1e-6, "scale 1e{e}: {got}");
            }
        }
        let p = Vec3::new(1.0, 2.0, 3.0);
        for [a, b, c] in [
            [p, p, p],
            [p, p * 2.0, p * 3.0],
            [p, Vec3::new(f32::NAN, 0.0, 0.0), p],
            [p, Vec3::splat(f32::INFINITY), Vec3::ZERO],
            [
                Vec3::splat(-3e38),
                Vec3::splat(3e38),
                Vec3::new(3e38, -3e38, 0.0),
            ],
        ] {
            let n = geometric_normal(nm, a, b, c);
            assert!(!n.is_nan(), "{a} {b} {c}: {n}");
        }
        assert_eq!(geometric_normal(nm, p, p, p), Vec3::ZERO);
    }
}
