//! Path mode against a peer renderer: Mitsuba 3 (`scalar_rgb`, `path`
//! integrator, box filter) rendered `examples/cornell-area.xml` (diffuse
//! walls, two boxes, one area light) once, offline, with
//! `bench/mitsuba/cornell_area.py reference`; its 32×32 linear image and
//! per-pixel standard errors are stored in `tests/data/cornell_area_mitsuba.txt`.
//! Here Trevi renders the same scene and the two are compared with
//! tolerances derived from the noise of both, so the test needs no Python.
//!
//! The comparison has teeth: the same check fails for the scene with its
//! light 3 % brighter, and with the paths cut after 3 bounces (tests below).

mod common;

use trevi_core::tile::render_tile;

const SCENE: &str = include_str!("../../examples/cornell-area.xml");
const REFERENCE: &str = include_str!("data/cornell_area_mitsuba.txt");
/// The render line of the example, which the test rewrites.
const RENDER_SIZE: &str = r#"width="256" height="256" supersample="16""#;
const SIDE: u32 = 32;
/// Independent Trevi renders (seeds), each at SS×SS samples per pixel.
const SEEDS: u64 = 4;
const SS: u32 = 8;
/// Pixels per side of the blocks whose means are compared one by one.
const BLOCK: usize = 4;

struct Reference {
    mean: Vec<[f64; 3]>,
    stderr: Vec<[f64; 3]>,
}

fn reference() -> Reference {
    let mut mean = Vec::new();
    let mut stderr = Vec::new();
    for line in REFERENCE.lines() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let v: Vec<f64> = line
            .split_whitespace()
            .map(|x| x.parse().expect("a number in the reference"))
            .collect();
        assert_eq!(v.len(), 6, "reference line {line:?}");
        mean.push([v[0], v[1], v[2]]);
        stderr.push([v[3], v[4], v[5]]);
    }
    assert_eq!(mean.len(), (SIDE * SIDE) as usize);
    Reference { mean, stderr }
}

