//! PLY loader (Stanford polygon format), ASCII and binary of both endiannesses.
//!
//! The header may declare any elements and properties; only `vertex`
//! (`x y z`, optional `nx ny nz`, any scalar types) and the list property
//! `vertex_indices` (or `vertex_index`, any integer types) of `face` and of
//! `tristrips` are used. Everything else is read and skipped, so it is still
//! checked for being well-formed and complete. Polygons are fan-triangulated
//! in file order, as for OBJ. Triangle strips (`element tristrips`, as in the
//! Stanford scans: one long list with `-1` between strips) become triangles
//! with alternating winding corrected, strip-stitching triangles that repeat
//! a vertex dropped (see `body.rs`); with both elements, triangles are
//! numbered in the order of the elements in the file.
//!
//! Parts: `header.rs` reads and checks the header, `body.rs` reads the
//! elements it declares into a mesh through `ascii.rs` or `binary.rs`; what
//! this reader shares with the OBJ reader is in `mesh/read.rs`.
//!
//! Resource bounds: before anything is allocated, the element counts of the
//! header are checked against the size of the body (every element has a
//! minimum encoded size: the sum of its scalars' sizes in binary, two bytes
//! per scalar in ASCII), so a header claiming 10^12 vertices is an error, and
//! list lengths are never trusted for allocation.
//!
//! Error locations: header errors and ASCII body errors point at the
//! offending token (line:column); binary body errors point at the line after
//! the header, column 1 + the byte offset into the body, and the message
//! says "byte N" (N = that offset).
//!
//! Texture coordinates: per vertex when the vertex element has both `u v`
//! (or `s t`, `texture_u texture_v`); per face corner when the face
//! element has a `texcoord` list (any scalar types) of `u v` for each
//! vertex of its `vertex_indices`, in that order (6 values for a triangle,
//! 2n for an n-gon, whose fan triangles `(0, k-1, k)` take those corners'
//! pairs; the list may come before or after the indices). Per-face ones win
//! over per-vertex ones. A vertex used with different uvs (a seam) is
//! copied, as in OBJ (`mesh/read.rs`); without file normals, smooth ones are
//! made before the split so the seam does not show. A list of another
//! length than 2n is an error at the second of the two lists' counts; an
//! empty one means the face has none, and then neither has the mesh (nor
//! when it also has triangle strips, which have no texture coordinates).
//!
//! Normals: used when the vertex element has all of `nx ny nz`; they are
//! normalised, and a zero-length one drops the normals of the whole mesh (the
//! caller then computes smooth ones). Non-finite coordinates or normals are
//! errors. Trailing data after the last element is an error in ASCII; in
//! binary only trailing ASCII whitespace is tolerated.

mod ascii;
mod binary;
mod body;
mod counts;
mod header;
#[cfg(test)]
mod test_files;

use super::read::MeshFile;
use super::Mesh;
use crate::error::SceneError;
use ascii::AsciiBody;
use binary::BinaryBody;
use body::read_body;
use header::{Format, Header};

pub use counts::counts;

