//! The render passes against closed forms computed here, independently of
//! the camera and the integrators: a plane seen head-on, a textured quad,
//! a mirror and a pane of glass in front of a diffuse wall; the beauty's
//! bytes with and without passes; the passes' bytes whatever the tiling
//! and threads.

use crate::aov::{Aov, AovTile, Aovs};
use crate::tile::{render_tile, render_tile_aovs, Rect, TileResult};
use crate::world::Scene;
use std::sync::atomic::AtomicBool;

fn aovs_of(scene: &Scene, rect: Rect, aovs: Aovs) -> (TileResult, AovTile) {
    render_tile_aovs(scene, 0, rect, aovs, &AtomicBool::new(false)).unwrap()
}

/// The direction through the centre of pixel (`i`, `r`) of a `w`×`h`
/// camera at the origin looking down −z with up +y, by the spec's camera
/// (s = ½/tan(fov/2), a pixel 1/w wide on the view plane), in f64.
// An independent closed form: std is fine here (clippy.toml).
#[allow(clippy::disallowed_methods)]
fn pixel_ray(fov_deg: f64, w: u32, h: u32, i: u32, r: u32) -> [f64; 3] {
    let s = 0.5 / (fov_deg.to_radians() / 2.0).tan();
    let x = (f64::from(i) + 0.5) / f64::from(w) - 0.5;
    let y = (f64::from(h) / 2.0 - f64::from(r) - 0.5) / f64::from(w);
    let n = (x * x + y * y + s * s).sqrt();
    [x / n, y / n, -s / n]
}

fn camera(fov: f64, w: u32, h: u32, render: &str) -> String {
    format!(
        r#"<camera id="c" position="0 0 0" direction="0 0 -1" up="0 1 0" fov="{fov}">
    <render width="{w}" height="{h}" {render} output="o.exr"/></camera>"#
    )
}

