//! The MTL reader on arbitrary bytes: materials or an error, never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(m) = trevi_core::mesh::mtl::parse("fuzz.mtl", data) {
        assert!(m.len() <= trevi_core::mesh::mtl::MAX_MTL_MATERIALS);
        // Colours are finite and not negative (issue 36).
        for c in m.iter().flat_map(|m| [m.kd, m.ka, m.ks]).flatten() {
            assert!(c.is_finite() && c.min_element() >= 0.0, "{c}");
        }
    }
});
