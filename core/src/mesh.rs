//! Triangle meshes as loaded: shared by every model that instances them.
//!
//! A mesh is stored once, in its own (object) space; models refer to it by
//! index and carry their own transform, so a mesh used by 100 models costs
//! its triangles once.

pub mod counts;
pub mod mtl;
pub mod obj;
pub mod ply;
mod read;

use glam::{Vec2, Vec3};

/// An indexed triangle mesh. `normals` always has one entry per position once
/// the mesh is finished (computed when the source had none). `uvs` (texture
/// coordinates, `v = 0` at the image's bottom row as in OBJ) has one entry
/// per position when the source gave every corner one, and is empty
/// otherwise: an untextured mesh pays no memory for them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    /// The vertices' positions in object space.
    pub positions: Vec<Vec3>,
    /// The vertices' shading normals in object space, one per position
    /// (as the file gave them, or computed smooth ones).
    pub normals: Vec<Vec3>,
    /// The vertices' texture coordinates, one per position, or none.
    pub uvs: Vec<Vec2>,
    /// Each triangle's three vertex indices `a b c` into `positions`; its
    /// front is the side `(b−a)×(c−a)` points to.
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// Smooth vertex normals: the area-weighted average of the adjacent face
    /// normals (the cross product's length is twice the area, so summing raw
    /// cross products weights by area for free). Vertices used by no triangle,
    /// or only by zero-area ones, get the zero vector's stand-in `0 1 0`.
    pub fn compute_smooth_normals(&mut self) {
        let mut acc = vec![glam::DVec3::ZERO; self.positions.len()];
        for t in &self.triangles {
            let [a, b, c] = t.map(|i| self.positions[i as usize].as_dvec3());
            let n = (b - a).cross(c - a);
            for &i in t {
                acc[i as usize] += n;
            }
        }
        self.normals = acc
            .into_iter()
            .map(|n| {
                let n = n.normalize_or_zero().as_vec3();
                if n == Vec3::ZERO {
                    Vec3::Y
                } else {
                    n
                }
            })
            .collect();
    }

    /// Renumbers the triangles so that triangle `k` is the old `order[k]`,
    /// and the vertices in order of first use by the renumbered triangles
    /// (unused ones last, in their old order). The geometry is unchanged:
    /// only which numbers name it, so that triangles the BVH visits
    /// together lie together in memory.
    pub fn reorder_triangles(&mut self, order: &[u32]) {
        debug_assert_eq!(order.len(), self.triangles.len());
        const NEW: u32 = u32::MAX;
        let mut new_index = vec![NEW; self.positions.len()];
        let mut old_of_new = Vec::with_capacity(self.positions.len());
        let triangles: Vec<[u32; 3]> = order
            .iter()
            .map(|&t| {
                self.triangles[t as usize].map(|v| {
                    let n = &mut new_index[v as usize];
                    if *n == NEW {
                        *n = old_of_new.len() as u32;
                        old_of_new.push(v);
                    }
                    *n
                })
            })
            .collect();
        old_of_new.extend((0..new_index.len() as u32).filter(|&v| new_index[v as usize] == NEW));
        self.triangles = triangles;
        self.positions = old_of_new
            .iter()
            .map(|&v| self.positions[v as usize])
            .collect();
        if !self.normals.is_empty() {
            self.normals = old_of_new
                .iter()
                .map(|&v| self.normals[v as usize])
                .collect();
        }
        if !self.uvs.is_empty() {
            self.uvs = old_of_new.iter().map(|&v| self.uvs[v as usize]).collect();
        }
    }

    /// `invert="true"`: reverse every triangle's winding and negate every normal.
    pub fn invert(&mut self) {
        for t in &mut self.triangles {
            t.swap(1, 2);
        }
        for n in &mut self.normals {
            *n = -*n;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reordering_renames_triangles_and_vertices_but_keeps_the_geometry() {
        // A fan of four triangles round vertex 0, plus an unused vertex 6.
        let p = |i: u32| Vec3::new(i as f32, (i * i) as f32, 1.0 - i as f32);
        let old = Mesh {
            positions: (0..7).map(p).collect(),
            normals: (0..7).map(|i| p(i).normalize()).collect(),
            uvs: (0..7).map(|i| Vec2::new(i as f32, 0.5)).collect(),
            triangles: vec![[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]],
        };
        let order = [2u32, 0, 3, 1];
        let mut m = old.clone();
        m.reorder_triangles(&order);
        for (k, &t) in order.iter().enumerate() {
            let new_tri = m.triangles[k].map(|v| {
                let v = v as usize;
                (m.positions[v], m.normals[v], m.uvs[v])
            });
            let old_tri = old.triangles[t as usize].map(|v| {
                let v = v as usize;
                (old.positions[v], old.normals[v], old.uvs[v])
            });
            assert_eq!(new_tri, old_tri, "triangle {k}");
        }
        // Vertices numbered by first use: old triangle 2 = [0, 3, 4] first.
        assert_eq!(m.triangles[0], [0, 1, 2]);
        assert_eq!(m.triangles[1], [0, 3, 4]);
        // The unused vertex is kept, last.
        assert_eq!(m.positions.len(), 7);
        assert_eq!(m.positions[6], p(6));
    }

    #[test]
    fn smooth_normals_are_area_weighted() {
        // Two triangles sharing vertex 0: one in the xz-plane (normal +y, area 2),
        // one in the xy-plane (normal +z, area 0.5).
        let mut m = Mesh {
            positions: vec![
                Vec3::ZERO,
                Vec3::new(0.0, 0.0, 2.0),
                Vec3::new(2.0, 0.0, 0.0),
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(0.0, 1.0, 0.0),
            ],
            normals: vec![],
            uvs: vec![],
            triangles: vec![[0, 1, 2], [0, 3, 4]],
        };
        m.compute_smooth_normals();
        let expect = (Vec3::Y * 4.0 + Vec3::Z * 1.0).normalize();
        assert!((m.normals[0] - expect).length() < 1e-6);
        assert!((m.normals[1] - Vec3::Y).length() < 1e-6);
        m.invert();
        assert_eq!(m.triangles[0], [0, 2, 1]);
        assert!((m.normals[1] + Vec3::Y).length() < 1e-6);
    }
}
