//! Whole renders checked against closed-form values of the spec's formulas
//! (spec/aisxml.md, "Lighting"), computed here independently in f64.

// Independent closed forms and test geometry, computed with std on purpose (clippy.toml).
#![allow(clippy::disallowed_methods)]

mod common;
use common::*;

const W: u32 = 64;
const H: u32 = 48;

/// A diffuse(+specular) plane y = 0 seen by a camera 3 units above looking
/// straight down, under one light given as XML; the image is rendered through
/// the EXR writer and read back, as a user would get it.
fn plane_scene(surface: &str, light: &str, ambient: &str) -> String {
    format!(
        r#"<scene version="1">
  <settings background="0 0 0" ambient="{ambient}"/>
  <plane id="p" point="0 0 0" normal="0 1 0"><surface {surface}/></plane>
  {light}
  <camera id="down" position="0 3 0" direction="0 -1 0" up="0 0 -1" fov="60">
    <render width="{W}" height="{H}" output="down.exr"/>
  </camera>
</scene>"#
    )
}

fn render_exr(xml: &str) -> Vec<[f32; 3]> {
    let scene = scene(xml);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("down.exr");
    render_to_file(&scene, 0, 16, &out);
    let (w, h, px) = trevi_core::output::read_exr_rgb(&out).unwrap();
    assert_eq!((w, h), (W, H));
    px
}

/// Where the pixel-centre ray of (i, r) meets the plane y = 0, and the unit
/// view vector V there.
fn plane_hit(cam: &SpecCamera, i: u32, r: u32) -> ([f64; 3], [f64; 3]) {
    let d = cam.dir(i, r);
    let t = -cam.pos[1] / d[1];
    (add(cam.pos, scale(d, t)), scale(d, -1.0))
}

fn down_camera() -> SpecCamera {
    SpecCamera::new(
        [0.0, 3.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, -1.0],
        60.0,
        W,
        H,
    )
}

#[test]
fn diffuse_plane_under_a_point_light_matches_the_closed_form() {
    let kd = [0.5, 0.6, 0.7];
    let (light, color, intensity, att) = ([0.3, 2.0, -0.2], [1.0, 0.9, 0.8], 1.5, [1.0, 0.2, 0.05]);
    let xml = plane_scene(
        "diffuse=\"0.5 0.6 0.7\" ambient=\"0.2 0.1 0.3\"",
        "<light type=\"point\" position=\"0.3 2 -0.2\" color=\"1 0.9 0.8\" intensity=\"1.5\" attenuation=\"1 0.2 0.05\"/>",
        "0.1 0.2 0.05",
    );
    let px = render_exr(&xml);
    let cam = down_camera();
    let amb = [0.2 * 0.1, 0.1 * 0.2, 0.3 * 0.05];
    for r in 0..H {
        for i in 0..W {
            let (p, _) = plane_hit(&cam, i, r);
            let to_l = sub(light, p);
            let d = dot(to_l, to_l).sqrt();
            let n_dot_l = to_l[1] / d;
            let e = intensity / (att[0] + att[1] * d + att[2] * d * d);
            for ch in 0..3 {
                let want = amb[ch] + kd[ch] * color[ch] * e * n_dot_l;
                assert_close(
                    px[(r * W + i) as usize][ch],
                    want,
                    1e-4,
                    &format!("pixel {i},{r} ch {ch}"),
                );
            }
        }
    }
}

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

