//! The PLY loader (ASCII and binary) on arbitrary bytes: a mesh or an
//! error, never a panic, and no allocation a header merely claims.
//!
//! The same bytes are also tried as the body of files whose polygons are
//! triangle strips (`element tristrips`, `-1` restarting a strip) and of
//! files whose faces carry a `texcoord` list (u v per corner), ASCII and
//! both binary byte orders, so that the strip and texcoord readers are
//! reached without the fuzzer having to discover their headers first.
#![no_main]
use libfuzzer_sys::fuzz_target;

const STRIP_HEADER: &str = "element vertex 4\nproperty float x\nproperty float y\n\
    property float z\nelement tristrips 1\nproperty list int int vertex_indices\nend_header\n";
const TEXCOORD_HEADER: &str = "element vertex 4\nproperty float x\nproperty float y\n\
    property float z\nproperty float nx\nproperty float ny\nproperty float nz\n\
    element face 2\nproperty list uchar int vertex_indices\n\
    property list uchar float texcoord\nend_header\n";

fuzz_target!(|data: &[u8]| {
    check(data, false);
    for format in ["ascii", "binary_little_endian", "binary_big_endian"] {
        for (header, strips) in [(STRIP_HEADER, true), (TEXCOORD_HEADER, false)] {
            let mut file = format!("ply\nformat {format} 1.0\n{header}").into_bytes();
            file.extend_from_slice(data);
            check(&file, strips);
        }
    }
});

/// The mesh's invariants, if `file` parses.
fn check(file: &[u8], strips: bool) {
    if let Ok(m) = trevi_core::mesh::ply::parse("fuzz.ply", file) {
        let n = m.positions.len() as u32;
        assert!(m.triangles.iter().flatten().all(|&i| i < n));
        assert!(m.normals.is_empty() || m.normals.len() == m.positions.len());
        assert!(m.uvs.is_empty() || m.uvs.len() == m.positions.len());
        assert!(m.uvs.iter().all(|uv| uv.is_finite()));
        if strips {
            assert!(m.triangles.iter().all(|&[a, b, c]| a != b && b != c && a != c));
        }
    }
}
