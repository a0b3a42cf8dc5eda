//! AISXML on arbitrary text, with a small OBJ and PLY in the bundle so that
//! `file=` references can resolve: the parse ends in a scene or an error,
//! never a panic. A scene that parses is also built (BVHs, camera views).
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::collections::BTreeMap;
use trevi_core::{Bundle, Scene};

const OBJ: &[u8] = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\n";
const PLY: &[u8] = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";

fuzz_target!(|data: &[u8]| {
    let mut files = BTreeMap::new();
    files.insert("scene.xml".to_string(), data.to_vec());
    files.insert("m.obj".to_string(), OBJ.to_vec());
    files.insert("m.ply".to_string(), PLY.to_vec());
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
