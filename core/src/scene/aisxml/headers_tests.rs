//! The headers-only parse ([`super::parse_scene_headers`]) against the full
//! one: the same scene checks, the same cameras, an estimate at least the
//! full one's (equal where no vertex can split), and hostile textures
//! refused from their headers.

use super::{parse_scene, parse_scene_headers};
use crate::bundle::{Bundle, ParsedBundle};
use crate::error::SceneErrorKind;
use crate::scene::estimate::{estimate, AssetSizes};
use std::collections::BTreeMap;
use std::path::Path;

fn bundle(scene: &str, files: &[(&str, Vec<u8>)]) -> Bundle {
    let mut map = BTreeMap::new();
    map.insert("s.xml".to_string(), scene.as_bytes().to_vec());
    for (n, b) in files {
        map.insert(n.to_string(), b.clone());
    }
    Bundle {
        scene: "s.xml".into(),
        files: map,
    }
}

#[track_caller]
fn agree(b: &Bundle) -> (u64, u64) {
    let full = parse_scene(&b.scene, b).unwrap();
    let h = parse_scene_headers(&b.scene, b).unwrap();
    assert!(h.desc.meshes.is_empty() && h.desc.textures.is_empty());
    assert_eq!(h.desc.cameras, full.cameras);
    assert_eq!(h.desc.files, full.files);
    assert_eq!(h.desc.models.len(), full.models.len());
    let sizes = AssetSizes::of(&full);
    assert_eq!(h.sizes.textures, sizes.textures);
    assert_eq!(h.sizes.triangle_surfaces, sizes.triangle_surfaces);
    for (a, b) in h.sizes.meshes.iter().zip(&sizes.meshes) {
        assert_eq!((a.triangles, a.uvs), (b.triangles, b.uvs));
        assert!(a.vertices >= b.vertices && a.file_vertices <= b.vertices);
    }
    let (from_headers, from_full) = (h.estimate().total(), estimate(&full).total());
    assert!(from_headers >= from_full, "{from_headers} < {from_full}");
    (from_headers, from_full)
}

#[test]
fn every_example_s_estimate_from_headers_is_at_least_the_full_one() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples");
    let mut seen = 0;
    for e in std::fs::read_dir(&dir).unwrap() {
        let path = e.unwrap().path();
        if path.extension().is_none_or(|x| x != "xml") {
            continue;
        }
        let ParsedBundle { bundle, .. } = ParsedBundle::from_scene_file(&path).unwrap();
        let (h, f) = agree(&bundle);
        // Only meshes whose vertices may split (vt or vn on every corner)
        // are counted above the full parse, by at most a vertex a corner.
        assert!(h <= f + f / 2, "{}: {h} vs {f}", path.display());
        seen += 1;
    }
    assert!(seen >= 5, "the examples are there");
}

const CAM: &str = r#"<camera id="c" position="0 0 5" lookat="0 0 0" fov="50"><render width="4" height="3"/></camera>"#;

#[test]
fn inline_obj_and_ply_meshes_with_textures_and_materials_agree() {
    let png = |w, h| crate::texture::tests::png_rgb8(w, h, &vec![9; (w * h * 3) as usize]);
    let obj = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n\
               usemtl a\nf 1/1 2/2 3/3\nusemtl b\nf 2/2 4/1 3/3\n";
    let mtl = "newmtl a\nmap_Kd t.png\nnewmtl b\nKd 1 0 0\n";
    let ply = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
               property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
               end_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n";
    let scene = format!(
        r#"<scene version="1">
  <mesh id="i"><vertices>0 0 0 1 0 0 0 1 0</vertices><uvs>0 0 1 0 0 1</uvs><triangles>0 1 2</triangles></mesh>
  <mesh id="o" file="o.obj"/>
  <mesh id="p" file="p.ply"/>
  <model id="a" mesh="i"><surface diffuse-texture="u.png"/></model>
  <model id="b" mesh="o"/>
  <model id="c" mesh="o"><surface/><surface triangles="1" emission="1 1 1"/></model>
  <model id="d" mesh="p"/>
  {CAM}
</scene>"#
    );
    let b = bundle(
        &scene,
        &[
            ("o.obj", obj.as_bytes().to_vec()),
            ("m.mtl", mtl.as_bytes().to_vec()),
            ("t.png", png(8, 4)),
            ("u.png", png(3, 5)),
            ("p.ply", ply.as_bytes().to_vec()),
        ],
    );
    agree(&b);
    let h = parse_scene_headers("s.xml", &b).unwrap();
    // Meshes first (with the textures of their materials), then models.
    assert_eq!(h.sizes.textures, vec![(8, 4), (3, 5)]);
    assert_eq!(h.sizes.triangle_surfaces, vec![0, 2, 2, 0]);
    assert!(h.desc.models.iter().all(|m| m.triangle_surface.is_empty()));
}

#[test]
fn scene_errors_are_the_full_parse_s() {
    for body in [
        r#"<mesh id="i"><vertices>0 0 0 1 0 0 0 1</vertices><triangles>0 1 2</triangles></mesh>"#,
        r#"<mesh id="i"><vertices>0 0 0 1 0 0 0 1 x</vertices><triangles>0 1 2</triangles></mesh>"#,
        r#"<mesh id="i"><vertices>0 0 0 1 0 0 0 1 0</vertices><triangles>0 1 3</triangles></mesh>"#,
        r#"<mesh id="i"><vertices>0 0 0 1 0 0 0 1 0</vertices><normals>0 0 1</normals><triangles>0 1 2</triangles></mesh>"#,
        r#"<mesh id="i"><vertices>0 0 0 1 0 0 0 1 0</vertices><triangles>0 1 2</triangles></mesh><model id="m" mesh="i"><surface triangles="1"/></model>"#,
        r#"<mesh id="i" file="none.obj"/>"#,
        r#"<model id="m" mesh="nothing"/>"#,
    ] {
        let b = bundle(
            &format!("<scene version=\"1\">\n{body}\n{CAM}</scene>"),
            &[],
        );
        let full = parse_scene("s.xml", &b).unwrap_err();
        let h = parse_scene_headers("s.xml", &b).unwrap_err();
        assert_eq!(h, full, "{body}");
    }
}

#[test]
fn a_hostile_texture_is_refused_from_its_headers() {
    let scene = format!(
        r#"<scene version="1">
  <mesh id="i"><vertices>0 0 0 1 0 0 0 1 0</vertices><uvs>0 0 1 0 0 1</uvs><triangles>0 1 2</triangles></mesh>
  <model id="a" mesh="i"><surface diffuse-texture="t.exr"/></model>
  {CAM}
</scene>"#
    );
    let exr = crate::texture::header::tests::hostile_two_part_exr(65_536);
    let b = bundle(&scene, &[("t.exr", exr)]);
    for e in [
        parse_scene_headers("s.xml", &b).unwrap_err(),
        parse_scene("s.xml", &b).unwrap_err(),
    ] {
        assert_eq!(e.kind, SceneErrorKind::Limit, "{e}");
        assert_eq!((e.location.line, e.location.column), (3, 35), "{e}");
        assert!(e.message.contains("65536 x 65536"), "{e}");
    }
}
