//! A mesh's tree with triangle leaves: every leaf holds up to four
//! triangles, their vertices copied into the leaf coordinate by coordinate
//! (one run of up to four lanes per vertex coordinate, as Embree's
//! `Triangle4` has one vector per coordinate), and tested four at a time by
//! the watertight test (`simd.rs`: the SSE test and its scalar twin,
//! [`triangle::intersect`] lane by lane, the same bits).
//!
//! The tree is built by SAH priced in blocks of four ([`Bvh::build_blocks`]:
//! a leaf of one to four triangles costs one test, as in Embree's builder
//! with `sahBlockSize = 4`), so leaves fill up. The mesh is renumbered in
//! leaf order, so a leaf's triangles are `first..first + n`, and their
//! copies are the 9·n floats from `9·first` on: no per-leaf index, and no
//! lane stored for a leaf that has fewer than four triangles (the SSE test
//! loads four lanes and masks off those past `n`, which belong to the next
//! coordinate or leaf; three floats of padding end the array).
//!
//! A leaf is answered lane by lane in triangle order: every lane is tested
//! against the bound the leaf was entered with, and a lane's hit is passed
//! on only if its computed `t` is below the bound as shortened by the
//! earlier lanes. A triangle is reported exactly when its computed `t` is
//! below the bound (see [`triangle::intersect`]), so this is what testing
//! the triangles one at a time would report, on every path.

use super::simd::{self, Simd};
use super::{Bvh, Visit};
use crate::geometry::triangle::{self, ShearedRay, TriangleHit};
use crate::geometry::Aabb;
use crate::mesh::Mesh;
use glam::Vec3;

/// Triangles per leaf (and lanes per test).
pub const PACK: usize = 4;

/// Floats of a leaf's copies past its own that the SSE test may load.
pub(super) const PAD: usize = 3;

/// A leaf's copied triangles: `p[(3·v + axis)·n + lane]` is coordinate
/// `axis` of vertex `v` (0, 1, 2 in winding order) of the leaf's triangle
/// `lane < n`; `p` runs on for [`PAD`] floats past `9·n`.
#[derive(Debug, Clone, Copy)]
pub(super) struct Leaf<'a> {
    pub p: &'a [f32],
    pub n: usize,
}

impl Leaf<'_> {
    /// Vertex `v` of lane `lane`.
    #[inline(always)]
    pub fn vertex(&self, v: usize, lane: usize) -> Vec3 {
        let n = self.n;
        Vec3::new(
            self.p[3 * v * n + lane],
            self.p[(3 * v + 1) * n + lane],
            self.p[(3 * v + 2) * n + lane],
        )
    }
}

/// A mesh's acceleration structure (see the module doc).
#[derive(Debug, Clone, Default)]
pub struct MeshBvh {
    /// The wide tree over the mesh as renumbered (leaf `first..first + n`).
    pub(super) tree: Bvh,
    /// The leaves' copies of their triangles (see the module doc), 9 floats
    /// a triangle, then [`PAD`] zeros.
    verts: Vec<f32>,
}

impl MeshBvh {
    /// Builds the tree of `mesh` and renumbers the mesh's triangles in its
    /// leaf order (see [`Mesh::reorder_triangles`]); returns the tree and
    /// the order (`order[k]`: the triangle as given that is now `k`).
    pub fn build(mesh: &mut Mesh) -> (MeshBvh, Vec<u32>) {
        let boxes: Vec<Aabb> = mesh
            .triangles
            .iter()
            .map(|t| Aabb::from_points(&t.map(|i| mesh.positions[i as usize])))
            .collect();
        let mut tree = Bvh::build_blocks(&boxes, PACK, PACK);
        drop(boxes);
        let order = tree.take_leaf_order();
        mesh.reorder_triangles(&order);
        let mut verts = vec![0.0f32; 9 * mesh.triangles.len() + PAD];
        for (first, n) in tree.leaf_ranges() {
            let (first, n) = (first as usize, n as usize);
            let p = &mut verts[9 * first..9 * (first + n)];
            for lane in 0..n {
                let tri = mesh.triangles[first + lane];
                for (v, &i) in tri.iter().enumerate() {
                    let x = mesh.positions[i as usize];
                    for axis in 0..3 {
                        p[(3 * v + axis) * n + lane] = x[axis];
                    }
                }
            }
        }
        (MeshBvh { tree, verts }, order)
    }

