//! Tests of the scene format's bounds and references: references from a subfolder
//! resolved against it, outputs of different cameras that would write one
//! file, `fps` too small for 32 bits, a camera id with `#`, rect lights too
//! large to render, and the `.mtl` libraries parsed once per scene.

use super::parse_scene;
use crate::error::SceneErrorKind;
use crate::scene::SceneDesc;
use crate::testing::assert_error_at;
use crate::Bundle;
use std::collections::BTreeMap;

fn bundle(scene: &str, files: &[(&str, &[u8])]) -> Bundle {
    let mut map = BTreeMap::new();
    map.insert("s.xml".to_string(), scene.as_bytes().to_vec());
    for (n, b) in files {
        map.insert(n.to_string(), b.to_vec());
    }
    Bundle {
        scene: "s.xml".into(),
        files: map,
    }
}

fn parse(scene: &str, files: &[(&str, &[u8])]) -> super::Result<SceneDesc> {
    parse_scene("s.xml", &bundle(scene, files))
}

const CAM: &str = r#"<camera id="c" position="0 0 5" lookat="0 0 0" fov="50"><render width="4" height="3"/></camera>"#;

/// A scene of `cameras`, each on its own line from line 2.
fn cameras(cameras: &[&str]) -> String {
    format!("<scene version=\"1\">\n{}\n</scene>\n", cameras.join("\n"))
}

fn cam(id: &str, render: &str) -> String {
    format!(
        r#"<camera id="{id}" position="0 0 5" lookat="0 0 0" fov="50"><render width="4" height="3" {render}/></camera>"#
    )
}

const QUAD_OBJ: &str = "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
                        f 1/1 2/2 3/3 4/4\n";

/// Regression: `models/x.obj` naming `../materials/x.mtl`, which names
/// `../textures/x.png`, was refused as climbing out although every file is
/// inside the scene's directory (the layout exporters write). Read from a
/// directory as `trevi-submit` collects a bundle, and rendered: the quad
/// shows the texture's red.
#[test]
fn references_from_a_subfolder_resolve_against_it_and_render() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path();
    for d in ["models", "materials", "textures"] {
        std::fs::create_dir(p.join(d)).unwrap();
    }
    let obj = format!("mtllib ../materials/x.mtl\nusemtl red\n{QUAD_OBJ}");
    std::fs::write(p.join("models/x.obj"), obj).unwrap();
    std::fs::write(
        p.join("materials/x.mtl"),
        "newmtl red\nKs 0 0 0\nmap_Kd ../textures/x.png\n",
    )
    .unwrap();
    let png = crate::texture::tests::png_rgb8(1, 1, &[255, 0, 0]);
    std::fs::write(p.join("textures/x.png"), &png).unwrap();
    let scene = r#"<scene version="1"><settings background="0 0 0"/>
<mesh id="m" file="models/x.obj"/><model id="a" mesh="m"/><light position="0 0 3"/>
<camera id="c" position="0 0 3" lookat="0 0 0" fov="30"><render width="4" height="4"/></camera></scene>"#;
    std::fs::write(p.join("s.xml"), scene).unwrap();
    let parsed = crate::ParsedBundle::from_scene_file(&p.join("s.xml")).unwrap();
    let files: Vec<&str> = parsed.bundle.files.keys().map(String::as_str).collect();
    assert_eq!(
        files,
        ["materials/x.mtl", "models/x.obj", "s.xml", "textures/x.png"]
    );
    let scene = crate::Scene::build(parsed.desc);
    let tile = crate::tile::render_tile(&scene, 0, crate::tile::Rect::new(0, 0, 4, 4));
    for px in &tile.pixels {
        assert!(px[0] > 0.1 && px[1] == 0.0 && px[2] == 0.0, "{px:?}");
    }

    // The same bundle decoded (what a worker parses) gives the same files.
    let again = crate::ParsedBundle::parse(parsed.bundle.clone()).unwrap();
    assert_eq!(
        again.desc.files,
        vec!["materials/x.mtl", "models/x.obj", "textures/x.png"]
    );
}

