//! Tests of `<animate>` and of `frames=`/`fps=`/output patterns on
//! `<render>`: what they resolve to, and one located error per kind of bad
//! key.

use super::*;
use crate::scene::animation::{Frames, MAX_KEYS};
use crate::Bundle;
use glam::{DMat4, DVec3, Vec3};

const MESH: &str =
    r#"<mesh id="q"><vertices>0 0 0 1 0 0 0 1 0</vertices><triangles>0 1 2</triangles></mesh>"#;
const CAM: &str = r#"<camera id="c" position="0 0 5" lookat="0 0 0" fov="50"><render width="4" height="3"/></camera>"#;

fn parse(body: &str) -> Result<SceneDesc> {
    let text = format!("<scene version=\"1\">\n{body}\n</scene>");
    parse_scene_str(
        "scene.xml",
        &text,
        &Bundle {
            scene: "scene.xml".into(),
            files: Default::default(),
        },
    )
}

/// `body` starts on line 2: errors are checked at `line:col` of the file.
#[track_caller]
fn check(body: &str, line: u32, col: u32, needles: &[&str]) {
    let e = match parse(body) {
        Ok(_) => panic!("expected an error at {line}:{col}, the scene parsed:\n{body}"),
        Err(e) => e,
    };
    assert_eq!(
        (e.location.line, e.location.column),
        (line, col),
        "wrong location for: {e}"
    );
    for n in needles {
        assert!(e.message.contains(n), "message of `{e}` lacks `{n}`");
    }
}

fn model(animates: &str) -> String {
    format!("{MESH}{CAM}\n<model id=\"m\" mesh=\"q\">\n{animates}\n</model>")
}

#[test]
fn keys_resolve_and_the_description_holds_the_scene_at_t_0() {
    let d = parse(&format!(
        r#"{MESH}
<model id="m" mesh="q">
  <transform><translate v="0 0 1"/></transform>
  <animate channel="translate" times="-1 1" values="0 0 0  4 0 0"/>
  <animate channel="scale" times="0" values="2 2 2"/>
</model>
<light position="0 5 0"><animate channel="intensity" times="0 2" values="1 3"/></light>
<camera id="c" position="0 0 5" lookat="0 0 0" fov="50">
  <animate channel="fov" times="0 1" values="40 60"/>
  <render width="4" height="3" frames="1-48" fps="25" output="shot.####.png"/>
</camera>"#
    ))
    .unwrap();
    // At t = 0: translate halfway (2 0 0), after scale 2 of the static +z.
    let expected = DMat4::from_translation(DVec3::new(2.0, 0.0, 0.0))
        * DMat4::from_scale(DVec3::splat(2.0))
        * DMat4::from_translation(DVec3::Z);
    assert!(d.models[0].transform.abs_diff_eq(expected, 1e-12));
    assert_eq!(d.lights[0].intensity, 1.0);
    assert_eq!(d.cameras[0].fov, 40.0);
    let r = &d.cameras[0].render;
    assert_eq!(r.frames, Some(Frames { first: 1, last: 48 }));
    assert_eq!((r.fps, r.output.as_str()), (25.0, "shot.####.png"));
    let a = &d.animation;
    assert_eq!((a.models.len(), a.lights.len(), a.cameras.len()), (1, 1, 1));
    assert_eq!(a.cameras[0].camera_at(0.5).unwrap().fov, 50.0);
    assert_eq!(a.lights[0].light_at(5.0).intensity, 3.0);
}

#[test]
fn a_scene_without_keys_or_frames_has_no_animation() {
    let d = parse(&format!("{MESH}{CAM}<model id=\"m\" mesh=\"q\"/>")).unwrap();
    assert!(d.animation.is_empty());
    assert_eq!(d.cameras[0].render.frames, None);
    assert_eq!(d.cameras[0].render.output, "c.png");
}

