//! Area lights on the farm: a scene lit by a `<light type="rect">` (and an
//! emitting sphere), in Whitted mode (sampled shadow rays) and in path mode
//! (next-event estimation), rendered by a real coordinator and three real
//! workers is byte-identical to `trevi-submit` rendering it alone: the
//! points sampled on the lights come from each pixel's own streams.

mod common;

use common::*;

const SCENE: &str = r#"<scene version="1">
  <settings background="0.02 0.02 0.05" ambient="0.05 0.05 0.05"/>
  <light id="panel" type="rect" position="0 1.9 0" edge-u="0.8 0 0" edge-v="0 0 0.6"
         power="12" color="1 0.9 0.8" sided="front"/>
  <sphere id="bulb" center="-1.2 1.2 -0.5" radius="0.1"><surface diffuse="0 0 0" emission="8 8 10"/></sphere>
  <sphere id="ball" center="0 0.6 0" radius="0.6">
    <surface diffuse="0.7 0.3 0.2" specular="0.3 0.3 0.3" shininess="40" reflectivity="0.1"/>
  </sphere>
  <sphere id="glass" center="0.9 0.4 0.6" radius="0.4"><surface opacity="0.1" ior="1.5"/></sphere>
  <plane id="ground" point="0 0 0" normal="0 1 0"><surface diffuse="0.6 0.6 0.6"/></plane>
  <camera id="main" position="0 1.2 4" lookat="0 0.8 0" fov="55">
    <render width="40" height="28" supersample="2" jitter="true" shadow-samples="3"
            integrator="MODE" max-bounces="6" output="main.png"/>
  </camera>
</scene>
"#;

#[test]
fn a_rect_lit_frame_on_three_workers_is_byte_identical_to_one_process_in_both_modes() {
    let dir = Dir::new();
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let _w: Vec<Proc> = (0..3)
        .map(|i| worker_with(&dir, &c.url, &format!("worker{i}"), &[], &[]))
        .collect();
    let mut images = Vec::new();
    for mode in ["whitted", "path"] {
        let scene = dir.write(&format!("{mode}/s.xml"), &SCENE.replace("MODE", mode));
        let expected = embedded(&dir, &scene, &format!("{mode}-embedded.png"));
        assert!(
            farm_render(&dir, &c.url, &scene, &format!("{mode}-farm.png"), 8) == expected,
            "{mode}: farm output differs\n{}",
            dir.logs()
        );
        images.push(expected);
    }
    // The modes differ, and the rect light is in effect in Whitted mode
    // (without it the frame is different).
    assert!(images[0] != images[1]);
    let dark = dir.write(
        "dark/s.xml",
        &SCENE
            .replace("MODE", "whitted")
            .replace(r#"power="12""#, r#"power="0""#),
    );
    assert!(embedded(&dir, &dark, "dark.png") != images[0]);
}
