//! `trevi-bench`: BVH build and ray traversal of trevi-core measured side by
//! side with Embree 3, plus end-to-end frame renders. Nothing here asserts a
//! timing; it prints figures. `bench/run.sh` is the one command.
//!
//! ```text
//! trevi-bench micro --out DIR --meshes ../shared/meshes --embree bench/embree/embree_bench [--reps 5] [--threads 2]
//! trevi-bench render SCENE.xml CAMERA [--threads 2]
//! trevi-bench mix SCENE.xml CAMERA [--every 16] [--reps 3] [--threads 2]
//! ```
//!
//! `micro` writes, per mesh, `DIR/<name>.mesh` (u32 vertex count, u32
//! triangle count, f32 xyz per vertex, u32 ×3 per triangle) and one ray file
//! per ray type, `DIR/<name>.<type>.rays` (u32 count, then f32 ox oy oz dx dy
//! dz t_max per ray), which the Embree program reads. Each repetition times
//! Trevi and then runs the Embree program on the same files, so the two are
//! measured interleaved in one run; the best repetition of each is reported.
//!
//! `mix` answers "how much of a render is traversal": it renders every
//! `every`-th 64×64 tile of a camera's frame (timed, as `render` does), then
//! renders the same tiles again on one thread recording every ray the
//! integrator traces ([`RayObserver`]), and times tracing exactly those rays,
//! in the order they were traced, with nothing else: the same ray mix.

use glam::{DMat4, Vec3};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;
use trevi_core::alloc_meter::{self, AllocMeter};
use trevi_core::bvh::MeshBvh;
use trevi_core::geometry::offset_ray_origin;
use trevi_core::integrator::{RayObserver, RenderOptions};
use trevi_core::math;
use trevi_core::mesh::Mesh;
use trevi_core::scene::{Model, Surface};
use trevi_core::world::HitKind;
use trevi_core::{Scene, SceneDesc};

/// Counts live heap bytes, for the memory figures.
#[global_allocator]
static GLOBAL: AllocMeter = AllocMeter;

fn live() -> usize {
    alloc_meter::held()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let opt = |name: &str| -> Option<String> {
        args.iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1).cloned())
    };
    let threads: usize = opt("--threads").map_or(2, |s| s.parse().expect("--threads"));
    // Trevi's parallel BVH build and the renders use rayon's pool.
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build_global()
        .expect("rayon pool");
    match args.get(1).map(String::as_str) {
        Some("micro") => {
            let out = PathBuf::from(opt("--out").expect("--out DIR"));
            let meshes = PathBuf::from(opt("--meshes").unwrap_or("../shared/meshes".into()));
            let embree = opt("--embree").map(PathBuf::from);
            let reps: usize = opt("--reps").map_or(5, |s| s.parse().expect("--reps"));
            std::fs::create_dir_all(&out).expect("create --out");
            micro(&out, &meshes, embree.as_deref(), reps, threads);
        }
        Some("mix") => {
            let scene = args.get(2).expect("mix SCENE.xml CAMERA");
            let camera = args.get(3).expect("mix SCENE.xml CAMERA");
            let every: usize = opt("--every").map_or(16, |s| s.parse().expect("--every"));
            let reps: usize = opt("--reps").map_or(3, |s| s.parse().expect("--reps"));
            mix(Path::new(scene), camera, every.max(1), reps.max(1), threads);
        }
        Some("render") => {
            let scene = args.get(2).expect("render SCENE.xml CAMERA");
            let camera = args.get(3).expect("render SCENE.xml CAMERA");
            render(Path::new(scene), camera, threads);
        }
        _ => {
            eprintln!("usage: trevi-bench micro --out DIR [--meshes DIR] [--embree PATH] [--reps N] [--threads N]\n       trevi-bench render SCENE.xml CAMERA [--threads N]\n       trevi-bench mix SCENE.xml CAMERA [--every N] [--reps N] [--threads N]");
            std::process::exit(2);
        }
    }
}

// ---------------------------------------------------------------- meshes

