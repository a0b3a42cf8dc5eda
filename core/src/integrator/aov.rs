//! Render passes of a camera sample (see [`crate::aov`]): the albedo, the
//! shading normal and the depth of the ray the beauty traced, and their
//! per-pixel sums.
//!
//! The passes follow their own walk from the camera ray: they draw no
//! random number and change nothing the beauty reads, so the beauty's
//! bytes are the same with or without them. The walk costs one closest-hit
//! ray per camera sample (more through mirrors and glass), counted with the
//! pixel's rays; a render without passes never enters it.
//!
//! Through a surface without a diffuse part the walk goes on as OIDN
//! expects of a denoiser's auxiliary images: a perfect mirror
//! (`reflectivity` 1) along the mirror direction, clear glass (`opacity`
//! 0, reflectivity under 1) along the refracted direction (the mirror one
//! under total internal reflection), at most `max-depth` (Whitted) or
//! `max-bounces` (path) times; the albedo and normal are those of the
//! surface where it stops. The depth is always the first hit's.
//!
//! Textures are read as the beauty reads them: with the Whitted ray cone,
//! or at their finest level in path mode.

use super::{Integrator, PixelContext, RayObserver, Sum};
use crate::aov::{Aov, Aovs};
use crate::geometry::optics::{reflect, refract};
use crate::scene::IntegratorKind;
use glam::Vec3;

/// The most values a pixel's passes have (every pass).
pub const MAX_AOV_CHANNELS: usize = 7;

/// The passes of one camera sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct AovSample {
    albedo: Vec3,
    normal: Vec3,
    depth: f32,
}

/// A pixel's pass sums, over the same samples as its beauty.
#[derive(Clone, Copy, Default)]
pub(super) struct AovSums {
    albedo: Sum<Vec3>,
    normal: Sum<Vec3>,
    depth: Sum<f32>,
    count: u32,
}

impl AovSums {
    #[inline]
    pub(super) fn add(&mut self, s: AovSample) {
        self.albedo.add(s.albedo);
        self.normal.add(s.normal);
        self.depth.add(s.depth);
        self.count += 1;
    }

    /// The means of the passes in `aovs`, in layout order, in the first
    /// `aovs.channels()` values (zeros for a pixel without samples). A
    /// depth with any +∞ sample (a miss) is +∞.
    pub(super) fn finish(&self, aovs: Aovs) -> [f32; MAX_AOV_CHANNELS] {
        let mut out = [0.0; MAX_AOV_CHANNELS];
        if self.count == 0 {
            return out;
        }
        let n = u64::from(self.count);
        let mut i = 0;
        for aov in aovs.iter() {
            let k = aov.channels();
            match aov {
                Aov::Albedo => out[i..i + k].copy_from_slice(&self.albedo.mean(n).to_array()),
                Aov::Normal => out[i..i + k].copy_from_slice(&self.normal.mean(n).to_array()),
                Aov::Depth => out[i] = self.depth.mean(n),
            }
            i += k;
        }
        out
    }
}

impl<'a, O: RayObserver> Integrator<'a, O> {
    /// The passes of the camera ray (`origin`, `dir`) (see the module
    /// documentation).
    pub(super) fn aov_sample(&self, ctx: &mut PixelContext, origin: Vec3, dir: Vec3) -> AovSample {
        let r = &self.desc.render;
        let path = r.integrator == IntegratorKind::Path;
        let max = if path { r.max_bounces } else { r.max_depth };
        let (mut origin, mut dir, mut cone) = (origin, dir, 0.0);
        let mut depth = None;
        let mut bounces = 0;
        loop {
            let Some(hit) = self.trace(ctx, origin, dir, f32::INFINITY) else {
                return AovSample {
                    albedo: self.background,
                    normal: Vec3::ZERO,
                    depth: depth.unwrap_or(f32::INFINITY),
                };
            };
            let first = *depth.get_or_insert(hit.t * dir.length());
            let mut sp = self.view.surface_point(origin, dir, &hit);
            if path {
                self.view.apply_texture(&mut sp, &hit, dir);
            } else {
                self.apply_texture(&mut sp, &hit, dir, cone, self.spread);
            }
            let s = sp.surface;
            let v = -dir.normalize();
            let next = if bounces >= max {
                None
            } else if s.reflectivity >= 1.0 {
                let mut m = reflect(-v, sp.ns);
                // Kept on the geometric front, as the integrators do.
                let m_ng = m.dot(sp.ng);
                if m_ng < 0.0 {
                    m -= 2.0 * m_ng * sp.ng;
                }
                Some(m)
            } else if s.opacity <= 0.0 {
                let eta = if sp.front { 1.0 / s.ior } else { s.ior };
                Some(refract(v, sp.ns, eta))
            } else {
                None
            };
            let Some(next) = next else {
                return AovSample {
                    albedo: sp.kd,
                    normal: sp.ns,
                    depth: first,
                };
            };
            origin = sp.spawn(next);
            dir = next;
            cone = sp.cone;
            bounces += 1;
        }
    }
}

#[cfg(test)]
mod tests;
