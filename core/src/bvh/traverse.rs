//! Walking the tree: closest-hit, any-hit and every-hit queries through one
//! generic walk, with both children's boxes tested at once in SSE where that
//! cannot differ from the scalar test (see the module doc of [`super`]).

use super::{Bvh, Ref, Visit};
use crate::geometry::{ray_box, Aabb};
use glam::Vec3;
use std::mem::MaybeUninit;

/// Depth of the traversal stack; deeper trees fall back to recursion at the
/// same point, in the same order, as the reference tree's walk does, so that
/// the visit order is the same. (Tests use a shallow stack so that the
/// fallback is exercised.)
pub(super) const STACK: usize = if cfg!(test) { 6 } else { 64 };

impl Bvh {
    /// Visits, nearest box first, every leaf primitive whose box the ray
    /// `origin + t·dir`, `t ∈ (0, t_max)` enters; `visit` intersects it.
    /// Returns the final `t_max` and whether any primitive reported a hit.
    #[inline]
    pub fn traverse<F: FnMut(u32, f32) -> Visit>(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_max: f32,
        mut visit: F,
    ) -> (f32, bool) {
        if self.len == 0 {
            return (t_max, false);
        }
        let inv = dir.recip();
        if ray_box(origin, inv, self.root_box.min, self.root_box.max, t_max).is_none() {
            return (t_max, false);
        }
        #[cfg(target_arch = "x86_64")]
        {
            if self.finite && origin.is_finite() && dir.is_finite() && inv.is_finite() {
                // SAFETY: SSE2 is part of the x86_64 baseline.
                return unsafe { self.traverse_sse(origin, dir, inv, t_max, &mut visit) };
            }
        }
        self.traverse_scalar(origin, dir, inv, t_max, &mut visit)
    }

    /// Visits the primitives of leaf `r`; true if the visitor said `Stop`.
    #[inline(always)]
    fn visit_leaf<F: FnMut(u32, f32) -> Visit>(
        &self,
        r: Ref,
        t_max: &mut f32,
        hit: &mut bool,
        visit: &mut F,
    ) -> bool {
        let first = r.first as usize;
        for i in first..first + r.count as usize {
            match visit(self.prim(i), *t_max) {
                Visit::Miss => {}
                Visit::Hit(t) => {
                    *hit = true;
                    if t < *t_max {
                        *t_max = t;
                    }
                }
                Visit::Stop => return true,
            }
        }
        false
    }

    fn traverse_scalar<F: FnMut(u32, f32) -> Visit>(
        &self,
        origin: Vec3,
        dir: Vec3,
        inv: Vec3,
        mut t_max: f32,
        visit: &mut F,
    ) -> (f32, bool) {
        let mut hit = false;
        // Left uninitialised: zeroing 768 bytes per walk (twice per ray,
        // top level and mesh) was measurable; slots are read only below `sp`.
        let mut stack = [const { MaybeUninit::<(Ref, f32)>::uninit() }; STACK];
        let mut sp = 0usize;
        let mut node = self.root;
        loop {
            if node.count > 0 {
                if self.visit_leaf(node, &mut t_max, &mut hit, visit) {
                    return (t_max, true);
                }
            } else {
                let p = &self.pairs[node.first as usize];
                let ta = ray_box(origin, inv, p.child_min(0), p.child_max(0), t_max);
                let tb = ray_box(origin, inv, p.child_min(1), p.child_max(1), t_max);
                match (ta, tb) {
                    (Some(x), Some(y)) => {
                        let (near, far, t_far) = if x <= y { (0, 1, y) } else { (1, 0, x) };
                        if sp < STACK {
                            stack[sp] = MaybeUninit::new((p.child[far], t_far));
                            sp += 1;
                        } else {
                            let (t2, h2) = self.traverse_from(
                                p.child[far],
                                p.child_box(far),
                                origin,
                                dir,
                                t_max,
                                visit,
                            );
                            t_max = t2;
                            hit |= h2;
                        }
                        node = p.child[near];
                        continue;
                    }
                    (Some(_), None) => {
                        node = p.child[0];
                        continue;
                    }
                    (None, Some(_)) => {
                        node = p.child[1];
                        continue;
                    }
                    (None, None) => {}
                }
            }
            // Pop the next node that the (possibly shortened) ray still
            // enters: it was entered at `enter` before `t_max` shrank, so it
            // still is exactly when `enter <= t_max·(1 + 4e-7)` ([`ray_box`]).
            loop {
                if sp == 0 {
                    return (t_max, hit);
                }
                sp -= 1;
                // SAFETY: slots below `sp` were written by the pushes above.
                let (c, enter) = unsafe { stack[sp].assume_init() };
                if enter <= t_max * 1.000_000_4 {
                    node = c;
                    break;
                }
            }
        }
    }

