//! Bounding volume hierarchy: a binned-SAH binary tree over primitive boxes.
//!
//! One builder serves both levels of the acceleration structure: the bottom
//! level (triangles of one mesh, in object space) and the top level (model
//! instances and spheres, in world space). The tree only stores indices; the
//! caller's closure intersects the primitives, so traversal is generic and
//! statically dispatched.
//!
//! Layout: an interior node is stored as the *pair* of its children's boxes
//! (64 bytes, one cache line, laid out so that SSE tests both boxes at once)
//! plus the two child references; the root's box is kept apart. That is the
//! same 32 bytes per node as a node-per-box layout, but one load serves both
//! children and the box of a node popped from the stack need not be tested
//! again (its entry distance is kept on the stack).
//!
//! Exactness: the closest-hit query keeps the *first* of several hits at the
//! same distance (two triangles sharing an edge), and translucent shadow rays
//! multiply their factors in visit order, so the order in which primitives
//! are visited is part of the rendered image. Build and traversal here visit
//! exactly the primitives, in exactly the order, of the original
//! one-node-per-box implementation (kept in the tests as a reference and
//! compared against on random scenes): the same splits and in-place partition,
//! children visited nearest entry first with ties to the left, popped nodes
//! culled on the same condition, the same fallback past 64 levels. The SIMD
//! box test is used only for rays whose arithmetic cannot produce a NaN
//! (finite origin, finite non-zero direction components, finite boxes), where
//! it computes bit-for-bit the values of the scalar [`ray_box`]; other rays
//! take the scalar path.

use crate::geometry::{ray_box, Aabb};
use glam::Vec3;
use std::mem::MaybeUninit;

/// What the primitive closure tells the traversal.
pub enum Visit {
    /// No hit (or one that does not shorten the ray).
    Miss,
    /// A hit at this parameter: only closer hits matter from now on.
    Hit(f32),
    /// Stop now (any-hit queries).
    Stop,
}

/// A child reference: `count == 0`: the interior node `pairs[first]`;
/// `count > 0`: the leaf `prims[first..first + count]`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Ref {
    first: u32,
    count: u32,
}

/// The two children of an interior node: their boxes, lane-interleaved
/// (left, right) so one SSE register holds the same coordinate of both.
#[derive(Debug, Clone, Copy, Default)]
#[repr(C, align(64))]
struct Pair {
    /// `[l.min.x, r.min.x, l.min.y, r.min.y]`
    min_xy: [f32; 4],
    /// `[l.max.x, r.max.x, l.max.y, r.max.y]`
    max_xy: [f32; 4],
    /// `[l.min.z, r.min.z, l.max.z, r.max.z]`
    z: [f32; 4],
    child: [Ref; 2],
}

impl Pair {
    fn new(l: Aabb, r: Aabb, lref: Ref, rref: Ref) -> Pair {
        Pair {
            min_xy: [l.min.x, r.min.x, l.min.y, r.min.y],
            max_xy: [l.max.x, r.max.x, l.max.y, r.max.y],
            z: [l.min.z, r.min.z, l.max.z, r.max.z],
            child: [lref, rref],
        }
    }

    #[inline(always)]
    fn child_min(&self, i: usize) -> Vec3 {
        Vec3::new(self.min_xy[i], self.min_xy[2 + i], self.z[i])
    }

    #[inline(always)]
    fn child_max(&self, i: usize) -> Vec3 {
        Vec3::new(self.max_xy[i], self.max_xy[2 + i], self.z[2 + i])
    }

    fn child_box(&self, i: usize) -> Aabb {
        Aabb {
            min: self.child_min(i),
            max: self.child_max(i),
        }
    }
}

#[derive(Debug, Clone)]
pub struct Bvh {
    pairs: Vec<Pair>,
    /// Primitive indices in leaf order; empty once the caller has taken
    /// them ([`Bvh::take_leaf_order`]) and numbered its primitives so.
    prims: Vec<u32>,
    /// Number of primitives.
    len: u32,
    root: Ref,
    root_box: Aabb,
    /// Every box is finite: the SIMD box test may be used.
    finite: bool,
}

impl Default for Bvh {
    /// The empty tree.
    fn default() -> Bvh {
        Bvh {
            pairs: Vec::new(),
            prims: Vec::new(),
            len: 0,
            root: Ref::default(),
            root_box: Aabb::EMPTY,
            finite: false,
        }
    }
}

const BINS: usize = 16;
const TRAVERSAL_COST: f32 = 1.0;
const INTERSECT_COST: f32 = 1.0;
/// Depth of the traversal stack; deeper trees fall back to recursion at the
/// same point, in the same order, as the original implementation did. (Tests
/// use a shallow stack so that the fallback is exercised.)
const STACK: usize = if cfg!(test) { 6 } else { 64 };
/// Subtrees of at least this many primitives are built in parallel.
const PAR_SUBTREE: usize = 8192;
/// Nodes of at least this many primitives are binned in parallel.
const PAR_BINNING: usize = 65536;
const PAR_CHUNK: usize = 16384;

