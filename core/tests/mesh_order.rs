//! `Scene::build` renumbers every mesh in its BVH's leaf order: the
//! triangles, their vertices and the model's per-triangle surfaces must move
//! together, so that each triangle the scene file numbers still shows the
//! surface the file gives it.

mod common;
use common::*;
use glam::Vec3;

#[test]
fn per_triangle_surfaces_follow_their_triangles_through_the_reordering() {
    // A row of 64 unit squares in the plane y = 0, two triangles each, listed
    // right to left so that the leaf order differs from the file's order.
    let n = 64;
    let mut vertices = String::new();
    let mut triangles = String::new();
    for k in 0..n {
        let x = (n - 1 - k) as f32;
        for (dx, dz) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
            vertices += &format!("{} 0 {}  ", x + dx, dz);
        }
        let v = 4 * k;
        triangles += &format!("{} {} {}  {} {} {}  ", v, v + 2, v + 1, v, v + 3, v + 2);
    }
    // Triangle t gets diffuse (t / 256, 0.5, 0.25).
    let surfaces: String = (0..2 * n)
        .map(|t| {
            format!(
                r#"<surface triangles="{t}" diffuse="{} 0.5 0.25"/>"#,
                t as f32 / 256.0
            )
        })
        .collect();
    let xml = format!(
        r#"<scene version="1">
  <mesh id="row"><vertices>{vertices}</vertices><triangles>{triangles}</triangles></mesh>
  <model id="m" mesh="row"><surface/>{surfaces}</model>
  <camera id="c" position="0 5 0" lookat="0 0 0.5" fov="40"><render width="4" height="4"/></camera>
</scene>"#
    );
    let s = scene(&xml);
    assert_ne!(
        s.desc.meshes[0].triangles[0],
        [0, 2, 1],
        "the test needs a mesh that the build reorders"
    );
    for k in 0..n {
        let x = (n - 1 - k) as f32;
        // Inside the square's first triangle (v, v+2, v+1: below the
        // diagonal, z < x-offset) and its second (above it).
        for (half, (dx, dz)) in [(0.7f32, 0.2f32), (0.2, 0.7)].into_iter().enumerate() {
            let o = Vec3::new(x + dx, 1.0, dz);
            let d = Vec3::new(0.0, -1.0, 0.0);
            let hit = s.intersect(o, d, f32::INFINITY).expect("the row is hit");
            let sp = s.surface_point(o, d, &hit);
            let t = 2 * k + half;
            assert_eq!(
                sp.surface.diffuse,
                Vec3::new(t as f32 / 256.0, 0.5, 0.25),
                "square {k}, triangle {t}"
            );
            assert!((sp.p - Vec3::new(x + dx, 0.0, dz)).length() < 1e-5);
        }
    }
}
