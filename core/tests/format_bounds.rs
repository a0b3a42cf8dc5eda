//! Every file format's parser has a cost bound in bytes
//! and CPU, checked before the work. Measured here, in one process with a
//! counting allocator (the bytes a parse allocates in all, and the most it
//! holds at once) and the thread's own CPU time (not wall-clock time, so
//! that a busy machine does not fail the test).

use std::collections::BTreeMap;
use trevi_core::alloc_meter::{thread_cost, AllocMeter};
use trevi_core::scene::aisxml::parse_scene;
use trevi_core::texture::{Texture, TextureError};
use trevi_core::Bundle;

#[global_allocator]
static METER: AllocMeter = AllocMeter;

/// This thread's CPU time in seconds (user + system), from
/// `/proc/thread-self/stat`; `None` where there is no such file.
fn thread_cpu_secs() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/thread-self/stat").ok()?;
    // The fields after the command's closing parenthesis; utime and stime
    // are fields 14 and 15, counted in clock ticks (100 a second on Linux).
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split(' ').collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// `f`'s result and the CPU seconds this thread spent in it (0 where the
/// platform cannot say).
fn cpu<T>(f: impl FnOnce() -> T) -> (T, f64) {
    let before = thread_cpu_secs();
    let out = f();
    let spent = match (before, thread_cpu_secs()) {
        (Some(a), Some(b)) => b - a,
        _ => 0.0,
    };
    (out, spent)
}

fn bundle(scene: &str, files: Vec<(&str, Vec<u8>)>) -> Bundle {
    let mut map = BTreeMap::new();
    map.insert("s.xml".to_string(), scene.as_bytes().to_vec());
    for (n, b) in files {
        map.insert(n.to_string(), b);
    }
    Bundle {
        scene: "s.xml".into(),
        files: map,
    }
}

const SCENE: &str = r#"<scene version="1"><mesh id="o" file="o.obj"/><model id="a" mesh="o"/>
<camera id="c" position="0 0 5" lookat="0 0 0" fov="50"><render width="4" height="3"/></camera></scene>"#;

const TRIANGLE: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";

/// Regression: each material of an `.mtl` copied the whole file (569 KB of
/// 20,000 materials wanted 11.4 GB), and each repeat of its name on an
/// `mtllib` line read and copied it again (a library named 50,000 times:
/// 2.5 GB). Now a library is read and parsed once; what a parse allocates
/// is a small multiple of the files' sizes.
#[test]
fn material_libraries_cost_memory_linear_in_their_size() {
    // 4,000 materials, each used by a triangle; the library named 2,000
    // times on one line and again on a second.
    let n = 4_000;
    let mut mtl = String::new();
    let mut obj = format!("mtllib{}\nmtllib lib.mtl\n", " lib.mtl".repeat(2_000));
    obj.push_str(TRIANGLE);
    for k in 0..n {
        mtl.push_str(&format!("newmtl material_{k:05}\nKd 0.5 0.5 0.5\nNs 10\n"));
        obj.push_str(&format!("usemtl material_{k:05}\nf 1 2 3\n"));
    }
    let input = mtl.len() + obj.len();
    let b = bundle(
        SCENE,
        vec![("o.obj", obj.into_bytes()), ("lib.mtl", mtl.into_bytes())],
    );
    let (d, total, peak) = thread_cost(|| parse_scene("s.xml", &b));
    let d = d.unwrap();
    assert_eq!(d.models[0].surfaces.len(), n + 1);
    eprintln!("{input} bytes of OBJ and MTL: {total} bytes allocated, peak {peak}");
    // Before: 4,000 copies of the 112 KB library, 450 MB (and 2,000 reads).
    assert!(
        total < 40 * input + (8 << 20),
        "{total} bytes allocated for {input} bytes of input"
    );
    assert!(
        peak < 20 * input + (4 << 20),
        "peak {peak} for {input} bytes"
    );
}