/// What really leaves the scene's directory is still refused, at the
/// line and column of the reference.
#[test]
fn references_that_climb_out_of_the_scene_directory_are_refused() {
    let png = crate::texture::tests::png_rgb8(1, 1, &[255, 0, 0]);
    let scene = format!(
        "<scene version=\"1\"><mesh id=\"m\" file=\"models/x.obj\"/><model id=\"a\" mesh=\"m\"/>{CAM}</scene>"
    );
    let obj = format!("mtllib ../../x.mtl\nusemtl red\n{QUAD_OBJ}");
    let e = parse(&scene, &[("models/x.obj", obj.as_bytes())]).unwrap_err();
    assert_eq!(e.kind, SceneErrorKind::Reference, "{e}");
    assert_eq!(
        (e.location.file.as_str(), e.location.line, e.location.column),
        ("models/x.obj", 1, 8),
        "{e}"
    );
    assert!(e.message.contains("\"../../x.mtl\" climbs out"), "{e}");
    let obj = format!("mtllib x.mtl\nusemtl red\n{QUAD_OBJ}");
    let e = parse(
        &scene,
        &[
            ("models/x.obj", obj.as_bytes()),
            ("models/x.mtl", b"newmtl red\nmap_Kd ../../t.png\n"),
            ("t.png", &png),
        ],
    )
    .unwrap_err();
    assert_eq!(
        (e.location.file.as_str(), e.location.line, e.location.column),
        ("models/x.mtl", 2, 8),
        "{e}"
    );
    assert!(e.message.contains("climbs out"), "{e}");
}

/// Regression: an `.mtl` named by many meshes and many times on one `mtllib`
/// line is read and parsed once; its materials are shared.
#[test]
fn a_library_named_many_times_is_read_once() {
    struct Counting<'a>(&'a Bundle, std::sync::Mutex<BTreeMap<String, usize>>);
    impl crate::scene::source::FileSource for Counting<'_> {
        fn read(&self, rel: &str) -> std::io::Result<Vec<u8>> {
            *self.1.lock().unwrap().entry(rel.to_string()).or_default() += 1;
            self.0.read(rel)
        }
    }
    let mut scene = String::from("<scene version=\"1\">");
    for k in 0..20 {
        scene.push_str(&format!(
            "<mesh id=\"m{k}\" file=\"x.obj\"/><model id=\"a{k}\" mesh=\"m{k}\"/>"
        ));
    }
    scene.push_str(CAM);
    scene.push_str("</scene>");
    let obj = format!("mtllib{}\nusemtl red\n{QUAD_OBJ}", " m.mtl".repeat(1000));
    let b = bundle(
        &scene,
        &[
            ("x.obj", obj.as_bytes()),
            ("m.mtl", b"newmtl red\nKd 1 0 0\n"),
        ],
    );
    let counting = Counting(&b, Default::default());
    let d = parse_scene("s.xml", &counting).unwrap();
    assert_eq!(d.models.len(), 20);
    assert_eq!(d.models[19].surfaces[1].diffuse, glam::Vec3::X);
    assert_eq!(counting.1.lock().unwrap().get("m.mtl"), Some(&1));
}

