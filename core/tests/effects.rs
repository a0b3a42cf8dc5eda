//! The Monte-Carlo effects of spec/aisxml.md ("Camera", "Lighting",
//! "Sampling and determinism") checked against closed forms and integrals of
//! the spec's formulas computed here independently in f64: ambient occlusion,
//! depth of field (square and disk lens), soft shadows, diffuse
//! interreflection, adaptive sampling, determinism with every effect on, and
//! the cost of a scene that uses no effect (rays traced).

// Independent closed forms and test geometry, computed with std on purpose (clippy.toml).
#![allow(clippy::disallowed_methods)]

mod common;
use common::*;
use trevi_core::integrator::RenderOptions;
use trevi_core::tile::band_order_tiles;
use trevi_core::{render_tile, Rect, Scene, TileResult};

fn whole(scene: &Scene, camera: usize) -> TileResult {
    let r = &scene.desc.cameras[camera].render;
    render_tile(scene, camera, Rect::new(0, 0, r.width, r.height))
}

/// Row-averaged horizontal profile of channel 0 (`values` is `w`×`h`).
fn row_profile(values: &[f64], w: usize, h: usize) -> Vec<f64> {
    (0..w)
        .map(|i| (0..h).map(|r| values[r * w + i]).sum::<f64>() / h as f64)
        .collect()
}

/// Where a rising profile sampled at pixel centres (`i + 0.5`) first reaches
/// `level`, by linear interpolation between neighbouring centres.
fn crossing(p: &[f64], level: f64) -> f64 {
    for i in 1..p.len() {
        if p[i] >= level && p[i - 1] < level {
            let t = (level - p[i - 1]) / (p[i] - p[i - 1]);
            return i as f64 - 0.5 + t;
        }
    }
    panic!("profile never crosses {level}: {p:?}");
}

/// 10–90 % width, in pixels, of a rising edge profile.
fn width_10_90(p: &[f64]) -> f64 {
    crossing(p, 0.9) - crossing(p, 0.1)
}

/// A continuous edge profile `cdf(x)` (x in pixels from the edge) averaged
/// over each pixel's box footprint, at the centres of `n` pixels whose
/// boundary `edge` (an integer) is where x = 0.
fn pixel_profile(cdf: impl Fn(f64) -> f64, n: usize, edge: f64) -> Vec<f64> {
    const K: usize = 2000;
    (0..n)
        .map(|i| {
            (0..K)
                .map(|k| cdf(i as f64 + (k as f64 + 0.5) / K as f64 - edge))
                .sum::<f64>()
                / K as f64
        })
        .collect()
}

/// CDF of a uniform distribution on [−half, half].
fn box_cdf(x: f64, half: f64) -> f64 {
    ((x + half) / (2.0 * half)).clamp(0.0, 1.0)
}

/// CDF of the x coordinate of a point uniform in the disk of radius `r`.
fn disk_cdf(x: f64, r: f64) -> f64 {
    let t = (x / r).clamp(-1.0, 1.0);
    0.5 + (t * (1.0 - t * t).sqrt() + t.asin()) / std::f64::consts::PI
}

/// Cosine-weighted hemisphere quadrature about +y: the midpoint rule in
/// (u = sin²θ, φ), where the density cos θ/π becomes uniform.
fn cosine_quadrature(n: usize, mut g: impl FnMut([f64; 3]) -> f64) -> f64 {
    let mut sum = 0.0;
    for a in 0..n {
        let u = (a as f64 + 0.5) / n as f64;
        let (st, ct) = (u.sqrt(), (1.0 - u).sqrt());
        for b in 0..n {
            let phi = std::f64::consts::TAU * (b as f64 + 0.5) / n as f64;
            sum += g([st * phi.cos(), ct, st * phi.sin()]);
        }
    }
    sum / (n * n) as f64
}

// ---------------------------------------------------------------- AO

