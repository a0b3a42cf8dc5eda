//! Sequences (animated scenes, `frames=` / `--frames`) rendered by
//! `trevi-submit` on this machine, as a user runs it: every frame is its own
//! file, and each is the scene at t = frame / fps.
//!
//! Sequences on a farm: tests/sequence_farm.rs.

mod common;

use common::{submit, Dir};

const BOX: &str = r#"<mesh id="box">
    <vertices>-1 -1 -1  1 -1 -1  1 1 -1  -1 1 -1  -1 -1 1  1 -1 1  1 1 1  -1 1 1</vertices>
    <triangles>0 2 1 0 3 2 4 5 6 4 6 7 0 1 5 0 5 4 3 6 2 3 7 6 0 4 7 0 7 3 1 2 6 1 6 5</triangles>
  </mesh>
  <light position="3 5 4"/>"#;

/// A box turning a quarter turn and moving +x over 2 s, the camera rising;
/// at 2 fps frame n is t = n/2. Sampling is deterministic (no jitter), so
/// the frame number in the sample hash does not show and a frame can be
/// compared with the scene written at its time.
fn animated() -> String {
    format!(
        r#"<scene version="1">{BOX}
  <model id="m" mesh="box">
    <transform><scale v="0.5"/></transform>
    <animate channel="rotate" times="0 2" values="0 1 0 0  0 1 0 90"/>
    <animate channel="translate" times="0 2" values="0 0 0  2 0 0"/>
  </model>
  <camera id="c" position="0 1 6" lookat="0 0 0" fov="40">
    <animate channel="position" times="0 2" values="0 1 6  0 3 6"/>
    <render width="32" height="24" frames="0-4" fps="2" output="out/f.##.png"/>
  </camera>
</scene>"#
    )
}

/// The scene at t = 1 s (frame 2) with no keys: a quarter turn's half, half
/// of the move, the camera halfway up.
fn at_one_second() -> String {
    format!(
        r#"<scene version="1">{BOX}
  <model id="m" mesh="box">
    <transform><scale v="0.5"/><rotate axis="0 1 0" angle="45"/><translate v="1 0 0"/></transform>
  </model>
  <camera id="c" position="0 2 6" lookat="0 0 0" fov="40">
    <render width="32" height="24" output="still.png"/>
  </camera>
</scene>"#
    )
}

#[test]
fn each_frame_is_the_scene_at_frame_over_fps() {
    let dir = Dir::new();
    let scene = dir.write("anim.xml", &animated());
    let out = submit(&dir, &[scene.to_str().unwrap(), "--frames", "1-3", "-q"]);
    assert!(out.status.success(), "{}", dir.logs());
    let frame = |n: u32| std::fs::read(dir.path().join(format!("out/f.{n:02}.png"))).unwrap();
    // Only the frames asked for.
    assert!(!dir.path().join("out/f.00.png").exists());
    assert!(!dir.path().join("out/f.04.png").exists());
    let still = dir.write("still.xml", &at_one_second());
    let out = submit(&dir, &[still.to_str().unwrap(), "-q"]);
    assert!(out.status.success(), "{}", dir.logs());
    let still = std::fs::read(dir.path().join("still.png")).unwrap();
    assert_eq!(
        frame(2),
        still,
        "frame 2 (t = 1 s) differs from the scene written at 1 s"
    );
    assert_ne!(frame(1), frame(2));
    assert_ne!(frame(3), frame(2));
}

#[test]
fn the_scene_range_is_the_default_and_one_frame_is_as_in_the_whole_sequence() {
    let dir = Dir::new();
    let scene = dir.write("anim.xml", &animated());
    let out = submit(&dir, &[scene.to_str().unwrap(), "-q"]);
    assert!(out.status.success(), "{}", dir.logs());
    let mut names: Vec<String> = std::fs::read_dir(dir.path().join("out"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(
        names,
        ["f.00.png", "f.01.png", "f.02.png", "f.03.png", "f.04.png"]
    );
    // A frame rendered alone is the same frame as in the whole sequence.
    let whole = std::fs::read(dir.path().join("out/f.03.png")).unwrap();
    let out = submit(
        &dir,
        &[
            scene.to_str().unwrap(),
            "--frames",
            "3",
            "-o",
            dir.path().join("alone.#.png").to_str().unwrap(),
            "-q",
        ],
    );
    assert!(out.status.success(), "{}", dir.logs());
    assert_eq!(
        std::fs::read(dir.path().join("alone.3.png")).unwrap(),
        whole
    );
}

#[test]
fn bad_sequences_are_refused_before_anything_renders() {
    let dir = Dir::new();
    let scene = dir.write("anim.xml", &animated());
    let still = dir.write("still.xml", &at_one_second());
    let cases: &[(&[&str], &str)] = &[
        (
            &[still.to_str().unwrap(), "--frames", "1-2"],
            "one run of #",
        ),
        (&[scene.to_str().unwrap(), "--frames", "3-1"], "reversed"),
    ];
    for (args, needle) in cases {
        let out = submit(&dir, args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} succeeded");
        assert!(err.contains(needle), "{args:?}: {err}");
    }
    assert!(
        !dir.path().join("out").exists(),
        "a refused sequence wrote files"
    );
    assert!(!dir.path().join("still.png").exists());
}
