//! The renderable scene: the description plus its two-level acceleration
//! structure, answering the two ray queries the integrator needs.
//!
//! Bottom level: one BVH per mesh over its triangles in object space, stored
//! once however many models use the mesh. Top level: one BVH over model
//! instances and spheres in world space; a ray entering an instance is moved
//! into the instance's object space. Infinite planes sit outside both trees
//! and are tested directly.
//!
//! Camera-relative coordinates: the description keeps positions in f64, and
//! each camera renders a [`View`] of the world shifted (in f64) so that the
//! camera sits at the origin; only then is everything rounded to f32. The
//! f32 precision that matters is then relative to the distance from the
//! camera, not from the world's origin, so a scene a million units out
//! renders like the same scene at the origin. The bottom-level BVHs are in
//! object space and shared by every view; a view holds its own top-level
//! BVH, instance transforms, sphere centres, plane points and light
//! positions (cameras at the same position share one view). The world-space
//! queries [`Scene::intersect`] and friends use a view whose origin is the
//! world's. See docs/numerics.md.

use crate::lights::area::AreaLights;
use crate::bundle::{Bundle, FileSource};
use crate::bvh::{simd, Bvh, MeshBvh, Visit};
use crate::camera::Camera;
use crate::error::SceneError;
use crate::geometry::{offset_from_surface, plane, sphere, triangle, Aabb};
use crate::sampling::{hash2, hash_str};
use crate::scene::{aisxml, AoDistance, SceneDesc, Sided, Surface};
use glam::{Affine3A, DMat4, DVec3, Mat3, Vec3};
use std::collections::HashMap;
use std::sync::OnceLock;

mod frame;

/// A model instance as the traversal sees it.
#[derive(Debug, Clone)]
struct Instance {
    mesh: u32,
    model: u32,
    /// Object space to the view's (camera-relative) space.
    to_world: Affine3A,
    to_object: Affine3A,
    normal_matrix: Mat3,
    /// Largest row sum of |linear part|: bounds how much the transform
    /// magnifies object-space coordinates (and so their rounding errors).
    lin_norm: f32,
    /// Largest |translation| component in the view's space.
    trans_mag: f32,
    /// The transform mirrors (negative determinant): world winding flips.
    mirrored: bool,
    /// Some triangle of this model uses `sided="front"`.
    any_front_only: bool,
}

/// The world relative to an eye (a camera position): everything instance-
/// or world-positioned, shifted by −eye in f64 and then rounded to f32. Only
/// shifted, not turned to the camera's axes, so cameras at one position
/// share it. A [`View`] renders with one.
struct WorldFromEye {
    eye: DVec3,
    instances: Vec<Instance>,
    /// Top-level primitives `0..instances.len()` are instances, the rest spheres.
    tlas: Bvh,
    sphere_centers: Vec<Vec3>,
    /// Per plane, its point nearest the eye (the smallest numbers that
    /// describe it, so the plane is as precise as the view allows).
    plane_points: Vec<Vec3>,
    light_positions: Vec<Vec3>,
    /// The emitting triangles and spheres (empty without `emission=`).
    area_lights: AreaLights,
    /// Bounds of the finite geometry (planes excluded).
    bounds: Aabb,
}

/// A view of the scene in coordinates relative to `eye()`: what a camera
/// renders with. Hits, surface points and ray origins are all in these
/// coordinates.
#[derive(Clone, Copy)]
pub struct View<'a> {
    scene: &'a Scene,
    world: &'a WorldFromEye,
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

/// A hit's place in the tie rule after its distance: (object, triangle).
/// Objects are numbered models first (document order), then spheres, then
/// planes; the triangle is its index in the mesh as loaded (0 for spheres
/// and planes).
type TieKey = (u32, u32);

/// The smallest f32 above `t` (for `t > 0` finite): `t' < above(t)` is
/// `t' <= t`. (`f32::next_up` needs Rust 1.86.)
#[inline]
fn above(t: f32) -> f32 {
    f32::from_bits(t.to_bits() + 1)
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
    /// The diffuse and ambient colours here: the surface's, times its
    /// texture once [`View::apply_texture`] has looked it up.
    pub kd: Vec3,
    pub ka: Vec3,
    /// The width of the ray cone at `p` (0 until the integrator sets it,
    /// which it does only in scenes with textures).
    pub cone: f32,
    /// Magnitude of the coordinates `p` was computed from (its rounding
    /// error is a few ULPs of this); scales the ray-origin offset.
    pub scale: f32,
}

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

