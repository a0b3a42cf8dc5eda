//! Wavefront OBJ loader.
//!
//! What is read: `v x y z [w]` (also the common `v x y z r g b` vertex-colour
//! extension; `w` and colours are ignored), `vn x y z`, `vt u [v [w]]` (`v`
//! defaults to 0, `w` is ignored) and `f` with corners
//! `v`, `v/vt`, `v//vn`, `v/vt/vn` (an empty `vt` or `vn` field counts as
//! absent), positive and negative (relative) indices. Polygons are
//! fan-triangulated: `v0 v1 v2 v3 …` becomes `(v0,v1,v2), (v0,v2,v3), …`, and
//! triangles are numbered in file order.
//!
//! `mtllib` and `usemtl` are kept by [`parse_with_materials`] (the scene
//! reader loads the `.mtl` files, see `mtl.rs`). Everything else (`vp`,
//! `o`, `g`, `s`, `l`, `p`, unknown statements, comments from `#` to the end
//! of the physical line, blank lines) is ignored. Lines may end in `\r\n`, and
//! a backslash at the very end of a line continues the statement on the next.
//!
//! Indices must refer to elements defined earlier in the file (that is what
//! negative indices are relative to as well).
//!
//! Normals: when every face corner names a `vn`, every vertex gets a normal;
//! a position used with different normals is split, the extra copies appended
//! after the original positions so that vertex `i` of the file stays vertex
//! `i`. When any corner lacks a `vn`, or a used `vn` has zero length, the mesh
//! has no normals (the caller computes smooth ones).
//!
//! Texture coordinates: when every face corner names a `vt`, every vertex
//! gets one, split like normals (a position used with different `vt`s, a UV
//! seam, is copied); when any corner lacks one the mesh has none. A mesh
//! with texture coordinates but without normals gets its smooth normals
//! here, before the split, so that a seam does not show in the shading.

use std::collections::{HashMap, HashSet};

use glam::{Vec2, Vec3};

use super::read::{parse_token, per_vertex_attributes, show, unit_normal, MeshFile};
use super::Mesh;
use crate::error::SceneError;

/// "No normal" marker in a face corner.
const NONE: u32 = u32::MAX;

/// Parses a OBJ file's bytes. `file` is the bundle-relative name used in errors.
pub fn parse(file: &str, bytes: &[u8]) -> Result<Mesh, SceneError> {
    parse_with_materials(file, bytes).map(|(m, _)| m)
}

/// What an OBJ says about materials: the `.mtl` files of its `mtllib`
/// statements and the names of its `usemtl` statements (each with the byte
/// offset of the name, for errors), and per triangle the index in `names`
/// of the material it uses ([`NO_MATERIAL`] before any `usemtl`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ObjMaterials {
    /// Each distinct `mtllib` file name, as written, with its byte offset.
    pub libs: Vec<(String, usize)>,
    /// Each distinct `usemtl` name in order of first use, with the byte
    /// offset of its first use.
    pub names: Vec<(String, usize)>,
    /// Per triangle of the mesh, its index in `names`, or [`NO_MATERIAL`].
    pub triangle_material: Vec<u32>,
}

/// A triangle no `usemtl` applies to.
pub const NO_MATERIAL: u32 = u32::MAX;

/// The most distinct `usemtl` names one OBJ may use: a triangle names its
/// surface in 16 bits, and surface 0 is the default. Checked when a name is
/// first seen; the error is at that name.
pub const MAX_OBJ_MATERIALS: usize = u16::MAX as usize - 1;

/// The most distinct `.mtl` files one OBJ's `mtllib` statements may name
/// (a name repeated costs a lookup, nothing more). Checked when a name is
/// first seen; the error is at that name.
pub const MAX_OBJ_LIBRARIES: usize = 1024;

