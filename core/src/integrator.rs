//! The lighting model of the spec: Whitted ray tracing (Phong local light,
//! shadows through translucent occluders, reflection then refraction blended
//! in the report's order) plus the Monte-Carlo effects (soft shadows,
//! ambient occlusion, diffuse interreflection) and the pixel estimate
//! (n×n supersampling with a box filter, or adaptive sampling).
//!
//! "Model only what a scene requires": every effect is skipped outright when
//! its settings make it a no-op (no AO rays when the ambient term is zero or
//! `ao-samples` is 0, one shadow ray for a point light however many
//! `shadow-samples`, no shadow ray when N·L ≤ 0, no gather when m = 0).
//!
//! Random numbers come from [`PixelSampler`] streams named after the node of
//! the ray tree they are used at (see `sampling`), so a pixel is a pure
//! function of its coordinates.

mod area;
mod path;
mod pixel;

pub use pixel::{Cancelled, CANCEL_EVERY};

use crate::camera::Camera;
use crate::geometry::optics::{reflect, refract};
use crate::lights::{incident, jittered_position};
use crate::sampling::{cosine_hemisphere, hash2, PixelSampler, SamplerKind};
use crate::scene::{CameraDesc, IntegratorKind};
use crate::world::{Hit, Scene, SurfacePoint, View};
use glam::Vec3;

// Stream tags (dimension pairs). Changing any of these changes every image.
const STREAM_PIXEL: u64 = 1;
const STREAM_LENS: u64 = 2;
const TAG_SHADOW: u64 = 3;
const TAG_AO: u64 = 4;
const TAG_GATHER: u64 = 5;
const TAG_GATHER_SHADOW: u64 = 6;
const TAG_REFLECT: u64 = 7;
const TAG_REFRACT: u64 = 8;

/// Reflection and refraction branches contributing less than this to the
/// pixel are not traced (see `Integrator::radiance`).
pub const MIN_BRANCH_WEIGHT: f32 = 1e-4;

/// Options that are not part of the scene: how to sample.
#[derive(Debug, Clone, Copy, Default)]
pub struct RenderOptions {
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

/// How many samples `Sum` adds in `f32` before moving them to its `f64`
/// total.
pub const SUM_BLOCK: u32 = 1024;

/// A sum of many `f32` samples that stays right however many there are.
///
/// Summed in plain `f32`, 8000² camera samples stall (the running sum grows
/// until each new sample is below half its ULP: 140 where 188 is right),
/// 65536² overflow the count into NaN. Here samples are added in `f32`
/// within blocks of [`SUM_BLOCK`] and the blocks in `f64`, so the relative
/// error is at most about `SUM_BLOCK`·2⁻²⁴ ≈ 6·10⁻⁵ whatever the count.
/// Up to `SUM_BLOCK` samples the mean is bit for bit the plain `f32` sum
/// divided in `f32` as before (adding the block to a zero `f64` is exact,
/// and an `f32` quotient computed in `f64` and rounded is the correctly
/// rounded `f32` quotient), so images with ordinary sample counts keep
/// their bytes.
#[derive(Clone, Copy, Default)]
struct Sum<T: Wide> {
    block: T,
    in_block: u32,
    total: T::Wide,
}

/// `f32` and `Vec3`, with their `f64` counterparts.
trait Wide: Copy + Default + std::ops::AddAssign {
    type Wide: Copy + Default + std::ops::AddAssign;
    fn widen(self) -> Self::Wide;
    /// `(total + self) / n`, rounded back.
    fn mean(self, total: Self::Wide, n: u64) -> Self;
}

impl Wide for f32 {
    type Wide = f64;
    #[inline]
    fn widen(self) -> f64 {
        f64::from(self)
    }
    #[inline]
    fn mean(self, total: f64, n: u64) -> f32 {
        ((total + f64::from(self)) / n as f64) as f32
    }
}

impl Wide for Vec3 {
    type Wide = glam::DVec3;
    #[inline]
    fn widen(self) -> glam::DVec3 {
        self.as_dvec3()
    }
    #[inline]
    fn mean(self, total: glam::DVec3, n: u64) -> Vec3 {
        ((total + self.as_dvec3()) / n as f64).as_vec3()
    }
}

impl<T: Wide> Sum<T> {
    #[inline]
    fn add(&mut self, v: T) {
        self.block += v;
        self.in_block += 1;
        if self.in_block == SUM_BLOCK {
            self.total += self.block.widen();
            self.block = T::default();
            self.in_block = 0;
        }
    }

