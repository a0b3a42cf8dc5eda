// The closed forms are an independent computation: std's maths (clippy.toml).
#![allow(clippy::disallowed_methods)]

// The same scene and pixel helpers as path mode's closed-form tests.
pub(super) use crate::integrator::path::tests::{pixels, scene};

/// Mean and standard error of the mean.
fn mean_and_error(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|&x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, (var / n).sqrt())
}

/// The configuration factor from a differential area to a parallel
/// rectangle a × b at distance c, the element below one corner (Howell's
/// catalogue, C-11).
fn corner_form_factor(a: f64, b: f64, c: f64) -> f64 {
    let (x, y) = (a / c, b / c);
    let (sx, sy) = ((1.0 + x * x).sqrt(), (1.0 + y * y).sqrt());
    (x / sx * (y / sx).atan() + y / sy * (x / sy).atan()) / std::f64::consts::TAU
}

/// A 1 × 0.6 `<light type="rect">` facing down at height h over a diffuse
/// floor, seen by a one-pixel camera looking straight down at (x, 0, z)
/// through the light's back (a front-only light cannot be hit from behind).
fn rect_over_floor(mode: &str, x: f64, z: f64, extra: &str) -> String {
    format!(
        r#"<scene version="1">
  <light type="rect" position="0 0.5 0" edge-u="1 0 0" edge-v="0 0 0.6" emission="2 2 2" sided="front"/>
  <plane id="floor" point="0 0 0" normal="0 1 0"><surface diffuse="0.7 0.7 0.7"/></plane>
  <camera id="c" position="{x} 2 {z}" direction="0 -1 0" up="0 0 -1" fov="0.001">
    <render width="1" height="1" integrator="{mode}" max-bounces="1" {extra}/></camera></scene>"#
    )
}

/// The floor below a rectangle light of radiance Le reflects kd·Le·F (F the
/// rectangle's form factor, in closed form) in Whitted mode as in path mode:
/// both within 0.5 % of the closed form, below the centre (four corners'
/// worth) and below a corner.
#[test]
fn a_rect_light_gives_a_parallel_plane_the_closed_form_irradiance_in_both_modes() {
    let (w, d, h, le, kd) = (1.0f64, 0.6f64, 0.5f64, 2.0f64, 0.7f64);
    let f_centre = 4.0 * corner_form_factor(w / 2.0, d / 2.0, h);
    let f_corner = corner_form_factor(w, d, h);
    for (x, z, f) in [(0.0, 0.0, f_centre), (w / 2.0, d / 2.0, f_corner)] {
        let expect = kd * le * f;
        // Whitted: 16 camera samples × 64 shadow samples; path: 1024 paths.
        let whitted = f64::from(
            pixels(&scene(&rect_over_floor(
                "whitted",
                x,
                z,
                r#"supersample="4" shadow-samples="64""#,
            )))[0][0],
        );
        let path = f64::from(
            pixels(&scene(&rect_over_floor(
                "path",
                x,
                z,
                r#"supersample="32""#,
            )))[0][0],
        );
        for (mode, v) in [("whitted", whitted), ("path", path)] {
            assert!(
                (v - expect).abs() <= 0.005 * expect,
                "{mode} at ({x}, {z}): {v} vs {expect} (F = {f})"
            );
        }
    }
}

/// Whitted's estimate is unbiased, not merely close: over many pixels with
/// one shadow sample each (jittered camera samples, so each pixel draws
/// its own points), the mean is within 4 standard errors of kd·Le·F.
#[test]
fn whitted_area_light_sampling_is_unbiased_at_one_shadow_sample() {
    let xml = rect_over_floor("whitted", 0.0, 0.0, "").replace(
        r#"width="1" height="1""#,
        r#"width="32" height="32" jitter="true""#,
    );
    let px: Vec<f64> = pixels(&scene(&xml))
        .iter()
        .map(|p| f64::from(p[0]))
        .collect();
    let expect = 0.7 * 2.0 * 4.0 * corner_form_factor(0.5, 0.3, 0.5);
    let (m, se) = mean_and_error(&px);
    assert!(se > 0.0, "one sample per pixel should be noisy");
    assert!((m - expect).abs() <= 4.0 * se, "{m} ± {se} vs {expect}");
}

/// A camera ray that hits a rect light sees its Le exactly, in both modes,
/// from the front; a front-only light is not hit from behind (the
/// background shows), a two-sided one is.
#[test]
fn a_rect_light_is_seen_by_camera_rays_on_the_sides_it_emits() {
    let xml = |mode: &str, sided: &str, cam_y: f32| {
        format!(
            r#"<scene version="1"><settings background="0.1 0.2 0.3"/>
  <light type="rect" position="0 1 0" edge-u="1 0 0" edge-v="0 0 1" emission="3 2 1" sided="{sided}"/>
  <camera id="c" position="0 {cam_y} 0" lookat="0 1 0" up="0 0 -1" fov="10">
    <render width="2" height="2" integrator="{mode}"/></camera></scene>"#
        )
    };
    for mode in ["whitted", "path"] {
        // The front faces −y (edge-u × edge-v): seen from below.
        for p in pixels(&scene(&xml(mode, "front", 0.0))) {
            assert_eq!(p, [3.0, 2.0, 1.0], "{mode}");
        }
        for p in pixels(&scene(&xml(mode, "front", 2.0))) {
            assert_eq!(p, [0.1, 0.2, 0.3], "{mode}");
        }
        for p in pixels(&scene(&xml(mode, "two", 2.0))) {
            assert_eq!(p, [3.0, 2.0, 1.0], "{mode}");
        }
    }
}

