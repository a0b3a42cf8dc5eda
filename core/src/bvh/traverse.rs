//! Walking the wide tree: closest-hit, any-hit and every-hit queries through
//! one generic walk, nearest child first, a node's eight boxes tested at
//! once on the path chosen in [`simd`] (the same bits on each; the walk is
//! monomorphised per path and chosen by one branch per walk).
//! Queries whose answer cannot depend on the visit order (opaque shadow
//! rays: is anything hit at all?) skip the sort and take the entered
//! children in slot order ([`Bvh::traverse_unordered`]).

use super::simd::{self, NodeRay, NodeTest, ScalarTest, Simd, Stack, SLACK};
use super::{Bvh, Ref, Visit, WIDTH};
use glam::Vec3;

/// How a walk ended: the final `t_max`, whether any primitive reported a
/// hit, and whether the visitor said `Stop`.
struct Walked {
    t_max: f32,
    hit: bool,
    stop: bool,
}

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
        visit: F,
    ) -> (f32, bool) {
        self.traverse_on::<F, true>(simd::current(), origin, dir, t_max, visit)
    }

    /// [`Bvh::traverse`] for a visitor whose answer cannot depend on the
    /// order of its visits (an any-hit query that stops at the first hit):
    /// the entered children are visited in slot order, without sorting them
    /// by entry distance. Every primitive `traverse` would visit before a
    /// `Stop` is still offered, so whether anything is hit is the same.
    #[inline]
    pub fn traverse_unordered<F: FnMut(u32, f32) -> Visit>(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_max: f32,
        visit: F,
    ) -> (f32, bool) {
        self.traverse_on::<F, false>(simd::current(), origin, dir, t_max, visit)
    }

    /// [`Bvh::traverse`] (`ORDERED`) or [`Bvh::traverse_unordered`] on the
    /// given path (the same visits on each).
    #[inline(always)]
    pub(crate) fn traverse_on<F: FnMut(u32, f32) -> Visit, const ORDERED: bool>(
        &self,
        path: Simd,
        origin: Vec3,
        dir: Vec3,
        t_max: f32,
        mut visit: F,
    ) -> (f32, bool) {
        self.traverse_leaves_on::<_, ORDERED>(path, origin, dir, t_max, |first, count, t_max| {
            let mut t_max = t_max;
            let mut result = Visit::Miss;
            for i in first as usize..(first + count) as usize {
                match visit(self.prim(i), t_max) {
                    Visit::Miss => {}
                    Visit::Hit(t) => {
                        if t < t_max {
                            t_max = t;
                        }
                        result = Visit::Hit(t_max);
                    }
                    Visit::Stop => return Visit::Stop,
                }
            }
            result
        })
    }

    /// The walk under every query: `leaf(first, count, t_max)` is called
    /// for each leaf the ray enters (nearest first when `ORDERED`, else in
    /// slot order), with its leaf positions `first..first + count`, and
    /// answers for the leaf as a whole. A tree that is one leaf calls it
    /// for that leaf without testing its box.
    #[inline(always)]
    pub(super) fn traverse_leaves_on<F: FnMut(u32, u32, f32) -> Visit, const ORDERED: bool>(
        &self,
        path: Simd,
        origin: Vec3,
        dir: Vec3,
        t_max: f32,
        mut leaf: F,
    ) -> (f32, bool) {
        if self.len == 0 {
            return (t_max, false);
        }
        if self.root.count > 0 {
            // A tree that is one leaf (the top level of a scene of one
            // model, a mesh of up to four triangles): its primitives are
            // tested without the root box, which could only cull rays they
            // miss (a box test is conservative; the primitive tests are
            // exact), and without the node ray's three divisions.
            return match leaf(self.root.first, self.root.count, t_max) {
                Visit::Miss => (t_max, false),
                Visit::Hit(t) => (if t < t_max { t } else { t_max }, true),
                Visit::Stop => (t_max, true),
            };
        }
        let ray = NodeRay::new(origin, dir);
        // The root box, as one lane of the scalar test (the same bits as
        // any path's).
        let b = self.root_box;
        let root = [
            [b.min.x; WIDTH],
            [b.max.x; WIDTH],
            [b.min.y; WIDTH],
            [b.max.y; WIDTH],
            [b.min.z; WIDTH],
            [b.max.z; WIDTH],
        ];
        if !simd::lane(&root, &ray, t_max, 0).1 {
            return (t_max, false);
        }
        let w = match path {
            #[cfg(target_arch = "x86_64")]
            Simd::Avx => match simd::AvxTest::new() {
                Some(avx) => self.walk_in::<_, F, ORDERED>(avx, self.root, &ray, t_max, &mut leaf),
                None => {
                    self.walk_in::<_, F, ORDERED>(simd::SseTest, self.root, &ray, t_max, &mut leaf)
                }
            },
            #[cfg(target_arch = "x86_64")]
            Simd::Sse => {
                self.walk_in::<_, F, ORDERED>(simd::SseTest, self.root, &ray, t_max, &mut leaf)
            }
            _ => self.walk_in::<_, F, ORDERED>(ScalarTest, self.root, &ray, t_max, &mut leaf),
        };
        (w.t_max, w.hit)
    }

    /// [`Bvh::walk`] compiled for the instruction set of `test`'s path.
    #[inline(always)]
    fn walk_in<T: NodeTest, F: FnMut(u32, u32, f32) -> Visit, const ORDERED: bool>(
        &self,
        test: T,
        start: Ref,
        ray: &NodeRay,
        t_max: f32,
        visit: &mut F,
    ) -> Walked {
        // Inlined into the region, so that the walk is compiled for its
        // instruction set (a call per node test otherwise).
        test.region(
            #[inline(always)]
            || self.walk::<T, F, ORDERED>(test, start, ray, t_max, visit),
        )
    }

    /// The walk from `start` (already entered). `test`: the node test's
    /// path; `ORDERED`: entered children nearest first (else in slot order).
    #[inline(always)]
    fn walk<T: NodeTest, F: FnMut(u32, u32, f32) -> Visit, const ORDERED: bool>(
        &self,
        test: T,
        start: Ref,
        ray: &NodeRay,
        mut t_max: f32,
        visit: &mut F,
    ) -> Walked {
        let mut hit = false;
        let mut stack = Stack::new();
        let mut node = start;
        loop {
            if node.count > 0 {
                match visit(node.first, node.count, t_max) {
                    Visit::Miss => {}
                    Visit::Hit(t) => {
                        hit = true;
                        if t < t_max {
                            t_max = t;
                        }
                    }
                    Visit::Stop => {
                        return Walked {
                            t_max,
                            hit: true,
                            stop: true,
                        }
                    }
                }
            } else {
                let n = &self.nodes[node.first as usize];
                let (enter, mask) = test.test(n, ray, t_max);
                // The entered children by entry distance, equal ones in
                // slot order (insertion sort of at most WIDTH).
                let mut order = [0usize; WIDTH];
                let mut k = 0;
                for i in 0..WIDTH {
                    if mask & (1 << i) == 0 || n.child[i] == Ref::NONE {
                        continue;
                    }
                    let mut j = k;
                    while ORDERED && j > 0 && enter[order[j - 1]] > enter[i] {
                        order[j] = order[j - 1];
                        j -= 1;
                    }
                    order[j] = i;
                    k += 1;
                }
                if k > 0 {
                    // Farthest pushed first, so popped last.
                    for &i in order[1..k].iter().rev() {
                        if !stack.push((n.child[i], enter[i])) {
                            // Stack full: walk that subtree now.
                            let w = self.walk_overflow::<T, F, ORDERED>(
                                test, n.child[i], ray, t_max, visit,
                            );
                            t_max = w.t_max;
                            hit |= w.hit;
                            if w.stop {
                                return w;
                            }
                        }
                    }
                    node = n.child[order[0]];
                    continue;
                }
            }
            // The next pushed node the (possibly shortened) ray still
            // enters: it was entered at `enter` before `t_max` shrank, so it
            // still is exactly when `enter <= t_max · SLACK`.
            loop {
                let Some((c, enter)) = stack.pop() else {
                    return Walked {
                        t_max,
                        hit,
                        stop: false,
                    };
                };
                if enter <= t_max * SLACK {
                    node = c;
                    break;
                }
            }
        }
    }

    /// The walk of a subtree whose root did not fit on the stack: a call,
    /// not inlined, since [`Bvh::walk`] is.
    #[inline(never)]
    fn walk_overflow<T: NodeTest, F: FnMut(u32, u32, f32) -> Visit, const ORDERED: bool>(
        &self,
        test: T,
        start: Ref,
        ray: &NodeRay,
        t_max: f32,
        visit: &mut F,
    ) -> Walked {
        self.walk_in::<T, F, ORDERED>(test, start, ray, t_max, visit)
    }
}
