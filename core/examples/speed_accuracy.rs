//! The speed/accuracy trade of Trevi's Monte-Carlo effects, measured.
//!
//! ```text
//! cargo run --release -p trevi-core --example speed_accuracy [-- RES]
//! ```
//!
//! Renders the Cornell-box example (`examples/cornell.xml`, camera `front`)
//! at RES×RES pixels (default 48) and writes, relative to the current
//! directory, `docs/speed-accuracy.csv` (one row per render) and
//! `docs/speed-accuracy.png` (RMSE against wall time, log–log, one curve per
//! strategy). Two groups of measurements:
//!
//! * `all`: every effect on (depth of field with a 0.06 square aperture,
//!   soft shadows from the example's 0.12-radius light, ambient occlusion,
//!   one level of diffuse interreflection, the glass and mirror), against a
//!   converged reference. Strategies: supersampling n×n with one sample of
//!   each effect per camera sample; 1–64 samples of one effect at a time;
//!   adaptive sampling at several noise thresholds.
//! * `isolated`: one effect's noise alone (pinhole camera, pixel centres, the
//!   other effects off), each against its own converged reference, to see
//!   what halving that effect's error costs; AO and soft shadows are also
//!   rendered with `SamplerKind::Independent` to show what the scrambled
//!   Sobol sequence buys.
//!
//! "Converged" is checked, not assumed: each reference is rendered again with
//! twice the samples, and the program reports by how much every RMSE in its
//! group changes when measured against the doubled reference (it must be
//! < 1%). Wall time is for the render alone (scene already built), on the
//! global rayon pool; the ray count is reported too as a machine-independent
//! cost.

// Statistics of measured figures, not pixels: std is fine (clippy.toml).
#![allow(clippy::disallowed_methods)]

mod common;

use common::{render, rmse, time_at_rmse};
use plotters::prelude::SeriesLabelPosition;
use std::fmt::Write as _;
use trevi_core::bundle::DirSource;
use trevi_core::sampling::SamplerKind;
use trevi_core::scene::aisxml::parse_scene;
use trevi_core::scene::{Adaptive, SceneDesc};

const APERTURE: f32 = 0.06;
/// References use their own seed so that their samples are not a superset
/// of the ladder's (which would correlate their errors and flatter the RMSE).
const REF_SEED: u64 = 0x5eed;

/// Settings of one render: everything the ladders vary.
#[derive(Clone, Copy)]
struct Cfg {
    ss: u32,
    jitter: bool,
    aperture: f32,
    light_radius: f32,
    shadow: u32,
    ao: u32,
    diffuse: u32,
    adaptive: Option<(f32, u32, u32)>,
    seed: u64,
}

fn apply(base: &SceneDesc, c: Cfg) -> SceneDesc {
    let mut d = base.clone();
    for l in &mut d.lights {
        l.radius = c.light_radius;
    }
    let cam = &mut d.cameras[0];
    cam.aperture = c.aperture;
    let r = &mut cam.render;
    r.supersample = c.ss;
    r.jitter = c.jitter;
    r.shadow_samples = c.shadow;
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
    group: &'static str,
    strategy: String,
    setting: String,
    seconds: f64,
    rays: u64,
    rmse: f64,
    rmse_vs_doubled: f64,
}

/// Renders a ladder and measures it against a reference and against the
/// reference rendered with twice the samples.
struct Group {
    name: &'static str,
    base: SceneDesc,
    reference: Vec<[f32; 3]>,
    doubled: Vec<[f32; 3]>,
    reference_note: String,
}

impl Group {
    fn new(name: &'static str, base: SceneDesc, reference: Cfg, doubled: Cfg, note: &str) -> Group {
        eprintln!("[{name}] reference: {note}");
        let r = render(&apply(&base, reference), SamplerKind::Sobol, 3);
        let d = render(&apply(&base, doubled), SamplerKind::Sobol, 3);
        eprintln!(
            "[{name}] reference {:.1} s, doubled {:.1} s, RMSE between them {:.2e}",
            r.seconds,
            d.seconds,
            rmse(&r.pixels, &d.pixels)
        );
        Group {
            name,
            base,
            reference: r.pixels,
            doubled: d.pixels,
            reference_note: note.to_string(),
        }
    }

    fn run(&self, rows: &mut Vec<Row>, strategy: &str, setting: String, c: Cfg, s: SamplerKind) {
        let r = render(&apply(&self.base, c), s, 3);
        let row = Row {
            group: self.name,
            strategy: strategy.to_string(),
            setting,
            seconds: r.seconds,
            rays: r.rays,
            rmse: rmse(&r.pixels, &self.reference),
            rmse_vs_doubled: rmse(&r.pixels, &self.doubled),
        };
        eprintln!(
            "[{}] {:<22} {:<26} {:>8.3} s {:>12} rays  RMSE {:.3e}",
            row.group, row.strategy, row.setting, row.seconds, row.rays, row.rmse
        );
        rows.push(row);
    }
}

