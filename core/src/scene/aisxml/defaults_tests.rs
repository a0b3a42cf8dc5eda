//! The attribute tables' defaults checked against the reader: for every
//! attribute whose default is a value, a scene that omits it and the same
//! scene that gives the table's default text must parse to the same
//! description. So the default written in a table (and in docs/aisxml.md,
//! which is checked against the tables) and the one the reader fills in
//! cannot drift apart.

use super::table::REQUIRED;
use super::{parse_scene, SceneDesc, ELEMENTS};
use crate::Bundle;
use std::collections::BTreeMap;

/// Attributes whose default is not a value the reader accepts but says
/// what absence means (another attribute's value, something computed, or
/// nothing), with the default text, so that a change of either is seen.
const DESCRIBED: &[(&str, &str, &str)] = &[
    ("camera", "direction", "required unless lookat"),
    ("camera", "lookat", "required unless direction"),
    ("camera", "focus", "|lookat − position|"),
    ("light", "id", "none"),
    ("light", "direction", "required for a spot"),
    ("light", "edge-u", "required for a rect"),
    ("light", "edge-v", "required for a rect"),
    ("light", "emission", "one of emission, power"),
    ("light", "power", "one of emission, power"),
    ("mesh", "file", "none (inline data)"),
    ("render", "output", "<camera id>.png"),
    ("render", "noise-threshold", "none (adaptive sampling off)"),
    ("render", "frames", "none (a still)"),
    ("render", "aovs", "none (no render passes)"),
    ("surface", "ambient", "= diffuse"),
    ("surface", "diffuse-texture", "none"),
    ("surface", "triangles", "none (the model's default surface)"),
];

/// The camera of every scene below but the camera's own.
const CAMERA: &str = r#"<camera id="c" position="0 0 5" lookat="0 0 0" fov="50"><render width="4" height="3"/></camera>"#;

/// A mesh with texture coordinates, for surfaces with a texture.
const MESH: &str = r#"<mesh id="m"><vertices>0 0 0 1 0 0 0 1 0</vertices><uvs>0 0 1 0 0 1</uvs><triangles>0 1 2</triangles></mesh>"#;

/// Scenes holding the element, with `{}` where the attribute under test
/// goes. Each is tried; the table's default must be accepted by at least
/// one, and give what omitting it gives in each that accepts it.
fn contexts(element: &str) -> Vec<String> {
    let scene = |body: &str| format!("<scene version=\"1\">{body}</scene>");
    let with_camera = |body: &str| scene(&format!("{body}{CAMERA}"));
    let render = |attrs: &str| {
        scene(&format!(
            r#"<camera id="c" position="0 0 5" lookat="0 0 0" fov="50"><render width="4" height="3" {attrs} {{}}/></camera>"#
        ))
    };
    match element {
        "settings" => vec![with_camera("<settings {}/>")],
        "mesh" => vec![with_camera(
            r#"<mesh id="m" {}><vertices>0 0 0 1 0 0 0 1 0</vertices><triangles>0 1 2</triangles></mesh><model id="a" mesh="m"/>"#,
        )],
        "surface" => vec![
            with_camera(r#"<sphere id="s" center="0 0 0" radius="1"><surface {}/></sphere>"#),
            with_camera(&format!(
                r#"{MESH}<model id="a" mesh="m"><surface diffuse-texture="t.png" {{}}/></model>"#
            )),
        ],
        "camera" => vec![
            scene(
                r#"<camera id="c" position="0 0 5" lookat="0 0 0" fov="50" {}><render width="4" height="3"/></camera>"#,
            ),
            scene(
                r#"<camera id="c" position="0 0 5" direction="0 0 -1" focus="2" aperture="0.1" fov="50" {}><render width="4" height="3"/></camera>"#,
            ),
        ],
        "render" => vec![
            render(""),
            render(r#"noise-threshold="0.1""#),
            render(r#"integrator="path""#),
            render(r#"frames="0-2" output="c.#.png""#),
        ],
        "light" => vec![
            with_camera(r#"<light position="0 1 0" {}/>"#),
            with_camera(r#"<light type="spot" position="0 1 0" direction="0 -1 0" {}/>"#),
            with_camera(
                r#"<light type="rect" position="0 1 0" edge-u="1 0 0" edge-v="0 0 1" power="1" {}/>"#,
            ),
        ],
        _ => Vec::new(),
    }
}

fn parse(text: &str) -> Result<SceneDesc, crate::SceneError> {
    let mut files = BTreeMap::new();
    files.insert("s.xml".to_string(), text.as_bytes().to_vec());
    files.insert("t.png".to_string(), png_2x2());
    parse_scene(
        "s.xml",
        &Bundle {
            scene: "s.xml".into(),
            files,
        },
    )
}

/// A 2×2 RGB PNG, for the surfaces with a texture.
fn png_2x2() -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, 2, 2);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header().expect("a PNG header");
    w.write_image_data(&[10; 12]).expect("PNG rows");
    w.finish().expect("a PNG");
    out
}

#[test]
fn every_default_in_a_table_is_the_readers() {
    let mut problems = Vec::new();
    let mut checked = 0;
    for e in ELEMENTS {
        for a in e.attributes.iter().filter(|a| a.default != REQUIRED) {
            if let Some(&(_, _, text)) = DESCRIBED
                .iter()
                .find(|&&(el, name, _)| el == e.name && name == a.name)
            {
                if a.default != text {
                    problems.push(format!(
                        "<{}> {}: the default \"{}\" is listed as \"{text}\" here",
                        e.name, a.name, a.default
                    ));
                }
                continue;
            }
            let mut accepted = 0;
            for context in contexts(e.name) {
                let omitted = parse(&context.replace("{}", ""))
                    .unwrap_or_else(|err| panic!("{context}: {err}"));
                let given = format!("{}=\"{}\"", a.name, a.default);
                let Ok(explicit) = parse(&context.replace("{}", &given)) else {
                    continue;
                };
                accepted += 1;
                if explicit != omitted {
                    problems.push(format!(
                        "<{}> {given} (the table's default) does not read as omitting it in {context}",
                        e.name
                    ));
                }
            }
            if accepted == 0 {
                problems.push(format!(
                    "<{}> {}: the table's default \"{}\" is not a value the reader takes here \
                     (list it as described, or give the element a scene above)",
                    e.name, a.name, a.default
                ));
            }
            checked += 1;
        }
    }
    for &(el, name, _) in DESCRIBED {
        let row = ELEMENTS
            .iter()
            .filter(|e| e.name == el)
            .flat_map(|e| e.attributes)
            .find(|a| a.name == name);
        if row.is_none_or(|a| a.default == REQUIRED) {
            problems.push(format!(
                "<{el}> {name} is listed as described, but has no default"
            ));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    // Every default that is a value was checked: camera 3, light 8, mesh 1,
    // render 15, settings 2, surface 11.
    assert_eq!(checked, 40);
}
