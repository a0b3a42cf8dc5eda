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

/// A local sequence interrupted keeps the frames it finished (complete
/// files under the pattern) and writes none of the others: its frames are
/// on the embedded farm until the end, and a signal used to drop them with
/// its data directory. Frame 0 sees nothing (the wall is behind the
/// camera) and is quick; from frame 1 on the wall fills the frame with
/// soft shadows and AO on one thread, so the signal lands in frame 1.
#[cfg(unix)]
#[test]
fn an_interrupted_local_sequence_keeps_the_frames_it_finished() {
    use std::io::{BufRead, BufReader};
    let dir = tempfile::tempdir().unwrap();
    let scene = r#"<scene version="1">
  <settings background="0.1 0.1 0.2" ambient="0.2 0.2 0.2"/>
  <mesh id="wall"><vertices>-50 -50 0  50 -50 0  50 50 0  -50 50 0</vertices>
    <triangles>0 1 2  0 2 3</triangles></mesh>
  <model id="w" mesh="wall">
    <animate channel="translate" times="0 0.001" values="0 0 1000   0 0 0"/>
    <surface diffuse="0.8 0.3 0.2" reflectivity="0.2"/>
  </model>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1" radius="0.5"/>
  <camera id="main" position="0 0 6" lookat="0 0 0" up="0 1 0" fov="50">
    <render width="96" height="64" supersample="6" shadow-samples="8" ao-samples="16"
            frames="0-2" output="shot.#.png"/>
  </camera>
</scene>
"#;
    std::fs::write(dir.path().join("seq.xml"), scene).unwrap();
    let mut child = Command::new(bin("trevi-submit"))
        .args(["seq.xml", "--threads", "1", "--tile-size", "16"])
        .current_dir(dir.path())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut said = String::new();
    // Not a terminal: one progress line each time a frame is done.
    while !said.contains("1/3 frames done") {
        let mut line = String::new();
        assert!(
            err.read_line(&mut line).unwrap() > 0,
            "trevi-submit ended before frame 0 was done: {said}"
        );
        said.push_str(&line);
    }
    let kill = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut err, &mut rest).unwrap();
    said.push_str(&rest);
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130), "{said}");
    assert!(said.contains("kept the 1 frames it finished"), "{said}");
    let frame0 = std::fs::read(dir.path().join("shot.0.png")).unwrap();
    let png = png::Decoder::new(std::io::Cursor::new(frame0))
        .read_info()
        .unwrap();
    assert_eq!((png.info().width, png.info().height), (96, 64));
    for f in ["shot.1.png", "shot.2.png"] {
        assert!(!dir.path().join(f).exists(), "{f}: {said}");
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
    refused(
        submit(&["two.xml", "--tile-size", "0"], dir.path()),
        "--tile-size",
    );
    // The old name, and the environment variable, are the same flag.
    refused(
        submit(&["two.xml", "--tile", "0"], dir.path()),
        "--tile-size",
    );
    let o = Command::new(bin("trevi-submit"))
        .arg("two.xml")
        .env("TREVI_TILE_SIZE", "0")
        .current_dir(dir.path())
        .output()
        .unwrap();
    refused(o, "--tile-size");
    assert_eq!(files_in(dir.path()), vec!["two.xml"]);
}

/// A still camera and a sequence camera in one scene: both render without
/// --camera, the still to its file and the sequence to its frames.
#[test]
fn a_scene_with_a_still_and_a_sequence_renders_both() {
    let dir = tempfile::tempdir().unwrap();
    let scene = TWO_CAMERAS.replace(
        r#"output="out/b.exr""#,
        r#"frames="3-4" output="out/b.#.exr""#,
    );
    assert_ne!(scene, TWO_CAMERAS);
    std::fs::write(dir.path().join("mixed.xml"), scene).unwrap();
    let o = submit(&["mixed.xml", "-q"], dir.path());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        files_in(&dir.path().join("out")),
        vec!["a.png", "b.3.exr", "b.4.exr"]
    );
}

/// `-o` follows the scene parser's rule for `#`: one run, in the file name,
/// only for a sequence. Nothing is made for a refused pattern (no `d#`).
#[test]
fn an_output_pattern_follows_the_parser_s_rule_for_hash() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("two.xml"), TWO_CAMERAS).unwrap();
    for (args, says) in [
        (
            &["--frames", "1-2", "-o", "d#/f.#.png"][..],
            "# may only be in the file name",
        ),
        (&["--frames", "1-2", "-o", "f.#.#.png"][..], "one run of #"),
        (&["-o", "d#/f.png"][..], "# may only be in the file name"),
        (&["-o", "f.#.png"][..], "only for a sequence"),
    ] {
        let all = [&["two.xml", "--camera", "a", "-q"][..], args].concat();
        let o = submit(&all, dir.path());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} accepted");
        assert!(
            err.contains(says) || err.contains("one run of #"),
            "{args:?}: {err}"
        );
    }
    assert_eq!(files_in(dir.path()), vec!["two.xml"]);
}

