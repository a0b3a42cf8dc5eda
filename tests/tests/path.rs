//! Path mode on the farm: a path-traced scene with an area light rendered by
//! a real coordinator and real workers is byte-identical to `trevi-submit`
//! rendering it alone (a pixel is a pure function of the scene and its
//! coordinates in path mode too: Russian roulette and light sampling draw
//! from the pixel's own streams).

mod common;

use common::*;

const SCENE: &str = r#"<scene version="1">
  <settings background="0.05 0.05 0.1"/>
  <mesh id="lamp"><vertices>-0.4 1.9 -0.4  0.4 1.9 -0.4  0.4 1.9 0.4  -0.4 1.9 0.4</vertices>
    <triangles>0 2 1  0 3 2</triangles></mesh>
  <model id="lamp" mesh="lamp"><surface diffuse="0 0 0" emission="6 5 4" sided="front"/></model>
  <sphere id="ball" center="0 0.6 0" radius="0.6">
    <surface diffuse="0.7 0.3 0.2" specular="0.3 0.3 0.3" shininess="40" reflectivity="0.1"/>
  </sphere>
  <sphere id="glass" center="0.9 0.4 0.6" radius="0.4"><surface opacity="0" ior="1.5"/></sphere>
  <plane id="ground" point="0 0 0" normal="0 1 0"><surface diffuse="0.6 0.6 0.6"/></plane>
  <light type="point" position="2 3 3" intensity="4" attenuation="0 0 1"/>
  <camera id="main" position="0 1.2 4" lookat="0 0.6 0" fov="50">
    <render width="48" height="32" supersample="2" jitter="true" integrator="path" max-bounces="8"
            output="main.png"/>
  </camera>
</scene>
"#;

#[test]
fn a_path_traced_frame_on_three_workers_is_byte_identical_to_one_process() {
    let dir = Dir::new();
    let scene = dir.write("scene/s.xml", SCENE);
    let expected = embedded(&dir, &scene, "embedded.png");
    // The mode is in effect: the same scene in Whitted mode differs.
    let whitted = dir.write(
        "scene/w.xml",
        &SCENE.replace(r#"integrator="path""#, r#"integrator="whitted""#),
    );
    assert!(embedded(&dir, &whitted, "whitted.png") != expected);
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let _w: Vec<Proc> = (0..3)
        .map(|i| worker_with(&dir, &c.url, &format!("worker{i}"), &[], &[]))
        .collect();
    assert!(
        farm_render(&dir, &c.url, &scene, "farm.png", 8) == expected,
        "farm output differs\n{}",
        dir.logs()
    );
}
