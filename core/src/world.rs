//! The renderable scene: the description plus its two-level acceleration
//! structure, answering the two ray queries the integrator needs.
//!
//! Bottom level: one BVH per mesh over its triangles in object space, stored
//! once however many models use the mesh. Top level: one BVH over model
//! instances and spheres in world space; a ray entering an instance is moved
//! into the instance's object space. Infinite planes sit outside both trees
//! and are tested directly.

use crate::bundle::{Bundle, FileSource};
use crate::bvh::{Bvh, Visit};
use crate::camera::Camera;
use crate::error::SceneError;
use crate::geometry::{plane, sphere, triangle, Aabb};
use crate::sampling::hash_str;
use crate::scene::{aisxml, AoDistance, SceneDesc, Sided, Surface};
use glam::{Affine3A, Mat3, Vec3};

/// A model instance as the traversal sees it.
#[derive(Debug, Clone)]
struct Instance {
    mesh: u32,
    model: u32,
    to_world: Affine3A,
    to_object: Affine3A,
    normal_matrix: Mat3,
    /// The transform mirrors (negative determinant): world winding flips.
    mirrored: bool,
    /// Some triangle of this model uses `sided="front"`.
    any_front_only: bool,
}

/// What a closest-hit query found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HitKind {
    Triangle {
        instance: u32,
        triangle: u32,
        bary: [f32; 3],
    },
    Sphere(u32),
    Plane(u32),
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    pub t: f32,
    pub kind: HitKind,
    /// The ray met the front (the side the winding or the normal faces).
    pub front: bool,
}

/// The local geometry at a hit.
#[derive(Debug, Clone, Copy)]
pub struct SurfacePoint<'a> {
    pub p: Vec3,
    /// Unit geometric normal, on the side the ray came from.
    pub ng: Vec3,
    /// Unit shading normal, on the side the ray came from.
    pub ns: Vec3,
    pub front: bool,
    pub surface: &'a Surface,
}

/// A scene ready to render.
pub struct Scene {
    pub desc: SceneDesc,
    blas: Vec<Bvh>,
    instances: Vec<Instance>,
    /// Top-level primitives `0..instances.len()` are instances, the rest spheres.
    tlas: Bvh,
    /// Bounds of the finite geometry (planes excluded).
    pub bounds: Aabb,
    /// Some surface has opacity < 1: shadow rays must gather every occluder.
    pub has_translucency: bool,
    pub cameras: Vec<Camera>,
    camera_hashes: Vec<u64>,
}

impl Scene {
    /// Parses and builds the scene in `bundle`.
    pub fn from_bundle(bundle: &Bundle) -> Result<Scene, SceneError> {
        Scene::from_source(&bundle.scene, bundle)
    }

    /// Parses and builds scene file `scene` read through `source`.
    pub fn from_source(scene: &str, source: &dyn FileSource) -> Result<Scene, SceneError> {
        Ok(Scene::build(aisxml::parse_scene(scene, source)?))
    }

    /// Builds the acceleration structures of a parsed scene.
    pub fn build(desc: SceneDesc) -> Scene {
        let blas: Vec<Bvh> = desc
            .meshes
            .iter()
            .map(|m| {
                let boxes: Vec<Aabb> = m
                    .triangles
                    .iter()
                    .map(|t| Aabb::from_points(&t.map(|i| m.positions[i as usize])))
                    .collect();
                Bvh::build(&boxes, 4)
            })
            .collect();
        let instances: Vec<Instance> = desc
            .models
            .iter()
            .enumerate()
            .map(|(i, model)| {
                let to_world = Affine3A::from_mat4(model.transform.as_mat4());
                let to_object = Affine3A::from_mat4(model.transform.inverse().as_mat4());
                let lin = model.transform.inverse().transpose().as_mat4();
                Instance {
                    mesh: model.mesh as u32,
                    model: i as u32,
                    to_world,
                    to_object,
                    normal_matrix: Mat3::from_mat4(lin),
                    mirrored: model.transform.determinant() < 0.0,
                    any_front_only: model.surfaces.iter().any(|s| s.sided == Sided::Front),
                }
            })
            .collect();
        let mut boxes: Vec<Aabb> = instances
            .iter()
            .map(|inst| transform_box(blas[inst.mesh as usize].bounds(), &inst.to_world))
            .collect();
        boxes.extend(desc.spheres.iter().map(|s| Aabb {
            min: s.center - Vec3::splat(s.radius),
            max: s.center + Vec3::splat(s.radius),
        }));
        let tlas = Bvh::build(&boxes, 2);
        let bounds = boxes.iter().fold(Aabb::EMPTY, |a, &b| a.union(b));
        let has_translucency = desc
            .models
            .iter()
            .flat_map(|m| m.surfaces.iter())
            .chain(desc.spheres.iter().map(|s| &s.surface))
            .chain(desc.planes.iter().map(|p| &p.surface))
            .any(|s| s.opacity < 1.0);
        let cameras = desc.cameras.iter().map(Camera::new).collect();
        let camera_hashes = desc.cameras.iter().map(|c| hash_str(&c.id)).collect();
        Scene {
            desc,
            blas,
            instances,
            tlas,
            bounds,
            has_translucency,
            cameras,
            camera_hashes,
        }
    }

