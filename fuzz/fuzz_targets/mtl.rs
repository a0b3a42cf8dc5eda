//! The MTL reader on arbitrary bytes: materials or an error, never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = trevi_core::mesh::mtl::parse("fuzz.mtl", data);
});
