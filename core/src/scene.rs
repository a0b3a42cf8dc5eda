//! The scene description: what an AISXML file says, resolved and validated.
//!
//! Data flows `scene file → parse (aisxml) → SceneDesc → build
//! ([`crate::Scene::build`], world.rs) → Scene`, with every file read through
//! a [`source::FileSource`]. A [`SceneDesc`] is plain data with every
//! reference resolved (meshes loaded, surfaces assigned to triangles,
//! defaults filled in); [`crate::Scene`] adds the acceleration structures
//! and precomputed camera frames.

pub mod aisxml;
pub mod animation;
pub mod estimate;
pub mod memory;
pub mod source;

use crate::mesh::Mesh;
use crate::texture::{Texture, Wrap};
use glam::{DMat4, DVec3, Vec2, Vec3};

/// `<settings>`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    pub background: Vec3,
    pub ambient: Vec3,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            background: Vec3::ZERO,
            ambient: Vec3::ZERO,
        }
    }
}

/// Which sides of a surface rays can hit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sided {
    Two,
    /// Only the side the triangle's winding faces (counter-clockwise seen from
    /// the front; the geometric normal `(b−a)×(c−a)` points to the front).
    Front,
}

/// `<surface>`: the Phong material plus reflection and refraction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Surface {
    pub diffuse: Vec3,
    pub ambient: Vec3,
    pub specular: Vec3,
    pub shininess: f32,
    pub reflectivity: f32,
    pub opacity: f32,
    pub ior: f32,
    pub smooth: bool,
    pub sided: Sided,
    /// `diffuse-texture`: multiplies `diffuse` (and `ambient`) at each hit.
    pub texture: Option<TextureMap>,
    /// Emitted radiance (Trevi's area lights, `emission=`), on the sides the
    /// surface can be hit from; zero for a surface that does not glow.
    pub emission: Vec3,
}

/// A surface's image texture: which of [`SceneDesc::textures`], how it
/// wraps, and the factors `uv` is multiplied by before the lookup.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TextureMap {
    pub texture: u32,
    pub wrap: Wrap,
    pub scale: Vec2,
}

impl Default for Surface {
    /// The spec's defaults (`ambient` defaults to the diffuse color).
    fn default() -> Self {
        let d = Vec3::splat(0.8);
        Surface {
            diffuse: d,
            ambient: d,
            specular: Vec3::ZERO,
            shininess: 32.0,
            reflectivity: 0.0,
            opacity: 1.0,
            ior: 1.5,
            smooth: true,
            sided: Sided::Two,
            texture: None,
            emission: Vec3::ZERO,
        }
    }
}

/// `<model>`: an instance of a mesh.
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    pub id: String,
    /// Index into [`SceneDesc::meshes`].
    pub mesh: usize,
    /// Object to world, composed in document order (first child applied first).
    /// When the parser recentred a mesh that lies far from its origin (see
    /// `aisxml/mesh.rs`), the recentring translation is folded in on the right.
    pub transform: DMat4,
    /// The surfaces of this model; `surfaces[0]` is the default one.
    pub surfaces: Vec<Surface>,
    /// Per triangle, an index into `surfaces`. Empty when the model has only
    /// its default surface (every triangle uses `surfaces[0]`).
    pub triangle_surface: Vec<u16>,
}

/// `<sphere>`.
#[derive(Debug, Clone, PartialEq)]
pub struct Sphere {
    pub id: String,
    /// In f64, like every position: the renderer moves the world next to
    /// each camera before going to f32 (see docs/numerics.md).
    pub center: DVec3,
    pub radius: f32,
    pub surface: Surface,
}

/// `<plane>`: infinite and two-sided.
#[derive(Debug, Clone, PartialEq)]
pub struct Plane {
    pub id: String,
    pub point: DVec3,
    /// Normalised.
    pub normal: Vec3,
    pub surface: Surface,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LightKind {
    Point,
    /// `direction` normalised; cosines of the `inner` and `outer` half-angles.
    Spot {
        direction: Vec3,
        cos_inner: f32,
        cos_outer: f32,
    },
}

/// `<light>`.
#[derive(Debug, Clone, PartialEq)]
pub struct Light {
    pub kind: LightKind,
    pub position: DVec3,
    pub color: Vec3,
    pub intensity: f32,
    pub radius: f32,
    /// `c l q` of E = color·intensity / (c + l·d + q·d²).
    pub attenuation: Vec3,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lens {
    Square,
    Disk,
}

/// `ao-distance`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AoDistance {
    /// Half the diagonal of the scene's bounding box.
    Auto,
    Fixed(f32),
}

/// Adaptive sampling (a Trevi extension of `<render>`, see docs/aisxml-extensions.md).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Adaptive {
    /// Target standard error of a pixel's mean, in linear units.
    pub threshold: f32,
    pub min_samples: u32,
    pub max_samples: u32,
}