/// A scene ready to render.
pub struct Scene {
    pub desc: SceneDesc,
    blas: Vec<MeshBvh>,
    /// Per mesh, the triangle's index as loaded for each triangle as stored
    /// (the build renumbers meshes): the tie rule ([`View::precedes`]) is
    /// stated in the numbering the scene file gives.
    loaded_index: Vec<Vec<u32>>,
    /// The world from each distinct camera position, built when first asked
    /// for: building every camera's up front would cost cameras × objects (a
    /// scene of 5,000 cameras and 5,000 spheres would build 25 million
    /// entries and 5,000 BVHs before rendering anything), while a render
    /// needs those of the cameras it renders.
    from_eyes: Vec<OnceLock<WorldFromEye>>,
    /// Per entry of `from_eyes`, the camera position it is seen from.
    eyes: Vec<DVec3>,
    /// Per camera, its index in `from_eyes`.
    camera_eye: Vec<usize>,
    /// The world from its own origin (for the world-space queries), built on
    /// first use unless a camera sits there.
    from_origin: OnceLock<WorldFromEye>,
    /// World-space bounds of the finite geometry (planes excluded).
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
    pub fn build(mut desc: SceneDesc) -> Scene {
        // Each mesh is renumbered in its BVH's leaf order (see
        // `MeshBvh::build`): a leaf's triangles are consecutive, and its
        // vertices are copied into the leaf. Per-triangle surfaces follow.
        let (blas, orders): (Vec<MeshBvh>, Vec<Vec<u32>>) =
            desc.meshes.iter_mut().map(MeshBvh::build).unzip();
        for model in &mut desc.models {
            if !model.triangle_surface.is_empty() {
                let old = std::mem::take(&mut model.triangle_surface);
                model.triangle_surface = orders[model.mesh]
                    .iter()
                    .map(|&t| old[t as usize])
                    .collect();
            }
        }
        let has_translucency = desc
            .models
            .iter()
            .flat_map(|m| m.surfaces.iter())
            .chain(desc.spheres.iter().map(|s| &s.surface))
            .chain(desc.planes.iter().map(|p| &p.surface))
            .any(|s| s.opacity < 1.0);
        let mut scene = Scene {
            desc,
            blas,
            loaded_index: orders,
            from_eyes: Vec::new(),
            eyes: Vec::new(),
            camera_eye: Vec::new(),
            from_origin: OnceLock::new(),
            bounds: Aabb::EMPTY,
            has_translucency,
            cameras: Vec::new(),
            camera_hashes: Vec::new(),
        };
        scene.place(None);
        scene
    }

    /// Computes everything that follows where the models, cameras and
    /// lights are (all but the meshes and their BVHs): the distinct camera
    /// positions and their (not yet built) views, the bounds, the cameras'
    /// frames and sample hashes. `frame` is the sequence's frame number,
    /// which enters every camera's hash (`None` for a still: the hash of a
    /// scene without frames is what it always was).
    fn place(&mut self, frame: Option<u32>) {
        let desc = &self.desc;
        let mut eyes: Vec<DVec3> = Vec::new();
        let mut index_of_eye: HashMap<[u64; 3], usize> = HashMap::new();
        let mut camera_eye = Vec::with_capacity(desc.cameras.len());
        for c in &desc.cameras {
            let i = *index_of_eye.entry(eye_key(c.position)).or_insert_with(|| {
                eyes.push(c.position);
                eyes.len() - 1
            });
            camera_eye.push(i);
        }
        self.from_eyes = eyes.iter().map(|_| OnceLock::new()).collect();
        self.from_origin = OnceLock::new();
        let mut bounds = Aabb::EMPTY;
        for model in &desc.models {
            let b = world_box(self.blas[model.mesh].bounds(), &model.transform);
            bounds = bounds.union(b);
        }
        for s in &desc.spheres {
            let r = DVec3::splat(s.radius as f64);
            bounds = bounds.union(Aabb {
                min: (s.center - r).as_vec3(),
                max: (s.center + r).as_vec3(),
            });
        }
        self.bounds = bounds;
        self.eyes = eyes;
        self.camera_eye = camera_eye;
        self.cameras = desc.cameras.iter().map(Camera::new).collect();
        self.camera_hashes = desc
            .cameras
            .iter()
            .map(|c| match frame {
                None => hash_str(&c.id),
                Some(f) => hash2(hash_str(&c.id), u64::from(f)),
            })
            .collect();
    }

