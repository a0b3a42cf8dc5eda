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
//!
//! This file holds the types; their code, one concept a file:
//!
//! | file | what |
//! |---|---|
//! | `world/build.rs` | the build step: BVHs over the meshes, where the cameras are (no parsing: see `bundle.rs`) |
//! | `world/eye.rs` | the world from one camera position: instances, top-level tree, lights, shifted and rounded |
//! | `world/query.rs` | the ray queries: closest hit with its tie rule, transmittance |
//! | `world/surface.rs` | surface points: position, normals, texture at a hit |
//! | `world/texture_lod.rs` | the texture level of detail of a ray cone |
//! | `world/frame.rs` | a sequence's frames from one built scene |

use crate::bvh::{Bvh, MeshBvh};
use crate::camera::Camera;
use crate::geometry::Aabb;
use crate::lights::area::AreaLights;
use crate::scene::{AoDistance, SceneDesc, Surface};
use glam::{Affine3A, DVec3, Mat3, Vec3};
use std::sync::OnceLock;

mod build;
mod eye;
mod frame;
mod query;
mod surface;
mod texture_lod;

pub use texture_lod::{log2, texture_lod};

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
    /// A triangle of a model.
    Triangle {
        /// The model instance, an index into the view's instances (each
        /// names its model in [`SceneDesc::models`]).
        instance: u32,
        /// The triangle's index in its mesh as stored (the build may have
        /// renumbered the mesh's triangles).
        triangle: u32,
        /// The weights of the triangle's three vertices at the hit.
        bary: [f32; 3],
    },
    /// A sphere: its index in [`SceneDesc::spheres`].
    Sphere(u32),
    /// A plane: its index in [`SceneDesc::planes`].
    Plane(u32),
}

/// The closest (or any) hit of a ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// The ray parameter of the hit: the point is `origin + t·dir`.
    pub t: f32,
    /// What was hit.
    pub kind: HitKind,
    /// The ray met the front (the side the winding or the normal faces).
    pub front: bool,
}

/// A hit's place in the tie rule after its distance: (object, triangle).
/// Objects are numbered models first (document order), then spheres, then
/// planes; the triangle is its index in the mesh as loaded (0 for spheres
/// and planes).
type TieKey = (u32, u32);

/// The local geometry at a hit.
#[derive(Debug, Clone, Copy)]
pub struct SurfacePoint<'a> {
    /// The hit point, in the view's coordinates.
    pub p: Vec3,
    /// Unit geometric normal, on the side the ray came from.
    pub ng: Vec3,
    /// Unit shading normal, on the side the ray came from.
    pub ns: Vec3,
    /// The ray met the front (see [`Hit::front`]).
    pub front: bool,
    /// The material hit.
    pub surface: &'a Surface,
    /// The diffuse and ambient colours here: the surface's, times its
    /// texture once [`View::apply_texture`] has looked it up.
    pub kd: Vec3,
    /// The ambient colour here, textured like `kd`.
    pub ka: Vec3,
    /// The width of the ray cone at `p` (0 until the integrator sets it,
    /// which it does only in scenes with textures).
    pub cone: f32,
    /// Magnitude of the coordinates `p` was computed from (its rounding
    /// error is a few ULPs of this); scales the ray-origin offset.
    pub scale: f32,
}

/// A scene ready to render.
pub struct Scene {
    /// The description it was built from.
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
    /// Per camera of [`SceneDesc::cameras`], in order, its primary-ray setup.
    pub cameras: Vec<Camera>,
    camera_hashes: Vec<u64>,
}

impl Scene {
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
        self.from_eyes[i]
            .get_or_init(|| eye::build_world_from_eye(&self.desc, &self.blas, self.eyes[i]))
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
                .get_or_init(|| eye::build_world_from_eye(&self.desc, &self.blas, DVec3::ZERO)),
        };
        View { scene: self, world }
    }

    /// The index of the camera whose id is `id`.
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
}
