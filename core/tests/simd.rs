//! Determinism across instruction sets: every node-test path this machine
//! can run (`TREVI_SIMD=scalar|sse|avx`) renders the same bytes. A farm that
//! mixes machines with and without a SIMD path must stitch one image.
//!
//! One test in its own binary: it switches the process-wide path.

mod common;
use common::*;
use trevi_core::bundle::DirSource;
use trevi_core::bvh::{simd, Simd};
use trevi_core::scene::aisxml::parse_scene;
use trevi_core::Scene;

fn example(file: &str, width: u32, height: u32) -> Scene {
    let dir = DirSource {
        root: concat!(env!("CARGO_MANIFEST_DIR"), "/../examples").into(),
    };
    let mut desc = parse_scene(file, &dir).expect("example parses");
    for cam in &mut desc.cameras {
        cam.render.width = width;
        cam.render.height = height;
        cam.render.ao_samples = cam.render.ao_samples.min(4);
        cam.render.diffuse_samples = cam.render.diffuse_samples.min(2);
        cam.render.shadow_samples = cam.render.shadow_samples.min(3);
    }
    Scene::build(desc)
}

fn frame(scene: &Scene, camera: usize) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("frame.exr");
    render_to_file(scene, camera, 16, &out);
    std::fs::read(&out).unwrap()
}

#[test]
fn every_simd_path_renders_the_same_bytes() {
    // Every triangle hit goes through the leaves' four-triangle test
    // (`bvh/simd.rs`), so these cover it on each path too: the Cornell
    // boxes' quads (shared edges on axis-aligned walls), the instanced
    // tori, the textured die and ring.
    let scenes = [
        example("cornell.xml", 48, 36),
        example("instancing.xml", 48, 36),
        example("textured.xml", 48, 36),
    ];
    let paths = Simd::available();
    assert_eq!(paths[0], Simd::Scalar);
    #[cfg(target_arch = "x86_64")]
    {
        assert!(paths.contains(&Simd::Sse));
        // The AVX path (8 boxes a pass, the walk compiled for AVX) wherever
        // the machine runs it.
        assert_eq!(
            paths.contains(&Simd::Avx),
            std::arch::is_x86_feature_detected!("avx")
        );
    }
    for (k, scene) in scenes.iter().enumerate() {
        for camera in 0..scene.cameras.len() {
            assert!(simd::force(Simd::Scalar));
            let reference = frame(scene, camera);
            for &p in &paths[1..] {
                assert!(simd::force(p));
                assert_eq!(simd::current(), p);
                assert!(
                    frame(scene, camera) == reference,
                    "scene {k}, camera {camera}: {p:?} differs from scalar"
                );
            }
        }
    }
}
