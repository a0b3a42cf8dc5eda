//! The closest-hit tie rule (`View::precedes`, docs/performance.md): of
//! hits at the same distance, the earlier model in the document wins, then
//! the earlier triangle of the mesh as loaded, whatever the order in which
//! the trees are built and walked.

mod common;
use common::*;
use glam::Vec3;
use trevi_core::world::HitKind;

/// A mesh of `n` triangles where triangles `i` and `j` are the same
/// triangle (the unit one in the z = 0 plane) and the others lie apart (in
/// z = 5..), so the tree puts them in varying places; two (or three)
/// models of it in the same place, the first with triangle
/// `min(i, j)` red, every other triangle of every model green.
fn tie_scene(n: usize, i: usize, j: usize, models: usize) -> String {
    let mut v = String::new();
    let mut t = String::new();
    for k in 0..n {
        let base = 3 * k;
        let (x, y, z) = if k == i || k == j {
            (0.0, 0.0, 0.0)
        } else {
            (
                (k % 7) as f32 * 1.5,
                (k / 7) as f32 * 1.5,
                5.0 + k as f32 * 0.25,
            )
        };
        v.push_str(&format!(
            "{x} {y} {z}  {} {y} {z}  {x} {} {z}  ",
            x + 1.0,
            y + 1.0
        ));
        t.push_str(&format!("{} {} {}  ", base, base + 1, base + 2));
    }
    let mut xml = format!(
        "<scene version=\"1\">\n<mesh id=\"m\"><vertices>{v}</vertices><triangles>{t}</triangles></mesh>\n"
    );
    for m in 0..models {
        let red = if m == 0 {
            format!("<surface triangles=\"{}\" diffuse=\"1 0 0\"/>", i.min(j))
        } else {
            String::new()
        };
        xml.push_str(&format!(
            "<model id=\"m{m}\" mesh=\"m\"><surface diffuse=\"0 1 0\"/>{red}</model>\n"
        ));
    }
    xml.push_str(
        "<camera id=\"c\" position=\"0 0 9\" lookat=\"0 0 0\" up=\"0 1 0\" fov=\"40\">\
         <render width=\"2\" height=\"2\"/></camera>\n</scene>\n",
    );
    xml
}

#[test]
fn equal_distances_go_to_the_first_model_and_the_first_triangle_as_loaded() {
    let mut checked = 0;
    for (n, i, j) in [
        (2, 0, 1),
        (2, 1, 0),
        (9, 3, 7),
        (9, 7, 3),
        (40, 0, 39),
        (40, 21, 2),
    ] {
        for models in [2, 3] {
            let scene = scene(&tie_scene(n, i, j, models));
            let view = scene.world_view();
            // Rays from both sides and from many directions (the near/far
            // order of every node flips with the direction's signs).
            for k in 0..64 {
                let u = 0.05 + 0.6 * ((k * 37 % 64) as f32 / 64.0);
                let w = 0.05 + 0.3 * ((k * 11 % 64) as f32 / 64.0);
                let target = Vec3::new(u, w, 0.0);
                for side in [1.0f32, -1.0] {
                    let o =
                        target + Vec3::new((k % 5) as f32 - 2.0, (k % 3) as f32 - 1.0, 3.0 * side);
                    let d = target - o;
                    let h = view
                        .intersect(o, d, f32::INFINITY)
                        .expect("the ray aims at the tied triangles");
                    assert!(
                        matches!(h.kind, HitKind::Triangle { instance: 0, .. }),
                        "{n} {i} {j} {models}: {h:?}"
                    );
                    let s = view.surface_point(o, d, &h);
                    assert_eq!(
                        s.surface.diffuse,
                        Vec3::new(1.0, 0.0, 0.0),
                        "{n} {i} {j} {models}: not the first triangle as loaded"
                    );
                    checked += 1;
                }
            }
        }
    }
    assert_eq!(checked, 6 * 2 * 64 * 2);
}
