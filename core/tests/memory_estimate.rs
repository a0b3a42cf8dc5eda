//! The memory estimate (`trevi_core::scene::estimate`) against what real
//! scenes take: a counting global allocator measures the heap held while a
//! scene is built from its description and once it is built (with its
//! camera's view), and the estimate must be at least the first (what a
//! worker's `--max-memory` has to allow) and at most `ESTIMATE_FACTOR`
//! times it plus `FIXED_BYTES` (so a worker does not turn down scenes it
//! could hold). What the built scene keeps afterwards is reported beside
//! (`--nocapture`): building a mesh holds about three times what it keeps.
//!
//! One test function: the allocator counts every thread (the BVH builder
//! runs on rayon's), so nothing else may allocate meanwhile.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use trevi_core::alloc_meter::{self, AllocMeter};
use trevi_core::math::{cos, sin};
use trevi_core::scene::estimate::{estimate, human_bytes, ESTIMATE_FACTOR, FIXED_BYTES};
use trevi_core::{Bundle, ParsedBundle, Rect, Scene};

#[global_allocator]
static METER: AllocMeter = AllocMeter;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The meshes kept in the repository (core/tests/data, with their licences).
fn data() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data")
}

/// A sphere of `stacks` × `slices` with lumps (so the BVH is not a grid),
/// as OBJ text without `vt`: 2 + (stacks − 1)·slices vertices and
/// 2·slices·(stacks − 1) triangles. Stands in for a scan such as the
/// Nefertiti bust, which stays out of the repository.
fn lumpy_sphere(stacks: usize, slices: usize) -> Vec<u8> {
    use std::fmt::Write;
    let mut s = String::new();
    let v = |s: &mut String, th: f64, ph: f64| {
        let r = 1.0 + 0.05 * sin(7.0 * th) * cos(5.0 * ph) + 0.02 * sin(31.0 * ph + 3.0 * th);
        let (x, y, z) = (r * sin(th) * cos(ph), r * cos(th), r * sin(th) * sin(ph));
        writeln!(s, "v {x:.6} {y:.6} {z:.6}").unwrap();
    };
    let pi = std::f64::consts::PI;
    v(&mut s, 0.0, 0.0);
    for i in 1..stacks {
        for j in 0..slices {
            v(
                &mut s,
                pi * i as f64 / stacks as f64,
                2.0 * pi * j as f64 / slices as f64,
            );
        }
    }
    v(&mut s, pi, 0.0);
    let ring = |i: usize, j: usize| 2 + (i - 1) * slices + j % slices;
    let last = 2 + (stacks - 1) * slices;
    for j in 0..slices {
        writeln!(s, "f 1 {} {}", ring(1, j + 1), ring(1, j)).unwrap();
        writeln!(
            s,
            "f {last} {} {}",
            ring(stacks - 1, j),
            ring(stacks - 1, j + 1)
        )
        .unwrap();
    }
    for i in 1..stacks - 1 {
        for j in 0..slices {
            let (a, b, c, d) = (
                ring(i, j),
                ring(i, j + 1),
                ring(i + 1, j),
                ring(i + 1, j + 1),
            );
            writeln!(s, "f {a} {b} {d}\nf {a} {d} {c}").unwrap();
        }
    }
    s.into_bytes()
}

/// A closed cylinder wall of `slices` × `rows` positions with texture
/// coordinates and a seam (the first column's positions carry u = 0 and
/// u = 1), naming the material library `mtl` (material `m`), as Bob's OBJ
/// does: (slices + 1)·rows vertices once split, 2·slices·(rows − 1)
/// triangles.
fn textured_cylinder(slices: usize, rows: usize, mtl: &str) -> Vec<u8> {
    use std::fmt::Write;
    let mut s = String::new();
    for r in 0..rows {
        for j in 0..slices {
            let a = 2.0 * std::f64::consts::PI * j as f64 / slices as f64;
            writeln!(
                s,
                "v {:.6} {:.6} {:.6}",
                cos(a),
                r as f64 / rows as f64,
                sin(a)
            )
            .unwrap();
        }
    }
    for r in 0..rows {
        for j in 0..=slices {
            writeln!(
                s,
                "vt {:.6} {:.6}",
                j as f64 / slices as f64,
                r as f64 / (rows - 1) as f64
            )
            .unwrap();
        }
    }
    writeln!(s, "mtllib {mtl}\nusemtl m").unwrap();
    let p = |r: usize, j: usize| 1 + r * slices + j % slices;
    let t = |r: usize, j: usize| 1 + r * (slices + 1) + j;
    for r in 0..rows - 1 {
        for j in 0..slices {
            let (a, b, c, d) = ((r, j), (r, j + 1), (r + 1, j), (r + 1, j + 1));
            let c3 = |(r, j): (usize, usize)| format!("{}/{}", p(r, j), t(r, j));
            writeln!(
                s,
                "f {} {} {}\nf {} {} {}",
                c3(a),
                c3(b),
                c3(d),
                c3(a),
                c3(d),
                c3(c)
            )
            .unwrap();
        }
    }
    s.into_bytes()
}

/// An 8-bit RGB PNG of `size` × `size` with a pattern that does not
/// compress away (what a painted texture decodes to is its size alone).
fn png(size: u32) -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, size, size);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    let mut w = enc.write_header().unwrap();
    let mut x = 0x9e37_79b9_u32;
    let pixels: Vec<u8> = (0..size * size * 3)
        .map(|i| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            ((i / 3 % size) as u8).wrapping_add((x & 15) as u8)
        })
        .collect();
    w.write_image_data(&pixels).unwrap();
    w.finish().unwrap();
    out
}

