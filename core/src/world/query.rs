//! The two ray queries the integrator asks a [`View`]: the closest hit
//! (with the tie rule that makes it independent of the traversal's order)
//! and the transmittance towards a light (through translucent occluders).
//! Both walk the top-level tree, enter instances in object space, and test
//! the infinite planes directly.

use super::{Hit, HitKind, TieKey, View};
use crate::bvh::{simd, Visit};
use crate::geometry::{plane, sphere, triangle};
use crate::scene::Sided;
use glam::Vec3;

/// The smallest f32 above `t` (for `t > 0` finite): `t' < above(t)` is
/// `t' <= t`. (`f32::next_up` needs Rust 1.86.)
#[inline]
fn above(t: f32) -> f32 {
    f32::from_bits(t.to_bits() + 1)
}

impl<'a> View<'a> {
    /// Calls `f` for hits along `origin + t·dir`, `t ∈ (0, t_max)`, nearest
    /// boxes first (`ORDERED`; else in the trees' slot order, for visitors
    /// whose answer does not depend on the order), honouring
    /// `sided="front"`. `f` decides, as in [`Bvh::traverse`](crate::bvh::Bvh::traverse), whether the
    /// ray shortens or stops.
    #[inline]
    fn for_each_hit<F: FnMut(Hit) -> Visit, const ORDERED: bool>(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_max: f32,
        mut f: F,
    ) -> (f32, bool) {
        let (scene, world) = (self.scene, self.world);
        let n_inst = world.instances.len() as u32;
        let path = simd::current();
        let tlas_visit = |prim: u32, t_max: f32| {
            if prim < n_inst {
                let inst = &world.instances[prim as usize];
                let o = inst.to_object.transform_point3(origin);
                let d = inst.to_object.transform_vector3(dir);
                let model = &scene.desc.models[inst.model as usize];
                let mut stopped = false;
                let mesh_visit = |tri: u32, h: triangle::TriangleHit| {
                    let front = h.front != inst.mirrored;
                    if inst.any_front_only && !front {
                        let s = if model.triangle_surface.is_empty() {
                            0
                        } else {
                            model.triangle_surface[tri as usize] as usize
                        };
                        if model.surfaces[s].sided == Sided::Front {
                            return Visit::Miss;
                        }
                    }
                    let v = f(Hit {
                        t: h.t,
                        kind: HitKind::Triangle {
                            instance: prim,
                            triangle: tri,
                            bary: h.bary,
                        },
                        front,
                    });
                    stopped = matches!(v, Visit::Stop);
                    v
                };
                let blas = &scene.blas[inst.mesh as usize];
                let (t, hit) = blas.traverse_on::<_, ORDERED>(path, o, d, t_max, mesh_visit);
                if stopped {
                    Visit::Stop
                } else if hit {
                    Visit::Hit(t)
                } else {
                    Visit::Miss
                }
            } else {
                let i = prim - n_inst;
                let s = &scene.desc.spheres[i as usize];
                let center = world.sphere_centers[i as usize];
                // Both crossings: the far one is offered only to a visitor
                // that asked for more after the near one (transmittance,
                // which counts every crossing), never to a closest- or
                // any-hit query, whose answer it cannot change.
                let mut result = Visit::Miss;
                for (t, front) in sphere::crossings(origin, dir, center, s.radius, t_max)
                    .into_iter()
                    .flatten()
                {
                    if front || s.surface.sided == Sided::Two {
                        result = f(Hit {
                            t,
                            kind: HitKind::Sphere(i),
                            front,
                        });
                        if !matches!(result, Visit::Miss) {
                            break;
                        }
                    }
                }
                result
            }
        };
        let (t_max, hit_a) = if ORDERED {
            world.tlas.traverse(origin, dir, t_max, tlas_visit)
        } else {
            world
                .tlas
                .traverse_unordered(origin, dir, t_max, tlas_visit)
        };
        let mut t_max = t_max;
        let mut hit = hit_a;
        for (i, pl) in scene.desc.planes.iter().enumerate() {
            let point = world.plane_points[i];
            if let Some((t, front)) = plane::intersect(origin, dir, point, pl.normal, t_max) {
                if !front && pl.surface.sided == Sided::Front {
                    continue;
                }
                match f(Hit {
                    t,
                    kind: HitKind::Plane(i as u32),
                    front,
                }) {
                    Visit::Miss => {}
                    Visit::Hit(t) => {
                        hit = true;
                        t_max = t_max.min(t);
                    }
                    Visit::Stop => return (t_max, true),
                }
            }
        }
        (t_max, hit)
    }

    /// The closest-hit order, a total order on a ray's hits, so that the
    /// answer of [`View::intersect`] cannot depend on the order in which the
    /// traversal meets them: the smaller `t` wins; at equal `t` (two
    /// triangles sharing an edge or coincident, two instances of one mesh in
    /// the same place) the smaller `TieKey` wins: the earlier model
    /// (models, then spheres, then planes, each in document order), then
    /// the earlier triangle of the mesh as loaded. See docs/performance.md.
    #[inline]
    pub fn precedes(&self, a: &Hit, b: &Hit) -> bool {
        a.t < b.t || (a.t == b.t && self.tie_key(a.kind) < self.tie_key(b.kind))
    }

    /// The hit's key in the tie rule ([`View::precedes`]).
    fn tie_key(&self, kind: HitKind) -> TieKey {
        let n_inst = self.world.instances.len() as u32;
        match kind {
            HitKind::Triangle {
                instance, triangle, ..
            } => {
                let mesh = self.world.instances[instance as usize].mesh as usize;
                (instance, self.scene.loaded_index[mesh][triangle as usize])
            }
            HitKind::Sphere(i) => (n_inst + i, 0),
            HitKind::Plane(i) => (n_inst + self.scene.desc.spheres.len() as u32 + i, 0),
        }
    }

    /// The nearest hit along the ray within `(0, t_max)`; of several at the
    /// same distance, the first in the tie rule ([`View::precedes`]).
    pub fn intersect(&self, origin: Vec3, dir: Vec3, t_max: f32) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        self.for_each_hit::<_, true>(origin, dir, t_max, |h| {
            let b = match best {
                Some(b) if !self.precedes(&h, &b) => b,
                _ => h,
            };
            best = Some(b);
            // Hits at exactly `b.t` must still be offered: the bound passed
            // on is the next float above it.
            Visit::Hit(above(b.t))
        });
        best
    }

    /// The fraction of light passing from `origin` to `origin + dir·t_max`:
    /// the product of (1 − α) over the surfaces in between (0 as soon as an
    /// opaque one is found). Without translucent surfaces in the scene this is
    /// a plain any-hit query.
    pub fn transmittance(&self, origin: Vec3, dir: Vec3, t_max: f32) -> f32 {
        if !self.scene.has_translucency {
            // Any hit at all: the order of the walk cannot matter.
            let (_, hit) = self.for_each_hit::<_, false>(origin, dir, t_max, |_| Visit::Stop);
            return if hit { 0.0 } else { 1.0 };
        }
        // The product is taken in the (nearest-first) visit order.
        let mut vis = 1.0f32;
        self.for_each_hit::<_, true>(origin, dir, t_max, |h| {
            vis *= 1.0 - self.surface_of(h.kind).opacity;
            if vis <= 0.0 {
                Visit::Stop
            } else {
                Visit::Miss
            }
        });
        vis.max(0.0)
    }
}
