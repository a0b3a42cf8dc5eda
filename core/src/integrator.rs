//! The lighting model of the spec: Whitted ray tracing (Phong local light,
//! shadows through translucent occluders, reflection then refraction blended
//! in the report's order) plus the Monte-Carlo effects (soft shadows,
//! ambient occlusion, diffuse interreflection, depth of field), the path
//! tracer, and the pixel estimate (n×n supersampling with a box filter, or
//! adaptive sampling).
//!
//! This file holds what they share (the [`Integrator`] of one camera, the
//! per-pixel [`PixelContext`], the stream tags) and dispatches a camera
//! sample to the integrator the camera asks for. The rest, one concept a file:
//!
//! | file | what |
//! |---|---|
//! | `integrator/pixel.rs` | the pixel loop: supersampling, adaptive sampling, cancellation, the ray queries |
//! | `integrator/whitted.rs` | the Whitted tree, `local`, direct light from point and spot lights |
//! | `integrator/effects.rs` | ambient occlusion, soft shadows, the diffuse gather, depth of field |
//! | `integrator/area.rs` | area lights in Whitted mode |
//! | `integrator/path.rs` | the path tracer (`integrator="path"`) |
//! | `integrator/sum.rs` | the sample sums every estimate averages with |
//! | `integrator/accumulate.rs` | a pixel's sums so far, to continue over more samples |
//! | `integrator/aov.rs` | the render passes (albedo, normal, depth) of a camera sample |
//!
//! "Model only what a scene requires": every effect is skipped outright when
//! its settings make it a no-op (no AO rays when the ambient term is zero or
//! `ao-samples` is 0, one shadow ray for a point light however many
//! `shadow-samples`, no shadow ray when N·L ≤ 0, no gather when m = 0).
//!
//! Random numbers come from [`PixelSampler`] streams named after the node of
//! the ray tree they are used at (see `sampling`), so a pixel is a pure
//! function of its coordinates.

mod accumulate;
mod aov;
mod area;
mod effects;
mod path;
mod pixel;
mod sum;
mod whitted;

pub use accumulate::PixelState;
pub use aov::MAX_AOV_CHANNELS;
pub use pixel::{samples_per_pixel, Cancelled, CANCEL_EVERY};
pub use sum::SUM_BLOCK;
pub use whitted::MIN_BRANCH_WEIGHT;

use effects::Link;
use sum::Sum;
use whitted::Pending;

use crate::camera::Camera;
use crate::sampling::{PixelSampler, SamplerKind};
use crate::scene::{CameraDesc, IntegratorKind};
use crate::world::{Hit, Scene, SurfacePoint, View};
use glam::Vec3;

// Stream tags (dimension pairs), shared by the integrator's files. Changing
// any of these changes every image.
const STREAM_PIXEL: u64 = 1;
const STREAM_LENS: u64 = 2;
const TAG_SHADOW: u64 = 3;
const TAG_AO: u64 = 4;
const TAG_GATHER: u64 = 5;
const TAG_GATHER_SHADOW: u64 = 6;
const TAG_REFLECT: u64 = 7;
const TAG_REFRACT: u64 = 8;

/// Options that are not part of the scene: how to sample.
#[derive(Debug, Clone, Copy, Default)]
pub struct RenderOptions {
    /// The point set of every pixel's sample streams (Sobol by default).
    pub sampler: SamplerKind,
}

/// Sees every ray the integrator traces, in the view's coordinates, just
/// before it is traced. The default `()` does nothing and compiles away
/// (the integrator is generic over it, not dynamic); `trevi-bench mix`
/// records a frame's rays with it to time the traversal alone on exactly the
/// rays a render traces.
pub trait RayObserver: Sync {
    /// A closest-hit ray (camera, reflection, refraction, AO, diffuse).
    #[inline(always)]
    fn closest(&self, _origin: Vec3, _dir: Vec3, _t_max: f32) {}
    /// A shadow ray (transmittance towards a light).
    #[inline(always)]
    fn shadow(&self, _origin: Vec3, _dir: Vec3, _t_max: f32) {}
}

impl RayObserver for () {}

/// Everything fixed for one camera's frame.
pub struct Integrator<'a, O: RayObserver = ()> {
    observer: &'a O,
    scene: &'a Scene,
    /// The world relative to the camera: every ray below is in these
    /// coordinates (see world.rs).
    view: View<'a>,
    camera: &'a Camera,
    desc: &'a CameraDesc,
    camera_hash: u64,
    s_max: f32,
    ambient: Vec3,
    background: Vec3,
    sampler: SamplerKind,
    /// The scene has textures: ray cones are tracked and hits looked up.
    textured: bool,
    /// A camera sample's ray cone spread angle (radians): a pixel's angle
    /// over the samples per side (see [`Integrator::apply_texture`]).
    spread: f32,
    /// Stops every pixel soon after it turns true (see `pixel.rs`).
    cancel: &'a std::sync::atomic::AtomicBool,
}