    /// The view camera `camera` renders with: the world relative to the
    /// camera's position.
    pub fn view(&self, camera: usize) -> View<'_> {
        View {
            scene: self,
            world: self.world_from_eye(self.camera_eye[camera]),
        }
    }

    /// Entry `i` of `from_eyes`, built on first use.
    fn world_from_eye(&self, i: usize) -> &WorldFromEye {
        self.from_eyes[i].get_or_init(|| build_world_from_eye(&self.desc, &self.blas, self.eyes[i]))
    }

    /// How many camera views have been built so far.
    pub fn built_views(&self) -> usize {
        self.from_eyes.iter().filter(|w| w.get().is_some()).count()
            + usize::from(self.from_origin.get().is_some())
    }

    /// The view in world coordinates (origin at the world's origin).
    pub fn world_view(&self) -> View<'_> {
        let world = match self.eyes.iter().position(|&e| e == DVec3::ZERO) {
            Some(i) => self.world_from_eye(i),
            None => self
                .from_origin
                .get_or_init(|| build_world_from_eye(&self.desc, &self.blas, DVec3::ZERO)),
        };
        View { scene: self, world }
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
                // Measured in the camera's view: the same box, without the
                // rounding of world coordinates far from the origin.
                let world = self.world_from_eye(self.camera_eye[camera]);
                let mut b = world.bounds;
                if b.diagonal() <= 0.0 {
                    for &l in &world.light_positions {
                        b = b.grow(l);
                    }
                    for c in &self.desc.cameras {
                        b = b.grow((c.position - world.eye).as_vec3());
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

    /// The nearest hit along the world-space ray within `(0, t_max)`
    /// (see [`View::intersect`]; this is the world view's).
    pub fn intersect(&self, origin: Vec3, dir: Vec3, t_max: f32) -> Option<Hit> {
        self.world_view().intersect(origin, dir, t_max)
    }

    /// [`View::transmittance`] in world space.
    pub fn transmittance(&self, origin: Vec3, dir: Vec3, t_max: f32) -> f32 {
        self.world_view().transmittance(origin, dir, t_max)
    }

    /// [`View::surface_point`] in world space, for a hit from [`Scene::intersect`].
    pub fn surface_point(&self, origin: Vec3, dir: Vec3, hit: &Hit) -> SurfacePoint<'_> {
        self.world_view().surface_point(origin, dir, hit)
    }
}

impl<'a> View<'a> {
    /// Where this view's origin is in the world.
    pub fn eye(&self) -> DVec3 {
        self.world.eye
    }

    /// Light `i`'s position in this view's coordinates.
    #[inline]
    pub fn light_position(&self, i: usize) -> Vec3 {
        self.world.light_positions[i]
    }

    /// The emitting triangles and spheres in this view's coordinates.
    #[inline]
    pub fn area_lights(&self) -> &'a AreaLights {
        &self.world.area_lights
    }

    fn surface_of(&self, kind: HitKind) -> &'a Surface {
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

    /// Calls `f` for hits along `origin + t·dir`, `t ∈ (0, t_max)`, nearest
    /// boxes first (`ORDERED`; else in the trees' slot order, for visitors
    /// whose answer does not depend on the order), honouring
    /// `sided="front"`. `f` decides, as in [`Bvh::traverse`], whether the
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
    /// the same place) the smaller [`TieKey`] wins: the earlier model
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

/// The texture's level of detail for a ray cone of width `width` meeting a
/// triangle at cosine `cos` (Akenine-Möller et al., "Texture Level of
/// Detail Strategies for Real-Time Ray Tracing", Ray Tracing Gems, 2019,
/// ch. 20): λ = ½·log₂(texel area / world area) + log₂(width / cos), the
/// areas being the triangle's in texels and in world units. A degenerate
/// triangle or a grazing ray gets level 0 or the coarsest (the lookup
/// clamps). The logarithm is [`log2`], plain arithmetic, so that every
/// worker computes the same level.
pub fn texture_lod(texel_area: f32, world_area: f32, width: f32, cos: f32) -> f32 {
    if !(texel_area > 0.0 && world_area > 0.0 && width > 0.0) {
        return 0.0;
    }
    let cos = cos.max(1e-6);
    0.5 * log2(texel_area / world_area) + log2(width / cos)
}

