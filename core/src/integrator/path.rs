//! `integrator="path"`: physically based path tracing (unidirectional, with
//! next-event estimation and multiple importance sampling), the ground truth
//! the Whitted model's approximations are measured against
//! (docs/speed-accuracy.md). The physical reading of `<surface>` and every
//! rule below is documented in docs/aisxml-extensions.md ("Path tracing").
//!
//! The BSDF of a surface with diffuse kd, specular ks, shininess n,
//! reflectivity r, opacity α and index η is the mix
//!
//! ```text
//! f = r·mirror + (1−r)(1−α)·dielectric(η) + (1−r)α·(kd'/π + ks'·(n+2)/(2π)·cosⁿ(R·ωi))
//! ```
//!
//! with kd', ks' the colours scaled down per channel so that kd' + ks' ≤ 1.
//! The weights sum to 1, each lobe reflects at most what it receives, so the
//! surface does too.
//!
//! Random numbers: bounce b (0 at the camera ray's hit) draws from the
//! streams `hash2(TAG_*, b)` below, at the camera sample's index: lobe
//! choice and Russian roulette share one 2D stream, the direction another,
//! the emitter choice and the point on it two more, the jitter of point
//! light j (radius > 0) `hash2(hash2(TAG_POINT, b), j)`. So a path is a pure
//! function of the pixel and sample index like every other sample.

use super::{Integrator, PixelContext, RayObserver};
use crate::geometry::optics::{reflect, refract};
use crate::lights::area::mean;
use crate::lights::{incident, jittered_position};
use crate::sampling::{basis, cosine_hemisphere, hash2};
use crate::world::{HitKind, SurfacePoint};
use glam::Vec3;
use std::f32::consts::{FRAC_1_PI, TAU};

// Stream tags of path mode (disjoint from the Whitted tags 1–8).
const TAG_LOBE: u64 = 0x70_01;
const TAG_DIR: u64 = 0x70_02;
const TAG_PICK: u64 = 0x70_03;
const TAG_POINT_ON_LIGHT: u64 = 0x70_04;
const TAG_POINT: u64 = 0x70_05;

/// Russian roulette starts after this many bounces.
pub const RR_START: u32 = 3;
/// The largest survival probability of Russian roulette.
const RR_MAX: f32 = 0.95;

/// The non-delta part of a surface's BSDF (diffuse + normalized Phong) and
/// the lobe weights, computed once per hit.
struct Bsdf {
    /// Weights of the mirror, dielectric and local (diffuse + glossy) lobes
    /// in f (they sum to 1).
    w_mirror: f32,
    w_glass: f32,
    w_local: f32,
    /// Selection probabilities of the three lobes.
    p_mirror: f32,
    p_glass: f32,
    p_local: f32,
    kd: Vec3,
    ks: Vec3,
    shininess: f32,
    /// Within the local lobe, the probability of sampling the diffuse part.
    p_diffuse: f32,
}

impl Bsdf {
    fn new(sp: &SurfacePoint) -> Bsdf {
        let s = sp.surface;
        let r = s.reflectivity.clamp(0.0, 1.0);
        let a = s.opacity.clamp(0.0, 1.0);
        // kd + ks ≤ 1 per channel: both scaled by the same factor.
        // `sp.kd`: the diffuse colour times its texture, if any.
        let sum = sp.kd + s.specular;
        let scale = Vec3::ONE / sum.max(Vec3::ONE);
        let (kd, ks) = (sp.kd * scale, s.specular * scale);
        let (md, ms) = (mean(kd), mean(ks));
        let (w_mirror, w_glass, w_local) = (r, (1.0 - r) * (1.0 - a), (1.0 - r) * a);
        // Lobes are chosen in proportion to what they can reflect, so a
        // black local lobe is never sampled.
        let q_local = w_local * (md + ms);
        let q = w_mirror + w_glass + q_local;
        let (p_mirror, p_glass, p_local) = if q > 0.0 {
            (w_mirror / q, w_glass / q, q_local / q)
        } else {
            (0.0, 0.0, 0.0)
        };
        Bsdf {
            w_mirror,
            w_glass,
            w_local,
            p_mirror,
            p_glass,
            p_local,
            kd,
            ks,
            shininess: s.shininess.max(0.0),
            p_diffuse: if md + ms > 0.0 { md / (md + ms) } else { 0.0 },
        }
    }

    /// The non-delta part of f (with its weight) for view `v` and light
    /// direction `l`, both unit and above the shading normal.
    fn eval(&self, sp: &SurfacePoint, v: Vec3, l: Vec3) -> Vec3 {
        let mut f = self.kd * FRAC_1_PI;
        if self.ks != Vec3::ZERO {
            let c = reflect(-l, sp.ns).dot(v).max(0.0);
            let n = self.shininess;
            f += self.ks * ((n + 2.0) / TAU * crate::math::pow_shading(c, n));
        }
        self.w_local * f
    }