    /// The sum divided by `n` (the number of samples, counting those that
    /// added nothing).
    #[inline]
    fn mean(&self, n: u64) -> T {
        self.block.mean(self.total, n)
    }
}

/// A ray of the reflection/refraction tree still to be traced.
#[derive(Clone, Copy)]
struct Branch {
    origin: Vec3,
    dir: Vec3,
    /// The node's name, for its sample streams.
    node: u64,
    /// The factor its colour gets in the pixel.
    weight: f32,
    /// The width of its ray cone at `origin` (textured scenes only).
    cone: f32,
}

/// Which child of a [`Pending`] node is being traced.
#[derive(Clone, Copy)]
enum Child {
    Refracted,
    Reflected,
}

/// A node of the reflection/refraction tree whose colour waits for a child.
#[derive(Clone, Copy)]
struct Pending {
    /// The colour so far: local, then blended with the refracted colour.
    c: Vec3,
    opacity: f32,
    reflectivity: f32,
    depth: u32,
    /// The reflected ray, when it is still to be traced after the refracted one.
    reflect: Option<Branch>,
    awaiting: Child,
}

/// The sample streams of one gather level, named once per level rather than
/// once per direction: the directions' stream `hash(stream, level)` and the
/// stream the shadow rays at the hits take theirs from,
/// `hash(hash(stream, TAG_GATHER_SHADOW), level)`.
struct GatherStreams {
    level: u32,
    directions: crate::sampling::Stream,
    shadows: u64,
}

impl GatherStreams {
    #[inline]
    fn new(ctx: &PixelContext, stream: u64, level: u32) -> Self {
        GatherStreams {
            level,
            directions: ctx.sampler.stream(hash2(stream, level as u64)),
            shadows: hash2(hash2(stream, TAG_GATHER_SHADOW), level as u64),
        }
    }
}

/// One level of a diffuse gather chain below the first: D(q) without G'(q)
/// yet, kd_q, and the distance weight f(s).
#[derive(Clone, Copy)]
struct Link {
    direct: Vec3,
    kd: Vec3,
    f: f32,
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

    fn camera_sample(
        &self,
        ctx: &mut PixelContext,
        x: u32,
        y: u32,
        s: u32,
        sx: f32,
        sy: f32,
    ) -> Vec3 {
        ctx.sample = s;
        let lens = if self.camera.has_lens() {
            ctx.sampler.get2(STREAM_LENS, s)
        } else {
            [0.5, 0.5]
        };
        let ray = self.camera.ray(x, y, sx, sy, lens);
        match self.desc.render.integrator {
            IntegratorKind::Whitted => self.radiance(ctx, ray.origin, ray.dir),
            IntegratorKind::Path => self.path_radiance(ctx, ray.origin, ray.dir),
        }
    }

