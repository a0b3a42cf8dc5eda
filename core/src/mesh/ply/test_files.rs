//! PLY files for the tests: typed values written as ASCII or binary of
//! either endianness, a hand-built mesh and its file, and the assertions
//! the tests of every part of the reader use.

use glam::Vec3;

use super::parse;
use crate::mesh::Mesh;
use crate::testing::assert_error_at;

/// A typed value to write into a test file.
#[derive(Clone, Copy, Debug)]
pub(super) enum V {
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
    pub(super) fn ascii(self) -> String {
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

    pub(super) fn binary(self, big: bool, out: &mut Vec<u8>) {
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
    pub(super) fn as_type(x: i32, ty: &str) -> V {
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

pub(super) const FORMATS: [&str; 3] = ["ascii", "binary_little_endian", "binary_big_endian"];
pub(super) const TYPES: [&str; 16] = [
    "char", "uchar", "short", "ushort", "int", "uint", "float", "double", "int8", "uint8", "int16",
    "uint16", "int32", "uint32", "float32", "float64",
];

/// A PLY file: `header` is everything between the format line and
/// `end_header`; each row is one element instance.
pub(super) fn ply(format: &str, header: &str, rows: &[Vec<V>]) -> Vec<u8> {
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

pub(super) fn ok(bytes: &[u8]) -> Mesh {
    match parse("m.ply", bytes) {
        Ok(m) => m,
        Err(e) => panic!("unexpected error: {e}"),
    }
}

/// Parses `bytes`, expecting an error at `line:column` whose message contains `msg`.
pub(super) fn fails(bytes: &[u8], line: u32, column: u32, msg: &str) {
    assert_error_at(parse("m.ply", bytes), "m.ply", line, column, msg);
}

/// A square pyramid, built by hand.
pub(super) fn pyramid() -> Mesh {
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
        uvs: vec![],
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
pub(super) fn pyramid_file(format: &str) -> Vec<u8> {
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
property list uint8 float32 quality
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

pub(super) const TRI_HEADER: &str =
    "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                          element face 1\nproperty list uchar int vertex_indices\n";

pub(super) fn head(lines: &str) -> Vec<u8> {
    format!("ply\nformat ascii 1.0\n{lines}").into_bytes()
}

/// A zig-zag of 8 vertices in the z = 0 plane: even ones on y = 0,
/// odd ones on y = 1, x increasing.
pub(super) fn zigzag_rows() -> Vec<Vec<V>> {
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

pub(super) const STRIP_HEADER: &str =
    "element vertex 8\nproperty float x\nproperty float y\nproperty float z\n\
     element tristrips 1\nproperty list int int vertex_indices\n";
