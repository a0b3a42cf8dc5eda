//! The PLY header: the format, the elements with their counts and
//! properties, and what each property is used for. It is read line by line
//! (one function per kind of line), then checked as a whole: the vertex
//! element has `x y z`, some face or strip element has an index list, and
//! the element counts fit in the body (before anything is allocated).

use std::collections::HashSet;

use crate::error::SceneError;
use crate::mesh::read::{parse_token, show, MeshFile};

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub(super) enum Format {
    Ascii,
    BinaryLe,
    BinaryBe,
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub(super) enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn from_name(name: &[u8]) -> Option<Scalar> {
        Some(match name {
            b"char" | b"int8" => Scalar::I8,
            b"uchar" | b"uint8" => Scalar::U8,
            b"short" | b"int16" => Scalar::I16,
            b"ushort" | b"uint16" => Scalar::U16,
            b"int" | b"int32" => Scalar::I32,
            b"uint" | b"uint32" => Scalar::U32,
            b"float" | b"float32" => Scalar::F32,
            b"double" | b"float64" => Scalar::F64,
            _ => return None,
        })
    }

    /// Bytes in a binary body.
    pub(super) fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }

    /// The range of an integer type.
    pub(super) fn int_range(self) -> (i64, i64) {
        match self {
            Scalar::I8 => (i8::MIN.into(), i8::MAX.into()),
            Scalar::U8 => (0, u8::MAX.into()),
            Scalar::I16 => (i16::MIN.into(), i16::MAX.into()),
            Scalar::U16 => (0, u16::MAX.into()),
            Scalar::I32 => (i32::MIN.into(), i32::MAX.into()),
            Scalar::U32 => (0, u32::MAX.into()),
            Scalar::F32 | Scalar::F64 => (i64::MIN, i64::MAX),
        }
    }

    pub(super) fn name(self) -> &'static str {
        match self {
            Scalar::I8 => "char",
            Scalar::U8 => "uchar",
            Scalar::I16 => "short",
            Scalar::U16 => "ushort",
            Scalar::I32 => "int",
            Scalar::U32 => "uint",
            Scalar::F32 => "float",
            Scalar::F64 => "double",
        }
    }
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub(super) enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

/// What a property is used for.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub(super) enum Role {
    Skip,
    /// Component 0..3 = x y z, 3..6 = nx ny nz, 6..8 = u v (also named
    /// `s t` or `texture_u texture_v`).
    Vertex(usize),
    Indices,
    /// A face's `texcoord` list: `u v` for each corner, in the order of
    /// its `vertex_indices`.
    TexCoord,
}