    pub fn camera_index(&self, id: &str) -> Option<usize> {
        self.desc.cameras.iter().position(|c| c.id == id)
    }

    pub(crate) fn camera_hash(&self, camera: usize) -> u64 {
        self.camera_hashes[camera]
    }

    /// `s_max` for a camera: its `ao-distance`, or half the diagonal of the
    /// scene's bounding box for `auto` (planes, being infinite, excluded;
    /// lights and cameras stand in for a scene with no finite geometry).
    pub fn ao_distance(&self, camera: usize) -> f32 {
        match self.desc.cameras[camera].render.ao_distance {
            AoDistance::Fixed(d) => d,
            AoDistance::Auto => {
                let mut b = self.bounds;
                if b.diagonal() <= 0.0 {
                    for l in &self.desc.lights {
                        b = b.grow(l.position);
                    }
                    for c in &self.desc.cameras {
                        b = b.grow(c.position);
                    }
                }
                let half = 0.5 * b.diagonal();
                if half > 0.0 && half.is_finite() {
                    half
                } else {
                    1.0
                }
            }
        }
    }

    fn surface_of(&self, kind: HitKind) -> &Surface {
        match kind {
            HitKind::Triangle {
                instance, triangle, ..
            } => {
                let m = &self.desc.models[self.instances[instance as usize].model as usize];
                let s = if m.triangle_surface.is_empty() {
                    0
                } else {
                    m.triangle_surface[triangle as usize] as usize
                };
                &m.surfaces[s]
            }
            HitKind::Sphere(i) => &self.desc.spheres[i as usize].surface,
            HitKind::Plane(i) => &self.desc.planes[i as usize].surface,
        }
    }

