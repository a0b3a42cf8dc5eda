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
    /// `background`: the linear RGB colour of rays that hit nothing.
    pub background: Vec3,
    /// `ambient`: the linear RGB colour of the ambient light.
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
    /// Both sides (the default).
    Two,
    /// Only the side the triangle's winding faces (counter-clockwise seen from
    /// the front; the geometric normal `(b−a)×(c−a)` points to the front).
    Front,
}

/// `<surface>`: the Phong material plus reflection and refraction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Surface {
    /// kd, the diffuse colour (linear RGB, each ≥ 0).
    pub diffuse: Vec3,
    /// ka, the ambient colour (linear RGB, each ≥ 0).
    pub ambient: Vec3,
    /// ks, the specular colour (linear RGB, each ≥ 0).
    pub specular: Vec3,
    /// n, the Phong exponent (≥ 0).
    pub shininess: f32,
    /// r, the share of mirror reflection, in `[0, 1]`.
    pub reflectivity: f32,
    /// α, in `[0, 1]`: below 1 the rest is refracted.
    pub opacity: f32,
    /// The index of refraction (> 0).
    pub ior: f32,
    /// Shade with the interpolated vertex normals (`true`) or the geometric
    /// normal.
    pub smooth: bool,
    /// Which sides rays can hit.
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
    /// Index into [`SceneDesc::textures`].
    pub texture: u32,
    /// What a coordinate outside `[0, 1]` looks up (`texture-wrap`).
    pub wrap: Wrap,
    /// `su sv` of `texture-scale` (or a `.mtl`'s `map_Kd -s`).
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
    /// `id`: unique among models, spheres and planes.
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
    /// `id`: unique among models, spheres and planes.
    pub id: String,
    /// In f64, like every position: the renderer moves the world next to
    /// each camera before going to f32 (see docs/numerics.md).
    pub center: DVec3,
    /// The radius (> 0), in scene units.
    pub radius: f32,
    /// Its one surface.
    pub surface: Surface,
}

/// `<plane>`: infinite and two-sided.
#[derive(Debug, Clone, PartialEq)]
pub struct Plane {
    /// `id`: unique among models, spheres and planes.
    pub id: String,
    /// A point on the plane (f64, like every position).
    pub point: DVec3,
    /// Normalised.
    pub normal: Vec3,
    /// Its one surface.
    pub surface: Surface,
}

/// `<light type>`: how a light's emission depends on direction. (A rect
/// light is no [`Light`]: the parser makes it an emitting model.)
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LightKind {
    /// The same in every direction.
    Point,
    /// `direction` normalised; cosines of the `inner` and `outer` half-angles.
    Spot {
        /// Where the spot points (unit length).
        direction: Vec3,
        /// The cosine of the full-intensity half-angle.
        cos_inner: f32,
        /// The cosine of the cut-off half-angle (at most `cos_inner`).
        cos_outer: f32,
    },
}

/// `<light>`.
#[derive(Debug, Clone, PartialEq)]
pub struct Light {
    /// Point or spot.
    pub kind: LightKind,
    /// Where the light is (f64, like every position).
    pub position: DVec3,
    /// The light's colour (linear RGB).
    pub color: Vec3,
    /// The factor on `color` (≥ 0).
    pub intensity: f32,
    /// Half the side of the square its shadow rays aim at; 0 is a point
    /// (hard shadows).
    pub radius: f32,
    /// `c l q` of E = color·intensity / (c + l·d + q·d²).
    pub attenuation: Vec3,
}

/// `<camera lens>`: the shape of a thin lens' aperture.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lens {
    /// A square of side `aperture` (the default).
    Square,
    /// A disk of diameter `aperture`.
    Disk,
}

/// `ao-distance`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AoDistance {
    /// Half the diagonal of the scene's bounding box.
    Auto,
    /// A given distance (> 0), in scene units.
    Fixed(f32),
}