/// [`parse`], keeping the material statements. Triangles are in file order
/// (as in the mesh), and a position split by the loader keeps its triangles.
/// `libs` and `names` hold each name once, in order of first appearance
/// (looked up by hash: a file of many `usemtl` lines costs linear time), at
/// most [`MAX_OBJ_LIBRARIES`] and [`MAX_OBJ_MATERIALS`] of them.
pub fn parse_with_materials(file: &str, bytes: &[u8]) -> Result<(Mesh, ObjMaterials), SceneError> {
    let mut materials = ObjMaterials::default();
    let mut lib_seen: HashSet<String> = HashSet::new();
    let mut name_index: HashMap<String, u32> = HashMap::new();
    let mut current = NO_MATERIAL;
    let mut p = Parser {
        file: MeshFile { name: file, bytes },
        positions: Vec::new(),
        normals: Vec::new(),
        texcoords: Vec::new(),
        triangles: Vec::new(),
        tri_normals: Vec::new(),
        all_normals: true,
        tri_uvs: Vec::new(),
        all_uvs: true,
    };
    let mut lx = Lexer { b: bytes, pos: 0 };
    while lx.pos < bytes.len() {
        if let Some((at, keyword)) = lx.token() {
            match keyword {
                b"mtllib" => {
                    // Names may not contain blanks (each token is a file).
                    while let Some((at, name)) = lx.token() {
                        let name = String::from_utf8_lossy(name);
                        if lib_seen.contains(&*name) {
                            continue;
                        }
                        if lib_seen.len() == MAX_OBJ_LIBRARIES {
                            return Err(p.err(
                                at,
                                format!("more than {MAX_OBJ_LIBRARIES} material libraries (mtllib) in one mesh"),
                            ));
                        }
                        lib_seen.insert(name.clone().into_owned());
                        materials.libs.push((name.into_owned(), at));
                    }
                }
                b"usemtl" => {
                    let Some((at, name)) = lx.token() else {
                        return Err(p.err(at, "expected a material name after \"usemtl\""));
                    };
                    let name = String::from_utf8_lossy(name);
                    current = match name_index.get(&*name) {
                        Some(&i) => i,
                        None => {
                            if materials.names.len() == MAX_OBJ_MATERIALS {
                                return Err(p.err(
                                    at,
                                    format!("more than {MAX_OBJ_MATERIALS} materials (usemtl names) in one mesh"),
                                ));
                            }
                            let i = materials.names.len() as u32;
                            name_index.insert(name.clone().into_owned(), i);
                            materials.names.push((name.into_owned(), at));
                            i
                        }
                    };
                }
                _ => {
                    let before = p.triangles.len();
                    p.statement(&mut lx, at, keyword)?;
                    if !materials.names.is_empty() {
                        materials.triangle_material.resize(before, NO_MATERIAL);
                        materials
                            .triangle_material
                            .resize(p.triangles.len(), current);
                    }
                }
            }
        }
        lx.finish_statement();
    }
    if !materials.names.is_empty() {
        materials
            .triangle_material
            .resize(p.triangles.len(), NO_MATERIAL);
    }
    Ok((p.finish()?, materials))
}

/// Blanks separating tokens inside a statement.
fn is_blank(c: u8) -> bool {
    matches!(c, b' ' | b'\t' | b'\r' | 0x0b | 0x0c)
}

/// Splits the file into statements and statements into tokens, without
/// allocating. A statement ends at a newline that is not escaped by a
/// trailing backslash, or at a comment.
struct Lexer<'a> {
    b: &'a [u8],
    pos: usize,
}

impl<'a> Lexer<'a> {
    /// If the backslash at `at` ends its line, the number of bytes of the
    /// continuation (backslash plus line ending).
    fn continuation_len(&self, at: usize) -> Option<usize> {
        match (self.b.get(at + 1), self.b.get(at + 2)) {
            (None, _) => Some(1),
            (Some(b'\n'), _) => Some(2),
            (Some(b'\r'), Some(b'\n')) => Some(3),
            (Some(b'\r'), None) => Some(2),
            _ => None,
        }
    }

