//! Triangle meshes as loaded: shared by every model that instances them.
//!
//! A mesh is stored once, in its own (object) space; models refer to it by
//! index and carry their own transform, so a mesh used by 100 models costs
//! its triangles once.

pub mod obj;
pub mod ply;

use glam::Vec3;

/// An indexed triangle mesh. `normals` always has one entry per position once
/// the mesh is finished (computed when the source had none).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
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