/// A mistyped subcommand is not read as a scene file: the closest
/// subcommand is suggested, exit status 2. A missing scene is still named
/// as a missing file.
#[test]
fn a_mistyped_subcommand_suggests_the_closest_one() {
    let dir = tempfile::tempdir().unwrap();
    let o = submit(&["lsit"], dir.path());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("did you mean `trevi-submit list`"), "{err}");
    let o = submit(&["canel", "3"], dir.path());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("did you mean `trevi-submit cancel`"), "{err}");
    let o = submit(&["missing.xml"], dir.path());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("missing.xml") && !err.contains("did you mean"),
        "{err}"
    );
}

/// Subcommand help shows what the subcommand takes: a required
/// --coordinator (no "render on this machine"), its <ID> described, and
/// --preview / --quiet only where they do something.
#[test]
fn subcommand_help_describes_what_each_takes() {
    let dir = tempfile::tempdir().unwrap();
    let help = |cmd: &str| {
        let o = submit(&[cmd, "--help"], dir.path());
        assert!(o.status.success(), "{cmd}");
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    for cmd in ["status", "list", "cancel", "fetch", "wait"] {
        let h = help(cmd);
        assert!(!h.contains("render on this machine"), "{cmd}: {h}");
        assert!(h.contains("--coordinator <COORDINATOR>"), "{cmd}: {h}");
        assert!(!h.contains("--tile"), "{cmd}: {h}");
        if cmd != "list" {
            assert!(h.contains("The job's id"), "{cmd}: {h}");
        }
        assert_eq!(h.contains("--preview"), cmd == "status", "{cmd}: {h}");
        assert_eq!(
            h.contains("--quiet"),
            cmd == "fetch" || cmd == "wait",
            "{cmd}: {h}"
        );
    }
    // Without a coordinator, a farm command says it needs one.
    let o = Command::new(bin("trevi-submit"))
        .args(["status", "1"])
        .env_remove("TREVI_COORDINATOR")
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--coordinator"));
    // Every flag of a render has its environment variable.
    let o = submit(&["--help"], dir.path());
    let h = String::from_utf8_lossy(&o.stdout);
    for env in [
        "TREVI_COORDINATOR",
        "TREVI_SUBMIT_TOKEN",
        "TREVI_JOB_PRIORITY",
        "TREVI_DETACH",
        "TREVI_CAMERA",
        "TREVI_OUTPUT",
        "TREVI_FRAMES",
        "TREVI_THREADS",
        "TREVI_TILE_SIZE",
        "TREVI_QUIET",
        "TREVI_PREVIEW",
        "TREVI_TLS_CA",
        "TREVI_TLS_DOMAIN",
    ] {
        assert!(h.contains(&format!("[env: {env}")), "{env}: {h}");
    }
}

/// TREVI_TOKEN named two different secrets (trevi-submit's and
/// trevi-worker's): both now refuse it, naming the variable to set, rather
/// than send the wrong one.
#[test]
fn the_ambiguous_trevi_token_is_refused_naming_the_new_variables() {
    let dir = tempfile::tempdir().unwrap();
    let o = Command::new(bin("trevi-submit"))
        .args(["list", "--coordinator", "http://127.0.0.1:9"])
        .env("TREVI_TOKEN", "x")
        .env_remove("TREVI_SUBMIT_TOKEN")
        .current_dir(dir.path())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("set TREVI_SUBMIT_TOKEN"),
        "{err}"
    );
    let o = Command::new(bin("trevi-worker"))
        .args(["--coordinator", "http://127.0.0.1:9"])
        .env("TREVI_TOKEN", "x")
        .env_remove("TREVI_WORKER_TOKEN")
        .env_remove("TREVI_WORKER_TOKEN_FILE")
        .env_remove("TREVI_TOKEN_FILE")
        .current_dir(dir.path())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("set TREVI_WORKER_TOKEN"),
        "{err}"
    );
}

/// The worker's CPU class is --cpu-priority (a job's priority is
/// trevi-submit's --priority); a memory limit that rounds to 0 bytes is
/// refused, not taken as "no limit".
#[test]
fn worker_flags_have_names_of_their_own_and_tiny_sizes_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let o = Command::new(bin("trevi-worker"))
        .arg("--help")
        .output()
        .unwrap();
    let h = String::from_utf8_lossy(&o.stdout);
    assert!(
        h.contains("--cpu-priority") && h.contains("TREVI_CPU_PRIORITY"),
        "{h}"
    );
    assert!(!h.contains("--priority <"), "{h}");
    assert!(h.contains("TREVI_WORKER_TOKEN"), "{h}");
    let o = Command::new(bin("trevi-worker"))
        .args([
            "--coordinator",
            "http://127.0.0.1:9",
            "--max-memory",
            "0.0000001K",
        ])
        .current_dir(dir.path())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--max-memory") && err.contains("not a size"),
        "{err}"
    );
}

/// A sequence of two 16×16 frames.
const TWO_FRAMES: &str = r#"<scene version="1">
  <sphere id="ball" center="0 1 0" radius="1"> <surface diffuse="0.8 0.3 0.2"/> </sphere>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1"/>
  <camera id="main" position="0 2 6" lookat="0 1 0" up="0 1 0" fov="50">
    <render width="16" height="16" frames="1-2" output="shot.#.png"/>
  </camera>
