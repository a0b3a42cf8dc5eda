//! A mesh's tree with triangle leaves: every leaf holds up to four
//! triangles, their vertices copied into the leaf plane by plane (one
//! 4-lane vector per vertex coordinate, as Embree's `Triangle4`), and tested
//! four at a time by the watertight test (`simd.rs`: the SSE test and its
//! scalar twin, [`triangle::intersect`] lane by lane, the same bits).
//!
//! The tree is built by SAH priced in blocks of four ([`Bvh::build_blocks`]:
//! a leaf of one to four triangles costs one pack test, as in Embree's
//! builder with `sahBlockSize = 4`), so leaves fill up. The mesh is
//! renumbered in leaf order, so a leaf's triangles are `first..first + n`;
//! the leaf references of the wide tree then point at packs, and
//! [`MeshBvh::pack_first`](MeshBvh) keeps each pack's first triangle.
//!
//! A leaf is answered lane by lane in triangle order: every lane is tested
//! against the bound the leaf was entered with, and a lane's hit is passed
//! on only if its computed `t` is below the bound as shortened by the
//! earlier lanes. A triangle is reported exactly when its computed `t` is
//! below the bound (see [`triangle::intersect`]), so this is what testing
//! the triangles one at a time would report, on every path.

use super::simd::{self, Simd};
use super::{Bvh, Ref, Visit};
use crate::geometry::triangle::{self, ShearedRay, TriangleHit};
use crate::geometry::Aabb;
use crate::mesh::Mesh;
use glam::Vec3;

/// Triangles per leaf (and lanes per test).
pub const PACK: usize = 4;

/// A leaf's triangles: `p[3·v + axis][lane]` is coordinate `axis` of vertex
/// `v` (0, 1, 2 in winding order) of triangle `first + lane`. Lanes past the
/// leaf's count repeat its last triangle (finite numbers; they are masked
/// off).
#[derive(Debug, Clone, Copy)]
#[repr(C, align(16))]
pub(super) struct Pack {
    pub p: [[f32; 4]; 9],
}

impl Pack {
    /// Vertex `v` of lane `lane`.
    #[inline(always)]
    pub fn vertex(&self, v: usize, lane: usize) -> Vec3 {
        Vec3::new(
            self.p[3 * v][lane],
            self.p[3 * v + 1][lane],
            self.p[3 * v + 2][lane],
        )
    }
}

/// A mesh's acceleration structure (see the module doc).
#[derive(Debug, Clone, Default)]
pub struct MeshBvh {
    /// The wide tree; a leaf `Ref { first: k, count }` is pack `k` with
    /// `count` live lanes.
    tree: Bvh,
    pub(super) packs: Vec<Pack>,
    /// Per pack, its first triangle (as the mesh is numbered after
    /// [`MeshBvh::build`]).
    pub(super) pack_first: Vec<u32>,
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
        let leaves = tree.number_leaves();
        let mut packs = Vec::with_capacity(leaves.len());
        let mut pack_first = Vec::with_capacity(leaves.len());
        for &(first, count) in &leaves {
            debug_assert!((1..=PACK as u32).contains(&count));
            let mut pack = Pack { p: [[0.0; 4]; 9] };
            for lane in 0..PACK {
                let t = first + (lane as u32).min(count - 1);
                let tri = mesh.triangles[t as usize];
                for (v, &i) in tri.iter().enumerate() {
                    let p = mesh.positions[i as usize];
                    for axis in 0..3 {
                        pack.p[3 * v + axis][lane] = p[axis];
                    }
                }
            }
            packs.push(pack);
            pack_first.push(first);
        }
        (
            MeshBvh {
                tree,
                packs,
                pack_first,
            },
            order,
        )
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

    /// Number of leaves (packs), for the figures.
    pub fn packs(&self) -> usize {
        self.packs.len()
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
        self.tree
            .traverse_leaves_on::<_, ORDERED>(path, origin, dir, t_max, |k, count, t_enter| {
                let pack = &self.packs[k as usize];
                let first = self.pack_first[k as usize];
                let mut t_max = t_enter;
                let mut result = Visit::Miss;
                let mut offer = |lane: usize, h: TriangleHit| {
                    if !(h.t < t_max) {
                        return Visit::Miss;
                    }
                    match visit(first + lane as u32, h) {
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
                let lanes = count as usize;
                match path {
                    #[cfg(target_arch = "x86_64")]
                    Simd::Sse => {
                        let l = simd::triangles_sse(&pack.p, &sheared, t_enter);
                        let live = (1u32 << lanes) - 1;
                        let mut m = (l.hit | l.edge) & live;
                        while m != 0 {
                            let lane = m.trailing_zeros() as usize;
                            m &= m - 1;
                            let h = if l.edge & (1 << lane) != 0 {
                                // An edge function was exactly zero: the
                                // scalar test redoes it in f64.
                                match scalar_lane(pack, lane, &sheared, t_enter) {
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
                            if let Some(h) = scalar_lane(pack, lane, &sheared, t_enter) {
                                if let Visit::Stop = offer(lane, h) {
                                    return Visit::Stop;
                                }
                            }
                        }
                    }
                }
                result
            })
    }
}

/// The scalar test of one lane: [`triangle::intersect`] itself.
#[inline(always)]
fn scalar_lane(pack: &Pack, lane: usize, r: &ShearedRay, t_max: f32) -> Option<TriangleHit> {
    triangle::intersect(
        r,
        pack.vertex(0, lane),
        pack.vertex(1, lane),
        pack.vertex(2, lane),
        t_max,
    )
}

impl Bvh {
    /// Renumbers the leaves `0, 1, …` in the order of their primitives
    /// (leaf order) and returns each one's former `(first, count)`: the leaf
    /// references then index the caller's per-leaf data. The tree no longer
    /// knows its primitives, so only [`Bvh::traverse_leaves_on`] makes sense
    /// on it afterwards.
    pub(super) fn number_leaves(&mut self) -> Vec<(u32, u32)> {
        if self.len == 0 {
            return Vec::new();
        }
        let mut leaves = Vec::new();
        let refs = std::iter::once(&mut self.root)
            .chain(self.nodes.iter_mut().flat_map(|n| n.child.iter_mut()));
        let mut refs: Vec<&mut Ref> = refs.filter(|r| r.count > 0).collect();
        for r in &refs {
            leaves.push((r.first, r.count));
        }
        // Leaves partition the primitives, so their firsts are distinct.
        leaves.sort_unstable();
        for r in &mut refs {
            let k = leaves.partition_point(|&(first, _)| first < r.first);
            r.first = k as u32;
        }
        leaves
    }
}