    /// The union of the triangles' boxes.
    pub fn bounds(&self) -> Aabb {
        self.tree.bounds()
    }

    /// The SAH cost of the binary tree, leaves priced per triangle (as
    /// [`Bvh::sah_cost`], comparable with other binary builders').
    pub fn sah_cost(&self) -> f32 {
        self.tree.sah_cost()
    }

    /// Calls `visit(triangle, hit)` for the triangles the ray
    /// `origin + t·dir`, `t ∈ (0, t_max)` hits, leaves nearest first
    /// (`ORDERED`, else in slot order), a leaf's triangles in their order,
    /// on the code path `path`; `visit` answers as in [`Bvh::traverse`].
    /// Returns the final `t_max` and whether `visit` reported a hit.
    #[inline(always)]
    pub(crate) fn traverse_on<F: FnMut(u32, TriangleHit) -> Visit, const ORDERED: bool>(
        &self,
        path: Simd,
        origin: Vec3,
        dir: Vec3,
        t_max: f32,
        mut visit: F,
    ) -> (f32, bool) {
        let sheared = ShearedRay::new(origin, dir);
        self.tree.traverse_leaves_on::<_, ORDERED>(
            path,
            origin,
            dir,
            t_max,
            |first, count, t_enter| {
                let (first, lanes) = (first as usize, count as usize);
                let leaf = Leaf {
                    p: &self.verts[9 * first..9 * (first + lanes) + PAD],
                    n: lanes,
                };
                let mut t_max = t_enter;
                let mut result = Visit::Miss;
                let mut offer = |lane: usize, h: TriangleHit| {
                    if !(h.t < t_max) {
                        return Visit::Miss;
                    }
                    match visit((first + lane) as u32, h) {
                        Visit::Miss => Visit::Miss,
                        Visit::Hit(t) => {
                            if t < t_max {
                                t_max = t;
                            }
                            result = Visit::Hit(t_max);
                            Visit::Miss
                        }
                        Visit::Stop => Visit::Stop,
                    }
                };
                match path {
                    #[cfg(target_arch = "x86_64")]
                    Simd::Sse | Simd::Avx => {
                        let l = simd::triangles_sse(leaf.p, leaf.n, &sheared, t_enter);
                        let live = (1u32 << lanes) - 1;
                        let mut m = (l.hit | l.edge) & live;
                        while m != 0 {
                            let lane = m.trailing_zeros() as usize;
                            m &= m - 1;
                            let h = if l.edge & (1 << lane) != 0 {
                                // An edge function was exactly zero: the
                                // scalar test redoes it in f64.
                                match scalar_lane(&leaf, lane, &sheared, t_enter) {
                                    Some(h) => h,
                                    None => continue,
                                }
                            } else {
                                l.hit_of(lane)
                            };
                            if let Visit::Stop = offer(lane, h) {
                                return Visit::Stop;
                            }
                        }
                    }
                    _ => {
                        for lane in 0..lanes {
                            if let Some(h) = scalar_lane(&leaf, lane, &sheared, t_enter) {
                                if let Visit::Stop = offer(lane, h) {
                                    return Visit::Stop;
                                }
                            }
                        }
                    }
                }
                result
            },
        )
    }
}

/// The scalar test of one lane: [`triangle::intersect`] itself.
#[inline(always)]
fn scalar_lane(leaf: &Leaf, lane: usize, r: &ShearedRay, t_max: f32) -> Option<TriangleHit> {
    triangle::intersect(
        r,
        leaf.vertex(0, lane),
        leaf.vertex(1, lane),
        leaf.vertex(2, lane),
        t_max,
    )
}

impl Bvh {
    /// Every leaf's `(first, count)`, in no particular order.
    pub(super) fn leaf_ranges(&self) -> Vec<(u32, u32)> {
        if self.len == 0 {
            return Vec::new();
        }
        std::iter::once(&self.root)
            .chain(self.nodes.iter().flat_map(|n| n.child.iter()))
            .filter(|r| r.count > 0)
            .map(|r| (r.first, r.count))
            .collect()
    }
}
