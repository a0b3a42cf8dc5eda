//! The trade from "Whitted in seconds" to converged global illumination,
//! measured against path-traced ground truth.
//!
//! ```text
//! cargo run --release -p trevi-core --example ground_truth [-- RES REF_SS]
//! ```
//!
//! For two scenes, `examples/cornell.xml` (camera `front`) and
//! `bench/cornell-nefertiti.xml` (the same box with the 99 938-triangle
//! Nefertiti scan from `../shared/meshes`, camera `effects`), at RES×RES
//! pixels (default 48), renders the ground truth (path mode, two independent
//! references of REF_SS² samples per pixel, default 96, averaged) and then,
//! each timed (best of up to three runs, scene already built) and measured by
//! its RMSE against the ground truth:
//!
//! * `whitted`: the spec's model as the scene sets it (ambient term, the
//!   light's soft shadow with one shadow ray per camera sample);
//! * `+AO`: plus 4 ambient-occlusion rays per camera sample;
//! * `+AO +diffuse k`: plus one level of diffuse interreflection, k = 1, 4, 16
//!   gather rays per camera sample;
//! * `diffuse 16 without ambient`: the gather instead of the ambient term;
//!
//!   each at supersample 1, 2, 4, 8;
//! * `path`: path tracing at supersample 1…32 (1…1024 samples per pixel);
//! * `path adaptive`: path tracing with adaptive sampling (min 16, max 1024
//!   samples, noise thresholds 0.1…0.01).
//!
//! Writes `docs/ground-truth.csv` and `docs/ground-truth.png` (relative to
//! the current directory) and prints, per scene, the noise floor of the
//! ground truth, each strategy's best RMSE, and for a ladder of time budgets
//! the strategy with the lowest RMSE.

// Statistics of measured figures (interpolating times), not pixels: std is fine (clippy.toml).
#![allow(clippy::disallowed_methods)]

mod common;

use common::{render, rmse, Render};
use glam::Vec3;
use plotters::prelude::SeriesLabelPosition;
use std::fmt::Write as _;
use std::path::PathBuf;
use trevi_core::bundle::DirSource;
use trevi_core::sampling::SamplerKind;
use trevi_core::scene::aisxml::parse_scene;
use trevi_core::scene::{Adaptive, IntegratorKind, SceneDesc};

const REF_SEEDS: [u64; 2] = [0x5eed, 0x5eed + 1];
const MAX_BOUNCES: u32 = 1000;

fn mean(a: &[[f32; 3]]) -> f64 {
    a.iter()
        .flat_map(|p| p.iter().map(|&x| x as f64))
        .sum::<f64>()
        / (3 * a.len()) as f64
}

#[derive(Clone, Copy)]
struct Cfg {
    path: bool,
    ss: u32,
    ao: u32,
    diffuse: u32,
    ambient: bool,
    adaptive: Option<(f32, u32, u32)>,
    seed: u64,
}

fn apply(base: &SceneDesc, c: Cfg) -> SceneDesc {
    let mut d = base.clone();
    if !c.ambient {
        d.settings.ambient = Vec3::ZERO;
    }
    let r = &mut d.cameras[0].render;
    r.integrator = if c.path {
        IntegratorKind::Path
    } else {
        IntegratorKind::Whitted
    };
    r.max_bounces = MAX_BOUNCES;
    r.supersample = c.ss;
    r.jitter = true;
    r.shadow_samples = 1;
    r.ao_samples = c.ao;
    r.diffuse_samples = c.diffuse;
    r.diffuse_depth = 1;
    r.seed = c.seed;
    r.adaptive = c.adaptive.map(|(t, min, max)| Adaptive {
        threshold: t,
        min_samples: min,
        max_samples: max,
    });
    d
}

struct Row {
    scene: &'static str,
    strategy: String,
    setting: String,
    seconds: f64,
    rays: u64,
    rmse: f64,
    mean_bias: f64,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let res: u32 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(48);
    let ref_ss: u32 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(96);
    let manifest = PathBuf::from(env!("CARGO_MANIFEST_DIR"));