#[test]
fn spot_light_cone_edge_matches_the_smoothstep_falloff() {
    let xml = plane_scene(
        "diffuse=\"1 1 1\"",
        "<light type=\"spot\" position=\"0.1 2 0\" direction=\"0 -1 0\" inner=\"15\" outer=\"25\"/>",
        "0 0 0",
    );
    let px = render_exr(&xml);
    let cam = down_camera();
    let light = [0.1, 2.0, 0.0];
    let (ci, co) = (15f64.to_radians().cos(), 25f64.to_radians().cos());
    let (mut lit, mut dark, mut edge) = (0, 0, 0);
    for r in 0..H {
        for i in 0..W {
            let (p, _) = plane_hit(&cam, i, r);
            let to_l = sub(light, p);
            let d = dot(to_l, to_l).sqrt();
            // θ between the spot direction (0,−1,0) and the light-to-point vector.
            let cos_theta = to_l[1] / d;
            let f = smoothstep(co, ci, cos_theta);
            let want = f * (to_l[1] / d);
            let got = px[(r * W + i) as usize][0];
            if want == 0.0 {
                assert_eq!(got, 0.0, "pixel {i},{r} outside the cone");
                dark += 1;
            } else {
                // Relative 1e-4 of the value, or of 1% of the peak where the
                // falloff nears zero (f32 cos θ limits precision there).
                let err = (got as f64 - want).abs();
                assert!(
                    err <= 1e-4 * want.max(0.01),
                    "pixel {i},{r}: got {got}, want {want}"
                );
                if f < 1.0 {
                    edge += 1;
                } else {
                    lit += 1;
                }
            }
        }
    }
    // The image must actually contain the inside, the edge and the outside.
    assert!(
        lit > 50 && dark > 50 && edge > 50,
        "lit {lit} dark {dark} edge {edge}"
    );
}

#[test]
fn specular_term_peaks_at_the_mirror_direction_and_matches_phong() {
    let (kd, ks, n) = (0.2, 0.5, 20.0);
    let light = [0.6, 2.0, 0.3];
    let xml = plane_scene(
        "diffuse=\"0.2 0.2 0.2\" specular=\"0.5 0.5 0.5\" shininess=\"20\"",
        "<light type=\"point\" position=\"0.6 2 0.3\"/>",
        "0 0 0",
    );
    let px = render_exr(&xml);
    let cam = down_camera();
    let mut best = (0.0f32, 0u32, 0u32);
    for r in 0..H {
        for i in 0..W {
            let (p, v) = plane_hit(&cam, i, r);
            let l = norm(sub(light, p));
            let refl = [-l[0], l[1], -l[2]]; // reflect(−L, N) with N = +y
            let spec = dot(refl, v).max(0.0).powf(n);
            let want = kd * l[1] + ks * spec;
            let got = px[(r * W + i) as usize][1];
            assert_close(got, want, 1e-4, &format!("pixel {i},{r}"));
            if got > best.0 {
                best = (got, i, r);
            }
        }
    }
    // The mirror point: where the camera-to-plane and plane-to-light paths
    // make equal angles, at (x, z) = light·3/(3+2) along the way.
    let mp = [0.6 * 3.0 / 5.0, 0.0, 0.3 * 3.0 / 5.0];
    let (_, i, r) = best;
    let (p, _) = plane_hit(&cam, i, r);
    let pixel = 2.0 * 3.0 * (30f64.to_radians()).tan() / W as f64; // world size of a pixel
    assert!(
        (p[0] - mp[0]).abs() <= 1.5 * pixel && (p[2] - mp[2]).abs() <= 1.5 * pixel,
        "brightest pixel at {p:?}, mirror point {mp:?}"
    );
}

/// A camera at the origin looking down −z sees a small white square at
/// (x, y, −5): the centroid of its image.
fn marker_centroid(x: f64, y: f64, fov: f64, w: u32, h: u32) -> (f64, f64) {
    let xml = format!(
        r#"<scene version="1">
  <settings ambient="1 1 1"/>
  <mesh id="sq">
    <vertices>-0.1 -0.1 0  0.1 -0.1 0  0.1 0.1 0  -0.1 0.1 0</vertices>
    <triangles>0 1 2  0 2 3</triangles>
  </mesh>
  <model id="m" mesh="sq">
    <transform><translate v="{x} {y} -5"/></transform>
    <surface diffuse="0 0 0" ambient="1 1 1"/>
  </model>
  <camera id="c" position="0 0 0" direction="0 0 -1" fov="{fov}">
    <render width="{w}" height="{h}" supersample="4"/>
  </camera>
</scene>"#
    );
    let s = scene(&xml);
    let px = render(&s, 0);
    let (mut sx, mut sy, mut m) = (0.0, 0.0, 0.0);
    for r in 0..h {
        for i in 0..w {
            let v = px[(r * w + i) as usize][0] as f64;
            sx += v * (i as f64 + 0.5);
            sy += v * (r as f64 + 0.5);
            m += v;
        }
    }
    assert!(m > 0.0, "marker not visible");
    (sx / m, sy / m)
}