    /// The next token of the current statement with its byte offset, or
    /// `None` at the end of the statement (the newline is not consumed).
    fn token(&mut self) -> Option<(usize, &'a [u8])> {
        loop {
            let c = *self.b.get(self.pos)?;
            match c {
                b'\n' => return None,
                b'#' => {
                    self.pos = self.b[self.pos..]
                        .iter()
                        .position(|&c| c == b'\n')
                        .map_or(self.b.len(), |i| self.pos + i);
                    return None;
                }
                b'\\' => match self.continuation_len(self.pos) {
                    Some(n) => self.pos += n,
                    None => break,
                },
                c if is_blank(c) => self.pos += 1,
                _ => break,
            }
        }
        let start = self.pos;
        while let Some(&c) = self.b.get(self.pos) {
            if c == b'\n'
                || c == b'#'
                || is_blank(c)
                || (c == b'\\' && self.continuation_len(self.pos).is_some())
            {
                break;
            }
            self.pos += 1;
        }
        Some((start, &self.b[start..self.pos]))
    }

    /// Skips what is left of the current statement and its newline.
    fn finish_statement(&mut self) {
        while self.token().is_some() {}
        if self.pos < self.b.len() {
            self.pos += 1;
        }
    }
}

struct Parser<'a> {
    file: MeshFile<'a>,
    positions: Vec<Vec3>,
    /// Raw `vn` values, as written.
    normals: Vec<Vec3>,
    /// `vt` values (u, v).
    texcoords: Vec<Vec2>,
    triangles: Vec<[u32; 3]>,
    /// `vn` index of each triangle corner, kept while `all_normals` holds.
    tri_normals: Vec<[u32; 3]>,
    all_normals: bool,
    /// `vt` index of each triangle corner, kept while `all_uvs` holds.
    tri_uvs: Vec<[u32; 3]>,
    all_uvs: bool,
}

/// One face corner: position, `vt` and `vn` index (or [`NONE`]).
#[derive(Clone, Copy)]
struct Corner {
    v: u32,
    t: u32,
    n: u32,
}