    /// The same walk with both children's boxes tested at once in SSE.
    /// Only for rays and boxes where no NaN can arise (see the module doc).
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn traverse_sse<F: FnMut(u32, f32) -> Visit>(
        &self,
        origin: Vec3,
        dir: Vec3,
        inv: Vec3,
        mut t_max: f32,
        visit: &mut F,
    ) -> (f32, bool) {
        use std::arch::x86_64::*;
        let o_xy = _mm_setr_ps(origin.x, origin.x, origin.y, origin.y);
        let i_xy = _mm_setr_ps(inv.x, inv.x, inv.y, inv.y);
        let o_z = _mm_set1_ps(origin.z);
        let i_z = _mm_set1_ps(inv.z);
        let zero = _mm_setzero_ps();
        let slack = _mm_set1_ps(1.000_000_4);
        let mut hit = false;
        // Left uninitialised: zeroing 768 bytes per walk (twice per ray,
        // top level and mesh) was measurable; slots are read only below `sp`.
        let mut stack = [const { MaybeUninit::<(Ref, f32)>::uninit() }; STACK];
        let mut sp = 0usize;
        let mut node = self.root;
        loop {
            if node.count > 0 {
                if self.visit_leaf(node, &mut t_max, &mut hit, visit) {
                    return (t_max, true);
                }
            } else {
                let p = self.pairs.get_unchecked(node.first as usize);
                let t0 = _mm_mul_ps(_mm_sub_ps(_mm_load_ps(p.min_xy.as_ptr()), o_xy), i_xy);
                let t1 = _mm_mul_ps(_mm_sub_ps(_mm_load_ps(p.max_xy.as_ptr()), o_xy), i_xy);
                let tz = _mm_mul_ps(_mm_sub_ps(_mm_load_ps(p.z.as_ptr()), o_z), i_z);
                let tz_hi = _mm_movehl_ps(tz, tz);
                // Lanes 0, 1: left, right.
                let lo = _mm_min_ps(t0, t1);
                let hi = _mm_max_ps(t0, t1);
                let enter = _mm_max_ps(
                    _mm_max_ps(_mm_max_ps(lo, _mm_movehl_ps(lo, lo)), _mm_min_ps(tz, tz_hi)),
                    zero,
                );
                let exit = _mm_min_ps(
                    _mm_min_ps(_mm_min_ps(hi, _mm_movehl_ps(hi, hi)), _mm_max_ps(tz, tz_hi)),
                    _mm_set1_ps(t_max),
                );
                let mask = _mm_movemask_ps(_mm_cmple_ps(enter, _mm_mul_ps(exit, slack))) & 3;
                match mask {
                    3 => {
                        let mut e = [0.0f32; 4];
                        _mm_storeu_ps(e.as_mut_ptr(), enter);
                        let (near, far, t_far) = if e[0] <= e[1] {
                            (0, 1, e[1])
                        } else {
                            (1, 0, e[0])
                        };
                        if sp < STACK {
                            *stack.get_unchecked_mut(sp) = MaybeUninit::new((p.child[far], t_far));
                            sp += 1;
                        } else {
                            let (t2, h2) = self.traverse_from(
                                p.child[far],
                                p.child_box(far),
                                origin,
                                dir,
                                t_max,
                                visit,
                            );
                            t_max = t2;
                            hit |= h2;
                        }
                        node = p.child[near];
                        continue;
                    }
                    1 => {
                        node = p.child[0];
                        continue;
                    }
                    2 => {
                        node = p.child[1];
                        continue;
                    }
                    _ => {}
                }
            }
            loop {
                if sp == 0 {
                    return (t_max, hit);
                }
                sp -= 1;
                let (c, enter) = stack.get_unchecked(sp).assume_init();
                if enter <= t_max * 1.000_000_4 {
                    node = c;
                    break;
                }
            }
        }
    }

    /// Simple recursive walk (children left then right, each box tested on
    /// entry), used only past [`STACK`] levels of nesting.
    fn traverse_from<F: FnMut(u32, f32) -> Visit>(
        &self,
        r: Ref,
        b: Aabb,
        origin: Vec3,
        dir: Vec3,
        t_max: f32,
        visit: &mut F,
    ) -> (f32, bool) {
        let inv = dir.recip();
        if ray_box(origin, inv, b.min, b.max, t_max).is_none() {
            return (t_max, false);
        }
        let mut t_max = t_max;
        let mut hit = false;
        if r.count > 0 {
            let first = r.first as usize;
            for i in first..first + r.count as usize {
                match visit(self.prim(i), t_max) {
                    Visit::Miss => {}
                    Visit::Hit(t) => {
                        hit = true;
                        t_max = t_max.min(t);
                    }
                    Visit::Stop => return (t_max, true),
                }
            }
        } else {
            let p = &self.pairs[r.first as usize];
            for c in 0..2 {
                let (t, h) =
                    self.traverse_from(p.child[c], p.child_box(c), origin, dir, t_max, visit);
                t_max = t;
                hit |= h;
            }
        }
        (t_max, hit)
    }
}
