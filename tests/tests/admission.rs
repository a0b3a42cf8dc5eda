//! Admission reads headers, never pixels (issue 36, class 1): with real
//! processes, a 33 KB two-part OpenEXR whose second part claims 65536² is
//! refused at submission with a clear error (and by `trevi-submit`'s own
//! parse), while the coordinator goes on serving another job; bundles of
//! PNGs that decode to 256 MiB each are admitted without the coordinator's
//! peak memory growing by anything like their decoded size.

mod common;

use common::*;
use std::collections::BTreeMap;
use trevi_proto::pb;

/// A scene whose one model is textured with `file`.
fn textured_scene(file: &str, seed: u32) -> String {
    format!(
        r#"<scene version="1">
  <!-- {seed} -->
  <mesh id="q"><vertices>-1 0 -1 1 0 -1 1 0 1</vertices><uvs>0 0 1 0 1 1</uvs>
    <triangles>0 2 1</triangles></mesh>
  <model id="m" mesh="q"><surface diffuse-texture="{file}"/></model>
  <light type="point" position="0 3 0"/>
  <camera id="main" position="0 2 3" lookat="0 0 0" fov="50"><render width="16" height="16"/></camera>
</scene>
"#
    )
}

/// One OpenEXR attribute: name, type, size, value.
fn attr(out: &mut Vec<u8>, name: &str, ty: &str, value: &[u8]) {
    out.extend_from_slice(name.as_bytes());
    out.push(0);
    out.extend_from_slice(ty.as_bytes());
    out.push(0);
    out.extend_from_slice(&(value.len() as i32).to_le_bytes());
    out.extend_from_slice(value);
}

fn ints(v: &[i32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// The header of a scan-line part of `side × side` floats in three
/// `channels`, ZIP (16 lines a chunk), written by hand after the OpenEXR
/// file layout.
fn exr_part_header(name: &str, side: i32, channels: [&str; 3]) -> Vec<u8> {
    let mut h = Vec::new();
    let mut ch = Vec::new();
    for c in channels {
        ch.extend_from_slice(c.as_bytes());
        ch.push(0);
        ch.extend_from_slice(&ints(&[2])); // FLOAT
        ch.extend_from_slice(&[0, 0, 0, 0]); // pLinear, reserved
        ch.extend_from_slice(&ints(&[1, 1])); // sampling
    }
    ch.push(0);
    attr(&mut h, "channels", "chlist", &ch);
    attr(&mut h, "chunkCount", "int", &ints(&[(side + 15) / 16]));
    attr(&mut h, "compression", "compression", &[3]); // ZIP
    attr(
        &mut h,
        "dataWindow",
        "box2i",
        &ints(&[0, 0, side - 1, side - 1]),
    );
    attr(&mut h, "displayWindow", "box2i", &ints(&[0, 0, 0, 0]));
    attr(&mut h, "lineOrder", "lineOrder", &[0]);
    attr(&mut h, "name", "string", name.as_bytes());
    attr(&mut h, "pixelAspectRatio", "float", &1f32.to_le_bytes());
    attr(&mut h, "screenWindowCenter", "v2f", &[0; 8]);
    attr(&mut h, "screenWindowWidth", "float", &1f32.to_le_bytes());
    attr(&mut h, "type", "string", b"scanlineimage");
    h.push(0);
    h
}

/// The attack of issue 36: a multi-part OpenEXR whose part 0 is 1 × 1 (not
/// RGB, so the decoder's layer is part 1) and whose part 1 claims 65536 ×
/// 65536 RGB, with the offset table that claim needs (4096 chunks), about
/// 33 KB. A decoder that checked part 0's header only went on to allocate
/// 48 GiB for part 1, and the process aborted.
fn hostile_exr() -> Vec<u8> {
    let mut f = vec![0x76, 0x2f, 0x31, 0x01, 2, 0x10, 0, 0]; // version 2, multi-part
    f.extend(exr_part_header("small", 1, ["X", "Y", "Z"]));
    f.extend(exr_part_header("huge", 65_536, ["B", "G", "R"]));
    f.push(0); // end of the headers
    let tables = 8 * (1 + 4096);
    let first_chunk = (f.len() + tables) as u64;
    f.extend_from_slice(&first_chunk.to_le_bytes());
    f.extend(std::iter::repeat_n(0u8, 8 * 4096));
    // Part 0's one chunk: part, y, size, three floats (stored as they are).
    f.extend(ints(&[0, 0, 12]));
    f.extend([0.5f32, 0.5, 0.5].iter().flat_map(|x| x.to_le_bytes()));
    f
}

fn upload_bundle(rt: &tokio::runtime::Runtime, c: &Coordinator, files: &[(&str, &[u8])]) -> String {
    let mut map = BTreeMap::new();
    for (n, b) in files {
        map.insert(n.to_string(), b.to_vec());
    }
    let b = trevi_core::Bundle {
        scene: files[0].0.into(),
        files: map,
    };
    rt.block_on(async { upload(&mut bundles(c, None).await, vec![b.encode()]).await })
        .unwrap_or_else(|e| panic!("upload: {e:?}"))
}

#[test]
fn a_multi_part_exr_claiming_65536_squared_is_refused_and_the_farm_keeps_serving() {
    let dir = Dir::new();
    let exr = hostile_exr();
    assert!(exr.len() < 40_000, "{} bytes", exr.len());
    let scene = textured_scene("t.exr", 0);

    // trevi-submit's own (full) parse decodes the texture: refused, with
    // the attribute's location, instead of aborting.
    std::fs::create_dir_all(dir.path().join("hostile")).unwrap();
    std::fs::write(dir.path().join("hostile/t.exr"), &exr).unwrap();
    let local = dir.write("hostile/s.xml", &scene);
    let out = dir.path().join("x.png");
    let o = submit(
        &dir,
        &[local.to_str().unwrap(), "-o", out.to_str().unwrap()],
    );
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "trevi-submit: {stderr}");
    assert!(
        stderr.contains("s.xml:5:") && stderr.contains("65536 x 65536"),
        "{stderr}"
    );
    assert!(!out.exists());

    // The coordinator, sent the bundle directly, refuses the job from the
    // texture's headers.
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let _w = worker_with(&dir, &c.url, "worker0", &[], &[]);
    let rt = runtime();
    let hash = upload_bundle(&rt, &c, &[("s.xml", scene.as_bytes()), ("t.exr", &exr)]);
    let e = rt.block_on(submit_job(&c, &hash)).unwrap_err();
    assert_eq!(e.code(), tonic::Code::InvalidArgument, "{e:?}");
    assert!(
        e.message().contains("s.xml:5:") && e.message().contains("65536 x 65536"),
        "{e:?}"
    );
    // ... and serves the next job to the end.
    let tiny = dir.write("tiny/s.xml", &tiny_scene(1));
    let png = farm_render(&dir, &c.url, &tiny, "tiny.png", 16);
    assert!(png.starts_with(b"\x89PNG"));
}

/// A 4096 × 4096 PNG of one bit a pixel (a few KB; decoded to linear RGB
/// with its MIP chain, 256 MiB).
fn big_png() -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, 4096, 4096);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::One);
    let mut w = enc.write_header().unwrap();
    w.write_image_data(&vec![0b1010_1010; 4096 * 4096 / 8])
        .unwrap();
    drop(w);
    out
}

