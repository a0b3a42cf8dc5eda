//! The OBJ loader on arbitrary bytes (with `vt`, `mtllib` and `usemtl`): a
//! mesh or an error, never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok((mesh, m)) = trevi_core::mesh::obj::parse_with_materials("fuzz.obj", data) {
        assert!(mesh.uvs.is_empty() || mesh.uvs.len() == mesh.positions.len());
        assert!(mesh.uvs.iter().all(|uv| uv.is_finite()));
        assert!(m.names.is_empty() || m.triangle_material.len() == mesh.triangles.len());
    }
});
