//! The PLY body: the elements the header declares, in order, read through
//! a [`Body`] (ASCII or binary) into a [`Mesh`]: vertices, faces
//! (fan-triangulated) and triangle strips; every other property is read
//! and dropped, so it is still checked for being well-formed and complete.

use glam::{Vec2, Vec3};

use super::header::{Header, Kind, Role, Scalar, Use};
use crate::error::SceneError;
use crate::mesh::read::unit_normal;
use crate::mesh::Mesh;

/// Which value is being read, for error messages.
pub(super) struct Ctx<'h> {
    element: &'h str,
    index: u64,
    property: &'h str,
}

impl std::fmt::Display for Ctx<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "property \"{}\" of {} {}",
            self.property, self.element, self.index
        )
    }
}

/// A PLY body, ASCII or binary.
pub(super) trait Body {
    /// Reads one value of type `ty` (integers are exact in an f64).
    fn read(&mut self, ty: Scalar, ctx: &Ctx) -> Result<f64, SceneError>;
    /// Skips `n` list items of type `ty`.
    fn skip(&mut self, n: u64, ty: Scalar, ctx: &Ctx) -> Result<(), SceneError>;
    /// An error at the value read last.
    fn error(&self, msg: String) -> SceneError;
    /// Checks that nothing but allowed padding follows the last element.
    fn finish(&self) -> Result<(), SceneError>;
}

/// Reads the body `h` describes from `src`.
pub(super) fn read_body(src: &mut impl Body, h: &Header) -> Result<Mesh, SceneError> {
    let nv = h.vertex_count;
    // Both capacities are bounded by the body size (checked in the header).
    let mut positions: Vec<Vec3> = Vec::with_capacity(nv as usize);
    let mut normals: Vec<Vec3> = Vec::with_capacity(if h.has_normals { nv as usize } else { 0 });
    let mut uvs: Vec<Vec2> = Vec::with_capacity(if h.has_uvs { nv as usize } else { 0 });
    let face_count = h
        .elements
        .iter()
        .find(|e| e.used == Use::Face)
        .map_or(0, |e| e.count);
    let mut triangles: Vec<[u32; 3]> = Vec::with_capacity(face_count.min(1 << 24) as usize);
    let mut zero_normal = false;

    for el in &h.elements {
        if el.props.is_empty() {
            continue; // nothing to read, whatever the count
        }
        for index in 0..el.count {
            let mut v = [0f64; 8];
            for p in &el.props {
                let ctx = Ctx {
                    element: &el.name,
                    index,
                    property: &p.name,
                };
                match (p.kind, p.role) {
                    (Kind::Scalar(s), Role::Vertex(k)) => {
                        v[k] = src.read(s, &ctx)?;
                        if !(v[k] as f32).is_finite() {
                            return Err(src.error(format!(
                                "{ctx}: value {} is not a finite single-precision number",
                                v[k]
                            )));
                        }
                    }
                    (Kind::Scalar(s), _) => {
                        src.read(s, &ctx)?;
                    }
                    (Kind::List { count, item }, role) => {
                        let n = src.read(count, &ctx)?;
                        if n < 0.0 {
                            return Err(src.error(format!("{ctx}: negative list length {n}")));
                        }
                        let n = n as u64;
                        if role != Role::Indices {
                            src.skip(n, item, &ctx)?;
                        } else if el.used == Use::Strips {
                            read_strips(src, n, item, nv, &ctx, &mut triangles)?;
                        } else {
                            read_face(src, n, item, nv, &ctx, &mut triangles)?;
                        }
                    }
                }
            }
            if el.used == Use::Vertex {
                positions.push(Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32));
                if h.has_normals {
                    let n = Vec3::new(v[3] as f32, v[4] as f32, v[5] as f32);
                    match unit_normal(n) {
                        Some(n) => normals.push(n),
                        None => zero_normal = true,
                    }
                }
                if h.has_uvs {
                    uvs.push(Vec2::new(v[6] as f32, v[7] as f32));
                }
            }
        }
    }
    src.finish()?;
    if triangles.is_empty() {
        // Only strips can get here (a face is at least one triangle).
        return Err(src.error(
            "mesh has no triangles (every triangle strip has fewer than 3 vertices \
             or only repeated ones)"
                .into(),
        ));
    }
    if zero_normal {
        normals = Vec::new();
    }
    Ok(Mesh {
        positions,
        normals,
        uvs,
        triangles,
    })
}

/// `i` as the index of one of `nv` vertices, if it is one.
fn vertex_index(i: f64, nv: u32) -> Option<u32> {
    (0.0..nv as f64).contains(&i).then_some(i as u32)
}

/// Reads one face's index list of `n` items, fan-triangulated in file
/// order: `v0 v1 v2 v3 …` becomes `(v0,v1,v2), (v0,v2,v3), …`.
fn read_face(
    src: &mut impl Body,
    n: u64,
    item: Scalar,
    nv: u32,
    ctx: &Ctx,
    triangles: &mut Vec<[u32; 3]>,
) -> Result<(), SceneError> {
    if n < 3 {
        return Err(src.error(format!(
            "{ctx}: a face needs at least 3 vertices, found {n}"
        )));
    }
    let (mut first, mut prev) = (0u32, 0u32);
    for k in 0..n {
        let i = src.read(item, ctx)?;
        let Some(i) = vertex_index(i, nv) else {
            return Err(src.error(format!(
                "{ctx}: vertex index {i} out of range ({nv} vertices)"
            )));
        };
        match k {
            0 => first = i,
            1 => {}
            _ => triangles.push([first, prev, i]),
        }
        prev = i;
    }
    Ok(())
}

