//! Bounding volume hierarchy: a binned-SAH binary tree over primitive boxes.
//!
//! One builder serves both levels of the acceleration structure: the bottom
//! level (triangles of one mesh, in object space) and the top level (model
//! instances and spheres, in world space). The tree only stores indices; the
//! caller's closure intersects the primitives, so traversal is generic and
//! statically dispatched.

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
pub struct Bvh {
    pub nodes: Vec<Node>,
    /// Primitive indices in leaf order.
    pub prims: Vec<u32>,
}

/// What the primitive closure tells the traversal.
pub enum Visit {
    /// No hit (or one that does not shorten the ray).
    Miss,
    /// A hit at this parameter: only closer hits matter from now on.
    Hit(f32),
    /// Stop now (any-hit queries).
    Stop,
}

const BINS: usize = 16;
const TRAVERSAL_COST: f32 = 1.0;
const INTERSECT_COST: f32 = 1.0;

impl Bvh {
    /// Builds the tree; `max_leaf` bounds a leaf's primitive count except
    /// where primitives cannot be told apart at all.
    pub fn build(boxes: &[Aabb], max_leaf: usize) -> Bvh {
        let mut bvh = Bvh {
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
        let mut stack = [0u32; 64];
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
        let cost = acc.half_area() * n as f32 + right_area[i + 1] * right_count[i + 1] as f32;
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

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn every_primitive_is_in_exactly_one_leaf_and_inside_its_boxes() {
        let boxes = random_boxes(5000, 7);
        let bvh = Bvh::build(&boxes, 4);
        let mut seen = vec![0; boxes.len()];
        for (i, n) in bvh.nodes.iter().enumerate() {
            if n.count > 0 {
                for &p in &bvh.prims[n.first as usize..(n.first + n.count) as usize] {
                    seen[p as usize] += 1;
                    let b = boxes[p as usize];
                    assert!(
                        b.min.cmpge(n.min).all() && b.max.cmple(n.max).all(),
                        "node {i}"
                    );
                }
            } else {
                for c in [n.first, n.first + 1] {
                    let cn = bvh.nodes[c as usize];
                    assert!(cn.min.cmpge(n.min).all() && cn.max.cmple(n.max).all());
                }
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
        assert!(bvh.nodes.iter().all(|n| n.count <= 4));
    }
}
