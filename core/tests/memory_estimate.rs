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
use trevi_core::scene::estimate::{estimate, human_bytes, ESTIMATE_FACTOR, FIXED_BYTES};
use trevi_core::{Bundle, ParsedBundle, Rect, Scene};

mod meter {
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};

    pub struct Meter;

    static HELD: AtomicUsize = AtomicUsize::new(0);
    static PEAK: AtomicUsize = AtomicUsize::new(0);

    fn add(n: usize) {
        let v = HELD.fetch_add(n, Relaxed) + n;
        PEAK.fetch_max(v, Relaxed);
    }

    fn sub(n: usize) {
        HELD.fetch_sub(n, Relaxed);
    }

    unsafe impl GlobalAlloc for Meter {
        unsafe fn alloc(&self, l: Layout) -> *mut u8 {
            let p = unsafe { System.alloc(l) };
            if !p.is_null() {
                add(l.size());
            }
            p
        }
        unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
            let p = unsafe { System.alloc_zeroed(l) };
            if !p.is_null() {
                add(l.size());
            }
            p
        }
        unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
            unsafe { System.dealloc(p, l) };
            sub(l.size());
        }
        unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
            let q = unsafe { System.realloc(p, l, new) };
            if !q.is_null() {
                sub(l.size());
                add(new);
            }
            q
        }
    }

    pub fn held() -> usize {
        HELD.load(Relaxed)
    }

    /// Starts a new peak from what is held now.
    pub fn reset_peak() {
        PEAK.store(HELD.load(Relaxed), Relaxed);
    }

    pub fn peak() -> usize {
        PEAK.load(Relaxed)
    }
}

#[global_allocator]
static METER: meter::Meter = meter::Meter;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn shared_meshes() -> PathBuf {
    repo().join("../shared/meshes")
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
    let sm = shared_meshes();
    let example = |name: &'static str| Case {
        name,
        bundle: Bundle::from_scene_file(&ex.join(name)).expect("example bundles"),
    };
    vec![
        example("cornell.xml"),
        example("instancing.xml"),
        example("turntable.xml"),
        Case {
            name: "nefertiti (99,938 triangles)",
            bundle: bundle(
                &mesh_scene("n.obj", r#"diffuse="0.8 0.8 0.8""#, 1),
                &[("n.obj", read(&sm.join("nefertiti.obj")))],
            ),
        },
        Case {
            name: "nefertiti x 50 instances",
            bundle: bundle(
                &mesh_scene("n.obj", r#"diffuse="0.8 0.8 0.8""#, 50),
                &[("n.obj", read(&sm.join("nefertiti.obj")))],
            ),
        },
        Case {
            name: "teapot",
            bundle: bundle(
                &mesh_scene("t.obj", r#"diffuse="0.8 0.8 0.8""#, 1),
                &[("t.obj", read(&sm.join("teapot.obj")))],
            ),
        },
        Case {
            name: "spot textured (1024x1024)",
            bundle: bundle(
                &mesh_scene("s.obj", r#"diffuse="1 1 1" diffuse-texture="s.png""#, 1),
                &[
                    ("s.obj", read(&sm.join("spot/spot_triangulated.obj"))),
                    ("s.png", read(&sm.join("spot/spot_texture.png"))),
                ],
            ),
        },
        Case {
            name: "bob textured (2048x2048)",
            bundle: bundle(
                &mesh_scene("b.obj", r#"diffuse="1 1 1" diffuse-texture="b.png""#, 1),
                &[
                    ("b.obj", read(&sm.join("bob/bob_tri.obj"))),
                    ("bob_tri.mtl", read(&sm.join("bob/bob_tri.mtl"))),
                    ("bob_diffuse.png", read(&sm.join("bob/bob_diffuse.png"))),
                    ("b.png", read(&sm.join("bob/bob_diffuse.png"))),
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
        let before_desc = meter::held();
        let desc_copy = desc.clone();
        let desc_bytes = meter::held() - before_desc;
        drop(desc_copy);

        let base = meter::held();
        meter::reset_peak();
        let scene = Scene::build(desc);
        // The camera's view is built by its first render.
        let _ = trevi_core::render_tile(&scene, 0, Rect::new(0, 0, 1, 1));
        let _ = scene.world_view();
        let built = meter::held() - base + desc_bytes;
        let peak = meter::peak() - base + desc_bytes;
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
