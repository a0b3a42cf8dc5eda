//! Closed-form checks of path mode: furnaces, the environment alone, the
//! irradiance of a rectangle light, and degenerate input that must not give
//! NaN.

use super::*;
use crate::integrator::RenderOptions;
use crate::Scene;

pub(crate) use crate::testing::scene;

/// Every pixel of camera 0, row by row.
pub(crate) fn pixels(s: &Scene) -> Vec<[f32; 3]> {
    let r = &s.desc.cameras[0].render;
    let it = Integrator::observed(s, 0, RenderOptions::default(), &());
    (0..r.height)
        .flat_map(|y| (0..r.width).map(move |x| (x, y)))
        .map(|(x, y)| it.pixel(x, y).unwrap().0)
        .collect()
}

/// Mean and standard error of the mean of one channel over pixels.
fn mean_and_error(v: &[f32]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().map(|&x| f64::from(x)).sum::<f64>() / n;
    let var = v.iter().map(|&x| (f64::from(x) - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, (var / n).sqrt())
}

/// Inside a closed diffuse sphere of albedo a that emits Le and nothing
/// else, the radiance everywhere is Le·(1 + a + a² + …) = Le/(1 − a).
#[test]
fn furnace_inside_a_glowing_diffuse_sphere_every_pixel_is_le_over_one_minus_albedo() {
    for (a, le) in [(0.5f32, 0.3f32), (0.8, 0.1)] {
        let s = scene(&format!(
            r#"<scene version="1">
  <sphere id="s" center="0 0 0" radius="5">
    <surface diffuse="{a} {a} {a}" emission="{le} {le} {le}"/></sphere>
  <camera id="c" position="0 1 0.5" direction="0.3 -0.2 -1" fov="90">
    <render width="12" height="12" supersample="8" jitter="true" integrator="path"
            max-bounces="10000"/></camera></scene>"#
        ));
        let px = pixels(&s);
        let expect = f64::from(le / (1.0 - a));
        let red: Vec<f32> = px.iter().map(|p| p[0]).collect();
        let (m, se) = mean_and_error(&red);
        // The image mean within 4 standard errors and 1 %.
        assert!(
            (m - expect).abs() <= 4.0 * se + 1e-4 && (m - expect).abs() <= 0.01 * expect,
            "a={a}: mean {m} ± {se}, expected {expect}"
        );
        // Every pixel within 6 standard deviations of a pixel.
        let sd = se * (red.len() as f64).sqrt();
        for (i, p) in px.iter().enumerate() {
            for c in p {
                assert!(
                    (f64::from(*c) - expect).abs() <= 6.0 * sd + 1e-4,
                    "pixel {i}: {c}"
                );
            }
        }
    }
}

/// Zero albedo: the wall's own emission and nothing else, exactly.
#[test]
fn a_black_glowing_sphere_shows_exactly_its_emission() {
    let s = scene(
        r#"<scene version="1">
  <sphere id="s" center="0 0 0" radius="5"><surface diffuse="0 0 0" emission="0.25 0.5 2"/></sphere>
  <camera id="c" position="0 0 0" direction="0 0 -1" fov="90">
    <render width="4" height="4" integrator="path"/></camera></scene>"#,
    );
    for p in pixels(&s) {
        assert_eq!(p, [0.25, 0.5, 2.0]);
    }
}

/// No geometry: every pixel is the background; a white Lambertian sphere
/// (albedo 1, convex) in a white environment is white (the white furnace).
#[test]
fn a_white_environment_is_seen_as_it_is_and_a_white_sphere_in_it_vanishes() {
    let empty = scene(
        r#"<scene version="1"><settings background="0.2 0.7 1.3"/>
  <camera id="c" position="0 0 0" direction="0 0 -1" fov="60">
    <render width="3" height="3" integrator="path"/></camera></scene>"#,
    );
    for p in pixels(&empty) {
        assert_eq!(p, [0.2, 0.7, 1.3]);
    }
    let sphere = scene(
        r#"<scene version="1"><settings background="1 1 1"/>
  <sphere id="s" center="0 0 -3" radius="1"><surface diffuse="1 1 1"/></sphere>
  <camera id="c" position="0 0 0" direction="0 0 -1" fov="60">
    <render width="8" height="8" supersample="2" integrator="path" max-bounces="3"/></camera></scene>"#,
    );
    for p in pixels(&sphere) {
        for c in p {
            assert!((c - 1.0).abs() < 1e-4, "{p:?}");
        }
    }
}

// An independent closed form: std is fine here (clippy.toml).
#[allow(clippy::disallowed_methods)]
/// The configuration factor from a differential area to a parallel
/// rectangle a × b at distance c, the element below one corner (Howell's
/// catalogue, C-11).
fn corner_form_factor(a: f64, b: f64, c: f64) -> f64 {
    let (x, y) = (a / c, b / c);
    let (sx, sy) = ((1.0 + x * x).sqrt(), (1.0 + y * y).sqrt());
    (x / sx * (y / sx).atan() + y / sy * (x / sy).atan()) / std::f64::consts::TAU
}

/// A rectangle light of radiance Le over a diffuse floor of albedo kd: the
/// floor's radiance below it is kd·Le·F, F the rectangle's form factor (the
/// closed form above, four corners' worth for the point below the centre
/// and one for the point below a corner).
#[test]
fn a_rectangle_light_gives_a_parallel_plane_the_closed_form_irradiance() {
    let (w, d, h, le, kd) = (1.0f64, 0.6f64, 0.5f64, 2.0f64, 0.7f64);
    let f_centre = 4.0 * corner_form_factor(w / 2.0, d / 2.0, h);
    let f_corner = corner_form_factor(w, d, h);
    for (x, z, f) in [(0.0, 0.0, f_centre), (w / 2.0, d / 2.0, f_corner)] {
        // The camera looks straight down through the light's back (a
        // front-only surface cannot be hit from behind) at (x, 0, z).
        let s = scene(&format!(
            r#"<scene version="1">
  <mesh id="rect"><vertices>{x0} {h} {z0}  {x1} {h} {z0}  {x1} {h} {z1}  {x0} {h} {z1}</vertices>
    <triangles>0 1 2  0 2 3</triangles></mesh>
  <model id="light" mesh="rect"><surface diffuse="0 0 0" emission="{le} {le} {le}" sided="front"/></model>
  <plane id="floor" point="0 0 0" normal="0 1 0"><surface diffuse="{kd} {kd} {kd}"/></plane>
  <camera id="c" position="{x} 2 {z}" direction="0 -1 0" up="0 0 -1" fov="0.001">
    <render width="1" height="1" supersample="64" integrator="path" max-bounces="1"/></camera></scene>"#,
            x0 = -w / 2.0,
            x1 = w / 2.0,
            z0 = -d / 2.0,
            z1 = d / 2.0,
        ));
        let v = f64::from(pixels(&s)[0][0]);
        let expect = kd * le * f;
        assert!(
            (v - expect).abs() <= 0.005 * expect,
            "at ({x}, {z}): {v} vs {expect} (F = {f})"
        );
    }
}

/// Grazing camera rays along a plane, zero albedo, a light far smaller than
/// a pixel, a point light on the surface, glass and mirrors facing each
/// other: every pixel finite and ≥ 0.
#[test]
fn degenerate_paths_never_give_nan_or_infinity() {
    let s = scene(
        r#"<scene version="1"><settings background="0.5 0.5 0.5"/>
  <mesh id="tiny"><vertices>0 1 0  1e-7 1 0  0 1 1e-7</vertices><triangles>0 1 2</triangles></mesh>
  <mesh id="flat"><vertices>0 0.5 0  1 0.5 0  2 0.5 0</vertices><triangles>0 1 2</triangles></mesh>
  <model id="t" mesh="tiny"><surface emission="1e30 1e30 1e30"/></model>
  <model id="f" mesh="flat"><surface emission="1 1 1"/></model>
  <plane id="floor" point="0 0 0" normal="0 1 0"><surface diffuse="0 0 0" specular="1 1 1" shininess="0"/></plane>
  <plane id="wall" point="0 0 -4" normal="0 0 1"><surface diffuse="1 1 1" specular="1 1 1" shininess="1e6"/></plane>
  <sphere id="g" center="0.5 0.3 -1" radius="0.3"><surface opacity="0" ior="1.5"/></sphere>
  <sphere id="m" center="-0.5 0.3 -1" radius="0.3"><surface reflectivity="1" emission="0 0 1e-30"/></sphere>
  <sphere id="z" center="0 2 -1" radius="0.2"><surface diffuse="0 0 0" emission="0 0 0"/></sphere>
  <light position="0 0 -2" attenuation="0 0 1"/>
  <light type="spot" position="0 0.000001 -3" direction="0 -1 0" radius="0.5"/>
  <camera id="c" position="0 0 2" direction="0 0 -1" fov="120">
    <render width="16" height="16" supersample="4" jitter="true" integrator="path"
            max-bounces="64"/></camera></scene>"#,
    );
    for p in pixels(&s) {
        assert!(p.iter().all(|c| c.is_finite() && *c >= 0.0), "{p:?}");
    }
}

/// A Lambertian surface's direct light from a point light is the Whitted
/// value kd·E·cos θ in both modes.
#[test]
fn a_point_light_gives_a_diffuse_surface_the_same_direct_light_in_both_modes() {
    let xml = |mode: &str| {
        format!(
            r#"<scene version="1">
  <plane id="floor" point="0 0 0" normal="0 1 0"><surface diffuse="0.6 0.5 0.4"/></plane>
  <light position="1 2 0" color="1 0.8 0.5" intensity="3" attenuation="0 0 1"/>
  <camera id="c" position="0 3 0" direction="0 -1 0" up="0 0 -1" fov="0.01">
    <render width="1" height="1" integrator="{mode}" max-bounces="1"/></camera></scene>"#
        )
    };
    let whitted = pixels(&scene(&xml("whitted")))[0];
    let path = pixels(&scene(&xml("path")))[0];
    // E = 3/5 (d² = 5), cos θ = 2/√5.
    let e = 3.0f32 / 5.0 * 2.0 / 5f32.sqrt();
    let expect = [0.6 * e, 0.5 * 0.8 * e, 0.4 * 0.5 * e];
    for c in 0..3 {
        assert!((whitted[c] - expect[c]).abs() < 1e-4, "{whitted:?}");
        assert!((path[c] - expect[c]).abs() < 1e-4, "{path:?}");
    }
}

#[test]
fn fresnel_is_the_dielectric_formula_with_total_internal_reflection() {
    // Normal incidence: ((1 − 1.5)/(1 + 1.5))² = 0.04.
    assert!((fresnel(1.0, 1.0 / 1.5) - 0.04).abs() < 1e-6);
    // Past the critical angle inside glass: everything reflects.
    assert_eq!(fresnel(0.5, 1.5), 1.0);
    // Grazing: everything reflects.
    assert!((fresnel(0.0, 1.0 / 1.5) - 1.0).abs() < 1e-6);
}