/// A bundle of `xml` and the given files (bundle path, bytes).
fn bundle(xml: &str, files: &[(&str, Vec<u8>)]) -> Bundle {
    let mut map = BTreeMap::new();
    map.insert("scene.xml".to_string(), xml.as_bytes().to_vec());
    for (p, b) in files {
        map.insert(p.to_string(), b.clone());
    }
    Bundle {
        scene: "scene.xml".into(),
        files: map,
    }
}

fn read(p: &Path) -> Vec<u8> {
    std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// A mesh from a file, seen by one camera, under one light.
fn mesh_scene(file: &str, surface: &str, models: usize) -> String {
    let models: String = (0..models)
        .map(|i| {
            format!(
                r#"<model id="m{i}" mesh="m"><transform><translate v="{} 0 0"/></transform><surface {surface}/></model>"#,
                i * 3
            )
        })
        .collect();
    format!(
        r#"<scene version="1">
  <mesh id="m" file="{file}"/>
  {models}
  <light type="point" position="5 5 5" color="1 1 1" intensity="1"/>
  <camera id="c" position="0 0 4" lookat="0 0 0" fov="45"><render width="32" height="32"/></camera>
</scene>"#
    )
}

struct Case {
    name: &'static str,
    bundle: Bundle,
}

fn cases() -> Vec<Case> {
    let ex = repo().join("examples");
    let spot = data().join("spot");
    let example = |name: &'static str| Case {
        name,
        bundle: Bundle::from_scene_file(&ex.join(name)).expect("example bundles"),
    };
    // The size of the Nefertiti scan (99,938 triangles, no uvs).
    let bust = lumpy_sphere(159, 316);
    vec![
        example("cornell.xml"),
        example("instancing.xml"),
        example("turntable.xml"),
        Case {
            name: "lumpy sphere (99,856 triangles)",
            bundle: bundle(
                &mesh_scene("n.obj", r#"diffuse="0.8 0.8 0.8""#, 1),
                &[("n.obj", bust.clone())],
            ),
        },
        Case {
            name: "lumpy sphere x 50 instances",
            bundle: bundle(
                &mesh_scene("n.obj", r#"diffuse="0.8 0.8 0.8""#, 50),
                &[("n.obj", bust)],
            ),
        },
        Case {
            name: "lumpy sphere (6,400 triangles)",
            bundle: bundle(
                &mesh_scene("t.obj", r#"diffuse="0.8 0.8 0.8""#, 1),
                &[("t.obj", lumpy_sphere(41, 80))],
            ),
        },
        Case {
            name: "spot textured (1024x1024)",
            bundle: bundle(
                &mesh_scene("s.obj", r#"diffuse="1 1 1" diffuse-texture="s.png""#, 1),
                &[
                    ("s.obj", read(&spot.join("spot_triangulated.obj"))),
                    ("s.png", read(&spot.join("spot_texture.png"))),
                ],
            ),
        },
        // Bob's shape: an OBJ naming a library whose map_Kd is a 2048² PNG,
        // and the same PNG again as the model's diffuse texture.
        Case {
            name: "textured cylinder (2048x2048)",
            bundle: bundle(
                &mesh_scene("b.obj", r#"diffuse="1 1 1" diffuse-texture="b.png""#, 1),
                &[
                    ("b.obj", textured_cylinder(96, 57, "b.mtl")),
                    ("b.mtl", b"newmtl m\nmap_Kd b_diffuse.png\n".to_vec()),
                    ("b_diffuse.png", png(2048)),
                    ("b.png", png(2048)),
                ],
            ),
        },
    ]
}

#[test]
fn the_estimate_bounds_the_peak_of_the_build_and_stays_within_its_factor_of_it() {
    let mut report = String::new();
    let mut failures = Vec::new();
    for case in cases() {
        let parsed = ParsedBundle::parse(case.bundle).expect("the scene parses");
        let desc = parsed.desc;
        drop(parsed.bundle);
        let est = estimate(&desc).total();
        // What the description holds already counts: the built scene keeps it.
        let before_desc = alloc_meter::held();
        let desc_copy = desc.clone();
        let desc_bytes = alloc_meter::held() - before_desc;
        drop(desc_copy);

        let base = alloc_meter::held();
        alloc_meter::reset_peak();
        let scene = Scene::build(desc);
        // The camera's view is built by its first render.
        let _ = trevi_core::render_tile(&scene, 0, Rect::new(0, 0, 1, 1));
        let _ = scene.world_view();
        let built = alloc_meter::held() - base + desc_bytes;
        let peak = alloc_meter::peak() - base + desc_bytes;
        drop(scene);

        let ratio = est as f64 / peak as f64;
        report.push_str(&format!(
            "{:<30} estimate {:>10} ({}), peak {:>10}, built {:>10}, estimate/peak {ratio:.2}\n",
            case.name,
            est,
            human_bytes(est),
            peak,
            built
        ));
        if (est as usize) < peak {
            failures.push(format!("{}: estimate {est} < peak {peak}", case.name));
        }
        if est as f64 > ESTIMATE_FACTOR * peak as f64 + FIXED_BYTES as f64 {
            failures.push(format!(
                "{}: estimate {est} is {ratio:.2} x the peak {peak}",
                case.name
            ));
        }
    }
    println!("{report}");
    assert!(failures.is_empty(), "{}\n{report}", failures.join("\n"));
}