/// Reads one `tristrips` index list of `n` items: `-1` ends a strip and
/// starts the next. In a strip `v0 v1 v2 v3 …`, triangle k is
/// `(v_k, v_k+1, v_k+2)` for even k and `(v_k+1, v_k, v_k+2)` for odd k, so
/// that every triangle of the strip has the winding of the first. A
/// triangle naming a vertex twice is the strip's way of turning a corner or
/// joining strips, not geometry: it is dropped (it still counts for the
/// parity of the ones after it). Triangles are numbered in file order.
fn read_strips(
    src: &mut impl Body,
    n: u64,
    item: Scalar,
    nv: u32,
    ctx: &Ctx,
    triangles: &mut Vec<[u32; 3]>,
) -> Result<(), SceneError> {
    // Vertices in the current strip so far, and its last two.
    let mut run = 0u64;
    let (mut a, mut b) = (0u32, 0u32);
    for _ in 0..n {
        let i = src.read(item, ctx)?;
        if i == -1.0 {
            run = 0;
            continue;
        }
        let Some(c) = vertex_index(i, nv) else {
            return Err(src.error(format!(
                "{ctx}: vertex index {i} out of range ({nv} vertices; -1 restarts a strip)"
            )));
        };
        if run >= 2 && a != b && b != c && a != c {
            triangles.push(if (run - 2).is_multiple_of(2) {
                [a, b, c]
            } else {
                [b, a, c]
            });
        }
        (a, b) = (b, c);
        run += 1;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::test_files::*;

    #[test]
    fn tristrips_become_triangles_with_alternating_winding_and_no_stitching() {
        // Three strips and a one-vertex one: 0 1 2 3 4 | 5 6 7 | 1 | 3 4 4 5 6 7.
        let list = [0, 1, 2, 3, 4, -1, 5, 6, 7, -1, 1, -1, 3, 4, 4, 5, 6, 7];
        // By hand: strip k-th triangle is (v_k, v_k+1, v_k+2), odd k swapped;
        // (3 4 4) and (4 4 5) of the last strip repeat a vertex and go.
        let expect = vec![
            [0, 1, 2],
            [2, 1, 3],
            [2, 3, 4],
            [5, 6, 7],
            [4, 5, 6],
            [6, 5, 7],
        ];
        for format in FORMATS {
            let mut rows = zigzag_rows();
            let mut strip = vec![V::I32(list.len() as i32)];
            strip.extend(list.iter().map(|&i| V::I32(i)));
            rows.push(strip);
            let m = ok(&ply(format, STRIP_HEADER, &rows));
            assert_eq!(m.triangles, expect, "{format}");
            assert_eq!(m.positions.len(), 8);
            // The first strip's triangles all face the same way.
            for t in &m.triangles[..3] {
                let [a, b, c] = t.map(|i| m.positions[i as usize]);
                assert!((b - a).cross(c - a).z < 0.0, "{format}: {t:?}");
            }
        }
        // Faces and strips together: numbered in element order.
        let header =
            format!("{STRIP_HEADER}element face 1\nproperty list uchar int vertex_indices\n");
        let mut rows = zigzag_rows();
        rows.push(vec![V::I32(3), V::I32(0), V::I32(1), V::I32(2)]);
        rows.push(vec![V::U8(3), V::I32(7), V::I32(6), V::I32(5)]);
        assert_eq!(
            ok(&ply("ascii", &header, &rows)).triangles,
            vec![[0, 1, 2], [7, 6, 5]]
        );
    }

    #[test]
    fn tristrip_errors_are_located() {
        let file = |list: &str| {
            let body = "0 0 0\n1 0 0\n0 1 0\n1 1 0\n2 0 0\n2 1 0\n3 0 0\n3 1 0\n";
            head(&format!("{STRIP_HEADER}end_header\n{body}{list}\n"))
        };
        // The header has 9 lines, the vertices 8: the strip is line 18.
        assert_eq!(ok(&file("3 0 1 2")).triangles, vec![[0, 1, 2]]);
        fails(
            &file("5 0 1 2 8 3"),
            18,
            9,
            "property \"vertex_indices\" of tristrips 0: vertex index 8 out of range (8 vertices",
        );
        fails(&file("4 0 1 -2 3"), 18, 7, "vertex index -2 out of range");
        fails(&file("4 0 1 2"), 19, 1, "unexpected end of file");
        fails(&file("5 0 1 -1 2 2"), 18, 12, "mesh has no triangles");
        fails(
            &head(&STRIP_HEADER.replace("list int int", "int")),
            8,
            14,
            "tristrips property \"vertex_indices\" must be a list",
        );
        fails(
            &head(&format!(
                "{}end_header\n",
                STRIP_HEADER.replace("vertex_indices", "other")
            )),
            7,
            19,
            "tristrips element has no vertex_indices list",
        );
        for format in ["binary_little_endian", "binary_big_endian"] {
            let mut rows = zigzag_rows();
            rows.push(vec![V::I32(3), V::I32(0), V::I32(9), V::I32(2)]);
            // Vertices take 96 bytes, the count 4 more: index 9 is at byte 104.
            fails(
                &ply(format, STRIP_HEADER, &rows),
                10,
                105,
                "byte 104 of the binary body: property \"vertex_indices\" of tristrips 0: vertex index 9 out of range",
            );
        }
    }
}
