//! The PLY body: the elements the header declares, in order, read through
//! a [`Body`] (ASCII or binary) into a [`Mesh`]: vertices, faces
//! (fan-triangulated) and triangle strips; every other property is read
//! and dropped, so it is still checked for being well-formed and complete.

use glam::{Vec2, Vec3};

use super::header::{Header, Kind, Role, Scalar, Use};
use crate::error::SceneError;
use crate::mesh::read::{per_vertex_attributes, unit_normal};
use crate::mesh::Mesh;

/// Which value is being read, for error messages.
pub(super) struct Ctx<'h> {
    element: &'h str,
    index: u64,
    property: &'h str,
}

impl<'h> Ctx<'h> {
    /// Property `property` of instance `index` of element `element`.
    pub(super) fn new(element: &'h str, index: u64, property: &'h str) -> Self {
        Ctx {
            element,
            index,
            property,
        }
    }
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
    let mut faces = FaceUvs::new(h.has_face_uvs);

    for el in &h.elements {
        if el.props.is_empty() {
            continue; // nothing to read, whatever the count
        }
        for index in 0..el.count {
            let mut v = [0f64; 8];
            let first_triangle = triangles.len();
            faces.start();
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
                        match role {
                            Role::Indices if el.used == Use::Strips => {
                                read_strips(src, n, item, nv, &ctx, &mut triangles)?
                            }
                            Role::Indices => {
                                faces.corners(src, n, &ctx)?;
                                read_face(src, n, item, nv, &ctx, &mut triangles)?
                            }
                            Role::TexCoord => faces.read(src, n, item, &ctx)?,
                            _ => src.skip(n, item, &ctx)?,
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
            if el.used != Use::Vertex {
                faces.finish(triangles.len() - first_triangle);
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
    let mut mesh = Mesh {
        positions,
        normals,
        uvs,
        triangles,
    };
    if let Some(corner_uvs) = faces.into_corner_uvs(mesh.triangles.len()) {
        let corner_normals = (!mesh.normals.is_empty()).then(|| {
            mesh.triangles
                .iter()
                .map(|t| t.map(|i| mesh.normals[i as usize]))
                .collect()
        });
        mesh.normals = Vec::new();
        if per_vertex_attributes(&mut mesh, corner_normals, Some(corner_uvs)).is_err() {
            return Err(src.error("too many vertices after splitting by texture coordinate".into()));
        }
    }
    Ok(mesh)
}

/// The faces' `texcoord` lists: `u v` for each corner of the face, turned
/// into one `[uv; 3]` per triangle of its fan. A face whose list is empty
/// has no texture coordinates, and then neither has the mesh (as in OBJ,
/// where a corner without `vt` drops them all); so do triangle strips,
/// which have none.
struct FaceUvs {
    used: bool,
    /// This face's vertex count and `texcoord` list length, once read.
    corners: Option<u64>,
    values: Option<u64>,
    /// This face's `u v` pairs (reused from face to face: its size is
    /// bounded by the file, since every value is read before it is kept).
    uv: Vec<Vec2>,
    /// One entry per triangle so far, while every one has texture coordinates.
    per_triangle: Vec<[Vec2; 3]>,
    complete: bool,
}

impl FaceUvs {
    fn new(used: bool) -> FaceUvs {
        FaceUvs {
            used,
            corners: None,
            values: None,
            uv: Vec::new(),
            per_triangle: Vec::new(),
            complete: used,
        }
    }

    /// A new element instance begins.
    fn start(&mut self) {
        self.corners = None;
        self.values = None;
        self.uv.clear();
    }

    /// Checks the lengths of a face's two lists once both are known; the
    /// error is at the count read last (the second list's).
    fn check(&self, src: &impl Body, ctx: &Ctx) -> Result<(), SceneError> {
        match (self.corners, self.values) {
            (Some(n), Some(m)) if m != 0 && Some(m) != n.checked_mul(2) => Err(src.error(format!(
                "{ctx}: a face of {n} vertices has a texcoord list of {m} values \
                 (expected {}: u v for each corner, or 0 for none)",
                n.saturating_mul(2)
            ))),
            _ => Ok(()),
        }
    }

    /// The face's vertex count `n`, just read.
    fn corners(&mut self, src: &impl Body, n: u64, ctx: &Ctx) -> Result<(), SceneError> {
        self.corners = Some(n);
        self.check(src, ctx)
    }

    /// Reads a `texcoord` list of `m` values of type `item`, whose count was just read.
    fn read(
        &mut self,
        src: &mut impl Body,
        m: u64,
        item: Scalar,
        ctx: &Ctx,
    ) -> Result<(), SceneError> {
        self.values = Some(m);
        if m % 2 == 1 {
            return Err(src.error(format!(
                "{ctx}: a texcoord list needs an even number of values (u v for each corner), \
                 found {m}"
            )));
        }
        self.check(src, ctx)?;
        for _ in 0..m / 2 {
            let mut uv = [0f32; 2];
            for x in &mut uv {
                let value = src.read(item, ctx)?;
                *x = value as f32;
                if !x.is_finite() {
                    return Err(src.error(format!(
                        "{ctx}: value {value} is not a finite single-precision number"
                    )));
                }
            }
            self.uv.push(Vec2::from(uv));
        }
        Ok(())
    }

    /// The element instance is read and added `added` triangles: a face's
    /// fan `(0, k-1, k)` takes the uvs of those corners.
    fn finish(&mut self, added: usize) {
        if !self.complete || added == 0 {
            return;
        }
        if self.uv.is_empty() {
            self.complete = false;
            self.per_triangle = Vec::new();
            return;
        }
        // The lengths were checked: `uv` has one entry per corner.
        self.per_triangle
            .extend((2..self.uv.len()).map(|k| [self.uv[0], self.uv[k - 1], self.uv[k]]));
    }

    /// The per-triangle texture coordinates, if every one of the mesh's
    /// `triangles` has them.
    fn into_corner_uvs(self, triangles: usize) -> Option<Vec<[Vec2; 3]>> {
        (self.used && self.complete && self.per_triangle.len() == triangles)
            .then_some(self.per_triangle)
    }
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

// Test geometry only: std's maths is fine here (clippy.toml).
#[cfg(test)]
#[allow(clippy::disallowed_methods)]
mod tests {
    use super::super::test_files::*;
    use glam::{Vec2, Vec3};

    /// A unit square as two triangles sharing the edge 0-2, with a UV seam
    /// along it: the first face maps to the left half of the image, the
    /// second to the right half, so vertices 0 and 2 have two uvs each.
    const SQUARE_HEADER: &str = "element vertex 4\nproperty float x\nproperty float y\n\
         property float z\nproperty float u\nproperty float v\nelement face 2\n\
         property list uchar int vertex_indices\nproperty list uchar float texcoord\n";

    fn square_rows() -> Vec<Vec<V>> {
        let f = V::F32;
        // Vertex u v are there too, and must lose to the faces' texcoord.
        let mut rows: Vec<Vec<V>> = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
            .iter()
            .map(|&[x, y]| vec![f(x), f(y), f(0.0), f(9.0), f(9.0)])
            .collect();
        let face = |idx: [i32; 3], uv: [f32; 6]| {
            let mut row = vec![V::U8(3)];
            row.extend(idx.map(V::I32));
            row.push(V::U8(6));
            row.extend(uv.map(V::F32));
            row
        };
        rows.push(face([0, 1, 2], [0.0, 0.0, 0.5, 0.0, 0.5, 1.0]));
        rows.push(face([0, 2, 3], [0.5, 0.0, 1.0, 1.0, 1.0, 0.0]));
        rows
    }

    /// Each triangle's corners as (position, uv), from the loaded mesh.
    fn corners(m: &crate::mesh::Mesh) -> Vec<[(Vec3, Vec2); 3]> {
        m.triangles
            .iter()
            .map(|t| t.map(|i| (m.positions[i as usize], m.uvs[i as usize])))
            .collect()
    }

    #[test]
    fn face_texcoord_lists_give_each_corner_its_uv_and_split_seams() {
        let p = |x: f32, y: f32| Vec3::new(x, y, 0.0);
        let uv = Vec2::new;
        let expect = vec![
            [
                (p(0., 0.), uv(0.0, 0.0)),
                (p(1., 0.), uv(0.5, 0.0)),
                (p(1., 1.), uv(0.5, 1.0)),
            ],
            [
                (p(0., 0.), uv(0.5, 0.0)),
                (p(1., 1.), uv(1.0, 1.0)),
                (p(0., 1.), uv(1.0, 0.0)),
            ],
        ];
        // The texcoord list after the indices, and before them.
        let before = SQUARE_HEADER.replace(
            "property list uchar int vertex_indices\nproperty list uchar float texcoord\n",
            "property list uchar float texcoord\nproperty list uchar int vertex_indices\n",
        );
        let mut swapped = square_rows();
        for row in &mut swapped[4..] {
            row.rotate_left(4);
        }
        for format in FORMATS {
            for (header, rows) in [
                (SQUARE_HEADER, square_rows()),
                (before.as_str(), swapped.clone()),
            ] {
                let m = ok(&ply(format, header, &rows));
                assert_eq!(corners(&m), expect, "{format}");
                // 0 and 2 are on the seam: one copy each.
                assert_eq!(m.positions.len(), 6, "{format}");
                // No file normals: smooth ones, the same on both sides of the seam.
                assert_eq!(m.normals.len(), 6);
                assert!(m.normals.iter().all(|n| (*n - Vec3::Z).length() < 1e-6));
                crate::testing::check_mesh_invariants(&m);
            }
        }
    }

    /// A polygon is fan-triangulated, `(0, k-1, k)`, and so are its uvs;
    /// file normals follow their vertices into the copies.
    #[test]
    fn a_polygon_s_texcoords_follow_its_fan_and_normals_follow_the_split() {
        let header = "element vertex 5\nproperty float x\nproperty float y\nproperty float z\n\
             property float nx\nproperty float ny\nproperty float nz\n\
             element face 2\nproperty list uchar int vertex_indices\n\
             property list uint double texcoord\n";
        let f = V::F32;
        let mut rows: Vec<Vec<V>> = (0..5)
            .map(|i| {
                let a = i as f32 * 1.2566371;
                vec![
                    f(a.cos()),
                    f(a.sin()),
                    f(0.0),
                    f(0.0),
                    f(0.0),
                    f(2.0 + i as f32),
                ]
            })
            .collect();
        let mut pentagon = vec![V::U8(5)];
        pentagon.extend((0..5).map(V::I32));
        pentagon.push(V::U32(10));
        pentagon.extend((0..10).map(|k| V::F64(k as f64 / 10.0)));
        rows.push(pentagon);
        // A second face reusing vertex 1 with another uv: a copy of it.
        rows.push(vec![
            V::U8(3),
            V::I32(1),
            V::I32(0),
            V::I32(4),
            V::U32(6),
            V::F64(7.0),
            V::F64(8.0),
            V::F64(0.0),
            V::F64(0.1),
            V::F64(0.8),
            V::F64(0.9),
        ]);
        for format in FORMATS {
            let m = ok(&ply(format, header, &rows));
            let uv = |k: usize| Vec2::new(k as f32 * 0.2, k as f32 * 0.2 + 0.1);
            let got: Vec<[Vec2; 3]> = m
                .triangles
                .iter()
                .map(|t| t.map(|i| m.uvs[i as usize]))
                .collect();
            for (t, g) in got[..3].iter().enumerate() {
                for (c, k) in [0, t + 1, t + 2].into_iter().enumerate() {
                    assert!(
                        (g[c] - uv(k)).length() < 1e-6,
                        "{format}: triangle {t} corner {c}: {g:?}"
                    );
                }
            }
            assert_eq!(
                got[3],
                [
                    Vec2::new(7.0, 8.0),
                    Vec2::new(0.0, 0.1),
                    Vec2::new(0.8, 0.9)
                ]
            );
            assert_eq!(m.triangles.len(), 4);
            // Vertex 1 is split; the copy has the same position and file normal.
            let copy = m.triangles[3][0] as usize;
            assert_eq!(copy, 5, "{format}");
            assert_eq!(m.positions[copy], m.positions[1]);
            assert_eq!(m.normals[copy], Vec3::Z);
            assert_eq!(m.positions.len(), 6);
        }
    }

    /// An empty list is a face without texture coordinates, so the mesh
    /// has none (as an OBJ corner without `vt`); triangle strips have none.
    #[test]
    fn an_empty_texcoord_list_or_a_strip_leaves_the_mesh_without_uvs() {
        let mut rows = square_rows();
        rows[5].truncate(5);
        rows[5][4] = V::U8(0);
        for format in FORMATS {
            let m = ok(&ply(format, SQUARE_HEADER, &rows));
            assert!(m.uvs.is_empty(), "{format}");
            assert_eq!(m.positions.len(), 4);
            assert!(m.normals.is_empty(), "the caller makes smooth ones");
        }
        let header =
            format!("{SQUARE_HEADER}element tristrips 1\nproperty list int int vertex_indices\n");
        let mut rows = square_rows();
        rows.push(vec![V::I32(3), V::I32(1), V::I32(2), V::I32(3)]);
        for format in FORMATS {
            let m = ok(&ply(format, &header, &rows));
            assert!(m.uvs.is_empty(), "{format}");
            assert_eq!(m.triangles.len(), 3);
        }
    }

    #[test]
    fn texcoord_errors_are_located() {
        let file = |faces: &str| {
            head(&format!(
                "{SQUARE_HEADER}end_header\n0 0 0 0 0\n1 0 0 0 0\n1 1 0 0 0\n0 1 0 0 0\n{faces}"
            ))
        };
        // The header has 12 lines, the vertices 4: the faces are lines 17 and 18.
        assert_eq!(
            ok(&file("3 0 1 2 6 0 0 1 0 1 1\n3 0 2 3 0\n"))
                .triangles
                .len(),
            2
        );
        fails(
            &file("3 0 1 2 6 0 0 1 0 1 1\n3 0 2 3 4 0 0 1 0\n"),
            18,
            9,
            "property \"texcoord\" of face 1: a face of 3 vertices has a texcoord list of 4 values (expected 6",
        );
        fails(
            &file("3 0 1 2 5 0 0 1 0 1\n"),
            17,
            9,
            "texcoord list needs an even number of values",
        );
        fails(
            &file("3 0 1 2 6 0 0 1 0 1 zz\n"),
            17,
            21,
            "expected float, found \"zz\"",
        );
        fails(&file("3 0 1 2 6 0 0 1 0 1 1e39\n"), 17, 21, "not a finite");
        fails(
            &file("3 0 1 2 6 0 0 1 0 1\n"),
            18,
            1,
            "unexpected end of file",
        );
        fails(
            &head(&SQUARE_HEADER.replace("list uchar float texcoord", "float texcoord")),
            11,
            16,
            "face property \"texcoord\" must be a list",
        );
        // The texcoord list first: the error is at the vertex count.
        let before = SQUARE_HEADER.replace(
            "property list uchar int vertex_indices\nproperty list uchar float texcoord\n",
            "property list uchar float texcoord\nproperty list uchar int vertex_indices\n",
        );
        fails(
            &head(&format!(
                "{before}end_header\n0 0 0 0 0\n1 0 0 0 0\n1 1 0 0 0\n0 1 0 0 0\n6 0 0 1 0 1 1 4 0 1 2 3\n"
            )),
            17,
            15,
            "property \"vertex_indices\" of face 0: a face of 4 vertices has a texcoord list of 6 values",
        );
        for format in ["binary_little_endian", "binary_big_endian"] {
            let mut rows = square_rows();
            rows[5][4] = V::U8(4);
            rows[5].truncate(9);
            // Vertices take 4 x 20 bytes, face 0 13 + 25: face 1's texcoord count is at byte 131.
            fails(
                &ply(format, SQUARE_HEADER, &rows),
                13,
                132,
                "byte 131 of the binary body: property \"texcoord\" of face 1: a face of 3 vertices has a texcoord list of 4 values",
            );
        }
    }

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