    /// The color seen along a camera ray: the Whitted tree below it, walked
    /// depth first (the refracted subtree, then the reflected one, as the
    /// spec's blend order has it) with the nodes waiting for a child on a
    /// heap stack, not the thread's: `max-depth="3000"` in a mirror sphere
    /// overflowed the render thread's stack and aborted the process. The
    /// stack holds at most `max-depth` nodes (≤ [`crate::scene::MAX_DEPTH`]).
    ///
    /// Each node's `node` names its place in the tree (for sample streams)
    /// and `weight` is the factor its color gets in the pixel (the product
    /// of the blend weights above it). A branch whose weight falls below
    /// [`MIN_BRANCH_WEIGHT`] is not traced (its term of the blend keeps the
    /// local color instead). Without this a surface that both reflects and
    /// refracts doubles the rays at every level, and two such panes facing
    /// each other at max-depth 64 are 2⁶⁴ rays per sample: the render never
    /// ends. A pruned branch changes the pixel by at most 10⁻⁴ times its
    /// radiance, under a 40th of an 8-bit level for radiance up to 1.
    fn radiance(&self, ctx: &mut PixelContext, origin: Vec3, dir: Vec3) -> Vec3 {
        let mut stack = std::mem::take(&mut ctx.pending);
        stack.clear();
        let mut ray = Branch {
            origin,
            dir,
            node: 0,
            weight: 1.0,
            cone: 0.0,
        };
        let mut depth = 0u32;
        let color = 'descend: loop {
            let mut value = match self.shade(ctx, ray, depth) {
                Shaded::Leaf(c) => c,
                Shaded::Node(p, child) => {
                    stack.push(p);
                    ray = child;
                    depth += 1;
                    continue 'descend;
                }
            };
            // Blend `value` into the nodes waiting for it, bottom up, until
            // one has another child to trace.
            loop {
                let Some(top) = stack.last_mut() else {
                    break 'descend value;
                };
                match top.awaiting {
                    Child::Refracted => {
                        top.c = saturate(top.opacity * top.c + (1.0 - top.opacity) * value);
                        if let Some(child) = top.reflect.take() {
                            top.awaiting = Child::Reflected;
                            depth = top.depth + 1;
                            ray = child;
                            continue 'descend;
                        }
                        value = top.c;
                    }
                    Child::Reflected => {
                        value =
                            saturate((1.0 - top.reflectivity) * top.c + top.reflectivity * value);
                    }
                }
                stack.pop();
            }
        };
        ctx.pending = stack;
        color
    }

    /// Traces `ray` (at `depth` in the tree) and shades its hit: the local
    /// color, and the refracted and reflected rays to trace if any.
    fn shade(&self, ctx: &mut PixelContext, ray: Branch, depth: u32) -> Shaded {
        let Branch {
            origin,
            dir,
            node,
            weight,
            cone,
        } = ray;
        let Some(hit) = self.trace(ctx, origin, dir, f32::INFINITY) else {
            return Shaded::Leaf(self.background);
        };
        let mut sp = self.view.surface_point(origin, dir, &hit);
        self.apply_texture(&mut sp, &hit, dir, cone, self.spread);
        // Every ray of the tree is unit already: camera rays and refracted
        // ones are normalised, reflected ones are mirror images of unit
        // vectors about a unit normal.
        let v = -dir;
        let surf = sp.surface;
        let c = saturate(self.local(ctx, &sp, v, node));
        let max_depth = self.desc.render.max_depth;
        // The refracted color is blended in with 1 − α, then the whole with
        // 1 − r by the reflection.
        let w_refract = weight * (1.0 - surf.opacity) * (1.0 - surf.reflectivity);
        let refract = (surf.opacity < 1.0 && depth < max_depth && w_refract >= MIN_BRANCH_WEIGHT)
            .then(|| {
                let eta = if sp.front { 1.0 / surf.ior } else { surf.ior };
                let t = refract(v, sp.ns, eta);
                Branch {
                    origin: sp.spawn(t),
                    dir: t,
                    node: hash2(node, TAG_REFRACT),
                    weight: w_refract,
                    cone: sp.cone,
                }
            });
        let w_reflect = weight * surf.reflectivity;
        let reflect = (surf.reflectivity > 0.0
            && depth < max_depth
            && w_reflect >= MIN_BRANCH_WEIGHT)
            .then(|| {
                let mut r = reflect(-v, sp.ns);
                // A smooth normal can tilt the mirror direction into the
                // surface; mirrored back out in the geometric plane it cannot
                // start on the far side of a thin wall (a light leak).
                let r_ng = r.dot(sp.ng);
                if r_ng < 0.0 {
                    r -= 2.0 * r_ng * sp.ng;
                }
                Branch {
                    origin: sp.spawn(r),
                    dir: r,
                    node: hash2(node, TAG_REFLECT),
                    weight: w_reflect,
                    cone: sp.cone,
                }
            });
        let pending = |reflect, awaiting| Pending {
            c,
            opacity: surf.opacity,
            reflectivity: surf.reflectivity,
            depth,
            reflect,
            awaiting,
        };
        match (refract, reflect) {
            (Some(t), r) => Shaded::Node(pending(r, Child::Refracted), t),
            (None, Some(r)) => Shaded::Node(pending(None, Child::Reflected), r),
            (None, None) => Shaded::Leaf(c),
        }
    }