#[test]
fn ambient_occlusion_on_an_unoccluded_plane_is_exactly_one() {
    let xml = r#"<scene version="1">
  <settings ambient="0.3 0.2 0.1"/>
  <plane id="p" point="0 0 0" normal="0 1 0"><surface diffuse="0 0 0" ambient="0.5 0.7 0.9"/></plane>
  <camera id="c" position="0 2 0" direction="0 -1 0" up="0 0 -1" fov="60">
    <render width="16" height="12" ao-samples="16" ao-distance="5"/>
  </camera>
</scene>"#;
    let scene = scene(xml);
    let t = whole(&scene, 0);
    let want = [0.5f32 * 0.3, 0.7f32 * 0.2, 0.9f32 * 0.1];
    for px in &t.pixels {
        assert_eq!(*px, want, "A(p) must be exactly 1 on an unoccluded plane");
    }
    // The AO rays were traced (16 per primary ray), they just hit nothing.
    assert_eq!(t.rays, 16 * 12 * (1 + 16));
}

#[test]
fn ambient_occlusion_at_the_centre_of_a_closed_cube_floor_matches_the_integral() {
    // The cube [−1,1]³ from six planes; a 1×1 camera at the centre looking
    // straight down sees the floor centre p = (0,−1,0). ka = ambient = 1 and
    // kd = 0, so the pixel is A(p).
    let s_max = 2.0f64;
    let xml = format!(
        r#"<scene version="1">
  <settings ambient="1 1 1"/>
  <plane id="floor" point="0 -1 0" normal="0 1 0"><surface diffuse="0 0 0" ambient="1 1 1"/></plane>
  <plane id="ceil" point="0 1 0" normal="0 -1 0"/>
  <plane id="x0" point="-1 0 0" normal="1 0 0"/>
  <plane id="x1" point="1 0 0" normal="-1 0 0"/>
  <plane id="z0" point="0 0 -1" normal="0 0 1"/>
  <plane id="z1" point="0 0 1" normal="0 0 -1"/>
  <camera id="c" position="0 0 0" direction="0 -1 0" up="0 0 -1" fov="10">
    <render width="1" height="1" ao-samples="4096" ao-distance="{s_max}"/>
  </camera>
</scene>"#
    );
    let got = whole(&scene(&xml), 0).pixels[0];
    // A = ∫ cos θ/π · min(1, s(ω)/s_max) dω, s the distance from p to the
    // cube's wall along ω.
    let want = cosine_quadrature(1500, |d| {
        let mut s = f64::INFINITY;
        for (k, o) in [(0usize, 0.0), (1, -1.0), (2, 0.0)] {
            if d[k] > 0.0 {
                s = s.min((1.0 - o) / d[k]);
            } else if d[k] < 0.0 {
                s = s.min((-1.0 - o) / d[k]);
            }
        }
        (s / s_max).min(1.0)
    });
    assert!(
        want > 0.5 && want < 0.95,
        "the test geometry occludes: {want}"
    );
    for v in got {
        assert_close(v, want, 0.02, "AO at the cube floor centre");
    }
}

// ---------------------------------------------------------------- DOF

/// A white half-plane x ≥ 0 (value exactly 1: ka = ambient = 1, kd = 0) at
/// depth `z` in front of a camera at the origin looking down −z, on black.
fn edge_scene(z: f64, aperture: f64, focus: f64, lens: &str, w: u32, h: u32, fov: f64) -> String {
    format!(
        r#"<scene version="1">
  <settings ambient="1 1 1" background="0 0 0"/>
  <mesh id="half">
    <vertices>0 -100 -{z}  100 -100 -{z}  100 100 -{z}  0 100 -{z}</vertices>
    <triangles>0 1 2  0 2 3</triangles>
  </mesh>
  <model id="m" mesh="half"><surface diffuse="0 0 0" ambient="1 1 1"/></model>
  <camera id="c" position="0 0 0" direction="0 0 -1" up="0 1 0" fov="{fov}"
          aperture="{aperture}" focus="{focus}" lens="{lens}">
    <render width="{w}" height="{h}" supersample="16" jitter="true"/>
  </camera>
</scene>"#
    )
}

fn edge_profile(xml: &str) -> Vec<f64> {
    let scene = scene(xml);
    let r = &scene.desc.cameras[0].render;
    let (w, h) = (r.width as usize, r.height as usize);
    let px: Vec<f64> = whole(&scene, 0)
        .pixels
        .iter()
        .map(|p| p[0] as f64)
        .collect();
    row_profile(&px, w, h)
}