impl Parser<'_> {
    fn err(&self, at: usize, msg: impl Into<String>) -> SceneError {
        self.file.error_at(at, msg)
    }

    fn statement(
        &mut self,
        lx: &mut Lexer<'_>,
        at: usize,
        keyword: &[u8],
    ) -> Result<(), SceneError> {
        match keyword {
            b"v" => self.vertex(lx, at),
            b"vn" => self.normal(lx, at),
            b"vt" => self.texcoord(lx, at),
            b"f" => self.face(lx, at),
            _ => Ok(()),
        }
    }

    fn number(&self, at: usize, tok: &[u8]) -> Result<f32, SceneError> {
        let x = parse_token::<f32>(tok)
            .ok_or_else(|| self.err(at, format!("malformed number \"{}\"", show(tok))))?;
        if !x.is_finite() {
            return Err(self.err(
                at,
                format!(
                    "non-finite number \"{}\" (out of range or nan/inf)",
                    show(tok)
                ),
            ));
        }
        Ok(x)
    }

    /// Reads the numbers of a `v` or `vn` statement into `out`; returns how
    /// many there were. More than `out.len()` is an error at the first extra.
    fn numbers(
        &self,
        lx: &mut Lexer<'_>,
        keyword: &str,
        expected: &str,
        out: &mut [f32],
    ) -> Result<usize, SceneError> {
        let mut n = 0;
        while let Some((at, tok)) = lx.token() {
            if n == out.len() {
                return Err(self.err(
                    at,
                    format!("too many numbers after \"{keyword}\": expected {expected}"),
                ));
            }
            out[n] = self.number(at, tok)?;
            n += 1;
        }
        Ok(n)
    }

    fn vertex(&mut self, lx: &mut Lexer<'_>, at: usize) -> Result<(), SceneError> {
        const EXPECTED: &str = "x y z [w] (or x y z r g b)";
        let mut xs = [0f32; 6];
        let n = self.numbers(lx, "v", EXPECTED, &mut xs)?;
        if !matches!(n, 3 | 4 | 6) {
            return Err(self.err(
                at,
                format!("expected {EXPECTED} after \"v\", found {n} numbers"),
            ));
        }
        if self.positions.len() >= NONE as usize {
            return Err(self.err(at, "too many vertices"));
        }
        self.positions.push(Vec3::new(xs[0], xs[1], xs[2]));
        Ok(())
    }

    fn normal(&mut self, lx: &mut Lexer<'_>, at: usize) -> Result<(), SceneError> {
        let mut xs = [0f32; 3];
        let n = self.numbers(lx, "vn", "x y z", &mut xs)?;
        if n != 3 {
            return Err(self.err(
                at,
                format!("expected x y z after \"vn\", found {n} numbers"),
            ));
        }
        if self.normals.len() >= NONE as usize {
            return Err(self.err(at, "too many normals"));
        }
        self.normals.push(Vec3::from_array(xs));
        Ok(())
    }

    fn texcoord(&mut self, lx: &mut Lexer<'_>, at: usize) -> Result<(), SceneError> {
        let mut xs = [0f32; 3];
        let n = self.numbers(lx, "vt", "u [v [w]]", &mut xs)?;
        if n == 0 {
            return Err(self.err(at, "expected u [v [w]] after \"vt\", found no numbers"));
        }
        if self.texcoords.len() >= NONE as usize {
            return Err(self.err(at, "too many texture coordinates"));
        }
        self.texcoords.push(Vec2::new(xs[0], xs[1]));
        Ok(())
    }

    /// Resolves a 1-based or negative (relative) index against the `count`
    /// elements defined so far into a 0-based one.
    fn index(&self, at: usize, tok: &[u8], count: usize, what: &str) -> Result<u32, SceneError> {
        let raw = parse_token::<i64>(tok)
            .ok_or_else(|| self.err(at, format!("malformed {what} index \"{}\"", show(tok))))?;
        if raw == 0 {
            return Err(self.err(
                at,
                format!("{what} index 0 is invalid (OBJ indices start at 1)"),
            ));
        }
        let count = count as i64;
        let i = if raw > 0 { raw - 1 } else { count + raw };
        if !(0..count).contains(&i) {
            return Err(self.err(
                at,
                format!("{what} index {raw} out of range ({count} defined so far)"),
            ));
        }
        Ok(i as u32)
    }

    /// Parses one face corner `v[/[vt][/[vn]]]` starting at byte `at`.
    fn corner(&self, at: usize, tok: &[u8]) -> Result<Corner, SceneError> {
        let mut fields: [(usize, &[u8]); 3] = [(at, &[]); 3];
        let mut rest = tok;
        let mut off = at;
        let mut n = 0;
        loop {
            if n == 3 {
                return Err(self.err(
                    off - 1,
                    format!(
                        "malformed face vertex \"{}\": expected v, v/vt, v//vn or v/vt/vn",
                        show(tok)
                    ),
                ));
            }
            let end = rest.iter().position(|&c| c == b'/').unwrap_or(rest.len());
            fields[n] = (off, &rest[..end]);
            n += 1;
            if end == rest.len() {
                break;
            }
            rest = &rest[end + 1..];
            off += end + 1;
        }
        let (v_at, v) = fields[0];
        if v.is_empty() {
            return Err(self.err(
                v_at,
                format!("face vertex \"{}\" has no position index", show(tok)),
            ));
        }
        let v = self.index(v_at, v, self.positions.len(), "vertex")?;
        let (t_at, t) = fields[1];
        let t = if t.is_empty() {
            NONE
        } else {
            self.index(t_at, t, self.texcoords.len(), "texture coordinate")?
        };
        let (n_at, nf) = fields[2];
        let n = if nf.is_empty() {
            NONE
        } else {
            self.index(n_at, nf, self.normals.len(), "normal")?
        };
        Ok(Corner { v, t, n })
    }

    fn face(&mut self, lx: &mut Lexer<'_>, at: usize) -> Result<(), SceneError> {
        let mut first = Corner {
            v: 0,
            t: NONE,
            n: NONE,
        };
        let mut prev = first;
        let mut count = 0usize;
        while let Some((c_at, tok)) = lx.token() {
            let c = self.corner(c_at, tok)?;
            match count {
                0 => first = c,
                1 => {}
                _ => self.push_triangle([first, prev, c]),
            }
            prev = c;
            count += 1;
        }
        if count < 3 {
            return Err(self.err(
                at,
                format!("a face needs at least 3 vertices, found {count}"),
            ));
        }
        Ok(())
    }

    fn push_triangle(&mut self, t: [Corner; 3]) {
        self.triangles.push(t.map(|c| c.v));
        if self.all_normals {
            if t.iter().all(|c| c.n != NONE) {
                self.tri_normals.push(t.map(|c| c.n));
            } else {
                self.all_normals = false;
                self.tri_normals = Vec::new();
            }
        }
        if self.all_uvs {
            if t.iter().all(|c| c.t != NONE) {
                self.tri_uvs.push(t.map(|c| c.t));
            } else {
                self.all_uvs = false;
                self.tri_uvs = Vec::new();
            }
        }
    }

    fn finish(self) -> Result<Mesh, SceneError> {
        if self.triangles.is_empty() {
            return Err(self.err(self.file.bytes.len(), "mesh has no triangles"));
        }
        let file = self.file;
        let mut mesh = Mesh {
            positions: self.positions,
            normals: Vec::new(),
            uvs: Vec::new(),
            triangles: self.triangles,
        };
        let corner_normals = if self.all_normals {
            let unit: Vec<Option<Vec3>> = self.normals.iter().map(|&n| unit_normal(n)).collect();
            // A zero-length normal: no normals for the whole mesh.
            self.tri_normals
                .iter()
                .map(|t| match t.map(|i| unit[i as usize]) {
                    [Some(a), Some(b), Some(c)] => Some([a, b, c]),
                    _ => None,
                })
                .collect::<Option<Vec<[Vec3; 3]>>>()
        } else {
            None
        };
        let corner_uvs = self.all_uvs.then(|| {
            self.tri_uvs
                .iter()
                .map(|t| t.map(|i| self.texcoords[i as usize]))
                .collect::<Vec<[Vec2; 3]>>()
        });
        if let Err(at) = per_vertex_attributes(&mut mesh, corner_normals, corner_uvs) {
            return Err(file.error_at(
                at,
                "too many vertices after splitting by normal and texture coordinate",
            ));
        }
        Ok(mesh)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{apply_edits, assert_error_at, check_mesh_invariants, Edit};
    use proptest::prelude::*;

    fn ok(src: &str) -> Mesh {
        match parse("m.obj", src.as_bytes()) {
            Ok(m) => m,
            Err(e) => panic!("unexpected error: {e}"),
        }
    }

    /// Parses `src`, expecting an error at `line:column` whose message contains `msg`.
    fn fails(src: &str, line: u32, column: u32, msg: &str) {
        assert_error_at(parse("m.obj", src.as_bytes()), "m.obj", line, column, msg);
    }

    const CUBE: &str = "\
# unit cube
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
f 1 4 3 2
f 5 6 7 8
f 1 2 6 5
f 2 3 7 6
f 3 4 8 7
f 4 1 5 8
";

    #[test]
    fn unit_cube_quads_fan_into_twelve_triangles_in_order() {
        let m = ok(CUBE);
        assert_eq!(m.positions.len(), 8);
        assert_eq!(m.positions[6], Vec3::new(1.0, 1.0, 1.0));
        assert!(m.normals.is_empty());
        assert_eq!(
            m.triangles,
            vec![
                [0, 3, 2],
                [0, 2, 1],
                [4, 5, 6],
                [4, 6, 7],
                [0, 1, 5],
                [0, 5, 4],
                [1, 2, 6],
                [1, 6, 5],
                [2, 3, 7],
                [2, 7, 6],
                [3, 0, 4],
                [3, 4, 7],
            ]
        );
    }

    #[test]
    fn pentagon_fans_from_its_first_vertex() {
        let m = ok("v 0 0 0\nv 1 0 0\nv 2 1 0\nv 1 2 0\nv 0 1 0\nf 1 2 3 4 5\n");
        assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 3, 4]]);
    }

    #[test]
    fn negative_indices_are_relative_to_what_is_defined_so_far() {
        let m = ok("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 1 1 0\nf -3 -1 -2\nf 1 -1 3\n");
        assert_eq!(m.triangles, vec![[0, 1, 2], [1, 3, 2], [0, 3, 2]]);
    }

    #[test]
    fn ignored_statements_comments_crlf_and_continuations() {
        let src = "mtllib a.mtl\r\no thing\r\ng group one\r\n\r\n   # comment\r\n\
                   v 0 0 0 1\r\nv 1 0 0 # trailing comment\r\nv 0 1 0\r\n\
                   v 1 1 0 0.5 0.5 0.5\r\nvt 0 0\r\nvt 1 0\r\nvt 0 1\r\nvp 0.5\r\n\
                   s off\r\nusemtl red\r\nl 1 2\r\np 1\r\ncstype bezier\r\nfrobnicate 1 2 3\r\n\
                   f 1/1 2/2 \\\r\n  3/3\r\nf 2 4 \\\n3\n";
        let m = ok(src);
        assert_eq!(m.positions.len(), 4);
        assert_eq!(m.positions[3], Vec3::new(1.0, 1.0, 0.0));
        assert_eq!(m.triangles, vec![[0, 1, 2], [1, 3, 2]]);
        assert!(m.normals.is_empty());
        // A continuation at the very end of the file, and no final newline.
        let m = ok("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 \\");
        assert_eq!(m.triangles, vec![[0, 1, 2]]);
    }

    #[test]
    fn per_face_normals_split_vertices_and_keep_original_order() {
        // Two triangles of a folded square sharing the edge 1-3 (0-based 0-2),
        // each with its own face normal; plus an unused vertex 5.
        let src = "\
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 1
v 9 9 9
vn 0 0 2
vn 0 -1 1
vn 0 0 1
f 1//1 2//1 3//1
f 1//2 3//2 4//2
f 1//3 2//3 3//3
";
        let m = ok(src);
        // The first five positions are the file's, in order; vertices 0 and 2
        // are used with a second normal, so they get copies 5 and 6. The third
        // face's normal equals the first's after normalisation: no new split.
        assert_eq!(m.positions.len(), 7);
        assert_eq!(m.positions[4], Vec3::new(9.0, 9.0, 9.0));
        assert_eq!(m.positions[5], m.positions[0]);
        assert_eq!(m.positions[6], m.positions[2]);
        assert_eq!(m.triangles, vec![[0, 1, 2], [5, 6, 3], [0, 1, 2]]);
        let n2 = Vec3::new(0.0, -1.0, 1.0).normalize();
        assert_eq!(m.normals.len(), 7);
        assert_eq!(m.normals[0], Vec3::Z);
        assert_eq!(m.normals[1], Vec3::Z);
        assert_eq!(m.normals[2], Vec3::Z);
        assert!((m.normals[3] - n2).length() < 1e-6);
        assert_eq!(m.normals[4], Vec3::Y, "unused vertex gets the stand-in");
        assert!((m.normals[5] - n2).length() < 1e-6);
        assert!((m.normals[6] - n2).length() < 1e-6);
    }

    #[test]
    fn full_corner_form_with_normals_and_no_split() {
        let m = ok("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\nvn 0 0 -1\n\
                    f 1/1/1 2/1/1 3/1/1\nf 1/1/1 3/1/1 2/1/1\n");
        assert_eq!(m.positions.len(), 3);
        assert_eq!(m.normals, vec![Vec3::Z; 3]);
        assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 1]]);
    }

    #[test]
    fn missing_or_zero_normals_drop_normals_for_the_whole_mesh() {
        let m = ok("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\nf 1//1 2 3//1\n");
        assert!(m.normals.is_empty());
        assert_eq!(m.positions.len(), 3);
        let m = ok("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nvn 0 0 0\nf 1//1 2//2 3//1\n");
        assert!(m.normals.is_empty());
        // An unused zero normal does no harm.
        let m = ok("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nvn 0 0 0\nf 1//1 2//1 3//1\n");
        assert_eq!(m.normals, vec![Vec3::Z; 3]);
    }

    #[test]
    fn errors_name_the_offending_token() {
        fails("v 0 0 0\nv 1 0 zero\n", 2, 7, "malformed number \"zero\"");
        fails("v 0 0 0\nv 1 0 1e40\n", 2, 7, "non-finite");
        fails("v 0 0 nan\n", 1, 7, "non-finite");
        fails("v 0 0 inf\n", 1, 7, "non-finite");
        fails("v 0 0\n", 1, 1, "found 2 numbers");
        fails("v 0 0 0 1 2\n", 1, 1, "found 5 numbers");
        fails("v 0 0 0 1 2 3 4\n", 1, 15, "too many numbers");
        fails("vn 0 1\n", 1, 1, "expected x y z after \"vn\"");
        fails("vn 0 1 0 0\n", 1, 10, "too many numbers");
        fails(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n",
            4,
            7,
            "index 0 is invalid",
        );
        fails(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n",
            4,
            7,
            "vertex index 4 out of range",
        );
        fails(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n",
            4,
            7,
            "vertex index -4 out of range",
        );
        fails(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n",
            4,
            7,
            "malformed vertex index",
        );
        fails(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n",
            4,
            1,
            "at least 3 vertices, found 2",
        );
        fails("v 0 0 0\nv 1 0 0\nv 0 1 0\nf\n", 4, 1, "found 0");
        fails(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3//1\n",
            4,
            10,
            "normal index 1 out of range",
        );
        fails(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1 2/2 3\n",
            5,
            7,
            "texture coordinate index 2",
        );
        fails(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3/1/1/1\n",
            4,
            12,
            "malformed face vertex",
        );
        fails(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 /1\n",
            4,
            7,
            "no position index",
        );
        // Columns count characters, and lines continue past a backslash.
        fails("# é\nv 0 0 0 \\\n 1 2 3 4\n", 3, 8, "too many numbers");
        fails(
            "g é\r\nv 0 0 0\r\nf 1 1 é\r\n",
            3,
            7,
            "malformed vertex index \"é\"",
        );
        fails("v 0 0 0\nv 1 0 0\nv 0 1 0\n", 4, 1, "mesh has no triangles");
        fails("", 1, 1, "mesh has no triangles");
        fails("vt\n", 1, 1, "expected u [v [w]] after \"vt\"");
        fails("vt 1 2 3 4\n", 1, 10, "too many numbers after \"vt\"");
        fails("vt 1 x\n", 1, 6, "malformed number");
        fails(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/2 3/1\n",
            5,
            9,
            "texture coordinate index 2 out of range (1 defined so far)",
        );
    }

    /// Two triangles sharing an edge whose second uses other `vt`s at the
    /// shared corners (a UV seam): the shared positions are copied with the
    /// second triangle's uvs, every corner sees the uv its face named, and
    /// `v` defaults to 0 when a `vt` gives only `u`.
    #[test]
    fn texture_coordinates_follow_their_corners_and_split_seams() {
        let src = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n\
                   vt 0 0\nvt 1 0\nvt 0 1\nvt 0.5 0.25 7\nvt 0.75\n\
                   f 1/1 2/2 3/3\nf 2/4 4/-1 3/3\n";
        let m = ok(src);
        check_mesh_invariants(&m);
        assert_eq!(m.uvs.len(), m.positions.len());
        let corner = |t: usize, j: usize| {
            let i = m.triangles[t][j] as usize;
            (m.positions[i], m.uvs[i])
        };
        assert_eq!(corner(0, 0), (Vec3::ZERO, Vec2::new(0.0, 0.0)));
        assert_eq!(corner(0, 1), (Vec3::X, Vec2::new(1.0, 0.0)));
        assert_eq!(corner(1, 0), (Vec3::X, Vec2::new(0.5, 0.25)));
        assert_eq!(
            corner(1, 1),
            (Vec3::new(1.0, 1.0, 0.0), Vec2::new(0.75, 0.0))
        );
        assert_eq!(corner(1, 2), (Vec3::Y, Vec2::new(0.0, 1.0)));
        // Vertex 2 (1 0 0) is split; vertex 3 (0 1 0) is shared unchanged.
        assert_eq!(m.positions.len(), 5);
        assert_eq!(m.triangles[1][2], 2);
        // With normals too, both split together.
        let m = ok(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 1\nvn 0 0 1\nvn 0 1 0\n\
                    f 1/1/1 2/1/1 3/1/1\nf 1/2/1 3/1/2 2/1/1\n",
        );
        check_mesh_invariants(&m);
        assert_eq!(m.positions.len(), 5);
        assert_eq!(m.normals.len(), 5);
        // One corner without a vt: no uvs at all (normals kept).
        let m = ok("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\nf 1/1/1 2/1/1 3//1\n");
        assert!(m.uvs.is_empty());
        assert_eq!(m.normals.len(), 3);
    }

    #[test]
    fn a_real_mesh_has_the_documented_counts() {
        // Spot, kept in the repository (core/tests/data, public domain): it
        // has texture coordinates with seams, so its 2,930 positions become
        // 3,225 vertices, one per distinct (position, vt).
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/data/spot/spot_triangulated.obj"
        );
        let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{path}: {e}"));
        let m = parse("spot_triangulated.obj", &bytes).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(m.positions.len(), 3_225);
        assert_eq!(m.triangles.len(), 5_856);
        // No vn: normals only where the loader made them (with uvs).
        assert_eq!(m.normals.is_empty(), m.uvs.is_empty());
        assert_eq!(m.uvs.len(), m.positions.len());
        check_mesh_invariants(&m);
    }

    /// Regression: `mtllib` names are kept once each (a library named 50,000
    /// times on a line was read 50,000 times), at most
    /// [`MAX_OBJ_LIBRARIES`] of them, the error at the one that passes it.
    #[test]
    fn material_libraries_are_kept_once_and_bounded() {
        let src = format!(
            "mtllib{}\nmtllib b.mtl a.mtl\n{CUBE}",
            " a.mtl".repeat(50_000)
        );
        let (_, m) = parse_with_materials("m.obj", src.as_bytes()).unwrap();
        let names: Vec<&str> = m.libs.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["a.mtl", "b.mtl"]);
        let mut src = String::from("mtllib");
        for k in 0..=MAX_OBJ_LIBRARIES {
            src.push_str(&format!(" l{k:04}.mtl"));
        }
        src.push('\n');
        src.push_str(CUBE);
        let col = 1 + "mtllib".len() + MAX_OBJ_LIBRARIES * " l0000.mtl".len() + 1;
        fails(&src, 1, col as u32, "more than 1024 material libraries");
    }

    fn edit() -> impl Strategy<Value = Edit> {
        // Bytes that matter to the grammar, plus anything.
        crate::testing::edit(b"/-\\\n\r #.0123456789ef+vn")
    }

    const WITH_NORMALS: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 1\nvt 0 0\nvn 0 0 1\nvn 0 -1 1\n\
                                f 1/1/1 2/1/1 3/1/1\nf -4//2 -2//2 -1//-1 \\\n 2//1\n";

    proptest! {
        #[test]
        fn mutated_obj_never_panics(
            base in prop::sample::select(vec![CUBE, WITH_NORMALS]),
            edits in prop::collection::vec(edit(), 1..12),
        ) {
            let bytes = apply_edits(base.as_bytes().to_vec(), &edits);
            if let Ok(m) = parse("m.obj", &bytes) {
                check_mesh_invariants(&m);
            }
        }

        #[test]
        fn random_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..300)) {
            if let Ok(m) = parse("m.obj", &bytes) {
                check_mesh_invariants(&m);
            }
        }

        #[test]
        fn random_statements_never_panic(
            lines in prop::collection::vec(
                (prop::sample::select(vec!["v", "vn", "vt", "f", "l", "#", "o"]),
                 prop::collection::vec(
                     prop_oneof![
                         (-6i64..7).prop_map(|i| i.to_string()),
                         (-6i64..7, -3i64..4).prop_map(|(a, b)| format!("{a}//{b}")),
                         (-6i64..7, -3i64..4, -3i64..4).prop_map(|(a, b, c)| format!("{a}/{b}/{c}")),
                         any::<f32>().prop_map(|x| x.to_string()),
                         Just("\\".to_string()),
                     ],
                     0..6)),
                0..30),
        ) {
            let src: String = lines
                .iter()
                .map(|(k, args)| format!("{k} {}\n", args.join(" ")))
                .collect();
            if let Ok(m) = parse("m.obj", src.as_bytes()) {
                check_mesh_invariants(&m);
            }
        }
    }
}