    /// `local` of the spec at a hit of the Whitted tree.
    fn local(&self, ctx: &mut PixelContext, sp: &SurfacePoint, v: Vec3, node: u64) -> Vec3 {
        let r = &self.desc.render;
        let mut c = Vec3::ZERO;
        let ka_ambient = saturate(sp.ka * self.ambient);
        if ka_ambient != Vec3::ZERO {
            let a = if r.ao_samples > 0 {
                self.ambient_occlusion(ctx, sp, hash2(node, TAG_AO))
            } else {
                1.0
            };
            c += ka_ambient * a;
        }
        c += self.direct(
            ctx,
            sp,
            Some(v),
            hash2(node, TAG_SHADOW),
            u64::from(ctx.sample),
        );
        // An emitting surface's Le (integrator/area.rs); zero for the rest.
        c += self.emitted(sp);
        if r.diffuse_samples > 0 && sp.kd != Vec3::ZERO {
            let g = self.gather(
                ctx,
                sp,
                1,
                r.diffuse_samples,
                hash2(node, TAG_GATHER),
                u64::from(ctx.sample),
            );
            c += sp.kd * g;
        }
        saturate(c)
    }

    /// Σ over lights of vis·E⊙(kd·max(0,N·L) + ks·max(0,R·V)^n), the
    /// specular term only where N·L > 0 and only when `v` is given (the
    /// diffuse gather uses the diffuse part alone). Soft shadows average
    /// `shadow-samples` jittered light positions; sample `k` of light `j`
    /// draws index `index·S + k` of stream `hash(stream, j)` (in 64 bits:
    /// the parser's bounds keep every such index below 2⁶⁴).
    fn direct(
        &self,
        ctx: &mut PixelContext,
        sp: &SurfacePoint,
        v: Option<Vec3>,
        stream: u64,
        index: u64,
    ) -> Vec3 {
        let surf = sp.surface;
        let specular = v.is_some() && surf.specular != Vec3::ZERO;
        if sp.kd == Vec3::ZERO && !specular {
            return Vec3::ZERO;
        }
        let mut total = Vec3::ZERO;
        for (j, light) in self.scene.desc.lights.iter().enumerate() {
            let samples = if light.radius > 0.0 {
                self.desc.render.shadow_samples.max(1)
            } else {
                1
            };
            let points = (light.radius > 0.0).then(|| ctx.sampler.stream(hash2(stream, j as u64)));
            let mut sum = Sum::<Vec3>::default();
            for k in 0..samples {
                let pos = if let Some(points) = &points {
                    let i = index * u64::from(samples) + u64::from(k);
                    let u = points.get2_wide(i);
                    jittered_position(light, self.view.light_position(j), sp.p, u)
                } else {
                    self.view.light_position(j)
                };
                let Some(inc) = incident(light, pos, sp.p) else {
                    continue;
                };
                let n_dot_l = sp.ns.dot(inc.l);
                // The light must also be in front of the geometric surface:
                // a smooth normal can face a light behind the surface, and
                // the shadow ray would then start on the wall's far side
                // (light leaking through touching or thin geometry).
                if n_dot_l <= 0.0 || sp.ng.dot(inc.l) <= 0.0 {
                    continue;
                }
                let vis = self.visibility(ctx, sp, pos);
                if vis <= 0.0 {
                    continue;
                }
                let mut term = sp.kd * n_dot_l;
                if specular {
                    if let Some(v) = v {
                        let refl = reflect(-inc.l, sp.ns);
                        let rv = refl.dot(v).max(0.0);
                        term += surf.specular * crate::math::pow_shading(rv, surf.shininess);
                    }
                }
                sum.add(inc.e * saturate(term) * vis);
            }
            total += sum.mean(u64::from(samples));
        }
        // Area lights (integrator/area.rs): zero, and nothing drawn, without.
        total += self.area_direct(ctx, sp, v, stream, index);
        saturate(total)
    }

