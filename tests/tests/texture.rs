//! Textures on the farm: a scene with an image texture (shipped in the
//! bundle, decoded by each worker) rendered by a real coordinator and real
//! workers is byte-identical to `trevi-submit` rendering it alone, through a
//! mirror too (the texture's level of detail follows the reflected ray cone);
//! the workers report the scene's memory (meshes and MIP chains). A textured
//! PLY (per-face `texcoord`) renders its texture. The shipped example (an OBJ
//! with its `.mtl`, a PLY with texcoords) is byte-identical on the farm.

mod common;

use common::*;

const SCENE: &str = r#"<scene version="1">
  <settings background="0.1 0.1 0.15"/>
  <mesh id="quad"><vertices>-2 0 -2  2 0 -2  2 0 2  -2 0 2</vertices>
    <uvs>0 0  1 0  1 1  0 1</uvs><triangles>0 2 1  0 3 2</triangles></mesh>
  <model id="floor" mesh="quad">
    <surface diffuse="1 1 1" diffuse-texture="tex.png" texture-scale="3 3"/>
  </model>
  <sphere id="mirror" center="0.4 0.6 0" radius="0.6">
    <surface diffuse="0.1 0.1 0.1" reflectivity="0.8"/>
  </sphere>
  <light type="point" position="2 3 3" intensity="6" attenuation="0 0 1"/>
  <camera id="main" position="0 1.5 3.5" lookat="0 0.3 0" fov="55">
    <render width="48" height="32" supersample="2" output="main.png"/>
  </camera>
</scene>
"#;

/// A 64 × 64 8-bit RGB checker of 8-texel cells in four colours.
fn texture_png() -> Vec<u8> {
    const COLOURS: [[u8; 3]; 4] = [[230, 40, 30], [20, 180, 60], [30, 60, 220], [240, 220, 40]];
    let mut rgb = Vec::with_capacity(64 * 64 * 3);
    for y in 0..64 {
        for x in 0..64 {
            rgb.extend_from_slice(&COLOURS[(x / 8 + 2 * (y / 8)) % 4]);
        }
    }
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, 64, 64);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header().unwrap();
    w.write_image_data(&rgb).unwrap();
    drop(w);
    out
}

