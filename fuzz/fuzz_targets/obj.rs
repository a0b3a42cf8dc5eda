//! The OBJ loader on arbitrary bytes: a mesh or an error, never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = trevi_core::mesh::obj::parse("fuzz.obj", data);
});
