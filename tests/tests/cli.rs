//! `trevi-submit` on this machine, as a user runs it: real process, real
//! files; and the flag values `trevi-submit` and `trevi-worker` refuse.

mod common;

use common::bin;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

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

/// `-o y.exr` for a scene whose `output` is `.png` once wrote PNG bytes
/// under the EXR name (and the reverse), and `-o x.jpg` got PNG bytes: the
/// format follows `-o`, and an extension that names none is refused before
/// anything renders.
#[test]
fn the_format_follows_dash_o_and_an_unknown_extension_is_refused() {
    use trevi_core::output::{read_exr_rgb, read_png_rgb8, Format};
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("two.xml"), TWO_CAMERAS).unwrap();
    // Camera a's output is out/a.png, b's is out/b.exr.
    for (camera, out, format) in [
        ("a", "a.exr", Format::Exr),
        ("a", "a.PNG", Format::Png),
        ("b", "b.png", Format::Png),
        ("b", "b.Exr", Format::Exr),
    ] {
        let o = submit(
            &["two.xml", "--camera", camera, "-o", out, "-q"],
            dir.path(),
        );
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let bytes = std::fs::read(dir.path().join(out)).unwrap();
        assert_eq!(Format::sniff(&bytes), Some(format), "{out}");
    }
    // The same pixels either way: the PNG is the EXR's values in sRGB.
    let (w, h, exr) = read_exr_rgb(&dir.path().join("a.exr")).unwrap();
    let (_, _, png) = read_png_rgb8(&dir.path().join("a.PNG")).unwrap();
    assert_eq!((w, h), (24, 16));
    let srgb = trevi_core::output::Srgb8::new();
    let from_exr: Vec<u8> = exr.iter().flat_map(|p| p.map(|c| srgb.encode(c))).collect();
    assert!(from_exr == png.concat(), "the EXR and the PNG differ");

    for bad in ["x.jpg", "x.bmp", "x", "x.png.part"] {
        let o = submit(&["two.xml", "--camera", "a", "-o", bad], dir.path());
        assert_eq!(o.status.code(), Some(1), "{bad}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains(bad) && err.contains("expected .png or .exr"),
            "{bad}: {err}"
        );
    }
    assert_eq!(
        files_in(dir.path()),
        ["a.PNG", "a.exr", "b.Exr", "b.png", "two.xml"]
    );
}

/// A target that exists and is not a regular file (a device behind a link,
/// a FIFO, a directory) is refused before rendering and left as it was:
/// renaming the image onto `-o /dev/full` would replace the device node.
#[cfg(unix)]
#[test]
fn a_target_that_is_not_a_regular_file_is_refused_and_left_alone() {
    use std::os::unix::fs::FileTypeExt;
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("two.xml"), TWO_CAMERAS).unwrap();
    std::os::unix::fs::symlink("/dev/null", dir.path().join("null.png")).unwrap();
    assert!(Command::new("mkfifo")
        .arg(dir.path().join("fifo.exr"))
        .status()
        .unwrap()
        .success());
    std::fs::create_dir(dir.path().join("folder.png")).unwrap();
    for (out, what) in [
        ("null.png", "a character device"),
        ("fifo.exr", "a FIFO"),
        ("folder.png", "a directory"),
    ] {
        let o = submit(&["two.xml", "--camera", "a", "-o", out], dir.path());
        assert_eq!(o.status.code(), Some(1), "{out}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains(&format!("{out} exists and is {what}, not a regular file")),
            "{out}: {err}"
        );
    }
    // The scene's own outputs are checked the same way, before rendering.
    std::fs::create_dir_all(dir.path().join("out/b.exr")).unwrap();
    let o = submit(&["two.xml"], dir.path());
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("b.exr exists and is a directory"));
    assert_eq!(files_in(&dir.path().join("out")), ["b.exr"]);

    let meta = |n: &str| std::fs::symlink_metadata(dir.path().join(n)).unwrap();
    assert!(meta("null.png").file_type().is_symlink());
    assert!(meta("fifo.exr").file_type().is_fifo());
    assert!(meta("folder.png").is_dir());
    assert!(std::fs::metadata("/dev/null")
        .unwrap()
        .file_type()
        .is_char_device());
    assert_eq!(
        files_in(dir.path()),
        ["fifo.exr", "folder.png", "null.png", "out", "two.xml"]
    );
}