#[test]
fn depth_of_field_keeps_the_focal_plane_sharp_and_blurs_by_the_circle_of_confusion() {
    let (w, h, fov) = (64u32, 4u32, 30.0f64);
    let s = 0.5 / (fov.to_radians() / 2.0).tan();
    let focus = 4.0;
    for lens in ["square", "disk"] {
        // At the focal distance: sharp (10–90 % within one pixel) even with a
        // large aperture.
        let p = edge_profile(&edge_scene(focus, 0.8, focus, lens, w, h, fov));
        let sharp = width_10_90(&p);
        assert!(sharp <= 1.0, "{lens}: in-focus edge is {sharp} px wide");

        // Off the focal plane (nearer and farther): a lens point offset x on
        // the lens moves the ray's crossing of depth z by x·(1 − z/F), which
        // is x·(1 − z/F)·s·W/z pixels. So the edge is the lens's x-marginal
        // scaled by the circle of confusion A·s·W·|1/z − 1/F| pixels, then
        // box-filtered by the pixel.
        for (z, aperture) in [(2.0, 0.4), (8.0, 0.8)] {
            let coc = aperture * s * w as f64 * (1.0 / z - 1.0 / focus).abs();
            let half = coc / 2.0;
            let edge = (w / 2) as f64;
            let predicted = if lens == "square" {
                pixel_profile(|x| box_cdf(x, half), w as usize, edge)
            } else {
                pixel_profile(|x| disk_cdf(x, half), w as usize, edge)
            };
            let want = width_10_90(&predicted);
            let got = width_10_90(&edge_profile(&edge_scene(
                z, aperture, focus, lens, w, h, fov,
            )));
            assert!(
                want > 6.0,
                "test geometry: blur should span several pixels ({want})"
            );
            assert!(
                (got - want).abs() <= 0.1 * want,
                "{lens} lens, edge at {z} (focus {focus}): 10–90 width {got:.3} px, \
                 circle of confusion {coc:.3} px predicts {want:.3} px"
            );
        }
    }
}

// ---------------------------------------------------------------- soft shadows

/// A receiving wall x = 0 (kd = 1), a point light of radius `r` at
/// (`l`, 0, 0), and, with `occluder`, an opaque half-plane z ≤ 0 at x = `d`
/// whose front faces the wall: with `sided="front"` the camera (on the light
/// side, looking at the wall through it) sees through its back while shadow
/// rays from the wall hit its front.
fn penumbra_scene(occluder: bool, r: f64, l: f64, d: f64, render_extra: &str) -> String {
    let occ = if occluder {
        format!(
            r#"<mesh id="half">
    <vertices>{d} -50 -50  {d} -50 0  {d} 50 0  {d} 50 -50</vertices>
    <triangles>0 1 2  0 2 3</triangles>
  </mesh>
  <model id="occ" mesh="half"><surface diffuse="0 0 0" sided="front"/></model>"#
        )
    } else {
        String::new()
    };
    format!(
        r#"<scene version="1">
  <plane id="wall" point="0 0 0" normal="1 0 0"><surface diffuse="1 1 1"/></plane>
  {occ}
  <light type="point" position="{l} 0 0" radius="{r}" intensity="{l2}"/>
  <camera id="c" position="3 0 0" direction="-1 0 0" up="0 1 0" fov="{PEN_FOV}">
    <render width="{PEN_W}" height="{PEN_H}" {render_extra}/>
  </camera>
</scene>"#,
        l2 = 1.0
    )
}

const PEN_W: u32 = 64;
const PEN_H: u32 = 4;
const PEN_FOV: f64 = 10.0;