#[test]
fn bundles_of_big_pngs_are_admitted_without_decoding_them() {
    const BUNDLES: u32 = 8;
    let dir = Dir::new();
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let rt = runtime();
    let png = big_png();
    // Four textures a scene: the most a scene may have (4 × 4096²).
    let hashes: Vec<String> = (0..BUNDLES)
        .map(|i| {
            let scene = textured_scene("a.png", i)
                .replace(
                    r#"<surface diffuse-texture="a.png"/>"#,
                    r#"<surface diffuse-texture="a.png"/><surface triangles="0" diffuse-texture="b.png"/>"#,
                )
                .replace(
                    "<light",
                    r#"<model id="n" mesh="q"><surface diffuse-texture="c.png"/><surface triangles="0" diffuse-texture="d.png"/></model>
  <light"#,
                );
            upload_bundle(
                &rt,
                &c,
                &[
                    ("s.xml", scene.as_bytes()),
                    ("a.png", &png),
                    ("b.png", &png),
                    ("c.png", &png),
                    ("d.png", &png),
                ],
            )
        })
        .collect();
    let pid = c.proc.0.id();
    let before = proc_kib(pid, "VmHWM");
    // All at once, as the attack did: each is admitted or refused as busy.
    let results = rt.block_on(async {
        let mut set = tokio::task::JoinSet::new();
        for h in hashes.clone() {
            let mut j = jobs(&c, None).await;
            set.spawn(async move {
                j.submit_job(pb::SubmitJobRequest {
                    bundle_hash: h,
                    ..Default::default()
                })
                .await
            });
        }
        set.join_all().await
    });
    let mut admitted = 0;
    for r in &results {
        match r {
            Ok(_) => admitted += 1,
            Err(e) => {
                assert_eq!(e.code(), tonic::Code::ResourceExhausted, "{e:?}");
                assert!(e.message().contains("--max-admissions"), "{e:?}");
            }
        }
    }
    // A refused one goes through once the others are admitted.
    for h in &hashes {
        let r = rt.block_on(submit_job(&c, h));
        assert!(r.is_ok(), "{r:?}\n{}", dir.logs());
    }
    let peak = proc_kib(pid, "VmHWM");
    eprintln!(
        "{BUNDLES} bundles of four 4096² PNGs ({admitted} admitted at once): coordinator peak \
         {} MiB before, {} MiB after",
        before / 1024,
        peak / 1024
    );
    // Decoding one texture alone would take 256 MiB (before the fix the
    // coordinator decoded all four of every bundle).
    assert!(
        peak < before + 64 * 1024,
        "peak RSS grew by {} MiB\n{}",
        (peak - before) / 1024,
        dir.logs()
    );
    assert!(admitted >= 1);
}
