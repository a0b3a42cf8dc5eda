//! How big a mesh file's mesh is, without building it: what the
//! coordinator needs to admit a job (its memory estimate, and the triangle
//! count `<surface triangles=>` is checked against) at the cost of one
//! streaming scan of the file, with no allocation per line or per element.
//!
//! OBJ: `v`, `vt`, `vn` statements are counted, and the corners of each
//! `f` (a polygon of n corners is n − 2 triangles, as the loader's fan
//! makes); `mtllib` and `usemtl` are kept as the loader keeps them (each
//! distinct material name once). PLY: the header's vertex count and a walk
//! over the body that reads each list's length and skips its items
//! (`ply/counts.rs`).
//!
//! The counts are what the loader makes, or more (documented per field):
//! the loader copies a vertex used with different normals or texture
//! coordinates, which only the full parse can tell, so the vertex count is
//! then bounded by one vertex per face corner on top of the file's.
//! Nothing here checks what the full parse checks inside the data (index
//! ranges, number syntax, finite values): the worker's full parse does, and
//! fails the job with a located error.

use crate::error::SceneError;
use std::collections::HashSet;

/// What a mesh file holds, counted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MeshCounts {
    /// Vertices the loaded mesh has at most: exactly the file's when no
    /// vertex can be split, else the file's plus one per face corner.
    pub vertices: u64,
    /// Vertices the file defines (a lower bound of the loaded mesh's).
    pub file_vertices: u64,
    /// Triangles the loaded mesh has (a PLY's triangle strips count at
    /// most one a strip vertex).
    pub triangles: u64,
    /// Whether the loaded mesh may have texture coordinates.
    pub uvs: bool,
}

impl MeshCounts {
    /// The counts of a mesh already loaded.
    pub fn of(mesh: &super::Mesh) -> MeshCounts {
        MeshCounts {
            vertices: mesh.positions.len() as u64,
            file_vertices: mesh.positions.len() as u64,
            triangles: mesh.triangles.len() as u64,
            uvs: !mesh.uvs.is_empty(),
        }
    }
}

/// An OBJ's counts and its material statements (as
/// [`super::obj::ObjMaterials`] has them, without the per-triangle table).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ObjCounts {
    /// The mesh's vertex and triangle counts.
    pub counts: MeshCounts,
    /// `mtllib` file names with the byte offset of each.
    pub libs: Vec<(String, usize)>,
    /// Distinct `usemtl` names in order of first use, with the offset of
    /// the first.
    pub names: Vec<(String, usize)>,
}

/// Counts an OBJ file's vertices and triangles (see the module's
/// documentation). `file` names it in errors.
pub fn obj(file: &str, bytes: &[u8]) -> Result<ObjCounts, SceneError> {
    let mut out = ObjCounts::default();
    let (mut v, mut corners, mut tris) = (0u64, 0u64, 0u64);
    let (mut all_uvs, mut all_normals) = (true, true);
    let mut seen: HashSet<&[u8]> = HashSet::new();
    let mut lx = Lexer { b: bytes, pos: 0 };
    while lx.pos < bytes.len() {
        if let Some((_, keyword)) = lx.token() {
            match keyword {
                b"v" => v += 1,
                b"f" => {
                    let mut n = 0u64;
                    while let Some((_, tok)) = lx.token() {
                        let mut fields = tok.split(|&c| c == b'/');
                        fields.next();
                        let vt = fields.next().is_some_and(|f| !f.is_empty());
                        let vn = fields.next().is_some_and(|f| !f.is_empty());
                        all_uvs &= vt;
                        all_normals &= vn;
                        n += 1;
                    }
                    if n >= 3 {
                        tris += n - 2;
                        corners += 3 * (n - 2);
                    }
                }
                b"mtllib" => {
                    while let Some((at, name)) = lx.token() {
                        out.libs
                            .push((String::from_utf8_lossy(name).into_owned(), at));
                    }
                }
                b"usemtl" => {
                    let Some((at, name)) = lx.token() else {
                        return Err(super::read::MeshFile { name: file, bytes }
                            .error_at(lx.pos, "expected a material name after \"usemtl\""));
                    };
                    if seen.insert(name) {
                        out.names
                            .push((String::from_utf8_lossy(name).into_owned(), at));
                    }
                }
                _ => {}
            }
        }
        lx.finish_statement();
    }
    let split = tris > 0 && (all_uvs || all_normals);
    out.counts = MeshCounts {
        vertices: if split { v.saturating_add(corners) } else { v },
        file_vertices: v,
        triangles: tris,
        uvs: tris > 0 && all_uvs,
    };
    Ok(out)
}

