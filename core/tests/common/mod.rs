//! Shared helpers for the core's scene-level tests.
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::path::Path;
use trevi_core::tile::band_order_tiles;
use trevi_core::{render_tile, Bundle, FrameWriter, Rect, Scene};

/// A bundle holding one scene file.
pub fn bundle(xml: &str) -> Bundle {
    let mut files = BTreeMap::new();
    files.insert("scene.xml".to_string(), xml.as_bytes().to_vec());
    Bundle {
        scene: "scene.xml".into(),
        files,
    }
}

pub fn scene(xml: &str) -> Scene {
    match Scene::from_bundle(&bundle(xml)) {
        Ok(s) => s,
        Err(e) => panic!("test scene does not parse: {e}"),
    }
}

/// The whole frame of `camera` as linear RGB, rendered in one tile.
pub fn render(scene: &Scene, camera: usize) -> Vec<[f32; 3]> {
    let r = &scene.desc.cameras[camera].render;
    render_tile(scene, camera, Rect::new(0, 0, r.width, r.height)).pixels
}

/// Renders `camera` tile by tile (band order) into `out` through the
/// FrameWriter, as trevi-submit does.
pub fn render_to_file(scene: &Scene, camera: usize, tile: u32, out: &Path) {
    let r = &scene.desc.cameras[camera].render;
    let mut w = FrameWriter::create(out, r.width, r.height).expect("create output");
    for rect in band_order_tiles(r.width, r.height, tile) {
        let t = render_tile(scene, camera, rect);
        w.write_tile(rect, &t.pixels).expect("write tile");
    }
    w.finish().expect("finish output");
}

/// The spec's camera frame and pinhole direction, computed independently in
/// f64 from the formulas in spec/aisxml.md.
pub struct SpecCamera {
    pub pos: [f64; 3],
    a: [f64; 3],
    b: [f64; 3],
    c: [f64; 3],
    w: f64,
    h: f64,
}

pub fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
pub fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
pub fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}
pub fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
pub fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
pub fn norm(a: [f64; 3]) -> [f64; 3] {
    scale(a, 1.0 / dot(a, a).sqrt())
}

impl SpecCamera {
    // An independent closed form: std is fine here (clippy.toml).
    #[allow(clippy::disallowed_methods)]
    pub fn new(
        pos: [f64; 3],
        dir: [f64; 3],
        up: [f64; 3],
        fov_deg: f64,
        width: u32,
        height: u32,
    ) -> Self {
        let d = norm(dir);
        let w = scale(d, -1.0);
        let u = norm(cross(up, w));
        let v = cross(w, u);
        let (wf, hf) = (width as f64, height as f64);
        let s = 0.5 / (fov_deg.to_radians() / 2.0).tan();
        let a = u;
        let b = scale(v, hf / wf);
        let c = sub(sub(scale(a, -0.5), scale(b, 0.5)), scale(w, s));
        SpecCamera {
            pos,
            a,
            b,
            c,
            w: wf,
            h: hf,
        }
    }

    /// Unit direction through the centre of pixel (column i, row r).
    pub fn dir(&self, i: u32, r: u32) -> [f64; 3] {
        let x = (i as f64 + 0.5) / self.w;
        let y = (self.h - r as f64 - 0.5) / self.h;
        norm(add(add(self.c, scale(self.a, x)), scale(self.b, y)))
    }
}

pub fn assert_close(got: f32, want: f64, rel: f64, what: &str) {
    let err = (got as f64 - want).abs();
    assert!(
        err <= rel * want.abs().max(1e-6),
        "{what}: got {got}, want {want} (relative error {:.3e})",
        err / want.abs().max(1e-12)
    );
}
