//! Numerical stability at the extremes: self-intersection at every
//! scene scale, scenes far from the origin, degenerate geometry, extreme
//! parameters, and the parsers fed mutated inputs. Every rendered sample is
//! checked to be finite. See docs/numerics.md for the measurements.

// Independent closed forms and test geometry, computed with std on purpose (clippy.toml).
#![allow(clippy::disallowed_methods)]

mod common;
use common::*;
use trevi_core::alloc_meter::{thread_cost, AllocMeter};
use trevi_core::output::linear_to_srgb8;
use trevi_core::{render_tile, Rect, Scene};

/// Renders the whole frame of camera 0 and asserts every value is finite.
fn render_finite(scene: &Scene, what: &str) -> Vec<[f32; 3]> {
    let px = render(scene, 0);
    if let Some((i, p)) = px
        .iter()
        .enumerate()
        .find(|(_, p)| !p.iter().all(|c| c.is_finite()))
    {
        panic!("{what}: pixel {i} is {p:?}");
    }
    px
}

fn srgb8(px: &[[f32; 3]]) -> Vec<u8> {
    px.iter()
        .flat_map(|p| p.map(linear_to_srgb8))
        .collect::<Vec<u8>>()
}

/// PSNR in dB of two images as 8-bit sRGB (what a PNG holds).
fn psnr(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let (a, b) = (srgb8(a), srgb8(b));
    assert_eq!(a.len(), b.len());
    let mse = a
        .iter()
        .zip(&b)
        .map(|(&x, &y)| (x as f64 - y as f64).powi(2))
        .sum::<f64>()
        / a.len() as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }
}

/// "x y z" of point `p` scaled by `k` and moved by `off`, printed so that
/// parsing gives back exactly the f64 it was computed as.
fn pt(p: [f64; 3], k: f64, off: [f64; 3]) -> String {
    format!(
        "{:?} {:?} {:?}",
        p[0] * k + off[0],
        p[1] * k + off[1],
        p[2] * k + off[2]
    )
}

// ------------------------------------------------------------ self-intersection