    /// The density with which BSDF sampling picks direction `l`.
    fn pdf(&self, sp: &SurfacePoint, v: Vec3, l: Vec3) -> f32 {
        if self.p_local <= 0.0 {
            return 0.0;
        }
        let cos = sp.ns.dot(l).max(0.0);
        let mut pdf = self.p_diffuse * cos * FRAC_1_PI;
        if self.p_diffuse < 1.0 {
            let c = reflect(-v, sp.ns).dot(l).max(0.0);
            let n = self.shininess;
            pdf += (1.0 - self.p_diffuse) * ((n + 1.0) / TAU * crate::math::pow_shading(c, n));
        }
        self.p_local * pdf
    }
}

/// A direction about unit `axis` with density (n+1)/(2π)·cosⁿ.
fn phong_lobe(axis: Vec3, n: f32, u: [f32; 2]) -> Vec3 {
    let cos = crate::math::powf(u[0], 1.0 / (n + 1.0));
    let sin = (1.0 - cos * cos).max(0.0).sqrt();
    // φ = 2π·u[1].
    let (sin_phi, cos_phi) = crate::math::sin_cos_turns(u[1]);
    let (t, b) = basis(axis);
    (t * (sin * cos_phi) + b * (sin * sin_phi) + axis * cos).normalize()
}

/// Fresnel reflectance of a smooth dielectric, cos_i the cosine on the
/// incident side and η = n_incident / n_transmitted; 1 under total internal
/// reflection.
pub fn fresnel(cos_i: f32, eta: f32) -> f32 {
    let cos_i = cos_i.clamp(0.0, 1.0);
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    (0.5 * (rs * rs + rp * rp)).clamp(0.0, 1.0)
}

/// The power heuristic (β = 2) weight of a strategy with density `a` against
/// one with density `b`.
#[inline]
fn power_heuristic(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 && (a2 + b2).is_finite() {
        a2 / (a2 + b2)
    } else if a.is_infinite() {
        1.0
    } else {
        0.0
    }
}

impl<'a, O: RayObserver> Integrator<'a, O> {
    /// The radiance along a camera ray, one path. Never NaN: a sample that
    /// would be is dropped (counted as 0), and ±∞ saturates.
    pub(super) fn path_radiance(&self, ctx: &mut PixelContext, origin: Vec3, dir: Vec3) -> Vec3 {
        let l = self.trace_path(ctx, origin, dir);
        if l.is_nan() {
            Vec3::ZERO
        } else {
            l.min(Vec3::splat(f32::MAX))
        }
    }

    fn trace_path(&self, ctx: &mut PixelContext, origin: Vec3, dir: Vec3) -> Vec3 {
        let max_bounces = self.desc.render.max_bounces;
        let lights = self.view.area_lights();
        let index = ctx.sample;
        let mut radiance = Vec3::ZERO;
        let mut beta = Vec3::ONE;
        let (mut origin, mut dir) = (origin, dir.normalize());
        // The density with which the last bounce's BSDF sampling chose `dir`;
        // None after a delta lobe or at the camera (no light sampling could
        // have produced that path: full weight to what the ray hits).
        let mut prev_pdf: Option<f32> = None;
        let mut bounce = 0u32;
        loop {
            let Some(hit) = self.trace(ctx, origin, dir, f32::INFINITY) else {
                radiance += beta * self.background;
                break;
            };
            let mut sp = self.view.surface_point(origin, dir, &hit);
            // Paths carry no ray cone: the texture is read at its finest
            // level, and the pixel's samples do the filtering.
            self.view.apply_texture(&mut sp, &hit, dir);
            let surf = sp.surface;
            if surf.emission != Vec3::ZERO {
                let w = match (prev_pdf, hit.kind) {
                    (Some(pdf_b), HitKind::Triangle { .. } | HitKind::Sphere(_)) => {
                        let cos_l = sp.ng.dot(dir).abs();
                        let pdf_l = lights.pdf_area(surf.emission) * hit.t * hit.t / cos_l;
                        power_heuristic(pdf_b, pdf_l)
                    }
                    _ => 1.0,
                };
                radiance += beta * surf.emission * w;
            }
            if bounce >= max_bounces {
                break;
            }
            let v = -dir;
            let bsdf = Bsdf::new(&sp);
            if bsdf.p_local > 0.0 {
                radiance += beta * self.next_event(ctx, &sp, &bsdf, v, bounce, index);
            }
            // Choose a lobe, then a direction.
            let [u_lobe, u_rr] = ctx.sampler.get2(hash2(TAG_LOBE, u64::from(bounce)), index);
            let u_dir = ctx.sampler.get2(hash2(TAG_DIR, u64::from(bounce)), index);
            let new_dir;
            if u_lobe < bsdf.p_mirror {
                new_dir = mirror(&sp, v);
                beta *= bsdf.w_mirror / bsdf.p_mirror;
                prev_pdf = None;
            } else if u_lobe < bsdf.p_mirror + bsdf.p_glass {
                let eta = if sp.front { 1.0 / surf.ior } else { surf.ior };
                let f = fresnel(sp.ns.dot(v), eta);
                // The lobe's own choice between reflection and refraction
                // reuses u_lobe, rescaled to [0,1) within the lobe's share.
                let u = ((u_lobe - bsdf.p_mirror) / bsdf.p_glass).clamp(0.0, 1.0);
                new_dir = if u < f {
                    mirror(&sp, v)
                } else {
                    refract(v, sp.ns, eta)
                };
                beta *= bsdf.w_glass / bsdf.p_glass;
                prev_pdf = None;
            } else if bsdf.p_local > 0.0 {
                let u = ((u_lobe - bsdf.p_mirror - bsdf.p_glass) / bsdf.p_local).clamp(0.0, 1.0);
                let d = if u < bsdf.p_diffuse {
                    cosine_hemisphere(sp.ns, u_dir)
                } else {
                    phong_lobe(reflect(-v, sp.ns), bsdf.shininess, u_dir)
                };
                let cos = sp.ns.dot(d);
                // Below the shading or the geometric surface: absorbed.
                if !(cos > 0.0) || !(sp.ng.dot(d) > 0.0) {
                    break;
                }
                let pdf = bsdf.pdf(&sp, v, d);
                if !(pdf > 0.0) {
                    break;
                }
                beta *= bsdf.eval(&sp, v, d) * (cos / pdf);
                prev_pdf = Some(pdf);
                new_dir = d;
            } else {
                // Reflects nothing.
                break;
            }
            bounce += 1;
            if bounce > RR_START {
                let q = beta.max_element().min(RR_MAX);
                if !(u_rr < q) {
                    break;
                }
                beta /= q;
            }
            if !beta.is_finite() || beta == Vec3::ZERO {
                break;
            }
            dir = new_dir;
            origin = sp.spawn(dir);
        }
        radiance
    }

