//! Texture decoding of PNG bytes (`Texture::decode_within`, what the scene
//! parser calls for a `diffuse-texture` or `map_Kd`): a texture or an
//! error, never a panic; within the texel budget it was given; and cheap
//! (run.sh gives every input a time and an RSS limit).
#![no_main]
use libfuzzer_sys::fuzz_target;
use trevi_core::texture::Texture;

/// A small budget (512 × 512), so that one input's decode stays well under
/// the per-input time limit whatever its header claims.
const BUDGET: u64 = 1 << 18;

/// The format's signature, so the fuzzer starts inside the format.
const MAGIC: &[u8] = b"\x89PNG\r\n\x1a\n";

fuzz_target!(|data: &[u8]| {
    // Seeds (real files) start with the signature; other inputs get it.
    let mut bytes = Vec::with_capacity(data.len() + 8);
    if !data.starts_with(MAGIC) {
        bytes.extend_from_slice(MAGIC);
    }
    bytes.extend_from_slice(data);
    if let Ok(t) = Texture::decode_within(&bytes, BUDGET) {
        let l = &t.levels[0];
        assert!(u64::from(l.width) * u64::from(l.height) <= BUDGET);
        assert_eq!(l.texels.len(), l.width as usize * l.height as usize);
    }
});
