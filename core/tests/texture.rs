//! Textured renders checked against closed forms computed here, in f64,
//! independently of the renderer's texture code: a quad facing the camera,
//! lit by the ambient light alone (ka = diffuse = 1, ambient 1, no AO), so
//! each pixel is the texture's value where its ray meets the quad.

// Independent closed forms and test geometry, computed with std on purpose (clippy.toml).
#![allow(clippy::disallowed_methods)]

mod common;
use common::*;
use std::collections::BTreeMap;
use trevi_core::{Bundle, Scene};

const W: u32 = 48;

/// A PNG of `side × side` grey texels, rows from the top.
fn grey_png(side: u32, value: impl Fn(u32, u32) -> u8) -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, side, side);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header().unwrap();
    let data: Vec<u8> = (0..side * side)
        .flat_map(|k| [value(k % side, k / side); 3])
        .collect();
    w.write_image_data(&data).unwrap();
    w.finish().unwrap();
    out
}

/// The quad [-1, 1]² in z = 0 with uv = (x+1)/2, (y+1)/2, seen head on from
/// z = 2, textured with `tex.png` under `surface_attrs`.
fn quad_scene(surface_attrs: &str, render_attrs: &str) -> String {
    format!(
        r#"<scene version="1">
  <settings background="0 0 0" ambient="1 1 1"/>
  <mesh id="q"><vertices>-1 -1 0  1 -1 0  1 1 0  -1 1 0</vertices>
    <uvs>0 0  1 0  1 1  0 1</uvs><triangles>0 1 2  0 2 3</triangles></mesh>
  <model id="m" mesh="q"><surface diffuse="1 1 1" diffuse-texture="tex.png" {surface_attrs}/></model>
  <camera id="c" position="0 0 2" direction="0 0 -1" up="0 1 0" fov="60">
    <render width="{W}" height="{W}" {render_attrs}/>
  </camera>
</scene>"#
    )
}

fn textured_scene(xml: &str, png: Vec<u8>) -> Scene {
    let mut files = BTreeMap::new();
    files.insert("scene.xml".to_string(), xml.as_bytes().to_vec());
    files.insert("tex.png".to_string(), png);
    let b = Bundle {
        scene: "scene.xml".into(),
        files,
    };
    Scene::from_bundle(&b).unwrap_or_else(|e| panic!("{e}"))
}

