//! Whitted ray tracing as the spec has it: the reflection/refraction tree
//! below a camera ray (walked on a heap stack, refracted subtree first, then
//! the reflected one, blended in the report's order), `local` (ambient,
//! direct Phong light from point, spot and area lights, emission, diffuse
//! gather) and shadows through translucent occluders. The Monte-Carlo
//! effects it calls (ambient occlusion, soft shadows, the diffuse gather,
//! depth of field) are in `effects.rs`; Whitted area lights in `area.rs`.

use super::{saturate, Integrator, PixelContext, RayObserver, Sum};
use super::{TAG_AO, TAG_GATHER, TAG_REFLECT, TAG_REFRACT, TAG_SHADOW};
use crate::geometry::optics::{reflect, refract};
use crate::lights::incident;
use crate::sampling::hash2;
use crate::world::SurfacePoint;
use glam::Vec3;

/// Reflection and refraction branches contributing less than this to the
/// pixel are not traced (see `Integrator::radiance`).
pub const MIN_BRANCH_WEIGHT: f32 = 1e-4;

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
pub(super) struct Pending {
    /// The colour so far: local, then blended with the refracted colour.
    c: Vec3,
    opacity: f32,
    reflectivity: f32,
    depth: u32,
    /// The reflected ray, when it is still to be traced after the refracted one.
    reflect: Option<Branch>,
    awaiting: Child,
}

/// What shading one ray of the Whitted tree gives: a final color, or a node
/// waiting for the color of its first child, the ray to trace next.
enum Shaded {
    Leaf(Vec3),
    Node(Pending, Branch),
}

impl<'a, O: RayObserver> Integrator<'a, O> {
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
    pub(super) fn radiance(&self, ctx: &mut PixelContext, origin: Vec3, dir: Vec3) -> Vec3 {
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
    pub(super) fn direct(
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
            // Soft shadows (effects.rs): `shadow-samples` jittered
            // positions of a light with a radius, its position for the rest.
            let (samples, points) = self.soft_shadow_points(ctx, light, j, stream);
            let mut sum = Sum::<Vec3>::default();
            for k in 0..samples {
                let pos =
                    self.light_sample_position(light, j, points.as_ref(), sp.p, index, samples, k);
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
    pub(super) fn visibility(
        &self,
        ctx: &mut PixelContext,
        sp: &SurfacePoint,
        light_pos: Vec3,
    ) -> f32 {
        let o = sp.spawn(light_pos - sp.p);
        // dir spans the whole segment, so t < 1 is "before the light".
        self.trace_shadow(ctx, o, light_pos - o, 1.0 - 1e-6)
    }
}

#[cfg(test)]
mod tests {
    use crate::integrator::{Integrator, RenderOptions};
    use crate::scene::MAX_DEPTH;
    use crate::testing::{on_a_small_stack, scene};

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
            Integrator::observed(&s, 0, RenderOptions::default(), &())
                .pixel(0, 0)
                .unwrap()
        });
        assert_eq!(rays, u64::from(MAX_DEPTH) + 1);
        assert_eq!(px, [0.2f32 * 0.5, 0.4 * 0.5, 0.6 * 0.5]);
    }
}