/// A bumpy torus of `2·nu·nv` triangles: deterministic, closed, with
/// curvature at several scales so the BVH is not a regular grid.
fn procedural_torus(nu: u32, nv: u32) -> Mesh {
    let mut positions = Vec::with_capacity((nu * nv) as usize);
    for i in 0..nu {
        let th = std::f64::consts::TAU * i as f64 / nu as f64;
        for j in 0..nv {
            let ph = std::f64::consts::TAU * j as f64 / nv as f64;
            let bump = 1.0
                + 0.12 * math::sin(9.0 * th) * math::cos(7.0 * ph)
                + 0.04 * math::sin(37.0 * th + 3.0 * ph) * math::sin(23.0 * ph)
                + 0.01 * math::cos(151.0 * th) * math::sin(97.0 * ph);
            let r = 0.35 * bump;
            let ring = 1.0 + r * math::cos(ph);
            positions.push(Vec3::new(
                (ring * math::cos(th)) as f32,
                (r * math::sin(ph)) as f32,
                (ring * math::sin(th)) as f32,
            ));
        }
    }
    let mut triangles = Vec::with_capacity((2 * nu * nv) as usize);
    let idx = |i: u32, j: u32| (i % nu) * nv + (j % nv);
    for i in 0..nu {
        for j in 0..nv {
            let (a, b, c, d) = (idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1));
            triangles.push([a, c, b]);
            triangles.push([a, d, c]);
        }
    }
    let mut m = Mesh {
        positions,
        normals: Vec::new(),
        uvs: Vec::new(),
        triangles,
    };
    m.compute_smooth_normals();
    m
}

fn write_mesh(path: &Path, m: &Mesh) {
    let mut b = Vec::with_capacity(8 + m.positions.len() * 12 + m.triangles.len() * 12);
    b.extend_from_slice(&(m.positions.len() as u32).to_le_bytes());
    b.extend_from_slice(&(m.triangles.len() as u32).to_le_bytes());
    for p in &m.positions {
        for c in p.to_array() {
            b.extend_from_slice(&c.to_le_bytes());
        }
    }
    for t in &m.triangles {
        for i in t {
            b.extend_from_slice(&i.to_le_bytes());
        }
    }
    std::fs::write(path, b).expect("write mesh");
}

fn scene_of(mesh: Mesh, instances: usize) -> Scene {
    let models = (0..instances)
        .map(|i| Model {
            id: format!("m{i}"),
            mesh: 0,
            transform: DMat4::from_translation(glam::DVec3::new(3.0 * i as f64, 0.0, 0.0)),
            surfaces: vec![Surface::default()],
            triangle_surface: Vec::new(),
        })
        .collect();
    Scene::build(SceneDesc {
        meshes: vec![mesh],
        models,
        ..Default::default()
    })
}

/// The BLAS build exactly as `world::Scene::build` does it (tree, the
/// mesh renumbered in leaf order, the triangle packs).
fn build_blas(m: &mut Mesh) -> MeshBvh {
    MeshBvh::build(m).0
}

// ---------------------------------------------------------------- rays

#[derive(Clone, Copy)]
struct R {
    o: Vec3,
    d: Vec3,
    t_max: f32,
}

fn write_rays(path: &Path, rays: &[R]) {
    let mut b = Vec::with_capacity(4 + rays.len() * 28);
    b.extend_from_slice(&(rays.len() as u32).to_le_bytes());
    for r in rays {
        for c in [r.o.x, r.o.y, r.o.z, r.d.x, r.d.y, r.d.z, r.t_max] {
            b.extend_from_slice(&c.to_le_bytes());
        }
    }
    std::fs::write(path, b).expect("write rays");
}

fn unit_pair(h: u64) -> [f32; 2] {
    [
        (h >> 40) as f32 / (1u64 << 24) as f32,
        ((h >> 16) & 0xff_ffff) as f32 / (1u64 << 24) as f32,
    ]
}

