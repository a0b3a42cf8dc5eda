//! `trevi-submit` on this machine, as a user runs it: real process, real files.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A workspace binary, built by `cargo test --workspace` next to the test
/// executable's directory (target/<profile>/).
fn bin(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    let dir = exe.parent().and_then(Path::parent).expect("target dir");
    let path = dir.join(format!("{name}{}", std::env::consts::EXE_SUFFIX));
    assert!(
        path.exists(),
        "{} is missing: run the tests with `cargo test --workspace` so the binaries are built",
        path.display()
    );
    path
}

fn submit(args: &[&str], cwd: &Path) -> Output {
    Command::new(bin("trevi-submit"))
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("run trevi-submit")
}

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples")
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

const TWO_CAMERAS: &str = r#"<scene version="1">
  <sphere id="s" center="0 0 -4" radius="1"/>
  <light position="3 3 0"/>
  <camera id="a" position="0 0 0" direction="0 0 -1" fov="40">
    <render width="24" height="16" output="out/a.png"/>
  </camera>
  <camera id="b" position="0 0 0" direction="0 0 -1" fov="60">
    <render width="20" height="10" output="out/b.exr"/>
  </camera>
</scene>
"#;

#[test]
fn renders_an_example_from_an_obj_file_to_the_given_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("frame.png");
    let scene = examples().join("instancing.xml");
    let o = submit(
        &[
            scene.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--quiet",
        ],
        dir.path(),
    );
    assert!(
        o.status.success(),
        "stderr: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let (w, h, px) = trevi_core::output::read_png_rgb8(&out).unwrap();
    assert_eq!((w, h), (640, 360));
    // The picture is not blank: sky at the top, lit tori and ground below.
    let distinct: std::collections::BTreeSet<_> = px.iter().collect();
    assert!(distinct.len() > 1000, "only {} colors", distinct.len());
    assert_eq!(files_in(dir.path()), vec!["frame.png"]);
}

#[test]
fn every_camera_goes_to_its_own_output_and_the_format_follows_the_extension() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("two.xml"), TWO_CAMERAS).unwrap();
    let o = submit(&["two.xml"], dir.path());
    assert!(
        o.status.success(),
        "stderr: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let (w, h, _) = trevi_core::output::read_png_rgb8(&dir.path().join("out/a.png")).unwrap();
    assert_eq!((w, h), (24, 16));
    let (w, h, px) = trevi_core::output::read_exr_rgb(&dir.path().join("out/b.exr")).unwrap();
    assert_eq!((w, h), (20, 10));
    assert!(px.iter().any(|p| p[0] > 0.0));

    // One camera by id; -o needs a single camera.
    let o = submit(
        &["two.xml", "--camera", "b", "-o", "b.png", "-q"],
        dir.path(),
    );
    assert!(o.status.success());
    assert!(dir.path().join("b.png").exists());
    let o = submit(&["two.xml", "-o", "x.png"], dir.path());
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--camera"));
    let o = submit(&["two.xml", "--camera", "nope"], dir.path());
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("nope") && err.contains("a, b"), "{err}");
    assert!(!dir.path().join("x.png").exists());
}

#[test]
fn a_scene_error_names_file_line_and_column_exits_non_zero_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let bad = TWO_CAMERAS.replace("fov=\"60\"", "fov=\"200\"");
    std::fs::write(dir.path().join("bad.xml"), bad).unwrap();
    let o = submit(&["bad.xml"], dir.path());
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    // Line 7, the attribute's column.
    let col = TWO_CAMERAS.lines().nth(6).unwrap().find("fov").unwrap() + 1;
    assert!(err.contains(&format!("bad.xml:7:{col}")), "{err}");
    assert!(err.contains("fov"), "{err}");
    // Not even the valid first camera was rendered.
    assert_eq!(files_in(dir.path()), vec!["bad.xml"]);
}

#[test]
fn a_reference_outside_the_scene_directory_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let sub = dir.path().join("scene");
    std::fs::create_dir(&sub).unwrap();
    std::fs::write(
        dir.path().join("secret.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    )
    .unwrap();
    let xml = TWO_CAMERAS.replace(
        "<sphere id=\"s\" center=\"0 0 -4\" radius=\"1\"/>",
        "<mesh id=\"m\" file=\"../secret.obj\"/>",
    );
    std::fs::write(sub.join("s.xml"), xml).unwrap();
    let o = submit(&["s.xml"], &sub);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("s.xml:2:") && err.contains("../secret.obj"),
        "{err}"
    );
    assert_eq!(files_in(&sub), vec!["s.xml"]);
}
