//! Bounding volume hierarchy: a binned-SAH binary tree over primitive boxes.
//!
//! One builder serves both levels of the acceleration structure: the bottom
//! level (triangles of one mesh, in object space) and the top level (model
//! instances and spheres, in world space). The tree only stores indices; the
//! caller's closure intersects the primitives, so traversal is generic and
//! statically dispatched.
//!
//! This file holds the tree's layout; `build.rs` makes it and `traverse.rs`
//! walks it.
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
//! are visited is part of the rendered image. Build and traversal visit
//! exactly the primitives, in exactly the order, of the plain
//! one-node-per-box tree in `reference.rs` (test builds only; the tests
//! compare the two on random scenes): the same splits and in-place
//! partition, children visited nearest entry first with ties to the left,
//! popped nodes culled on the same condition, the same fallback past 64
//! levels. The SIMD box test is used only for rays whose arithmetic cannot
//! produce a NaN (finite origin, finite non-zero direction components,
//! finite boxes), where it computes bit-for-bit the values of the scalar
//! [`ray_box`](crate::geometry::ray_box); other rays take the scalar path.

mod build;
#[cfg(test)]
mod reference;
#[cfg(test)]
mod tests;
mod traverse;

use crate::geometry::Aabb;
use glam::Vec3;

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

/// A built tree (see the module doc for its layout).
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

impl Bvh {
    /// The union of every primitive's box.
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
