//! Tests of the AISXML parser: a full scene resolving correctly, then one
//! test per error class, each checking the exact line and column and that the
//! message says what was expected.

use super::*;
use crate::scene::*;
use crate::Bundle;
use glam::{DMat4, DVec4, Vec3};
use std::collections::BTreeMap;

const CAM: &str = r#"<camera id="c" position="0 0 5" lookat="0 0 0" fov="50"><render width="4" height="3"/></camera>"#;
const MESH_Q: &str = r#"<mesh id="q"><vertices>0 0 0 1 0 0 0 1 0 1 1 0</vertices><triangles>0 1 2 1 3 2</triangles></mesh>"#;

/// A scene with `body` on line 2 (and on), followed by a valid camera.
fn doc(body: &str) -> String {
    format!("<scene version=\"1\">\n{body}\n{CAM}\n</scene>\n")
}

/// A scene with the two-triangle mesh "q" on line 2 and `body` on line 3.
fn doc_q(body: &str) -> String {
    doc(&format!("{MESH_Q}\n{body}"))
}

fn bundle_with(text: &str, files: &[(&str, &[u8])]) -> Bundle {
    let mut map = BTreeMap::new();
    map.insert("scene.xml".to_string(), text.as_bytes().to_vec());
    for (name, data) in files {
        map.insert(name.to_string(), data.to_vec());
    }
    Bundle {
        scene: "scene.xml".into(),
        files: map,
    }
}

fn parse(text: &str) -> Result<SceneDesc> {
    parse_scene("scene.xml", &bundle_with(text, &[]))
}

/// Asserts that `text` fails at `line:col` with a message containing every
/// one of `needles`.
#[track_caller]
fn check(text: &str, line: u32, col: u32, needles: &[&str]) {
    let e = match parse(text) {
        Ok(_) => panic!("expected an error at {line}:{col}, the scene parsed:\n{text}"),
        Err(e) => e,
    };
    assert_eq!(e.location.file, "scene.xml", "{e}");
    assert_eq!(
        (e.location.line, e.location.column),
        (line, col),
        "wrong location for: {e}"
    );
    for n in needles {
        assert!(e.message.contains(n), "message of `{e}` lacks `{n}`");
    }
}

fn close(a: Vec3, b: Vec3) -> bool {
    (a - b).length() < 1e-5
}

const FULL: &str = r#"<?xml version="1.0" encoding="UTF-8"?>
<!-- The spec's example, with inline meshes only. -->
<scene version="1">
  <settings background="0.1 0.2 0.3" ambient="0.1 0.1 0.1"/>
  <mesh id="quad">
    <vertices>0 0 0  1 0 0  1 0 1  0 0 1</vertices>
    <normals>0 1 0  0 1 0  0 1 0  0 1 0</normals>   <!-- optional -->
    <triangles>0 2 1  0 3 2</triangles>
  </mesh>
  <mesh id="tri" invert="true">
    <vertices><![CDATA[0 0 0  1 0 0]]>  &#48; 1 0</vertices>
    <triangles>0 1 2</triangles>
  </mesh>
  <model id="floor" mesh="quad">
    <transform>
      <scale v="10 1 10"/>
      <rotate axis="0 1 0" angle="30"/>
      <translate v="-5 0 -5"/>
    </transform>
    <surface diffuse="0.8 0.8 0.8"/>                       <!-- default surface -->
    <surface triangles="1" diffuse="0.7 0.1 0.1" specular="0.5 0.5 0.5"
             shininess="64" reflectivity="0.2" smooth="false"/>
  </model>
  <model id="t" mesh="tri"/>
  <sphere id="ball" center="0 1 0" radius="1"> <surface reflectivity="0.9"/> </sphere>
  <plane id="ground" point="0 0 0" normal="0 2 0"> <surface diffuse="0.5 0.5 0.5" sided="front"/> </plane>
  <light type="point" position="0 5 0"/>
  <light type="spot" position="3 5 3" direction="-1 -1 -1" inner="15" outer="25" color="1 0.9 0.8"/>
  <camera id="main" position="0 2 8" lookat="0 2 0" fov="50">
    <render width="300" height="200" supersample="2"/>
  </camera>
  <camera id="dof" position="0 0 0" direction="0 0 -2" fov="40" aperture="0.1" focus="3" lens="disk">
    <render width="10" height="10" output="out/dof.EXR" noise-threshold="0.01" jitter="1"
            seed="18446744073709551615" ao-distance="2" max-depth="0" ao-samples="3"/>
  </camera>
</scene>
"#;