/// The build inputs shared by every node.
struct Input<'a> {
    boxes: &'a [Aabb],
    centroids: &'a [Vec3],
    max_leaf: usize,
}

/// A split: `mid` primitives go left; the children's boxes and centroid boxes.
struct Split {
    mid: usize,
    left: Aabb,
    left_c: Aabb,
    right: Aabb,
    right_c: Aabb,
}

impl Bvh {
    /// Builds the tree; `max_leaf` bounds a leaf's primitive count except
    /// where primitives cannot be told apart at all.
    pub fn build(boxes: &[Aabb], max_leaf: usize) -> Bvh {
        use rayon::prelude::*;
        let n = boxes.len();
        let mut prims: Vec<u32> = (0..n as u32).collect();
        if boxes.is_empty() {
            return Bvh::default();
        }
        let centroids: Vec<Vec3> = boxes.par_iter().map(|b| b.center()).collect();
        let (bounds, cb) = boxes
            .par_chunks(PAR_CHUNK)
            .zip(centroids.par_chunks(PAR_CHUNK))
            .map(|(bs, cs)| {
                (
                    bs.iter().fold(Aabb::EMPTY, |a, &b| a.union(b)),
                    cs.iter().fold(Aabb::EMPTY, |a, &c| a.grow(c)),
                )
            })
            .reduce(
                || (Aabb::EMPTY, Aabb::EMPTY),
                |a, b| (a.0.union(b.0), a.1.union(b.1)),
            );
        let input = Input {
            boxes,
            centroids: &centroids,
            max_leaf,
        };
        let mut bins = vec![0u8; n];
        let mut pairs = Vec::with_capacity(n / 2 + 1);
        let root = build_node(&input, &mut prims, &mut bins, 0, 0, bounds, cb, &mut pairs);
        pairs.shrink_to_fit();
        let finite = bounds.min.is_finite()
            && bounds.max.is_finite()
            && pairs.iter().all(|p| {
                p.min_xy
                    .iter()
                    .chain(&p.max_xy)
                    .chain(&p.z)
                    .all(|c| c.is_finite())
            });
        Bvh {
            pairs,
            len: n as u32,
            prims,
            root,
            root_box: bounds,
            finite,
        }
    }

    pub fn bounds(&self) -> Aabb {
        self.root_box
    }

    /// Hands over the primitive order of the leaves: `order[k]` is the
    /// primitive the traversal visits as number `k`. The caller renumbers
    /// its primitives so that primitive `k` is `order[k]` (leaf neighbours
    /// become memory neighbours), and the tree reports `k` from then on,
    /// without keeping an index array. The tree and its visits are unchanged.
    pub fn take_leaf_order(&mut self) -> Vec<u32> {
        std::mem::take(&mut self.prims)
    }

    /// The primitive in leaf position `i`.
    #[inline(always)]
    fn prim(&self, i: usize) -> u32 {
        if self.prims.is_empty() {
            i as u32
        } else {
            self.prims[i]
        }
    }

    /// Heap bytes of the tree (nodes and primitive indices).
    pub fn heap_bytes(&self) -> usize {
        self.pairs.capacity() * std::mem::size_of::<Pair>()
            + self.prims.capacity() * std::mem::size_of::<u32>()
    }

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

    /// Visits the primitives of leaf `r`; `Err` carries the result of a `Stop`.
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

    /// The tree's SAH cost (traversal 1, intersection 1), relative to the
    /// root's area: the usual measure of tree quality.
    pub fn sah_cost(&self) -> f32 {
        if self.len == 0 {
            return 0.0;
        }
        let root_area = self.root_box.half_area().max(f32::MIN_POSITIVE) as f64;
        let cost = |b: Aabb, r: Ref| -> f64 {
            let a = b.half_area() as f64 / root_area;
            if r.count > 0 {
                a * (INTERSECT_COST * r.count as f32) as f64
            } else {
                a * TRAVERSAL_COST as f64
            }
        };
        let mut sum = cost(self.root_box, self.root);
        for p in &self.pairs {
            sum += cost(p.child_box(0), p.child[0]) + cost(p.child_box(1), p.child[1]);
        }
        sum as f32
    }

    /// The leaves in the order of the tree's layout, for tests: (box, prims).
    #[cfg(test)]
    fn leaves(&self) -> Vec<(Aabb, &[u32])> {
        let mut out = Vec::new();
        let mut stack = vec![(self.root, self.root_box)];
        while let Some((r, b)) = stack.pop() {
            if r.count > 0 {
                out.push((
                    b,
                    &self.prims[r.first as usize..(r.first + r.count) as usize],
                ));
            } else {
                let p = &self.pairs[r.first as usize];
                assert!(p.child_min(0).cmpge(b.min).all() && p.child_max(0).cmple(b.max).all());
                assert!(p.child_min(1).cmpge(b.min).all() && p.child_max(1).cmple(b.max).all());
                stack.push((p.child[1], p.child_box(1)));
                stack.push((p.child[0], p.child_box(0)));
            }
        }
        out
    }
}