#[derive(Debug)]
pub(super) struct Property {
    pub name: String,
    pub kind: Kind,
    pub role: Role,
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub(super) enum Use {
    Vertex,
    Face,
    /// `element tristrips`: one or more lists of strip vertices, `-1`
    /// restarting the strip.
    Strips,
    Other,
}

#[derive(Debug)]
pub(super) struct Element {
    pub name: String,
    pub count: u64,
    pub props: Vec<Property>,
    pub used: Use,
}

#[derive(Debug)]
pub(super) struct Header {
    pub format: Format,
    pub elements: Vec<Element>,
    /// Byte offset of the body in the file.
    pub body_start: usize,
    /// 1-based line number of the body's first byte.
    pub body_line: u32,
    pub vertex_count: u32,
    pub has_normals: bool,
    /// The vertex element has `u v` (or `s t`, `texture_u texture_v`) and
    /// the face element has no `texcoord` list.
    pub has_uvs: bool,
    /// The face element has a `texcoord` list (which then wins over any
    /// per-vertex texture coordinates).
    pub has_face_uvs: bool,
}

/// One header line: its whitespace-separated tokens with their byte
/// offsets in the file, and the offset of its end.
struct Line<'a> {
    tokens: Vec<(usize, &'a [u8])>,
    end: usize,
}

impl<'a> Line<'a> {
    fn new(bytes: &'a [u8], start: usize, end: usize) -> Line<'a> {
        let line = &bytes[start..end];
        let mut tokens = Vec::new();
        let mut i = 0;
        while i < line.len() {
            if line[i].is_ascii_whitespace() {
                i += 1;
                continue;
            }
            let first = i;
            while i < line.len() && !line[i].is_ascii_whitespace() {
                i += 1;
            }
            tokens.push((start + first, &line[first..i]));
        }
        Line { tokens, end }
    }
}

/// The header as read so far.
struct Reader<'a> {
    file: MeshFile<'a>,
    format: Option<Format>,
    elements: Vec<Element>,
    /// Offset of each element's count token, for errors about counts.
    count_at: Vec<usize>,
    /// The property names of the current (last) element, so that a
    /// duplicate is found in constant time: a header may have hundreds of
    /// thousands of property lines, and scanning the earlier ones for each
    /// would make the header quadratic.
    prop_names: HashSet<&'a [u8]>,
}

impl Header {
    /// Reads and checks the header of PLY file `file`.
    pub(super) fn parse(file: MeshFile<'_>) -> Result<Header, SceneError> {
        let bytes = file.bytes;
        let mut r = Reader {
            file,
            format: None,
            elements: Vec::new(),
            count_at: Vec::new(),
            prop_names: HashSet::new(),
        };
        let mut pos = 0usize;
        let mut line_no = 0u32;
        let (body_start, end_header_at) = loop {
            if pos >= bytes.len() {
                return Err(file.error_at(
                    bytes.len(),
                    if line_no == 0 {
                        "not a PLY file (empty)"
                    } else {
                        "unexpected end of file in the PLY header (no end_header)"
                    },
                ));
            }
            let end = bytes[pos..]
                .iter()
                .position(|&c| c == b'\n')
                .map_or(bytes.len(), |i| pos + i);
            let line = Line::new(bytes, pos, end);
            pos = (end + 1).min(bytes.len());
            line_no = line_no.saturating_add(1);
            if line_no == 1 {
                r.magic_line(&line)?;
                continue;
            }
            let Some(&(kw_at, keyword)) = line.tokens.first() else {
                continue;
            };
            match keyword {
                b"comment" | b"obj_info" => {}
                b"format" => r.format_line(&line)?,
                b"element" => r.element_line(&line)?,
                b"property" => r.property_line(&line)?,
                b"end_header" => {
                    r.expect_len(&line, 1, "end_header")?;
                    break (pos, kw_at);
                }
                _ => {
                    return Err(file.error_at(
                        kw_at,
                        format!("unknown PLY header line \"{}\"", show(keyword)),
                    ))
                }
            }
        };
        r.finish(body_start, line_no.saturating_add(1), end_header_at)
    }
}

impl<'a> Reader<'a> {
    fn err(&self, at: usize, msg: impl Into<String>) -> SceneError {
        self.file.error_at(at, msg)
    }

    /// Checks that `line` has exactly `n` tokens; the error points at the
    /// first extra one (or the end of a short line) and shows `usage`.
    fn expect_len(&self, line: &Line, n: usize, usage: &str) -> Result<(), SceneError> {
        if line.tokens.len() == n {
            Ok(())
        } else {
            let at = line.tokens.get(n).map_or(line.end, |t| t.0);
            Err(self.err(at, format!("expected \"{usage}\"")))
        }
    }

    /// `ply`, alone on the first line.
    fn magic_line(&self, line: &Line) -> Result<(), SceneError> {
        if line.tokens.len() != 1 || line.tokens[0].1 != b"ply" {
            return Err(self.err(0, "not a PLY file (expected \"ply\" on the first line)"));
        }
        Ok(())
    }

    /// `format ascii|binary_little_endian|binary_big_endian 1.0`, once.
    fn format_line(&mut self, line: &Line) -> Result<(), SceneError> {
        self.expect_len(
            line,
            3,
            "format ascii|binary_little_endian|binary_big_endian 1.0",
        )?;
        if self.format.is_some() {
            return Err(self.err(line.tokens[0].0, "duplicate format line"));
        }
        let (f_at, f) = line.tokens[1];
        self.format = Some(match f {
            b"ascii" => Format::Ascii,
            b"binary_little_endian" => Format::BinaryLe,
            b"binary_big_endian" => Format::BinaryBe,
            _ => {
                return Err(self.err(
                    f_at,
                    format!(
                        "unknown PLY format \"{}\" (expected ascii, \
                         binary_little_endian or binary_big_endian)",
                        show(f)
                    ),
                ))
            }
        });
        let (v_at, v) = line.tokens[2];
        if v != b"1.0" && v != b"1" {
            return Err(self.err(
                v_at,
                format!("unsupported PLY version \"{}\" (expected 1.0)", show(v)),
            ));
        }
        Ok(())
    }