// An independent closed form: std is fine here (clippy.toml).
#[allow(clippy::disallowed_methods)]
#[test]
fn full_scene_resolves_with_defaults() {
    let s = parse(FULL).unwrap();
    assert_eq!(s.settings.background, Vec3::new(0.1, 0.2, 0.3));
    assert_eq!(s.settings.ambient, Vec3::splat(0.1));
    assert_eq!(s.meshes.len(), 2);
    assert!(s.files.is_empty());

    // Given normals are kept; computed ones are smooth, then inverted.
    let quad = &s.meshes[0];
    assert_eq!(quad.triangles, vec![[0, 2, 1], [0, 3, 2]]);
    assert_eq!(quad.normals, vec![Vec3::Y; 4]);
    let tri = &s.meshes[1];
    assert_eq!(tri.positions[2], Vec3::new(0.0, 1.0, 0.0));
    assert_eq!(
        tri.triangles,
        vec![[0, 2, 1]],
        "invert reverses the winding"
    );
    for n in &tri.normals {
        assert!(close(*n, -Vec3::Z), "smooth normal +z, inverted: {n}");
    }

    // Transform order: scale, then rotate 30° about +y, then translate.
    let floor = &s.models[0];
    assert_eq!(floor.mesh, 0);
    let p = floor.transform * DVec4::new(1.0, 0.0, 0.0, 1.0);
    let c = 30f64.to_radians().cos() * 10.0;
    let z = -30f64.to_radians().sin() * 10.0;
    assert!(
        (p - DVec4::new(c - 5.0, 0.0, z - 5.0, 1.0)).length() < 1e-9,
        "{p}"
    );

    // Surfaces: the default first, named ones after, per-triangle table.
    assert_eq!(floor.surfaces.len(), 2);
    assert_eq!(floor.surfaces[0].diffuse, Vec3::splat(0.8));
    let red = floor.surfaces[1];
    assert_eq!(red.diffuse, Vec3::new(0.7, 0.1, 0.1));
    assert_eq!(red.ambient, red.diffuse, "ambient defaults to diffuse");
    assert_eq!(red.specular, Vec3::splat(0.5));
    assert_eq!(red.shininess, 64.0);
    assert_eq!(red.reflectivity, 0.2);
    assert!(!red.smooth);
    assert_eq!(red.opacity, 1.0);
    assert_eq!(red.ior, 1.5);
    assert_eq!(red.sided, Sided::Two);
    assert_eq!(floor.triangle_surface, vec![0, 1]);
    let t = &s.models[1];
    assert_eq!((t.mesh, t.transform), (1, DMat4::IDENTITY));
    assert_eq!(t.surfaces, vec![Surface::default()]);
    assert!(t.triangle_surface.is_empty());

    assert_eq!(s.spheres[0].surface.reflectivity, 0.9);
    assert_eq!(s.spheres[0].surface.diffuse, Vec3::splat(0.8));
    assert_eq!(s.planes[0].normal, Vec3::Y, "plane normal normalised");
    assert_eq!(s.planes[0].surface.sided, Sided::Front);

    let point = &s.lights[0];
    assert_eq!(point.kind, LightKind::Point);
    assert_eq!(
        (
            point.color,
            point.intensity,
            point.radius,
            point.attenuation
        ),
        (Vec3::ONE, 1.0, 0.0, Vec3::X)
    );
    let LightKind::Spot {
        direction,
        cos_inner,
        cos_outer,
    } = s.lights[1].kind
    else {
        panic!("second light is a spot");
    };
    assert!(close(direction, Vec3::splat(-1.0).normalize()));
    assert!((cos_inner - 15f32.to_radians().cos()).abs() < 1e-6);
    assert!((cos_outer - 25f32.to_radians().cos()).abs() < 1e-6);

    let main = &s.cameras[0];
    assert_eq!(main.direction, -Vec3::Z);
    assert_eq!(
        (main.up, main.fov, main.aperture, main.focus),
        (Vec3::Y, 50.0, 0.0, 8.0)
    );
    assert_eq!(main.lens, Lens::Square);
    assert_eq!(
        main.render,
        RenderSettings {
            width: 300,
            height: 200,
            supersample: 2,
            jitter: false,
            max_depth: 5,
            shadow_samples: 1,
            ao_samples: 0,
            ao_distance: AoDistance::Auto,
            diffuse_samples: 0,
            diffuse_depth: 1,
            seed: 0,
            output: "main.png".into(),
            adaptive: None,
            integrator: IntegratorKind::Whitted,
            max_bounces: DEFAULT_MAX_BOUNCES,
            aovs: crate::aov::Aovs::NONE,
            denoise: false,
            frames: None,
            fps: 24.0,
        }
    );
    let dof = &s.cameras[1];
    assert_eq!(dof.direction, -Vec3::Z);
    assert_eq!((dof.aperture, dof.focus, dof.lens), (0.1, 3.0, Lens::Disk));
    let r = &dof.render;
    assert!(r.jitter);
    assert_eq!((r.seed, r.max_depth, r.ao_samples), (u64::MAX, 0, 3));
    assert_eq!(r.ao_distance, AoDistance::Fixed(2.0));
    assert_eq!(r.output, "out/dof.EXR");
    assert_eq!(
        r.adaptive,
        Some(Adaptive {
            threshold: 0.01,
            min_samples: 4,
            max_samples: 256
        })
    );
}

#[test]
fn smallest_scene_and_focus_default() {
    let s = parse(&doc("")).unwrap();
    assert_eq!(s.cameras.len(), 1);
    assert_eq!(s.settings, Settings::default());
    let c = &s.cameras[0];
    assert_eq!((c.focus, c.direction), (5.0, -Vec3::Z));
    // direction without aperture: focus is unused and set to 1.
    let s = parse(&doc(
        r#"<camera id="d" position="0 0 0" direction="1 0 0" fov="20"><render width="1" height="1"/></camera>"#,
    ))
    .unwrap();
    assert_eq!(s.cameras[0].focus, 1.0);
    assert_eq!(s.cameras[0].render.output, "d.png");
}

#[test]
fn scene_in_a_subdirectory_resolves_paths_from_there() {
    let text = doc("");
    let b = Bundle {
        scene: "sub/scene.xml".into(),
        files: [("sub/scene.xml".to_string(), text.into_bytes())].into(),
    };
    let s = parse_scene("sub/scene.xml", &b).unwrap();
    assert_eq!(s.cameras[0].render.output, "sub/c.png");
}

#[test]
fn model_may_refer_to_a_later_mesh_and_ids_have_namespaces() {
    // A mesh, a model and a camera may share an id; models refer forward.
    let s = parse(&doc(&format!(
        r#"<model id="q" mesh="q"/>{MESH_Q}<light id="q" position="0 0 0"/>"#
    )))
    .unwrap();
    assert_eq!(s.models[0].mesh, 0);
}

#[test]
fn transform_children_compose_in_document_order() {
    let s = parse(&doc_q(
        r#"<model id="m" mesh="q"><transform>
             <translate v="1 0 0"/>
             <rotate axis="0 0 2" angle="90"/>
             <scale v="2"/>
             <matrix m="1 0 0 0  0 1 0 5  0 0 1 0  0 0 0 1"/>
           </transform></model>"#,
    ))
    .unwrap();
    // (0,0,0) → (1,0,0) → (0,1,0) → (0,2,0) → (0,7,0)
    let p = s.models[0].transform * DVec4::new(0.0, 0.0, 0.0, 1.0);
    assert!((p - DVec4::new(0.0, 7.0, 0.0, 1.0)).length() < 1e-12, "{p}");
}

// ------------------------------------------------------------- XML level

#[test]
fn malformed_xml() {
    check(
        "<scene version=\"1\">\n<settings background=0/>\n</scene>",
        2,
        22,
        &["malformed XML", "expected a quoted value"],
    );
    check(
        "<scene version=\"1\">\n<settings background=\"0 0 0\" background=\"1 1 1\"/>\n</scene>",
        2,
        30,
        &[
            "malformed XML",
            "given twice",
            "expected each attribute at most once",
        ],
    );
    check(
        "<scene version=\"1\">\n  <settings>\n</scene>",
        3,
        1,
        &["malformed XML", "expected"],
    );
    check(
        "<scene version=\"1\">\n  <settings/>\n",
        1,
        1,
        &["malformed XML", "not closed", "expected </scene>"],
    );
    check(
        "<scene version=\"1\">\n  <settings background=\"0 0 0\"\n</scene>",
        3,
        1,
        &[
            "malformed XML",
            "expected an attribute name or the end of the tag, found \"<\"",
        ],
    );
    check(
        &format!("{}<scene version=\"1\"/>", doc("")),
        5,
        1,
        &["after the root element", "expected a single <scene> root"],
    );
    check(
        &format!("\n<?xml version=\"1.0\"?>{}", doc("")),
        2,
        1,
        &["XML declaration", "only allowed at the very start"],
    );
    check(
        "<scene version=\"1\">\n<settings background=\"0 & 0\"/>\n</scene>",
        2,
        25,
        &["malformed XML", "expected an entity reference"],
    );
    check(
        "",
        1,
        1,
        &["no root element", "expected <scene version=\"1\">"],
    );
}

