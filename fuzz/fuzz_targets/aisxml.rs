//! AISXML on arbitrary text, with small meshes, a material library and a
//! texture in the bundle so that `file=`, `mtllib`, `map_Kd` and
//! `diffuse-texture=` references can resolve: the parse ends in a scene or
//! an error, never a panic. A scene that parses is also built (BVHs, camera
//! views, textures decoded with their MIP chains).
//!
//! Bundle files: `m.obj` and `m.ply` (plain triangles), `t.obj` (`vt`,
//! `f v/vt/vn`, `mtllib t.mtl`, `usemtl`), `t.mtl` (`Kd`, `illum`, `map_Kd
//! t.png`), `t.ply` (a per-face `texcoord` list) and `t.png` (2 x 2 RGB).
//! `fuzz/run.sh` seeds the corpus with a scene using all of them.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::collections::BTreeMap;
use trevi_core::{Bundle, Scene};

const OBJ: &[u8] = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\n";
const PLY: &[u8] = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
const TEXTURED_OBJ: &[u8] = b"mtllib t.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\nvn 0 0 1\nusemtl a\nf 1/1/1 2/2/1 3/3/1\nusemtl b\nf 2/2/1 4/4/1 3/3/1\n";
const MTL: &[u8] = b"newmtl a\nKd 1 0.5 0.25\nmap_Kd -s 2 2 t.png\nnewmtl b\nKs 0.5 0.5 0.5\nillum 3\n";
const TEXTURED_PLY: &[u8] = b"ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nproperty list uchar float texcoord\nend_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3 8 0 0 1 0 1 1 0 1\n";
const PNG: &[u8] = b"\x89\x50\x4e\x47\x0d\x0a\x1a\x0a\x00\x00\x00\x0d\x49\x48\x44\x52\x00\x00\x00\x02\x00\x00\x00\x02\x08\x02\x00\x00\x00\xfd\xd4\x9a\x73\x00\x00\x00\x12\x49\x44\x41\x54\x78\xda\x63\x60\x60\xf8\xff\x9f\x01\x48\x30\x80\x08\x00\x1b\xf2\x03\xfd\x81\x5f\x5c\x76\x00\x00\x00\x00\x49\x45\x4e\x44\xae\x42\x60\x82";

fuzz_target!(|data: &[u8]| {
    let mut files = BTreeMap::new();
    files.insert("scene.xml".to_string(), data.to_vec());
    for (name, bytes) in [
        ("m.obj", OBJ),
        ("m.ply", PLY),
        ("t.obj", TEXTURED_OBJ),
        ("t.mtl", MTL),
        ("t.ply", TEXTURED_PLY),
        ("t.png", PNG),
    ] {
        files.insert(name.to_string(), bytes.to_vec());
    }
    let bundle = Bundle {
        scene: "scene.xml".into(),
        files,
    };
    if let Ok(scene) = Scene::from_bundle(&bundle) {
        // Keep the build cheap: the farm limits nothing here, but the fuzzer
        // only needs the parse and the structures, not a render.
        let _ = scene.camera_index("c");
    }
});