/// A wall at z = −3 facing the camera, for both integrators: every pixel's
/// normal is the wall's, its depth the length of its ray to the wall
/// (3 / cos of its angle with the axis), its albedo the wall's colour.
#[test]
fn a_plane_seen_head_on_has_its_normal_its_colour_and_each_ray_s_length() {
    let (fov, w, h) = (70.0, 9, 7);
    for integrator in ["whitted", "path"] {
        let s = crate::testing::scene(&format!(
            r#"<scene version="1">
  <plane id="p" point="0 0 -3" normal="0 0 1"><surface diffuse="0.25 0.5 0.75"/></plane>
  <light position="0 0 0"/>
  {}</scene>"#,
            camera(fov, w, h, &format!(r#"integrator="{integrator}""#))
        ));
        let (_, t) = aovs_of(&s, Rect::new(0, 0, w, h), Aovs::ALL);
        for r in 0..h {
            for i in 0..w {
                let px = (r * w + i) as usize;
                assert_eq!(t.get(px, Aov::Albedo), [0.25, 0.5, 0.75]);
                assert_eq!(t.get(px, Aov::Normal), [0.0, 0.0, 1.0]);
                let d = pixel_ray(fov, w, h, i, r);
                let expected = 3.0 / -d[2];
                let got = f64::from(t.get(px, Aov::Depth)[0]);
                assert!(
                    (got - expected).abs() < 1e-5 * expected,
                    "{integrator} ({i},{r}): {got} vs {expected}"
                );
            }
        }
    }
}

/// A sphere in the middle of the frame: the corners miss it and take the
/// background, a zero normal and an infinite depth; the centre sees the
/// sphere's front at distance 4 with normal +z.
#[test]
fn a_miss_has_the_background_no_normal_and_infinite_depth() {
    let s = crate::testing::scene(&format!(
        r#"<scene version="1"><settings background="0.1 0.2 0.3"/>
  <sphere id="s" center="0 0 -5" radius="1"><surface diffuse="1 0 0"/></sphere>
  {}</scene>"#,
        camera(40.0, 5, 5, "")
    ));
    let (_, t) = aovs_of(&s, Rect::new(0, 0, 5, 5), Aovs::ALL);
    assert_eq!(t.get(0, Aov::Albedo), [0.1, 0.2, 0.3]);
    assert_eq!(t.get(0, Aov::Normal), [0.0; 3]);
    assert_eq!(t.get(0, Aov::Depth), [f32::INFINITY]);
    assert_eq!(t.get(12, Aov::Albedo), [1.0, 0.0, 0.0]);
    assert_eq!(t.get(12, Aov::Normal), [0.0, 0.0, 1.0]);
    assert!((t.get(12, Aov::Depth)[0] - 4.0).abs() < 1e-5);
}

/// A perfect mirror, then a clear pane of glass, in front of the camera:
/// the albedo and normal are those of the diffuse wall the specular path
/// reaches (behind the camera for the mirror, behind the pane for the
/// glass), the depth stays the distance to the specular surface.
#[test]
fn albedo_and_normal_follow_mirrors_and_glass_and_depth_does_not() {
    let wall_behind =
        r#"<plane id="b" point="0 0 4" normal="0 0 -1"><surface diffuse="0 0.5 1"/></plane>"#;
    let wall_beyond =
        r#"<plane id="b" point="0 0 -6" normal="0 0 1"><surface diffuse="0 0.5 1"/></plane>"#;
    let cases = [
        (
            wall_behind,
            r#"reflectivity="1" diffuse="1 1 1""#,
            [0.0, 0.0, -1.0],
        ),
        (wall_beyond, r#"opacity="0" ior="1.5""#, [0.0, 0.0, 1.0]),
    ];
    for (wall, specular, normal) in cases {
        for integrator in ["whitted", "path"] {
            let s = crate::testing::scene(&format!(
                r#"<scene version="1">
  <plane id="m" point="0 0 -2" normal="0 0 1"><surface {specular}/></plane>
  {wall}
  {}</scene>"#,
                camera(30.0, 3, 3, &format!(r#"integrator="{integrator}""#))
            ));
            let (_, t) = aovs_of(&s, Rect::new(0, 0, 3, 3), Aovs::ALL);
            // The centre pixel looks straight down the axis.
            assert_eq!(
                t.get(4, Aov::Albedo),
                [0.0, 0.5, 1.0],
                "{integrator} {specular}"
            );
            assert_eq!(t.get(4, Aov::Normal), normal, "{integrator} {specular}");
            assert!((t.get(4, Aov::Depth)[0] - 2.0).abs() < 1e-5);
            // With the depth to reach the wall cut to 0, the specular
            // surface itself is reported.
            let s0 = crate::testing::scene(&format!(
                r#"<scene version="1">
  <plane id="m" point="0 0 -2" normal="0 0 1"><surface {specular}/></plane>
  {wall}
  {}</scene>"#,
                camera(
                    30.0,
                    3,
                    3,
                    &format!(r#"integrator="{integrator}" max-depth="0" max-bounces="0""#)
                )
            ));
            let (_, t0) = aovs_of(&s0, Rect::new(0, 0, 3, 3), Aovs::ALL);
            assert_ne!(t0.get(4, Aov::Albedo), [0.0, 0.5, 1.0]);
            assert_eq!(t0.get(4, Aov::Normal), [0.0, 0.0, 1.0]);
        }
    }
}

/// A quad textured with a 4×4 image fills the frame; one sample at each
/// pixel's centre (path mode reads the finest level): the albedo is the
/// texture's bilinear value at the uv where that pixel's centre ray meets
/// the quad, computed here from the ray.
#[test]
fn a_textured_quad_s_albedo_is_the_texture_at_each_pixel_s_centre() {
    let texels: Vec<u8> = (0..48u32).map(|i| (i * 37 % 251) as u8).collect();
    let (fov, w, h) = (40.0, 8, 6);
    let xml = format!(
        r#"<scene version="1">
  <mesh id="q"><vertices>-1 -1 -2  1 -1 -2  1 1 -2  -1 1 -2</vertices>
    <uvs>0 0 1 0 1 1 0 1</uvs><triangles>0 1 2 0 2 3</triangles></mesh>
  <model id="m" mesh="q"><surface diffuse="1 1 1" diffuse-texture="t.png"/></model>
  {}</scene>"#,
        camera(fov, w, h, r#"integrator="path""#)
    );
    let bundle = crate::Bundle {
        scene: "s.xml".into(),
        files: [
            ("s.xml".to_string(), xml.into_bytes()),
            (
                "t.png".to_string(),
                crate::texture::tests::png_rgb8(4, 4, &texels),
            ),
        ]
        .into(),
    };
    let s = Scene::from_bundle(&bundle).unwrap();
    let tex = &s.desc.textures[0];
    let (_, t) = aovs_of(&s, Rect::new(0, 0, w, h), Aovs::parse("albedo").unwrap());
    assert_eq!(t.values.len(), (w * h * 3) as usize);
    let mut distinct = std::collections::BTreeSet::new();
    for r in 0..h {
        for i in 0..w {
            let d = pixel_ray(fov, w, h, i, r);
            let k = -2.0 / d[2];
            let (x, y) = (d[0] * k, d[1] * k);
            let uv = glam::Vec2::new(((x + 1.0) / 2.0) as f32, ((y + 1.0) / 2.0) as f32);
            let expected = tex.sample(uv, 0.0, crate::texture::Wrap::Repeat);
            let got = t.get((r * w + i) as usize, Aov::Albedo);
            for c in 0..3 {
                assert!(
                    (got[c] - expected[c]).abs() < 1e-4,
                    "({i},{r}) {got:?} vs {expected}"
                );
            }
            distinct.insert(got[0].to_bits());
        }
    }
    // The texture shows: not one colour everywhere.
    assert!(distinct.len() > 10, "{}", distinct.len());
}

/// A scene with every effect (AO, soft shadows, the diffuse gather, depth
/// of field, reflection and refraction, jittered supersampling), in both
/// integrators and with adaptive sampling.
fn busy_scene(render: &str) -> Scene {
    crate::testing::scene(&format!(
        r#"<scene version="1"><settings ambient="0.2 0.2 0.2" background="0.05 0.1 0.2"/>
  <sphere id="a" center="-0.6 0 -4" radius="0.7"><surface diffuse="0.8 0.3 0.2" reflectivity="0.4"/></sphere>
  <sphere id="b" center="0.7 0.1 -3.5" radius="0.5"><surface opacity="0.3" ior="1.4"/></sphere>
  <plane id="f" point="0 -0.7 0" normal="0 1 0"><surface diffuse="0.6 0.6 0.6"/></plane>
  <light position="2 4 1" radius="0.5"/>
  <camera id="c" position="0 0 0" direction="0 0 -1" up="0 1 0" fov="50" aperture="0.05" focus="4">
    <render width="13" height="11" {render} output="o.exr"/></camera></scene>"#
    ))
}

const RENDERS: [&str; 3] = [
    r#"supersample="2" jitter="true" ao-samples="2" shadow-samples="2" diffuse-samples="2""#,
    r#"integrator="path" supersample="2" jitter="true""#,
    r#"noise-threshold="0.05" min-samples="2" max-samples="6" ao-samples="1""#,
];

/// The beauty is the same bytes with or without passes.
#[test]
fn the_beauty_is_byte_identical_with_and_without_passes() {
    for render in RENDERS {
        let s = busy_scene(render);
        let rect = Rect::new(0, 0, 13, 11);
        let plain = render_tile(&s, 0, rect);
        for aovs in [Aovs::ALL, Aovs::parse("depth").unwrap()] {
            let (beauty, t) = aovs_of(&s, rect, aovs);
            let bits = |p: &[[f32; 3]]| p.iter().flatten().map(|c| c.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&beauty.pixels), bits(&plain.pixels), "{render}");
            assert_eq!(t.values.len(), 13 * 11 * aovs.channels());
            // The passes trace rays of their own.
            assert!(beauty.rays > plain.rays);
        }
        // No passes: nothing more traced.
        let (none, t) = aovs_of(&s, rect, Aovs::NONE);
        assert_eq!((none, t.values.len()), (plain, 0));
    }
}

/// The passes are the same bytes whatever the tile size and the number of
/// threads.
#[test]
fn passes_are_byte_identical_whatever_the_tiles_and_threads() {
    for render in RENDERS {
        let s = busy_scene(render);
        let (w, h) = (13u32, 11u32);
        let (_, whole) = aovs_of(&s, Rect::new(0, 0, w, h), Aovs::ALL);
        let bits = |v: &[f32]| v.iter().map(|c| c.to_bits()).collect::<Vec<_>>();
        // The frame is not one value everywhere.
        assert!(whole.values.iter().any(|v| *v != whole.values[0]));
        for (tile, threads) in [(3, 1), (5, 3), (16, 2)] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut frame = vec![0.0f32; whole.values.len()];
            for rect in crate::tile::band_order_tiles(w, h, tile) {
                let (_, t) = pool.install(|| aovs_of(&s, rect, Aovs::ALL));
                for y in 0..rect.h {
                    for x in 0..rect.w {
                        let src = t.pixel((y * rect.w + x) as usize);
                        let at = ((rect.y + y) * w + rect.x + x) as usize * 7;
                        frame[at..at + 7].copy_from_slice(src);
                    }
                }
            }
            assert_eq!(
                bits(&frame),
                bits(&whole.values),
                "{render} tile {tile} threads {threads}"
            );
        }
    }
}
