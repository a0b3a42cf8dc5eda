//! A PLY file's vertex and triangle counts without building its mesh (see
//! `mesh/counts.rs`): the header is read as the loader reads it, then the
//! body is walked once, each list's length read and its items skipped, so
//! nothing is allocated for the elements.

use super::ascii::AsciiBody;
use super::binary::BinaryBody;
use super::body::{Body, Ctx};
use super::header::{Format, Header, Kind, Role, Use};
use crate::error::SceneError;
use crate::mesh::counts::MeshCounts;
use crate::mesh::read::MeshFile;

/// Counts a PLY file's vertices and triangles. A face of n vertices is
/// n − 2 triangles (the loader's fan); a triangle strip of n vertices at
/// most n − 2 (the loader drops the stitching ones), counted as n. With
/// per-face texture coordinates a vertex may be split once per corner.
pub fn counts(file: &str, bytes: &[u8]) -> Result<MeshCounts, SceneError> {
    let file = MeshFile { name: file, bytes };
    let h = Header::parse(file)?;
    let triangles = match h.format {
        Format::Ascii => walk(&mut AsciiBody::new(file, h.body_start), &h)?,
        Format::BinaryLe | Format::BinaryBe => walk(
            &mut BinaryBody::new(
                file,
                h.body_start,
                h.body_line,
                h.format == Format::BinaryBe,
            ),
            &h,
        )?,
    };
    let v = u64::from(h.vertex_count);
    Ok(MeshCounts {
        vertices: if h.has_face_uvs {
            v.saturating_add(triangles.saturating_mul(3))
        } else {
            v
        },
        file_vertices: v,
        triangles,
        uvs: h.has_uvs || h.has_face_uvs,
    })
}

/// Reads every element's scalars and list lengths, skipping list items;
/// returns the triangle count.
fn walk(src: &mut impl Body, h: &Header) -> Result<u64, SceneError> {
    let mut triangles = 0u64;
    for el in &h.elements {
        if el.props.is_empty() {
            continue;
        }
        for index in 0..el.count {
            for p in &el.props {
                let ctx = Ctx::new(&el.name, index, &p.name);
                match p.kind {
                    Kind::Scalar(s) => {
                        src.read(s, &ctx)?;
                    }
                    Kind::List { count, item } => {
                        let n = src.read(count, &ctx)?;
                        if n < 0.0 {
                            return Err(src.error(format!("{ctx}: negative list length {n}")));
                        }
                        let n = n as u64;
                        if p.role == Role::Indices {
                            triangles = triangles.saturating_add(match el.used {
                                Use::Strips => n,
                                _ => n.saturating_sub(2),
                            });
                        }
                        src.skip(n, item, &ctx)?;
                    }
                }
            }
        }
    }
    src.finish()?;
    Ok(triangles)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ply_counts_match_the_loader_in_ascii_and_binary() {
        let ascii = "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\n\
                     property float z\nelement face 2\nproperty list uchar int vertex_indices\n\
                     end_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n0 2 0\n4 0 1 2 3\n3 0 3 4\n";
        let c = counts("m.ply", ascii.as_bytes()).unwrap();
        let m = crate::mesh::ply::parse("m.ply", ascii.as_bytes()).unwrap();
        assert_eq!(c, MeshCounts::of(&m));
        assert_eq!((c.vertices, c.triangles), (5, 3));
        let mut bin = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n\
                        property float y\nproperty float z\nelement face 1\n\
                        property list uchar uint vertex_indices\nend_header\n"
            .to_vec();
        for v in [0f32, 0., 0., 1., 0., 0., 0., 1., 0.] {
            bin.extend_from_slice(&v.to_le_bytes());
        }
        bin.push(3);
        for i in [0u32, 1, 2] {
            bin.extend_from_slice(&i.to_le_bytes());
        }
        let c = counts("m.ply", &bin).unwrap();
        assert_eq!(
            c,
            MeshCounts::of(&crate::mesh::ply::parse("m.ply", &bin).unwrap())
        );
        // A body cut short is an error, as for the loader.
        assert!(counts("m.ply", &bin[..bin.len() - 2]).is_err());
    }
}