/// log₂ of a positive finite `x` to within 0.008 from its exponent and a
/// cubic in the mantissa (no libm: its `log2f` may differ between the
/// machines of a farm in the last bit). Non-positive or non-finite `x` give
/// ∓ a large number.
pub fn log2(x: f32) -> f32 {
    if !(x > 0.0) {
        return -1e30;
    }
    if !x.is_finite() {
        return 1e30;
    }
    // Subnormals: scale into the normal range first.
    let (x, bias) = if x < f32::MIN_POSITIVE {
        (x * 16_777_216.0, 24.0)
    } else {
        (x, 0.0)
    };
    let bits = x.to_bits();
    let e = ((bits >> 23) & 0xff) as i32 - 127;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000) - 1.0;
    // log₂(1 + m) on [0, 1): a cubic through 0 and 1 fitted to it.
    let p = m * (std::f32::consts::LOG2_E + m * (-0.680_347 + m * 0.237_652));
    e as f32 + p - bias
}

/// The world seen from `eye`: instance transforms composed with the shift
/// by −eye in f64 before rounding, and every position likewise.
fn build_world_from_eye(desc: &SceneDesc, blas: &[MeshBvh], eye: DVec3) -> WorldFromEye {
    let shift = DMat4::from_translation(-eye);
    let instances: Vec<Instance> = desc
        .models
        .iter()
        .enumerate()
        .map(|(i, model)| {
            let m = shift * model.transform;
            let lin = model.transform.inverse().transpose().as_mat4();
            let l = Mat3::from_mat4(m.as_mat4());
            let lin_norm = (0..3)
                .map(|r| l.row(r).abs().element_sum())
                .fold(0.0f32, f32::max);
            Instance {
                mesh: model.mesh as u32,
                model: i as u32,
                to_world: Affine3A::from_mat4(m.as_mat4()),
                to_object: Affine3A::from_mat4(m.inverse().as_mat4()),
                normal_matrix: Mat3::from_mat4(lin),
                lin_norm,
                trans_mag: m.w_axis.truncate().abs().max_element() as f32,
                mirrored: model.transform.determinant() < 0.0,
                any_front_only: model.surfaces.iter().any(|s| s.sided == Sided::Front),
            }
        })
        .collect();
    let mut boxes: Vec<Aabb> = desc
        .models
        .iter()
        .map(|model| world_box(blas[model.mesh].bounds(), &(shift * model.transform)))
        .collect();
    let sphere_centers: Vec<Vec3> = desc
        .spheres
        .iter()
        .map(|s| (s.center - eye).as_vec3())
        .collect();
    boxes.extend(desc.spheres.iter().zip(&sphere_centers).map(|(s, &c)| {
        let r = Vec3::splat(s.radius);
        pad(Aabb {
            min: c - r,
            max: c + r,
        })
    }));
    let tlas = Bvh::build(&boxes, 2);
    let bounds = boxes.iter().fold(Aabb::EMPTY, |a, &b| a.union(b));
    let plane_points = desc
        .planes
        .iter()
        .map(|pl| {
            let n = pl.normal.as_dvec3();
            let n = n / n.length();
            (n * (pl.point - eye).dot(n)).as_vec3()
        })
        .collect();
    let light_positions = desc
        .lights
        .iter()
        .map(|l| (l.position - eye).as_vec3())
        .collect();
    let area_lights = build_area_lights(desc, &instances, &sphere_centers);
    WorldFromEye {
        eye,
        instances,
        tlas,
        sphere_centers,
        plane_points,
        light_positions,
        area_lights,
        bounds,
    }
}