/// A plane z = 0 facing a camera 3k above it, lit by a soft light 1000k away
/// on the axis (so N·L and E are uniform to 10⁻⁶ over the view), with
/// specular (shininess 0: a constant term), reflection, refraction (the plane
/// is translucent: shadow rays gather through it), AO and diffuse
/// interreflection. Nothing else is in the scene, so every secondary ray
/// must escape: a ray that hits the surface it starts on darkens (shadow, AO)
/// or brightens (gather) its pixel. `mesh` uses two big triangles instead of
/// the analytic plane (their shared diagonal crosses the view).
fn plane_scene(k: f64, mesh: bool) -> String {
    let o = [0.0; 3];
    let surf = r#"<surface diffuse="0.6 0.5 0.4" specular="0.2 0.2 0.2" shininess="0" reflectivity="0.3" opacity="0.7" ior="1.3"/>"#;
    let geometry = if mesh {
        format!(
            r#"<mesh id="q"><vertices>{} {} {} {}</vertices><triangles>0 1 2 0 2 3</triangles></mesh>
  <model id="m" mesh="q">{surf}</model>"#,
            pt([-100.0, -100.0, 0.0], k, o),
            pt([100.0, -90.0, 0.0], k, o),
            pt([90.0, 100.0, 0.0], k, o),
            pt([-100.0, 100.0, 0.0], k, o),
        )
    } else {
        format!(r#"<plane id="p" point="0 0 0" normal="0 0 1">{surf}</plane>"#)
    };
    format!(
        r#"<scene version="1">
  <settings background="0.2 0.3 0.4" ambient="0.3 0.3 0.3"/>
  {geometry}
  <light position="{}" radius="{:?}" intensity="0.9"/>
  <camera id="c" position="{}" direction="0 0 -1" up="0 1 0" fov="40">
    <render width="24" height="16" supersample="2" jitter="true" max-depth="4"
            shadow-samples="2" ao-samples="3" diffuse-samples="2" diffuse-depth="2"/>
  </camera>
</scene>"#,
        pt([0.0, 0.0, 1000.0], k, o),
        10.0 * k,
        pt([0.1, 0.2, 3.0], k, o),
    )
}

#[test]
fn a_lit_plane_renders_uniformly_at_every_scale() {
    for mesh in [false, true] {
        for k in [1e-4, 1.0, 1e4, 1e6] {
            let what = format!("{} at scale {k}", if mesh { "mesh quad" } else { "plane" });
            let scene = scene(&plane_scene(k, mesh));
            let px = render_finite(&scene, &what);
            let b = srgb8(&px);
            for ch in 0..3 {
                let vals = b.iter().skip(ch).step_by(3);
                let (lo, hi) = vals.fold((255u8, 0u8), |(l, h), &v| (l.min(v), h.max(v)));
                assert!(hi - lo <= 1, "{what}: channel {ch} spans {lo}..={hi}");
            }
        }
    }
}

/// Two unit cubes touching face to face (x = 1k), a plane coincident with
/// their floors, the camera inside cube A looking at the shared wall, the
/// light inside cube B. Smooth normals (so shading normals tilt at the
/// edges), a reflective wall, AO and diffuse interreflection: the render
/// must be exactly the render with the light switched off.
fn boxes_scene(k: f64, intensity: f64) -> String {
    let o = [0.0; 3];
    let verts: Vec<String> = (0..8)
        .map(|i| {
            pt(
                [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64],
                k,
                o,
            )
        })
        .collect();
    format!(
        r#"<scene version="1">
  <settings background="1 1 1" ambient="0.2 0.2 0.2"/>
  <mesh id="cube"><vertices>{}</vertices>
    <triangles>0 2 3 0 3 1  4 5 7 4 7 6  0 1 5 0 5 4  2 6 7 2 7 3  0 4 6 0 6 2  1 3 7 1 7 5</triangles>
  </mesh>
  <model id="a" mesh="cube"><surface diffuse="0.7 0.7 0.7" specular="0.5 0.5 0.5"/>
    <surface triangles="2 3" reflectivity="0.5"/></model>
  <model id="b" mesh="cube"><transform><translate v="{:?} 0 0"/></transform></model>
  <plane id="floor" point="0 0 0" normal="0 1 0"/>
  <light position="{}" radius="{:?}" intensity="{intensity}"/>
  <camera id="c" position="{}" lookat="{}" fov="100">
    <render width="24" height="16" max-depth="3" shadow-samples="2"
            ao-samples="2" diffuse-samples="2"/>
  </camera>
</scene>"#,
        verts.join("  "),
        k,
        pt([1.5, 0.5, 0.5], k, o),
        0.2 * k,
        pt([0.2, 0.45, 0.55], k, o),
        pt([1.0, 0.5, 0.5], k, o),
    )
}

#[test]
fn no_light_leaks_through_touching_geometry_at_any_scale() {
    for k in [1e-4, 1.0, 1e4, 1e6] {
        let lit = render_finite(&scene(&boxes_scene(k, 1.0)), "lit boxes");
        let dark = render_finite(&scene(&boxes_scene(k, 0.0)), "zero-intensity light");
        // Something is visible (ambient), and none of it is the light's.
        assert!(dark.iter().any(|p| p[0] > 0.01), "scale {k}: black image");
        for (i, (a, b)) in lit.iter().zip(&dark).enumerate() {
            assert_eq!(a, b, "scale {k}: light leaks into pixel {i}");
        }
    }
}

// ---------------------------------------------------------- far from the origin

/// A small scene with every kind of primitive and effect, all of it scaled
/// by `k` and moved by `off`: inline mesh vertices written at their
/// far-away coordinates, a model placed by `<translate>`, spheres, plane,
/// soft and spot lights, camera. Attenuation `1 0 0` and every length
/// scaled (radii, light size, AO distance `auto`) make the image independent
/// of `k` and `off` in exact arithmetic.
pub fn far_scene(off: [f64; 3], k: f64) -> String {
    let cube: Vec<String> = (0..8)
        .map(|i| {
            pt(
                [
                    (i & 1) as f64 - 1.5,
                    ((i >> 1) & 1) as f64,
                    ((i >> 2) & 1) as f64 - 0.5,
                ],
                k,
                off,
            )
        })
        .collect();
    format!(
        r#"<scene version="1">
  <settings background="0.05 0.05 0.1" ambient="0.2 0.2 0.2"/>
  <mesh id="cube"><vertices>{}</vertices>
    <triangles>0 2 3 0 3 1  4 5 7 4 7 6  0 1 5 0 5 4  2 6 7 2 7 3  0 4 6 0 6 2  1 3 7 1 7 5</triangles>
  </mesh>
  <mesh id="tri"><vertices>-0.5 0 0  0.5 0 0  0 1 0</vertices><triangles>0 1 2</triangles></mesh>
  <model id="box" mesh="cube"><surface diffuse="0.7 0.3 0.2" smooth="false" specular="0.4 0.4 0.4" shininess="40"/></model>
  <model id="sail" mesh="tri">
    <transform><scale v="{:?}"/><rotate axis="0 1 0" angle="25"/><translate v="{}"/></transform>
    <surface diffuse="0.2 0.6 0.3" reflectivity="0.3"/>
  </model>
  <sphere id="ball" center="{}" radius="{:?}">
    <surface diffuse="0.1 0.1 0.1" opacity="0.2" ior="1.5" reflectivity="0.2"/>
  </sphere>
  <sphere id="dot" center="{}" radius="{:?}"><surface diffuse="0.3 0.3 0.9"/></sphere>
  <plane id="floor" point="{}" normal="0 1 0"><surface diffuse="0.6 0.6 0.6" reflectivity="0.1"/></plane>
  <light position="{}" radius="{:?}" intensity="1.2"/>
  <light type="spot" position="{}" direction="1 -2 -1" inner="15" outer="30" color="1 0.8 0.6"/>
  <camera id="c" position="{}" lookat="{}" fov="55">
    <render width="64" height="48" supersample="2" jitter="true" shadow-samples="2"
            ao-samples="2" diffuse-samples="1"/>
  </camera>
</scene>"#,
        cube.join("  "),
        1.5 * k,
        pt([1.2, 0.0, -1.0], k, off),
        pt([0.6, 0.6, 0.5], k, off),
        0.6 * k,
        pt([-0.2, 0.25, 1.0], k, off),
        0.25 * k,
        pt([0.0, 0.0, 0.0], k, off),
        pt([1.0, 4.0, 3.0], k, off),
        0.3 * k,
        pt([-3.0, 4.0, 2.0], k, off),
        pt([0.5, 1.6, 4.5], k, off),
        pt([0.0, 0.4, 0.0], k, off),
    )
}

#[test]
fn a_scene_far_from_the_origin_renders_like_the_scene_at_the_origin() {
    let reference = render_finite(&scene(&far_scene([0.0; 3], 1.0)), "scene at the origin");
    for d in [1e5, 1e6] {
        let off = [d, 0.5 * d, -0.8 * d];
        let px = render_finite(&scene(&far_scene(off, 1.0)), "far scene");
        let db = psnr(&reference, &px);
        assert!(db >= 40.0, "translated by {d}: PSNR {db:.1} dB");
    }
    // And scaled: the same image from 10⁻⁴ to 10⁶ (normals, sphere roots and
    // offsets must not overflow, underflow or stop scaling).
    for k in [1e-4, 1e4, 1e6] {
        let px = render_finite(&scene(&far_scene([0.0; 3], k)), "scaled scene");
        let db = psnr(&reference, &px);
        assert!(db >= 40.0, "scaled by {k}: PSNR {db:.1} dB");
    }
}

// ------------------------------------------------------------ degenerate input

/// Zero-area, needle and coincident-vertex triangles, a triangle seen exactly
/// edge-on (rays in its plane), a closed mesh with the camera inside, a light
/// inside a sphere, and lights sitting exactly on a plane and on a vertex.
fn degenerate_scene(camera: &str) -> String {
    format!(
        r#"<scene version="1">
  <settings background="0.1 0.1 0.1" ambient="0.2 0.2 0.2"/>
  <mesh id="junk">
    <vertices>0 0 0  1 0 0  2 0 0  0 1 0  0 1 0  0 1 1e-7  3 1 0  0 0 1e-30  1e-30 0 0  3 1 1e-6</vertices>
    <triangles>0 1 2  3 4 4  3 4 5  0 6 5  1 1 1  0 7 8  0 3 6  0 6 9</triangles>
  </mesh>
  <mesh id="cube"><vertices>-1 -1 -1  1 -1 -1  -1 1 -1  1 1 -1  -1 -1 1  1 -1 1  -1 1 1  1 1 1</vertices>
    <normals>0 0 0  0 0 0  0 0 0  0 0 0  1 0 0  1 0 0  1 0 0  1 0 0</normals>
    <triangles>0 2 3 0 3 1  4 5 7 4 7 6  0 1 5 0 5 4  2 6 7 2 7 3  0 4 6 0 6 2  1 3 7 1 7 5</triangles>
  </mesh>
  <model id="j" mesh="junk"><surface reflectivity="0.5" opacity="0.5" specular="1 1 1"/></model>
  <model id="edge-on" mesh="junk"><transform><translate v="0 0.5 -3"/></transform></model>
  <model id="room" mesh="cube"><transform><scale v="6"/></transform>
    <surface diffuse="0.5 0.5 0.5" reflectivity="0.2"/></model>
  <sphere id="lamp" center="2 2 -2" radius="0.5"><surface opacity="0.5" ior="1.4"/></sphere>
  <plane id="floor" point="0 -2 0" normal="0 1 0"><surface specular="1 1 1" shininess="0"/></plane>
  <light position="2 2 -2" radius="0.1"/>
  <light position="0 -2 -1"/>
  <light position="1 0 0" radius="0.2" attenuation="0 0 1"/>
  <light type="spot" position="0 1 0" direction="0 -1 0" inner="0" outer="0"/>
  {camera}
</scene>"#
    )
}

#[test]
fn degenerate_geometry_grazing_rays_and_lights_on_surfaces_give_finite_samples() {
    let render = r#"<render width="20" height="14" supersample="2" jitter="true" max-depth="6"
        shadow-samples="2" ao-samples="2" diffuse-samples="2" diffuse-depth="2"/>"#;
    let cameras = [
        // Inside the room, looking at everything.
        format!(r#"<camera id="c" position="0.3 0.2 3" lookat="0 0 0" fov="90">{render}</camera>"#),
        // In the plane of the edge-on triangles (y = 0.5 plane holds z = -3 copy).
        format!(
            r#"<camera id="c" position="-4 0.5 -3" direction="1 0 0" fov="60">{render}</camera>"#
        ),
        // Exactly on a light, and on the floor plane.
        format!(
            r#"<camera id="c" position="0 -2 -1" direction="0 0.2 -1" fov="120">{render}</camera>"#
        ),
        // Inside the lamp sphere, with a lens.
        format!(
            r#"<camera id="c" position="2 2 -2" direction="-1 -0.3 0.1" fov="170" aperture="0.3" focus="2">{render}</camera>"#
        ),
    ];
    for cam in &cameras {
        let s = scene(&degenerate_scene(cam));
        render_finite(&s, cam);
    }
    // The world-space queries themselves: zero, parallel and denormal rays.
    let s = scene(&degenerate_scene(&cameras[0]));
    use glam::Vec3;
    for (o, d) in [
        (Vec3::ZERO, Vec3::ZERO),
        (Vec3::new(-5.0, 0.0, 0.5), Vec3::X),
        (Vec3::new(0.0, 0.5, -3.0), Vec3::new(1.0, 0.0, 1e-30)),
        (Vec3::new(0.5, 0.5, 0.5), Vec3::new(1e-38, -1e-38, 1e-39)),
        (Vec3::splat(1e30), Vec3::NEG_ONE),
    ] {
        if let Some(h) = s.intersect(o, d, f32::INFINITY) {
            assert!(h.t.is_finite() && h.t > 0.0, "ray {o} {d}: t {}", h.t);
            let sp = s.surface_point(o, d, &h);
            assert!(sp.p.is_finite() && sp.ng.is_finite() && sp.ns.is_finite());
        }
        let v = s.transmittance(o, d, 1.0);
        assert!((0.0..=1.0).contains(&v), "transmittance {v}");
    }
}

// ----------------------------------------------------------- extreme parameters

fn param_scene(camera_attrs: &str, render_attrs: &str, surface: &str, light: &str) -> String {
    format!(
        r#"<scene version="1">
  <settings background="0.3 0.4 0.5" ambient="0.1 0.1 0.1"/>
  <plane id="floor" point="0 0 0" normal="0 1 0"><surface reflectivity="0.5"/></plane>
  <plane id="mirror" point="0 0 -4" normal="0 0 1"><surface reflectivity="0.95" diffuse="0.1 0.1 0.1"/></plane>
  <plane id="mirror2" point="0 0 6" normal="0 0 -1"><surface reflectivity="0.95" diffuse="0.1 0.1 0.1"/></plane>
  <sphere id="s" center="0 1 0" radius="1"><surface {surface}/></sphere>
  <light position="2 5 3" {light}/>
  <camera id="c" position="0 1.5 4" lookat="0 1 0" {camera_attrs}>
    <render {render_attrs}/>
  </camera>
</scene>"#
    )
}

#[test]
fn extreme_parameters_render_finite_values() {
    let glass = r#"opacity="0.1" ior="1.5" reflectivity="0.1""#;
    let cases: &[(&str, &str, &str, &str)] = &[
        (r#"fov="0.01""#, r#"width="8" height="6""#, glass, ""),
        (r#"fov="179.9""#, r#"width="8" height="6""#, glass, ""),
        (r#"fov="50""#, r#"width="1" height="1""#, glass, ""),
        (r#"fov="50""#, r#"width="1" height="10000""#, "", ""),
        (r#"fov="50""#, r#"width="10000" height="1""#, "", ""),
        (
            r#"fov="50""#,
            r#"width="2" height="2" supersample="16" jitter="true""#,
            glass,
            "",
        ),
        (
            r#"fov="50""#,
            r#"width="8" height="6" max-depth="0""#,
            glass,
            "",
        ),
        (
            r#"fov="50""#,
            r#"width="8" height="6" max-depth="64""#,
            glass,
            "",
        ),
        (
            r#"fov="50""#,
            r#"width="8" height="6" max-depth="64""#,
            r#"opacity="0.5" ior="1e-3""#,
            "",
        ),
        (
            r#"fov="50""#,
            r#"width="8" height="6" max-depth="64""#,
            r#"opacity="0.5" ior="1e3""#,
            "",
        ),
        (
            r#"fov="50""#,
            r#"width="8" height="6""#,
            glass,
            r#"intensity="0""#,
        ),
        (
            r#"fov="50""#,
            r#"width="8" height="6""#,
            glass,
            r#"intensity="0" radius="1""#,
        ),
        (
            r#"fov="50""#,
            r#"width="8" height="6" ao-samples="4" ao-distance="1e-30" diffuse-samples="2""#,
            "",
            "",
        ),
        (
            r#"fov="50""#,
            r#"width="8" height="6" ao-samples="4" ao-distance="1e-45" diffuse-samples="2""#,
            "",
            "",
        ),
        (
            r#"fov="50""#,
            r#"width="8" height="6" ao-samples="4" ao-distance="3e38" diffuse-samples="2""#,
            "",
            "",
        ),
        (
            r#"fov="50" aperture="1e-30" focus="1e30""#,
            r#"width="8" height="6""#,
            glass,
            r#"attenuation="0 0 1e-30""#,
        ),
        (
            r#"fov="50""#,
            r#"width="8" height="6""#,
            "",
            r#"intensity="3e38" attenuation="1e-30 0 0""#,
        ),
    ];
    for (cam, render, surf, light) in cases {
        let xml = param_scene(cam, render, surf, light);
        let s = scene(&xml);
        render_finite(
            &s,
            &format!("camera {cam}, render {render}, surface {surf}, light {light}"),
        );
    }
}

/// Two facing panes that both reflect and refract double the rays at every
/// level: at max-depth 64 that is 2⁶⁴ rays per sample unless branches too
/// faint to see are pruned. It must finish, quickly, with finite values.
#[test]
fn max_depth_64_between_glass_panes_finishes() {
    let xml = r#"<scene version="1">
  <settings background="0.5 0.6 0.7" ambient="0.1 0.1 0.1"/>
  <plane id="a" point="0 0 -1" normal="0 0 1"><surface opacity="0.5" reflectivity="0.5" ior="1.2"/></plane>
  <plane id="b" point="0 0 -2" normal="0 0 1"><surface opacity="0.5" reflectivity="0.5" ior="1.2"/></plane>
  <plane id="c" point="0 0 1" normal="0 0 1"><surface opacity="0.5" reflectivity="0.5" ior="1.2"/></plane>
  <light position="0 3 0"/>
  <camera id="c" position="0 0 0" direction="0.1 0.1 -1" fov="40"><render width="4" height="3" max-depth="64"/></camera>
</scene>"#;
    let t0 = std::time::Instant::now();
    let s = scene(xml);
    let r = render_tile(&s, 0, Rect::new(0, 0, 4, 3));
    assert!(r.pixels.iter().flatten().all(|c| c.is_finite()));
    // The bound on rays below is the check; this one only catches a hang,
    // generous for a busy machine.
    assert!(t0.elapsed().as_secs() < 120, "took {:?}", t0.elapsed());
    assert!(r.rays < 12 * 20_000, "{} rays for 12 samples", r.rays);
}

#[test]
fn out_of_range_parameters_fail_with_a_clear_error() {
    for (cam, render, what) in [
        (r#"fov="0""#, r#"width="8" height="6""#, "(0, 180)"),
        (r#"fov="180""#, r#"width="8" height="6""#, "(0, 180)"),
        (r#"fov="50""#, r#"width="0" height="6""#, "width"),
        (
            r#"fov="50""#,
            r#"width="8" height="6" supersample="0""#,
            "supersample",
        ),
        (
            r#"fov="50""#,
            r#"width="8" height="6" ao-distance="0""#,
            "ao-distance",
        ),
        (
            r#"fov="50""#,
            r#"width="8" height="6" ao-distance="1e39""#,
            "ao-distance",
        ),
    ] {
        let xml = param_scene(cam, render, "", "");
        let err = match Scene::from_bundle(&bundle(&xml)) {
            Ok(_) => panic!("{cam} {render} was accepted"),
            Err(e) => e.to_string(),
        };
        // Located (file:line:column) and naming what was expected.
        assert!(
            err.contains(what) && err.contains("scene.xml:"),
            "{cam} {render}: {err}"
        );
    }
    let xml = param_scene(r#"fov="50""#, r#"width="8" height="6""#, r#"ior="0""#, "");
    let err = Scene::from_bundle(&bundle(&xml))
        .err()
        .expect("ior 0 accepted");
    assert!(err.to_string().contains("ior"), "{err}");
}

/// ior 1 bends nothing: a fully transparent sphere with ior 1 in front of a
/// lit box and floor renders as if it were not there.
#[test]
fn ior_one_passes_rays_straight_through() {
    let with = |sphere: &str| {
        format!(
            r#"<scene version="1">
  <settings background="0.3 0.4 0.5" ambient="0.1 0.1 0.1"/>
  <mesh id="cube"><vertices>-1 0 -1  1 0 -1  -1 2 -1  1 2 -1  -1 0 1  1 0 1  -1 2 1  1 2 1</vertices>
    <triangles>0 2 3 0 3 1  4 5 7 4 7 6  0 1 5 0 5 4  2 6 7 2 7 3  0 4 6 0 6 2  1 3 7 1 7 5</triangles>
  </mesh>
  <model id="box" mesh="cube"><transform><rotate axis="0 1 0" angle="30"/><translate v="0.5 0 -3"/></transform>
    <surface diffuse="0.8 0.3 0.2" smooth="false"/></model>
  <plane id="floor" point="0 0 0" normal="0 1 0"><surface diffuse="0.4 0.6 0.4"/></plane>
  {sphere}
  <light position="2 5 3"/>
  <camera id="c" position="0 1.5 4" lookat="0 1 -1" fov="50"><render width="32" height="24"/></camera>
</scene>"#
        )
    };
    let a = render_finite(
        &scene(&with(
            r#"<sphere id="s" center="0 1 0" radius="1"><surface opacity="0" ior="1"/></sphere>"#,
        )),
        "ior 1",
    );
    let b = render_finite(&scene(&with("")), "no sphere");
    let (a8, b8) = (srgb8(&a), srgb8(&b));
    let worst = a8
        .iter()
        .zip(&b8)
        .map(|(&x, &y)| (x as i32 - y as i32).abs())
        .max()
        .unwrap();
    assert!(worst <= 1, "ior 1 sphere changes a pixel by {worst} levels");
}

#[test]
fn tiles_of_a_far_scene_agree_with_the_whole_frame() {
    // Camera-relative coordinates must not depend on the tile.
    let s = scene(&far_scene([1e6, 0.0, 1e6], 1.0));
    let whole = render(&s, 0);
    let t = render_tile(&s, 0, Rect::new(10, 7, 13, 9));
    for r in 0..9 {
        for c in 0..13 {
            assert_eq!(t.pixels[r * 13 + c], whole[(7 + r) * 64 + 10 + c]);
        }
    }
}

// ------------------------------------------------------- parsers under mutation

/// Counts the bytes each thread holds, and the peak, so a parse can be
/// checked not to allocate beyond a bound (a header's claims must not turn
/// into allocations).
#[global_allocator]
static METER: AllocMeter = AllocMeter;

/// Runs `f` and returns the most bytes this thread held during it above
/// what it held before.
fn peak_during<T>(f: impl FnOnce() -> T) -> (T, usize) {
    let (out, _, peak) = thread_cost(f);
    (out, peak)
}

struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        self.0 >> 33
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// Tokens a mutation may splice in: numbers at and past every limit,
/// markup, headers that claim too much.
const INTERESTING: &[&str] = &[
    "1e39",
    "-1e39",
    "3.4028235e38",
    "1e-45",
    "-0",
    "0",
    "-1",
    "nan",
    "inf",
    "NaN",
    "4294967295",
    "4294967296",
    "1000000000000",
    "18446744073709551616",
    "-2147483648",
    "0x10",
    "1e",
    ".",
    "-",
    "\0",
    "\u{fffd}",
    "é",
    "\r\n",
    " ",
    "\t",
    "<",
    ">",
    "\"",
    "'",
    "&amp;",
    "&#0;",
    "&#x110000;",
    "&lt;",
    "<!DOCTYPE x>",
    "<![CDATA[",
    "]]>",
    "<!--",
    "-->",
    "<?xml version=\"1.0\"?>",
    "</scene>",
    "<scene version=\"1\">",
    "<model id=\"x\" mesh=\"q\"/>",
    "<sphere id=\"y\" center=\"0 0 0\" radius=\"1e-45\"/>",
    "<transform><scale v=\"0\"/></transform>",
    "<matrix m=\"1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 0\"/>",
    "triangles=\"0-4294967295\"",
    "file=\"m.obj\"",
    "file=\"m.ply\"",
    "file=\"../x.obj\"",
    "element vertex 1000000000000\n",
    "element face 1000000000000\n",
    "element vertex 4294967295\n",
    "property list uint int vertex_indices\n",
    "property list uchar float x\n",
    "property double x\n",
    "format binary_little_endian 1.0\n",
    "format binary_big_endian 1.0\n",
    "format ascii 1.0\n",
    "end_header\n",
    "comment x\n",
    "obj_info y\n",
    "v 1e38 1e38 1e38\n",
    "v 0 0 0\n",
    "vn 0 0 0\n",
    "vt 0 0\n",
    "f 1 2 3 4 5 6 7\n",
    "f -1 -2 -3\n",
    "f 0 0 0\n",
    "f 1/1/1 2//2 3/3\n",
    "f 1000000000000 1 2\n",
    "\\\n",
    "o g\n",
    "usemtl m\n",
    "s off\n",
];

fn mutate(rng: &mut Lcg, input: &[u8]) -> Vec<u8> {
    let mut v = input.to_vec();
    for _ in 0..1 + rng.below(4) {
        let at = rng.below(v.len() + 1);
        match rng.below(7) {
            0 if !v.is_empty() => {
                let i = rng.below(v.len());
                v[i] = rng.next() as u8;
            }
            1 | 2 => {
                let t = INTERESTING[rng.below(INTERESTING.len())].as_bytes();
                v.splice(at..at, t.iter().copied());
            }
            3 => {
                let end = (at + rng.below(64)).min(v.len());
                v.drain(at..end);
            }
            4 => {
                let end = (at + rng.below(256)).min(v.len());
                let chunk = v[at..end].to_vec();
                for _ in 0..1 + rng.below(8) {
                    v.splice(at..at, chunk.iter().copied());
                }
            }
            5 => v.truncate(at),
            _ => {
                // Replace the number nearest `at` with an interesting one.
                let start = (at..v.len()).find(|&i| v[i].is_ascii_digit());
                if let Some(s) = start {
                    let e = (s..v.len())
                        .find(|&i| !(v[i].is_ascii_digit() || v[i] == b'.' || v[i] == b'e'))
                        .unwrap_or(v.len());
                    let t = INTERESTING[rng.below(12)].as_bytes();
                    v.splice(s..e, t.iter().copied());
                }
            }
        }
    }
    v
}

const SEED_OBJ: &str = "# a quad and a triangle\no thing\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0.5 0.5 1\nvt 0 0\nvt 1 0\nvt 1 1\nvn 0 0 1\nvn 0 1 0\ng top\nusemtl red\nf 1/1/1 2/2/1 3/3/1 4/1/1\ns 1\nf -1//2 -2//2 -3//2\nf 1 2 5\n";

fn seed_ply_ascii() -> Vec<u8> {
    b"ply\nformat ascii 1.0\ncomment tetrahedron\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nelement face 4\nproperty list uchar int vertex_indices\nelement junk 1\nproperty list uchar uchar stuff\nend_header\n0 0 0 0 0 -1\n1 0 0 1 0 0\n0 1 0 0 1 0\n0 0 1 0 0 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n4 1 2 3 0\n2 7 8\n".to_vec()
}

fn seed_ply_binary(big: bool) -> Vec<u8> {
    let fmt = if big {
        "binary_big_endian"
    } else {
        "binary_little_endian"
    };
    let mut b = format!("ply\nformat {fmt} 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty double z\nelement face 2\nproperty list uchar uint vertex_indices\nproperty short flags\nend_header\n").into_bytes();
    let f32b = |x: f32| {
        if big {
            x.to_be_bytes()
        } else {
            x.to_le_bytes()
        }
    };
    let f64b = |x: f64| {
        if big {
            x.to_be_bytes()
        } else {
            x.to_le_bytes()
        }
    };
    let u32b = |x: u32| {
        if big {
            x.to_be_bytes()
        } else {
            x.to_le_bytes()
        }
    };
    for p in [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.5]] {
        b.extend(f32b(p[0] as f32));
        b.extend(f32b(p[1] as f32));
        b.extend(f64b(p[2]));
    }
    for f in [[0u32, 1, 2], [2, 1, 0]] {
        b.push(3);
        for i in f {
            b.extend(u32b(i));
        }
        b.extend([0u8, 7]);
    }
    b
}

fn seed_scenes() -> Vec<String> {
    let spec_like = r#"<?xml version="1.0" encoding="UTF-8"?>
<scene version="1">
  <!-- every element -->
  <settings background="0 0 0" ambient="0.1 0.1 0.1"/>
  <mesh id="q"><vertices>0 0 0  1 0 0  1 0 1  0 0 1</vertices>
    <normals>0 1 0  0 1 0  0 1 0  0 1 0</normals><triangles>0 2 1  0 3 2</triangles></mesh>
  <mesh id="o" file="m.obj"/>
  <mesh id="p" file="m.ply" invert="true"/>
  <model id="floor" mesh="q">
    <transform><scale v="10 1 10"/><rotate axis="0 1 0" angle="30"/><translate v="-5 0 -5"/>
      <matrix m="1 0 0 0  0 1 0 0  0 0 1 0  0 0 0 1"/></transform>
    <surface diffuse="0.8 0.8 0.8"/>
    <surface triangles="0-1" diffuse="0.7 0.1 0.1" specular="0.5 0.5 0.5" shininess="64" reflectivity="0.2" smooth="false"/>
  </model>
  <model id="o1" mesh="o"><surface opacity="0.5" ior="1.3" sided="front"/></model>
  <model id="p1" mesh="p"/>
  <sphere id="ball" center="0 1 0" radius="1"> <surface reflectivity="0.9"/> </sphere>
  <plane id="ground" point="0 0 0" normal="0 1 0"> <surface diffuse="0.5 0.5 0.5"/> </plane>
  <light type="point" position="0 5 0" color="1 1 1" intensity="1" radius="0" attenuation="1 0 0"/>
  <light id="s" type="spot" position="3 5 3" direction="-1 -1 -1" inner="15" outer="25" color="1 0.9 0.8"/>
  <camera id="c" position="0 2 8" lookat="0 1 0" up="0 1 0" fov="50" aperture="0.1" lens="disk">
    <render width="30" height="20" supersample="2" jitter="true" max-depth="3" shadow-samples="2"
      ao-samples="1" ao-distance="auto" diffuse-samples="1" diffuse-depth="1" seed="7" output="c.exr"/>
  </camera>
  <camera id="d" position="0 0 0" direction="0 0 -1" fov="20">
    <render width="4" height="4" noise-threshold="0.01" min-samples="2" max-samples="8"/>
  </camera>
</scene>"#;
    vec![
        spec_like.to_string(),
        include_str!("../../examples/cornell.xml").to_string(),
    ]
}

/// Every input ends in a value or an error: no panic, no hang (each batch
/// runs on a watchdog), and no allocation beyond a bound proportional to the
/// input (so a header claiming 10¹² vertices cannot reserve them).
fn survive(name: &str, seeds: Vec<Vec<u8>>, count: usize, parse: fn(&[u8]) -> bool) {
    let name = name.to_string();
    let (tx, rx) = std::sync::mpsc::channel();
    let worker_name = name.clone();
    std::thread::spawn(move || {
        let mut rng = Lcg(0x7265_7669 ^ worker_name.len() as u64);
        let (mut ok, mut err) = (0usize, 0usize);
        let mut pool: Vec<Vec<u8>> = seeds.clone();
        for i in 0..count {
            let base = &pool[rng.below(pool.len())];
            let input = mutate(&mut rng, base);
            // CPU time of this thread: a busy machine stretches wall-clock
            // time, not the work a parse does.
            let t0 = thread_cpu();
            let (r, peak) = peak_during(|| {
                std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| parse(&input)))
            });
            let took = thread_cpu().saturating_sub(t0);
            let shown = String::from_utf8_lossy(&input[..input.len().min(300)]).to_string();
            let outcome = match r {
                Err(_) => Err(format!("{worker_name} input {i} panicked: {shown:?}")),
                Ok(_) if took.as_secs_f64() > 2.0 => {
                    Err(format!("{worker_name} input {i} took {took:?}: {shown:?}"))
                }
                Ok(_) if peak > (32 << 20) + 256 * input.len() => Err(format!(
                    "{worker_name} input {i} ({} bytes) allocated {peak} bytes: {shown:?}",
                    input.len()
                )),
                Ok(true) => {
                    ok += 1;
                    Ok(())
                }
                Ok(false) => {
                    err += 1;
                    Ok(())
                }
            };
            if let Err(e) = outcome {
                let _ = tx.send(Err(e));
                return;
            }
            // Grow the pool with mutants (bounded), so mutations stack.
            if pool.len() < 64 && input.len() < 1 << 16 {
                pool.push(input);
            } else if input.len() < 1 << 16 {
                let k = rng.below(pool.len());
                if k >= seeds.len() {
                    pool[k] = input;
                }
            }
        }
        let _ = tx.send(Ok((ok, err)));
    });
    match rx.recv_timeout(std::time::Duration::from_secs(600)) {
        Ok(Ok((ok, err))) => {
            assert!(ok > 0 && err > 0, "{name}: {ok} parsed, {err} errors");
        }
        Ok(Err(e)) => panic!("{e}"),
        Err(_) => panic!("{name}: a parse hangs (no answer within 600 s)"),
    }
}

fn parse_scene_bytes(data: &[u8]) -> bool {
    let mut b = bundle("");
    b.files.insert("scene.xml".into(), data.to_vec());
    b.files.insert("m.obj".into(), SEED_OBJ.as_bytes().to_vec());
    b.files.insert("m.ply".into(), seed_ply_ascii());
    match Scene::from_bundle(&b) {
        Ok(s) => {
            // Built scenes answer queries without panicking.
            let _ = s.intersect(glam::Vec3::ZERO, glam::Vec3::NEG_Z, f32::INFINITY);
            let _ = s.ao_distance(0);
            true
        }
        Err(e) => {
            assert!(!e.to_string().is_empty());
            false
        }
    }
}

#[test]
fn the_aisxml_parser_survives_mutated_scenes() {
    let seeds = seed_scenes().into_iter().map(String::into_bytes).collect();
    survive("aisxml", seeds, 6000, parse_scene_bytes);
}

#[test]
fn the_obj_loader_survives_mutated_files() {
    survive("obj", vec![SEED_OBJ.as_bytes().to_vec()], 10000, |d| {
        trevi_core::mesh::obj::parse("m.obj", d).is_ok()
    });
}

#[test]
fn the_ply_loader_survives_mutated_files() {
    let seeds = vec![
        seed_ply_ascii(),
        seed_ply_binary(false),
        seed_ply_binary(true),
    ];
    survive("ply", seeds, 10000, |d| {
        trevi_core::mesh::ply::parse("m.ply", d).is_ok()
    });
}

#[test]
fn headers_and_indices_that_claim_too_much_are_errors_not_allocations() {
    let huge_vertices = b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\0\0\0\0".to_vec();
    let huge_faces = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1000000000000\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n".to_vec();
    let huge_list = b"ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uint int vertex_indices\nend_header\n\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\xff\xff\xff\xff".to_vec();
    for (what, data) in [
        ("10^12 vertices", huge_vertices),
        ("10^12 faces", huge_faces),
        ("a 4-billion-entry face", huge_list),
    ] {
        let (r, peak) = peak_during(|| trevi_core::mesh::ply::parse("m.ply", &data));
        assert!(r.is_err(), "{what}: accepted");
        assert!(peak < 1 << 20, "{what}: allocated {peak} bytes");
    }
    let (r, peak) = peak_during(|| {
        trevi_core::mesh::obj::parse("m.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 1000000000000\n")
    });
    assert!(
        r.is_err() && peak < 1 << 20,
        "OBJ index 10^12: {peak} bytes"
    );
    let xml = r#"<scene version="1"><mesh id="q"><vertices>0 0 0 1 0 0 0 1 0</vertices><triangles>0 1 1000000000000</triangles></mesh>
      <camera id="c" position="0 0 5" lookat="0 0 0" fov="50"><render width="1000000" height="1000000"/></camera></scene>"#;
    let (r, peak) = peak_during(|| Scene::from_bundle(&bundle(xml)).is_ok());
    assert!(!r && peak < 1 << 20, "inline index 10^12: {peak} bytes");
    // Deep nesting: an error, not a stack overflow.
    let deep = format!(
        r#"<scene version="1">{}{}</scene>"#,
        "<model>".repeat(100_000),
        "</model>".repeat(100_000)
    );
    assert!(Scene::from_bundle(&bundle(&deep)).is_err());
}

// ------------------------------------------------------------- measurements
// Not run by default: `cargo test --release -p trevi-core --test numerics --
// --ignored --nocapture --test-threads 1 measure` prints the tables of
// docs/numerics.md.

#[test]
#[ignore = "a measurement that prints docs/numerics.md's tables, asserts nothing: \
            cargo test --release -p trevi-core --test numerics -- --ignored \
            --nocapture --test-threads 1 measure"]
fn measure_image_psnr_against_distance_and_scale() {
    let reference = render(&scene(&far_scene([0.0; 3], 1.0)), 0);
    println!("| distance from the origin | PSNR (dB) vs the scene at the origin |");
    println!("|---|---|");
    for d in [
        1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e12, 1e14, 1e16,
    ] {
        let off = [d, 0.5 * d, -0.8 * d];
        let px = render(&scene(&far_scene(off, 1.0)), 0);
        println!("| {d:e} | {:.1} |", psnr(&reference, &px));
    }
    println!();
    println!("| scene scale | PSNR (dB) vs scale 1 | lit plane: 8-bit spread (analytic / mesh) |");
    println!("|---|---|---|");
    for k in [
        1e-16, 1e-14, 1e-12, 1e-8, 1e-6, 1e-4, 1e-2, 1e2, 1e4, 1e6, 1e8, 1e10, 1e11, 1e12, 1e14,
    ] {
        let px = render(&scene(&far_scene([0.0; 3], k)), 0);
        let spread = |mesh: bool| {
            let b = srgb8(&render(&scene(&plane_scene(k, mesh)), 0));
            (0..3)
                .map(|ch| {
                    let v: Vec<u8> = b.iter().skip(ch).step_by(3).copied().collect();
                    v.iter().max().unwrap() - v.iter().min().unwrap()
                })
                .max()
                .unwrap()
        };
        println!(
            "| {k:e} | {:.1} | {} / {} |",
            psnr(&reference, &px),
            spread(false),
            spread(true)
        );
    }
}

/// Exact (f64) hit of the ray `o + t·d` with the plane `n·(x − p) = 0`.
fn exact_plane(o: [f64; 3], d: [f64; 3], p: [f64; 3], n: [f64; 3]) -> [f64; 3] {
    let t = dot(sub(p, o), n) / dot(d, n);
    add(o, scale(d, t))
}

/// Hit-point error of the world-space (f32) queries and of the camera's
/// view, against an f64 reference: rays from a camera 5 units from a plane,
/// a sphere and a triangle, all moved `d` from the origin.
#[test]
#[ignore = "a measurement that prints docs/numerics.md's tables, asserts nothing: \
            cargo test --release -p trevi-core --test numerics -- --ignored --nocapture \
            --test-threads 1 measure"]
fn measure_hit_point_error_against_distance() {
    println!("| distance | world f32: max error | camera-relative: max error |");
    println!("|---|---|---|");
    for d in [1.0, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e10, 1e12] {
        let off = [d, 0.5 * d, -0.8 * d];
        let cam = [off[0] + 0.3, off[1] + 2.0, off[2] + 5.0];
        let tri = [[-2.0, 0.0, -2.0], [3.0, 0.5, -1.0], [0.0, 0.2, 3.0]].map(|v| add(v, off));
        let xml = format!(
            r#"<scene version="1">
  <mesh id="t"><vertices>{} {} {}</vertices><triangles>0 1 2</triangles></mesh>
  <model id="m" mesh="t"/>
  <plane id="p" point="{}" normal="0 1 0"/>
  <sphere id="s" center="{}" radius="0.7"/>
  <camera id="c" position="{}" lookat="{}" fov="50"><render width="1" height="1"/></camera>
</scene>"#,
            pt(tri[0], 1.0, [0.0; 3]),
            pt(tri[1], 1.0, [0.0; 3]),
            pt(tri[2], 1.0, [0.0; 3]),
            pt([0.0, -1.0, 0.0], 1.0, off),
            pt([1.5, 0.3, 0.5], 1.0, off),
            pt([0.0; 3], 1.0, [cam[0], cam[1], cam[2]]),
            pt([0.0; 3], 1.0, off),
        );
        let s = scene(&xml);
        let view = s.view(0);
        let (mut world_err, mut view_err) = (0.0f64, 0.0f64);
        let (mut world_n, mut world_lost) = (0usize, 0usize);
        let mut rng = Lcg(5);
        for _ in 0..20000 {
            // A direction towards a random point of the scene's region.
            let target = [
                off[0] + rng.below(10_000) as f64 / 1000.0 - 4.0,
                off[1] + rng.below(10_000) as f64 / 5000.0 - 1.0,
                off[2] + rng.below(10_000) as f64 / 1000.0 - 4.0,
            ];
            let dir = norm(sub(target, cam));
            let dir32 = glam::Vec3::new(dir[0] as f32, dir[1] as f32, dir[2] as f32);
            let dir = [dir32.x as f64, dir32.y as f64, dir32.z as f64];
            let Some(hv) = view.intersect(glam::Vec3::ZERO, dir32, f32::INFINITY) else {
                continue;
            };
            let sp = view.surface_point(glam::Vec3::ZERO, dir32, &hv);
            let eye = view.eye();
            let p_view = [
                eye.x + sp.p.x as f64,
                eye.y + sp.p.y as f64,
                eye.z + sp.p.z as f64,
            ];
            // The exact hit on whichever primitive the view hit.
            let exact = match hv.kind {
                trevi_core::world::HitKind::Plane(_) => {
                    exact_plane(cam, dir, add(off, [0.0, -1.0, 0.0]), [0.0, 1.0, 0.0])
                }
                trevi_core::world::HitKind::Triangle { .. } => {
                    let n = cross(sub(tri[1], tri[0]), sub(tri[2], tri[0]));
                    exact_plane(cam, dir, tri[0], n)
                }
                trevi_core::world::HitKind::Sphere(_) => {
                    let c = add(off, [1.5, 0.3, 0.5]);
                    let f = sub(cam, c);
                    let b = dot(f, dir);
                    let disc = b * b - (dot(f, f) - 0.49);
                    if disc < 0.0 {
                        continue;
                    }
                    add(cam, scale(dir, -b - disc.sqrt()))
                }
            };
            let e = |p: [f64; 3]| dot(sub(p, exact), sub(p, exact)).sqrt();
            view_err = view_err.max(e(p_view));
            let o32 = glam::Vec3::new(cam[0] as f32, cam[1] as f32, cam[2] as f32);
            match s.intersect(o32, dir32, f32::INFINITY) {
                Some(hw)
                    if std::mem::discriminant(&hw.kind) == std::mem::discriminant(&hv.kind) =>
                {
                    let p = s.surface_point(o32, dir32, &hw).p;
                    world_err = world_err.max(e([p.x as f64, p.y as f64, p.z as f64]));
                    world_n += 1;
                }
                _ => world_lost += 1,
            }
        }
        let lost = if world_lost > 0 {
            format!(
                " ({:.0}% of rays hit nothing or the wrong primitive)",
                100.0 * world_lost as f64 / (world_n + world_lost) as f64
            )
        } else {
            String::new()
        };
        println!("| {d:e} | {world_err:.3e}{lost} | {view_err:.3e} |");
    }
}

/// The CPU time the calling thread has used (`/proc/thread-self/stat`, in
/// clock ticks of 10 ms); where there is no /proc, the wall-clock time since
/// the first call.
fn thread_cpu() -> std::time::Duration {
    let from_proc = std::fs::read_to_string("/proc/thread-self/stat")
        .ok()
        .and_then(|stat| {
            let rest = &stat[stat.rfind(')')? + 1..];
            let f: Vec<&str> = rest.split_whitespace().collect();
            Some(f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?)
        });
    match from_proc {
        // Linux's USER_HZ is 100.
        Some(ticks) => std::time::Duration::from_millis(ticks * 10),
        None => {
            static START: std::sync::OnceLock<std::time::Instant> = std::sync::OnceLock::new();
            START.get_or_init(std::time::Instant::now).elapsed()
        }
    }
}