#[test]
fn plus_x_is_on_the_right_and_plus_y_at_the_top() {
    let (w, h) = (200, 100);
    let (cx, cy) = marker_centroid(1.0, 0.0, 60.0, w, h);
    assert!(cx > w as f64 / 2.0 + 10.0, "+x marker at column {cx}");
    assert!((cy - h as f64 / 2.0).abs() < 1.0);
    let (cx, cy) = marker_centroid(0.0, 0.8, 60.0, w, h);
    assert!(
        cy < h as f64 / 2.0 - 10.0,
        "+y marker at row {cy} (row 0 is the top)"
    );
    assert!((cx - w as f64 / 2.0).abs() < 1.0);
}

#[test]
fn field_of_view_scales_marker_position_as_s_predicts() {
    let (w, h) = (400, 300);
    for fov in [30.0f64, 60.0, 90.0, 120.0] {
        let s = 0.5 / (fov.to_radians() / 2.0).tan();
        // A point at (X, Y, −Z) lands at column W·(0.5 + s·X/Z) and at row
        // H/2 − W·s·Y/Z (b = v·H/W, rows counted from the top).
        let (x, y, z) = (0.6, 0.3, 5.0);
        let (cx, cy) = marker_centroid(x, y, fov, w, h);
        let want_x = w as f64 * (0.5 + s * x / z);
        let want_y = h as f64 / 2.0 - w as f64 * s * y / z;
        // Supersampling 4×4 places each edge within 1/8 pixel.
        assert!(
            (cx - want_x).abs() < 0.15,
            "fov {fov}: column {cx}, predicted {want_x}"
        );
        assert!(
            (cy - want_y).abs() < 0.15,
            "fov {fov}: row {cy}, predicted {want_y}"
        );
    }
}

#[test]
fn a_mirror_facing_a_uniformly_lit_wall_returns_the_spec_blend() {
    // Lit by ambient light only, so the wall's radiance is ka·ambient
    // everywhere and the mirror's local term is its own ka·ambient.
    let xml = r#"<scene version="1">
  <settings ambient="0.5 0.5 0.5" background="1 0 1"/>
  <plane id="mirror" point="0 0 -2" normal="0 0 1">
    <surface diffuse="0 0 0" ambient="0.2 0.4 0.6" reflectivity="0.7"/>
  </plane>
  <plane id="wall" point="0 0 5" normal="0 0 -1">
    <surface diffuse="0 0 0" ambient="0.9 0.5 0.1"/>
  </plane>
  <camera id="c" position="0 0 0" direction="0 0 -1" fov="70">
    <render width="32" height="24"/>
  </camera>
</scene>"#;
    let px = render(&scene(xml), 0);
    let r = 0.7;
    for (ch, (m, w)) in [(0.2, 0.9), (0.4, 0.5), (0.6, 0.1)].into_iter().enumerate() {
        let want = (1.0 - r) * m * 0.5 + r * w * 0.5;
        for p in &px {
            assert_close(p[ch], want, 1e-6, "mirror pixel");
        }
    }
}