/// Regression: `usemtl` names were looked up linearly (100,000 names: 21 s,
/// 200,000: 91 s) and the 65,534 limit checked after all of them. Now by
/// hash, and the limit where the name that passes it is.
#[test]
fn usemtl_names_are_hashed_and_their_limit_is_at_the_name_that_passes_it() {
    let max = trevi_core::mesh::obj::MAX_OBJ_MATERIALS;
    let mut obj = String::from("mtllib m.mtl\n");
    obj.push_str(TRIANGLE);
    for k in 0..max {
        obj.push_str(&format!("usemtl m{k}\nf 1 2 3\n"));
    }
    let (r, secs) = cpu(|| trevi_core::mesh::obj::parse_with_materials("o.obj", obj.as_bytes()));
    let (mesh, m) = r.unwrap();
    assert_eq!((m.names.len(), mesh.triangles.len()), (max, max + 1));
    // Linear: well under a second even unoptimised; the linear search
    // made 2·10⁹ string comparisons here (tens of seconds unoptimised).
    assert!(secs < 1.5, "{max} usemtl names took {secs} s of CPU");
    obj.push_str("usemtl one_too_many\nf 1 2 3\n");
    let e = trevi_core::mesh::obj::parse_with_materials("o.obj", obj.as_bytes()).unwrap_err();
    assert_eq!(
        (e.location.file.as_str(), e.location.line, e.location.column),
        ("o.obj", 6 + 2 * max as u32, 8),
        "{e}"
    );
    assert!(e.message.contains("more than 65534 materials"), "{e}");
}

/// A segment of a JPEG: marker code and body (its length is added).
fn seg(code: u8, body: &[u8]) -> Vec<u8> {
    let mut v = vec![0xFF, code];
    v.extend_from_slice(&((body.len() + 2) as u16).to_be_bytes());
    v.extend_from_slice(body);
    v
}

/// A progressive greyscale JPEG of `w × h` whose every coefficient is 0:
/// one DC scan and `ac_scans` repeats of the same AC scan, each one bit
/// per block (Huffman tables of one code each). The file is a few bytes a
/// block, and a decoder walks every block once per scan.
fn progressive_jpeg(w: u16, h: u16, ac_scans: usize) -> Vec<u8> {
    let mut f = vec![0xFF, 0xD8];
    let mut dqt = vec![0u8];
    dqt.extend_from_slice(&[1; 64]);
    f.extend(seg(0xDB, &dqt));
    let mut sof = vec![8];
    sof.extend_from_slice(&h.to_be_bytes());
    sof.extend_from_slice(&w.to_be_bytes());
    sof.extend_from_slice(&[1, 1, 0x11, 0]);
    f.extend(seg(0xC2, &sof));
    // One code of length 1 for symbol 0: DC "difference 0", AC "EOB".
    let mut one_code = [0u8; 17];
    one_code[1] = 1;
    for class in [0x00u8, 0x10] {
        let mut dht = vec![class];
        dht.extend_from_slice(&one_code[1..]);
        dht.push(0);
        f.extend(seg(0xC4, &dht));
    }
    let blocks = usize::from(w).div_ceil(8) * usize::from(h).div_ceil(8);
    let data = vec![0u8; blocks.div_ceil(8)];
    f.extend(seg(0xDA, &[1, 1, 0x00, 0, 0, 0]));
    f.extend_from_slice(&data);
    for _ in 0..ac_scans {
        f.extend(seg(0xDA, &[1, 1, 0x00, 1, 63, 0]));
        f.extend_from_slice(&data);
    }
    f.extend_from_slice(&[0xFF, 0xD9]);
    f
}