/// Blanks separating tokens inside a statement (as the OBJ loader has them).
fn is_blank(c: u8) -> bool {
    matches!(c, b' ' | b'\t' | b'\r' | 0x0b | 0x0c)
}

/// The OBJ loader's tokenizer (`obj.rs`): statements end at a newline not
/// escaped by a trailing backslash, or at a comment.
struct Lexer<'a> {
    b: &'a [u8],
    pos: usize,
}

impl<'a> Lexer<'a> {
    fn continuation_len(&self, at: usize) -> Option<usize> {
        match (self.b.get(at + 1), self.b.get(at + 2)) {
            (None, _) => Some(1),
            (Some(b'\n'), _) => Some(2),
            (Some(b'\r'), Some(b'\n')) => Some(3),
            (Some(b'\r'), None) => Some(2),
            _ => None,
        }
    }

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

    fn finish_statement(&mut self) {
        while self.token().is_some() {}
        if self.pos < self.b.len() {
            self.pos += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The counts agree with the loader's mesh (equal, or more where the
    /// documentation says).
    #[track_caller]
    fn agrees(src: &str) -> ObjCounts {
        let c = obj("m.obj", src.as_bytes()).unwrap();
        let (mesh, m) = crate::mesh::obj::parse_with_materials("m.obj", src.as_bytes()).unwrap();
        let full = MeshCounts::of(&mesh);
        assert_eq!(c.counts.triangles, full.triangles, "{src}");
        assert_eq!(c.counts.uvs, full.uvs, "{src}");
        assert!(c.counts.vertices >= full.vertices, "{src}");
        assert!(c.counts.file_vertices <= full.vertices, "{src}");
        assert_eq!(c.libs, m.libs);
        assert_eq!(c.names, m.names);
        c
    }

    #[test]
    fn obj_counts_match_the_loader() {
        let quad = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n";
        let c = agrees(quad);
        assert_eq!(c.counts.vertices, 4, "no split possible: exact");
        // Continuations, comments, CRLF; a pentagon is three triangles.
        let c = agrees(
            "v 0 0 0\r\nv 1 0 0\nv 1 1 0 # x\nv 0 1 0\nv 0 2 0\nf 1 2 \\\n 3 4 5 # f 1 2 3\n",
        );
        assert_eq!(c.counts.triangles, 3);
        // Texture coordinates on every corner: may split.
        let c = agrees(
            "mtllib a.mtl b.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n\
             usemtl x\nf 1/1 2/2 3/3\nusemtl y\nf 1/2 3/3 2/1\nusemtl x\nf 1 2/3 3/1\n",
        );
        assert!(c.counts.vertices <= 3 + 9);
        assert!(!c.counts.uvs, "a corner without vt: none");
        let c = agrees("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/1\n");
        assert!(c.counts.uvs);
    }

    #[test]
    fn a_huge_obj_is_counted_without_holding_it() {
        // 200,000 triangles: counting allocates nothing per line.
        let mut s = String::from("v 0 0 0\nv 1 0 0\nv 0 1 0\n");
        for _ in 0..200_000 {
            s.push_str("f 1 2 3\n");
        }
        let c = obj("m.obj", s.as_bytes()).unwrap();
        assert_eq!((c.counts.vertices, c.counts.triangles), (3, 200_000));
    }
}
