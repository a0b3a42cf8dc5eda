//! The Monte-Carlo effects of the Whitted integrator: ambient occlusion,
//! soft shadows (jittered positions of a light with a radius), the diffuse
//! gather (interreflection, `diffuse-depth` levels walked on a heap chain)
//! and depth of field (the lens sample of a camera with an aperture). Each
//! is skipped outright when its settings make it a no-op.

use super::{saturate, Integrator, PixelContext, RayObserver, Sum};
use super::{STREAM_LENS, TAG_GATHER_SHADOW};
use crate::lights::jittered_position;
use crate::sampling::{cosine_hemisphere, hash2, Stream};
use crate::scene::Light;
use crate::world::SurfacePoint;
use glam::Vec3;

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
pub(super) struct Link {
    direct: Vec3,
    kd: Vec3,
    f: f32,
}

impl<'a, O: RayObserver> Integrator<'a, O> {
    /// Depth of field: the lens sample of camera sample `s` (the lens
    /// centre for a pinhole camera).
    #[inline(always)]
    pub(super) fn lens_sample(&self, ctx: &PixelContext, s: u32) -> [f32; 2] {
        if self.camera.has_lens() {
            ctx.sampler.get2(STREAM_LENS, s)
        } else {
            [0.5, 0.5]
        }
    }

    /// Soft shadows: how many positions of light `j` the direct light
    /// averages (`shadow-samples` for a light with a radius, else one), and
    /// for a light with a radius the stream `hash(stream, j)` they come from.
    #[inline(always)]
    pub(super) fn soft_shadow_points(
        &self,
        ctx: &PixelContext,
        light: &Light,
        j: usize,
        stream: u64,
    ) -> (u32, Option<Stream>) {
        let samples = if light.radius > 0.0 {
            self.desc.render.shadow_samples.max(1)
        } else {
            1
        };
        let points = (light.radius > 0.0).then(|| ctx.sampler.stream(hash2(stream, j as u64)));
        (samples, points)
    }

    /// Sample `k` of the `samples` positions of light `j` seen from `p`:
    /// a jittered position drawn at index `index·samples + k` of `points`,
    /// or the light's own position without a stream.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) fn light_sample_position(
        &self,
        light: &Light,
        j: usize,
        points: Option<&Stream>,
        p: Vec3,
        index: u64,
        samples: u32,
        k: u32,
    ) -> Vec3 {
        if let Some(points) = points {
            let i = index * u64::from(samples) + u64::from(k);
            let u = points.get2_wide(i);
            jittered_position(light, self.view.light_position(j), p, u)
        } else {
            self.view.light_position(j)
        }
    }

    /// A(p): mean over cosine-distributed directions of min(1, s_k/s_max),
    /// 1 where nothing is hit within s_max.
    pub(super) fn ambient_occlusion(
        &self,
        ctx: &mut PixelContext,
        sp: &SurfacePoint,
        stream: u64,
    ) -> f32 {
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
    pub(super) fn gather(
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

#[cfg(test)]
mod tests {
    use crate::integrator::{Integrator, RenderOptions};
    use crate::scene::MAX_DEPTH;
    use crate::testing::{on_a_small_stack, scene};

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
            Integrator::observed(&s, 0, RenderOptions::default(), &())
                .pixel(0, 0)
                .unwrap()
        });
        // One camera ray, then per level a gather ray and a shadow ray.
        assert!(rays >= 2 * u64::from(MAX_DEPTH), "{rays}");
        assert!(px.iter().all(|c| c.is_finite() && *c > 0.0), "{px:?}");
    }
}