/// Regression: a 713 KB progressive JPEG of repeated scans cost 23 s of CPU
/// a decode. Its scans are counted from its markers first, and past
/// `MAX_JPEG_SCANS` it is refused for the cost of that pass; within it,
/// the decode of the largest image allowed is bounded.
#[test]
fn a_jpeg_of_too_many_scans_is_refused_before_decoding() {
    use trevi_core::texture::jpeg_scan::{JpegScanError, MAX_JPEG_SCANS};
    // A 1024 × 1024 frame with 10,000 scans: 160 MB of blocks to walk.
    let hostile = progressive_jpeg(1024, 1024, 10_000);
    let (r, secs) = cpu(|| Texture::decode(&hostile));
    match r {
        Err(TextureError::Jpeg(JpegScanError::TooManyScans { nth, .. })) => {
            assert_eq!(nth, MAX_JPEG_SCANS + 1)
        }
        other => panic!("{:?}", other.map(|t| t.levels.len())),
    }
    assert!(secs < 1.0, "refusing took {secs} s");
    // Within the bound it decodes, and to black.
    let ok = progressive_jpeg(64, 32, MAX_JPEG_SCANS as usize - 1);
    let t = Texture::decode(&ok).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((t.levels[0].width, t.levels[0].height), (64, 32));
    // And the message names the bound, for the scene's error.
    let e = Texture::decode(&hostile).unwrap_err().to_string();
    assert!(e.contains("more than 64 scans"), "{e}");
}

/// Within the bound the cost is bounded too: the worst a file of
/// `MAX_JPEG_SCANS` scans can make a decode walk is 64 passes over the
/// blocks of the largest image allowed. Measured on a quarter of that
/// image (1024 × 1024: a sixteenth of the texels), printed for
/// docs/farm.md, and held to a generous bound.
#[test]
fn a_jpeg_of_the_most_scans_allowed_decodes_in_bounded_time() {
    use trevi_core::texture::jpeg_scan::MAX_JPEG_SCANS;
    let f = progressive_jpeg(1024, 1024, MAX_JPEG_SCANS as usize - 1);
    let (t, secs) = cpu(|| Texture::decode(&f));
    let t = t.unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(t.levels[0].width, 1024);
    eprintln!(
        "{} byte JPEG of 1024 x 1024 and {MAX_JPEG_SCANS} scans: {secs} s of CPU",
        f.len()
    );
    assert!(secs < 10.0, "{secs} s");
}

/// A scene naming such a JPEG gets an error at the reference naming the
/// file.
#[test]
fn a_scene_with_a_hostile_jpeg_is_refused_naming_the_file() {
    let scene = r#"<scene version="1"><mesh id="q"><vertices>0 0 0 1 0 0 0 1 0</vertices><uvs>0 0 1 0 0 1</uvs><triangles>0 1 2</triangles></mesh>
<model id="a" mesh="q"><surface diffuse-texture="t/x.jpg"/></model>
<camera id="c" position="0 0 5" lookat="0 0 0" fov="50"><render width="4" height="3"/></camera></scene>"#;
    let b = bundle(scene, vec![("t/x.jpg", progressive_jpeg(256, 256, 1_000))]);
    let line2 = scene.lines().nth(1).unwrap();
    let col = line2.find("diffuse-texture").unwrap() as u32 + 1;
    // The full parse (a worker, trevi-submit) and the headers-only one (the
    // coordinator's admission) refuse it by the same rule, at the same place.
    let full = parse_scene("s.xml", &b).unwrap_err();
    let headers = trevi_core::scene::aisxml::parse_scene_headers("s.xml", &b).unwrap_err();
    for e in [full, headers] {
        assert_eq!((e.location.line, e.location.column), (2, col), "{e}");
        assert!(e.message.contains("\"t/x.jpg\""), "{e}");
        assert!(e.message.contains("more than 64 scans"), "{e}");
    }
}

