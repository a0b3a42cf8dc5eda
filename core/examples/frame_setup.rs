//! Per-frame set-up time of a sequence against a still's set-up, measured
//! in one run (docs/farm.md, "Sequences", has the same set-ups measured in
//! a worker).
//!
//! ```sh
//! cargo run --release -p trevi-core --example frame_setup -- SCENE.xml [RUNS]
//! ```
//!
//! A still's set-up is what a worker does before its first tile: build the
//! parsed scene (every mesh BVH) and the camera's view (instances, top-level
//! BVH, lights). A frame's set-up is `Scene::set_frame` on the built scene
//! and the same view: the keyed channels at the frame's time, the top-level
//! tree and cameras again, the mesh BVHs kept. Each is timed `RUNS` times
//! (default 9); the medians and their ratio are printed. Parsing (reading
//! files, mesh loading) is common to both and not counted.

use std::time::{Duration, Instant};
use trevi_core::{ParsedBundle, Scene};

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

fn main() {
    let mut args = std::env::args().skip(1);
    let path = args.next().expect("usage: frame_setup SCENE.xml [RUNS]");
    let runs: usize = args.next().map_or(9, |r| r.parse().expect("RUNS"));
    let parsed = ParsedBundle::from_scene_file(std::path::Path::new(&path))
        .unwrap_or_else(|e| panic!("{e}"));
    let desc = parsed.desc;
    let triangles: usize = desc.meshes.iter().map(|m| m.triangles.len()).sum();

    let mut still = Vec::new();
    for _ in 0..runs {
        let d = desc.clone();
        let t0 = Instant::now();
        let s = Scene::build(d);
        let _ = s.view(0);
        still.push(t0.elapsed());
    }
    let mut scene = Scene::build(desc.clone());
    let mut frame = Vec::new();
    for f in 0..runs as u32 {
        let t0 = Instant::now();
        scene.set_frame(0, f + 1).expect("a frame of the scene");
        let _ = scene.view(0);
        frame.push(t0.elapsed());
    }
    let (s, f) = (median(still), median(frame));
    println!(
        "{path}: {} meshes, {triangles} triangles, {} models, animated: {}",
        desc.meshes.len(),
        desc.models.len(),
        scene.animated()
    );
    println!(
        "still set-up {:.3} ms, frame set-up {:.3} ms (medians of {runs}); frame/still = {:.4}",
        s.as_secs_f64() * 1e3,
        f.as_secs_f64() * 1e3,
        f.as_secs_f64() / s.as_secs_f64()
    );
}
