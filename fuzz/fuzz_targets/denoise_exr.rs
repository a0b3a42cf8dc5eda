//! The denoiser's reader of a stitched noisy frame (`ExrSource::open`, then
//! a band read): an error or the band, never a panic; within the bounds its
//! documentation gives (headers checked before a pixel is allocated: sides
//! at most 65 536, blocks at most 64 MiB, offset tables within the file);
//! cheap (run.sh gives every input a time and an RSS limit). The bytes go
//! through a file, as the reader reads one.
#![no_main]
use libfuzzer_sys::fuzz_target;
use trevi_denoise::{ExrSource, Inputs, Source};

/// The format's magic number, so the fuzzer starts inside the format.
const MAGIC: &[u8] = &[0x76, 0x2f, 0x31, 0x01];

/// Rows of the band read (the farm reads bands of 256 and more; a few keep
/// a wide frame's band cheap here).
const ROWS: u32 = 4;

fuzz_target!(|data: &[u8]| {
    let mut bytes = Vec::with_capacity(data.len() + 8);
    if !data.starts_with(MAGIC) {
        bytes.extend_from_slice(MAGIC);
    }
    bytes.extend_from_slice(data);
    let dir = std::env::temp_dir().join(format!("trevi-fuzz-denoise-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join("frame.exr");
    if std::fs::write(&path, &bytes).is_err() {
        return;
    }
    let Ok(mut source) = ExrSource::open(&path) else {
        return;
    };
    assert!(source.width() <= 65_536 && source.height() <= 65_536);
    let rows = 0..source.height().min(ROWS);
    let mut band = Inputs::default();
    if source.read(rows.clone(), &mut band).is_ok() {
        let n = source.width() as usize * rows.len();
        assert_eq!(band.color.len(), n);
    }
});