/// Builds the subtree over `prims` (which start at `offset` in the whole
/// array), whose boxes' union is `bounds` and centroids' union `cb`, into
/// `out`; `bins` is scratch aligned with `prims`. Returns its reference.
#[allow(clippy::too_many_arguments)]
fn build_node(
    input: &Input,
    prims: &mut [u32],
    bins: &mut [u8],
    offset: usize,
    depth: usize,
    bounds: Aabb,
    cb: Aabb,
    out: &mut Vec<Pair>,
) -> Ref {
    let count = prims.len();
    let split = if count <= 1 {
        None
    } else {
        find_split(input, prims, bins, bounds, cb)
    };
    let Some(s) = split else {
        return Ref {
            first: offset as u32,
            count: count as u32,
        };
    };
    let (lp, rp) = prims.split_at_mut(s.mid);
    let (lb, rb) = bins.split_at_mut(s.mid);
    let index = out.len();
    out.push(Pair::default());
    let (lref, rref) = if s.mid.min(count - s.mid) >= PAR_SUBTREE && depth < 4 {
        let mut lv = Vec::with_capacity(s.mid / 2);
        let mut rv = Vec::with_capacity((count - s.mid) / 2);
        let (lr, rr) = rayon::join(
            || build_node(input, lp, lb, offset, depth + 1, s.left, s.left_c, &mut lv),
            || {
                build_node(
                    input,
                    rp,
                    rb,
                    offset + s.mid,
                    depth + 1,
                    s.right,
                    s.right_c,
                    &mut rv,
                )
            },
        );
        (append(out, lv, lr), append(out, rv, rr))
    } else {
        let lr = build_node(input, lp, lb, offset, depth + 1, s.left, s.left_c, out);
        let rr = build_node(
            input,
            rp,
            rb,
            offset + s.mid,
            depth + 1,
            s.right,
            s.right_c,
            out,
        );
        (lr, rr)
    };
    out[index] = Pair::new(s.left, s.right, lref, rref);
    Ref {
        first: index as u32,
        count: 0,
    }
}

/// Appends a subtree built on its own, renumbering its interior nodes.
fn append(out: &mut Vec<Pair>, sub: Vec<Pair>, r: Ref) -> Ref {
    let base = out.len() as u32;
    let shift = |r: Ref| {
        if r.count == 0 {
            Ref {
                first: r.first + base,
                count: 0,
            }
        } else {
            r
        }
    };
    out.extend(sub.into_iter().map(|mut p| {
        p.child = p.child.map(shift);
        p
    }));
    shift(r)
}

/// Union of boxes and of centroids of `prims` (the rare unbinned splits).
fn fold_bounds(input: &Input, prims: &[u32]) -> (Aabb, Aabb) {
    prims.iter().fold((Aabb::EMPTY, Aabb::EMPTY), |(b, c), &p| {
        (
            b.union(input.boxes[p as usize]),
            c.grow(input.centroids[p as usize]),
        )
    })
}

fn middle_split(input: &Input, prims: &[u32]) -> Split {
    let mid = prims.len() / 2;
    let (left, left_c) = fold_bounds(input, &prims[..mid]);
    let (right, right_c) = fold_bounds(input, &prims[mid..]);
    Split {
        mid,
        left,
        left_c,
        right,
        right_c,
    }
}

#[derive(Clone, Copy)]
struct BinStats {
    boxes: [Aabb; BINS],
    centroids: [Aabb; BINS],
    count: [usize; BINS],
}

impl BinStats {
    const EMPTY: BinStats = BinStats {
        boxes: [Aabb::EMPTY; BINS],
        centroids: [Aabb::EMPTY; BINS],
        count: [0; BINS],
    };

    fn merge(mut self, o: BinStats) -> BinStats {
        for i in 0..BINS {
            self.boxes[i] = self.boxes[i].union(o.boxes[i]);
            self.centroids[i] = self.centroids[i].union(o.centroids[i]);
            self.count[i] += o.count[i];
        }
        self
    }
}