/// Primary rays of a pinhole camera framing the mesh, in 8×8-pixel blocks
/// (the order a tile renderer traces them); then shadow rays from each hit
/// to a point light, and cosine-distributed rays from each hit.
fn make_rays(scene: &Scene, side: u32, from: Vec3, up: Vec3) -> (Vec<R>, Vec<R>, Vec<R>) {
    let b = scene.bounds;
    let c = b.center();
    let rad = 0.5 * b.diagonal();
    let fwd_from = from.normalize();
    let eye = c + fwd_from * 2.2 * rad;
    let fwd = -fwd_from;
    let right = fwd.cross(up).normalize();
    let up = right.cross(fwd);
    let th = 0.42f32;
    let mut primary = Vec::with_capacity((side * side) as usize);
    for by in (0..side).step_by(8) {
        for bx in (0..side).step_by(8) {
            for y in by..(by + 8).min(side) {
                for x in bx..(bx + 8).min(side) {
                    let sx = (2.0 * (x as f32 + 0.5) / side as f32 - 1.0) * th;
                    let sy = (1.0 - 2.0 * (y as f32 + 0.5) / side as f32) * th;
                    primary.push(R {
                        o: eye,
                        d: (fwd + right * sx + up * sy).normalize(),
                        t_max: f32::INFINITY,
                    });
                }
            }
        }
    }
    let light = c + (fwd_from + up + right * 0.5).normalize() * 3.0 * rad;
    let mesh = &scene.desc.meshes[0];
    let mut shadow = Vec::new();
    let mut incoherent = Vec::new();
    for (i, r) in primary.iter().enumerate() {
        let Some(h) = scene.intersect(r.o, r.d, r.t_max) else {
            continue;
        };
        let HitKind::Triangle { triangle, .. } = h.kind else {
            continue;
        };
        let [a, b2, c2] = mesh.triangles[triangle as usize].map(|i| mesh.positions[i as usize]);
        let mut n = (b2 - a).cross(c2 - a).normalize_or_zero();
        if n.dot(r.d) > 0.0 {
            n = -n;
        }
        let p = offset_ray_origin(r.o + r.d * h.t, n);
        shadow.push(R {
            o: p,
            d: light - p,
            t_max: 1.0,
        });
        let u = unit_pair(trevi_core::sampling::hash2(0x5eed, i as u64));
        incoherent.push(R {
            o: p,
            d: trevi_core::sampling::cosine_hemisphere(n, u),
            t_max: f32::INFINITY,
        });
    }
    (primary, shadow, incoherent)
}

// ---------------------------------------------------------------- timing

#[derive(Clone, Copy, PartialEq)]
enum Query {
    Closest,
    AnyHit,
}

/// CPU time of the calling thread in seconds (`/proc/thread-self/schedstat`,
/// nanoseconds): on a shared machine, throughput per CPU-second is far less
/// noisy than per wall-clock second.
fn thread_cpu() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .map_or(0.0, |ns| ns as f64 * 1e-9)
}

/// CPU time of the whole process in seconds: the sum over its threads
/// (rayon's pool persists, so before/after differences are exact).
fn process_cpu() -> f64 {
    let Ok(dir) = std::fs::read_dir("/proc/self/task") else {
        return 0.0;
    };
    dir.filter_map(|e| std::fs::read_to_string(e.ok()?.path().join("schedstat")).ok())
        .filter_map(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .map(|ns| ns as f64 * 1e-9)
        .sum()
}

/// Traces `rays` on `threads` threads (chunks of 256 handed out in order);
/// returns (wall seconds, CPU seconds of the tracing threads, hits).
fn trace(scene: &Scene, rays: &[R], q: Query, threads: usize) -> (f64, f64, usize) {
    trace_with(rays, threads, |r| match q {
        Query::Closest => scene.intersect(r.o, r.d, r.t_max).is_some(),
        Query::AnyHit => scene.transmittance(r.o, r.d, r.t_max) == 0.0,
    })
}

/// Runs `hit` over `rays` on `threads` threads, chunks of 256 handed out in
/// order; returns (wall seconds, CPU seconds of those threads, hits).
fn trace_with<T: Sync>(
    rays: &[T],
    threads: usize,
    hit: impl Fn(&T) -> bool + Sync,
) -> (f64, f64, usize) {
    const CHUNK: usize = 256;
    let next = AtomicUsize::new(0);
    let hits = AtomicUsize::new(0);
    let cpu_ns = AtomicUsize::new(0);
    let t0 = Instant::now();
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| {
                let c0 = thread_cpu();
                let mut local = 0;
                loop {
                    let start = next.fetch_add(CHUNK, Ordering::Relaxed);
                    if start >= rays.len() {
                        break;
                    }
                    for r in &rays[start..(start + CHUNK).min(rays.len())] {
                        local += hit(r) as usize;
                    }
                }
                hits.fetch_add(local, Ordering::Relaxed);
                cpu_ns.fetch_add(((thread_cpu() - c0) * 1e9) as usize, Ordering::Relaxed);
            });
        }
    });
    (
        t0.elapsed().as_secs_f64(),
        cpu_ns.load(Ordering::Relaxed) as f64 * 1e-9,
        hits.load(Ordering::Relaxed),
    )
}