    /// `element <name> <count>`: starts a new element. Of `vertex`, `face`
    /// and `tristrips` (the ones used) there may be one each.
    fn element_line(&mut self, line: &Line) -> Result<(), SceneError> {
        if self.format.is_none() {
            return Err(self.err(line.tokens[0].0, "\"element\" before the format line"));
        }
        self.expect_len(line, 3, "element <name> <count>")?;
        let (n_at, name) = line.tokens[1];
        let (c_at, count) = line.tokens[2];
        let count = Some(count)
            .filter(|c| c.iter().all(u8::is_ascii_digit))
            .and_then(parse_token::<u64>)
            .ok_or_else(|| self.err(c_at, format!("invalid element count \"{}\"", show(count))))?;
        let used = match name {
            b"vertex" => Use::Vertex,
            b"face" => Use::Face,
            b"tristrips" => Use::Strips,
            _ => Use::Other,
        };
        if used != Use::Other && self.elements.iter().any(|e| e.used == used) {
            return Err(self.err(n_at, format!("duplicate element \"{}\"", show(name))));
        }
        self.elements.push(Element {
            name: show(name),
            count,
            props: Vec::new(),
            used,
        });
        self.count_at.push(c_at);
        self.prop_names.clear();
        Ok(())
    }

    /// `property <type> <name>` or `property list <count type> <item type>
    /// <name>` of the current element.
    fn property_line(&mut self, line: &Line<'a>) -> Result<(), SceneError> {
        let tokens = &line.tokens;
        let Some(el) = self.elements.last() else {
            return Err(self.err(tokens[0].0, "\"property\" before any \"element\""));
        };
        let scalar = |(at, name): (usize, &[u8])| {
            Scalar::from_name(name)
                .ok_or_else(|| self.err(at, format!("unknown property type \"{}\"", show(name))))
        };
        let (kind, (name_at, name)) = match tokens.get(1) {
            Some(&(_, b"list")) => {
                self.expect_len(line, 5, "property list <count type> <item type> <name>")?;
                let count = scalar(tokens[2])?;
                if !count.is_integer() {
                    return Err(self.err(
                        tokens[2].0,
                        format!("list count type must be an integer, not {}", count.name()),
                    ));
                }
                let item = scalar(tokens[3])?;
                (Kind::List { count, item }, tokens[4])
            }
            _ => {
                self.expect_len(line, 3, "property <type> <name>")?;
                (Kind::Scalar(scalar(tokens[1])?), tokens[2])
            }
        };
        if self.prop_names.contains(name) {
            return Err(self.err(
                name_at,
                format!(
                    "duplicate property \"{}\" in element \"{}\"",
                    show(name),
                    el.name
                ),
            ));
        }
        let role = self.role(el, line, kind, (name_at, name))?;
        self.prop_names.insert(name);
        let el = self.elements.last_mut().expect("checked above");
        el.props.push(Property {
            name: show(name),
            kind,
            role,
        });
        Ok(())
    }

