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
//! a vertex dropped (see [`read_strips`]); with both elements, triangles are
//! numbered in the order of the elements in the file.
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
//! Normals: used when the vertex element has all of `nx ny nz`; they are
//! normalised, and a zero-length one drops the normals of the whole mesh (the
//! caller then computes smooth ones). Non-finite coordinates or normals are
//! errors. Trailing data after the last element is an error in ASCII; in
//! binary only trailing ASCII whitespace is tolerated.

use std::collections::HashSet;

use glam::Vec3;

use super::obj::{show, unit_normal};
use super::Mesh;
use crate::error::{Location, SceneError};

/// Parses a PLY file's bytes. `file` is the bundle-relative name used in errors.
pub fn parse(file: &str, bytes: &[u8]) -> Result<Mesh, SceneError> {
    let header = Header::parse(file, bytes)?;
    let body = &bytes[header.body_start..];
    match header.format {
        Format::Ascii => read_body(
            &mut AsciiBody {
                file,
                bytes,
                pos: header.body_start,
                last: header.body_start,
            },
            &header,
        ),
        Format::BinaryLe | Format::BinaryBe => read_body(
            &mut BinaryBody {
                file,
                body,
                pos: 0,
                last: 0,
                big_endian: header.format == Format::BinaryBe,
                line: header.body_line,
            },
            &header,
        ),
    }
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Format {
    Ascii,
    BinaryLe,
    BinaryBe,
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Scalar {
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

    fn size(self) -> usize {
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
    fn int_range(self) -> (i64, i64) {
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

    fn name(self) -> &'static str {
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
enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

/// What a property is used for.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Role {
    Skip,
    /// Component 0..3 = x y z, 3..6 = nx ny nz.
    Vertex(usize),
    Indices,
}

#[derive(Debug)]
struct Property {
    name: String,
    kind: Kind,
    role: Role,
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Use {
    Vertex,
    Face,
    /// `element tristrips`: one or more lists of strip vertices, `-1`
    /// restarting the strip.
    Strips,
    Other,
}

#[derive(Debug)]
struct Element {
    name: String,
    count: u64,
    props: Vec<Property>,
    used: Use,
}

#[derive(Debug)]
struct Header {
    format: Format,
    elements: Vec<Element>,
    /// Byte offset of the body in the file.
    body_start: usize,
    /// 1-based line number of the body's first byte.
    body_line: u32,
    vertex_count: u32,
    has_normals: bool,
}

impl Header {
    fn parse(file: &str, bytes: &[u8]) -> Result<Header, SceneError> {
        let err =
            |at: usize, msg: String| SceneError::new(Location::at_offset(file, bytes, at), msg);
        let mut format = None;
        let mut elements: Vec<Element> = Vec::new();
        // Offset of each element's count token, for errors about counts.
        let mut count_at: Vec<usize> = Vec::new();
        // The property names of the current (last) element, so that a
        // duplicate is found in constant time: a header may have hundreds of
        // thousands of property lines, and scanning the earlier ones for
        // each made the header quadratic (200k lines took 19 s).
        let mut prop_names: HashSet<&[u8]> = HashSet::new();
        let mut pos = 0usize;
        let mut line_no = 0u32;
        let (body_start, end_header_at) = loop {
            if pos >= bytes.len() {
                return Err(err(
                    bytes.len(),
                    if line_no == 0 {
                        "not a PLY file (empty)".into()
                    } else {
                        "unexpected end of file in the PLY header (no end_header)".into()
                    },
                ));
            }
            let end = bytes[pos..]
                .iter()
                .position(|&c| c == b'\n')
                .map_or(bytes.len(), |i| pos + i);
            let line_start = pos;
            pos = (end + 1).min(bytes.len());
            line_no = line_no.saturating_add(1);
            let tokens = tokenize(&bytes[line_start..end], line_start);
            let Some(&(kw_at, keyword)) = tokens.first() else {
                if line_no == 1 {
                    return Err(err(
                        0,
                        "not a PLY file (expected \"ply\" on the first line)".into(),
                    ));
                }
                continue;
            };
            if line_no == 1 {
                if tokens.len() != 1 || keyword != b"ply" {
                    return Err(err(
                        0,
                        "not a PLY file (expected \"ply\" on the first line)".into(),
                    ));
                }
                continue;
            }
            let expect_len = |n: usize, usage: &str| {
                if tokens.len() == n {
                    Ok(())
                } else {
                    let at = tokens.get(n).map_or(end, |t| t.0);
                    Err(err(at, format!("expected \"{usage}\"")))
                }
            };
            match keyword {
                b"comment" | b"obj_info" => {}
                b"format" => {
                    expect_len(3, "format ascii|binary_little_endian|binary_big_endian 1.0")?;
                    if format.is_some() {
                        return Err(err(kw_at, "duplicate format line".into()));
                    }
                    let (f_at, f) = tokens[1];
                    format = Some(match f {
                        b"ascii" => Format::Ascii,
                        b"binary_little_endian" => Format::BinaryLe,
                        b"binary_big_endian" => Format::BinaryBe,
                        _ => {
                            return Err(err(
                                f_at,
                                format!(
                                    "unknown PLY format \"{}\" (expected ascii, \
                                     binary_little_endian or binary_big_endian)",
                                    show(f)
                                ),
                            ))
                        }
                    });
                    let (v_at, v) = tokens[2];
                    if v != b"1.0" && v != b"1" {
                        return Err(err(
                            v_at,
                            format!("unsupported PLY version \"{}\" (expected 1.0)", show(v)),
                        ));
                    }
                }
                b"element" => {
                    if format.is_none() {
                        return Err(err(kw_at, "\"element\" before the format line".into()));
                    }
                    expect_len(3, "element <name> <count>")?;
                    let (n_at, name) = tokens[1];
                    let (c_at, count) = tokens[2];
                    let count = std::str::from_utf8(count)
                        .ok()
                        .filter(|s| s.bytes().all(|c| c.is_ascii_digit()))
                        .and_then(|s| s.parse::<u64>().ok())
                        .ok_or_else(|| {
                            err(c_at, format!("invalid element count \"{}\"", show(count)))
                        })?;
                    let used = match name {
                        b"vertex" => Use::Vertex,
                        b"face" => Use::Face,
                        b"tristrips" => Use::Strips,
                        _ => Use::Other,
                    };
                    if used != Use::Other && elements.iter().any(|e| e.used == used) {
                        return Err(err(n_at, format!("duplicate element \"{}\"", show(name))));
                    }
                    elements.push(Element {
                        name: show(name),
                        count,
                        props: Vec::new(),
                        used,
                    });
                    count_at.push(c_at);
                    prop_names.clear();
                }
                b"property" => {
                    let Some(el) = elements.last_mut() else {
                        return Err(err(kw_at, "\"property\" before any \"element\"".into()));
                    };
                    let scalar = |(at, name): (usize, &[u8])| {
                        Scalar::from_name(name).ok_or_else(|| {
                            err(at, format!("unknown property type \"{}\"", show(name)))
                        })
                    };
                    let (kind, (name_at, name)) = match tokens.get(1) {
                        Some(&(_, b"list")) => {
                            expect_len(5, "property list <count type> <item type> <name>")?;
                            let count = scalar(tokens[2])?;
                            if !count.is_integer() {
                                return Err(err(
                                    tokens[2].0,
                                    format!(
                                        "list count type must be an integer, not {}",
                                        count.name()
                                    ),
                                ));
                            }
                            let item = scalar(tokens[3])?;
                            (Kind::List { count, item }, tokens[4])
                        }
                        _ => {
                            expect_len(3, "property <type> <name>")?;
                            (Kind::Scalar(scalar(tokens[1])?), tokens[2])
                        }
                    };
                    if !prop_names.insert(name) {
                        return Err(err(
                            name_at,
                            format!(
                                "duplicate property \"{}\" in element \"{}\"",
                                show(name),
                                el.name
                            ),
                        ));
                    }
                    let role = match (el.used, name, kind) {
                        (
                            Use::Vertex,
                            b"x" | b"y" | b"z" | b"nx" | b"ny" | b"nz",
                            Kind::List { .. },
                        ) => {
                            return Err(err(
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
                        (
                            Use::Face | Use::Strips,
                            b"vertex_indices" | b"vertex_index",
                            Kind::Scalar(_),
                        ) => {
                            return Err(err(
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
                                return Err(err(
                                    tokens[3].0,
                                    format!("vertex indices must be integers, not {}", item.name()),
                                ));
                            }
                            if el.props.iter().any(|p| p.role == Role::Indices) {
                                return Err(err(
                                    name_at,
                                    format!(
                                        "{} element has both vertex_indices and vertex_index",
                                        el.name
                                    ),
                                ));
                            }
                            Role::Indices
                        }
                        _ => Role::Skip,
                    };
                    el.props.push(Property {
                        name: show(name),
                        kind,
                        role,
                    });
                }
                b"end_header" => {
                    expect_len(1, "end_header")?;
                    break (pos, kw_at);
                }
                _ => {
                    return Err(err(
                        kw_at,
                        format!("unknown PLY header line \"{}\"", show(keyword)),
                    ))
                }
            }
        };
        let Some(format) = format else {
            return Err(err(end_header_at, "PLY header has no format line".into()));
        };

        // The vertex element: x y z required, normals only if all three.
        let Some(vi) = elements.iter().position(|e| e.used == Use::Vertex) else {
            return Err(err(
                end_header_at,
                "PLY header declares no vertex element".into(),
            ));
        };
        let mut has = [false; 6];
        for p in &elements[vi].props {
            if let Role::Vertex(k) = p.role {
                has[k] = true;
            }
        }
        if let Some(k) = (0..3).find(|&k| !has[k]) {
            return Err(err(
                count_at[vi],
                format!("vertex element has no \"{}\" property", ["x", "y", "z"][k]),
            ));
        }
        let has_normals = has[3..].iter().all(|&h| h);
        if !has_normals {
            for p in &mut elements[vi].props {
                if matches!(p.role, Role::Vertex(3..)) {
                    p.role = Role::Skip;
                }
            }
        }
        // Faces or triangle strips (or both), each with a vertex index list,
        // and at least one of them. (Every face yields at least one triangle,
        // since smaller polygons are errors; a strip may yield none, which
        // the body checks.)
        let polygons: Vec<usize> = (0..elements.len())
            .filter(|&i| matches!(elements[i].used, Use::Face | Use::Strips))
            .collect();
        if polygons.is_empty() {
            return Err(err(
                end_header_at,
                "mesh has no triangles (no face or tristrips element)".into(),
            ));
        }
        for &i in &polygons {
            if !elements[i].props.iter().any(|p| p.role == Role::Indices) {
                return Err(err(
                    count_at[i],
                    format!("{} element has no vertex_indices list", elements[i].name),
                ));
            }
        }
        if polygons.iter().all(|&i| elements[i].count == 0) {
            return Err(err(count_at[polygons[0]], "mesh has no triangles".into()));
        }

        // Counts against the body size, before anything is allocated.
        let body_len = (bytes.len() - body_start) as u128;
        // In ASCII, the last scalar may lack a separator.
        let available = if format == Format::Ascii {
            body_len + 1
        } else {
            body_len
        };
        let mut needed: u128 = 0;
        for (el, &at) in elements.iter().zip(&count_at) {
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
                return Err(err(
                    at,
                    format!(
                        "element \"{}\" count {} is impossible: the elements up to it need at \
                         least {needed} bytes but the body has {body_len}",
                        el.name, el.count
                    ),
                ));
            }
        }

        let vertex_count = u32::try_from(elements[vi].count)
            .ok()
            .filter(|&n| n < u32::MAX)
            .ok_or_else(|| err(count_at[vi], "too many vertices".into()))?;

        Ok(Header {
            format,
            elements,
            body_start,
            body_line: line_no.saturating_add(1),
            vertex_count,
            has_normals,
        })
    }
}

/// The whitespace-separated tokens of a header line, with their offsets.
fn tokenize(line: &[u8], offset: usize) -> Vec<(usize, &[u8])> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < line.len() {
        if line[i].is_ascii_whitespace() {
            i += 1;
            continue;
        }
        let start = i;
        while i < line.len() && !line[i].is_ascii_whitespace() {
            i += 1;
        }
        out.push((offset + start, &line[start..i]));
    }
    out
}

/// Which value is being read, for error messages.
struct Ctx<'h> {
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
trait Body {
    /// Reads one value of type `ty` (integers are exact in an f64).
    fn read(&mut self, ty: Scalar, ctx: &Ctx) -> Result<f64, SceneError>;
    /// Skips `n` list items of type `ty`.
    fn skip(&mut self, n: u64, ty: Scalar, ctx: &Ctx) -> Result<(), SceneError>;
    /// An error at the value read last.
    fn error(&self, msg: String) -> SceneError;
    /// Checks that nothing but allowed padding follows the last element.
    fn finish(&self) -> Result<(), SceneError>;
}

fn read_body(src: &mut impl Body, h: &Header) -> Result<Mesh, SceneError> {
    let nv = h.vertex_count;
    // Both capacities are bounded by the body size (checked in the header).
    let mut positions: Vec<Vec3> = Vec::with_capacity(nv as usize);
    let mut normals: Vec<Vec3> = Vec::with_capacity(if h.has_normals { nv as usize } else { 0 });
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
            let mut v = [0f64; 6];
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
                            continue;
                        }
                        if el.used == Use::Strips {
                            read_strips(src, n, item, nv, &ctx, &mut triangles)?;
                            continue;
                        }
                        if n < 3 {
                            return Err(src.error(format!(
                                "{ctx}: a face needs at least 3 vertices, found {n}"
                            )));
                        }
                        let (mut first, mut prev) = (0u32, 0u32);
                        for k in 0..n {
                            let i = src.read(item, &ctx)?;
                            if !(0.0..nv as f64).contains(&i) {
                                return Err(src.error(format!(
                                    "{ctx}: vertex index {i} out of range ({nv} vertices)"
                                )));
                            }
                            let i = i as u32;
                            match k {
                                0 => first = i,
                                1 => {}
                                _ => triangles.push([first, prev, i]),
                            }
                            prev = i;
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
        triangles,
    })
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
        if !(0.0..nv as f64).contains(&i) {
            return Err(src.error(format!(
                "{ctx}: vertex index {i} out of range ({nv} vertices; -1 restarts a strip)"
            )));
        }
        let c = i as u32;
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

struct AsciiBody<'a> {
    file: &'a str,
    /// The whole file, so that locations count lines from its start.
    bytes: &'a [u8],
    pos: usize,
    /// Offset of the token read last.
    last: usize,
}

impl<'a> AsciiBody<'a> {
    fn token(&mut self) -> Option<&'a [u8]> {
        let b = self.bytes;
        while self.pos < b.len() && b[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        if self.pos == b.len() {
            return None;
        }
        let start = self.pos;
        while self.pos < b.len() && !b[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        self.last = start;
        Some(&b[start..self.pos])
    }

    fn at(&self, pos: usize, msg: String) -> SceneError {
        SceneError::new(Location::at_offset(self.file, self.bytes, pos), msg)
    }
}

impl Body for AsciiBody<'_> {
    fn read(&mut self, ty: Scalar, ctx: &Ctx) -> Result<f64, SceneError> {
        let Some(tok) = self.token() else {
            return Err(self.at(
                self.bytes.len(),
                format!("unexpected end of file: expected {ctx} ({})", ty.name()),
            ));
        };
        let text = std::str::from_utf8(tok).ok();
        let value = match ty {
            Scalar::F32 => text.and_then(|s| s.parse::<f32>().ok()).map(f64::from),
            Scalar::F64 => text.and_then(|s| s.parse::<f64>().ok()),
            _ => {
                let (lo, hi) = ty.int_range();
                match text.and_then(|s| s.parse::<i64>().ok()) {
                    Some(i) if (lo..=hi).contains(&i) => Some(i as f64),
                    Some(i) => {
                        return Err(
                            self.error(format!("{ctx}: {i} is out of range for {}", ty.name()))
                        )
                    }
                    None => None,
                }
            }
        };
        value.ok_or_else(|| {
            self.error(format!(
                "{ctx}: expected {}, found \"{}\"",
                ty.name(),
                show(tok)
            ))
        })
    }

    fn skip(&mut self, n: u64, ty: Scalar, ctx: &Ctx) -> Result<(), SceneError> {
        // Each item is checked; the loop ends at the end of the file at the latest.
        for _ in 0..n {
            self.read(ty, ctx)?;
        }
        Ok(())
    }

    fn error(&self, msg: String) -> SceneError {
        self.at(self.last, msg)
    }

    fn finish(&self) -> Result<(), SceneError> {
        let mut rest = AsciiBody { ..*self };
        match rest.token() {
            None => Ok(()),
            Some(tok) => Err(rest.error(format!(
                "unexpected data \"{}\" after the last element",
                show(tok)
            ))),
        }
    }
}

struct BinaryBody<'a> {
    file: &'a str,
    body: &'a [u8],
    pos: usize,
    /// Offset of the value read last.
    last: usize,
    big_endian: bool,
    /// Line number of the body's first byte.
    line: u32,
}

impl BinaryBody<'_> {
    fn at(&self, pos: usize, msg: String) -> SceneError {
        let column = u32::try_from(pos).unwrap_or(u32::MAX - 1) + 1;
        SceneError::new(
            Location::new(self.file, self.line, column),
            format!("byte {pos} of the binary body: {msg}"),
        )
    }

    fn bytes<const N: usize>(&self) -> [u8; N] {
        let mut a = [0u8; N];
        a.copy_from_slice(&self.body[self.pos..self.pos + N]);
        if self.big_endian {
            a.reverse();
        }
        a
    }
}

impl Body for BinaryBody<'_> {
    fn read(&mut self, ty: Scalar, ctx: &Ctx) -> Result<f64, SceneError> {
        let size = ty.size();
        if self.body.len() - self.pos < size {
            return Err(self.at(
                self.pos,
                format!("unexpected end of file: expected {ctx} ({})", ty.name()),
            ));
        }
        let v = match ty {
            Scalar::I8 => f64::from(i8::from_le_bytes(self.bytes())),
            Scalar::U8 => f64::from(self.body[self.pos]),
            Scalar::I16 => f64::from(i16::from_le_bytes(self.bytes())),
            Scalar::U16 => f64::from(u16::from_le_bytes(self.bytes())),
            Scalar::I32 => f64::from(i32::from_le_bytes(self.bytes())),
            Scalar::U32 => f64::from(u32::from_le_bytes(self.bytes())),
            Scalar::F32 => f64::from(f32::from_le_bytes(self.bytes())),
            Scalar::F64 => f64::from_le_bytes(self.bytes()),
        };
        self.last = self.pos;
        self.pos += size;
        Ok(v)
    }

    fn skip(&mut self, n: u64, ty: Scalar, ctx: &Ctx) -> Result<(), SceneError> {
        let len = n.checked_mul(ty.size() as u64);
        match len {
            Some(len) if len <= (self.body.len() - self.pos) as u64 => {
                self.pos += len as usize;
                Ok(())
            }
            // Reported at the list's count, the value that is wrong.
            _ => Err(self.at(
                self.last,
                format!(
                    "unexpected end of file: {ctx} claims {n} {} items but only {} bytes remain",
                    ty.name(),
                    self.body.len() - self.pos
                ),
            )),
        }
    }

    fn error(&self, msg: String) -> SceneError {
        self.at(self.last, msg)
    }

    fn finish(&self) -> Result<(), SceneError> {
        let rest = &self.body[self.pos..];
        if rest.iter().all(|c| c.is_ascii_whitespace()) {
            Ok(())
        } else {
            Err(self.at(
                self.pos,
                format!(
                    "{} bytes of unexpected data after the last element",
                    rest.len()
                ),
            ))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{apply_edits, assert_error_at, check_mesh_invariants, Edit};
    use proptest::prelude::*;

    /// A typed value to write into a test file.
    #[derive(Clone, Copy, Debug)]
    enum V {
        I8(i8),
        U8(u8),
        I16(i16),
        U16(u16),
        I32(i32),
        U32(u32),
        F32(f32),
        F64(f64),
    }

    impl V {
        fn ascii(self) -> String {
            match self {
                V::I8(x) => x.to_string(),
                V::U8(x) => x.to_string(),
                V::I16(x) => x.to_string(),
                V::U16(x) => x.to_string(),
                V::I32(x) => x.to_string(),
                V::U32(x) => x.to_string(),
                V::F32(x) => x.to_string(),
                V::F64(x) => x.to_string(),
            }
        }

        fn binary(self, big: bool, out: &mut Vec<u8>) {
            macro_rules! put {
                ($x:expr) => {
                    if big {
                        out.extend_from_slice(&$x.to_be_bytes())
                    } else {
                        out.extend_from_slice(&$x.to_le_bytes())
                    }
                };
            }
            match self {
                V::I8(x) => put!(x),
                V::U8(x) => put!(x),
                V::I16(x) => put!(x),
                V::U16(x) => put!(x),
                V::I32(x) => put!(x),
                V::U32(x) => put!(x),
                V::F32(x) => put!(x),
                V::F64(x) => put!(x),
            }
        }

        /// The same number as another type (for files of every scalar type).
        fn as_type(x: i32, ty: &str) -> V {
            match ty {
                "char" | "int8" => V::I8(x as i8),
                "uchar" | "uint8" => V::U8(x as u8),
                "short" | "int16" => V::I16(x as i16),
                "ushort" | "uint16" => V::U16(x as u16),
                "int" | "int32" => V::I32(x),
                "uint" | "uint32" => V::U32(x as u32),
                "float" | "float32" => V::F32(x as f32),
                "double" | "float64" => V::F64(x as f64),
                _ => panic!("unknown type {ty}"),
            }
        }
    }

    const FORMATS: [&str; 3] = ["ascii", "binary_little_endian", "binary_big_endian"];
    const TYPES: [&str; 16] = [
        "char", "uchar", "short", "ushort", "int", "uint", "float", "double", "int8", "uint8",
        "int16", "uint16", "int32", "uint32", "float32", "float64",
    ];

    /// A PLY file: `header` is everything between the format line and
    /// `end_header`; each row is one element instance.
    fn ply(format: &str, header: &str, rows: &[Vec<V>]) -> Vec<u8> {
        let mut out = format!("ply\nformat {format} 1.0\n{header}end_header\n").into_bytes();
        for row in rows {
            if format == "ascii" {
                let line: Vec<String> = row.iter().map(|v| v.ascii()).collect();
                out.extend_from_slice(line.join(" ").as_bytes());
                out.push(b'\n');
            } else {
                for v in row {
                    v.binary(format == "binary_big_endian", &mut out);
                }
            }
        }
        out
    }

    fn ok(bytes: &[u8]) -> Mesh {
        match parse("m.ply", bytes) {
            Ok(m) => m,
            Err(e) => panic!("unexpected error: {e}"),
        }
    }

    /// Parses `bytes`, expecting an error at `line:column` whose message contains `msg`.
    fn fails(bytes: &[u8], line: u32, column: u32, msg: &str) {
        assert_error_at(parse("m.ply", bytes), "m.ply", line, column, msg);
    }

    /// A square pyramid, built by hand.
    fn pyramid() -> Mesh {
        Mesh {
            positions: vec![
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(1.0, 0.0, 1.0),
                Vec3::new(0.0, 0.0, 1.0),
                Vec3::new(0.5, 1.0, 0.5),
            ],
            normals: vec![
                Vec3::new(0.0, -1.0, 0.0),
                Vec3::new(0.6, 0.8, 0.0),
                Vec3::new(0.0, 0.0, 1.0),
                Vec3::new(0.0, 0.6, -0.8),
                Vec3::new(0.0, 1.0, 0.0),
            ],
            // The base quad fans into two; then the four sides.
            triangles: vec![
                [0, 1, 2],
                [0, 2, 3],
                [0, 4, 1],
                [1, 4, 2],
                [2, 4, 3],
                [3, 4, 0],
            ],
        }
    }

    /// The pyramid with unnormalised normals, extra vertex properties, an
    /// extra element with lists between vertices and faces, extra face
    /// properties around the index list, and an element after the faces.
    fn pyramid_file(format: &str) -> Vec<u8> {
        let header = "\
comment made by hand
obj_info nothing to see
element vertex 5
property float x
property uchar confidence
property double y
property float32 z
property float nx
property float ny
property float nz
element material 3
property uchar red
property list ushort uint32 tags
property list uint8 float64 weights
element face 5
property list uint8 float32 texcoord
property list uchar int vertex_indices
property int16 flags
element trailer 2
property list int char bytes
";
        let v = |x: f32, y: f64, z: f32, n: [f32; 3]| {
            vec![
                V::F32(x),
                V::U8(200),
                V::F64(y),
                V::F32(z),
                V::F32(n[0]),
                V::F32(n[1]),
                V::F32(n[2]),
            ]
        };
        let face = |idx: &[i32]| {
            let mut row = vec![V::U8(2), V::F32(0.25), V::F32(-0.5), V::U8(idx.len() as u8)];
            row.extend(idx.iter().map(|&i| V::I32(i)));
            row.push(V::I16(-7));
            row
        };
        let rows = vec![
            v(0.0, 0.0, 0.0, [0.0, -3.0, 0.0]),
            v(1.0, 0.0, 0.0, [3.0, 4.0, 0.0]),
            v(1.0, 0.0, 1.0, [0.0, 0.0, 0.5]),
            v(0.0, 0.0, 1.0, [0.0, 3.0, -4.0]),
            v(0.5, 1.0, 0.5, [0.0, 1.0, 0.0]),
            vec![V::U8(1), V::U16(0), V::U8(1), V::F64(2.5)],
            vec![
                V::U8(2),
                V::U16(3),
                V::U32(7),
                V::U32(8),
                V::U32(4_000_000_000),
                V::U8(0),
            ],
            vec![
                V::U8(3),
                V::U16(1),
                V::U32(9),
                V::U8(2),
                V::F64(-1.0),
                V::F64(1e300),
            ],
            face(&[0, 1, 2, 3]),
            face(&[0, 4, 1]),
            face(&[1, 4, 2]),
            face(&[2, 4, 3]),
            face(&[3, 4, 0]),
            vec![V::I32(3), V::I8(-1), V::I8(0), V::I8(127)],
            vec![V::I32(0)],
        ];
        ply(format, header, &rows)
    }

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

    const TRI_HEADER: &str =
        "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                              element face 1\nproperty list uchar int vertex_indices\n";

    fn head(lines: &str) -> Vec<u8> {
        format!("ply\nformat ascii 1.0\n{lines}").into_bytes()
    }

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
    fn ascii_body_errors_are_located() {
        let file = |body: &str| head(&format!("{TRI_HEADER}end_header\n{body}"));
        // The body starts on line 10.
        assert_eq!(
            ok(&file("0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")).triangles,
            vec![[0, 1, 2]]
        );
        assert_eq!(
            ok(&file("0 0 0 1 0 0 0 1 0 3 0 1 2")).triangles,
            vec![[0, 1, 2]]
        );
        fails(
            &file("0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n"),
            13,
            7,
            "vertex index 3 out of range (3 vertices)",
        );
        fails(
            &file("0 0 0\n1 0 0\n0 1 0\n3 0 1 -1\n"),
            13,
            7,
            "vertex index -1 out of range",
        );
        fails(
            &file("0 0 0\n1 0 zz\n0 1 0\n3 0 1 2\n"),
            11,
            5,
            "expected float, found \"zz\"",
        );
        fails(
            &file("0 0 0\n1 0 0\n0 1 0\n3 0 1.0 2\n"),
            13,
            5,
            "expected int, found \"1.0\"",
        );
        fails(
            &file("0 0 0\n1 0 0\n0 1 0\n256 0 1 2\n"),
            13,
            1,
            "256 is out of range for uchar",
        );
        fails(
            &file("0 0 0\n1 0 0\n0 1 0\n2 0 1\n"),
            13,
            1,
            "at least 3 vertices, found 2",
        );
        fails(
            &file("0 0 0\n1 0 0\n0 1 0\n3 0 1\n"),
            14,
            1,
            "unexpected end of file",
        );
        fails(
            &file("0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n  7\n"),
            14,
            3,
            "unexpected data \"7\"",
        );
        fails(
            &file("0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n"),
            11,
            1,
            "not a finite",
        );
        fails(
            &file("0 0 0\n1e39 0 0\n0 1 0\n3 0 1 2\n"),
            11,
            1,
            "not a finite",
        );
    }

    #[test]
    fn binary_body_errors_name_the_byte() {
        for format in ["binary_little_endian", "binary_big_endian"] {
            let rows = |last: i32| {
                vec![
                    vec![V::F32(0.0), V::F32(0.0), V::F32(0.0)],
                    vec![V::F32(1.0), V::F32(f32::NAN), V::F32(0.0)],
                    vec![V::F32(0.0), V::F32(1.0), V::F32(0.0)],
                    vec![V::U8(3), V::I32(0), V::I32(1), V::I32(last)],
                ]
            };
            let mut good = rows(2);
            good[1][1] = V::F32(0.0);
            let bytes = ply(format, TRI_HEADER, &good);
            assert_eq!(ok(&bytes).triangles, vec![[0, 1, 2]]);
            // The header has 9 lines; vertices take bytes 0..36, the face 36..49.
            let mut bad = rows(3);
            bad[1][1] = V::F32(0.0);
            fails(&ply(format, TRI_HEADER, &bad), 10, 46, "byte 45 of the binary body: property \"vertex_indices\" of face 0: vertex index 3 out of range");
            fails(
                &ply(format, TRI_HEADER, &rows(2)),
                10,
                17,
                "byte 16 of the binary body: property \"y\" of vertex 1",
            );
            fails(
                &bytes[..bytes.len() - 2],
                10,
                46,
                "byte 45 of the binary body: unexpected end of file",
            );
            let mut trailing = bytes.clone();
            trailing.extend_from_slice(b"\r\n");
            assert_eq!(ok(&trailing).triangles, vec![[0, 1, 2]]);
            trailing.extend_from_slice(b"xyz");
            fails(
                &trailing,
                10,
                50,
                "byte 49 of the binary body: 5 bytes of unexpected data",
            );
            // A skipped list claiming four billion items ends in an error, quickly.
            let header = format!("{TRI_HEADER}element junk 1\nproperty list uint uchar stuff\n");
            let mut junk = good.clone();
            junk.push(vec![V::U32(4_000_000_000), V::U8(1)]);
            fails(&ply(format, &header, &junk), 12, 50, "byte 49 of the binary body: unexpected end of file: property \"stuff\" of junk 0 claims 4000000000 uchar items but only 1 bytes remain");
        }
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

    /// A zig-zag of 8 vertices in the z = 0 plane: even ones on y = 0,
    /// odd ones on y = 1, x increasing.
    fn zigzag_rows() -> Vec<Vec<V>> {
        (0..8)
            .map(|i| {
                vec![
                    V::F32((i / 2) as f32 + (i % 2) as f32 * 0.5),
                    V::F32((i % 2) as f32),
                    V::F32(0.0),
                ]
            })
            .collect()
    }

    const STRIP_HEADER: &str =
        "element vertex 8\nproperty float x\nproperty float y\nproperty float z\n\
         element tristrips 1\nproperty list int int vertex_indices\n";

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

    /// Issue 15 item 14: checking each property name against every earlier
    /// one made the header quadratic (200,000 property lines took 19 s).
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
                 property list {count_ty} {index_ty} vertex_indices\nend_header\n"
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
