//! What the OBJ and PLY readers share: the file being read (for errors that
//! point at a byte of it), tokens shown in messages, numbers read from
//! tokens, file normals made unit length, and per-corner normals and
//! texture coordinates turned into per-vertex ones.

use std::collections::HashMap;

use glam::{Vec2, Vec3};

use super::Mesh;
use crate::error::{Location, SceneError};

/// A mesh file being read: its bundle-relative name and its bytes, so that
/// an error can say where in it it was found.
#[derive(Clone, Copy)]
pub(super) struct MeshFile<'a> {
    pub name: &'a str,
    pub bytes: &'a [u8],
}

impl MeshFile<'_> {
    /// An error at byte offset `at` (reported as line:column).
    pub fn error_at(&self, at: usize, msg: impl Into<String>) -> SceneError {
        SceneError::new(Location::at_offset(self.name, self.bytes, at), msg)
    }

    /// An error at an explicit line and column, for text that has no lines
    /// of its own (a binary body).
    pub fn error_at_line(&self, line: u32, column: u32, msg: impl Into<String>) -> SceneError {
        SceneError::new(Location::new(self.name, line, column), msg)
    }
}

/// A token for an error message: lossy, and cut short if it is very long.
pub(super) fn show(tok: &[u8]) -> String {
    const MAX: usize = 40;
    if tok.len() > MAX {
        format!("{}…", String::from_utf8_lossy(&tok[..MAX]))
    } else {
        String::from_utf8_lossy(tok).into_owned()
    }
}

/// `tok` parsed as a `T` (a number), or `None` if it is not UTF-8 or not
/// in `T`'s syntax.
pub(super) fn parse_token<T: std::str::FromStr>(tok: &[u8]) -> Option<T> {
    std::str::from_utf8(tok).ok()?.parse().ok()
}

/// `n` normalised, or `None` if it has no direction. `-0.0` becomes `0.0`
/// so that equal normals compare equal bit for bit.
pub(super) fn unit_normal(n: Vec3) -> Option<Vec3> {
    let d = n.as_dvec3();
    let len = d.length();
    if len > 0.0 && len.is_finite() {
        Some((d / len).as_vec3() + Vec3::ZERO)
    } else {
        None
    }
}

/// Gives `mesh` per-vertex normals and texture coordinates from per-corner
/// ones (one `[_; 3]` per triangle), whichever are given; with neither the
/// mesh is left as it is. Texture coordinates without normals: the smooth
/// normals are made now, before seams are split, so that a seam's copies
/// share their original's normal and the shading does not show the seam.
/// `Err(0)` if the vertex count would overflow u32.
pub(super) fn per_vertex_attributes(
    mesh: &mut Mesh,
    corner_normals: Option<Vec<[Vec3; 3]>>,
    corner_uvs: Option<Vec<[Vec2; 3]>>,
) -> Result<(), usize> {
    if corner_uvs.is_none() && corner_normals.is_none() {
        return Ok(());
    }
    let corner_normals = match corner_normals {
        Some(c) => c,
        None => {
            mesh.compute_smooth_normals();
            mesh.triangles
                .iter()
                .map(|t| t.map(|i| mesh.normals[i as usize]))
                .collect()
        }
    };
    split_corners(mesh, Some(&corner_normals), corner_uvs.as_deref())
}

/// A corner's attributes as bits, for comparing them exactly: normal, uv.
type CornerKey = ([u32; 3], [u32; 2]);

/// Gives `mesh` one normal and/or uv per vertex from the per-corner ones
/// (whichever are given), splitting a position used with different ones.
/// Original positions keep their indices (with the first attributes they
/// are used with; unused ones get `+y` and uv `0 0`); the copies are
/// appended. `Err(0)` if the vertex count would overflow u32.
fn split_corners(
    mesh: &mut Mesh,
    corner_normals: Option<&[[Vec3; 3]]>,
    corner_uvs: Option<&[[Vec2; 3]]>,
) -> Result<(), usize> {
    let original = mesh.positions.len();
    let mut assigned: Vec<Option<(Vec3, Vec2)>> = vec![None; original];
    let mut extra: Vec<(Vec3, Vec2)> = Vec::new();
    let mut copies: HashMap<(u32, CornerKey), u32> = HashMap::new();
    let key = |(n, uv): (Vec3, Vec2)| -> CornerKey {
        (
            n.to_array().map(f32::to_bits),
            uv.to_array().map(f32::to_bits),
        )
    };
    for (k, t) in mesh.triangles.iter_mut().enumerate() {
        for (j, v) in t.iter_mut().enumerate() {
            let attrs = (
                corner_normals.map_or(Vec3::Y, |c| c[k][j]),
                corner_uvs.map_or(Vec2::ZERO, |c| c[k][j]),
            );
            let slot = &mut assigned[*v as usize];
            match slot {
                None => *slot = Some(attrs),
                Some(m) if key(*m) == key(attrs) => {}
                Some(_) => {
                    let ck = (*v, key(attrs));
                    *v = match copies.get(&ck) {
                        Some(&i) => i,
                        None => {
                            let i = mesh.positions.len();
                            if i >= u32::MAX as usize {
                                return Err(0);
                            }
                            mesh.positions.push(mesh.positions[*v as usize]);
                            extra.push(attrs);
                            copies.insert(ck, i as u32);
                            i as u32
                        }
                    };
                }
            }
        }
    }
    let all = assigned
        .into_iter()
        .map(|a| a.unwrap_or((Vec3::Y, Vec2::ZERO)))
        .chain(extra);
    if corner_normals.is_some() && corner_uvs.is_some() {
        (mesh.normals, mesh.uvs) = all.unzip();
    } else if corner_normals.is_some() {
        mesh.normals = all.map(|a| a.0).collect();
    } else {
        mesh.uvs = all.map(|a| a.1).collect();
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_are_shown_cut_short_and_parsed_strictly() {
        assert_eq!(show(b"abc"), "abc");
        assert_eq!(show(&[b'x'; 50]), format!("{}…", "x".repeat(40)));
        assert_eq!(show(b"\xffa"), "\u{fffd}a");
        assert_eq!(parse_token::<f32>(b"1.5"), Some(1.5));
        assert_eq!(parse_token::<i64>(b"1.5"), None);
        assert_eq!(parse_token::<i64>(b"\xff1"), None);
        assert_eq!(parse_token::<u64>(b"-1"), None);
    }

    #[test]
    fn unit_normals_have_no_negative_zero_and_zero_has_none() {
        let n = unit_normal(Vec3::new(-0.0, 0.0, -3.0)).unwrap();
        assert_eq!(n.to_array().map(f32::to_bits), [0, 0, (-1.0f32).to_bits()]);
        assert_eq!(unit_normal(Vec3::ZERO), None);
        assert_eq!(unit_normal(Vec3::new(f32::INFINITY, 0.0, 0.0)), None);
        assert_eq!(unit_normal(Vec3::new(f32::NAN, 0.0, 0.0)), None);
        // Large enough that squaring overflows f32: still a direction.
        assert_eq!(unit_normal(Vec3::new(0.0, 1e30, 0.0)), Some(Vec3::Y));
    }

    #[test]
    fn errors_point_at_a_byte_or_a_line() {
        let f = MeshFile {
            name: "m.obj",
            bytes: b"v 0\nv 1 x\n",
        };
        assert_eq!(f.error_at(8, "bad").to_string(), "m.obj:2:5: bad");
        assert_eq!(f.error_at_line(7, 3, "bad").to_string(), "m.obj:7:3: bad");
    }
}