#[test]
fn a_sequence_defaults_to_a_padded_output() {
    let d = parse(r#"<camera id="c" position="0 0 5" lookat="0 0 0" fov="50"><render width="4" height="3" frames="7"/></camera>"#).unwrap();
    let r = &d.cameras[0].render;
    assert_eq!(r.frames, Some(Frames { first: 7, last: 7 }));
    assert_eq!((r.fps, r.output.as_str()), (24.0, "c.####.png"));
}

#[test]
fn a_camera_follows_its_keyed_lookat() {
    let d = parse(
        r#"<camera id="c" position="0 0 5" lookat="0 0 0" fov="50">
  <animate channel="lookat" times="0 1" values="0 0 0  5 0 5"/>
  <render width="4" height="3"/></camera>"#,
    )
    .unwrap();
    let c = d.animation.cameras[0].camera_at(1.0).unwrap();
    assert_eq!(c.direction, Vec3::X);
    // focus follows |lookat − position| when not given.
    assert_eq!(c.focus, 5.0);
}

#[test]
fn unsorted_and_repeated_times_are_located_errors() {
    check(
        &model(r#"<animate channel="translate" times="0 2 1" values="0 0 0 1 1 1 2 2 2"/>"#),
        4,
        30,
        &[
            "times",
            "strictly increasing",
            "key 2 at t = 1 comes before key 1 at t = 2",
        ],
    );
    check(
        &model(r#"<animate channel="translate" times="0 1 1" values="0 0 0 1 1 1 2 2 2"/>"#),
        4,
        30,
        &["key 2 at t = 1 repeats key 1"],
    );
}

#[test]
fn a_wrong_count_of_values_is_a_located_error() {
    check(
        &model(r#"<animate channel="rotate" times="0 1" values="0 1 0 0  0 1 0"/>"#),
        4,
        39,
        &[
            "values",
            "x y z angle",
            "2 keys (8 numbers), found 7 numbers",
        ],
    );
}

#[test]
fn too_many_keys_is_a_limit() {
    let times: Vec<String> = (0..=MAX_KEYS).map(|i| i.to_string()).collect();
    let body = model(&format!(
        r#"<animate channel="scale" times="{}" values="1 1 1"/>"#,
        times.join(" ")
    ));
    let e = parse(&body).unwrap_err();
    assert_eq!(e.kind, SceneErrorKind::Limit, "{e}");
    assert!(
        e.message.contains("65537 keys (expected at most 65536"),
        "{e}"
    );
    assert_eq!((e.location.line, e.location.column), (4, 26));
}

#[test]
fn bad_values_channels_and_duplicates_are_located_errors() {
    check(
        &model(r#"<animate channel="scale" times="0 1" values="1 1 1  1 0 1"/>"#),
        4,
        38,
        &["each > 0", "key 1 is \"1 0 1\""],
    );
    check(
        &model(r#"<animate channel="position" times="0" values="1 1 1"/>"#),
        4,
        10,
        &["\"translate\", \"rotate\", \"scale\""],
    );
    check(
        &model(
            "<animate channel=\"scale\" times=\"0\" values=\"1 1 1\"/>\n<animate channel=\"scale\" times=\"1\" values=\"2 2 2\"/>",
        ),
        5,
        1,
        &["second <animate channel=\"scale\">", "4:1"],
    );
    check(
        r#"<camera id="c" position="0 0 5" lookat="0 0 0" fov="50">
<animate channel="fov" times="0 1" values="40 180"/><render width="4" height="3"/></camera>"#,
        3,
        36,
        &["(0, 180)"],
    );
    check(
        r#"<camera id="c" position="0 0 5" lookat="0 0 0" fov="50">
<animate channel="direction" times="0" values="0 0 -1"/><render width="4" height="3"/></camera>"#,
        3,
        1,
        &["on a <camera> with lookat="],
    );
    check(
        r#"<camera id="c" position="0 0 5" direction="0 0 -1" fov="50">
<animate channel="direction" times="0 1" values="0 0 -1  0 1 0"/><render width="4" height="3"/></camera>"#,
        3,
        1,
        &["parallel to up"],
    );
    check(
        r#"<light position="0 1 0"><animate channel="intensity" times="0" values="-1"/></light>"#,
        2,
        64,
        &["≥ 0"],
    );
}

#[test]
fn frames_and_patterns_are_checked() {
    let cam = |render: &str| {
        format!(
            "<camera id=\"c\" position=\"0 0 5\" lookat=\"0 0 0\" fov=\"50\">\n<render width=\"4\" height=\"3\" {render}/></camera>"
        )
    };
    check(&cam(r#"frames="5-2""#), 3, 30, &["first-last"]);
    check(&cam(r#"frames="1-10000000""#), 3, 30, &["9999999"]);
    check(&cam(r#"fps="0""#), 3, 30, &["> 0"]);
    check(
        &cam(r#"frames="1-3" output="shot.png""#),
        3,
        43,
        &["run of #"],
    );
    check(
        &cam(r#"output="shot.##.png""#),
        3,
        30,
        &["only for a sequence"],
    );
    check(
        &cam(r#"frames="1-3" output="a.##.b.##.png""#),
        3,
        43,
        &["one run of #"],
    );
}

#[test]
fn a_light_follows_its_keyed_position_between_and_beyond_its_keys() {
    let mut d = parse(&format!(
        r#"{MESH}{CAM}
<light position="9 9 9" intensity="2">
  <animate channel="position" times="1 3" values="0 2 0  4 6 -2"/>
</light>"#
    ))
    .unwrap();
    let a = d.animation.clone();
    let at = |t: f64| a.lights[0].light_at(t).position;
    // Held before the first key and after the last, linear between.
    assert_eq!(at(0.0), DVec3::new(0.0, 2.0, 0.0));
    assert_eq!(at(1.0), DVec3::new(0.0, 2.0, 0.0));
    assert_eq!(at(2.0), DVec3::new(2.0, 4.0, -1.0));
    assert_eq!(at(2.5), DVec3::new(3.0, 5.0, -1.5));
    assert_eq!(at(7.0), DVec3::new(4.0, 6.0, -2.0));
    // The description holds t = 0; applying a time moves the light (its
    // other attributes kept).
    assert_eq!(d.lights[0].position, DVec3::new(0.0, 2.0, 0.0));
    a.apply(&mut d, 2.0).unwrap();
    assert_eq!(d.lights[0].position, DVec3::new(2.0, 4.0, -1.0));
    assert_eq!(d.lights[0].intensity, 2.0);
}

/// The rotation the keys give at `t`, with the model's static transform
/// taken out (the keys at `t = 0` are the identity in these tests).
fn keyed_rotation(keys: &str, t: f64) -> DMat4 {
    let d = parse(&model(&format!(
        r#"<animate channel="rotate" times="0 1 2" values="{keys}"/>"#
    )))
    .unwrap();
    let m = &d.animation.models[0];
    m.transform(t) * m.transform(0.0).inverse()
}

fn about(axis: DVec3, deg: f64) -> DMat4 {
    DMat4::from_quat(glam::DQuat::from_axis_angle(
        axis.normalize(),
        deg.to_radians(),
    ))
}

#[test]
fn rotation_keys_turn_the_shorter_way_on_one_axis_and_between_two() {
    // 0° then 350° about +y: the shorter way is 10° back, so halfway is
    // −5°, not the 175° of interpolating the angle.
    let r = keyed_rotation("0 1 0 0  0 1 0 0  0 1 0 350", 1.5);
    assert!(r.abs_diff_eq(about(DVec3::Y, -5.0), 1e-12), "{r}");
    // 0° then 270° about +z: −90° the short way; a quarter of it at 1.25.
    let r = keyed_rotation("0 0 1 0  0 0 1 0  0 0 1 270", 1.25);
    assert!(r.abs_diff_eq(about(DVec3::Z, -22.5), 1e-12), "{r}");
    // 170° then −170° about +x: 20° apart through 180°, not 340° through 0°.
    let r = keyed_rotation("1 0 0 0  1 0 0 170  1 0 0 -170", 1.5);
    assert!(r.abs_diff_eq(about(DVec3::X, 180.0), 1e-12), "{r}");
    // 90° about +x then 90° about +y: the great arc between the two, whose
    // midpoint is, in closed form, the normalised sum of the two
    // quaternions, q = (qx + qy) / |qx + qy| (their dot product is > 0).
    let qx = glam::DQuat::from_axis_angle(DVec3::X, 90f64.to_radians());
    let qy = glam::DQuat::from_axis_angle(DVec3::Y, 90f64.to_radians());
    let mid = DMat4::from_quat((qx + qy).normalize());
    let r = keyed_rotation("1 0 0 0  1 0 0 90  0 1 0 90", 1.5);
    assert!(r.abs_diff_eq(mid, 1e-12), "{r} vs {mid}");
    // Neither key, nor one of them held.
    assert!(!r.abs_diff_eq(about(DVec3::X, 90.0), 1e-3));
    assert!(!r.abs_diff_eq(about(DVec3::Y, 90.0), 1e-3));
}