    let mut scenes: Vec<(&'static str, SceneDesc)> = Vec::new();
    let dir = DirSource {
        root: manifest.join("../examples"),
    };
    let mut cornell = parse_scene("cornell.xml", &dir)?;
    cornell.cameras.truncate(1); // "front"
    scenes.push(("cornell.xml (front)", cornell));
    // The mesh scene reads meshes/nefertiti.obj from its bundle directory:
    // a copy in a temporary bundle (bundles may not reach outside).
    let mesh = manifest.join("../../shared/meshes/nefertiti.obj");
    if mesh.exists() {
        let tmp = std::env::temp_dir().join(format!("trevi-ground-truth-{}", std::process::id()));
        std::fs::create_dir_all(tmp.join("meshes"))?;
        std::fs::copy(&mesh, tmp.join("meshes/nefertiti.obj"))?;
        std::fs::copy(
            manifest.join("../bench/cornell-nefertiti.xml"),
            tmp.join("scene.xml"),
        )?;
        let mut d = parse_scene("scene.xml", &DirSource { root: tmp.clone() })?;
        d.cameras.retain(|c| c.id == "effects");
        scenes.push(("cornell-nefertiti.xml (effects)", d));
        std::fs::remove_dir_all(&tmp)?;
    } else {
        eprintln!("{} not found: the mesh scene is skipped", mesh.display());
    }
    for (_, d) in &mut scenes {
        d.cameras[0].render.width = res;
        d.cameras[0].render.height = res;
    }

    let mut rows = Vec::new();
    let mut summary = String::new();
    for (name, base) in &scenes {
        let name: &'static str = name;
        let whitted = Cfg {
            path: false,
            ss: 1,
            ao: 0,
            diffuse: 0,
            ambient: true,
            adaptive: None,
            seed: 0,
        };
        let path = Cfg {
            path: true,
            ..whitted
        };
        eprintln!("[{name}] ground truth: 2 × path tracing at supersample {ref_ss}");
        let refs: Vec<Render> = REF_SEEDS
            .iter()
            .map(|&seed| {
                render(
                    &apply(
                        base,
                        Cfg {
                            ss: ref_ss,
                            seed,
                            ..path
                        },
                    ),
                    SamplerKind::Sobol,
                    1,
                )
            })
            .collect();
        let truth: Vec<[f32; 3]> = refs[0]
            .pixels
            .iter()
            .zip(&refs[1].pixels)
            .map(|(a, b)| [0, 1, 2].map(|c| 0.5 * (a[c] + b[c])))
            .collect();
        // RMSE(a, b) = √2·σ for two independent references of noise σ; their
        // mean has σ/√2 = RMSE(a, b)/2.
        let floor = rmse(&refs[0].pixels, &refs[1].pixels) / 2.0;
        let truth_mean = mean(&truth);
        writeln!(
            summary,
            "[{name}] {res}x{res}; ground truth: 2 x {} spp in {:.1} s + {:.1} s, mean {:.4e}, noise (RMSE) of the ground truth {:.3e}",
            ref_ss * ref_ss,
            refs[0].seconds,
            refs[1].seconds,
            truth_mean,
            floor
        )?;
        let mut run = |strategy: &str, setting: String, c: Cfg| {
            let r = render(&apply(base, c), SamplerKind::Sobol, 3);
            let row = Row {
                scene: name,
                strategy: strategy.to_string(),
                setting,
                seconds: r.seconds,
                rays: r.rays,
                rmse: rmse(&r.pixels, &truth),
                mean_bias: mean(&r.pixels) / truth_mean - 1.0,
            };
            eprintln!(
                "[{}] {:<26} {:<22} {:>8.3} s {:>12} rays  RMSE {:.3e}  mean bias {:+.1}%",
                row.scene,
                row.strategy,
                row.setting,
                row.seconds,
                row.rays,
                row.rmse,
                100.0 * row.mean_bias
            );
            rows.push(row);
        };
        let whitted_ladder: [(&str, Cfg); 6] = [
            ("whitted", whitted),
            ("+AO 4", Cfg { ao: 4, ..whitted }),
            (
                "+AO 4 +diffuse 1",
                Cfg {
                    ao: 4,
                    diffuse: 1,
                    ..whitted
                },
            ),
            (
                "+AO 4 +diffuse 4",
                Cfg {
                    ao: 4,
                    diffuse: 4,
                    ..whitted
                },
            ),
            (
                "+AO 4 +diffuse 16",
                Cfg {
                    ao: 4,
                    diffuse: 16,
                    ..whitted
                },
            ),
            (
                "diffuse 16 without ambient",
                Cfg {
                    diffuse: 16,
                    ambient: false,
                    ..whitted
                },
            ),
        ];
        for (strategy, cfg) in whitted_ladder {
            for n in [1, 2, 4, 8] {
                run(strategy, format!("ss={n}"), Cfg { ss: n, ..cfg });
            }
        }
        for n in [1, 2, 3, 4, 6, 8, 11, 16, 23, 32] {
            run("path", format!("ss={n}"), Cfg { ss: n, ..path });
        }
        for t in [0.1f32, 0.05, 0.02, 0.01] {
            run(
                "path adaptive",
                format!("threshold={t} min=16 max=1024"),
                Cfg {
                    adaptive: Some((t, 16, 1024)),
                    ..path
                },
            );
        }
        summarise(&mut summary, name, &rows, floor)?;
    }

    std::fs::create_dir_all("docs")?;
    let mut csv = String::from("scene,strategy,setting,seconds,rays,rmse,mean_bias\n");
    for r in &rows {
        writeln!(
            csv,
            "{},{},{},{:.6},{},{:.6e},{:.5}",
            r.scene, r.strategy, r.setting, r.seconds, r.rays, r.rmse, r.mean_bias
        )?;
    }
    std::fs::write("docs/ground-truth.csv", csv)?;
    plot(&rows, &scenes.iter().map(|s| s.0).collect::<Vec<_>>())?;
    print!("{summary}");
    Ok(())
}

/// [`common::time_at_rmse`], and for a curve that starts at or below `e`
/// its first time (the truth reaches `e` no later than that).
fn time_at_rmse(curve: &[(f64, f64)], e: f64) -> Option<f64> {
    match curve.first() {
        Some(&(t, e0)) if e0 <= e => Some(t),
        _ => common::time_at_rmse(curve, e),
    }
}

fn summarise(out: &mut String, scene: &str, rows: &[Row], floor: f64) -> std::fmt::Result {
    let sel: Vec<&Row> = rows.iter().filter(|r| r.scene == scene).collect();
    let mut strategies: Vec<&str> = Vec::new();
    for r in &sel {
        if !strategies.contains(&r.strategy.as_str()) {
            strategies.push(&r.strategy);
        }
    }
    let mut path: Vec<(f64, f64)> = sel
        .iter()
        .filter(|r| r.strategy == "path")
        .map(|r| (r.seconds, r.rmse))
        .collect();
    path.sort_by(|a, b| a.0.total_cmp(&b.0));
    for s in &strategies {
        let best = sel
            .iter()
            .filter(|r| r.strategy == *s)
            .min_by(|a, b| a.rmse.total_cmp(&b.rmse))
            .unwrap();
        let fastest = sel
            .iter()
            .filter(|r| r.strategy == *s)
            .min_by(|a, b| a.seconds.total_cmp(&b.seconds))
            .unwrap();
        let path_time = time_at_rmse(&path, best.rmse)
            .map(|t| format!("{t:.3} s"))
            .unwrap_or_else(|| "more than the ladder".into());
        writeln!(
            out,
            "[{scene}] {s:<26} fastest {:.3} s (RMSE {:.3e}); best RMSE {:.3e} ({}, {:.3} s, mean bias {:+.1}%); path tracing reaches that RMSE in {path_time}",
            fastest.seconds,
            fastest.rmse,
            best.rmse,
            best.setting,
            best.seconds,
            100.0 * best.mean_bias,
        )?;
    }
    // The better buy at each time budget: the lowest RMSE among renders that
    // take at most that long.
    let mut budget = 0.002;
    let tmax = sel.iter().map(|r| r.seconds).fold(0.0, f64::max);
    while budget < tmax * 2.0 {
        if let Some(b) = sel
            .iter()
            .filter(|r| r.seconds <= budget)
            .min_by(|a, b| a.rmse.total_cmp(&b.rmse))
        {
            writeln!(
                out,
                "[{scene}] budget {budget:>8.3} s: best {} {} (RMSE {:.3e}, {:.3} s)",
                b.strategy, b.setting, b.rmse, b.seconds
            )?;
        }
        budget *= 2.0;
    }
    writeln!(out, "[{scene}] noise of the ground truth {floor:.3e}")
}

fn plot(rows: &[Row], scenes: &[&str]) -> Result<(), Box<dyn std::error::Error>> {
    let panels: Vec<common::Panel> = scenes
        .iter()
        .map(|scene| common::Panel {
            title: format!("{scene}: RMSE vs path-traced truth"),
            points: rows
                .iter()
                .filter(|r| r.scene == *scene)
                .map(|r| (r.strategy.as_str(), r.seconds, r.rmse))
                .collect(),
        })
        .collect();
    common::plot(
        "docs/ground-truth.png",
        &panels,
        &common::Style {
            caption_size: 20,
            x_desc: "wall time (s), 2 cores",
            legend: SeriesLabelPosition::LowerLeft,
            round_ticks: true,
        },
    )
}
