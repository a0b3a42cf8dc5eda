//! What render passes cost: renders a camera's frame in 64-pixel tiles
//! `reps` times with the passes named in the environment variable `AOVS`
//! (none if unset) and prints the best time, the rays traced and an FNV-1a
//! hash of the beauty's bits; with `OUT=file.exr` (or `.png`) it also
//! writes the last render, passes included (docs/aisxml-extensions.md,
//! "Render passes").
//!
//! ```text
//! AOVS="albedo normal depth" OUT=cornell-aovs.exr \
//!   cargo run -p trevi-core --example aov_cost -- examples/cornell-path.xml whitted 2
//! ```

use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;
use trevi_core::tile::{band_order_tiles, render_tile_aovs};
use trevi_core::{Aovs, FrameWriter, ParsedBundle, Scene};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 3 {
        eprintln!("usage: aov_cost SCENE.xml CAMERA [REPS]");
        std::process::exit(2);
    }
    let parsed = ParsedBundle::from_scene_file(Path::new(&a[1])).expect("the scene");
    let scene = Scene::build(parsed.desc);
    let cam = scene.camera_index(&a[2]).expect("the camera");
    let reps: usize = a.get(3).map_or(5, |r| r.parse().expect("REPS"));
    let aovs = Aovs::parse(&std::env::var("AOVS").unwrap_or_default()).expect("AOVS");
    let r = &scene.desc.cameras[cam].render;
    let tiles = band_order_tiles(r.width, r.height, 64);
    let never = AtomicBool::new(false);
    let mut best = f64::MAX;
    let mut out = Vec::new();
    for _ in 0..reps.max(1) {
        let t0 = Instant::now();
        out = tiles
            .iter()
            .map(|t| render_tile_aovs(&scene, cam, *t, aovs, &never).expect("never cancelled"))
            .collect();
        best = best.min(t0.elapsed().as_secs_f64());
    }
    let mut hash = 0xcbf2_9ce4_8422_2325u64;
    for (t, _) in &out {
        for b in t
            .pixels
            .iter()
            .flatten()
            .flat_map(|c| c.to_bits().to_le_bytes())
        {
            hash = (hash ^ u64::from(b)).wrapping_mul(0x100_0000_01b3);
        }
    }
    let rays: u64 = out.iter().map(|(t, _)| t.rays).sum();
    println!(
        "{} {} aovs=\"{aovs}\": best of {reps} {best:.3} s, {rays} rays, beauty fnv1a {hash:016x}",
        a[1], a[2]
    );
    if let Ok(path) = std::env::var("OUT") {
        let mut fw = FrameWriter::create_with_aovs(Path::new(&path), r.width, r.height, aovs)
            .expect("the output");
        for (rect, (t, p)) in tiles.iter().zip(&out) {
            fw.write_tile_aovs(*rect, &t.pixels, p).expect("a tile");
        }
        fw.finish().expect("the output");
    }
}