#[test]
fn glass_with_ior_1_passes_what_is_behind_it_through_unchanged() {
    let slab = r#"
  <mesh id="cube">
    <vertices>-0.5 -0.5 -0.5  -0.5 -0.5 0.5  -0.5 0.5 -0.5  -0.5 0.5 0.5
              0.5 -0.5 -0.5  0.5 -0.5 0.5  0.5 0.5 -0.5  0.5 0.5 0.5</vertices>
    <triangles>1 3 2 1 2 0  4 6 7 4 7 5  0 4 5 0 5 1  3 7 6 3 6 2  2 6 4 2 4 0  1 5 7 1 7 3</triangles>
  </mesh>
  <model id="slab" mesh="cube">
    <transform><scale v="6 6 0.4"/><rotate axis="0 1 0" angle="35"/><rotate axis="1 0 0" angle="20"/><translate v="0 0 -2.5"/></transform>
    <surface opacity="0" ior="1" diffuse="1 1 1" specular="1 1 1"/>
  </model>"#;
    let camera = r#"<camera id="c" position="0 0.5 1" lookat="0 0 -6" fov="50"><render width="48" height="36"/></camera>"#;
    // Nothing behind the slab: every pixel is exactly the background.
    let empty = scene(&format!(
        "<scene version=\"1\"><settings background=\"0.2 0.4 0.6\"/>{slab}{camera}</scene>"
    ));
    for p in render(&empty, 0) {
        assert_eq!(p, [0.2, 0.4, 0.6]);
    }
    // A lit wall behind it looks as it does without the slab. (Each surface
    // crossing moves the ray sideways by the few-ULP origin offset, so the
    // comparison allows 1e-4 relative.)
    let wall = r#"
  <plane id="wall" point="0 0 -6" normal="0 0 1"><surface diffuse="0.9 0.3 0.2"/></plane>
  <light type="point" position="2 4 0"/>"#;
    let open = scene(&format!("<scene version=\"1\">{wall}{camera}</scene>"));
    let glazed = scene(&format!(
        "<scene version=\"1\">{wall}{slab}{camera}</scene>"
    ));
    let a = render(&open, 0);
    let b = render(&glazed, 0);
    for (i, (p, q)) in a.iter().zip(&b).enumerate() {
        for ch in 0..3 {
            assert_close(q[ch], p[ch] as f64, 1e-4, &format!("pixel {i}"));
        }
    }
}

#[test]
fn total_internal_reflection_starts_exactly_at_the_critical_angle() {
    // The camera sits inside glass (below the interface y = 0, whose normal
    // faces up, so rays meet its back: η = ior). Rays closer to the normal
    // than the critical angle leave into the sky (background); the others
    // reflect down onto a floor lit only by ambient light.
    let ior = 1.5f64;
    let xml = r#"<scene version="1">
  <settings background="0 0 1" ambient="1 1 1"/>
  <plane id="interface" point="0 0 0" normal="0 1 0">
    <surface opacity="0" ior="1.5" diffuse="0 0 0" ambient="0 0 0"/>
  </plane>
  <plane id="floor" point="0 -50 0" normal="0 1 0">
    <surface diffuse="0 0 0" ambient="1 0 0"/>
  </plane>
  <camera id="c" position="0 -1 0" direction="1 1 0" up="0 0 1" fov="100">
    <render width="200" height="8"/>
  </camera>
</scene>"#;
    let px = render(&scene(xml), 0);
    let cam = SpecCamera::new(
        [0.0, -1.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
        100.0,
        200,
        8,
    );
    let crit = (1.0 / ior).asin();
    let (mut tir, mut out) = (0, 0);
    for r in 0..8 {
        for i in 0..200 {
            let d = cam.dir(i, r);
            if d[1] <= 0.0 {
                continue;
            }
            let theta = d[1].acos(); // angle to the interface normal
            let p = px[(r * 200 + i) as usize];
            if theta < crit - 1e-4 {
                assert_eq!(
                    p,
                    [0.0, 0.0, 1.0],
                    "pixel {i},{r} at {theta} rad should leave the glass"
                );
                out += 1;
            } else if theta > crit + 1e-4 {
                assert_eq!(
                    p,
                    [1.0, 0.0, 0.0],
                    "pixel {i},{r} at {theta} rad should reflect"
                );
                tir += 1;
            }
        }
    }
    assert!(tir > 100 && out > 100, "tir {tir} out {out}");
}