#[test]
fn root_must_be_scene_version_1() {
    check(
        "<scen version=\"1\"/>",
        1,
        1,
        &["expected the root element <scene version=\"1\">", "<scen>"],
    );
    check(
        "<?xml version=\"1.0\"?>\n<scene>\n</scene>",
        2,
        1,
        &[
            "expected the root element <scene version=\"1\">",
            "\"version\" is missing",
        ],
    );
    check(
        "<scene version=\"2\">\n</scene>",
        1,
        8,
        &[
            "attribute \"version\" of <scene>",
            "expected \"1\"",
            "found \"2\"",
        ],
    );
    check(
        "<scene version=\"1\" author=\"me\">\n</scene>",
        1,
        20,
        &[
            "unknown attribute \"author\"",
            "expected one of \"version\"",
        ],
    );
}

#[test]
fn at_least_one_camera() {
    check(
        "<!-- empty -->\n  <scene version=\"1\"></scene>",
        2,
        3,
        &["no <camera>", "expected at least one"],
    );
}

#[test]
fn dtd_and_entities_are_rejected() {
    check(
        &format!(
            "<?xml version=\"1.0\"?>\n<!DOCTYPE scene [<!ENTITY x \"1\">]>\n{}",
            doc("")
        ),
        2,
        1,
        &["DTD", "expected no DTD"],
    );
    check(
        &doc(r#"<settings background="0 &zero; 0"/>"#),
        2,
        25,
        &["\"&zero;\" is not allowed", "expected one of &lt;"],
    );
    check(
        &doc(
            r#"<mesh id="q"><vertices>0 0 0 1 0 0 &zero; 1 0</vertices><triangles>0 1 2</triangles></mesh>"#,
        ),
        2,
        36,
        &["\"&zero;\" is not allowed", "expected one of"],
    );
    // The five predefined entities and character references are fine.
    parse(&doc(r#"<camera id="&lt;&#x41;&amp;&quot;&apos;&gt;" position="0 0 0" lookat="0 0 1" fov="9"><render width="1" height="1" output="a.png"/></camera>"#)).unwrap();
}

#[test]
fn unknown_element() {
    check(
        &doc(r#"<sphere id="s" center="0 0 0" radius="1"><bogus/></sphere>"#),
        2,
        42,
        &[
            "unknown element <bogus> inside <sphere>",
            "expected one of <surface>",
        ],
    );
    check(
        &doc("<render width=\"1\" height=\"1\"/>"),
        2,
        1,
        &["unknown element <render> inside <scene>", "expected one of"],
    );
}

#[test]
fn unknown_attribute() {
    check(
        &doc(r#"<sphere id="s" center="0 0 0" radius="1" color="1 1 1"/>"#),
        2,
        42,
        &[
            "unknown attribute \"color\" of <sphere>",
            "expected one of \"id\", \"center\", \"radius\"",
        ],
    );
    // triangles= only on a model's surfaces.
    check(
        &doc(r#"<sphere id="s" center="0 0 0" radius="1"><surface triangles="0"/></sphere>"#),
        2,
        51,
        &["unknown attribute \"triangles\" of <surface>"],
    );
}

#[test]
fn missing_required_attribute() {
    check(
        &doc(r#"  <sphere id="s" center="0 0 0"/>"#),
        2,
        3,
        &["<sphere> is missing its required attribute \"radius\""],
    );
    check(
        &doc(
            r#"<camera id="d" position="0 0 0" lookat="0 0 -1"><render width="4" height="3"/></camera>"#,
        ),
        2,
        1,
        &["missing its required attribute \"fov\""],
    );
}

#[test]
fn malformed_number() {
    check(
        &doc(r#"<sphere id="s" center="0 x 0" radius="1"/>"#),
        2,
        16,
        &[
            "attribute \"center\" of <sphere>",
            "expected three numbers",
            "\"x\" is not a number",
        ],
    );
    check(
        &doc(
            r#"<mesh id="q"><vertices>0 0 0 1 zz 0 0 1 0</vertices><triangles>0 1 2</triangles></mesh>"#,
        ),
        2,
        32,
        &["<vertices>: expected a number, found \"zz\""],
    );
}

#[test]
fn non_finite_number() {
    for bad in ["inf", "nan", "1e999", "-infinity", "1e39"] {
        check(
            &doc(&format!(
                r#"<sphere id="s" center="0 0 0" radius="{bad}"/>"#
            )),
            2,
            31,
            &["attribute \"radius\" of <sphere>", "finite"],
        );
    }
    check(
        &doc(
            r#"<mesh id="q"><vertices>0 0 0 1 0 0 0 1e999 0</vertices><triangles>0 1 2</triangles></mesh>"#,
        ),
        2,
        38,
        &["expected a finite number, found \"1e999\""],
    );
}

#[test]
fn wrong_count_of_numbers() {
    check(
        &doc(r#"<light position="0 0"/>"#),
        2,
        8,
        &[
            "attribute \"position\" of <light>",
            "expected three numbers",
            "found 2 numbers",
        ],
    );
    check(
        &doc_q(r#"<model id="m" mesh="q"><transform><scale v="1 2"/></transform></model>"#),
        3,
        42,
        &["expected one number or three numbers"],
    );
}

#[test]
fn dangling_reference() {
    check(
        &doc(r#"<model id="m" mesh="nope"/>"#),
        2,
        15,
        &[
            "attribute \"mesh\" of <model>",
            "no <mesh> has the id \"nope\"",
            "expected the id of a <mesh>",
        ],
    );
}

#[test]
fn duplicate_ids() {
    check(
        &doc(
            r#"<mesh id="q"><vertices>0 0 0 1 0 0 0 1 0</vertices><triangles>0 1 2</triangles></mesh><mesh id="q" file="a.obj"/>"#,
        ),
        2,
        93,
        &["duplicate id \"q\"", "<mesh> at 2:1", "expected a unique"],
    );
    check(
        &doc(
            r#"<sphere id="a" center="0 0 0" radius="1"/> <plane id="a" point="0 0 0" normal="0 1 0"/>"#,
        ),
        2,
        51,
        &[
            "duplicate id \"a\"",
            "<sphere> at 2:1",
            "expected a unique id",
        ],
    );
    check(
        &doc(
            r#"<camera id="c" position="0 0 5" direction="0 0 -1" fov="50"><render width="4" height="3" output="x.png"/></camera>"#,
        ),
        3,
        9,
        &["duplicate id \"c\"", "<camera> at 2:1"],
    );
    check(
        &doc(r#"<light id="l" position="0 0 0"/><light id="l" position="1 0 0"/>"#),
        2,
        40,
        &["duplicate id \"l\"", "<light> at 2:1"],
    );
}

// ---------------------------------------------------------------- meshes

#[test]
fn mesh_index_out_of_range() {
    check(
        &doc(
            r#"<mesh id="q"><vertices>0 0 0 1 0 0 0 1 0</vertices><triangles>0 1 2 2 1 3</triangles></mesh>"#,
        ),
        2,
        73,
        &[
            "vertex index 3 is out of range",
            "expected an index below the vertex count, 3",
        ],
    );
    check(
        &doc(
            r#"<mesh id="q"><vertices>0 0 0 1 0 0 0 1 0</vertices><triangles>0 1 -2</triangles></mesh>"#,
        ),
        2,
        67,
        &["expected a vertex index (an integer ≥ 0), found \"-2\""],
    );
}

#[test]
fn mesh_without_triangles() {
    check(
        &doc(
            r#"<mesh id="q"><vertices>0 0 0 1 0 0 0 1 0</vertices><triangles> </triangles></mesh>"#,
        ),
        2,
        52,
        &["is empty", "expected at least one triangle"],
    );
    check(
        &doc(r#"<mesh id="q"><vertices>0 0 0 1 0 0 0 1 0</vertices></mesh>"#),
        2,
        1,
        &[
            "has no <triangles>",
            "expected file= or inline <vertices> and <triangles>",
        ],
    );
    check(
        &doc(
            r#"<mesh id="q"><vertices>0 0 0 1 0 0 0 1 0</vertices><triangles>0 1</triangles></mesh>"#,
        ),
        2,
        52,
        &["expected 3 indices per triangle", "found 2"],
    );
}

#[test]
fn vertex_count_not_a_multiple_of_3() {
    check(
        &doc(
            r#"<mesh id="q"><vertices>0 0 0 1 0 0 0 1</vertices><triangles>0 1 2</triangles></mesh>"#,
        ),
        2,
        14,
        &[
            "<vertices> of mesh \"q\"",
            "expected 3 numbers per vertex",
            "found 8",
        ],
    );
}

#[test]
fn normals_count_differs_from_vertices() {
    check(
        &doc(
            r#"<mesh id="q"><vertices>0 0 0 1 0 0 0 1 0</vertices><normals>0 0 1 0 0 1</normals><triangles>0 1 2</triangles></mesh>"#,
        ),
        2,
        52,
        &[
            "<normals> of mesh \"q\"",
            "expected one normal per vertex (9 numbers",
            "found 6",
        ],
    );
}

#[test]
fn inline_uvs_one_pair_per_vertex() {
    let d = parse(&doc(
        r#"<mesh id="q"><vertices>0 0 0 1 0 0 0 1 0</vertices><uvs>0 0  1 0.5  0 1</uvs><triangles>0 1 2</triangles></mesh>"#,
    ))
    .unwrap();
    assert_eq!(
        d.meshes[0].uvs,
        vec![
            glam::Vec2::new(0.0, 0.0),
            glam::Vec2::new(1.0, 0.5),
            glam::Vec2::new(0.0, 1.0)
        ]
    );
    check(
        &doc(
            r#"<mesh id="q"><vertices>0 0 0 1 0 0 0 1 0</vertices><uvs>0 0 1 1</uvs><triangles>0 1 2</triangles></mesh>"#,
        ),
        2,
        52,
        &[
            "<uvs> of mesh \"q\"",
            "one u v pair per vertex (6 numbers for 3 vertices)",
            "found 4",
        ],
    );
    check(
        &doc(
            r#"<mesh id="q"><vertices>0 0 0 1 0 0 0 1 0</vertices><uvs>0 0 1 1 0 1e300</uvs><triangles>0 1 2</triangles></mesh>"#,
        ),
        2,
        67,
        &["<uvs>", "expected a finite number, found \"1e300\""],
    );
}

#[test]
fn mesh_file_references() {
    check(
        &doc(r#"<mesh id="q" file="/etc/x.obj"/>"#),
        2,
        14,
        &[
            "attribute \"file\" of <mesh>",
            "absolute",
            "expected a relative path",
        ],
    );
    check(
        &doc(r#"<mesh id="q" file="m/../../x.obj"/>"#),
        2,
        14,
        &["climbs out", "expected a relative path"],
    );
    check(
        &doc(r#"<mesh id="q" file="m/missing.obj"/>"#),
        2,
        14,
        &[
            "cannot read mesh file \"m/missing.obj\"",
            "expected a file of the scene bundle",
        ],
    );
    check(
        &doc(r#"<mesh id="q" file="m/x.stl"/>"#),
        2,
        14,
        &[
            "expected a mesh file ending in .obj or .ply",
            "found \"m/x.stl\"",
        ],
    );
    check(
        &doc(r#"<mesh id="q" file="m/x.obj"><triangles>0 1 2</triangles></mesh>"#),
        2,
        29,
        &["expected either file= or inline data"],
    );
}

// ------------------------------------------------------ models, surfaces

#[test]
fn triangle_named_twice_or_beyond_the_mesh() {
    check(
        &doc_q(
            r#"<model id="m" mesh="q"><surface triangles="0"/><surface triangles="1 0-1"/></model>"#,
        ),
        3,
        57,
        &[
            "triangle 0 is named twice",
            "<surface> at 3:24",
            "expected each triangle in at most one",
        ],
    );
    check(
        &doc_q(r#"<model id="m" mesh="q"><surface triangles="0-2"/></model>"#),
        3,
        33,
        &[
            "triangle 2 is beyond the mesh's 2 triangles",
            "expected indices 0-1",
        ],
    );
    check(
        &doc_q(r#"<model id="m" mesh="q"><surface diffuse="1 0 0" triangles="1-0"/></model>"#),
        3,
        49,
        &[
            "reversed range \"1-0\"",
            "expected triangle indices and inclusive ranges",
        ],
    );
    check(
        &doc_q(r#"<model id="m" mesh="q"><surface diffuse="1 0 0" triangles="1 x"/></model>"#),
        3,
        49,
        &[
            "expected triangle indices and inclusive ranges",
            "found \"x\"",
        ],
    );
}

#[test]
fn more_than_one_default_surface() {
    check(
        &doc_q(
            r#"<model id="m" mesh="q"><surface/><surface triangles="1"/><surface diffuse="1 1 1"/></model>"#,
        ),
        3,
        58,
        &[
            "more than one default <surface>",
            "first is at 3:24",
            "expected at most one",
        ],
    );
}

#[test]
fn singular_transform() {
    check(
        &doc_q(
            r#"<model id="m" mesh="q"><transform><translate v="1 2 3"/><scale v="1 0 1"/></transform></model>"#,
        ),
        3,
        57,
        &["singular <scale>", "expected an invertible transform"],
    );
    check(
        &doc_q(
            r#"<model id="m" mesh="q"><transform><matrix m="1 0 0 0  1 0 0 0  0 0 1 0  0 0 0 1"/></transform></model>"#,
        ),
        3,
        35,
        &["singular <matrix>"],
    );
    check(
        &doc_q(
            r#"<model id="m" mesh="q"><transform><rotate axis="0 0 0" angle="3"/></transform></model>"#,
        ),
        3,
        43,
        &[
            "attribute \"axis\" of <rotate>",
            "expected a non-zero direction",
        ],
    );
}

#[test]
fn matrix_last_row_must_be_0_0_0_1() {
    check(
        &doc_q(
            r#"<model id="m" mesh="q"><transform><matrix m="1 0 0 0 0 1 0 0 0 0 1 0 0 0 1 1"/></transform></model>"#,
        ),
        3,
        43,
        &[
            "attribute \"m\" of <matrix>",
            "expected the last row \"0 0 0 1\"",
            "found \"0 0 1 1\"",
        ],
    );
}

#[test]
fn surface_value_ranges() {
    let sphere = |attr: &str| {
        doc(&format!(
            r#"<sphere id="s" center="0 0 0" radius="1"><surface {attr}/></sphere>"#
        ))
    };
    check(
        &sphere(r#"reflectivity="1.5""#),
        2,
        51,
        &[
            "attribute \"reflectivity\" of <surface>",
            "expected a number in [0, 1], found \"1.5\"",
        ],
    );
    check(
        &sphere(r#"opacity="-0.1""#),
        2,
        51,
        &["expected a number in [0, 1]"],
    );
    check(
        &sphere(r#"ior="0""#),
        2,
        51,
        &["attribute \"ior\"", "expected a number > 0"],
    );
    check(
        &sphere(r#"shininess="-1""#),
        2,
        51,
        &["expected a number ≥ 0, found \"-1\""],
    );
    check(
        &sphere(r#"diffuse="1 1 -1""#),
        2,
        51,
        &["expected a color \"r g b\" (three numbers ≥ 0)"],
    );
}

#[test]
fn negative_color_components() {
    check(
        &doc(r#"<settings ambient="0.1 0.1 0.1" background="0 -1 0"/>"#),
        2,
        33,
        &[
            "attribute \"background\" of <settings>",
            "three numbers ≥ 0",
            "found \"0 -1 0\"",
        ],
    );
    check(
        &doc(r#"<light position="0 0 0" color="1 -1 1"/>"#),
        2,
        25,
        &["attribute \"color\" of <light>", "≥ 0"],
    );
}

#[test]
fn bad_enum_and_boolean_values() {
    check(
        &doc(r#"<sphere id="s" center="0 0 0" radius="1"><surface sided="back"/></sphere>"#),
        2,
        51,
        &[
            "attribute \"sided\"",
            "expected one of \"two\", \"front\"",
            "found \"back\"",
        ],
    );
    check(
        &doc(r#"<sphere id="s" center="0 0 0" radius="1"><surface smooth="yes"/></sphere>"#),
        2,
        51,
        &["attribute \"smooth\"", "expected \"true\" or \"false\""],
    );
    check(
        &doc(r#"<light type="area" position="0 0 0"/>"#),
        2,
        8,
        &[
            "attribute \"type\" of <light>",
            "expected one of \"point\", \"spot\"",
        ],
    );
    check(
        &doc(
            r#"<camera id="d" position="0 0 0" lookat="0 0 -1" fov="20" lens="round"><render width="1" height="3"/></camera>"#,
        ),
        2,
        58,
        &[
            "attribute \"lens\" of <camera>",
            "expected one of \"square\", \"disk\"",
        ],
    );
    check(
        &doc(r#"<mesh id="q" invert="TRUE"/>"#),
        2,
        14,
        &["attribute \"invert\"", "expected \"true\" or \"false\""],
    );
}

// ------------------------------------------------------- spheres, planes

#[test]
fn sphere_radius_must_be_positive() {
    check(
        &doc(r#"<sphere id="s" center="0 0 0" radius="0"/>"#),
        2,
        31,
        &[
            "attribute \"radius\" of <sphere>",
            "expected a number > 0, found \"0\"",
        ],
    );
    check(
        &doc(r#"<sphere id="s" center="0 0 0" radius="1"><surface/>
  <surface/></sphere>"#),
        3,
        3,
        &["second <surface>", "expected at most one"],
    );
}

#[test]
fn plane_normal_must_be_non_zero() {
    check(
        &doc(r#"<plane id="p" point="0 0 0" normal="0 0 0"/>"#),
        2,
        29,
        &[
            "attribute \"normal\" of <plane>",
            "expected a non-zero direction",
        ],
    );
}

// ---------------------------------------------------------------- lights

#[test]
fn light_values() {
    check(
        &doc(r#"<light position="0 0 0" attenuation="0 0 0"/>"#),
        2,
        25,
        &["attribute \"attenuation\"", "not all 0"],
    );
    check(
        &doc(r#"<light position="0 0 0" intensity="-1"/>"#),
        2,
        25,
        &["attribute \"intensity\"", "expected a number ≥ 0"],
    );
    check(
        &doc(r#"<light type="spot" position="0 0 0"/>"#),
        2,
        1,
        &["missing its required attribute \"direction\""],
    );
    check(
        &doc(r#"<light type="spot" position="0 0 0" direction="0 -1 0" inner="40"/>"#),
        2,
        56,
        &["attribute \"inner\"", "expected an angle ≤ outer (30"],
    );
    check(
        &doc(r#"<light type="spot" position="0 0 0" direction="0 -1 0" outer="180"/>"#),
        2,
        56,
        &["attribute \"outer\"", "in [0, 180)"],
    );
    // Point lights accept and ignore spot attributes.
    let s = parse(&doc(
        r#"<light position="0 0 0" direction="0 0 0" inner="50" outer="1"/>"#,
    ))
    .unwrap();
    assert_eq!(s.lights[0].kind, LightKind::Point);
}

// --------------------------------------------------------------- cameras

#[test]
fn camera_direction_parallel_to_up() {
    check(
        &doc(
            r#"<camera id="d" position="0 0 0" direction="0 2 0" fov="50"><render width="4" height="3"/></camera>"#,
        ),
        2,
        33,
        &[
            "attribute \"direction\" of <camera>",
            "parallel to up",
            "expected a direction not parallel to up",
        ],
    );
    check(
        &doc(
            r#"<camera id="d" position="0 0 0" lookat="0 0 -1" up="0 0 1" fov="50"><render width="4" height="3"/></camera>"#,
        ),
        2,
        49,
        &["attribute \"up\" of <camera>", "parallel to up"],
    );
}

#[test]
fn fov_must_be_in_0_180() {
    check(
        &doc(
            r#"<camera id="d" position="0 0 0" lookat="0 0 -1" fov="200"><render width="4" height="3"/></camera>"#,
        ),
        2,
        49,
        &["attribute \"fov\" of <camera>: expected a number in (0, 180), found \"200\""],
    );
}

#[test]
fn direction_and_lookat() {
    check(
        &doc(
            r#"<camera id="d" position="0 0 0" lookat="0 0 -1" fov="20" direction="0 0 1"><render width="1" height="3"/></camera>"#,
        ),
        2,
        58,
        &[
            "attribute \"direction\" of <camera>",
            "expected exactly one of \"direction\" and \"lookat\", found both",
        ],
    );
    check(
        &doc(r#"<camera id="d" position="0 0 0" fov="20"><render width="1" height="3"/></camera>"#),
        2,
        1,
        &[
            "exactly one of the attributes \"direction\" and \"lookat\"",
            "found neither",
        ],
    );
    check(
        &doc(
            r#"<camera id="d" position="1 1 1" lookat="1 1 1" fov="20"><render width="1" height="3"/></camera>"#,
        ),
        2,
        33,
        &[
            "attribute \"lookat\"",
            "expected a point different from the camera's position",
        ],
    );
    check(
        &doc(
            r#"<camera id="d" position="0 0 0" direction="0 0 1" fov="20" aperture="0.5"><render width="1" height="3"/></camera>"#,
        ),
        2,
        1,
        &["missing its required attribute \"focus\""],
    );
    check(
        &doc(
            r#"<camera id="d" position="0 0 0" direction="0 0 1" fov="20" focus="0"><render width="1" height="3"/></camera>"#,
        ),
        2,
        60,
        &["attribute \"focus\"", "expected a number > 0"],
    );
}

#[test]
fn render_missing_or_repeated() {
    check(
        &doc(r#"<camera id="d" position="0 0 0" lookat="0 0 -1" fov="20"></camera>"#),
        2,
        1,
        &["<camera> \"d\" has no <render>", "expected exactly one"],
    );
    check(
        &doc(
            r#"<camera id="d" position="0 0 0" lookat="0 0 -1" fov="20"><render width="1" height="3"/><render width="1" height="3"/></camera>"#,
        ),
        2,
        88,
        &["second <render>", "expected exactly one"],
    );
}

/// Every count of `<render>` has a documented maximum (the limits table of
/// docs/aisxml-extensions.md). At the maximum the scene parses; one past it
/// is an error at the attribute, so that no count can make a render run
/// for ever (`ao-samples` of 4294967295) or overflow (`supersample` 65537
/// squared).
#[test]
fn render_counts_have_documented_maxima() {
    use crate::scene::{
        MAX_ADAPTIVE_SAMPLES, MAX_DEPTH, MAX_IMAGE_SIDE, MAX_RAY_SAMPLES, MAX_SUPERSAMPLE,
    };
    type Case = (&'static str, u32, u32, fn(&RenderSettings) -> u32);
    let cases: [Case; 10] = [
        ("width", 1, MAX_IMAGE_SIDE, |r| r.width),
        ("height", 1, MAX_IMAGE_SIDE, |r| r.height),
        ("supersample", 1, MAX_SUPERSAMPLE, |r| r.supersample),
        ("max-depth", 0, MAX_DEPTH, |r| r.max_depth),
        ("shadow-samples", 1, MAX_RAY_SAMPLES, |r| r.shadow_samples),
        ("ao-samples", 0, MAX_RAY_SAMPLES, |r| r.ao_samples),
        ("diffuse-samples", 0, MAX_RAY_SAMPLES, |r| r.diffuse_samples),
        ("diffuse-depth", 1, MAX_DEPTH, |r| r.diffuse_depth),
        ("min-samples", 1, MAX_ADAPTIVE_SAMPLES, |r| {
            r.adaptive.map_or(0, |a| a.min_samples)
        }),
        ("max-samples", 1, MAX_ADAPTIVE_SAMPLES, |r| {
            r.adaptive.map_or(0, |a| a.max_samples)
        }),
    ];
    for (name, min, max, get) in cases {
        let text = |v: u64| {
            let mut attrs = String::new();
            for (n, d) in [("width", 3u64), ("height", 3)] {
                if n != name {
                    attrs.push_str(&format!(r#"{n}="{d}" "#));
                }
            }
            match name {
                "min-samples" => attrs.push_str(&format!(r#"max-samples="{}" "#, u32::MAX)),
                "max-samples" => attrs.push_str(r#"min-samples="1" "#),
                _ => {}
            }
            if name.ends_with("-samples") && name.starts_with('m') {
                attrs.push_str(r#"noise-threshold="0.1" "#);
            }
            attrs.push_str(&format!(r#"{name}="{v}""#));
            doc(&format!(
                r#"<camera id="d" position="0 0 0" lookat="0 0 -1" fov="20"><render {attrs}/></camera>"#
            ))
        };
        let ok = text(u64::from(max));
        match parse(&ok) {
            Ok(desc) => assert_eq!(get(&desc.cameras[0].render), max, "{name}"),
            Err(e) => panic!("{name}=\"{max}\" is the documented maximum: {e}"),
        }
        let bad = text(u64::from(max) + 1);
        let line = bad.lines().nth(1).unwrap();
        let col = line.find(&format!(" {name}=")).unwrap() as u32 + 2;
        check(
            &bad,
            2,
            col,
            &[
                &format!("attribute \"{name}\" of <render>"),
                &format!(
                    "expected an integer in [{min}, {max}], found \"{}\"",
                    u64::from(max) + 1
                ),
            ],
        );
    }
    // The reported ones.
    for (attr, v) in [("ao-samples", "4294967295"), ("supersample", "65537")] {
        let text = doc(&format!(
            r#"<camera id="d" position="0 0 0" lookat="0 0 -1" fov="20"><render width="3" height="3" {attr}="{v}"/></camera>"#
        ));
        check(
            &text,
            2,
            87,
            &[&format!("attribute \"{attr}\""), "expected an integer in"],
        );
    }
}

/// Hostile input must not make a reader quadratic: the duplicate-attribute
/// check stays linear in a tag's attributes (a pairwise comparison took
/// tens of seconds on 200,000 of them).
#[test]
fn a_tag_with_200k_attributes_is_checked_in_linear_time() {
    let mut tag = String::from(r#"<scene version="1""#);
    for i in 0..200_000 {
        tag.push_str(&format!(r#" a{i}="""#));
    }
    let first = tag.find(" a7=").unwrap() + 2;
    let col = tag.len() as u32 + 2;
    tag.push_str(r#" a7="">"#);
    let text = format!("{tag}\n{CAM}\n</scene>\n");
    let start = std::time::Instant::now();
    check(
        &text,
        1,
        col,
        &[&format!(
            "attribute \"a7\" is given twice (first at 1:{first})"
        )],
    );
    let took = start.elapsed();
    assert!(took < std::time::Duration::from_secs(2), "{took:?}");
}

#[test]
fn render_values() {
    let cam = |attrs: &str| {
        doc(&format!(
            r#"<camera id="d" position="0 0 0" lookat="0 0 -1" fov="20"><render {attrs}/></camera>"#
        ))
    };
    // <render  is at column 58, its first attribute at column 66.
    check(
        &cam(r#"width="0" height="3""#),
        2,
        66,
        &[
            "attribute \"width\" of <render>",
            "expected an integer in [1, 65536], found \"0\"",
        ],
    );
    check(
        &cam(r#"width="3" height="3" supersample="1.5""#),
        2,
        87,
        &[
            "attribute \"supersample\"",
            "expected an integer",
            "found \"1.5\"",
        ],
    );
    check(
        &cam(r#"width="3""#),
        2,
        58,
        &["missing its required attribute \"height\""],
    );
    check(
        &cam(r#"width="3" height="3" output="a.jpg""#),
        2,
        87,
        &[
            "attribute \"output\"",
            "expected a file name ending in .png or .exr",
        ],
    );
    check(
        &cam(r#"width="3" height="3" output="../a.png""#),
        2,
        87,
        &["attribute \"output\"", "climbs out"],
    );
    check(
        &cam(r#"width="3" height="3" ao-distance="0""#),
        2,
        87,
        &["expected a number > 0 or \"auto\""],
    );
    check(
        &cam(r#"width="3" height="3" min-samples="8""#),
        2,
        87,
        &["attribute \"min-samples\"", "expected noise-threshold="],
    );
    check(
        &cam(r#"width="3" height="3" noise-threshold="0.1" min-samples="8" max-samples="4""#),
        2,
        125,
        &[
            "attribute \"max-samples\"",
            "expected max-samples ≥ min-samples",
        ],
    );
    check(
        &cam(r#"width="3" height="3" jitter="maybe""#),
        2,
        87,
        &["attribute \"jitter\"", "expected \"true\" or \"false\""],
    );
    check(
        &cam(r#"width="3" height="3" output="c.png""#),
        3,
        57,
        &[
            "output \"c.png\" is already written",
            "expected a distinct output",
        ],
    );
    check(
        &cam(r#"width="3" height="3" diffuse-depth="0""#),
        2,
        87,
        &["attribute \"diffuse-depth\"", "expected an integer in [1,"],
    );
}

#[test]
fn more_than_one_settings() {
    check(
        &doc(r#"<settings/><!-- x --><settings ambient="1 1 1"/>"#),
        2,
        22,
        &["more than one <settings>", "expected at most one"],
    );
}

#[test]
fn non_whitespace_text() {
    check(
        &doc(r#"<sphere id="s" center="0 0 0" radius="1"> hello </sphere>"#),
        2,
        43,
        &[
            "unexpected text inside <sphere>",
            "expected only whitespace",
        ],
    );
    check(
        &format!("{}  trailing", doc("")),
        5,
        3,
        &["unexpected text outside the root element"],
    );
    check(
        &doc(r#"<settings><![CDATA[x]]></settings>"#),
        2,
        20,
        &["unexpected text inside <settings>"],
    );
}

#[test]
fn encoding_bom_and_columns_in_characters() {
    // Columns count characters, not bytes.
    check(
        &doc(r#"<!-- é→ --><sphere id="s" center="0 0 0" radius="0"/>"#),
        2,
        42,
        &["expected a number > 0"],
    );
    // A BOM and a declaration at the start are fine.
    parse(&format!(
        "\u{feff}<?xml version=\"1.0\" encoding=\"utf-8\"?>\n{}",
        doc("")
    ))
    .unwrap();
    check(
        &format!(
            "<?xml version=\"1.0\" encoding=\"ISO-8859-1\"?>\n{}",
            doc("")
        ),
        1,
        1,
        &["encoding other than UTF-8"],
    );
    let mut bytes = doc("").into_bytes();
    bytes.splice(20..20, [b'x', 0xff]);
    let b = Bundle {
        scene: "scene.xml".into(),
        files: [("scene.xml".to_string(), bytes)].into(),
    };
    let e = parse_scene("scene.xml", &b).unwrap_err();
    assert_eq!((e.location.line, e.location.column), (2, 2), "{e}");
    assert!(e.message.contains("expected UTF-8"), "{e}");
    check(
        &format!("<![CDATA[ ]]>{}", doc("")),
        1,
        1,
        &["CDATA section outside the root element"],
    );
}

// ------------------------------------------------------------ mesh files

#[test]
fn obj_mesh_file_is_loaded_once_and_recorded() {
    // Needs the OBJ loader (crate::mesh::obj).
    let text = doc(r#"<mesh id="a" file="./m/Tri.OBJ" invert="true"/>
<model id="x" mesh="a"/><model id="y" mesh="a"><surface triangles="0"/></model>"#);
    let obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
    let b = bundle_with(&text, &[("m/Tri.OBJ", obj)]);
    let s = parse_scene("scene.xml", &b).unwrap();
    assert_eq!(s.meshes.len(), 1);
    assert_eq!(s.files, vec!["m/Tri.OBJ".to_string()]);
    assert_eq!(s.meshes[0].triangles, vec![[0, 2, 1]]);
    assert!(close(s.meshes[0].normals[0], -Vec3::Z));
    assert_eq!((s.models[0].mesh, s.models[1].mesh), (0, 0));
    assert_eq!(s.models[1].triangle_surface, vec![1]);
}

#[test]
fn ply_mesh_file_is_loaded() {
    // Needs the PLY loader (crate::mesh::ply).
    let text = doc(r#"<mesh id="a" file="m/t.ply"/><model id="x" mesh="a"/>"#);
    let ply = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
    let b = bundle_with(&text, &[("m/t.ply", ply)]);
    let s = parse_scene("scene.xml", &b).unwrap();
    assert_eq!(s.files, vec!["m/t.ply".to_string()]);
    assert_eq!(s.meshes[0].triangles, vec![[0, 1, 2]]);
    assert!(close(s.meshes[0].normals[1], Vec3::Z));
}

#[test]
fn mesh_file_errors_pass_through() {
    let text = doc(r#"<mesh id="a" file="m/bad.obj"/>"#);
    let b = bundle_with(
        &text,
        &[("m/bad.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n")],
    );
    let e = parse_scene("scene.xml", &b).unwrap_err();
    assert_eq!(e.location.file, "m/bad.obj", "{e}");
    assert_eq!(e.location.line, 4, "{e}");
}

// -------------------------------------------------------------- robustness

mod fuzz {
    use super::*;
    use proptest::prelude::*;

    #[derive(Debug, Clone)]
    enum Edit {
        Flip(usize, u8),
        Insert(usize, u8),
        Delete(usize),
    }

    fn edit() -> impl Strategy<Value = Edit> {
        let byte = prop_oneof![
            any::<u8>(),
            proptest::sample::select(b"<>/=\"'& ;#-0123456789.eE!?[]x\n".to_vec()),
        ];
        prop_oneof![
            (any::<usize>(), byte.clone()).prop_map(|(i, b)| Edit::Flip(i, b)),
            (any::<usize>(), byte).prop_map(|(i, b)| Edit::Insert(i, b)),
            any::<usize>().prop_map(Edit::Delete),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]
        #[test]
        fn mutated_scenes_never_panic(edits in proptest::collection::vec(edit(), 1..8)) {
            let mut bytes = FULL.as_bytes().to_vec();
            for e in edits {
                match e {
                    Edit::Flip(i, b) if !bytes.is_empty() => { let n = bytes.len(); bytes[i % n] = b; }
                    Edit::Insert(i, b) => { let n = bytes.len() + 1; bytes.insert(i % n, b); }
                    Edit::Delete(i) if !bytes.is_empty() => { let n = bytes.len(); bytes.remove(i % n); }
                    _ => {}
                }
            }
            let mut files = BTreeMap::new();
            files.insert("scene.xml".to_string(), bytes);
            let b = Bundle { scene: "scene.xml".into(), files };
            match parse_scene("scene.xml", &b) {
                Ok(s) => prop_assert!(!s.cameras.is_empty()),
                Err(e) => {
                    prop_assert!(e.location.line >= 1 && e.location.column >= 1);
                    prop_assert!(!e.message.is_empty());
                }
            }
        }
    }
}

#[test]
fn errors_say_their_kind() {
    use crate::SceneErrorKind as K;
    let kind = |text: &str| parse(text).unwrap_err().kind;
    assert_eq!(kind("<scene version=\"1\">"), K::Syntax);
    assert_eq!(kind(&doc("<cube/>")), K::UnknownElement);
    assert_eq!(
        kind(&doc(r#"<settings colour="1 1 1"/>"#)),
        K::UnknownAttribute
    );
    assert_eq!(kind(&doc(r#"<sphere id="s" center="0 0 0"/>"#)), K::Missing);
    assert_eq!(
        kind(&doc(r#"<sphere id="s" center="0 0 0" radius="-1"/>"#)),
        K::BadValue
    );
    assert_eq!(
        kind(&doc(r#"<model id="m" mesh="nothing"/>"#)),
        K::Reference
    );
    assert_eq!(
        kind(&doc(r#"<mesh id="m" file="../m.obj"/>"#)),
        K::Reference
    );
    assert_eq!(kind(&doc(r#"<mesh id="m" file="m.obj"/>"#)), K::MissingFile);
    assert_eq!(kind("<scene version=\"1\"></scene>"), K::Missing);
}

/// `aovs=`: names in any order, separated by spaces or commas; none by
/// default; an unknown name is refused at the attribute, with the name.
#[test]
fn render_passes_are_named_in_any_order_and_unknown_ones_are_refused() {
    let cam = |aovs: &str| {
        format!(
            "<scene version=\"1\">\n<camera id=\"c\" position=\"0 0 5\" lookat=\"0 0 0\" fov=\"50\">\n  <render width=\"4\" height=\"3\" {aovs}/></camera>\n</scene>\n"
        )
    };
    let aovs = |text: &str| parse(text).unwrap().cameras[0].render.aovs;
    assert_eq!(aovs(&cam("")), crate::aov::Aovs::NONE);
    assert_eq!(
        aovs(&cam(r#"aovs="depth,normal  albedo""#)),
        crate::aov::Aovs::ALL
    );
    let d = aovs(&cam(r#"aovs=" depth ""#));
    assert_eq!(d.iter().collect::<Vec<_>>(), [crate::aov::Aov::Depth]);
    assert_eq!(aovs(&cam(r#"aovs="""#)), crate::aov::Aovs::NONE);
    check(
        &cam(r#"aovs="albedo beauty""#),
        3,
        32,
        &[
            "aovs",
            "unknown render pass \"beauty\"",
            "albedo, normal, depth",
        ],
    );
    check(&cam(r#"aovs="Depth""#), 3, 32, &["\"Depth\""]);
    // `denoise=`: a flag for trevi-submit, parsed and checked here.
    let denoise = |text: &str| parse(text).unwrap().cameras[0].render.denoise;
    assert!(!denoise(&cam("")));
    assert!(denoise(&cam(r#"denoise="true""#)));
    assert!(!denoise(&cam(r#"denoise="0""#)));
    check(
        &cam(r#"denoise="yes""#),
        3,
        32,
        &["denoise", "\"true\" or \"false\""],
    );
    // A PNG's passes go to files beside it: another camera may not write
    // one of them.
    let two = |first: &str, second: &str| {
        format!(
            "<scene version=\"1\">\n<camera id=\"a\" position=\"0 0 5\" lookat=\"0 0 0\" fov=\"50\"><render width=\"4\" height=\"3\" {first}/></camera>\n<camera id=\"b\" position=\"0 0 5\" lookat=\"0 0 0\" fov=\"50\"><render width=\"4\" height=\"3\" {second}/></camera>\n</scene>\n"
        )
    };
    check(
        &two(
            r#"output="x.png" aovs="albedo depth""#,
            r#"output="x.depth.exr""#,
        ),
        3,
        86,
        &["\"x.depth.exr\" is already written by the <render> at 2:57"],
    );
    check(
        &two(
            r#"output="x.normal.png""#,
            r#"output="x.png" aovs="normal""#,
        ),
        3,
        86,
        &["\"x.png\" writes \"x.normal.png\""],
    );
    // An EXR holds its passes: nothing beside it.
    parse(&two(
        r#"output="x.exr" aovs="albedo normal depth""#,
        r#"output="x.albedo.png""#,
    ))
    .unwrap();
}