fn crc32(bytes: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xedb8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

fn chunk(kind: &[u8; 4], data: &[u8]) -> Vec<u8> {
    let mut c = kind.to_vec();
    c.extend_from_slice(data);
    let mut out = (data.len() as u32).to_be_bytes().to_vec();
    out.extend_from_slice(&c);
    out.extend_from_slice(&crc32(&c).to_be_bytes());
    out
}

/// A PNG of `w × h` grey pixels whose IDAT is `zlib` followed by `extra`
/// chunks of `extra_kind` before IEND.
fn png_with(w: u32, h: u32, zlib: &[u8], extra_kind: &[u8; 4], extra: usize) -> Vec<u8> {
    let mut ihdr = w.to_be_bytes().to_vec();
    ihdr.extend_from_slice(&h.to_be_bytes());
    ihdr.extend_from_slice(&[8, 0, 0, 0, 0]);
    let mut f = b"\x89PNG\r\n\x1a\n".to_vec();
    f.extend(chunk(b"IHDR", &ihdr));
    f.extend(chunk(b"IDAT", zlib));
    let c = chunk(extra_kind, &[]);
    for _ in 0..extra {
        f.extend_from_slice(&c);
    }
    f.extend(chunk(b"IEND", &[]));
    f
}

/// Regression: a PNG's size is read from IHDR before decoding (the texel
/// budget), and the decoder inflates all of its image data, also past the
/// last row: a 16 × 16 PNG of 65 KB inflated 64 MiB (a bundle-sized one,
/// hundreds of GB). Compressed data beyond what the image can need is
/// refused from the chunk headers; a million empty chunks cost a pass.
#[test]
fn a_png_costs_what_its_header_allows_however_its_data_inflate() {
    use trevi_core::texture::png_scan::PngScanError;
    // 64 MiB of zeros, deflated (about 64 KB): rows of filter 0.
    let zeros = vec![0u8; 64 << 20];
    let zlib = miniz_oxide::deflate::compress_to_vec_zlib(&zeros, 9);
    drop(zeros);
    let bomb = png_with(16, 16, &zlib, b"tEXt", 0);
    let ((r, total, peak), secs) = cpu(|| thread_cost(|| Texture::decode(&bomb)));
    eprintln!(
        "{} byte PNG inflating to 64 MiB: {:?}, {total} bytes allocated, peak {peak}, {secs} s",
        bomb.len(),
        r.as_ref().err()
    );
    match r {
        Err(TextureError::Png(PngScanError::TooMuchData { idat, max, .. })) => {
            assert_eq!(idat as usize, zlib.len());
            assert_eq!(max, 16 * 17 + 16 * 17 / 8 + 4096);
        }
        other => panic!("{:?}", other.map(|t| t.levels.len())),
    }
    assert!(total < 1 << 20, "{total} bytes allocated");

    // A real image's data, however it was compressed, is within the bound:
    // stored (level 0) noise of the largest size a test affords.
    let noise: Vec<u8> = (0..256 * 257u32)
        .map(|i| {
            if i % 257 == 0 {
                0
            } else {
                (i.wrapping_mul(2_654_435_761) >> 24) as u8
            }
        })
        .collect();
    let stored = miniz_oxide::deflate::compress_to_vec_zlib(&noise, 0);
    assert!(stored.len() > noise.len());
    let t = Texture::decode(&png_with(256, 256, &stored, b"tEXt", 0)).unwrap();
    assert_eq!(t.levels[0].width, 256);

    // A million empty ancillary chunks after the image data.
    let zlib = miniz_oxide::deflate::compress_to_vec_zlib(&vec![0u8; 16 * 17], 9);
    let many = png_with(16, 16, &zlib, b"tEXt", 1_000_000);
    let ((r, _, peak), secs) = cpu(|| thread_cost(|| Texture::decode(&many)));
    eprintln!(
        "{} byte PNG of 10⁶ chunks: ok {}, peak {peak}, {secs} s",
        many.len(),
        r.is_ok()
    );
    assert!(peak < 2 * many.len() + (16 << 20), "peak {peak}");
    assert!(secs < 10.0, "{secs} s");
}