    /// Calls `f` for hits along `origin + t·dir`, `t ∈ (0, t_max)`, nearest
    /// boxes first, honouring `sided="front"`. `f` decides, as in
    /// [`Bvh::traverse`], whether the ray shortens or stops.
    #[inline]
    fn for_each_hit<F: FnMut(Hit) -> Visit>(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_max: f32,
        mut f: F,
    ) -> (f32, bool) {
        let n_inst = self.instances.len() as u32;
        let (t_max, hit_a) = self.tlas.traverse(origin, dir, t_max, |prim, t_max| {
            if prim < n_inst {
                let inst = &self.instances[prim as usize];
                let o = inst.to_object.transform_point3(origin);
                let d = inst.to_object.transform_vector3(dir);
                let sheared = triangle::ShearedRay::new(o, d);
                let mesh = &self.desc.meshes[inst.mesh as usize];
                let model = &self.desc.models[inst.model as usize];
                let mut result = Visit::Miss;
                let (_, _) = self.blas[inst.mesh as usize].traverse(o, d, t_max, |tri, t_max| {
                    let [i0, i1, i2] = mesh.triangles[tri as usize];
                    let p = &mesh.positions;
                    let Some(h) = triangle::intersect(
                        &sheared,
                        p[i0 as usize],
                        p[i1 as usize],
                        p[i2 as usize],
                        t_max,
                    ) else {
                        return Visit::Miss;
                    };
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
                    match v {
                        Visit::Hit(t) => {
                            result = Visit::Hit(t);
                            Visit::Hit(t)
                        }
                        Visit::Stop => {
                            result = Visit::Stop;
                            Visit::Stop
                        }
                        Visit::Miss => Visit::Miss,
                    }
                });
                result
            } else {
                let i = prim - n_inst;
                let s = &self.desc.spheres[i as usize];
                match sphere::intersect(origin, dir, s.center, s.radius, t_max) {
                    Some((t, front)) if front || s.surface.sided == Sided::Two => f(Hit {
                        t,
                        kind: HitKind::Sphere(i),
                        front,
                    }),
                    _ => Visit::Miss,
                }
            }
        });
        let mut t_max = t_max;
        let mut hit = hit_a;
        for (i, pl) in self.desc.planes.iter().enumerate() {
            if let Some((t, front)) = plane::intersect(origin, dir, pl.point, pl.normal, t_max) {
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

    /// The nearest hit along the ray within `(0, t_max)`.
    pub fn intersect(&self, origin: Vec3, dir: Vec3, t_max: f32) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        self.for_each_hit(origin, dir, t_max, |h| {
            if best.is_none_or(|b| h.t < b.t) {
                best = Some(h);
            }
            Visit::Hit(h.t)
        });
        best
    }

    /// The fraction of light passing from `origin` to `origin + dir·t_max`:
    /// the product of (1 − α) over the surfaces in between (0 as soon as an
    /// opaque one is found). Without translucent surfaces in the scene this is
    /// a plain any-hit query.
    pub fn transmittance(&self, origin: Vec3, dir: Vec3, t_max: f32) -> f32 {
        if !self.has_translucency {
            let (_, hit) = self.for_each_hit(origin, dir, t_max, |_| Visit::Stop);
            return if hit { 0.0 } else { 1.0 };
        }
        let mut vis = 1.0f32;
        self.for_each_hit(origin, dir, t_max, |h| {
            vis *= 1.0 - self.surface_of(h.kind).opacity;
            if vis <= 0.0 {
                Visit::Stop
            } else {
                Visit::Miss
            }
        });
        vis.max(0.0)
    }

    /// Position, normals and surface at a hit of ray `origin + t·dir`.
    pub fn surface_point(&self, origin: Vec3, dir: Vec3, hit: &Hit) -> SurfacePoint<'_> {
        let surface = self.surface_of(hit.kind);
        let (p, ng, ns) = match hit.kind {
            HitKind::Triangle {
                instance,
                triangle,
                bary,
            } => {
                let inst = &self.instances[instance as usize];
                let mesh = &self.desc.meshes[inst.mesh as usize];
                let [i0, i1, i2] = mesh.triangles[triangle as usize].map(|i| i as usize);
                let (a, b, c) = (mesh.positions[i0], mesh.positions[i1], mesh.positions[i2]);
                // Barycentric interpolation is more accurate than o + t·d.
                let p_obj = a * bary[0] + b * bary[1] + c * bary[2];
                let p = inst.to_world.transform_point3(p_obj);
                let ng = (inst.normal_matrix * (b - a).cross(c - a)).normalize_or_zero();
                let ns = if surface.smooth {
                    let n = mesh.normals[i0] * bary[0]
                        + mesh.normals[i1] * bary[1]
                        + mesh.normals[i2] * bary[2];
                    (inst.normal_matrix * n).normalize_or_zero()
                } else {
                    ng
                };
                (p, ng, if ns == Vec3::ZERO { ng } else { ns })
            }
            HitKind::Sphere(i) => {
                let s = &self.desc.spheres[i as usize];
                let p = origin + dir * hit.t;
                let n = ((p - s.center) / s.radius).normalize_or_zero();
                // Project onto the surface to remove the error of o + t·d.
                (s.center + n * s.radius, n, n)
            }
            HitKind::Plane(i) => {
                let pl = &self.desc.planes[i as usize];
                let p = origin + dir * hit.t;
                // Project onto the plane.
                let p = p - pl.normal * (p - pl.point).dot(pl.normal);
                (p, pl.normal, pl.normal)
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
        }
    }
}

fn transform_box(b: Aabb, m: &Affine3A) -> Aabb {
    if b.is_empty() {
        return b;
    }
    let mut out = Aabb::EMPTY;
    for i in 0..8 {
        let c = Vec3::new(
            if i & 1 == 0 { b.min.x } else { b.max.x },
            if i & 2 == 0 { b.min.y } else { b.max.y },
            if i & 4 == 0 { b.min.z } else { b.max.z },
        );
        out = out.grow(m.transform_point3(c));
    }
    out
}