/// Least-squares slope of log(rmse) against log(seconds).
fn loglog_slope(pts: &[(f64, f64)]) -> f64 {
    let n = pts.len() as f64;
    let (mx, my) = pts.iter().fold((0.0, 0.0), |(a, b), &(t, e)| {
        (a + t.ln() / n, b + e.ln() / n)
    });
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for &(t, e) in pts {
        sxy += (t.ln() - mx) * (e.ln() - my);
        sxx += (t.ln() - mx).powi(2);
    }
    sxy / sxx
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let res: u32 = std::env::args()
        .nth(1)
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(48);
    let dir = DirSource {
        root: concat!(env!("CARGO_MANIFEST_DIR"), "/../examples").into(),
    };
    let mut base = parse_scene("cornell.xml", &dir)?;
    base.cameras.truncate(1); // "front"
    base.cameras[0].render.width = res;
    base.cameras[0].render.height = res;
    let light_radius = base.lights[0].radius;
    let sobol = SamplerKind::Sobol;
    let mut rows = Vec::new();

    // ------------------------------------------------ every effect on
    let all = Cfg {
        ss: 1,
        jitter: true,
        aperture: APERTURE,
        light_radius,
        shadow: 1,
        ao: 1,
        diffuse: 1,
        adaptive: None,
        seed: 0,
    };
    let g = Group::new(
        "all",
        base.clone(),
        Cfg { ss: 128, seed: REF_SEED, ..all },
        Cfg { ss: 181, seed: REF_SEED, ..all },
        "supersample 128 (16384 spp), one sample of each effect per camera sample; doubled: supersample 181 (32761 spp)",
    );
    for n in [1, 2, 3, 4, 6, 8, 11, 16] {
        g.run(
            &mut rows,
            "supersample",
            format!("n={n}"),
            Cfg { ss: n, ..all },
            sobol,
        );
    }
    for k in [1, 2, 4, 8, 16, 32, 64] {
        let ss = 2;
        g.run(
            &mut rows,
            "shadow-samples (ss 2)",
            format!("k={k}"),
            Cfg {
                ss,
                shadow: k,
                ..all
            },
            sobol,
        );
        g.run(
            &mut rows,
            "ao-samples (ss 2)",
            format!("k={k}"),
            Cfg { ss, ao: k, ..all },
            sobol,
        );
        g.run(
            &mut rows,
            "diffuse-samples (ss 2)",
            format!("k={k}"),
            Cfg {
                ss,
                diffuse: k,
                ..all
            },
            sobol,
        );
    }
    for min in [4u32, 16] {
        for t in [0.08f32, 0.04, 0.02, 0.014, 0.01] {
            g.run(
                &mut rows,
                &format!("adaptive min {min}"),
                format!("threshold={t} min={min} max=256"),
                Cfg {
                    adaptive: Some((t, min, 256)),
                    ..all
                },
                sobol,
            );
        }
    }
    let mut groups = vec![(g.name, g.reference_note.clone())];
    drop(g);

    // ------------------------------------------------ one effect at a time
    let none = Cfg {
        ss: 1,
        jitter: false,
        aperture: 0.0,
        light_radius: 0.0,
        shadow: 1,
        ao: 0,
        diffuse: 0,
        adaptive: None,
        seed: 0,
    };
    let ks = [1u32, 2, 4, 8, 16, 32, 64];
    /// (group, base settings, "with k samples of the effect", reference k)
    type Effect = (&'static str, Cfg, fn(Cfg, u32) -> Cfg, u32);
    let effects: [Effect; 4] = [
        (
            "iso-ao",
            Cfg { ao: 1, ..none },
            |c, k| Cfg { ao: k, ..c },
            16384,
        ),
        (
            "iso-shadow",
            Cfg {
                light_radius,
                ..none
            },
            |c, k| Cfg { shadow: k, ..c },
            32768,
        ),
        (
            "iso-diffuse",
            Cfg { diffuse: 1, ..none },
            |c, k| Cfg { diffuse: k, ..c },
            8192,
        ),
        (
            "iso-dof",
            Cfg {
                aperture: APERTURE,
                jitter: true,
                ..none
            },
            // k samples of the lens: supersample √k (k a square or near it).
            |c, k| Cfg {
                ss: (k as f64).sqrt().round() as u32,
                ..c
            },
            4096,
        ),
    ];
    for (name, cfg, with, reference) in effects {
        let g = Group::new(
            name,
            base.clone(),
            Cfg {
                seed: REF_SEED,
                ..with(cfg, reference)
            },
            Cfg {
                seed: REF_SEED,
                ..with(cfg, 2 * reference)
            },
            &format!("{reference} samples; doubled: {} samples", 2 * reference),
        );
        let ladder: Vec<u32> = if name == "iso-dof" {
            vec![1, 4, 9, 16, 36, 64]
        } else {
            ks.to_vec()
        };
        for &k in &ladder {
            g.run(&mut rows, name, format!("k={k}"), with(cfg, k), sobol);
        }
        if name == "iso-ao" || name == "iso-shadow" {
            for k in [4, 16, 64] {
                g.run(
                    &mut rows,
                    &format!("{name} independent"),
                    format!("k={k}"),
                    with(cfg, k),
                    SamplerKind::Independent,
                );
            }
        }
        groups.push((g.name, g.reference_note.clone()));
    }

    // ------------------------------------------------ outputs
    std::fs::create_dir_all("docs")?;
    let mut csv =
        String::from("group,strategy,setting,seconds,rays,rmse,rmse_vs_doubled_reference\n");
    for r in &rows {
        writeln!(
            csv,
            "{},{},{},{:.6},{},{:.6e},{:.6e}",
            r.group, r.strategy, r.setting, r.seconds, r.rays, r.rmse, r.rmse_vs_doubled
        )?;
    }
    std::fs::write("docs/speed-accuracy.csv", csv)?;
    plot(&rows)?;

    // ------------------------------------------------ summary
    println!("resolution {res}x{res}");
    for (name, note) in &groups {
        let change = rows
            .iter()
            .filter(|r| r.group == *name)
            .map(|r| (r.rmse_vs_doubled / r.rmse - 1.0).abs())
            .fold(0.0, f64::max);
        println!(
            "reference [{name}] {note}: largest relative RMSE change against the doubled reference {:.3}%{}",
            100.0 * change,
            if change < 0.01 { "" } else { "  (NOT < 1%)" }
        );
    }
    let curve = |group: &str, strategy: &str| -> Vec<(f64, f64)> {
        let mut v: Vec<(f64, f64)> = rows
            .iter()
            .filter(|r| r.group == group && r.strategy == strategy)
            .map(|r| (r.seconds, r.rmse))
            .collect();
        v.sort_by(|a, b| a.0.total_cmp(&b.0));
        v
    };
    for (group, strategy) in [
        ("iso-ao", "iso-ao"),
        ("iso-shadow", "iso-shadow"),
        ("iso-diffuse", "iso-diffuse"),
        ("iso-dof", "iso-dof"),
        ("all", "supersample"),
    ] {
        // Fit over the upper half of the ladder (past the fixed costs).
        let c = curve(group, strategy);
        let tail = &c[c.len() / 2 - 1..];
        let s = loglog_slope(tail);
        println!(
            "{group}/{strategy}: RMSE ∝ time^{s:.2}; halving the error costs {:.1}× the time",
            2f64.powf(-1.0 / s)
        );
    }
    let ss = curve("all", "supersample");
    for r in rows.iter().filter(|r| r.strategy.starts_with("adaptive")) {
        match time_at_rmse(&ss, r.rmse) {
            Some(t) => println!(
                "{} {}: RMSE {:.3e} in {:.2} s; supersampling needs {:.2} s for it: saves {:.0}%",
                r.strategy,
                r.setting,
                r.rmse,
                r.seconds,
                t,
                100.0 * (1.0 - r.seconds / t)
            ),
            None => println!(
                "{} {}: RMSE {:.3e} in {:.2} s; outside the supersampling curve",
                r.strategy, r.setting, r.rmse, r.seconds
            ),
        }
    }
    let ss_rays: Vec<(f64, f64)> = {
        let mut v: Vec<(f64, f64)> = rows
            .iter()
            .filter(|r| r.group == "all" && r.strategy == "supersample")
            .map(|r| (r.rays as f64, r.rmse))
            .collect();
        v.sort_by(|a, b| a.0.total_cmp(&b.0));
        v
    };
    for r in rows.iter().filter(|r| r.strategy.starts_with("adaptive")) {
        if let Some(n) = time_at_rmse(&ss_rays, r.rmse) {
            println!(
                "{} {}: {} rays; supersampling needs {:.0} rays for the same RMSE: saves {:.0}%",
                r.strategy,
                r.setting,
                r.rays,
                n,
                100.0 * (1.0 - r.rays as f64 / n)
            );
        }
    }
    for name in ["iso-ao", "iso-shadow"] {
        for k in [4, 16, 64] {
            let get = |s: &str| {
                rows.iter()
                    .find(|r| r.strategy == s && r.setting == format!("k={k}"))
                    .map(|r| r.rmse)
                    .unwrap()
            };
            let (a, b) = (get(name), get(&format!("{name} independent")));
            println!(
                "{name} k={k}: Sobol RMSE {a:.3e}, independent {b:.3e} (ratio {:.2})",
                b / a
            );
        }
    }
    Ok(())
}

fn plot(rows: &[Row]) -> Result<(), Box<dyn std::error::Error>> {
    let panel = |title: &str, groups: &[&str]| common::Panel {
        title: title.to_string(),
        points: rows
            .iter()
            .filter(|r| groups.contains(&r.group))
            .map(|r| (r.strategy.as_str(), r.seconds, r.rmse))
            .collect(),
    };
    common::plot(
        "docs/speed-accuracy.png",
        &[
            panel("Every effect on (Cornell box)", &["all"]),
            panel(
                "One effect at a time",
                &["iso-ao", "iso-shadow", "iso-diffuse", "iso-dof"],
            ),
        ],
        &common::Style {
            caption_size: 22,
            x_desc: "wall time (s)",
            legend: SeriesLabelPosition::UpperRight,
            round_ticks: false,
        },
    )
}