/// Per-pixel state: the sampler, the current camera sample, a ray count,
/// and the heap stacks the ray-tree walks reuse from sample to sample.
pub struct PixelContext {
    sampler: PixelSampler,
    sample: u32,
    /// Rays traced for this pixel so far, of every kind (camera, shadow,
    /// secondary).
    pub rays: u64,
    /// The cancellation flag was seen: every further ray misses.
    stopped: bool,
    /// Nodes of the reflection/refraction tree waiting for a child (see
    /// `Integrator::radiance`).
    pending: Vec<Pending>,
    /// Levels of a diffuse gather chain waiting for the level below (see
    /// `Integrator::gather_chain`).
    links: Vec<Link>,
}

impl<'a, O: RayObserver> Integrator<'a, O> {
    /// The integrator of camera `camera` of `scene`, showing every traced ray
    /// to `observer` first (`&()` shows them to no one).
    pub fn observed(
        scene: &'a Scene,
        camera: usize,
        options: RenderOptions,
        observer: &'a O,
    ) -> Self {
        Integrator {
            observer,
            scene,
            view: scene.view(camera),
            camera: &scene.cameras[camera],
            desc: &scene.desc.cameras[camera],
            camera_hash: scene.camera_hash(camera),
            s_max: scene.ao_distance(camera),
            ambient: scene.desc.settings.ambient,
            background: scene.desc.settings.background,
            sampler: options.sampler,
            textured: !scene.desc.textures.is_empty(),
            spread: pixel_spread(&scene.desc.cameras[camera]),
            cancel: &pixel::NEVER,
        }
    }

    /// In a textured scene: the ray cone's width at the hit `sp` of a ray
    /// from a cone of width `cone` and spread `spread` (both at the ray's
    /// origin; `dir` need not be unit), and the texture looked up with it.
    /// Reflected and refracted rays keep the camera's spread from the
    /// width at their origin (surfaces are taken as flat: curvature does
    /// not widen or narrow the cone).
    #[inline(always)]
    fn apply_texture(
        &self,
        sp: &mut SurfacePoint<'a>,
        hit: &Hit,
        dir: Vec3,
        cone: f32,
        spread: f32,
    ) {
        if self.textured {
            sp.cone = cone + spread * hit.t * dir.length();
            self.view.apply_texture(sp, hit, dir);
        }
    }

    /// The radiance of camera sample `s` at offset (`sx`, `sy`) of pixel
    /// (`x`, `y`), and with `aov` its render passes added to those sums
    /// (from the same ray, after the beauty: see `integrator/aov.rs`),
    /// only when `AOV`.
    #[allow(clippy::too_many_arguments)]
    fn camera_sample<const AOV: bool>(
        &self,
        ctx: &mut PixelContext,
        x: u32,
        y: u32,
        s: u32,
        sx: f32,
        sy: f32,
        aov: Option<&mut aov::AovSums>,
    ) -> Vec3 {
        ctx.sample = s;
        let lens = self.lens_sample(ctx, s);
        let ray = self.camera.ray(x, y, sx, sy, lens);
        let c = match self.desc.render.integrator {
            IntegratorKind::Whitted => self.radiance(ctx, ray.origin, ray.dir),
            IntegratorKind::Path => self.path_radiance(ctx, ray.origin, ray.dir),
        };
        if AOV {
            if let Some(sums) = aov {
                sums.add(self.aov_sample(ctx, ray.origin, ray.dir));
            }
        }
        c
    }
}

/// The angle (radians) one camera sample subtends: a pixel's width on the
/// view plane (1/width at distance s = ½/tan(fov/2), as in camera.rs) over
/// the samples per side (the supersample grid; 1 with adaptive sampling).
fn pixel_spread(desc: &CameraDesc) -> f32 {
    let r = &desc.render;
    let s = 0.5 / crate::math::tanf(desc.fov.to_radians() * 0.5);
    let per_side = if r.adaptive.is_some() {
        1
    } else {
        r.supersample.max(1)
    };
    1.0 / (s * r.width as f32 * per_side as f32)
}

/// Overflow guard: +∞ components become `f32::MAX`. Radiance can overflow
/// f32 (a light of intensity 10³⁸ with attenuation 10⁻³⁰ is a valid scene),
/// and an infinity turns into NaN as soon as a blend multiplies it by 0, so
/// every sum that feeds a blend is saturated. A NaN is left as it is (it
/// would be a bug, and the tests look for it). One comparison when finite.
#[inline(always)]
fn saturate(v: Vec3) -> Vec3 {
    if v.is_finite() {
        v
    } else {
        v.map(|c| if c == f32::INFINITY { f32::MAX } else { c })
    }
}