/// A local render stopped by SIGINT or SIGTERM removes its
/// `trevi-submit-*` directory from the temporary directory, writes no
/// output, and exits with 128 + the signal's number, so that a shell sees
/// which signal it was and nothing piles up in the temporary directory.
#[cfg(unix)]
#[test]
fn a_local_render_interrupted_by_a_signal_leaves_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    // Hundreds of slow tiles on one thread: still rendering when signalled.
    let scene =
        common::SLOW_SCENE.replace(r#"width="96" height="64""#, r#"width="384" height="256""#);
    assert_ne!(scene, common::SLOW_SCENE);
    std::fs::write(dir.path().join("slow.xml"), scene).unwrap();
    for (signal, code) in [("INT", 130), ("TERM", 143)] {
        let tmp = dir.path().join(format!("tmp-{signal}"));
        std::fs::create_dir(&tmp).unwrap();
        let mut child = Command::new(bin("trevi-submit"))
            .args(["slow.xml", "--threads", "1", "--tile", "16", "-q"])
            .current_dir(dir.path())
            .env("TMPDIR", &tmp)
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        // The job is on the embedded coordinator: its output is being
        // written in the data directory.
        let started = std::time::Instant::now();
        let writing = || {
            let Ok(mut data) = std::fs::read_dir(&tmp) else {
                return false;
            };
            let Some(Ok(data)) = data.next() else {
                return false;
            };
            std::fs::read_dir(data.path().join("jobs/1")).is_ok_and(|mut d| {
                d.any(|e| {
                    e.unwrap()
                        .file_name()
                        .to_string_lossy()
                        .contains(".trevi-tmp-")
                })
            })
        };
        while !writing() {
            assert!(
                started.elapsed() < std::time::Duration::from_secs(60),
                "the render never started"
            );
            assert!(
                child.try_wait().unwrap().is_none(),
                "trevi-submit ended early"
            );
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        let kill = Command::new("kill")
            .args([&format!("-{signal}"), &child.id().to_string()])
            .status()
            .unwrap();
        assert!(kill.success());
        let o = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(code), "SIG{signal}: {err}");
        assert!(
            err.contains(&format!("interrupted by SIG{signal}")),
            "{err}"
        );
        assert_eq!(files_in(&tmp), Vec::<String>::new(), "SIG{signal}");
        assert_eq!(
            files_in(dir.path()).len(),
            2 + usize::from(signal == "TERM")
        );
        assert!(!dir.path().join("slow.png").exists());
    }
}

/// A flag value that makes no sense (0 scenes cached, 0 tiles in flight,
/// polling every 0 ms, 0-pixel tiles) is refused, naming the flag, before
/// anything starts, and nothing is written: taking it as 1 instead would
/// hide the mistake.
#[test]
fn nonsense_flag_values_are_refused_naming_the_flag() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("two.xml"), TWO_CAMERAS).unwrap();
    let refused = |o: Output, flag: &str| {
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{flag} 0 was accepted: {err}");
        assert!(
            err.contains(&format!("'{flag} <")) && err.contains("at least 1"),
            "{flag}: {err}"
        );
    };
    // Unreachable: a worker that started would only retry its connection,
    // so one still running after a while is killed (and the check fails).
    let worker = |args: &[&str], envs: &[(&str, &str)]| {
        let mut child = Command::new(bin("trevi-worker"))
            .args(["--coordinator", "http://127.0.0.1:9"])
            .args(args)
            .env_remove("TREVI_SCENE_CACHE")
            .env_remove("TREVI_TILES_IN_FLIGHT")
            .env_remove("TREVI_POLL_MS")
            .envs(envs.iter().copied())
            .current_dir(dir.path())
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("run trevi-worker");
        let started = std::time::Instant::now();
        while child.try_wait().unwrap().is_none()
            && started.elapsed() < std::time::Duration::from_secs(60)
        {
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        let _ = child.kill();
        child.wait_with_output().unwrap()
    };
    for flag in ["--scene-cache", "--tiles-in-flight", "--poll-ms"] {
        refused(worker(&[flag, "0"], &[]), flag);
    }
    // The same through the environment.
    refused(worker(&[], &[("TREVI_SCENE_CACHE", "0")]), "--scene-cache");
    refused(
        worker(&[], &[("TREVI_TILES_IN_FLIGHT", "0")]),
        "--tiles-in-flight",
    );
    refused(submit(&["two.xml", "--tile", "0"], dir.path()), "--tile");
    assert_eq!(files_in(dir.path()), vec!["two.xml"]);
}