    /// Transmittance from a surface point to a light position.
    fn visibility(&self, ctx: &mut PixelContext, sp: &SurfacePoint, light_pos: Vec3) -> f32 {
        let o = sp.spawn(light_pos - sp.p);
        // dir spans the whole segment, so t < 1 is "before the light".
        self.trace_shadow(ctx, o, light_pos - o, 1.0 - 1e-6)
    }

    /// A(p): mean over cosine-distributed directions of min(1, s_k/s_max),
    /// 1 where nothing is hit within s_max.
    fn ambient_occlusion(&self, ctx: &mut PixelContext, sp: &SurfacePoint, stream: u64) -> f32 {
        let n = self.desc.render.ao_samples;
        let mut sum = Sum::<f32>::default();
        let points = ctx.sampler.stream(stream);
        for k in 0..n {
            let i = u64::from(ctx.sample) * u64::from(n) + u64::from(k);
            let u = points.get2_wide(i);
            let d = cosine_hemisphere(sp.ns, u);
            if d.dot(sp.ng) <= 0.0 {
                // Into the surface itself (a smooth normal's hemisphere dips
                // below the geometric one): occluded at distance 0.
                continue;
            }
            let o = sp.spawn(d);
            sum.add(match self.trace(ctx, o, d, self.s_max) {
                Some(h) => (h.t / self.s_max).min(1.0),
                None => 1.0,
            });
        }
        sum.mean(u64::from(n))
    }

    /// G at the first level: mean over `count` cosine directions of
    /// f(s_k)·D(q_k), with D(q) = kd_q ⊙ (Σ vis·E·max(0,N·L) + G'(q)) and
    /// G' one direction deeper, `diffuse-depth` levels in all (see
    /// [`Integrator::gather_chain`]). Sample `k` uses index `index·count + k`.
    fn gather(
        &self,
        ctx: &mut PixelContext,
        sp: &SurfacePoint,
        level: u32,
        count: u32,
        stream: u64,
        index: u64,
    ) -> Vec3 {
        let mut sum = Sum::<Vec3>::default();
        let at = GatherStreams::new(ctx, stream, level);
        for k in 0..count {
            let idx = index * u64::from(count) + u64::from(k);
            let Some((link, q)) = self.gather_direction(ctx, sp, &at, idx) else {
                continue;
            };
            let mut d_q = link.direct;
            if level < self.desc.render.diffuse_depth {
                d_q += link.kd * self.gather_chain(ctx, q, level + 1, stream, idx);
            }
            sum.add(d_q * link.f);
        }
        saturate(sum.mean(u64::from(count)))
    }

    /// One gather direction at `level` from `sp` with sample index `idx`:
    /// the first hit q, kd_q, f(s) and the direct part of D(q); `None` when
    /// the direction contributes nothing.
    fn gather_direction(
        &self,
        ctx: &mut PixelContext,
        sp: &SurfacePoint,
        at: &GatherStreams,
        idx: u64,
    ) -> Option<(Link, SurfacePoint<'a>)> {
        let level = at.level;
        let u = at.directions.get2_wide(idx);
        let d = cosine_hemisphere(sp.ns, u);
        if d.dot(sp.ng) <= 0.0 {
            // Into the surface itself: nothing gathered (see AO).
            return None;
        }
        let o = sp.spawn(d);
        let hit = self.trace(ctx, o, d, self.s_max)?;
        let f = (1.0 - hit.t / self.s_max).max(0.0);
        if f <= 0.0 {
            return None;
        }
        let mut q = self.view.surface_point(o, d, &hit);
        if self.textured {
            // The cone of one of `count` directions over the hemisphere: the
            // side of a patch of solid angle 2π/count.
            let count = if level == 1 {
                self.desc.render.diffuse_samples
            } else {
                1
            };
            let spread = (std::f32::consts::TAU / count.max(1) as f32).sqrt();
            self.apply_texture(&mut q, &hit, d, sp.cone, spread);
        }
        if q.kd == Vec3::ZERO {
            return None;
        }
        // `direct` already weights by kd_q, so D(q) = direct + kd_q ⊙ G'(q).
        let direct = self.direct(ctx, &q, None, at.shadows, idx);
        Some((
            Link {
                direct,
                kd: q.kd,
                f,
            },
            q,
        ))
    }