/// Parses a PLY file's bytes. `file` is the bundle-relative name used in errors.
pub fn parse(file: &str, bytes: &[u8]) -> Result<Mesh, SceneError> {
    let file = MeshFile { name: file, bytes };
    let header = Header::parse(file)?;
    match header.format {
        Format::Ascii => read_body(&mut AsciiBody::new(file, header.body_start), &header),
        Format::BinaryLe | Format::BinaryBe => read_body(
            &mut BinaryBody::new(
                file,
                header.body_start,
                header.body_line,
                header.format == Format::BinaryBe,
            ),
            &header,
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::test_files::*;
    use super::*;
    use crate::testing::{apply_edits, check_mesh_invariants, Edit};
    use glam::{Vec2, Vec3};
    use proptest::prelude::*;

    #[test]
    fn ascii_and_both_binary_endiannesses_give_the_hand_built_mesh() {
        let reference = pyramid();
        for format in FORMATS {
            let m = ok(&pyramid_file(format));
            assert_eq!(m.positions, reference.positions, "{format}");
            assert_eq!(m.triangles, reference.triangles, "{format}");
            for (a, b) in m.normals.iter().zip(&reference.normals) {
                assert!((*a - *b).length() < 1e-7, "{format}: {a} vs {b}");
            }
            assert_eq!(m.normals.len(), 5, "{format}");
        }
    }

    #[test]
    fn every_scalar_type_and_both_index_names_work() {
        let int_types: Vec<&str> = TYPES
            .iter()
            .copied()
            .filter(|t| !t.starts_with("float") && *t != "double")
            .collect();
        for format in FORMATS {
            for (k, ty) in TYPES.iter().enumerate() {
                let count_ty = int_types[k % int_types.len()];
                let index_ty = int_types[(k + 3) % int_types.len()];
                let list_name = ["vertex_indices", "vertex_index"][k % 2];
                let header = format!(
                    "element vertex 4\nproperty {ty} x\nproperty {ty} y\nproperty {ty} z\n\
                     element face 1\nproperty list {count_ty} {index_ty} {list_name}\n"
                );
                let c = |x| V::as_type(x, ty);
                let i = |x| V::as_type(x, index_ty);
                let rows = vec![
                    vec![c(0), c(0), c(0)],
                    vec![c(1), c(0), c(0)],
                    vec![c(1), c(1), c(2)],
                    vec![c(0), c(1), c(0)],
                    vec![V::as_type(4, count_ty), i(0), i(1), i(2), i(3)],
                ];
                let m = ok(&ply(format, &header, &rows));
                let what = format!("{format} {ty} {count_ty} {index_ty}");
                assert_eq!(
                    m.positions,
                    vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 2.0), Vec3::Y],
                    "{what}"
                );
                assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]], "{what}");
                assert!(m.normals.is_empty(), "{what}");
            }
        }
    }

    /// Per-vertex texture coordinates under each of their three names, in
    /// every format, and in any property order; only one of the pair is
    /// skipped like any other property.
    #[test]
    fn vertex_texture_coordinates_under_each_name() {
        for (u, v) in [("u", "v"), ("s", "t"), ("texture_u", "texture_v")] {
            let header = format!(
                "element vertex 3\nproperty float {v}\nproperty float x\nproperty float y\n\
                 property float z\nproperty double {u}\n\
                 element face 1\nproperty list uchar uint vertex_indices\n"
            );
            let rows = vec![
                vec![
                    V::F32(0.25),
                    V::F32(0.0),
                    V::F32(0.0),
                    V::F32(0.0),
                    V::F64(0.5),
                ],
                vec![
                    V::F32(0.0),
                    V::F32(1.0),
                    V::F32(0.0),
                    V::F32(0.0),
                    V::F64(1.0),
                ],
                vec![
                    V::F32(1.0),
                    V::F32(0.0),
                    V::F32(1.0),
                    V::F32(0.0),
                    V::F64(-2.0),
                ],
                vec![V::U8(3), V::U32(0), V::U32(1), V::U32(2)],
            ];
            for format in FORMATS {
                let m = ok(&ply(format, &header, &rows));
                assert_eq!(
                    m.uvs,
                    vec![
                        Vec2::new(0.5, 0.25),
                        Vec2::new(1.0, 0.0),
                        Vec2::new(-2.0, 1.0)
                    ],
                    "{u} {v} {format}"
                );
                assert_eq!(m.positions[2], Vec3::new(0.0, 1.0, 0.0));
            }
            let half = header.replace(&format!("property float {v}\n"), "property float w\n");
            for format in FORMATS {
                let m = ok(&ply(format, &half, &rows));
                assert!(m.uvs.is_empty(), "{u} alone {format}");
            }
        }
    }

    #[test]
    fn crlf_header_and_zero_or_partial_normals() {
        let header =
            "element vertex 3\r\nproperty float x\r\nproperty float y\r\nproperty float z\r\n\
                      property float nx\r\nproperty float ny\r\nproperty float nz\r\n\
                      element face 1\r\nproperty list uchar uint vertex_indices\r\n";
        let mut rows = vec![
            vec![
                V::F32(0.0),
                V::F32(0.0),
                V::F32(0.0),
                V::F32(0.0),
                V::F32(0.0),
                V::F32(5.0),
            ],
            vec![
                V::F32(1.0),
                V::F32(0.0),
                V::F32(0.0),
                V::F32(0.0),
                V::F32(0.0),
                V::F32(1.0),
            ],
            vec![
                V::F32(0.0),
                V::F32(1.0),
                V::F32(0.0),
                V::F32(0.0),
                V::F32(0.0),
                V::F32(1.0),
            ],
            vec![V::U8(3), V::U32(0), V::U32(1), V::U32(2)],
        ];
        for format in FORMATS {
            let m = ok(&ply(format, header, &rows));
            assert_eq!(m.normals, vec![Vec3::Z; 3], "{format}");
        }
        rows[1][5] = V::F32(0.0);
        for format in FORMATS {
            let m = ok(&ply(format, header, &rows));
            assert!(
                m.normals.is_empty(),
                "{format}: a zero normal drops them all"
            );
            assert_eq!(m.triangles, vec![[0, 1, 2]]);
        }
        // Only nx and ny: the normals are skipped like any other property.
        let partial = header.replace("property float nz\r\n", "property float w\r\n");
        for format in FORMATS {
            let m = ok(&ply(format, &partial, &rows));
            assert!(m.normals.is_empty(), "{format}");
            assert_eq!(m.positions.len(), 3);
        }
    }

    fn edit() -> impl Strategy<Value = Edit> {
        crate::testing::edit(b"\n \r0123456789-.e")
    }

    fn count() -> impl Strategy<Value = u64> {
        prop_oneof![
            0u64..8,
            any::<u64>(),
            Just(u64::MAX),
            Just(1 << 40),
            Just(u32::MAX as u64)
        ]
    }

    proptest! {
        #[test]
        fn mutated_ply_never_panics(
            format in prop::sample::select(FORMATS.to_vec()),
            edits in prop::collection::vec(edit(), 1..10),
        ) {
            let bytes = apply_edits(pyramid_file(format), &edits);
            if let Ok(m) = parse("m.ply", &bytes) {
                check_mesh_invariants(&m);
            }
        }

        #[test]
        fn random_headers_with_huge_counts_never_panic(
            format in prop::sample::select(FORMATS.to_vec()),
            vertices in count(),
            faces in count(),
            extra in count(),
            ty in prop::sample::select(TYPES.to_vec()),
            count_ty in prop::sample::select(vec!["uchar", "char", "uint", "int", "ushort"]),
            index_ty in prop::sample::select(vec!["uchar", "char", "uint", "int", "short"]),
            body in prop::collection::vec(
                prop_oneof![any::<u8>(), prop::sample::select(b"0123 \n-".to_vec())],
                0..200,
            ),
        ) {
            let header = format!(
                "ply\nformat {format} 1.0\nelement vertex {vertices}\nproperty {ty} x\n\
                 property {ty} y\nproperty {ty} z\nelement extra {extra}\n\
                 property list {count_ty} {ty} stuff\nelement face {faces}\n\
                 property list {count_ty} {index_ty} vertex_indices\n\
                 property list {count_ty} {ty} texcoord\nend_header\n"
            );
            let mut bytes = header.into_bytes();
            bytes.extend_from_slice(&body);
            if let Ok(m) = parse("m.ply", &bytes) {
                check_mesh_invariants(&m);
            }
        }

        #[test]
        fn random_bytes_after_the_magic_never_panic(
            bytes in prop::collection::vec(any::<u8>(), 0..300),
        ) {
            let mut file = b"ply\n".to_vec();
            file.extend_from_slice(&bytes);
            let _ = parse("m.ply", &file);
            let _ = parse("m.ply", &bytes);
        }
    }
}