/// The best (least) wall-clock and CPU time over the repetitions.
#[derive(Default, Clone)]
struct Best {
    secs: f64,
    cpu: f64,
    hits: usize,
}

impl Best {
    fn add(&mut self, secs: f64, hits: usize) {
        if self.secs == 0.0 || secs < self.secs {
            self.secs = secs;
        }
        self.hits = hits;
    }

    fn add_cpu(&mut self, cpu: f64) {
        if self.cpu == 0.0 || cpu < self.cpu {
            self.cpu = cpu;
        }
    }
}

const TYPES: [(&str, Query); 3] = [
    ("primary", Query::Closest),
    ("shadow", Query::AnyHit),
    ("incoherent", Query::Closest),
];

struct MeshReport {
    name: String,
    tris: usize,
    build: Best,
    sah: f32,
    bytes_per_tri: f64,
    bytes_per_instance: f64,
    rays: [usize; 3],
    trevi: [Best; 3],
    embree_scene_build: Best,
    embree_bvh2_build: Best,
    embree_sah: f64,
    embree_bytes: f64,
    embree: [Best; 3],
}

fn micro(out: &Path, meshes: &Path, embree: Option<&Path>, reps: usize, threads: usize) {
    let mut reports = Vec::new();
    for name in ["procedural-torus", "nefertiti"] {
        let mesh = if name == "nefertiti" {
            let path = meshes.join("nefertiti.obj");
            let bytes = std::fs::read(&path).unwrap_or_else(|e| {
                panic!(
                    "{}: {e} (CI keeps ../shared beside the checkout)",
                    path.display()
                )
            });
            trevi_core::mesh::obj::parse("nefertiti.obj", &bytes).expect("parse nefertiti.obj")
        } else {
            procedural_torus(1000, 500)
        };
        let tris = mesh.triangles.len();
        eprintln!("{name}: {tris} triangles");
        let mesh_file = out.join(format!("{name}.mesh"));
        write_mesh(&mesh_file, &mesh);

        // Memory: everything the scene holds (mesh, normals, BLAS, TLAS,
        // instance records), then the cost of 999 more instances.
        let before = live();
        let scene = scene_of(mesh.clone(), 1);
        let one = live() - before;
        let bytes_per_tri = one as f64 / tris as f64;
        let scene_k = scene_of(mesh.clone(), 1000);
        let thousand = live() - before - one;
        let bytes_per_instance = (thousand as f64 - one as f64) / 999.0;
        drop(scene_k);

        // Views: the torus from above at an angle; the bust (z up) from the front.
        let (from, up) = if name == "nefertiti" {
            (Vec3::new(0.3, -1.0, 0.15), Vec3::Z)
        } else {
            (Vec3::new(0.35, 1.0, 0.6), Vec3::Y)
        };
        let (primary, shadow, incoherent) = make_rays(&scene, 1024, from, up);
        let sets = [primary, shadow, incoherent];
        let mut ray_files = Vec::new();
        for ((t, _), rays) in TYPES.iter().zip(&sets) {
            let f = out.join(format!("{name}.{t}.rays"));
            write_rays(&f, rays);
            ray_files.push(f);
        }
        let mut rep = MeshReport {
            name: name.to_string(),
            tris,
            build: Best::default(),
            sah: 0.0,
            bytes_per_tri,
            bytes_per_instance,
            rays: [sets[0].len(), sets[1].len(), sets[2].len()],
            trevi: Default::default(),
            embree_scene_build: Best::default(),
            embree_bvh2_build: Best::default(),
            embree_sah: 0.0,
            embree_bytes: 0.0,
            embree: Default::default(),
        };
        for r in 0..reps {
            eprintln!("  repetition {}/{reps}", r + 1);
            // The mesh as the file gave it: the scene's copy is already in
            // leaf order, which would flatter the build.
            let mut copy = mesh.clone();
            let (t0, c0) = (Instant::now(), process_cpu());
            let bvh = build_blas(&mut copy);
            rep.build.add(t0.elapsed().as_secs_f64(), 0);
            rep.build.add_cpu(process_cpu() - c0);
            rep.sah = bvh.sah_cost();
            drop(bvh);
            drop(copy);
            for (k, (_, q)) in TYPES.iter().enumerate() {
                let (s, cpu, h) = trace(&scene, &sets[k], *q, threads);
                rep.trevi[k].add(s, h);
                rep.trevi[k].add_cpu(cpu);
            }
            if let Some(exe) = embree {
                let o = std::process::Command::new(exe)
                    .arg(threads.to_string())
                    .arg(&mesh_file)
                    .args(&ray_files)
                    .output()
                    .expect("run the Embree benchmark (bench/run.sh builds it)");
                if !o.status.success() {
                    panic!(
                        "embree_bench failed: {}",
                        String::from_utf8_lossy(&o.stderr)
                    );
                }
                for line in String::from_utf8_lossy(&o.stdout).lines() {
                    let w: Vec<&str> = line.split_whitespace().collect();
                    match w.as_slice() {
                        ["scene_build", s, cpu, bytes] => {
                            rep.embree_scene_build.add(s.parse().unwrap(), 0);
                            rep.embree_scene_build.add_cpu(cpu.parse().unwrap());
                            rep.embree_bytes = bytes.parse().unwrap();
                        }
                        ["bvh2_build", s, cpu, sah] => {
                            rep.embree_bvh2_build.add(s.parse().unwrap(), 0);
                            rep.embree_bvh2_build.add_cpu(cpu.parse().unwrap());
                            rep.embree_sah = sah.parse().unwrap();
                        }
                        [ty, _n, hits, s, cpu] => {
                            if let Some(k) = TYPES.iter().position(|(t, _)| t == ty) {
                                rep.embree[k].add(s.parse().unwrap(), hits.parse().unwrap());
                                rep.embree[k].add_cpu(cpu.parse().unwrap());
                            }
                        }
                        _ => {}
                    }
                }
            }
        }
        drop(scene);
        reports.push(rep);
    }
    print_report(&reports, threads, reps, embree.is_some());
}

