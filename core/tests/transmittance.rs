//! Shadow-ray transmittance against the spec: vis is the
//! product of (1 − α) over every crossing of a surface between the point and
//! the light, so a ray through a closed translucent object (a sphere, a
//! closed mesh) counts two, a ray from inside one counts one, a plane one.
//! Each case is checked against its closed form, for every primitive.

mod common;
use common::*;
use glam::Vec3;
use trevi_core::Scene;

/// Transmittance of the segment from `p` to `light` in world space, the way
/// the integrator asks for it (the direction spans the segment).
fn vis(s: &Scene, p: Vec3, light: Vec3) -> f32 {
    s.transmittance(p, light - p, 1.0 - 1e-6)
}

fn close(got: f32, want: f32, what: &str) {
    assert!((got - want).abs() < 1e-6, "{what}: {got}, expected {want}");
}

const CAMERA: &str = r#"<camera id="c" position="0 1 0" direction="0 -1 0" up="0 0 -1" fov="10">
    <render width="1" height="1"/></camera>"#;

/// A unit cube as a closed mesh (12 triangles, outward winding).
const CUBE: &str = r#"<mesh id="cube">
    <vertices>0 0 0  1 0 0  1 1 0  0 1 0  0 0 1  1 0 1  1 1 1  0 1 1</vertices>
    <triangles>0 2 1 0 3 2  4 5 6 4 6 7  0 1 5 0 5 4  3 7 6 3 6 2  0 4 7 0 7 3  1 2 6 1 6 5</triangles>
  </mesh>"#;

fn scene_with(objects: &str) -> Scene {
    scene(&format!(
        r#"<scene version="1">{CUBE}{objects}<light position="0 10 0"/>{CAMERA}</scene>"#
    ))
}

#[test]
fn a_translucent_sphere_counts_two_crossings_below_it_and_one_inside() {
    let a = 0.6f32;
    let s = scene_with(&format!(
        r#"<sphere id="g" center="0 3 0" radius="1"><surface opacity="{a}"/></sphere>"#
    ));
    let light = Vec3::new(0.0, 10.0, 0.0);
    close(
        vis(&s, Vec3::new(0.0, 0.0, 0.0), light),
        (1.0 - a) * (1.0 - a),
        "under",
    );
    close(
        vis(&s, Vec3::new(0.3, 1.5, -0.2), light),
        (1.0 - a) * (1.0 - a),
        "under, off-centre",
    );
    close(vis(&s, Vec3::new(0.0, 3.0, 0.0), light), 1.0 - a, "inside");
    close(
        vis(&s, Vec3::new(0.2, 2.5, 0.1), light),
        1.0 - a,
        "inside, off-centre",
    );
    close(vis(&s, Vec3::new(0.0, 5.0, 0.0), light), 1.0, "above");
    close(
        vis(&s, Vec3::new(3.0, 0.0, 0.0), Vec3::new(3.0, 10.0, 0.0)),
        1.0,
        "beside",
    );
    // The light inside the sphere: one crossing, on the way in.
    close(
        vis(&s, Vec3::ZERO, Vec3::new(0.0, 3.0, 0.0)),
        1.0 - a,
        "light inside",
    );
}

#[test]
fn a_front_sided_sphere_is_crossed_only_where_the_ray_enters() {
    let s = scene_with(
        r#"<sphere id="g" center="0 3 0" radius="1"><surface opacity="0.25" sided="front"/></sphere>"#,
    );
    let light = Vec3::new(0.0, 10.0, 0.0);
    close(vis(&s, Vec3::ZERO, light), 0.75, "under");
    close(
        vis(&s, Vec3::new(0.0, 3.0, 0.0), light),
        1.0,
        "inside (only back faces ahead)",
    );
}

#[test]
fn a_translucent_plane_counts_once() {
    let s = scene_with(
        r#"<plane id="p" point="0 5 0" normal="0 1 0"><surface opacity="0.3"/></plane>"#,
    );
    close(vis(&s, Vec3::ZERO, Vec3::new(0.0, 10.0, 0.0)), 0.7, "under");
    close(
        vis(&s, Vec3::new(4.0, 0.0, -7.0), Vec3::new(0.0, 10.0, 0.0)),
        0.7,
        "slanted",
    );
    close(
        vis(&s, Vec3::new(0.0, 6.0, 0.0), Vec3::new(0.0, 10.0, 0.0)),
        1.0,
        "above",
    );
}

#[test]
fn a_closed_translucent_mesh_counts_two_crossings_below_it_and_one_inside() {
    let a = 0.5f32;
    // The cube scaled to 2×2×2 around (0, 3, 0), as a model with a transform.
    let s = scene_with(&format!(
        r#"<model id="m" mesh="cube"><transform><translate v="-0.5 -0.5 -0.5"/><scale v="2"/>
           <translate v="0 3 0"/></transform><surface opacity="{a}"/></model>"#
    ));
    let light = Vec3::new(0.0, 10.0, 0.0);
    // Off the cube's diagonals so that no ray meets an edge.
    let under = Vec3::new(0.3, 0.0, -0.2);
    close(
        vis(&s, under, light + under),
        (1.0 - a) * (1.0 - a),
        "under",
    );
    close(vis(&s, Vec3::new(0.3, 3.0, -0.2), light), 1.0 - a, "inside");
    close(
        vis(&s, Vec3::new(5.0, 0.0, 0.0), Vec3::new(5.0, 10.0, 0.0)),
        1.0,
        "beside",
    );
}

#[test]
fn every_crossing_of_every_primitive_multiplies() {
    let s = scene_with(
        r#"<sphere id="g" center="0 3 0" radius="1"><surface opacity="0.5"/></sphere>
           <plane id="p" point="0 6 0" normal="0 -1 0"><surface opacity="0.2"/></plane>
           <model id="m" mesh="cube"><transform><translate v="-0.5 7 -0.5"/></transform>
             <surface opacity="0.1"/></model>"#,
    );
    let p = Vec3::new(0.05, 0.0, 0.07);
    let want = 0.5 * 0.5 * 0.8 * 0.9 * 0.9;
    close(vis(&s, p, p + Vec3::new(0.0, 10.0, 0.0)), want, "all");
}

/// A rendered pixel: the plane point under the sphere, lit straight from
/// above, is kd · E · (1 − α)² (counting only one of the sphere's two
/// surfaces would give kd · E · (1 − α): 0.2 instead of 0.08).
#[test]
fn the_pixel_under_a_glass_sphere_has_the_spec_value() {
    let s = scene(&format!(
        r#"<scene version="1">
  <plane id="floor" point="0 0 0" normal="0 1 0"><surface diffuse="0.5 0.5 0.5"/></plane>
  <sphere id="g" center="0 3 0" radius="1"><surface opacity="0.6" ior="1.5"/></sphere>
  <light position="0 10 0"/>
  {CAMERA}
</scene>"#
    ));
    let px = render(&s, 0)[0];
    for c in px {
        assert!(
            (c - 0.08).abs() < 1e-6,
            "{px:?}, expected 0.08 (0.5 · 0.4²)"
        );
    }
}