/// Regression: `x.#.png` and `x.##.png` both write `x.10.png`; a still
/// `x.10.png` is frame 10 of `x.#.png`. Refused at the second `<render>`'s
/// output, naming the file and the first.
#[test]
fn outputs_that_write_one_file_are_refused_where_the_second_is() {
    let col = |line: &str| line.find("output=").unwrap() as u32 + 1;
    let a = cam("a", r#"frames="1-20" output="x.#.png""#);
    let b = cam("b", r#"frames="5-30" output="x.##.png""#);
    assert_error_at(
        parse(&cameras(&[&a, &b]), &[]),
        "s.xml",
        3,
        col(&b),
        "output \"x.##.png\" writes \"x.10.png\", which the <render> at 2:",
    );
    let still = cam("s", r#"output="x.10.png""#);
    assert_error_at(
        parse(&cameras(&[&a, &still]), &[]),
        "s.xml",
        3,
        col(&still),
        "writes \"x.10.png\"",
    );
    assert_error_at(
        parse(&cameras(&[&still, &a]), &[]),
        "s.xml",
        3,
        col(&a),
        "writes \"x.10.png\"",
    );
    // The default output of a camera: c.####.png for a sequence.
    let c = cam("c", r#"frames="0-9999999""#);
    let d = cam("d", r#"output="c.0042.png""#);
    assert!(parse(&cameras(&[&c, &d]), &[])
        .unwrap_err()
        .message
        .contains("writes \"c.0042.png\""));
    // Ranges that do not meet, and other folders, are fine.
    let e = cam("e", r#"frames="1-9" output="x.#.png""#);
    let f = cam(
        "f",
        r#"frames="10-99" output="x.#.png""#.replace("x.#", "y.#").as_str(),
    );
    let g = cam("g", r#"frames="10-99" output="x.##.png""#);
    let h = cam("h", r#"frames="0-9999999" output="sub/x.#.png""#);
    parse(&cameras(&[&e, &f, &g, &h]), &[]).unwrap();
}

/// Regression: a run of `#` is bounded (the names are compared as numbers).
#[test]
fn a_pattern_run_is_bounded() {
    let long = format!(r#"frames="1-2" output="x.{}.png""#, "#".repeat(33));
    let c = cam("c", &long);
    assert_error_at(
        parse(&cameras(&[&c]), &[]),
        "s.xml",
        2,
        c.find("output=").unwrap() as u32 + 1,
        "at most 32 #",
    );
    let ok = cam(
        "c",
        &format!(r#"frames="1-2" output="x.{}.png""#, "#".repeat(32)),
    );
    parse(&cameras(&[&ok]), &[]).unwrap();
}

/// Regression: `fps="1e-300"` was refused as "not > 0".
#[test]
fn an_fps_too_small_for_32_bits_says_so() {
    let c = cam("c", r#"frames="1-2" fps="1e-300""#);
    let e = parse(&cameras(&[&c]), &[]).unwrap_err();
    assert_error_at::<()>(
        Err(e.clone()),
        "s.xml",
        2,
        c.find("fps=").unwrap() as u32 + 1,
        "fps 1e-300 is too small (expected at least 1.1754944e-38",
    );
    assert!(!e.message.contains("> 0"), "{e}");
    let c = cam("c", r#"frames="1-2" fps="1e-30""#);
    let d = parse(&cameras(&[&c]), &[]).unwrap();
    assert_eq!(d.cameras[0].render.fps, f64::from(1e-30f32));
    let c = cam("c", r#"frames="1-2" fps="-1""#);
    assert!(parse(&cameras(&[&c]), &[])
        .unwrap_err()
        .message
        .contains("> 0"));
}

/// Regression: a camera id with `#` failed later, without a place.
#[test]
fn a_camera_id_with_a_hash_is_refused_at_the_id() {
    for render in ["", r#"frames="1-3""#] {
        let c = cam("a#b", render);
        assert_error_at(
            parse(&cameras(&[&c]), &[]),
            "s.xml",
            2,
            c.find("id=").unwrap() as u32 + 1,
            "the camera id \"a#b\" contains #",
        );
    }
    // With an explicit output, the id is only a name.
    let c = cam("a#b", r#"output="x.png""#);
    parse(&cameras(&[&c]), &[]).unwrap();
}

/// A scene lit only by a rect light of square edges `edge` at height
/// `edge`, above a grey plane, path traced; the mean of its pixels.
fn lit_by_a_rect_of(edge: &str) -> super::Result<f32> {
    let scene = format!(
        r#"<scene version="1"><settings background="0 0 0" ambient="0 0 0"/>
<light type="rect" position="0 {edge} 0" edge-u="{edge} 0 0" edge-v="0 0 {edge}" emission="1 1 1"/>
<plane id="floor" point="0 0 0" normal="0 1 0"><surface diffuse="0.8 0.8 0.8" specular="0 0 0"/></plane>
<camera id="c" position="0 {edge} -{edge}" lookat="0 0 0" fov="40"><render width="4" height="4" supersample="4" integrator="path"/></camera></scene>"#
    );
    let d = parse(&scene, &[])?;
    let s = crate::Scene::build(d);
    let t = crate::tile::render_tile(&s, 0, crate::tile::Rect::new(0, 0, 4, 4));
    Ok(t.pixels.iter().map(|p| p[0] + p[1] + p[2]).sum::<f32>() / 48.0)
}

/// Regression: a rect light with edges of 1e18 vanished without an error
/// (its area's square overflowed 32 bits). Past `MAX_RECT_EDGE` it is
/// refused at the edge; at the bound it lights the scene as a small one
/// does at its own scale.
#[test]
fn rect_lights_too_large_to_render_are_refused_at_the_edge() {
    let e = lit_by_a_rect_of("1e18").unwrap_err();
    assert_eq!(e.kind, SceneErrorKind::Limit, "{e}");
    assert_eq!((e.location.line, e.location.column), (2, 40), "{e}");
    assert!(e.message.contains("at most 1e9 long"), "{e}");
    let small = lit_by_a_rect_of("1").unwrap();
    let large = lit_by_a_rect_of("1e9").unwrap();
    assert!(small > 0.01, "{small}");
    assert!((large / small - 1.0).abs() < 0.2, "{large} vs {small}");
}
