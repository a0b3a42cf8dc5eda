//! The PLY loader (ASCII and binary) on arbitrary bytes: a mesh or an
//! error, never a panic, and no allocation a header merely claims.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = trevi_core::mesh::ply::parse("fuzz.ply", data);
});