    /// Direct light at `sp` through the non-delta lobes: every point and spot
    /// light (their E, read as irradiance π·E at normal incidence so that a
    /// Lambertian surface gets kd·E·cos θ, the Whitted value), plus one
    /// sample of the area lights weighted by MIS against BSDF sampling.
    fn next_event(
        &self,
        ctx: &mut PixelContext,
        sp: &SurfacePoint,
        bsdf: &Bsdf,
        v: Vec3,
        bounce: u32,
        index: u32,
    ) -> Vec3 {
        let mut total = Vec3::ZERO;
        for (j, light) in self.scene.desc.lights.iter().enumerate() {
            let center = self.view.light_position(j);
            let pos = if light.radius > 0.0 {
                let stream = hash2(hash2(TAG_POINT, u64::from(bounce)), j as u64);
                jittered_position(light, center, sp.p, ctx.sampler.get2(stream, index))
            } else {
                center
            };
            let Some(inc) = incident(light, pos, sp.p) else {
                continue;
            };
            let cos = sp.ns.dot(inc.l);
            if cos <= 0.0 || sp.ng.dot(inc.l) <= 0.0 {
                continue;
            }
            if !self.unoccluded(ctx, sp, pos) {
                continue;
            }
            total += bsdf.eval(sp, v, inc.l) * inc.e * (std::f32::consts::PI * cos);
        }
        let lights = self.view.area_lights();
        if !lights.is_empty() {
            let [u_pick, _] = ctx.sampler.get2(hash2(TAG_PICK, u64::from(bounce)), index);
            let u = ctx
                .sampler
                .get2(hash2(TAG_POINT_ON_LIGHT, u64::from(bounce)), index);
            if let Some(s) = lights.sample(u_pick, u, sp.p) {
                let to = s.y - sp.p;
                let d2 = to.length_squared();
                let l = to / d2.sqrt();
                let cos_l = -s.n.dot(l);
                let emits = cos_l > 0.0 || (s.two_sided && cos_l < 0.0);
                let cos = sp.ns.dot(l);
                if emits
                    && d2 > 0.0
                    && cos > 0.0
                    && sp.ng.dot(l) > 0.0
                    && self.unoccluded(ctx, sp, s.y)
                {
                    let pdf_l = s.pdf_area * d2 / cos_l.abs();
                    let pdf_b = bsdf.pdf(sp, v, l);
                    let w = power_heuristic(pdf_l, pdf_b);
                    let c = bsdf.eval(sp, v, l) * s.radiance * (cos * w / pdf_l);
                    if c.is_finite() {
                        total += c;
                    }
                }
            }
        }
        total
    }

    /// Nothing between `sp` and `target`: a translucent occluder blocks too
    /// (light through glass arrives by BSDF sampling, not here).
    fn unoccluded(&self, ctx: &mut PixelContext, sp: &SurfacePoint, target: Vec3) -> bool {
        let o = sp.spawn(target - sp.p);
        let d = target - o;
        if self.scene.has_translucency {
            self.trace(ctx, o, d, 1.0 - 1e-6).is_none()
        } else {
            self.trace_shadow(ctx, o, d, 1.0 - 1e-6) > 0.0
        }
    }
}

/// The mirror direction of `v` about the shading normal, kept on the
/// geometric front (as the Whitted reflection does).
fn mirror(sp: &SurfacePoint, v: Vec3) -> Vec3 {
    let mut r = reflect(-v, sp.ns);
    let r_ng = r.dot(sp.ng);
    if r_ng < 0.0 {
        r -= 2.0 * r_ng * sp.ng;
    }
    r
}

#[cfg(test)]
pub(super) mod tests;