    /// What property `name` (of kind `kind`, in element `el`, declared by
    /// `line`) is used for: a vertex coordinate or normal component
    /// (scalars), the vertex index list of a face or strip element (integer
    /// lists, one per element), or nothing.
    fn role(
        &self,
        el: &Element,
        line: &Line,
        kind: Kind,
        (name_at, name): (usize, &[u8]),
    ) -> Result<Role, SceneError> {
        let tokens = &line.tokens;
        Ok(match (el.used, name, kind) {
            (
                Use::Vertex,
                b"x" | b"y" | b"z" | b"nx" | b"ny" | b"nz" | b"u" | b"v" | b"s" | b"t"
                | b"texture_u" | b"texture_v",
                Kind::List { .. },
            ) => {
                return Err(self.err(
                    name_at,
                    format!(
                        "vertex property \"{}\" must be a scalar, not a list",
                        show(name)
                    ),
                ))
            }
            (Use::Vertex, b"x", _) => Role::Vertex(0),
            (Use::Vertex, b"y", _) => Role::Vertex(1),
            (Use::Vertex, b"z", _) => Role::Vertex(2),
            (Use::Vertex, b"nx", _) => Role::Vertex(3),
            (Use::Vertex, b"ny", _) => Role::Vertex(4),
            (Use::Vertex, b"nz", _) => Role::Vertex(5),
            (Use::Vertex, b"u" | b"s" | b"texture_u", _) => Role::Vertex(6),
            (Use::Vertex, b"v" | b"t" | b"texture_v", _) => Role::Vertex(7),
            (Use::Face | Use::Strips, b"vertex_indices" | b"vertex_index", Kind::Scalar(_)) => {
                return Err(self.err(
                    name_at,
                    format!("{} property \"{}\" must be a list", el.name, show(name)),
                ))
            }
            (
                Use::Face | Use::Strips,
                b"vertex_indices" | b"vertex_index",
                Kind::List { item, .. },
            ) => {
                if !item.is_integer() {
                    return Err(self.err(
                        tokens[3].0,
                        format!("vertex indices must be integers, not {}", item.name()),
                    ));
                }
                if el.props.iter().any(|p| p.role == Role::Indices) {
                    return Err(self.err(
                        name_at,
                        format!(
                            "{} element has both vertex_indices and vertex_index",
                            el.name
                        ),
                    ));
                }
                Role::Indices
            }
            (Use::Face, b"texcoord", Kind::Scalar(_)) => {
                return Err(self.err(
                    name_at,
                    "face property \"texcoord\" must be a list (u v for each corner)",
                ))
            }
            (Use::Face, b"texcoord", Kind::List { .. }) => Role::TexCoord,
            _ => Role::Skip,
        })
    }

    /// The checks of the whole header, once `end_header` (at
    /// `end_header_at`) is read; the body starts at `body_start`, on line
    /// `body_line`.
    fn finish(
        mut self,
        body_start: usize,
        body_line: u32,
        end_header_at: usize,
    ) -> Result<Header, SceneError> {
        let Some(format) = self.format else {
            return Err(self.err(end_header_at, "PLY header has no format line"));
        };
        let has_face_uvs = self
            .elements
            .iter()
            .any(|e| e.props.iter().any(|p| p.role == Role::TexCoord));
        let (vi, has_normals, has_uvs) = self.vertex_element(end_header_at, has_face_uvs)?;
        self.check_polygon_elements(end_header_at)?;
        self.check_counts(format, body_start)?;
        let vertex_count = u32::try_from(self.elements[vi].count)
            .ok()
            .filter(|&n| n < u32::MAX)
            .ok_or_else(|| self.err(self.count_at[vi], "too many vertices"))?;
        Ok(Header {
            format,
            elements: self.elements,
            body_start,
            body_line,
            vertex_count,
            has_normals,
            has_uvs,
            has_face_uvs,
        })
    }

    /// The vertex element: its index, and whether it has normals and
    /// texture coordinates. `x y z` are required; normals are used only if
    /// all of `nx ny nz` are there, texture coordinates only if both `u v`
    /// (or `s t`, `texture_u texture_v`) are (otherwise those present are
    /// skipped like any other property), and not when the faces have a
    /// `texcoord` list (`face_uvs`), which wins.
    fn vertex_element(
        &mut self,
        end_header_at: usize,
        face_uvs: bool,
    ) -> Result<(usize, bool, bool), SceneError> {
        let Some(vi) = self.elements.iter().position(|e| e.used == Use::Vertex) else {
            return Err(self.err(end_header_at, "PLY header declares no vertex element"));
        };
        let mut has = [false; 8];
        for p in &self.elements[vi].props {
            if let Role::Vertex(k) = p.role {
                has[k] = true;
            }
        }
        if let Some(k) = (0..3).find(|&k| !has[k]) {
            return Err(self.err(
                self.count_at[vi],
                format!("vertex element has no \"{}\" property", ["x", "y", "z"][k]),
            ));
        }
        let has_normals = has[3..6].iter().all(|&h| h);
        let has_uvs = has[6..].iter().all(|&h| h) && !face_uvs;
        for p in &mut self.elements[vi].props {
            if (!has_normals && matches!(p.role, Role::Vertex(3..6)))
                || (!has_uvs && matches!(p.role, Role::Vertex(6..)))
            {
                p.role = Role::Skip;
            }
        }
        Ok((vi, has_normals, has_uvs))
    }

