//! A pixel depends only on the scene and its coordinates: the same frame
//! rendered with any tile size and any thread count is byte-identical.

mod common;
use common::*;
use trevi_core::bundle::DirSource;
use trevi_core::scene::aisxml::parse_scene;
use trevi_core::Scene;

/// The Cornell-box example (every effect on), shrunk so the tile-size-1 run
/// stays quick.
fn cornell(
    width: u32,
    height: u32,
    extra: impl Fn(&mut trevi_core::scene::RenderSettings),
) -> Scene {
    let dir = DirSource {
        root: concat!(env!("CARGO_MANIFEST_DIR"), "/../examples").into(),
    };
    let mut desc = parse_scene("cornell.xml", &dir).expect("example parses");
    for cam in &mut desc.cameras {
        cam.render.width = width;
        cam.render.height = height;
        extra(&mut cam.render);
    }
    Scene::build(desc)
}

fn bytes_for(scene: &Scene, tile: u32, threads: usize, ext: &str) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join(format!("frame.{ext}"));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| render_to_file(scene, 0, tile, &out));
    std::fs::read(&out).unwrap()
}

#[test]
fn tile_size_and_thread_count_do_not_change_a_single_byte() {
    let scene = cornell(37, 29, |r| {
        r.ao_samples = 4;
        r.diffuse_samples = 2;
        r.diffuse_depth = 2;
        r.shadow_samples = 3;
    });
    for ext in ["png", "exr"] {
        let reference = bytes_for(&scene, 37, 1, ext);
        for (tile, threads) in [(1, 2), (7, 1), (7, 2), (64, 2), (37, 2)] {
            assert!(
                bytes_for(&scene, tile, threads, ext) == reference,
                "{ext}: tile {tile}, {threads} threads differs from the whole-frame render"
            );
        }
    }
}
