//! The PLY loader (ASCII and binary) on arbitrary bytes: a mesh or an
//! error, never a panic, and no allocation a header merely claims.
//!
//! The same bytes are also tried as the body of files whose polygons are
//! triangle strips (`element tristrips`, `-1` restarting a strip; ASCII and
//! both binary byte orders), so that the strip reader is reached without
//! the fuzzer having to discover its header first.
#![no_main]
use libfuzzer_sys::fuzz_target;

const STRIP_HEADER: &str = "element vertex 4\nproperty float x\nproperty float y\n\
    property float z\nelement tristrips 1\nproperty list int int vertex_indices\nend_header\n";

fuzz_target!(|data: &[u8]| {
    let _ = trevi_core::mesh::ply::parse("fuzz.ply", data);
    for format in ["ascii", "binary_little_endian", "binary_big_endian"] {
        let mut file = format!("ply\nformat {format} 1.0\n{STRIP_HEADER}").into_bytes();
        file.extend_from_slice(data);
        if let Ok(m) = trevi_core::mesh::ply::parse("fuzz.ply", &file) {
            let n = m.positions.len() as u32;
            assert!(m.triangles.iter().flatten().all(|&i| i < n));
            assert!(m.triangles.iter().all(|&[a, b, c]| a != b && b != c && a != c));
        }
    }
});