fn srgb(code: u8) -> f64 {
    let c = code as f64 / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Where pixel (i, r)'s centre ray meets the quad's plane, as uv; `None`
/// off the quad or within `margin` of its edge.
fn pixel_uv(cam: &SpecCamera, i: u32, r: u32, margin: f64) -> Option<(f64, f64)> {
    let d = cam.dir(i, r);
    let t = -2.0 / d[2];
    let (x, y) = (d[0] * t, d[1] * t);
    let lim = 1.0 - margin;
    (x.abs() < lim && y.abs() < lim).then(|| ((x + 1.0) / 2.0, (y + 1.0) / 2.0))
}

fn camera() -> SpecCamera {
    SpecCamera::new(
        [0.0, 0.0, 2.0],
        [0.0, 0.0, -1.0],
        [0.0, 1.0, 0.0],
        60.0,
        W,
        W,
    )
}

#[test]
fn magnified_texture_is_the_bilinear_value_of_its_texel_grid() {
    // 4 × 4 texels of distinct grey codes; the quad spans ~41 pixels, so
    // each texel covers ~10 pixels (magnification: level 0 only).
    const N: u32 = 4;
    let code = |i: u32, j: u32| (17 + 37 * i + 59 * j) as u8;
    for wrap in ["repeat", "clamp"] {
        let scene = textured_scene(
            &quad_scene(&format!("texture-wrap=\"{wrap}\""), ""),
            grey_png(N, code),
        );
        let px = render(&scene, 0);
        let cam = camera();
        let texel = |i: i64, j: i64| {
            let n = N as i64;
            let (i, j) = if wrap == "repeat" {
                (i.rem_euclid(n), j.rem_euclid(n))
            } else {
                (i.clamp(0, n - 1), j.clamp(0, n - 1))
            };
            srgb(code(i as u32, j as u32))
        };
        let mut checked = 0;
        for r in 0..W {
            for i in 0..W {
                let Some((u, v)) = pixel_uv(&cam, i, r, 1e-3) else {
                    continue;
                };
                // Texel centres at (k + ½)/N; rows from the top (v = 1).
                let x = u * N as f64 - 0.5;
                let y = (1.0 - v) * N as f64 - 0.5;
                let (x0, y0) = (x.floor(), y.floor());
                let (fx, fy) = (x - x0, y - y0);
                let (x0, y0) = (x0 as i64, y0 as i64);
                let top = texel(x0, y0) * (1.0 - fx) + texel(x0 + 1, y0) * fx;
                let bottom = texel(x0, y0 + 1) * (1.0 - fx) + texel(x0 + 1, y0 + 1) * fx;
                let want = top * (1.0 - fy) + bottom * fy;
                let got = px[(r * W + i) as usize];
                for c in got {
                    assert!(
                        (c as f64 - want).abs() < 2e-4,
                        "{wrap} pixel ({i}, {r}) uv ({u:.4}, {v:.4}): got {c}, want {want}"
                    );
                }
                checked += 1;
            }
        }
        assert!(checked > 1500, "{checked} pixels on the quad");
    }
}

/// Every pixel of the quad and their mean, for a one-texel black and white
/// checker repeated `repeats` times across it.
fn minified(repeats: u32, supersample: u32) -> (Vec<f64>, f64) {
    let scene = textured_scene(
        &quad_scene(
            &format!("texture-scale=\"{repeats} {repeats}\""),
            &format!("supersample=\"{supersample}\""),
        ),
        grey_png(64, |i, j| if (i + j) % 2 == 0 { 0 } else { 255 }),
    );
    let px = render(&scene, 0);
    let cam = camera();
    let mut on = Vec::new();
    for r in 0..W {
        for i in 0..W {
            // Whole pixels only: one pixel across from the edge.
            if pixel_uv(&cam, i, r, 0.1).is_some() {
                on.push(px[(r * W + i) as usize][0] as f64);
            }
        }
    }
    let mean = on.iter().sum::<f64>() / on.len() as f64;
    (on, mean)
}

#[test]
fn minified_texture_converges_to_its_mean_without_aliasing() {
    // The texture's mean: half its texels are 0, half 1 (linear).
    let want = 0.5;
    // 64 × 64 texels repeated 32 times: ~2048 texels across ~41 pixels,
    // 50 texels a pixel. Point sampling would give 0 or 1 per pixel.
    for supersample in [1, 3] {
        let (px, mean) = minified(32, supersample);
        assert!(
            (mean - want).abs() < 0.01,
            "supersample {supersample}: mean {mean}, want {want}"
        );
        let worst = px.iter().map(|p| (p - want).abs()).fold(0.0, f64::max);
        assert!(
            worst < 0.02,
            "supersample {supersample}: a pixel {worst} from the mean"
        );
    }
}

#[test]
fn the_level_of_detail_logarithm_is_close_to_log2_everywhere() {
    use trevi_core::world::{log2, texture_lod};
    let mut x = 1e-40f32;
    while x < 1e38 {
        let err = (log2(x) as f64 - (x as f64).log2()).abs();
        assert!(err < 0.008, "log2({x}) = {}, error {err}", log2(x));
        x *= 1.37;
    }
    assert_eq!(log2(1.0), 0.0);
    assert_eq!(log2(8.0), 3.0);
    assert!(log2(0.0) < -1e29 && log2(-1.0) < -1e29 && log2(f32::NAN) < -1e29);
    assert!(log2(f32::INFINITY) > 1e29);
    // λ = ½·log₂(ta/pa) + log₂(w/cos): 4·4 texels on 1 unit², a cone 1/4
    // wide head on: each texel is 1/4 wide, so level 0.
    assert!(texture_lod(16.0, 1.0, 0.25, 1.0).abs() < 0.01);
    // Twice as wide, or at 60°: one level up.
    assert!((texture_lod(16.0, 1.0, 0.5, 1.0) - 1.0).abs() < 0.01);
    assert!((texture_lod(16.0, 1.0, 0.25, 0.5) - 1.0).abs() < 0.01);
    // Degenerate inputs: level 0.
    assert_eq!(texture_lod(0.0, 1.0, 1.0, 1.0), 0.0);
    assert_eq!(texture_lod(1.0, 0.0, 1.0, 1.0), 0.0);
    assert_eq!(texture_lod(1.0, 1.0, 0.0, 1.0), 0.0);
}

/// A PNG of `side × side` texels of one 8-bit RGB colour.
fn uniform_png(side: u32, rgb: [u8; 3]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, side, side);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header().unwrap();
    let data: Vec<u8> = (0..side * side).flat_map(|_| rgb).collect();
    w.write_image_data(&data).unwrap();
    w.finish().unwrap();
    out
}