/// The z coordinate on the wall x = 0 of the centre of pixel column `i`.
fn wall_z(i: u32) -> f64 {
    let cam = SpecCamera::new(
        [3.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        PEN_FOV,
        PEN_W,
        PEN_H,
    );
    let d = cam.dir(i, PEN_H / 2);
    let t = -cam.pos[0] / d[0];
    cam.pos[2] + t * d[2]
}

/// Visibility profile (shadowed / unshadowed), columns reordered so that z
/// increases (the camera's image right is −z).
fn visibility_profile(r: f64, l: f64, d: f64, extra: &str) -> (Vec<f64>, Vec<f64>) {
    let lit = whole(&scene(&penumbra_scene(false, r, l, d, extra)), 0).pixels;
    let sh = whole(&scene(&penumbra_scene(true, r, l, d, extra)), 0).pixels;
    let ratio: Vec<f64> = sh
        .iter()
        .zip(&lit)
        .map(|(s, l)| s[0] as f64 / l[0] as f64)
        .collect();
    let mut p = row_profile(&ratio, PEN_W as usize, PEN_H as usize);
    let mut z: Vec<f64> = (0..PEN_W).map(wall_z).collect();
    p.reverse();
    z.reverse();
    (p, z)
}

#[test]
fn soft_shadow_penumbra_width_matches_the_geometric_prediction() {
    let (l, d) = (4.0, 1.0);
    for r in [0.25, 0.4] {
        let (p, z) = visibility_profile(r, l, d, "shadow-samples=\"256\"");
        // Umbra on one side, full light on the other.
        assert!(p[0] < 1e-6 && p[p.len() - 1] > 1.0 - 1e-6, "{p:?}");
        // Similar triangles: a light of width 2r at distance l from the wall,
        // an edge at distance d, cast a penumbra of width 2r·d/(l − d), across
        // which the visible part of the (uniform, square) light grows
        // linearly: 10–90 % is 0.8 of it.
        let penumbra = 2.0 * r * d / (l - d);
        let pitch = (z[1] - z[0]).abs();
        let predicted = pixel_profile(
            |x| box_cdf(x * pitch, penumbra / 2.0),
            PEN_W as usize,
            (PEN_W / 2) as f64,
        );
        let want = width_10_90(&predicted) * pitch;
        let got = width_10_90(&p) * pitch;
        assert!(want > 8.0 * pitch, "penumbra should span several pixels");
        assert!(
            (got - want).abs() <= 0.1 * want,
            "radius {r}: 10–90 penumbra {got:.4} on the wall, geometry predicts {want:.4}"
        );
        // And the penumbra is centred on the shadow of the light's centre (z = 0).
        let mid = crossing(&p, 0.5);
        let z_mid = z[0] + (mid - 0.5) * (z[1] - z[0]);
        assert!(
            z_mid.abs() < 0.1 * penumbra,
            "penumbra centre at z = {z_mid}"
        );
    }
    // A point light (radius 0) casts a hard shadow whatever shadow-samples says.
    let (p, _) = visibility_profile(0.0, l, d, "shadow-samples=\"64\"");
    assert!(width_10_90(&p) <= 1.0);
}

// ---------------------------------------------------------------- interreflection

/// A white floor y = 0 (kd = 1) beside a red wall x = 0 (kd = (0.9, 0, 0)),
/// a white light at `LIGHT`, and 1×1 cameras looking straight down at floor
/// points (x, 0, 0) for each x in `xs`.
fn red_wall_scene(xs: &[f64], diffuse: &str) -> String {
    let cams: String = xs
        .iter()
        .enumerate()
        .map(|(k, x)| {
            format!(
                r#"<camera id="c{k}" position="{x} 1 0" direction="0 -1 0" up="0 0 -1" fov="5">
    <render width="1" height="1" ao-distance="{S_MAX}" {diffuse}/>
  </camera>
"#
            )
        })
        .collect();
    format!(
        r#"<scene version="1">
  <plane id="floor" point="0 0 0" normal="0 1 0"><surface diffuse="1 1 1"/></plane>
  <plane id="wall" point="0 0 0" normal="1 0 0"><surface diffuse="0.9 0 0"/></plane>
  <light type="point" position="{} {} {}" intensity="{LIGHT_I}"/>
  {cams}
</scene>"#,
        LIGHT[0], LIGHT[1], LIGHT[2]
    )
}

const S_MAX: f64 = 3.0;
const LIGHT: [f64; 3] = [2.0, 3.0, 0.5];
const LIGHT_I: f64 = 2.0;

#[test]
fn red_wall_bleeds_onto_the_floor_falling_off_as_f_of_s_predicts() {
    let xs = [0.2, 0.5, 1.0, 1.6, 2.4, 3.2];
    let scene = scene(&red_wall_scene(&xs, "diffuse-samples=\"4096\""));
    let mut last = f64::INFINITY;
    for (k, &x) in xs.iter().enumerate() {
        let px = whole(&scene, k).pixels[0];
        // The floor is white and the light white, so the direct term is the
        // same in every channel; the red excess is kd_floor·G_r.
        let got = px[0] as f64 - px[1] as f64;
        assert_eq!(px[1], px[2]);
        // G_r(p) = ∫ cos θ/π · f(s) · kd_wall,r · E · max(0, N_wall·L) dω over
        // the directions that reach the wall, f(s) = max(0, 1 − s/s_max).
        let want = cosine_quadrature(1200, |d| {
            if d[0] >= 0.0 {
                return 0.0;
            }
            let s = x / -d[0];
            let f = (1.0 - s / S_MAX).max(0.0);
            if f == 0.0 {
                return 0.0;
            }
            let q = [0.0, s * d[1], s * d[2]];
            let to_l = sub(LIGHT, q);
            let n_dot_l = to_l[0] / dot(to_l, to_l).sqrt();
            f * 0.9 * LIGHT_I * n_dot_l.max(0.0)
        });
        if x >= S_MAX {
            // Every path to the wall is longer than s_max: f = 0, no red at all.
            assert_eq!(want, 0.0);
            assert_eq!(px[0], px[1], "no red beyond s_max at x = {x}");
        } else {
            assert!(
                (got - want).abs() <= 0.03 * want + 1e-4,
                "red excess at x = {x}: got {got}, f(s) predicts {want}"
            );
            assert!(got < last, "red light must fall off with distance");
            last = got;
        }
    }
}

#[test]
fn zero_diffuse_samples_render_byte_identical_to_whitted() {
    let xs = [0.2, 1.0];
    let whitted = scene(&red_wall_scene(&xs, ""));
    let m0 = scene(&red_wall_scene(
        &xs,
        "diffuse-samples=\"0\" diffuse-depth=\"3\"",
    ));
    for k in 0..xs.len() {
        let (a, b) = (whole(&whitted, k), whole(&m0, k));
        let bits = |t: &TileResult| -> Vec<u32> {
            t.pixels.iter().flatten().map(|v| v.to_bits()).collect()
        };
        assert_eq!(bits(&a), bits(&b));
        assert_eq!(a.rays, b.rays);
        // Whitted: primary + one shadow ray.
        assert_eq!(a.rays, 2);
    }
}

// ---------------------------------------------------------------- cost

#[test]
fn a_scene_with_no_effect_traces_exactly_the_whitted_rays() {
    // A plane under one light above it and one below it (N·L < 0 on the
    // visible side: no shadow ray), seen obliquely so the top rows see sky
    // (no shadow rays either). Ambient is on but ao-samples is 0.
    let (w, h) = (40u32, 30u32);
    let xml = |shadow_samples: u32| {
        format!(
            r#"<scene version="1">
  <settings ambient="0.2 0.2 0.2" background="0.1 0.2 0.3"/>
  <plane id="p" point="0 0 0" normal="0 1 0"/>
  <light type="point" position="0 4 0"/>
  <light type="point" position="1 -3 0"/>
  <camera id="c" position="0 1 4" direction="0 -0.1 -1" up="0 1 0" fov="60">
    <render width="{w}" height="{h}" shadow-samples="{shadow_samples}"/>
  </camera>
</scene>"#
        )
    };
    let base = whole(&scene(&xml(1)), 0);
    let cam = SpecCamera::new(
        [0.0, 1.0, 4.0],
        [0.0, -0.1, -1.0],
        [0.0, 1.0, 0.0],
        60.0,
        w,
        h,
    );
    let mut hits = 0u64;
    for r in 0..h {
        for i in 0..w {
            if cam.dir(i, r)[1] < 0.0 {
                hits += 1;
            }
        }
    }
    assert!(hits > 0 && hits < (w * h) as u64);
    assert_eq!(base.rays, (w * h) as u64 + hits);
    // shadow-samples > 1 with radius 0: not one ray more, the same bytes.
    let many = whole(&scene(&xml(16)), 0);
    assert_eq!(many.rays, base.rays);
    assert_eq!(many.pixels, base.pixels);
}

// ---------------------------------------------------------------- determinism

/// A small scene with every effect on: DOF (disk lens), jittered
/// supersampling, soft shadows, AO, two-level diffuse interreflection, glass.
fn all_effects(render: &str) -> Scene {
    scene(&format!(
        r#"<scene version="1">
  <settings ambient="0.2 0.2 0.2"/>
  <plane id="floor" point="0 0 0" normal="0 1 0"><surface diffuse="0.8 0.8 0.8"/></plane>
  <plane id="wall" point="-1.5 0 0" normal="1 0 0"><surface diffuse="0.8 0.1 0.1"/></plane>
  <sphere id="s" center="0 0.6 0" radius="0.6"><surface diffuse="0.2 0.5 0.8" specular="0.5 0.5 0.5"/></sphere>
  <sphere id="g" center="0.9 0.35 0.8" radius="0.35"><surface opacity="0.2" ior="1.5" reflectivity="0.1"/></sphere>
  <light type="point" position="1 3 1" radius="0.3"/>
  <camera id="c" position="0 1.2 4" lookat="0 0.5 0" fov="50" aperture="0.15" lens="disk">
    <render width="23" height="17" {render}/>
  </camera>
</scene>"#
    ))
}

fn tiled_bits(scene: &Scene, tile: u32, threads: usize, options: RenderOptions) -> Vec<u32> {
    let r = &scene.desc.cameras[0].render;
    let (w, h) = (r.width, r.height);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let mut out = vec![0u32; (w * h * 3) as usize];
    pool.install(|| {
        for rect in band_order_tiles(w, h, tile) {
            let t = trevi_core::tile::render_tile_with(scene, 0, rect, options);
            for (k, px) in t.pixels.iter().enumerate() {
                let (x, y) = (rect.x + k as u32 % rect.w, rect.y + k as u32 / rect.w);
                for ch in 0..3 {
                    out[((y * w + x) * 3) as usize + ch] = px[ch].to_bits();
                }
            }
        }
    });
    out
}

#[test]
fn every_effect_on_is_deterministic_across_tile_sizes_and_threads() {
    let fixed = "supersample=\"2\" jitter=\"true\" shadow-samples=\"3\" ao-samples=\"3\" \
                 diffuse-samples=\"2\" diffuse-depth=\"2\" seed=\"7\"";
    let adaptive = "noise-threshold=\"0.02\" min-samples=\"4\" max-samples=\"32\" \
                    shadow-samples=\"2\" ao-samples=\"2\" diffuse-samples=\"1\"";
    for render in [fixed, adaptive] {
        let scene = all_effects(render);
        for options in [
            RenderOptions::default(),
            RenderOptions {
                sampler: trevi_core::sampling::SamplerKind::Independent,
            },
        ] {
            let reference = tiled_bits(&scene, 64, 1, options);
            for (tile, threads) in [(1, 2), (5, 1), (7, 2)] {
                assert!(
                    tiled_bits(&scene, tile, threads, options) == reference,
                    "{render}: tile {tile}, {threads} threads differs"
                );
            }
        }
    }
    // The seed matters (the streams are not ignored).
    let a = tiled_bits(&all_effects(fixed), 64, 2, RenderOptions::default());
    let b = tiled_bits(
        &all_effects(&fixed.replace("seed=\"7\"", "seed=\"8\"")),
        64,
        2,
        RenderOptions::default(),
    );
    assert_ne!(a, b);
}

/// Records the rays the integrator shows its observer.
#[derive(Default)]
struct Recorder {
    closest: std::sync::Mutex<Vec<f32>>,
    shadow: std::sync::Mutex<Vec<f32>>,
}

impl trevi_core::integrator::RayObserver for Recorder {
    fn closest(&self, _o: glam::Vec3, _d: glam::Vec3, t_max: f32) {
        self.closest.lock().unwrap().push(t_max);
    }
    fn shadow(&self, _o: glam::Vec3, _d: glam::Vec3, t_max: f32) {
        self.shadow.lock().unwrap().push(t_max);
    }
}

#[test]
fn the_observer_sees_every_traced_ray_as_its_kind_and_changes_no_pixel() {
    let scene = all_effects(
        "supersample=\"2\" shadow-samples=\"3\" ao-samples=\"3\" diffuse-samples=\"2\" diffuse-depth=\"2\"",
    );
    let r = &scene.desc.cameras[0].render;
    let rect = Rect::new(0, 0, r.width, r.height);
    let rec = Recorder::default();
    let seen =
        trevi_core::tile::render_tile_observed(&scene, 0, rect, RenderOptions::default(), &rec);
    assert_eq!(seen, whole(&scene, 0), "observing changed the tile");
    let (closest, shadow) = (
        rec.closest.into_inner().unwrap(),
        rec.shadow.into_inner().unwrap(),
    );
    assert_eq!((closest.len() + shadow.len()) as u64, seen.rays);
    // Shadow rays span the segment to the light (t < 1); closest-hit rays
    // are camera/mirror rays (unbounded) or AO and gather rays (s_max).
    let s_max = scene.ao_distance(0);
    assert!(!shadow.is_empty() && shadow.iter().all(|&t| t == 1.0 - 1e-6));
    assert!(closest.iter().all(|&t| t == f32::INFINITY || t == s_max));
    let camera_rays = (r.width * r.height * 4) as usize;
    assert!(closest.iter().filter(|t| t.is_infinite()).count() >= camera_rays);
    assert!(closest.contains(&s_max));
}

// ---------------------------------------------------------------- adaptive

#[test]
fn adaptive_sampling_spends_samples_where_the_noise_is_and_meets_its_threshold() {
    let (l, d, r) = (4.0, 1.0, 0.4);
    let tau = 0.02;
    let (min, max) = (16u32, 1024u32);
    let adaptive = format!("noise-threshold=\"{tau}\" min-samples=\"{min}\" max-samples=\"{max}\"");
    let sc = scene(&penumbra_scene(true, r, l, d, &adaptive));
    // Samples per pixel: each camera sample hitting the lit side of the wall
    // traces the primary ray and one shadow ray.
    let mut spp = Vec::new();
    let mut values = Vec::new();
    for y in 0..PEN_H {
        for x in 0..PEN_W {
            let t = render_tile(&sc, 0, Rect::new(x, y, 1, 1));
            assert_eq!(t.rays % 2, 0);
            spp.push((t.rays / 2) as u32);
            values.push(t.pixels[0]);
        }
    }
    // Per-pixel determinism: the same values when rendered as one tile.
    assert_eq!(whole(&sc, 0).pixels, values);

    // A converged reference: 64×64 jittered samples per pixel.
    let reference = whole(
        &scene(&penumbra_scene(
            true,
            r,
            l,
            d,
            "supersample=\"64\" jitter=\"true\"",
        )),
        0,
    )
    .pixels;
    let (mut flat, mut noisy) = (Vec::new(), Vec::new());
    let mut sq_err = 0.0;
    let mut n_err = 0;
    for k in 0..values.len() {
        let v = reference[k][0] as f64;
        // Umbra (0) or full light (E·N·L ≈ 1, varying smoothly).
        if !(1e-4..=0.999).contains(&v) {
            flat.push(spp[k]);
        } else if v > 0.1 && v < 0.9 {
            noisy.push(spp[k]);
        }
        let err = (0..3)
            .map(|ch| (values[k][ch] as f64 - reference[k][ch] as f64).abs())
            .fold(0.0, f64::max);
        assert!(
            err <= 4.0 * tau,
            "pixel {k}: error {err} vs threshold {tau}"
        );
        if spp[k] < max {
            sq_err += err * err;
            n_err += 1;
        }
    }
    assert!(!flat.is_empty() && noisy.len() >= 8, "{flat:?} {noisy:?}");
    // Umbra pixels have zero variance and stop at min-samples.
    assert!(flat.iter().all(|&n| n == min), "flat pixels: {flat:?}");
    let mean_noisy = noisy.iter().sum::<u32>() as f64 / noisy.len() as f64;
    assert!(
        mean_noisy > 8.0 * min as f64,
        "penumbra pixels should sample much more: {noisy:?}"
    );
    assert!(spp.iter().all(|&n| n >= min && n <= max));
    // Pixels that stopped on their own meet the threshold in RMS.
    let rms = (sq_err / n_err as f64).sqrt();
    assert!(rms <= tau, "RMS error {rms} over threshold {tau}");
}
