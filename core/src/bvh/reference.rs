//! The reference tree for the tests: one node per box, built and walked
//! in the plainest way. The real tree's build must make the same splits
//! (`tests.rs` compares the leaves), and its walk must find what this one
//! finds. Its stack is shallow, so its recursion past it is exercised.

use super::build::{blocks, cheapest_split, BINS, INTERSECT_COST, TRAVERSAL_COST};
use super::Visit;
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

impl RefBvh {
    /// Builds the tree; `max_leaf` bounds a leaf's primitive count except
    /// where primitives cannot be told apart at all.
    pub fn build(boxes: &[Aabb], max_leaf: usize) -> RefBvh {
        RefBvh::build_blocks(boxes, max_leaf, 1)
    }

    /// [`RefBvh::build`] with leaves priced by blocks of `block` primitives
    /// (as `Bvh::build_blocks`).
    pub fn build_blocks(boxes: &[Aabb], max_leaf: usize, block: usize) -> RefBvh {
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
                    block,
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
        let mut stack = [0u32; 6];
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
                        let (t2, h2) = self.traverse_from(far, origin, dir, t_max, &mut visit);
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
    block: usize,
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
    let best = cheapest_split(&bin_box, &bin_count, block);
    let leaf_cost = bounds.half_area() * blocks(count, block) * INTERSECT_COST;
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