/// Every mode reads the textured albedo: with ambient occlusion and the
/// diffuse gather (whose gathered points are textured surfaces too), a
/// floor and a wall textured with one uniform colour render as the same
/// scene untextured with `diffuse` (and `ambient`) set to that colour,
/// decoded from sRGB here; and the gather and the texture both change the
/// picture, so the comparison is not vacuous.
#[test]
fn ao_and_the_diffuse_gather_use_the_textured_albedo() {
    const RGB: [u8; 3] = [200, 120, 60];
    let linear = RGB.map(srgb);
    let scene = |surface: &str, render: &str| {
        format!(
            r#"<scene version="1">
  <settings background="0.3 0.4 0.5" ambient="0.4 0.4 0.4"/>
  <mesh id="q"><vertices>-1 0 -1  1 0 -1  1 0 1  -1 0 1</vertices>
    <uvs>0 0  1 0  1 1  0 1</uvs><triangles>0 2 1  0 3 2</triangles></mesh>
  <model id="floor" mesh="q"><transform><scale v="3"/></transform>{surface}</model>
  <model id="wall" mesh="q">
    <transform><rotate axis="1 0 0" angle="90"/><scale v="3"/><translate v="0 1 -1.5"/></transform>{surface}</model>
  <sphere id="s" center="0 0.6 0" radius="0.6"><surface diffuse="0.8 0.8 0.8"/></sphere>
  <light type="point" position="1.5 2.5 2" intensity="3" attenuation="0 0 1"/>
  <camera id="c" position="0 1.2 3.5" lookat="0 0.5 0" fov="55">
    <render width="24" height="18" {render}/>
  </camera>
</scene>"#
        )
    };
    let textured = r#"<surface diffuse="1 1 1" diffuse-texture="tex.png"/>"#;
    let c = format!("{:.9} {:.9} {:.9}", linear[0], linear[1], linear[2]);
    let plain = format!(r#"<surface diffuse="{c}" ambient="{c}"/>"#);
    let png = || uniform_png(8, RGB);
    let effects = r#"ao-samples="4" diffuse-samples="4" diffuse-depth="2""#;
    let a = render(&textured_scene(&scene(textured, effects), png()), 0);
    let b = render(&textured_scene(&scene(&plain, effects), png()), 0);
    for (k, (x, y)) in a.iter().zip(&b).enumerate() {
        for c in 0..3 {
            assert!(
                (x[c] - y[c]).abs() < 1e-5,
                "pixel {k}: textured {x:?}, untextured {y:?}"
            );
        }
    }
    let differs = |p: &[[f32; 3]], q: &[[f32; 3]]| {
        p.iter()
            .zip(q)
            .any(|(x, y)| (0..3).any(|c| (x[c] - y[c]).abs() > 1e-3))
    };
    let no_gather = render(&textured_scene(&scene(textured, ""), png()), 0);
    assert!(differs(&a, &no_gather), "the gather adds nothing here");
    let white = r#"<surface diffuse="1 1 1"/>"#;
    let untextured = render(&textured_scene(&scene(white, effects), png()), 0);
    assert!(differs(&a, &untextured), "the texture changes nothing here");
}

/// Side of the multi-scale texture below.
const MS: u32 = 256;

/// A texture whose MIP levels all differ: the sum of checkers of every
/// scale, cells of 2^s texels weighted `w[s]`. Level k keeps the checkers
/// of cells ≥ 2^k and averages the finer ones away, so each level, and the
/// colour at any level of detail, is its own.
fn multiscale_code(i: u32, j: u32) -> u8 {
    const W: [u32; 8] = [4, 8, 16, 24, 32, 48, 56, 60];
    (0..8)
        .filter(|&s| ((i >> s) + (j >> s)) % 2 == 1)
        .map(|s| W[s as usize])
        .sum::<u32>() as u8
}

/// The MIP chain of [`multiscale_code`] in linear values, computed here in
/// f64 (sRGB decoded, then 2 × 2 box filters: the sides are powers of 2).
fn multiscale_levels() -> Vec<Vec<f64>> {
    let mut levels = vec![(0..MS * MS)
        .map(|k| srgb(multiscale_code(k % MS, k / MS)))
        .collect::<Vec<f64>>()];
    let mut side = MS;
    while side > 1 {
        let prev = levels.last().unwrap();
        let half = side / 2;
        let at = |i: u32, j: u32| prev[(j * side + i) as usize];
        levels.push(
            (0..half * half)
                .map(|k| {
                    let (i, j) = (2 * (k % half), 2 * (k / half));
                    (at(i, j) + at(i + 1, j) + at(i, j + 1) + at(i + 1, j + 1)) / 4.0
                })
                .collect(),
        );
        side = half;
    }
    levels
}

/// The texture at `uv` and level of detail `lod`, in f64: bilinear between
/// texel centres of each level (repeat), linear between the two levels.
fn sample_levels(levels: &[Vec<f64>], u: f64, v: f64, lod: f64) -> f64 {
    let bilinear = |k: usize| {
        let side = (MS >> k) as i64;
        let l = &levels[k];
        let x = u * side as f64 - 0.5;
        let y = (1.0 - v) * side as f64 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let t = |i: i64, j: i64| l[(j.rem_euclid(side) * side + i.rem_euclid(side)) as usize];
        let (i, j) = (x0 as i64, y0 as i64);
        let top = t(i, j) * (1.0 - fx) + t(i + 1, j) * fx;
        let bottom = t(i, j + 1) * (1.0 - fx) + t(i + 1, j + 1) * fx;
        top * (1.0 - fy) + bottom * fy
    };
    let top = (levels.len() - 1) as f64;
    let lod = lod.clamp(0.0, top);
    let l0 = lod.floor() as usize;
    let f = lod - l0 as f64;
    if f > 0.0 {
        bilinear(l0) * (1.0 - f) + bilinear(l0 + 1) * f
    } else {
        bilinear(l0)
    }
}

/// The ray-cone level of detail in closed form (Akenine-Möller et al.,
/// Ray Tracing Gems ch. 20): λ = ½·log₂(texel area / world area) +
/// log₂(w / cos θ), with w = spread · (length of the path from the camera),
/// spread = 1 / (W · ½ / tan(fov/2)) for one sample a pixel.
fn cone_lod(texel_area: f64, world_area: f64, path: f64, cos: f64) -> f64 {
    let spread = 1.0 / (W as f64 * 0.5 / (60f64.to_radians() / 2.0).tan());
    0.5 * (texel_area / world_area).log2() + (spread * path / cos).log2()
}

/// Checks a render against the closed form at every pixel given: `hit`
/// tells a pixel's centre ray's uv, path length to the textured surface
/// and cosine there (`None`: not on it). The renderer's logarithm is
/// within 0.008 of log₂, so the value is checked between the levels of
/// detail 0.01 either side. Returns the pixels checked and the highest
/// level of detail among them.
fn check_levels(
    px: &[[f32; 3]],
    texel_area: f64,
    world_area: f64,
    hit: impl Fn([f64; 3]) -> Option<(f64, f64, f64, f64)>,
    what: &str,
) -> (usize, f64) {
    let levels = multiscale_levels();
    let cam = camera();
    let (mut checked, mut highest) = (0, 0f64);
    for r in 0..W {
        for i in 0..W {
            let Some((u, v, path, cos)) = hit(cam.dir(i, r)) else {
                continue;
            };
            let lod = cone_lod(texel_area, world_area, path, cos);
            highest = highest.max(lod);
            let mut lods = vec![lod - 0.01, lod, lod + 0.01];
            if (lod - 0.01).floor() != (lod + 0.01).floor() {
                lods.push((lod + 0.01).floor());
            }
            let wants: Vec<f64> = lods
                .iter()
                .map(|&l| sample_levels(&levels, u, v, l))
                .collect();
            let lo = wants.iter().copied().fold(f64::INFINITY, f64::min) - 2e-4;
            let hi = wants.iter().copied().fold(f64::NEG_INFINITY, f64::max) + 2e-4;
            let got = px[(r * W + i) as usize][0] as f64;
            assert!(
                (lo..=hi).contains(&got),
                "{what}: pixel ({i}, {r}) uv ({u:.4}, {v:.4}) level {lod:.3}: got {got}, \
                 want {} (level {:.0}: {}, level {:.0}: {})",
                wants[1],
                lod.floor(),
                sample_levels(&levels, u, v, lod.floor()),
                lod.floor() + 1.0,
                sample_levels(&levels, u, v, lod.floor() + 1.0),
            );
            checked += 1;
        }
    }
    (checked, highest)
}

#[test]
fn the_level_of_detail_is_the_ray_cone_s_closed_form_head_on() {
    // The quad [-1, 1]² at distance 2 with 256² texels: levels 2 to 3,
    // each level of the texture distinct, so a level off by any amount (or
    // a cone of the wrong width) gives other values.
    let scene = textured_scene(&quad_scene("", ""), grey_png(MS, multiscale_code));
    let px = render(&scene, 0);
    // Each triangle: half the uv square (× 256² texels) over half of the
    // 2 × 2 quad; the areas are doubled alike.
    let texel_area = (MS * MS) as f64;
    let (checked, highest) = check_levels(
        &px,
        texel_area,
        4.0,
        |d| {
            let t = -2.0 / d[2];
            let (x, y) = (d[0] * t, d[1] * t);
            (x.abs() < 0.999 && y.abs() < 0.999)
                .then(|| ((x + 1.0) / 2.0, (y + 1.0) / 2.0, t, -d[2]))
        },
        "head on",
    );
    assert!(checked > 1500, "{checked} pixels");
    assert!(highest > 2.0, "levels up to {highest}");
}

#[test]
fn a_mirror_extends_the_ray_cone_by_the_reflected_path() {
    // A mirror in z = 0 in front of the camera (at z = 2, looking down −z)
    // shows the textured quad [-4, 4]² in z = 4 behind the camera: the cone
    // at the quad is as wide as the whole path's, camera to mirror to quad
    // (6 / cos θ), as if the quad were seen directly 6 away. A cone
    // restarted at the mirror would be 2 / 3 as wide (0.58 levels lower),
    // one that ignored the first leg the same.
    let xml = format!(
        r#"<scene version="1">
  <settings background="0 0 0" ambient="1 1 1"/>
  <mesh id="q"><vertices>-4 -4 4  4 -4 4  4 4 4  -4 4 4</vertices>
    <uvs>0 0  1 0  1 1  0 1</uvs><triangles>0 1 2  0 2 3</triangles></mesh>
  <model id="m" mesh="q"><surface diffuse="1 1 1" diffuse-texture="tex.png"/></model>
  <plane id="mirror" point="0 0 0" normal="0 0 1"><surface diffuse="0 0 0" reflectivity="1"/></plane>
  <camera id="c" position="0 0 2" direction="0 0 -1" up="0 1 0" fov="60">
    <render width="{W}" height="{W}" max-depth="4"/>
  </camera>
</scene>"#
    );
    let scene = textured_scene(&xml, grey_png(MS, multiscale_code));
    let px = render(&scene, 0);
    let (checked, highest) = check_levels(
        &px,
        (MS * MS) as f64,
        64.0,
        |d| {
            // To the mirror (t1), then mirrored in z to the quad (t2).
            let t1 = -2.0 / d[2];
            let t2 = -4.0 / d[2];
            let (x, y) = (d[0] * (t1 + t2), d[1] * (t1 + t2));
            (x.abs() < 3.99 && y.abs() < 3.99)
                .then(|| ((x + 4.0) / 8.0, (y + 4.0) / 8.0, t1 + t2, -d[2]))
        },
        "in the mirror",
    );
    assert_eq!(checked, (W * W) as usize, "the quad fills the mirror");
    assert!(highest > 2.0, "levels up to {highest}");
}