fn print_report(reports: &[MeshReport], threads: usize, reps: usize, embree: bool) {
    let mut o = std::io::stdout().lock();
    let mrays = |n: usize, b: &Best| n as f64 / b.secs / 1e6;
    writeln!(
        o,
        "\nBest of {reps} interleaved repetitions, {threads} threads for traversal.\n"
    )
    .unwrap();
    writeln!(o, "### BVH build\n").unwrap();
    writeln!(o, "M tri/s: million triangles per wall-clock second (CPU: per CPU-second, all threads). Trevi builds with rayon on {threads} threads, Embree with {threads} TBB threads.\n").unwrap();
    writeln!(o, "| mesh | triangles | Trevi build | Trevi SAH | Embree scene build | Embree BVH2 build | Embree BVH2 SAH | Trevi / Embree scene (wall) | Trevi / Embree scene (CPU) |").unwrap();
    writeln!(o, "|---|---:|---:|---:|---:|---:|---:|---:|---:|").unwrap();
    let rate = |n: usize, b: &Best| {
        format!(
            "{:.3} s = {:.2} M tri/s ({:.2} CPU)",
            b.secs,
            n as f64 / b.secs / 1e6,
            n as f64 / b.cpu / 1e6
        )
    };
    for r in reports {
        if embree {
            writeln!(
                o,
                "| {} | {} | {} | {:.1} | {} | {} | {:.1} | **{:.2}** | **{:.2}** |",
                r.name,
                r.tris,
                rate(r.tris, &r.build),
                r.sah,
                rate(r.tris, &r.embree_scene_build),
                rate(r.tris, &r.embree_bvh2_build),
                r.embree_sah,
                r.embree_scene_build.secs / r.build.secs,
                r.embree_scene_build.cpu / r.build.cpu,
            )
            .unwrap();
        } else {
            writeln!(
                o,
                "| {} | {} | {} | {:.1} | – | – | – | – | – |",
                r.name,
                r.tris,
                rate(r.tris, &r.build),
                r.sah
            )
            .unwrap();
        }
    }
    writeln!(
        o,
        "\n### Traversal, {threads} threads\n\nMrays/s: rays per wall-clock second; M/CPU-s: rays per CPU-second of the tracing threads.\n"
    )
    .unwrap();
    writeln!(o, "| mesh | ray type | rays | Trevi hits | Embree hits | Trevi Mrays/s | Embree Mrays/s | Trevi / Embree | Trevi M/CPU-s | Embree M/CPU-s | Trevi / Embree (CPU) |").unwrap();
    writeln!(o, "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|").unwrap();
    let per_cpu = |n: usize, b: &Best| n as f64 / b.cpu / 1e6;
    for r in reports {
        for (k, (ty, _)) in TYPES.iter().enumerate() {
            let t = mrays(r.rays[k], &r.trevi[k]);
            let tc = per_cpu(r.rays[k], &r.trevi[k]);
            if embree {
                let e = mrays(r.rays[k], &r.embree[k]);
                let ec = per_cpu(r.rays[k], &r.embree[k]);
                writeln!(
                    o,
                    "| {} | {} | {} | {} | {} | {:.2} | {:.2} | **{:.2}** | {:.2} | {:.2} | **{:.2}** |",
                    r.name, ty, r.rays[k], r.trevi[k].hits, r.embree[k].hits, t, e, t / e, tc, ec, tc / ec
                )
                .unwrap();
            } else {
                writeln!(
                    o,
                    "| {} | {} | {} | {} | – | {:.2} | – | – | {:.2} | – | – |",
                    r.name, ty, r.rays[k], r.trevi[k].hits, t, tc
                )
                .unwrap();
            }
        }
    }
    writeln!(o, "\n### Memory\n").unwrap();
    writeln!(o, "| mesh | Trevi bytes/triangle (mesh + normals + BVHs + instance) | Trevi bytes per extra instance | Embree bytes/triangle (BVH + mesh buffers) |").unwrap();
    writeln!(o, "|---|---:|---:|---:|").unwrap();
    for r in reports {
        writeln!(
            o,
            "| {} | {:.1} | {:.0} | {} |",
            r.name,
            r.bytes_per_tri,
            r.bytes_per_instance,
            if embree {
                format!("{:.1}", r.embree_bytes / r.tris as f64)
            } else {
                "–".into()
            }
        )
        .unwrap();
    }
    if !embree {
        return;
    }
    // The table of docs/performance.md's goals: every
    // ratio Trevi / Embree per CPU-second, from the figures above.
    writeln!(
        o,
        "\n### Trevi / Embree (per CPU-second), the issue's table\n"
    )
    .unwrap();
    writeln!(
        o,
        "| mesh | primary | shadow | incoherent | build | bytes/triangle |"
    )
    .unwrap();
    writeln!(o, "|---|---:|---:|---:|---:|---:|").unwrap();
    for r in reports {
        let ratio = |k: usize| r.embree[k].cpu / r.trevi[k].cpu;
        writeln!(
            o,
            "| {} ({} tris) | {:.2} | {:.2} | {:.2} | {:.2} | {:.1} (Embree {:.1}) |",
            r.name,
            r.tris,
            ratio(0),
            ratio(1),
            ratio(2),
            r.embree_scene_build.cpu / r.build.cpu,
            r.bytes_per_tri,
            r.embree_bytes / r.tris as f64
        )
        .unwrap();
    }
}