#[test]
fn a_textured_frame_on_three_workers_is_byte_identical_to_one_process() {
    let dir = Dir::new();
    std::fs::create_dir_all(dir.path().join("scene")).unwrap();
    std::fs::write(dir.path().join("scene/tex.png"), texture_png()).unwrap();
    let scene = dir.write("scene/s.xml", SCENE);
    let expected = embedded(&dir, &scene, "embedded.png");
    // The texture is in effect: the same scene without it differs.
    let plain = dir.write(
        "scene/plain.xml",
        &SCENE.replace(r#" diffuse-texture="tex.png" texture-scale="3 3""#, ""),
    );
    assert!(embedded(&dir, &plain, "plain.png") != expected);
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let _w: Vec<Proc> = (0..3)
        .map(|i| worker_with(&dir, &c.url, &format!("worker{i}"), &[], &[]))
        .collect();
    assert!(
        farm_render(&dir, &c.url, &scene, "farm.png", 8) == expected,
        "farm output differs\n{}",
        dir.logs()
    );
    // Each worker that built the scene reports its memory: the quad's
    // arrays (4 positions, 4 normals, 4 uvs of 8 bytes, 2 triangles) and
    // the 64 x 64 texture's MIP chain (64² + 32² + … + 1² texels of 12 bytes).
    let mesh_bytes = 4 * 12 + 4 * 12 + 4 * 8 + 2 * 12;
    let chain: u64 = (0..7).map(|k| (64u64 >> k).pow(2)).sum();
    let line = format!("mesh_bytes={mesh_bytes} texture_bytes={}", chain * 12);
    let built: Vec<String> = (0..3)
        .map(|i| dir.read_log(&format!("worker{i}")))
        .filter(|log| log.contains("scene built"))
        .collect();
    assert!(
        !built.is_empty(),
        "no worker built the scene\n{}",
        dir.logs()
    );
    for log in &built {
        assert!(log.contains(&line), "expected {line:?} in\n{log}");
    }
}

/// The floor of `SCENE` as a PLY whose faces carry `texcoord` lists (the
/// same uv at each corner as the inline mesh's `<uvs>`): the frame is
/// byte-identical to the inline mesh's, and differs without the texture.
#[test]
fn a_ply_with_face_texcoords_renders_as_the_inline_mesh_with_uvs() {
    const PLY: &str = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\n\
        property float y\nproperty float z\nelement face 2\n\
        property list uchar int vertex_indices\nproperty list uchar float texcoord\nend_header\n\
        -2 0 -2\n2 0 -2\n2 0 2\n-2 0 2\n3 0 2 1 6 0 0 1 1 1 0\n3 0 3 2 6 0 0 0 1 1 1\n";
    let dir = Dir::new();
    std::fs::create_dir_all(dir.path().join("scene")).unwrap();
    std::fs::write(dir.path().join("scene/tex.png"), texture_png()).unwrap();
    std::fs::write(dir.path().join("scene/floor.ply"), PLY).unwrap();
    let inline = dir.write("scene/inline.xml", SCENE);
    let (head, rest) = SCENE.split_once("<mesh id=\"quad\">").unwrap();
    let rest = rest.split_once("</mesh>").unwrap().1;
    let ply_scene = format!("{head}<mesh id=\"quad\" file=\"floor.ply\"/>{rest}");
    assert!(ply_scene.contains("floor.ply") && !ply_scene.contains("<uvs>"));
    let ply = dir.write("scene/ply.xml", &ply_scene);
    let from_ply = embedded(&dir, &ply, "ply.png");
    assert!(from_ply == embedded(&dir, &inline, "inline.png"));
    let plain = dir.write(
        "scene/plain.xml",
        &ply_scene.replace(r#" diffuse-texture="tex.png" texture-scale="3 3""#, ""),
    );
    assert!(embedded(&dir, &plain, "plain.png") != from_ply);
}

/// The shipped example `examples/textured.xml`: an OBJ that brings its own
/// `.mtl` with `map_Kd`, a PLY die with per-face `texcoord` lists and an
/// atlas, and an inline floor with `<uvs>`, seen directly and in a mirror.
/// On two workers it is byte-identical to `trevi-submit` alone (at 96 × 54,
/// so the test stays quick), and the OBJ's material is in effect: without
/// the `mtllib` line the frame differs.
#[test]
fn the_textured_example_obj_mtl_and_ply_on_two_workers_is_byte_identical_to_one_process() {
    let dir = Dir::new();
    let examples = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples");
    std::fs::create_dir_all(dir.path().join("scene/meshes")).unwrap();
    for f in [
        "ring.obj",
        "bricks.mtl",
        "brick.png",
        "die.ply",
        "die.png",
        "tiles.png",
    ] {
        std::fs::copy(
            examples.join("meshes").join(f),
            dir.path().join("scene/meshes").join(f),
        )
        .unwrap();
    }
    let xml = std::fs::read_to_string(examples.join("textured.xml")).unwrap();
    let small = xml.replace(r#"width="640" height="360""#, r#"width="96" height="54""#);
    assert!(small != xml, "the example's resolution moved");
    let scene = dir.write("scene/textured.xml", &small);
    let expected = embedded(&dir, &scene, "embedded.png");

    // Without its material library the ring renders in the default grey.
    let obj = std::fs::read_to_string(examples.join("meshes/ring.obj")).unwrap();
    let bare: String = obj
        .lines()
        .filter(|l| !l.starts_with("mtllib") && !l.starts_with("usemtl"))
        .map(|l| format!("{l}\n"))
        .collect();
    assert!(bare.len() < obj.len(), "ring.obj names no material");
    std::fs::create_dir_all(dir.path().join("bare/meshes")).unwrap();
    for f in ["die.ply", "die.png", "tiles.png"] {
        std::fs::copy(
            examples.join("meshes").join(f),
            dir.path().join("bare/meshes").join(f),
        )
        .unwrap();
    }
    std::fs::write(dir.path().join("bare/meshes/ring.obj"), bare).unwrap();
    let no_mtl = dir.write("bare/textured.xml", &small);
    assert!(embedded(&dir, &no_mtl, "bare.png") != expected);

    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let _w: Vec<Proc> = (0..2)
        .map(|i| worker_with(&dir, &c.url, &format!("worker{i}"), &[], &[]))
        .collect();
    assert!(
        farm_render(&dir, &c.url, &scene, "farm.png", 16) == expected,
        "farm output differs\n{}",
        dir.logs()
    );
}
