//! Area lights in Whitted mode: emitting surfaces (`emission` on a
//! `<surface>`, `<light type="rect">`) light a Whitted hit by sampled shadow
//! rays, and are seen (Le) by the rays that hit them.
//!
//! Each of `shadow-samples` samples picks a point y on the area lights
//! exactly as path mode's next-event estimation does ([`AreaLights::sample`]:
//! an emitter in proportion to mean(Le)·area, then a point uniform in its
//! area, density p(y) per area) and treats it as a point light with
//!
//! ```text
//! E = Le · |cos θ_y| / (π · d² · p(y))
//! ```
//!
//! (θ_y between the emitter's normal and the shadow ray, d the distance),
//! shadowed by the transmittance of the Whitted shadow ray and shaded with
//! the spec's Phong terms: E ⊙ (kd·max(0, N·L) + ks·max(0, R·V)ⁿ). The mean
//! over the samples of the diffuse part is an unbiased estimate of
//! kd/π · ∫ Le cos θ dω, the Lambertian reflection of the area light path
//! mode computes, so a diffuse surface gets the same direct light in both
//! modes. The specular part is the spec's (unnormalised) Phong highlight of
//! each sampled point, averaged; a mirror shows the emitter itself by its
//! reflected ray.
//!
//! Random numbers: sample k of camera sample `index` draws point
//! `index·S + k` (S = `shadow-samples`) of two streams named after the hit's
//! shadow stream: `hash(hash(stream, TAG_AREA), 0)` for the point on the
//! emitter, `… 1)` for the emitter choice. Consecutive Sobol points, so the
//! S points of one camera sample are stratified over the light.
//!
//! A scene without emitters returns at the first test and draws nothing:
//! its images keep their bytes (`pin.rs`).

use super::{saturate, Integrator, PixelContext, RayObserver, Sum};
use crate::geometry::optics::reflect;
use crate::lights::area::AreaLights;
use crate::sampling::hash2;
use crate::world::SurfacePoint;
use glam::Vec3;
use std::f32::consts::PI;

/// The tag of the area-light streams under a hit's shadow stream (point
/// lights use the light's index there, which stays far below this).
const TAG_AREA: u64 = 0xA4EA_0000_0000_0001;

impl<'a, O: RayObserver> Integrator<'a, O> {
    /// The Whitted direct light at `sp` from the area lights: the mean over
    /// `shadow-samples` sampled points (see the module's documentation).
    /// `v`: the view vector, for the specular term (none in the gather).
    pub(super) fn area_direct(
        &self,
        ctx: &mut PixelContext,
        sp: &SurfacePoint,
        v: Option<Vec3>,
        stream: u64,
        index: u64,
    ) -> Vec3 {
        let lights: &AreaLights = self.view.area_lights();
        if lights.is_empty() {
            return Vec3::ZERO;
        }
        let surf = sp.surface;
        let samples = self.desc.render.shadow_samples.max(1);
        let base = hash2(stream, TAG_AREA);
        let points = ctx.sampler.stream(hash2(base, 0));
        let picks = ctx.sampler.stream(hash2(base, 1));
        let mut sum = Sum::<Vec3>::default();
        for k in 0..samples {
            let i = index * u64::from(samples) + u64::from(k);
            let u = points.get2_wide(i);
            let [u_pick, _] = picks.get2_wide(i);
            let Some(s) = lights.sample(u_pick, u, sp.p) else {
                continue;
            };
            let to = s.y - sp.p;
            let d2 = to.length_squared();
            if !(d2 > 0.0) || !d2.is_finite() || !(s.pdf_area > 0.0) {
                continue;
            }
            let l = to / d2.sqrt();
            let cos_y = -s.n.dot(l);
            // The emitter's back faces us: dark unless it emits there too.
            if !(cos_y > 0.0 || (s.two_sided && cos_y < 0.0)) {
                continue;
            }
            let n_dot_l = sp.ns.dot(l);
            // As for point lights: in front of the shading and the
            // geometric surface both.
            if n_dot_l <= 0.0 || sp.ng.dot(l) <= 0.0 {
                continue;
            }
            let vis = self.visibility(ctx, sp, s.y);
            if vis <= 0.0 {
                continue;
            }
            let g = cos_y.abs() / (PI * d2 * s.pdf_area);
            let e = saturate(s.radiance * g.min(f32::MAX));
            let mut term = sp.kd * n_dot_l;
            if let Some(v) = v {
                if surf.specular != Vec3::ZERO {
                    let rv = reflect(-l, sp.ns).dot(v).max(0.0);
                    term += surf.specular * crate::math::pow_shading(rv, surf.shininess);
                }
            }
            sum.add(saturate(e * saturate(term) * vis));
        }
        saturate(sum.mean(u64::from(samples)))
    }

    /// What a Whitted ray sees a surface emit at `sp`: its `emission` (a
    /// surface is hit only from the sides it emits on), zero for the rest.
    #[inline(always)]
    pub(super) fn emitted(&self, sp: &SurfacePoint) -> Vec3 {
        sp.surface.emission
    }
}

#[cfg(test)]
mod pin;
#[cfg(test)]
mod tests;