// ---------------------------------------------------------------- render

/// Renders one camera's whole frame the way a worker does (tiles of 64,
/// rows in parallel) without writing it, and prints the time and rays.
fn render(scene_path: &Path, camera: &str, threads: usize) {
    let _ = threads; // the global rayon pool has `threads` threads
    let t0 = Instant::now();
    let parsed = trevi_core::ParsedBundle::from_scene_file(scene_path).expect("read the scene");
    let scene = Scene::build(parsed.desc);
    let t_build = t0.elapsed().as_secs_f64();
    let cam = scene.camera_index(camera).expect("camera id");
    let rs = &scene.desc.cameras[cam].render;
    let (w, h) = (rs.width, rs.height);
    let t1 = Instant::now();
    let mut rays = 0u64;
    let mut sum = 0.0f64;
    for rect in trevi_core::tile::band_order_tiles(w, h, 64) {
        let t = trevi_core::render_tile(&scene, cam, rect);
        rays += t.rays;
        sum += t
            .pixels
            .iter()
            .map(|p| (p[0] + p[1] + p[2]) as f64)
            .sum::<f64>();
    }
    let t_render = t1.elapsed().as_secs_f64();
    println!(
        "render {camera}: {w}x{h}, parse+build {t_build:.2} s, render {t_render:.2} s, total {:.2} s, {rays} rays, {:.2} M rays/s, mean value {:.6}",
        t_build + t_render,
        rays as f64 / t_render / 1e6,
        sum / (w as f64 * h as f64 * 3.0)
    );
}