/// The example at 32×32, `SS`×`SS` samples, seed `seed`, with `edit`
/// applied to its text (a deliberate error for the negative controls).
fn render(seed: u64, edit: &dyn Fn(&str) -> String) -> Vec<[f64; 3]> {
    assert!(SCENE.contains(RENDER_SIZE) && SCENE.contains(r#"seed="0""#));
    let xml = edit(SCENE)
        .replace(
            RENDER_SIZE,
            &format!(r#"width="{SIDE}" height="{SIDE}" supersample="{SS}""#),
        )
        .replace(r#"seed="0""#, &format!(r#"seed="{seed}""#));
    let scene = common::scene(&xml);
    let r = &scene.desc.cameras[0].render;
    render_tile(&scene, 0, trevi_core::Rect::new(0, 0, r.width, r.height))
        .pixels
        .iter()
        .map(|p| p.map(f64::from))
        .collect()
}

#[derive(Debug)]
struct Agreement {
    /// Trevi's image mean over Mitsuba's, minus 1, per channel.
    bias: [f64; 3],
    /// The standard error of that ratio (both renderers' noise).
    bias_se: [f64; 3],
    /// The largest |difference| / standard error over blocks and channels.
    block_z: f64,
    /// Mean over pixels and channels of difference² / variance.
    chi2: f64,
}

/// Trevi's mean over `SEEDS` renders against Mitsuba, with the variance of
/// Trevi's per-pixel mean estimated from the spread of the seeds (pooled
/// over each block, so each block's estimate has 16·3 degrees of freedom)
/// and Mitsuba's from its stored standard errors.
fn agreement(edit: &dyn Fn(&str) -> String) -> Agreement {
    let reference = reference();
    let renders: Vec<Vec<[f64; 3]>> = (1..=SEEDS).map(|s| render(s, edit)).collect();
    let n = (SIDE * SIDE) as usize;
    let k = SEEDS as f64;
    let mut mean = vec![[0.0; 3]; n];
    let mut var = vec![[0.0; 3]; n];
    for p in 0..n {
        for c in 0..3 {
            let m = renders.iter().map(|r| r[p][c]).sum::<f64>() / k;
            let v = renders.iter().map(|r| (r[p][c] - m).powi(2)).sum::<f64>() / (k - 1.0);
            mean[p][c] = m;
            var[p][c] = v / k; // of the mean of the seeds
        }
    }
    let side = SIDE as usize;
    let blocks = side / BLOCK;
    let mut block_z: f64 = 0.0;
    let mut chi2 = 0.0;
    let (mut sum_t, mut sum_m, mut var_sum) = ([0.0; 3], [0.0; 3], [0.0; 3]);
    for by in 0..blocks {
        for bx in 0..blocks {
            let pix: Vec<usize> = (0..BLOCK * BLOCK)
                .map(|i| (by * BLOCK + i / BLOCK) * side + bx * BLOCK + i % BLOCK)
                .collect();
            for c in 0..3 {
                let (mut t, mut m, mut v) = (0.0, 0.0, 0.0);
                for &p in &pix {
                    t += mean[p][c];
                    m += reference.mean[p][c];
                    v += var[p][c] + reference.stderr[p][c].powi(2);
                }
                let z = (t - m).abs() / v.sqrt();
                block_z = block_z.max(z);
                // Per pixel: the block's mean variance stands for each of its
                // pixels' (one seed spread alone is too noisy an estimate).
                let pixel_var = v / pix.len() as f64;
                for &p in &pix {
                    chi2 += (mean[p][c] - reference.mean[p][c]).powi(2) / pixel_var;
                }
                sum_t[c] += t;
                sum_m[c] += m;
                var_sum[c] += v;
            }
        }
    }
    Agreement {
        bias: [0, 1, 2].map(|c| sum_t[c] / sum_m[c] - 1.0),
        bias_se: [0, 1, 2].map(|c| var_sum[c].sqrt() / sum_m[c]),
        block_z,
        chi2: chi2 / (3 * n) as f64,
    }
}

/// The issue's criteria: image mean within 1 % (and within 4 standard
/// errors, which is tighter here), every 4×4 block within 5 standard errors
/// (with 48 degrees of freedom per estimate, P(|t| > 5) ≈ 10⁻⁵ a block and
/// channel), and the per-pixel differences no larger than the noise: the
/// mean of z² is 1 for agreeing renders (a little over 1 with estimated
/// variances), allowed up to 1.3.
fn check(a: &Agreement) -> Result<(), String> {
    for c in 0..3 {
        if a.bias[c].abs() > 0.01 || a.bias[c].abs() > 4.0 * a.bias_se[c] {
            return Err(format!(
                "channel {c}: image mean bias {:.3} % (standard error {:.3} %)",
                100.0 * a.bias[c],
                100.0 * a.bias_se[c]
            ));
        }
    }
    if a.block_z > 5.0 {
        return Err(format!(
            "a 4×4 block is {:.1} standard errors off",
            a.block_z
        ));
    }
    if a.chi2 > 1.3 {
        return Err(format!(
            "per-pixel mean z² = {:.3}: the differences exceed the noise",
            a.chi2
        ));
    }
    Ok(())
}

#[test]
fn path_mode_agrees_with_mitsuba_3_on_the_area_lit_cornell_box() {
    let a = agreement(&|s| s.to_string());
    eprintln!("{a:?}");
    if let Err(e) = check(&a) {
        panic!("Trevi and Mitsuba 3 disagree: {e} ({a:?})");
    }
}

#[test]
fn the_mitsuba_check_fails_for_a_light_three_percent_too_bright() {
    let bright = |s: &str| {
        assert!(s.contains(r#"emission="15 12 8""#));
        s.replace(r#"emission="15 12 8""#, r#"emission="15.45 12.36 8.24""#)
    };
    let a = agreement(&bright);
    eprintln!("{a:?}");
    assert!(check(&a).is_err(), "a 3 % brighter light passed: {a:?}");
}

#[test]
fn the_mitsuba_check_fails_when_paths_stop_after_three_bounces() {
    let short = |s: &str| {
        assert!(s.contains(r#"max-bounces="1000""#));
        s.replace(r#"max-bounces="1000""#, r#"max-bounces="3""#)
    };
    let a = agreement(&short);
    eprintln!("{a:?}");
    assert!(check(&a).is_err(), "paths cut at 3 bounces passed: {a:?}");
}