    /// G' from `sp` at `level` ≥ 2: one direction per level down to
    /// `diffuse-depth`, walked down a chain kept on the heap and folded back
    /// up (a recursion as deep as `diffuse-depth` overflowed the thread's
    /// stack). Each level is the mean of its one term, as a one-direction
    /// gather computes it.
    fn gather_chain(
        &self,
        ctx: &mut PixelContext,
        sp: SurfacePoint<'a>,
        level: u32,
        stream: u64,
        idx: u64,
    ) -> Vec3 {
        let mut links = std::mem::take(&mut ctx.links);
        links.clear();
        let one = |v: Vec3| {
            let mut sum = Sum::<Vec3>::default();
            sum.add(v);
            saturate(sum.mean(1))
        };
        let (mut sp, mut level) = (sp, level);
        let mut g = loop {
            let at = GatherStreams::new(ctx, stream, level);
            match self.gather_direction(ctx, &sp, &at, idx) {
                None => break saturate(Sum::<Vec3>::default().mean(1)),
                Some((link, q)) if level < self.desc.render.diffuse_depth => {
                    links.push(link);
                    sp = q;
                    level += 1;
                }
                Some((link, _)) => break one(link.direct * link.f),
            }
        };
        while let Some(link) = links.pop() {
            g = one((link.direct + link.kd * g) * link.f);
        }
        ctx.links = links;
        g
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

/// What shading one ray of the Whitted tree gives: a final color, or a node
/// waiting for the color of its first child, the ray to trace next.
enum Shaded {
    Leaf(Vec3),
    Node(Pending, Branch),
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::MAX_DEPTH;
    use crate::{Bundle, Scene};
    use std::collections::BTreeMap;

    fn scene(xml: &str) -> Scene {
        let mut files = BTreeMap::new();
        files.insert("s.xml".to_string(), xml.as_bytes().to_vec());
        Scene::from_bundle(&Bundle {
            scene: "s.xml".into(),
            files,
        })
        .unwrap()
    }

    /// Runs `f` on a thread with a 256 KiB stack: what a recursion as deep
    /// as the scene allows would overflow (and abort the process).
    fn on_a_small_stack<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
        std::thread::Builder::new()
            .stack_size(256 << 10)
            .spawn(f)
            .unwrap()
            .join()
            .unwrap()
    }

    /// A perfect mirror sphere round the camera at the largest max-depth:
    /// a recursion per bounce would overflow a thread's stack. The walk is MAX_DEPTH + 1 rays deep on the heap;
    /// every level passes its child's colour up unchanged (r = 1), so the
    /// pixel is the deepest hit's local colour, ka ⊙ ambient.
    #[test]
    fn a_mirror_sphere_at_the_largest_max_depth_does_not_overflow_the_stack() {
        let s = scene(&format!(
            r#"<scene version="1"><settings ambient="0.5 0.5 0.5"/>
  <sphere id="m" center="0 0 0" radius="5">
    <surface reflectivity="1" diffuse="0 0 0" ambient="0.2 0.4 0.6"/></sphere>
  <camera id="c" position="0 0 0" direction="0 0 -1" fov="30">
    <render width="1" height="1" max-depth="{MAX_DEPTH}"/></camera></scene>"#
        ));
        let (px, rays) = on_a_small_stack(move || {
            Integrator::observed(&s, 0, RenderOptions::default(), &()).pixel(0, 0).unwrap()
        });
        assert_eq!(rays, u64::from(MAX_DEPTH) + 1);
        assert_eq!(px, [0.2f32 * 0.5, 0.4 * 0.5, 0.6 * 0.5]);
    }

    /// The same for the diffuse gather chain: diffuse-depth at its largest,
    /// inside a closed diffuse sphere, one direction per level, every one
    /// hitting (ao-distance far beyond the sphere).
    #[test]
    fn a_gather_chain_at_the_largest_diffuse_depth_does_not_overflow_the_stack() {
        let s = scene(&format!(
            r#"<scene version="1">
  <sphere id="m" center="0 0 0" radius="5"><surface diffuse="0.5 0.5 0.5"/></sphere>
  <light position="0 4 0"/>
  <camera id="c" position="0 0 0" direction="0 0 -1" fov="30">
    <render width="1" height="1" max-depth="0" diffuse-samples="1" ao-distance="1000"
            diffuse-depth="{MAX_DEPTH}"/></camera></scene>"#
        ));
        let (px, rays) = on_a_small_stack(move || {
            Integrator::observed(&s, 0, RenderOptions::default(), &()).pixel(0, 0).unwrap()
        });
        // One camera ray, then per level a gather ray and a shadow ray.
        assert!(rays >= 2 * u64::from(MAX_DEPTH), "{rays}");
        assert!(px.iter().all(|c| c.is_finite() && *c > 0.0), "{px:?}");
    }

    /// 8000² samples of one value, summed in plain f32, stall far below the
    /// right mean (the sum stops growing once a sample is below half its
    /// ULP); `Sum` gets it.
    #[test]
    fn sums_of_64_million_samples_keep_their_mean() {
        let n = 8000u64 * 8000;
        let v = Vec3::new(0.737, 0.25, 1.0 / 3.0);
        let mut sum = Sum::<Vec3>::default();
        let mut plain = Vec3::ZERO;
        for _ in 0..n {
            sum.add(v);
            plain += v;
        }
        let mean = sum.mean(n);
        assert!(((mean - v) / v).abs().max_element() < 1e-5, "{mean} vs {v}");
        // The plain f32 mean is far off: the test would catch a plain sum.
        let plain_mean = plain / n as f32;
        assert!(
            ((plain_mean - v) / v).abs().max_element() > 0.1,
            "{plain_mean}"
        );
        let mut sum = Sum::<f32>::default();
        for _ in 0..n {
            sum.add(0.737);
        }
        assert!((sum.mean(n) - 0.737).abs() < 1e-5, "{}", sum.mean(n));
    }

    /// Up to SUM_BLOCK samples a mean is bit for bit the plain f32 sum
    /// divided in f32, so images with ordinary sample counts keep their
    /// bytes.
    #[test]
    fn small_sums_are_bit_identical_to_plain_f32() {
        let mut x = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            x = crate::sampling::mix64(x);
            // Radiance-like values over many magnitudes, some zero.
            let m = (x >> 40) as f32 / (1u64 << 24) as f32;
            m * [0.0, 1e-3, 1.0, 37.0, 1e6][(x & 3) as usize + usize::from(x & 4 != 0)]
        };
        for n in [1u32, 2, 4, 9, 16, 25, 64, 100, 256, 1000, SUM_BLOCK] {
            for _ in 0..50 {
                let mut sum = Sum::<Vec3>::default();
                let mut plain = Vec3::ZERO;
                let mut sum1 = Sum::<f32>::default();
                let mut plain1 = 0.0f32;
                for _ in 0..n {
                    let v = Vec3::new(next(), next(), next());
                    sum.add(v);
                    plain += v;
                    sum1.add(v.x);
                    plain1 += v.x;
                }
                let (a, b) = (sum.mean(u64::from(n)), plain / n as f32);
                assert_eq!(
                    a.to_array().map(f32::to_bits),
                    b.to_array().map(f32::to_bits),
                    "{n}"
                );
                assert_eq!(
                    sum1.mean(u64::from(n)).to_bits(),
                    (plain1 / n as f32).to_bits()
                );
            }
        }
    }
}