/// Chooses a split of `prims` (reordering it) by binned SAH; `None` makes a
/// leaf. `bounds` and `cb` are the unions of the primitives' boxes and
/// centroids. The decision and the partition are those of the original
/// builder, so the tree and its leaf order are too.
fn find_split(
    input: &Input,
    prims: &mut [u32],
    bins: &mut [u8],
    bounds: Aabb,
    cb: Aabb,
) -> Option<Split> {
    let count = prims.len();
    let max_leaf = input.max_leaf;
    let extent = cb.max - cb.min;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    if !(extent[axis] > 0.0) || !extent[axis].is_finite() {
        // All centroids coincide: SAH cannot separate them. Split in the
        // middle only to keep leaves small.
        return (count > max_leaf).then(|| middle_split(input, prims));
    }
    let scale = BINS as f32 / extent[axis];
    let lo = cb.min[axis];
    let centroids = input.centroids;
    let boxes = input.boxes;
    let bin_chunk = |ps: &[u32], bs: &mut [u8]| -> BinStats {
        let mut s = BinStats::EMPTY;
        for (&p, b) in ps.iter().zip(bs.iter_mut()) {
            let c = centroids[p as usize];
            let i = (((c[axis] - lo) * scale) as usize).min(BINS - 1);
            *b = i as u8;
            s.boxes[i] = s.boxes[i].union(boxes[p as usize]);
            s.centroids[i] = s.centroids[i].grow(c);
            s.count[i] += 1;
        }
        s
    };
    let stats = if count >= PAR_BINNING {
        use rayon::prelude::*;
        prims
            .par_chunks(PAR_CHUNK)
            .zip(bins.par_chunks_mut(PAR_CHUNK))
            .map(|(ps, bs)| bin_chunk(ps, bs))
            .reduce(|| BinStats::EMPTY, BinStats::merge)
    } else {
        bin_chunk(prims, bins)
    };
    let bin_box = &stats.boxes;
    let bin_count = &stats.count;
    // Sweep from the right to get suffix areas, then from the left.
    let mut right_area = [0.0f32; BINS];
    let mut acc = Aabb::EMPTY;
    let mut n = 0;
    let mut right_count = [0usize; BINS];
    for i in (1..BINS).rev() {
        acc = acc.union(bin_box[i]);
        n += bin_count[i];
        right_area[i] = acc.half_area();
        right_count[i] = n;
    }
    let mut best = (f32::INFINITY, 0usize);
    let mut acc = Aabb::EMPTY;
    let mut n = 0;
    for i in 0..BINS - 1 {
        acc = acc.union(bin_box[i]);
        n += bin_count[i];
        if n == 0 || right_count[i + 1] == 0 {
            continue;
        }
        let cost = acc.half_area() * n as f32 + right_area[i + 1] * right_count[i + 1] as f32;
        if cost < best.0 {
            best = (cost, i);
        }
    }
    let leaf_cost = bounds.half_area() * count as f32 * INTERSECT_COST;
    let split_cost = TRAVERSAL_COST * bounds.half_area() + INTERSECT_COST * best.0;
    if !best.0.is_finite() {
        return (count > max_leaf).then(|| middle_split(input, prims));
    }
    if count <= max_leaf && split_cost >= leaf_cost {
        return None;
    }
    // Partition in place (the original builder's order of swaps).
    let split_bin = best.1 as u8;
    let mut i = 0;
    let mut j = count;
    while i < j {
        if bins[i] <= split_bin {
            i += 1;
        } else {
            j -= 1;
            prims.swap(i, j);
            bins.swap(i, j);
        }
    }
    let mut s = Split {
        mid: i,
        left: Aabb::EMPTY,
        left_c: Aabb::EMPTY,
        right: Aabb::EMPTY,
        right_c: Aabb::EMPTY,
    };
    for (k, (b, c)) in bin_box.iter().zip(&stats.centroids).enumerate() {
        if k <= best.1 {
            s.left = s.left.union(*b);
            s.left_c = s.left_c.union(*c);
        } else {
            s.right = s.right.union(*b);
            s.right_c = s.right_c.union(*c);
        }
    }
    Some(s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::ray_box;

    /// The original one-node-per-box implementation, verbatim but for the
    /// stack depth (shallow in tests, as above): the new build and traversal
    /// must visit exactly what and as it did.
    #[allow(dead_code)]
    mod reference {
        use super::super::Visit;
        use crate::geometry::{ray_box, Aabb};
        use glam::Vec3;

        /// 32 bytes. `count == 0`: interior node whose children are `first` and
        /// `first + 1`. `count > 0`: leaf holding `prims[first..first + count]`.
        #[derive(Debug, Clone, Copy)]
        #[repr(C)]
        pub struct Node {
            pub min: Vec3,
            pub first: u32,
            pub max: Vec3,
            pub count: u32,
        }

        #[derive(Debug, Clone, Default)]
        pub struct RefBvh {
            pub nodes: Vec<Node>,
            /// Primitive indices in leaf order.
            pub prims: Vec<u32>,
        }

        const BINS: usize = 16;
        const TRAVERSAL_COST: f32 = 1.0;
        const INTERSECT_COST: f32 = 1.0;

        impl RefBvh {
            /// Builds the tree; `max_leaf` bounds a leaf's primitive count except
            /// where primitives cannot be told apart at all.
            pub fn build(boxes: &[Aabb], max_leaf: usize) -> RefBvh {
                let mut bvh = RefBvh {
                    nodes: Vec::with_capacity(boxes.len().max(1) * 2),
                    prims: (0..boxes.len() as u32).collect(),
                };
                if boxes.is_empty() {
                    return bvh;
                }
                let centroids: Vec<Vec3> = boxes.iter().map(|b| b.center()).collect();
                bvh.nodes.push(Node {
                    min: Vec3::ZERO,
                    first: 0,
                    max: Vec3::ZERO,
                    count: 0,
                });
                let mut stack = vec![(0usize, 0usize, boxes.len())];
                while let Some((node, start, end)) = stack.pop() {
                    let bounds = bvh.prims[start..end]
                        .iter()
                        .fold(Aabb::EMPTY, |b, &p| b.union(boxes[p as usize]));
                    bvh.nodes[node].min = bounds.min;
                    bvh.nodes[node].max = bounds.max;
                    let count = end - start;
                    let split = if count <= 1 {
                        None
                    } else {
                        find_split(
                            &mut bvh.prims[start..end],
                            boxes,
                            &centroids,
                            bounds,
                            max_leaf,
                        )
                    };
                    match split {
                        None => {
                            bvh.nodes[node].first = start as u32;
                            bvh.nodes[node].count = count as u32;
                        }
                        Some(mid) => {
                            let left = bvh.nodes.len();
                            let empty = Node {
                                min: Vec3::ZERO,
                                first: 0,
                                max: Vec3::ZERO,
                                count: 0,
                            };
                            bvh.nodes.push(empty);
                            bvh.nodes.push(empty);
                            bvh.nodes[node].first = left as u32;
                            bvh.nodes[node].count = 0;
                            stack.push((left + 1, start + mid, end));
                            stack.push((left, start, start + mid));
                        }
                    }
                }
                bvh
            }

            pub fn bounds(&self) -> Aabb {
                self.nodes.first().map_or(Aabb::EMPTY, |n| Aabb {
                    min: n.min,
                    max: n.max,
                })
            }

            /// Visits, nearest box first, every leaf primitive whose box the ray
            /// `origin + t·dir`, `t ∈ (0, t_max)` enters; `visit` intersects it.
            /// Returns the final `t_max` and whether any primitive reported a hit.
            #[inline]
            pub fn traverse<F: FnMut(u32, f32) -> Visit>(
                &self,
                origin: Vec3,
                dir: Vec3,
                mut t_max: f32,
                mut visit: F,
            ) -> (f32, bool) {
                let mut hit = false;
                if self.nodes.is_empty() {
                    return (t_max, hit);
                }
                let inv = dir.recip();
                let root = &self.nodes[0];
                if ray_box(origin, inv, root.min, root.max, t_max).is_none() {
                    return (t_max, hit);
                }
                let mut stack = [0u32; super::super::STACK]; // 64 outside tests
                let mut sp = 0usize;
                let mut node = 0usize;
                loop {
                    let n = self.nodes[node];
                    if n.count > 0 {
                        let first = n.first as usize;
                        for &p in &self.prims[first..first + n.count as usize] {
                            match visit(p, t_max) {
                                Visit::Miss => {}
                                Visit::Hit(t) => {
                                    hit = true;
                                    if t < t_max {
                                        t_max = t;
                                    }
                                }
                                Visit::Stop => return (t_max, true),
                            }
                        }
                    } else {
                        let l = n.first as usize;
                        let (a, b) = (&self.nodes[l], &self.nodes[l + 1]);
                        let ta = ray_box(origin, inv, a.min, a.max, t_max);
                        let tb = ray_box(origin, inv, b.min, b.max, t_max);
                        match (ta, tb) {
                            (Some(x), Some(y)) => {
                                let (near, far) = if x <= y { (l, l + 1) } else { (l + 1, l) };
                                if sp < stack.len() {
                                    stack[sp] = far as u32;
                                    sp += 1;
                                    node = near;
                                    continue;
                                }
                                // Deeper than the stack (only for pathological trees):
                                // fall back to visiting the far child later via recursion.
                                let (t2, h2) =
                                    self.traverse_from(far, origin, dir, t_max, &mut visit);
                                t_max = t2;
                                hit |= h2;
                                node = near;
                                continue;
                            }
                            (Some(_), None) => {
                                node = l;
                                continue;
                            }
                            (None, Some(_)) => {
                                node = l + 1;
                                continue;
                            }
                            (None, None) => {}
                        }
                    }
                    // Pop the next node that the (possibly shortened) ray still enters.
                    loop {
                        if sp == 0 {
                            return (t_max, hit);
                        }
                        sp -= 1;
                        let c = stack[sp] as usize;
                        let cn = &self.nodes[c];
                        if ray_box(origin, inv, cn.min, cn.max, t_max).is_some() {
                            node = c;
                            break;
                        }
                    }
                }
            }

            fn traverse_from<F: FnMut(u32, f32) -> Visit>(
                &self,
                start: usize,
                origin: Vec3,
                dir: Vec3,
                t_max: f32,
                visit: &mut F,
            ) -> (f32, bool) {
                // Simple recursive walk, used only past 64 levels of nesting.
                let inv = dir.recip();
                let n = self.nodes[start];
                if ray_box(origin, inv, n.min, n.max, t_max).is_none() {
                    return (t_max, false);
                }
                let mut t_max = t_max;
                let mut hit = false;
                if n.count > 0 {
                    let first = n.first as usize;
                    for &p in &self.prims[first..first + n.count as usize] {
                        match visit(p, t_max) {
                            Visit::Miss => {}
                            Visit::Hit(t) => {
                                hit = true;
                                t_max = t_max.min(t);
                            }
                            Visit::Stop => return (t_max, true),
                        }
                    }
                } else {
                    for c in [n.first as usize, n.first as usize + 1] {
                        let (t, h) = self.traverse_from(c, origin, dir, t_max, visit);
                        t_max = t;
                        hit |= h;
                    }
                }
                (t_max, hit)
            }

            /// The tree's SAH cost (traversal 1, intersection 1), relative to the
            /// root's area: the usual measure of tree quality.
            pub fn sah_cost(&self) -> f32 {
                let Some(root) = self.nodes.first() else {
                    return 0.0;
                };
                let root_area = Aabb {
                    min: root.min,
                    max: root.max,
                }
                .half_area()
                .max(f32::MIN_POSITIVE);
                self.nodes
                    .iter()
                    .map(|n| {
                        let a = Aabb {
                            min: n.min,
                            max: n.max,
                        }
                        .half_area()
                            / root_area;
                        if n.count > 0 {
                            a * INTERSECT_COST * n.count as f32
                        } else {
                            a * TRAVERSAL_COST
                        }
                    })
                    .sum()
            }
        }

        /// Chooses a split of `prims` (reordering it) by binned SAH; `None` makes a
        /// leaf. Returns the number of primitives that go left.
        fn find_split(
            prims: &mut [u32],
            boxes: &[Aabb],
            centroids: &[Vec3],
            bounds: Aabb,
            max_leaf: usize,
        ) -> Option<usize> {
            let count = prims.len();
            let cb = prims
                .iter()
                .fold(Aabb::EMPTY, |b, &p| b.grow(centroids[p as usize]));
            let extent = cb.max - cb.min;
            let axis = if extent.x >= extent.y && extent.x >= extent.z {
                0
            } else if extent.y >= extent.z {
                1
            } else {
                2
            };
            if !(extent[axis] > 0.0) || !extent[axis].is_finite() {
                // All centroids coincide: SAH cannot separate them. Split in the
                // middle only to keep leaves small.
                return if count > max_leaf {
                    Some(count / 2)
                } else {
                    None
                };
            }
            let scale = BINS as f32 / extent[axis];
            let bin_of = |p: u32| -> usize {
                let b = ((centroids[p as usize][axis] - cb.min[axis]) * scale) as usize;
                b.min(BINS - 1)
            };
            let mut bin_box = [Aabb::EMPTY; BINS];
            let mut bin_count = [0usize; BINS];
            for &p in prims.iter() {
                let b = bin_of(p);
                bin_box[b] = bin_box[b].union(boxes[p as usize]);
                bin_count[b] += 1;
            }
            // Sweep from the right to get suffix areas, then from the left.
            let mut right_area = [0.0f32; BINS];
            let mut acc = Aabb::EMPTY;
            let mut n = 0;
            let mut right_count = [0usize; BINS];
            for i in (1..BINS).rev() {
                acc = acc.union(bin_box[i]);
                n += bin_count[i];
                right_area[i] = acc.half_area();
                right_count[i] = n;
            }
            let mut best = (f32::INFINITY, 0usize);
            let mut acc = Aabb::EMPTY;
            let mut n = 0;
            for i in 0..BINS - 1 {
                acc = acc.union(bin_box[i]);
                n += bin_count[i];
                if n == 0 || right_count[i + 1] == 0 {
                    continue;
                }
                let cost =
                    acc.half_area() * n as f32 + right_area[i + 1] * right_count[i + 1] as f32;
                if cost < best.0 {
                    best = (cost, i);
                }
            }
            let leaf_cost = bounds.half_area() * count as f32 * INTERSECT_COST;
            let split_cost = TRAVERSAL_COST * bounds.half_area() + INTERSECT_COST * best.0;
            if !best.0.is_finite() {
                return if count > max_leaf {
                    Some(count / 2)
                } else {
                    None
                };
            }
            if count <= max_leaf && split_cost >= leaf_cost {
                return None;
            }
            // Partition in place.
            let mut i = 0;
            let mut j = count;
            while i < j {
                if bin_of(prims[i]) <= best.1 {
                    i += 1;
                } else {
                    j -= 1;
                    prims.swap(i, j);
                }
            }
            Some(i)
        }
    }
    fn lcg(state: &mut u64) -> f32 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*state >> 40) as f32) / (1u64 << 24) as f32
    }

    fn random_boxes(n: usize, seed: u64) -> Vec<Aabb> {
        let mut s = seed;
        (0..n)
            .map(|_| {
                let c = Vec3::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) * 10.0;
                let e = Vec3::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) * 0.3;
                Aabb {
                    min: c - e,
                    max: c + e,
                }
            })
            .collect()
    }

    /// Unit boxes on an integer lattice, some repeated: many equal entry
    /// distances, shared faces, and rays along the axes.
    fn lattice_boxes(n: usize) -> Vec<Aabb> {
        (0..n)
            .map(|i| {
                let c = Vec3::new((i % 7) as f32, ((i / 7) % 5) as f32, (i / 35 % 6) as f32);
                Aabb {
                    min: c,
                    max: c + Vec3::ONE,
                }
            })
            .collect()
    }

    /// Nested boxes halving in size: a chain far deeper than the stack.
    fn nested_boxes(n: usize) -> Vec<Aabb> {
        (0..n)
            .map(|i| {
                let s = 0.5f32.powi(i as i32 / 2) * 100.0;
                Aabb {
                    min: Vec3::ZERO,
                    max: Vec3::splat(s),
                }
            })
            .collect()
    }

    fn ref_leaves(r: &reference::RefBvh) -> Vec<Vec<u32>> {
        let mut out = Vec::new();
        let mut stack = vec![0usize];
        while let Some(i) = stack.pop() {
            let n = r.nodes[i];
            if n.count > 0 {
                out.push(r.prims[n.first as usize..(n.first + n.count) as usize].to_vec());
            } else {
                stack.push(n.first as usize + 1);
                stack.push(n.first as usize);
            }
        }
        out
    }

    #[derive(Clone, Copy, Debug)]
    enum Mode {
        Closest,
        Gather,
        StopAfter(usize),
    }

    type Trace = (Vec<(u32, u32)>, u32, bool);

    fn run(
        boxes: &[Aabb],
        o: Vec3,
        d: Vec3,
        mode: Mode,
        traverse: impl FnOnce(&mut dyn FnMut(u32, f32) -> Visit) -> (f32, bool),
    ) -> Trace {
        let inv = d.recip();
        let mut seen = Vec::new();
        let mut f = |p: u32, tm: f32| {
            seen.push((p, tm.to_bits()));
            let b = boxes[p as usize];
            match (mode, ray_box(o, inv, b.min, b.max, tm)) {
                (Mode::Closest, Some(t)) => Visit::Hit(t),
                (Mode::StopAfter(k), Some(_)) if seen.len() > k => Visit::Stop,
                _ => Visit::Miss,
            }
        };
        let (t, h) = traverse(&mut f);
        (seen, t.to_bits(), h)
    }

    fn rays(seed: u64, n: usize, boxes: &[Aabb]) -> Vec<(Vec3, Vec3, f32)> {
        let mut s = seed;
        let b = boxes.iter().fold(Aabb::EMPTY, |a, &b| a.union(b));
        let ext = b.max - b.min;
        let mut out = Vec::new();
        for i in 0..n {
            let mut o =
                b.min - ext * 0.2 + Vec3::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) * ext * 1.4;
            let mut d = Vec3::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) - 0.5;
            match i % 5 {
                // Along an axis: zero direction components (inf in 1/d).
                1 => d = [Vec3::X, -Vec3::Y, Vec3::Z, Vec3::new(0.0, 1.0, -1.0)][i / 5 % 4],
                // From a lattice point, on box faces.
                2 => o = o.round(),
                3 => {
                    o = o.round();
                    d = d.signum() * Vec3::new(1.0, 0.0, 1.0);
                }
                _ => {}
            }
            let t_max = if i % 7 == 0 { 2.5 } else { f32::INFINITY };
            out.push((o, d, t_max));
        }
        out
    }

    #[test]
    fn build_and_traversal_match_the_original_visit_for_visit() {
        let scenes = [
            (random_boxes(3000, 7), 4),
            (random_boxes(500, 8), 2),
            (lattice_boxes(400), 4),
            (lattice_boxes(300), 1),
            (nested_boxes(300), 2),
            (
                vec![
                    Aabb {
                        min: Vec3::ZERO,
                        max: Vec3::ONE
                    };
                    50
                ],
                4,
            ),
            (random_boxes(1, 3), 4),
        ];
        for (k, (boxes, max_leaf)) in scenes.iter().enumerate() {
            let new = Bvh::build(boxes, *max_leaf);
            let old = reference::RefBvh::build(boxes, *max_leaf);
            let leaves: Vec<Vec<u32>> = new.leaves().iter().map(|l| l.1.to_vec()).collect();
            assert_eq!(leaves, ref_leaves(&old), "scene {k}: leaves");
            assert_eq!(new.bounds(), old.bounds(), "scene {k}");
            let sah_old = old.sah_cost();
            assert!(
                (new.sah_cost() - sah_old).abs() <= 1e-4 * sah_old.max(1.0),
                "scene {k}"
            );
            for (i, &(o, d, t_max)) in rays(k as u64 + 1, 400, boxes).iter().enumerate() {
                for mode in [Mode::Closest, Mode::Gather, Mode::StopAfter(i % 4)] {
                    let a = run(boxes, o, d, mode, |f| new.traverse(o, d, t_max, f));
                    let b = run(boxes, o, d, mode, |f| old.traverse(o, d, t_max, f));
                    assert_eq!(a, b, "scene {k}, ray {i} {o} {d}, {mode:?}");
                }
            }
        }
    }

    #[test]
    fn after_taking_the_leaf_order_the_walk_reports_leaf_positions() {
        let boxes = random_boxes(2000, 21);
        let rays = rays(5, 300, &boxes);
        let modes = [Mode::Gather, Mode::Closest];
        let mut bvh = Bvh::build(&boxes, 4);
        let before: Vec<Trace> = rays
            .iter()
            .flat_map(|&(o, d, t_max)| {
                let bvh = &bvh;
                let boxes = &boxes;
                modes.map(move |m| run(boxes, o, d, m, |f| bvh.traverse(o, d, t_max, f)))
            })
            .collect();
        let order = bvh.take_leaf_order();
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert!(
            sorted.iter().copied().eq(0..boxes.len() as u32),
            "a permutation"
        );
        // Primitive k is now the old order[k]: the same visits, renamed.
        let renumbered: Vec<Aabb> = order.iter().map(|&p| boxes[p as usize]).collect();
        let mut i = 0;
        for &(o, d, t_max) in &rays {
            for m in modes {
                let (seen, t, h) = run(&renumbered, o, d, m, |f| bvh.traverse(o, d, t_max, f));
                let seen: Vec<(u32, u32)> = seen
                    .iter()
                    .map(|&(k, tm)| (order[k as usize], tm))
                    .collect();
                assert_eq!((seen, t, h), before[i], "ray {} {m:?}", i / 2);
                i += 1;
            }
        }
    }

    #[test]
    fn every_primitive_is_in_exactly_one_leaf_and_inside_its_boxes() {
        let boxes = random_boxes(5000, 7);
        let bvh = Bvh::build(&boxes, 4);
        let mut seen = vec![0; boxes.len()];
        for (b, prims) in bvh.leaves() {
            for &p in prims {
                seen[p as usize] += 1;
                let pb = boxes[p as usize];
                assert!(pb.min.cmpge(b.min).all() && pb.max.cmple(b.max).all());
            }
        }
        assert!(seen.iter().all(|&c| c == 1));
    }

    #[test]
    fn traversal_finds_the_same_closest_box_as_brute_force() {
        let boxes = random_boxes(2000, 11);
        let bvh = Bvh::build(&boxes, 4);
        let mut s = 99u64;
        for _ in 0..500 {
            let o = Vec3::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) * 14.0 - 2.0;
            let d = Vec3::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) - 0.5;
            let inv = d.recip();
            let brute = boxes
                .iter()
                .filter_map(|b| ray_box(o, inv, b.min, b.max, f32::INFINITY))
                .fold(f32::INFINITY, f32::min);
            let (t, hit) = bvh.traverse(o, d, f32::INFINITY, |p, tmax| {
                let b = boxes[p as usize];
                match ray_box(o, inv, b.min, b.max, tmax) {
                    Some(t) => Visit::Hit(t),
                    None => Visit::Miss,
                }
            });
            assert_eq!(hit, brute.is_finite());
            if hit {
                assert_eq!(t, brute);
            }
        }
    }

    #[test]
    fn sah_beats_a_single_leaf_and_identical_boxes_still_build() {
        let boxes = random_boxes(1000, 3);
        let bvh = Bvh::build(&boxes, 4);
        assert!(bvh.sah_cost() < 1000.0 / 10.0);
        let same = vec![
            Aabb {
                min: Vec3::ZERO,
                max: Vec3::ONE
            };
            100
        ];
        let bvh = Bvh::build(&same, 4);
        assert!(bvh.leaves().iter().all(|l| l.1.len() <= 4));
        assert_eq!(
            Bvh::build(&[], 4).traverse(Vec3::ZERO, Vec3::X, 1.0, |_, _| Visit::Stop),
            (1.0, false)
        );
    }

    #[test]
    fn large_builds_take_the_parallel_path_and_still_match() {
        // Above the parallel thresholds: parallel binning and subtrees.
        let boxes = random_boxes(150_000, 5);
        let new = Bvh::build(&boxes, 4);
        let old = reference::RefBvh::build(&boxes, 4);
        let leaves: Vec<Vec<u32>> = new.leaves().iter().map(|l| l.1.to_vec()).collect();
        assert_eq!(leaves, ref_leaves(&old));
    }
}
