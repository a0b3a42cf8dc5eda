//! The OBJ loader on arbitrary bytes (with `vt`, `mtllib` and `usemtl`): a
//! mesh or an error, never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok((mesh, m)) = trevi_core::mesh::obj::parse_with_materials("fuzz.obj", data) {
        assert!(mesh.uvs.is_empty() || mesh.uvs.len() == mesh.positions.len());
        assert!(mesh.uvs.iter().all(|uv| uv.is_finite()));
        assert!(m.names.is_empty() || m.triangle_material.len() == mesh.triangles.len());
        // Each name once, and within the bounds checked where they are read.
        assert!(m.names.len() <= trevi_core::mesh::obj::MAX_OBJ_MATERIALS);
        assert!(m.libs.len() <= trevi_core::mesh::obj::MAX_OBJ_LIBRARIES);
        let distinct: std::collections::HashSet<&str> =
            m.names.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(distinct.len(), m.names.len());
    }
});