/// Adaptive sampling (a Trevi extension of `<render>`, see docs/aisxml-extensions.md).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Adaptive {
    /// Target standard error of a pixel's mean, in linear units.
    pub threshold: f32,
    /// `min-samples`: camera samples every pixel takes before it may stop
    /// (≥ 1).
    pub min_samples: u32,
    /// `max-samples`: camera samples after which a pixel stops (≥
    /// `min_samples`).
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
    /// The frame's width in pixels, in `1..=`[`MAX_IMAGE_SIDE`].
    pub width: u32,
    /// The frame's height in pixels, in `1..=`[`MAX_IMAGE_SIDE`].
    pub height: u32,
    /// n: n×n camera samples per pixel, in `1..=`[`MAX_SUPERSAMPLE`].
    pub supersample: u32,
    /// Jitter samples inside their strata (else each at its stratum's
    /// centre).
    pub jitter: bool,
    /// The reflection and refraction depth, at most [`MAX_DEPTH`].
    pub max_depth: u32,
    /// Shadow rays per light per sample, in `1..=`[`MAX_RAY_SAMPLES`].
    pub shadow_samples: u32,
    /// Ambient-occlusion rays per sample (0: no AO), at most
    /// [`MAX_RAY_SAMPLES`].
    pub ao_samples: u32,
    /// s_max: how far an ambient-occlusion ray looks for a blocker.
    pub ao_distance: AoDistance,
    /// Diffuse-interreflection rays per sample at the first level (0:
    /// none), at most [`MAX_RAY_SAMPLES`].
    pub diffuse_samples: u32,
    /// Diffuse bounce levels, in `1..=`[`MAX_DEPTH`].
    pub diffuse_depth: u32,
    /// The random seed: every pixel's samples derive from it.
    pub seed: u64,
    /// Bundle-relative output path (`<camera id>.png` by default).
    pub output: String,
    /// `noise-threshold`, `min-samples`, `max-samples`: `None` when adaptive
    /// sampling is off (no `noise-threshold`).
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
    /// `aovs=` (a Trevi extension): the render passes written beside the
    /// beauty (none by default; see [`crate::aov`]).
    pub aovs: crate::aov::Aovs,
    /// `denoise=` (a Trevi extension): the frame is denoised after it is
    /// rendered (`trevi-submit --denoise`; docs/denoise.md). The renderer
    /// itself ignores it: the noisy frame is the same either way.
    pub denoise: bool,
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
    /// `id`: unique among cameras.
    pub id: String,
    /// The eye (f64, like every position).
    pub position: DVec3,
    /// Normalised view direction d.
    pub direction: Vec3,
    /// The image's up, normalised, not parallel to `direction`.
    pub up: Vec3,
    /// Horizontal field of view in degrees.
    pub fov: f32,
    /// The lens' size (≥ 0); 0 is a pinhole, > 0 gives depth of field.
    pub aperture: f32,
    /// Distance of the focal plane; always set (defaults resolved by the parser).
    pub focus: f32,
    /// The lens' shape.
    pub lens: Lens,
    /// Its `<render>` child: what to render and how.
    pub render: RenderSettings,
}

/// A whole scene, resolved and validated.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SceneDesc {
    /// `<settings>` (its defaults when the file has none).
    pub settings: Settings,
    /// The meshes models instance, each loaded once.
    pub meshes: Vec<Mesh>,
    /// The models, in document order (rect lights among them).
    pub models: Vec<Model>,
    /// The spheres, in document order.
    pub spheres: Vec<Sphere>,
    /// The planes, in document order.
    pub planes: Vec<Plane>,
    /// The point and spot lights, in document order.
    pub lights: Vec<Light>,
    /// The cameras, in document order: a camera index means this order.
    pub cameras: Vec<CameraDesc>,
    /// The decoded image textures surfaces refer to (each file once).
    pub textures: Vec<Texture>,
    /// Bundle-relative paths of every file the scene references, sorted.
    pub files: Vec<String>,
    /// The keyed channels (`<animate>`); the models, cameras and lights
    /// above hold their values at t = 0.
    pub animation: animation::Animation,
}