/// Every triangle and sphere whose surface emits, in the view's coordinates.
fn build_area_lights(
    desc: &SceneDesc,
    instances: &[Instance],
    sphere_centers: &[Vec3],
) -> AreaLights {
    let mut lights = AreaLights::new();
    for inst in instances {
        let model = &desc.models[inst.model as usize];
        if model.surfaces.iter().all(|s| s.emission == Vec3::ZERO) {
            continue;
        }
        let mesh = &desc.meshes[inst.mesh as usize];
        for (t, tri) in mesh.triangles.iter().enumerate() {
            let s = if model.triangle_surface.is_empty() {
                0
            } else {
                model.triangle_surface[t] as usize
            };
            let surf = &model.surfaces[s];
            if surf.emission != Vec3::ZERO {
                let v = tri.map(|i| inst.to_world.transform_point3(mesh.positions[i as usize]));
                lights.triangle(v, surf.emission, surf.sided == Sided::Two);
            }
        }
    }
    for (s, &c) in desc.spheres.iter().zip(sphere_centers) {
        if s.surface.emission != Vec3::ZERO {
            lights.sphere(
                c,
                s.radius,
                s.surface.emission,
                s.surface.sided == Sided::Two,
            );
        }
    }
    lights
}

/// A camera position as a hash key: positions equal as numbers (0 and −0
/// included) give the same key.
fn eye_key(p: DVec3) -> [u64; 3] {
    (p + DVec3::ZERO).to_array().map(f64::to_bits)
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

/// [`unit`] for the normals of a hit (`View::surface_point`, once or twice a
/// hit): `v · (1/|v|)`, one square root and one division, when `|v|²` is a
/// normal f32 far from overflow and underflow (every normal of an ordinary
/// scene); otherwise [`unit`]'s scaled form, which is right at every
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

/// Grows a box by a few ULPs of its coordinates, so that rounding its
/// corners (or the primitive inside) to f32 cannot leave a sliver outside.
fn pad(b: Aabb) -> Aabb {
    if b.is_empty() {
        return b;
    }
    let e = b.min.abs().max(b.max.abs()) * 4.0 * f32::EPSILON;
    Aabb {
        min: b.min - e,
        max: b.max + e,
    }
}

/// The box around object-space box `b` under `m`, computed in f64 and
/// rounded outwards to f32.
fn world_box(b: Aabb, m: &DMat4) -> Aabb {
    if b.is_empty() {
        return b;
    }
    let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for i in 0..8 {
        let c = DVec3::new(
            if i & 1 == 0 { b.min.x } else { b.max.x } as f64,
            if i & 2 == 0 { b.min.y } else { b.max.y } as f64,
            if i & 4 == 0 { b.min.z } else { b.max.z } as f64,
        );
        let p = m.transform_point3(c);
        lo = lo.min(p);
        hi = hi.max(p);
    }
    pad(Aabb {
        min: lo.as_vec3(),
        max: hi.as_vec3(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    /// Building every camera's view up front would cost cameras × objects
    /// (work quadratic in the size of the scene file): a view is built when
    /// a camera first renders, and cameras at one position share it.
    #[test]
    fn camera_views_are_built_for_the_cameras_rendered_only() {
        let n = 300;
        let mut xml = String::from("<scene version=\"1\">\n");
        for i in 0..n {
            xml.push_str(&format!(
                "<sphere id=\"s{i}\" center=\"{i} 0 -10\" radius=\"0.4\"/>\n\
                 <camera id=\"c{i}\" position=\"{i} 0 0\" direction=\"0 0 -1\" fov=\"10\">\
                 <render width=\"1\" height=\"1\"/></camera>\n"
            ));
        }
        // Two cameras at one position share a view.
        xml.push_str(
            "<camera id=\"twin\" position=\"7 0 0\" direction=\"0 0 -1\" fov=\"10\">\
             <render width=\"1\" height=\"1\"/></camera>\n</scene>\n",
        );
        let mut files = BTreeMap::new();
        files.insert("s.xml".to_string(), xml.into_bytes());
        let bundle = Bundle {
            scene: "s.xml".into(),
            files,
        };
        let scene = Scene::from_bundle(&bundle).unwrap();
        assert_eq!(scene.built_views(), 0);
        let hit = |c: usize| {
            let v = scene.view(c);
            v.intersect(Vec3::ZERO, -Vec3::Z, f32::INFINITY)
                .map(|h| h.kind)
        };
        assert_eq!(hit(7), Some(HitKind::Sphere(7)));
        assert_eq!(scene.built_views(), 1);
        assert_eq!(hit(n), Some(HitKind::Sphere(7)));
        assert_eq!(scene.built_views(), 1);
        assert_eq!(hit(250), Some(HitKind::Sphere(250)));
        assert_eq!(scene.built_views(), 2);
    }

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