/// `sided="front"`: a surface lit by a light that faces away gets nothing
/// in either mode; turned round (or two-sided) it is lit. The same for
/// `emission` on a `<surface>` of a mesh.
#[test]
fn a_front_only_emitter_lights_only_the_side_it_faces_in_both_modes() {
    let floor = |mode: &str, light: &str| {
        format!(
            r#"<scene version="1">
  <mesh id="q"><vertices>-0.5 1 -0.5  0.5 1 -0.5  0.5 1 0.5  -0.5 1 0.5</vertices><triangles>0 1 2  0 2 3</triangles></mesh>
  {light}
  <plane id="floor" point="0 0 0" normal="0 1 0"><surface diffuse="0.5 0.5 0.5"/></plane>
  <camera id="c" position="0.9 0.5 0.9" lookat="0 0 0" fov="1">
    <render width="1" height="1" integrator="{mode}" max-bounces="1" shadow-samples="4"/></camera></scene>"#
        )
    };
    let rect = |sided: &str, v: &str| {
        format!(
            r#"<light type="rect" position="0 1 0" edge-u="1 0 0" edge-v="{v}" emission="1 1 1" sided="{sided}"/>"#
        )
    };
    // Mesh q's winding faces −y ((1,0,0) × (1,0,1) = (0,−1,0)), towards
    // the floor; q reversed faces up.
    let mesh = |sided: &str, reversed: bool| {
        let m = if reversed { "r" } else { "q" };
        format!(
            r#"<mesh id="r"><vertices>-0.5 1 -0.5  0.5 1 -0.5  0.5 1 0.5  -0.5 1 0.5</vertices><triangles>0 2 1  0 3 2</triangles></mesh>
  <model id="m" mesh="{m}"><surface diffuse="0 0 0" emission="1 1 1" sided="{sided}"/></model>"#
        )
    };
    for mode in ["whitted", "path"] {
        let lit = |light: &str| pixels(&scene(&floor(mode, light)))[0][0];
        // edge-v = +z: front faces −y, towards the floor.
        assert!(lit(&rect("front", "0 0 1")) > 0.01, "{mode}");
        assert_eq!(lit(&rect("front", "0 0 -1")), 0.0, "{mode}");
        assert!(lit(&rect("two", "0 0 -1")) > 0.01, "{mode}");
        assert!(lit(&mesh("front", false)) > 0.01, "{mode}");
        assert_eq!(lit(&mesh("front", true)), 0.0, "{mode}");
        assert!(lit(&mesh("two", true)) > 0.01, "{mode}");
    }
}

/// A zero-area rect, a rect seen and lit edge-on (grazing: lying in the
/// floor's plane and in the camera's line of sight), a tiny very bright one,
/// a mirror and glass: every pixel finite and ≥ 0 in both modes.
#[test]
fn degenerate_rect_lights_never_give_nan_or_infinity() {
    for mode in ["whitted", "path"] {
        let s = scene(&format!(
            r#"<scene version="1"><settings background="0.2 0.2 0.2" ambient="0.1 0.1 0.1"/>
  <light type="rect" position="0 1 -1" edge-u="0 0 0" edge-v="0 0 1" emission="5 5 5"/>
  <light type="rect" position="1 1 -1" edge-u="1 0 0" edge-v="2 0 0" emission="5 5 5"/>
  <light type="rect" position="0 0 -2" edge-u="1 0 0" edge-v="0 0 1" emission="1 1 1"/>
  <light type="rect" position="0 0.5 0" edge-u="1e-6 0 0" edge-v="0 0 1e-6" emission="1e30 1e30 1e30"/>
  <light type="rect" position="0 2 -1" edge-u="1e-20 0 0" edge-v="0 0 1e-20" power="1e-30"/>
  <light type="rect" position="0 0.7 -1" edge-u="1e9 0 0" edge-v="0 0 1e9" emission="1 1 1"/>
  <plane id="floor" point="0 0 0" normal="0 1 0"><surface diffuse="0.8 0.8 0.8" specular="1 1 1" shininess="0"/></plane>
  <sphere id="m" center="-0.5 0.3 -1" radius="0.3"><surface reflectivity="1"/></sphere>
  <sphere id="g" center="0.5 0.3 -1" radius="0.3"><surface opacity="0" ior="1.5"/></sphere>
  <camera id="c" position="0 0 1" direction="0 0 -1" fov="120">
    <render width="12" height="12" supersample="2" jitter="true" shadow-samples="3"
            ao-samples="2" diffuse-samples="2" integrator="{mode}" max-bounces="8"/></camera></scene>"#
        ));
        for p in pixels(&s) {
            assert!(
                p.iter().all(|c| c.is_finite() && *c >= 0.0),
                "{mode}: {p:?}"
            );
        }
    }
}