/// Largest `width` and `height` of a `<render>`. Pixel coordinates reach the
/// camera as `f32`; up to 2¹⁶ a sample's position inside its pixel keeps 7
/// bits (1/128 of a pixel). Far beyond any frame the farm accepts by
/// default (16384² at supersample 8).
pub const MAX_IMAGE_SIDE: u32 = 1 << 16;

/// Largest `supersample` n: the n² camera samples of a pixel are counted
/// (and indexed) in a `u32`, and 65535² < 2³² ≤ 65536².
pub const MAX_SUPERSAMPLE: u32 = 65_535;

/// Largest `shadow-samples`, `ao-samples` and `diffuse-samples`. With at most
/// 2³² camera samples per pixel, every sample index the integrator forms
/// (camera sample × gather direction × shadow ray) stays below 2⁶⁴.
pub const MAX_RAY_SAMPLES: u32 = 65_536;

/// Largest `max-depth` and `diffuse-depth`. The ray-tree walks keep one
/// small record per level on the heap (not the thread's stack), so this
/// bounds that memory per rendering thread (under a megabyte), not
/// correctness.
pub const MAX_DEPTH: u32 = 10_000;

/// Largest `min-samples` and `max-samples` (adaptive sampling): a pixel's
/// samples are counted in a `u32`.
pub const MAX_ADAPTIVE_SAMPLES: u32 = u32::MAX;

/// Most vertices and most triangles in one mesh: both are indexed with `u32`
/// (and `u32::MAX` is kept free as a marker).
pub const MAX_MESH_ELEMENTS: usize = u32::MAX as usize - 1;

/// Most models and spheres in a scene together (the top-level BVH indexes
/// them with `u32`).
pub const MAX_OBJECTS: usize = u32::MAX as usize - 1;

/// `<render>`.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderSettings {
    pub width: u32,
    pub height: u32,
    pub supersample: u32,
    pub jitter: bool,
    pub max_depth: u32,
    pub shadow_samples: u32,
    pub ao_samples: u32,
    pub ao_distance: AoDistance,
    pub diffuse_samples: u32,
    pub diffuse_depth: u32,
    pub seed: u64,
    /// Bundle-relative output path (`<camera id>.png` by default).
    pub output: String,
    pub adaptive: Option<Adaptive>,
    /// `integrator=`: the spec's Whitted model or Trevi's path tracer.
    pub integrator: IntegratorKind,
    /// `max-bounces=`: scattering events along a path (path mode only).
    pub max_bounces: u32,
    /// `frames=` (a Trevi extension): the frames a sequence renders; `None`
    /// for a still.
    pub frames: Option<animation::Frames>,
    /// `fps=`: frame `n` is the scene at `n / fps` seconds.
    pub fps: f64,
}

/// `<render integrator>`: which light transport a camera renders with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum IntegratorKind {
    /// The spec's lighting model (the default).
    #[default]
    Whitted,
    /// Physically based path tracing (docs/aisxml-extensions.md).
    Path,
}

/// The default of `max-bounces`.
pub const DEFAULT_MAX_BOUNCES: u32 = 16;

/// `<camera>` with its `<render>`.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraDesc {
    pub id: String,
    pub position: DVec3,
    /// Normalised view direction d.
    pub direction: Vec3,
    pub up: Vec3,
    /// Horizontal field of view in degrees.
    pub fov: f32,
    pub aperture: f32,
    /// Distance of the focal plane; always set (defaults resolved by the parser).
    pub focus: f32,
    pub lens: Lens,
    pub render: RenderSettings,
}

/// A whole scene, resolved and validated.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SceneDesc {
    pub settings: Settings,
    pub meshes: Vec<Mesh>,
    pub models: Vec<Model>,
    pub spheres: Vec<Sphere>,
    pub planes: Vec<Plane>,
    pub lights: Vec<Light>,
    pub cameras: Vec<CameraDesc>,
    /// The decoded image textures surfaces refer to (each file once).
    pub textures: Vec<Texture>,
    /// Bundle-relative paths of every file the scene references, sorted.
    pub files: Vec<String>,
    /// The keyed channels (`<animate>`); the models, cameras and lights
    /// above hold their values at t = 0.
    pub animation: animation::Animation,
}
