//! Scenes without area lights render byte-identically to before area lights
//! reached Whitted mode: the hashes below were computed by this test on the
//! commit before `integrator/area.rs` existed, so a change that alters a
//! Whitted image without emitters fails here. The Cornell hash was pinned
//! again once, when transcendental functions moved from the system's libm to
//! `crate::math` (the same bits on every CPU); the effects scene's bytes did
//! not change then. Both were pinned again for shading that costs less (whole Phong
//! exponents by multiplication, the sine and cosine of sampled angles by
//! polynomial, fewer normalisations per hit: the last bits of pixels move;
//! docs/performance.md, "Third round: shading").

use super::tests::{pixels, scene};
use crate::sampling::mix64;
use crate::scene::aisxml::parse_scene;
use crate::Scene;

/// A hash of every channel's bits, row by row.
fn image_hash(s: &Scene, camera: usize) -> u64 {
    let r = &s.desc.cameras[camera].render;
    let it = crate::integrator::Integrator::observed(
        s,
        camera,
        crate::integrator::RenderOptions::default(),
        &(),
    );
    let mut h = 0x5eed_u64;
    for y in 0..r.height {
        for x in 0..r.width {
            for c in it.pixel(x, y).unwrap().0 {
                h = mix64(h ^ u64::from(c.to_bits()));
            }
        }
    }
    h
}

/// examples/cornell.xml (soft shadows, AO, glass, mirror), both cameras,
/// shrunk to 40 pixels wide.
#[test]
fn the_cornell_example_without_area_lights_keeps_its_bytes() {
    let dir = crate::bundle::DirSource {
        root: concat!(env!("CARGO_MANIFEST_DIR"), "/../examples").into(),
    };
    let mut desc = parse_scene("cornell.xml", &dir).expect("example parses");
    for cam in &mut desc.cameras {
        cam.render.height = cam.render.height * 40 / cam.render.width;
        cam.render.width = 40;
    }
    let s = Scene::build(desc);
    let got = [image_hash(&s, 0), image_hash(&s, 1)];
    assert_eq!(got, PINNED_CORNELL, "{got:#x?}");
}

/// Every Whitted effect on one small scene: diffuse gather two levels deep,
/// AO, soft shadows from a spot, Phong specular, glass and a mirror.
#[test]
fn a_scene_with_every_whitted_effect_and_no_emitter_keeps_its_bytes() {
    let s = scene(
        r#"<scene version="1"><settings background="0.1 0.2 0.3" ambient="0.2 0.2 0.2"/>
  <plane id="floor" point="0 0 0" normal="0 1 0"><surface diffuse="0.7 0.6 0.5" specular="0.3 0.3 0.3" shininess="20"/></plane>
  <plane id="wall" point="0 0 -3" normal="0 0 1"><surface diffuse="0.2 0.5 0.8"/></plane>
  <sphere id="g" center="0.6 0.5 -1" radius="0.5"><surface opacity="0.2" ior="1.5" reflectivity="0.1"/></sphere>
  <sphere id="m" center="-0.7 0.4 -1.5" radius="0.4"><surface reflectivity="0.8" diffuse="0.5 0.1 0.1"/></sphere>
  <light position="1 3 1" color="1 0.9 0.8" intensity="2" radius="0.3" attenuation="0.5 0.1 0.1"/>
  <light type="spot" position="-1 3 0" direction="0.2 -1 -0.3" radius="0.2" inner="15" outer="35"/>
  <camera id="c" position="0 1.2 2.5" lookat="0 0.4 -1" fov="55">
    <render width="24" height="18" supersample="2" jitter="true" shadow-samples="3"
            ao-samples="2" diffuse-samples="2" diffuse-depth="2" max-depth="4"/></camera></scene>"#,
    );
    let got = image_hash(&s, 0);
    assert_eq!(got, PINNED_EFFECTS, "{got:#x}");
    // The image is not trivially black (the hash would then pin little).
    assert!(pixels(&s).iter().any(|p| p[0] > 0.05));
}

const PINNED_CORNELL: [u64; 2] = [0x6dd2_d09c_0312_425d, 0xbb2e_7e31_11b0_de04];
const PINNED_EFFECTS: u64 = 0x1819_79cb_45de_9656;