// ---------------------------------------------------------------- same mix

/// A ray as the integrator traced it (view coordinates).
struct MixRay {
    r: R,
    shadow: bool,
}

/// Collects the traced rays; used on a one-thread pool, so in trace order.
#[derive(Default)]
struct Recorder(std::sync::Mutex<Vec<MixRay>>);

impl RayObserver for Recorder {
    fn closest(&self, o: Vec3, d: Vec3, t_max: f32) {
        let r = R { o, d, t_max };
        self.0.lock().unwrap().push(MixRay { r, shadow: false });
    }
    fn shadow(&self, o: Vec3, d: Vec3, t_max: f32) {
        let r = R { o, d, t_max };
        self.0.lock().unwrap().push(MixRay { r, shadow: true });
    }
}

/// End-to-end rays per CPU-second on every `every`-th tile of the frame,
/// against traversal alone on the very rays those tiles traced.
fn mix(scene_path: &Path, camera: &str, every: usize, reps: usize, threads: usize) {
    let parsed = trevi_core::ParsedBundle::from_scene_file(scene_path).expect("read the scene");
    let scene = Scene::build(parsed.desc);
    let cam = scene.camera_index(camera).expect("camera id");
    let rs = &scene.desc.cameras[cam].render;
    let all = trevi_core::tile::band_order_tiles(rs.width, rs.height, 64);
    let tiles: Vec<_> = all.iter().copied().step_by(every).collect();
    let pixels: usize = tiles.iter().map(|t| t.pixel_count()).sum();

    let mut render = Best::default();
    let mut rays = 0u64;
    for _ in 0..reps {
        let (t0, c0) = (Instant::now(), process_cpu());
        rays = tiles
            .iter()
            .map(|&rect| trevi_core::render_tile(&scene, cam, rect).rays)
            .sum();
        render.add(t0.elapsed().as_secs_f64(), rays as usize);
        render.add_cpu(process_cpu() - c0);
    }

    let rec = Recorder::default();
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("rayon pool");
    one.install(|| {
        for &rect in &tiles {
            trevi_core::tile::render_tile_observed(
                &scene,
                cam,
                rect,
                RenderOptions::default(),
                &rec,
            );
        }
    });
    let recorded = rec.0.into_inner().unwrap();
    assert_eq!(
        recorded.len() as u64,
        rays,
        "recorded and counted rays differ"
    );
    let shadow = recorded.iter().filter(|m| m.shadow).count();

    let view = scene.view(cam);
    let mut replay = Best::default();
    for _ in 0..reps {
        let (secs, cpu, hits) = trace_with(&recorded, threads, |m| {
            if m.shadow {
                view.transmittance(m.r.o, m.r.d, m.r.t_max) < 1.0
            } else {
                view.intersect(m.r.o, m.r.d, m.r.t_max).is_some()
            }
        });
        replay.add(secs, hits);
        replay.add_cpu(cpu);
    }
    let m = |secs: f64| rays as f64 / secs / 1e6;
    println!(
        "mix {camera}: {} of {} tiles (every {every}), {pixels} pixels, {rays} rays ({} closest-hit, {shadow} shadow), best of {reps}, {threads} threads",
        tiles.len(),
        all.len(),
        rays as usize - shadow,
    );
    println!(
        "mix {camera}: render      {:.3} s, {:.3} CPU-s: {:.2} M rays/s, {:.2} M rays/CPU-s",
        render.secs,
        render.cpu,
        m(render.secs),
        m(render.cpu)
    );
    println!(
        "mix {camera}: traversal   {:.3} s, {:.3} CPU-s: {:.2} M rays/s, {:.2} M rays/CPU-s ({} hit or shadowed)",
        replay.secs,
        replay.cpu,
        m(replay.secs),
        m(replay.cpu),
        replay.hits
    );
    println!(
        "mix {camera}: render / traversal-only = {:.2} (wall), {:.2} (CPU)",
        replay.secs / render.secs,
        replay.cpu / render.cpu
    );
}