    /// Faces or triangle strips (or both), each with a vertex index list,
    /// and at least one of them. (Every face yields at least one triangle,
    /// since smaller polygons are errors; a strip may yield none, which the
    /// body checks.)
    fn check_polygon_elements(&self, end_header_at: usize) -> Result<(), SceneError> {
        let elements = &self.elements;
        let polygons: Vec<usize> = (0..elements.len())
            .filter(|&i| matches!(elements[i].used, Use::Face | Use::Strips))
            .collect();
        if polygons.is_empty() {
            return Err(self.err(
                end_header_at,
                "mesh has no triangles (no face or tristrips element)",
            ));
        }
        for &i in &polygons {
            if !elements[i].props.iter().any(|p| p.role == Role::Indices) {
                return Err(self.err(
                    self.count_at[i],
                    format!("{} element has no vertex_indices list", elements[i].name),
                ));
            }
        }
        if polygons.iter().all(|&i| elements[i].count == 0) {
            return Err(self.err(self.count_at[polygons[0]], "mesh has no triangles"));
        }
        Ok(())
    }

    /// The element counts against the size of the body, before anything is
    /// allocated: every element has a minimum encoded size (the sum of its
    /// scalars' sizes in binary, two bytes per scalar in ASCII).
    fn check_counts(&self, format: Format, body_start: usize) -> Result<(), SceneError> {
        let body_len = (self.file.bytes.len() - body_start) as u128;
        // In ASCII, the last scalar may lack a separator.
        let available = if format == Format::Ascii {
            body_len + 1
        } else {
            body_len
        };
        let mut needed: u128 = 0;
        for (el, &at) in self.elements.iter().zip(&self.count_at) {
            let per_element: u128 = el
                .props
                .iter()
                .map(|p| match (format, p.kind) {
                    (Format::Ascii, _) => 2,
                    (_, Kind::Scalar(s)) | (_, Kind::List { count: s, .. }) => s.size() as u128,
                })
                .sum();
            needed += per_element * el.count as u128;
            if needed > available {
                return Err(self.err(
                    at,
                    format!(
                        "element \"{}\" count {} is impossible: the elements up to it need at \
                         least {needed} bytes but the body has {body_len}",
                        el.name, el.count
                    ),
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::super::parse;
    use super::super::test_files::*;

    #[test]
    fn header_errors_are_located() {
        fails(b"plx\nformat ascii 1.0\n", 1, 1, "not a PLY file");
        fails(b"", 1, 1, "not a PLY file");
        fails(
            b"ply\nformat ascii 2.0\nend_header\n",
            2,
            14,
            "unsupported PLY version",
        );
        fails(
            b"ply\nformat text 1.0\nend_header\n",
            2,
            8,
            "unknown PLY format \"text\"",
        );
        fails(
            b"ply\nformat ascii 1.0 x\nend_header\n",
            2,
            18,
            "expected \"format",
        );
        fails(&head("property float x\n"), 3, 1, "before any \"element\"");
        fails(
            &head("element vertex 3\nproperty flt x\n"),
            4,
            10,
            "unknown property type \"flt\"",
        );
        fails(
            &head("element vertex -3\n"),
            3,
            16,
            "invalid element count \"-3\"",
        );
        fails(&head("element vertex 3\n"), 4, 1, "no end_header");
        fails(
            &head("elephant 3\n"),
            3,
            1,
            "unknown PLY header line \"elephant\"",
        );
        fails(
            &head("element vertex 3\nproperty float x\nproperty double x\n"),
            5,
            17,
            "duplicate property",
        );
        fails(
            &head("element vertex 3\nproperty list uchar float x\n"),
            4,
            27,
            "must be a scalar",
        );
        fails(
            &head("element face 1\nproperty list float int vertex_indices\n"),
            4,
            15,
            "count type must be an integer",
        );
        fails(
            &head("element face 1\nproperty list uchar float vertex_indices\n"),
            4,
            21,
            "vertex indices must be integers",
        );
        fails(
            &head("element face 1\nproperty int vertex_indices\n"),
            4,
            14,
            "must be a list",
        );
        fails(
            &head("element vertex 3\nproperty float x\nproperty float y\nend_header\n"),
            3,
            16,
            "no \"z\" property",
        );
        fails(b"ply\nelement vertex 3\n", 2, 1, "before the format line");
        fails(&head("end_header\n"), 3, 1, "no vertex element");
        fails(&head("element vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n"), 7, 1, "mesh has no triangles");
        fails(
            &head(
                "element vertex 0\nproperty float x\nproperty float y\nproperty float z\n\
                     element face 0\nproperty list uchar int vertex_indices\nend_header\n",
            ),
            7,
            14,
            "mesh has no triangles",
        );
        fails(
            &head(
                "element vertex 0\nproperty float x\nproperty float y\nproperty float z\n\
                     element face 2\nproperty uchar n\nend_header\n",
            ),
            7,
            14,
            "no vertex_indices list",
        );
    }

    #[test]
    fn huge_counts_are_rejected_before_allocating() {
        let start = std::time::Instant::now();
        for format in FORMATS {
            let header = TRI_HEADER.replace("vertex 3", "vertex 1000000000000");
            let mut bytes = ply(format, &header, &[]);
            bytes.extend_from_slice(&[b'0'; 64]);
            fails(&bytes, 3, 16, "count 1000000000000 is impossible");
            let header = TRI_HEADER.replace("face 1", "face 18446744073709551615");
            let mut bytes = ply(format, &header, &[]);
            bytes.extend_from_slice(&b"0 ".repeat(64));
            fails(&bytes, 7, 14, "count 18446744073709551615 is impossible");
            let header = TRI_HEADER.replace("vertex 3", "vertex 18446744073709551616");
            fails(&ply(format, &header, &[]), 3, 16, "invalid element count");
            // An element without properties occupies nothing, whatever its count.
            let header = format!("element nothing 18446744073709551615\n{TRI_HEADER}");
            let rows = vec![
                vec![V::F32(0.0), V::F32(0.0), V::F32(0.0)],
                vec![V::F32(1.0), V::F32(0.0), V::F32(0.0)],
                vec![V::F32(0.0), V::F32(1.0), V::F32(0.0)],
                vec![V::U8(3), V::I32(0), V::I32(1), V::I32(2)],
            ];
            assert_eq!(ok(&ply(format, &header, &rows)).triangles, vec![[0, 1, 2]]);
            // A face list claiming billions of indices is cut short by the file's end.
            let mut rows = rows;
            rows[3] = vec![V::U8(3), V::I32(0), V::I32(1)];
            let header = TRI_HEADER.replace("uchar int", "uint int");
            rows[3][0] = V::U32(u32::MAX);
            assert!(parse("m.ply", &ply(format, &header, &rows)).is_err());
        }
        assert!(start.elapsed() < std::time::Duration::from_secs(1));
    }

    /// Checking each property name against every earlier one would make
    /// the header quadratic (19 s for 200,000 property lines): duplicates
    /// are found through a set.
    #[test]
    fn a_header_with_200k_properties_parses_in_linear_time() {
        let mut header = String::from(TRI_HEADER);
        header.push_str("element extra 0\n");
        for i in 0..200_000 {
            header.push_str(&format!("property uchar p{i}\n"));
        }
        let rows = vec![
            vec![V::F32(0.0), V::F32(0.0), V::F32(0.0)],
            vec![V::F32(1.0), V::F32(0.0), V::F32(0.0)],
            vec![V::F32(0.0), V::F32(1.0), V::F32(0.0)],
            vec![V::U8(3), V::I32(0), V::I32(1), V::I32(2)],
        ];
        let bytes = ply("ascii", &header, &rows);
        let start = std::time::Instant::now();
        assert_eq!(ok(&bytes).triangles, vec![[0, 1, 2]]);
        let took = start.elapsed();
        assert!(took < std::time::Duration::from_secs(2), "{took:?}");
        // A duplicate among them is still found, at its line.
        let dup = header.replace("property uchar p150000\n", "property uchar p7\n");
        fails(
            &ply("ascii", &dup, &rows),
            150_010,
            16,
            "duplicate property \"p7\" in element \"extra\"",
        );
    }
}
