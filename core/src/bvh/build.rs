//! Building the tree: binned SAH over the primitives' centroids, large
//! subtrees and large nodes' binning in parallel (rayon). The splits and the
//! in-place partition are those of the reference tree (`reference.rs`), so
//! the tree and its leaf order are too, whatever the thread count.

use super::{Bvh, Pair, Ref};
use crate::geometry::Aabb;
use glam::Vec3;

pub(super) const BINS: usize = 16;
pub(super) const TRAVERSAL_COST: f32 = 1.0;
pub(super) const INTERSECT_COST: f32 = 1.0;
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
    block: usize,
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
    /// Builds the tree; `max_leaf` bounds a leaf's primitive count.
    pub fn build(boxes: &[Aabb], max_leaf: usize) -> Bvh {
        Bvh::build_blocks(boxes, max_leaf, 1)
    }

    /// [`Bvh::build`] for leaves whose primitives are tested `block` at a
    /// time (triangle packs): the SAH prices a leaf or a side of a split by
    /// its number of blocks, `⌈count / block⌉`, not of primitives (Embree's
    /// `sahBlockSize`), so that leaves fill up to `block`.
    pub fn build_blocks(boxes: &[Aabb], max_leaf: usize, block: usize) -> Bvh {
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
            block: block.max(1),
        };
        let mut bins = vec![0u8; n];
        let mut pairs = Vec::with_capacity(n / 2 + 1);
        let root = build_node(&input, &mut prims, &mut bins, 0, 0, bounds, cb, &mut pairs);
        let sah = sah_cost(&pairs, root, bounds);
        let (nodes, root) = super::wide::collapse(&pairs, root);
        drop(pairs);
        Bvh {
            nodes,
            len: n as u32,
            prims,
            root,
            root_box: bounds,
            sah,
        }
    }

    /// The SAH cost (traversal 1, intersection 1), relative to the root's
    /// area, of the binary tree the wide one was collapsed from: the usual
    /// measure of tree quality, comparable with other binary builders'.
    pub fn sah_cost(&self) -> f32 {
        self.sah
    }
}

/// [`Bvh::sah_cost`] of a binary tree.
fn sah_cost(pairs: &[Pair], root: Ref, root_box: Aabb) -> f32 {
    let root_area = root_box.half_area().max(f32::MIN_POSITIVE) as f64;
    let cost = |b: Aabb, r: Ref| -> f64 {
        let a = b.half_area() as f64 / root_area;
        if r.count > 0 {
            a * (INTERSECT_COST * r.count as f32) as f64
        } else {
            a * TRAVERSAL_COST as f64
        }
    };
    let mut sum = cost(root_box, root);
    for p in pairs {
        sum += cost(p.child_box(0), p.child[0]) + cost(p.child_box(1), p.child[1]);
    }
    sum as f32
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
/// centroids. The decision and the partition are those of the reference
/// tree, so the tree and its leaf order are too.
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
    let best = cheapest_split(bin_box, bin_count, input.block);
    let leaf_cost = bounds.half_area() * blocks(count, input.block) * INTERSECT_COST;
    let split_cost = TRAVERSAL_COST * bounds.half_area() + INTERSECT_COST * best.0;
    if !best.0.is_finite() {
        return (count > max_leaf).then(|| middle_split(input, prims));
    }
    if count <= max_leaf && split_cost >= leaf_cost {
        return None;
    }
    // Partition in place, in the reference tree's order of swaps (it decides
    // the leaf order, and so the visit order).
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

/// The number of `block`-sized tests `count` primitives take, as the SAH
/// weighs them.
#[inline]
pub(super) fn blocks(count: usize, block: usize) -> f32 {
    count.div_ceil(block) as f32
}

/// The cheapest split between the bins: `(SAH cost of both sides, last bin
/// of the left side)`, or an infinite cost when every split leaves a side
/// empty; each side is weighed by its [`blocks`]. Shared by the build and
/// the reference tree, so both split alike.
pub(super) fn cheapest_split(
    bin_box: &[Aabb; BINS],
    bin_count: &[usize; BINS],
    block: usize,
) -> (f32, usize) {
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
        let cost = acc.half_area() * blocks(n, block)
            + right_area[i + 1] * blocks(right_count[i + 1], block);
        if cost < best.0 {
            best = (cost, i);
        }
    }
    best
}