</scene>
"#;

/// The farm commands on a finished sequence: `list --header` has a header
/// and columns (the scene file and the submitter among them), and the
/// still submitted after a sequence takes the next id (frames use none); `fetch -o` of a sequence needs a pattern or a directory
/// (`-o x.png` makes no directory `x.png`); reflection answers v1alpha,
/// which most gRPC clients still ask, as well as v1.
#[test]
fn farm_commands_on_a_sequence_and_reflection_v1alpha() {
    use common::*;
    let dir = Dir::new();
    let scene = dir.write("scene/two.xml", TWO_FRAMES);
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let _w = worker_with(&dir, &c.url, "worker", &[], &[]);
    let rt = runtime();
    let seq = submit_and_wait(&dir, &rt, &c, &scene, &[], 60).id;
    let id = seq.to_string();
    let still = dir.write(
        "scene/still.xml",
        &TWO_FRAMES.replace(
            r#"frames="1-2" output="shot.#.png""#,
            r#"output="still.png""#,
        ),
    );
    let after = submit_and_wait(&dir, &rt, &c, &still, &[], 60).id;
    assert_eq!(after, seq + 1, "the sequence's frames used ids up");
    let o = common::submit(&dir, &["list", "--header", "--coordinator", &c.url]);
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines.len(), 3, "{out}");
    for col in [
        "ID",
        "STATE",
        "SCENE",
        "CAMERA",
        "SIZE",
        "TILES",
        "PRIORITY",
        "QUEUED",
        "RENDER",
        "SUBMITTER",
        "OUTPUT",
    ] {
        assert!(lines[0].contains(col), "{out}");
    }
    assert!(
        lines[1].contains("shot.#.png") && lines[1].contains("2 done"),
        "{out}"
    );
    assert!(
        lines[1].contains("two.xml") && lines[2].contains("still.xml"),
        "{out}"
    );
    // Submitted over loopback: the submitter is the client's address,
    // under its column.
    let col = lines[0].find("SUBMITTER").unwrap();
    for row in &lines[1..] {
        assert_eq!(row.get(col..col + 9), Some("127.0.0.1"), "{out}");
    }
    // `status` says the same, and splits the time at the first lease.
    let o = common::submit(
        &dir,
        &["status", &after.to_string(), "--coordinator", &c.url],
    );
    let status = String::from_utf8_lossy(&o.stdout).into_owned();
    for part in ["still.xml", "queued ", "rendered ", "by 127.0.0.1", "done"] {
        assert!(status.contains(part), "{part}: {status}");
    }
    // Without --header, and not on a terminal: the rows alone.
    let o = common::submit(&dir, &["list", "--coordinator", &c.url]);
    assert_eq!(String::from_utf8_lossy(&o.stdout).lines().count(), 2);
    // One file's name for a sequence is refused, and nothing is made.
    let x = dir.path().join("x.png");
    let o = common::submit(
        &dir,
        &[
            "fetch",
            &id,
            "--coordinator",
            &c.url,
            "-o",
            x.to_str().unwrap(),
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("names one file"),
        "{err}"
    );
    assert!(!x.exists());
    // A device is one file too; a pattern under it fails once, saying why
    // once (not "Not a directory: Not a directory").
    let o = common::submit(
        &dir,
        &["fetch", &id, "--coordinator", &c.url, "-o", "/dev/full"],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("names one file"),
        "{err}"
    );
    let o = common::submit(
        &dir,
        &[
            "fetch",
            &id,
            "--coordinator",
            &c.url,
            "-o",
            "/dev/full/x.#.png",
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert_eq!(err.matches("Not a directory").count(), 1, "{err}");
    // A directory takes the frames.
    let frames = dir.path().join("frames");
    std::fs::create_dir(&frames).unwrap();
    let o = common::submit(
        &dir,
        &[
            "fetch",
            &id,
            "--coordinator",
            &c.url,
            "-o",
            frames.to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", dir.logs());
    assert_eq!(files_in(&frames), vec!["shot.1.png", "shot.2.png"]);
    rt.block_on(async {
        use tonic_reflection::pb::v1alpha::{
            server_reflection_client::ServerReflectionClient,
            server_reflection_request::MessageRequest, server_reflection_response::MessageResponse,
            ServerReflectionRequest,
        };
        let mut r = ServerReflectionClient::new(channel(&c).await);
        let req = ServerReflectionRequest {
            host: String::new(),
            message_request: Some(MessageRequest::ListServices(String::new())),
        };
        let mut stream = r
            .server_reflection_info(tokio_stream::iter([req]))
            .await
            .expect("reflection v1alpha")
            .into_inner();
        let msg = stream.message().await.unwrap().unwrap();
        let Some(MessageResponse::ListServicesResponse(list)) = msg.message_response else {
            panic!("unexpected reflection answer {msg:?}");
        };
        assert!(list.service.iter().any(|s| s.name == "trevi.v1.Jobs"));
    });
}
