//! Bounding volume hierarchy: a binned-SAH tree over primitive boxes,
//! collapsed into an 8-wide tree.
//!
//! One builder serves both levels of the acceleration structure: the bottom
//! level (triangles of one mesh, in object space) and the top level (model
//! instances and spheres, in world space). At the top level the tree only
//! stores indices and the caller's closure intersects the primitives, so
//! traversal is generic and statically dispatched; a mesh's tree
//! ([`MeshBvh`], `leaves.rs`) holds its triangles in the leaves, four to a
//! leaf, copied, and tests them four at a time.
//!
//! `build.rs` makes a binary tree by binned SAH, `wide.rs` collapses it into
//! nodes of up to `WIDTH` (eight) children (the largest child opened
//! first, as Embree's BVH8 builder does), `traverse.rs` walks that, nearest
//! child first, and `simd.rs` (the only `unsafe` code) tests a node's eight
//! boxes (one AVX pass or two SSE ones), or a leaf's four triangles, at once.
//!
//! Layout: a `Node` holds its eight children's boxes plane by plane (one
//! AVX register per plane: 192 bytes) and their references, 256 bytes, four
//! cache lines. The binary tree is dropped once collapsed.
//!
//! Visit order is not part of the image: the closest-hit query answers by a
//! total order on hits (`world::View::precedes`), and any-hit queries do not
//! depend on the order. The order is still a pure function of the ray and
//! the tree, the same on every code path (see `simd.rs`), so translucent
//! shadows, which multiply factors in visit order, are deterministic too.

mod build;
mod leaves;
#[cfg(test)]
mod reference;
pub mod simd;
#[cfg(test)]
mod tests;
mod traverse;
mod wide;

pub use leaves::{MeshBvh, PACK};
pub use simd::Simd;

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

/// A child reference: `count == 0`: the interior node `pairs[first]` of
/// the binary tree, or `nodes[first]` of the wide one; `count > 0`: the leaf
/// `prims[first..first + count]`; [`Ref::NONE`]: an empty slot of a node.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Ref {
    first: u32,
    count: u32,
}

impl Ref {
    const NONE: Ref = Ref {
        first: u32::MAX,
        count: 0,
    };
}

/// Children per wide node: the lanes of the node test (one AVX register,
/// or two SSE ones, per plane).
pub(crate) const WIDTH: usize = 8;

/// A wide node: up to [`WIDTH`] children. `b[2·axis]` holds the children's
/// minima on that axis, `b[2·axis + 1]` their maxima; empty slots have
/// [`Aabb::EMPTY`]'s planes and [`Ref::NONE`].
#[derive(Debug, Clone, Copy)]
#[repr(C, align(64))]
struct Node {
    b: [[f32; WIDTH]; 6],
    child: [Ref; WIDTH],
}

impl Node {
    const EMPTY: Node = Node {
        b: [
            [f32::INFINITY; WIDTH],
            [f32::NEG_INFINITY; WIDTH],
            [f32::INFINITY; WIDTH],
            [f32::NEG_INFINITY; WIDTH],
            [f32::INFINITY; WIDTH],
            [f32::NEG_INFINITY; WIDTH],
        ],
        child: [Ref::NONE; WIDTH],
    };

    fn set(&mut self, i: usize, b: Aabb, r: Ref) {
        for a in 0..3 {
            self.b[2 * a][i] = b.min[a];
            self.b[2 * a + 1][i] = b.max[a];
        }
        self.child[i] = r;
    }

    #[cfg(test)]
    fn child_box(&self, i: usize) -> Aabb {
        Aabb {
            min: Vec3::new(self.b[0][i], self.b[2][i], self.b[4][i]),
            max: Vec3::new(self.b[1][i], self.b[3][i], self.b[5][i]),
        }
    }
}

/// The two children of an interior node of the binary tree (the build's
/// intermediate form): their boxes and references.
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

    fn child_min(&self, i: usize) -> Vec3 {
        Vec3::new(self.min_xy[i], self.min_xy[2 + i], self.z[i])
    }

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
    nodes: Vec<Node>,
    /// Primitive indices in leaf order; empty once the caller has taken
    /// them ([`Bvh::take_leaf_order`]) and numbered its primitives so.
    prims: Vec<u32>,
    /// Number of primitives.
    len: u32,
    root: Ref,
    root_box: Aabb,
    /// The binary tree's SAH cost ([`Bvh::sah_cost`]).
    sah: f32,
}

impl Default for Bvh {
    /// The empty tree.
    fn default() -> Bvh {
        Bvh {
            nodes: Vec::new(),
            prims: Vec::new(),
            len: 0,
            root: Ref::default(),
            root_box: Aabb::EMPTY,
            sah: 0.0,
        }
    }
}

impl Bvh {
    /// The union of every primitive's box.
    pub fn bounds(&self) -> Aabb {
        self.root_box
    }

    /// Hands over the primitive order of the leaves: `order[k]` is the
    /// primitive in leaf position `k`. The caller renumbers its primitives
    /// so that primitive `k` is `order[k]` (leaf neighbours become memory
    /// neighbours), and the tree reports `k` from then on, without keeping
    /// an index array. The tree is unchanged.
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
    /// Checks on the way that every child box lies inside its parent's.
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
            } else if self.len > 0 {
                let n = &self.nodes[r.first as usize];
                for i in (0..WIDTH).rev() {
                    if n.child[i] == Ref::NONE {
                        continue;
                    }
                    let c = n.child_box(i);
                    assert!(c.min.cmpge(b.min).all() && c.max.cmple(b.max).all());
                    stack.push((n.child[i], c));
                }
            }
        }
        out
    }
}
