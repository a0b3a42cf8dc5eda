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

use crate::camera::Camera;
use crate::lights::{incident, jittered_position};
use crate::sampling::{cosine_hemisphere, hash2, pixel_seed, PixelSampler, SamplerKind};
use crate::scene::CameraDesc;
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
}

/// Per-pixel state: the sampler, the current camera sample, and a ray count.
pub struct PixelContext {
    sampler: PixelSampler,
    sample: u32,
    pub rays: u64,
}

impl<'a> Integrator<'a> {
    pub fn new(scene: &'a Scene, camera: usize, options: RenderOptions) -> Self {
        Integrator::observed(scene, camera, options, &())
    }
}

impl<'a, O: RayObserver> Integrator<'a, O> {
    /// [`Integrator::new`] with every traced ray shown to `observer` first.
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
        }
    }

    /// The linear RGB value of pixel (column `x`, row `y`), and rays traced.
    pub fn pixel(&self, x: u32, y: u32) -> ([f32; 3], u64) {
        let r = &self.desc.render;
        let mut ctx = PixelContext {
            sampler: PixelSampler {
                seed: pixel_seed(r.seed, self.camera_hash, x, y),
                kind: self.sampler,
            },
            sample: 0,
            rays: 0,
        };
        let value = match r.adaptive {
            None => {
                let n = r.supersample;
                let mut sum = Vec3::ZERO;
                for s in 0..n * n {
                    let (sx, sy) = if r.jitter {
                        let [jx, jy] = ctx.sampler.get2(STREAM_PIXEL, s);
                        (
                            ((s % n) as f32 + jx) / n as f32,
                            ((s / n) as f32 + jy) / n as f32,
                        )
                    } else {
                        (
                            ((s % n) as f32 + 0.5) / n as f32,
                            ((s / n) as f32 + 0.5) / n as f32,
                        )
                    };
                    sum += self.camera_sample(&mut ctx, x, y, s, sx, sy);
                }
                saturate(sum / (n * n) as f32)
            }
            Some(a) => {
                // Sample until the standard error of the mean (largest over the
                // channels) is under the threshold, between min and max samples.
                let mut sum = glam::DVec3::ZERO;
                let mut sum_sq = glam::DVec3::ZERO;
                let mut n = 0u32;
                while n < a.max_samples {
                    let [sx, sy] = ctx.sampler.get2(STREAM_PIXEL, n);
                    let v = self.camera_sample(&mut ctx, x, y, n, sx, sy).as_dvec3();
                    sum += v;
                    sum_sq += v * v;
                    n += 1;
                    if n >= a.min_samples.max(2) {
                        let nf = n as f64;
                        let var = ((sum_sq - sum * sum / nf) / (nf - 1.0)).max(glam::DVec3::ZERO);
                        let err = (var / nf).max_element().sqrt();
                        if err <= a.threshold as f64 {
                            break;
                        }
                    }
                }
                saturate((sum / n as f64).as_vec3())
            }
        };
        (value.to_array(), ctx.rays)
    }

    /// Every closest-hit ray goes through here: counted, observed, traced.
    #[inline(always)]
    fn trace(&self, ctx: &mut PixelContext, origin: Vec3, dir: Vec3, t_max: f32) -> Option<Hit> {
        ctx.rays += 1;
        self.observer.closest(origin, dir, t_max);
        self.view.intersect(origin, dir, t_max)
    }

    /// Every shadow ray goes through here: counted, observed, traced.
    #[inline(always)]
    fn trace_shadow(&self, ctx: &mut PixelContext, origin: Vec3, dir: Vec3, t_max: f32) -> f32 {
        ctx.rays += 1;
        self.observer.shadow(origin, dir, t_max);
        self.view.transmittance(origin, dir, t_max)
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
        self.radiance(ctx, ray.origin, ray.dir, 0, 0, 1.0)
    }

    /// The color seen along a ray at recursion `depth`; `node` names the ray's
    /// place in the reflection/refraction tree (for sample streams);
    /// `weight` is the factor its color gets in the pixel (the product of
    /// the blend weights above it).
    ///
    /// A branch whose weight falls below [`MIN_BRANCH_WEIGHT`] is not traced
    /// (its term of the blend keeps the local color instead). Without this a
    /// surface that both reflects and refracts doubles the rays at every
    /// level, and two such panes facing each other at max-depth 64 are 2⁶⁴
    /// rays per sample: the render never ends. A pruned branch changes the
    /// pixel by at most 10⁻⁴ times its radiance, under a 40th of an 8-bit
    /// level for radiance up to 1.
    fn radiance(
        &self,
        ctx: &mut PixelContext,
        origin: Vec3,
        dir: Vec3,
        depth: u32,
        node: u64,
        weight: f32,
    ) -> Vec3 {
        let Some(hit) = self.trace(ctx, origin, dir, f32::INFINITY) else {
            return self.background;
        };
        let sp = self.view.surface_point(origin, dir, &hit);
        let v = -dir.normalize();
        let surf = sp.surface;
        let mut c = saturate(self.local(ctx, &sp, v, node));
        let max_depth = self.desc.render.max_depth;
        // The refracted color is blended in with 1 − α, then the whole with
        // 1 − r by the reflection below.
        let w_refract = weight * (1.0 - surf.opacity) * (1.0 - surf.reflectivity);
        if surf.opacity < 1.0 && depth < max_depth && w_refract >= MIN_BRANCH_WEIGHT {
            let eta = if sp.front { 1.0 / surf.ior } else { surf.ior };
            let t = refract(v, sp.ns, eta);
            let o = sp.spawn(t);
            let l = self.radiance(ctx, o, t, depth + 1, hash2(node, TAG_REFRACT), w_refract);
            c = saturate(surf.opacity * c + (1.0 - surf.opacity) * l);
        }
        let w_reflect = weight * surf.reflectivity;
        if surf.reflectivity > 0.0 && depth < max_depth && w_reflect >= MIN_BRANCH_WEIGHT {
            let mut r = reflect(-v, sp.ns);
            // A smooth normal can tilt the mirror direction into the
            // surface; mirrored back out in the geometric plane it cannot
            // start on the far side of a thin wall (a light leak).
            let r_ng = r.dot(sp.ng);
            if r_ng < 0.0 {
                r -= 2.0 * r_ng * sp.ng;
            }
            let o = sp.spawn(r);
            let l = self.radiance(ctx, o, r, depth + 1, hash2(node, TAG_REFLECT), w_reflect);
            c = saturate((1.0 - surf.reflectivity) * c + surf.reflectivity * l);
        }
        c
    }

    /// `local` of the spec at a hit of the Whitted tree.
    fn local(&self, ctx: &mut PixelContext, sp: &SurfacePoint, v: Vec3, node: u64) -> Vec3 {
        let surf = sp.surface;
        let r = &self.desc.render;
        let mut c = Vec3::ZERO;
        let ka_ambient = saturate(surf.ambient * self.ambient);
        if ka_ambient != Vec3::ZERO {
            let a = if r.ao_samples > 0 {
                self.ambient_occlusion(ctx, sp, hash2(node, TAG_AO))
            } else {
                1.0
            };
            c += ka_ambient * a;
        }
        c += self.direct(ctx, sp, Some(v), hash2(node, TAG_SHADOW), ctx.sample);
        if r.diffuse_samples > 0 && surf.diffuse != Vec3::ZERO {
            let g = self.gather(
                ctx,
                sp,
                1,
                r.diffuse_samples,
                hash2(node, TAG_GATHER),
                ctx.sample,
            );
            c += surf.diffuse * g;
        }
        saturate(c)
    }

    /// Σ over lights of vis·E⊙(kd·max(0,N·L) + ks·max(0,R·V)^n), the
    /// specular term only where N·L > 0 and only when `v` is given (the
    /// diffuse gather uses the diffuse part alone). Soft shadows average
    /// `shadow-samples` jittered light positions; sample `k` of light `j`
    /// draws index `index·S + k` of stream `hash(stream, j)`.
    fn direct(
        &self,
        ctx: &mut PixelContext,
        sp: &SurfacePoint,
        v: Option<Vec3>,
        stream: u64,
        index: u32,
    ) -> Vec3 {
        let surf = sp.surface;
        let specular = v.is_some() && surf.specular != Vec3::ZERO;
        if surf.diffuse == Vec3::ZERO && !specular {
            return Vec3::ZERO;
        }
        let mut total = Vec3::ZERO;
        for (j, light) in self.scene.desc.lights.iter().enumerate() {
            let samples = if light.radius > 0.0 {
                self.desc.render.shadow_samples.max(1)
            } else {
                1
            };
            let light_stream = hash2(stream, j as u64);
            let mut sum = Vec3::ZERO;
            for k in 0..samples {
                let pos = if light.radius > 0.0 {
                    let u = ctx
                        .sampler
                        .get2(light_stream, index.wrapping_mul(samples).wrapping_add(k));
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
                let mut term = surf.diffuse * n_dot_l;
                if specular {
                    if let Some(v) = v {
                        let refl = reflect(-inc.l, sp.ns);
                        let rv = refl.dot(v).max(0.0);
                        term += surf.specular * rv.powf(surf.shininess);
                    }
                }
                sum += inc.e * saturate(term) * vis;
            }
            total += sum / samples as f32;
        }
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
        let mut sum = 0.0f32;
        for k in 0..n {
            let u = ctx
                .sampler
                .get2(stream, ctx.sample.wrapping_mul(n).wrapping_add(k));
            let d = cosine_hemisphere(sp.ns, u);
            if d.dot(sp.ng) <= 0.0 {
                // Into the surface itself (a smooth normal's hemisphere dips
                // below the geometric one): occluded at distance 0.
                continue;
            }
            let o = sp.spawn(d);
            sum += match self.trace(ctx, o, d, self.s_max) {
                Some(h) => (h.t / self.s_max).min(1.0),
                None => 1.0,
            };
        }
        sum / n as f32
    }

    /// G at `level` (1 = the first level): mean over `count` cosine
    /// directions of f(s_k)·D(q_k), with
    /// D(q) = kd_q ⊙ (Σ vis·E·max(0,N·L) + G'(q)) and G' one direction
    /// deeper, `diffuse-depth` levels in all.
    /// Sample `k` uses index `index·count + k`.
    fn gather(
        &self,
        ctx: &mut PixelContext,
        sp: &SurfacePoint,
        level: u32,
        count: u32,
        stream: u64,
        index: u32,
    ) -> Vec3 {
        let r = &self.desc.render;
        let mut sum = Vec3::ZERO;
        for k in 0..count {
            let idx = index.wrapping_mul(count).wrapping_add(k);
            let u = ctx.sampler.get2(hash2(stream, level as u64), idx);
            let d = cosine_hemisphere(sp.ns, u);
            if d.dot(sp.ng) <= 0.0 {
                // Into the surface itself: nothing gathered (see AO).
                continue;
            }
            let o = sp.spawn(d);
            let Some(hit) = self.trace(ctx, o, d, self.s_max) else {
                continue;
            };
            let f = (1.0 - hit.t / self.s_max).max(0.0);
            if f <= 0.0 {
                continue;
            }
            let q = self.view.surface_point(o, d, &hit);
            if q.surface.diffuse == Vec3::ZERO {
                continue;
            }
            let shadow_stream = hash2(hash2(stream, TAG_GATHER_SHADOW), level as u64);
            // `direct` already weights by kd_q, so D(q) = direct + kd_q ⊙ G'(q).
            let mut d_q = self.direct(ctx, &q, None, shadow_stream, idx);
            if level < r.diffuse_depth {
                d_q += q.surface.diffuse * self.gather(ctx, &q, level + 1, 1, stream, idx);
            }
            sum += d_q * f;
        }
        saturate(sum / count as f32)
    }
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

/// Mirror direction of `d` about unit `n`.
#[inline]
pub fn reflect(d: Vec3, n: Vec3) -> Vec3 {
    d - 2.0 * d.dot(n) * n
}

/// Snell refraction of the ray with view vector `v` (pointing back along the
/// ray) through unit normal `n` facing `v`, with η = n1/n2; the mirror
/// direction under total internal reflection.
#[inline]
pub fn refract(v: Vec3, n: Vec3, eta: f32) -> Vec3 {
    if eta == 1.0 {
        return -v;
    }
    let cos_i = n.dot(v).clamp(0.0, 1.0);
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i);
    if sin2_t > 1.0 {
        return reflect(-v, n);
    }
    (-eta * v + (eta * cos_i - (1.0 - sin2_t).sqrt()) * n).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refraction_obeys_snell_and_total_internal_reflection_starts_at_the_critical_angle() {
        let n = Vec3::Y;
        for deg in [0.0f32, 10.0, 30.0, 60.0, 85.0] {
            let a = deg.to_radians();
            let v = Vec3::new(-a.sin(), a.cos(), 0.0); // pointing back up the ray
            let t = refract(v, n, 1.0 / 1.5);
            let sin_t = t.x.abs();
            assert!((sin_t - a.sin() / 1.5).abs() < 1e-5, "{deg}");
            assert!(t.y < 0.0);
        }
        // Inside glass (η = 1.5): critical angle asin(1/1.5).
        let crit = (1.0f32 / 1.5).asin();
        for (a, tir) in [(crit - 1e-3, false), (crit + 1e-3, true)] {
            let v = Vec3::new(-a.sin(), a.cos(), 0.0);
            let t = refract(v, n, 1.5);
            assert_eq!(t.y > 0.0, tir, "angle {a}");
        }
        let v = Vec3::new(0.3, 0.9, 0.1).normalize();
        assert_eq!(refract(v, n, 1.0), -v);
    }
}
