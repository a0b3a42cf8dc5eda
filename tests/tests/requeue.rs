//! Requeue and retry with real processes (docs/farm.md, "Running a
//! farm"): a done still requeued whole and by a rect, a failed sequence
//! retried keeping its done frames, frames of a done and of a running
//! sequence requeued. Every output is compared with the bytes of
//! `trevi-submit` alone, and damaged first on the coordinator's disk, so
//! that a requeue that rendered nothing (or too much) shows. Every wait is
//! for a state, never for a time.

mod common;

use common::farm::{detach, job, wait_state};
use common::*;
use std::path::{Path, PathBuf};
use trevi_core::output::read_png_rgb8;
use trevi_core::{FrameWriter, Rect};
use trevi_proto::pb;

/// Four frames of 32 × 24 (soft shadows: the frame number in the sample
/// seed shows), quick.
const FRAMES: &str = r#"<scene version="1">
  <settings background="0.1 0.1 0.2" ambient="0.2 0.2 0.2"/>
  <sphere id="ball" center="0 1 0" radius="1"> <surface diffuse="0.8 0.3 0.2"/> </sphere>
  <plane id="ground" point="0 0 0" normal="0 1 0"> <surface diffuse="0.5 0.5 0.5"/> </plane>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1" radius="0.5"/>
  <camera id="c" position="0 2 6" lookat="0 1 0" fov="50">
    <animate channel="position" times="0 1" values="0 2 6  2 3 5"/>
    <render width="32" height="24" shadow-samples="4" frames="1-4" fps="4"
            output="shot.####.png"/>
  </camera>
</scene>
"#;

/// `trevi-submit ARGS --coordinator URL`: whether it succeeded, and its
/// stdout and stderr.
fn run(dir: &Dir, c: &Coordinator, args: &[&str]) -> (bool, String) {
    let mut all = args.to_vec();
    all.extend(["--coordinator", &c.url]);
    let o = submit(dir, &all);
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    (o.status.success(), text)
}

/// [`run`], which must succeed.
fn ok(dir: &Dir, c: &Coordinator, args: &[&str]) -> String {
    let (fine, text) = run(dir, c, args);
    assert!(fine, "trevi-submit {args:?}: {text}\n{}", dir.logs());
    text
}

/// [`run`], which must fail saying `says`.
fn refused(dir: &Dir, c: &Coordinator, args: &[&str], says: &str) {
    let (fine, text) = run(dir, c, args);
    assert!(!fine, "trevi-submit {args:?} succeeded: {text}");
    assert!(text.contains(says), "trevi-submit {args:?}: {text}");
    assert!(!text.contains("panicked"), "{text}");
}

/// The pixels of a PNG on disk.
fn pixels(path: &Path) -> Vec<[u8; 3]> {
    read_png_rgb8(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .2
}

/// Writes a `w` × `h` PNG of `px` to `path` (over the coordinator's
/// output: the "old output" a requeue starts from).
fn write_png(path: &Path, w: u32, h: u32, px: &[[u8; 3]]) {
    let mut f = FrameWriter::create(path, w, h).unwrap();
    let bytes: Vec<u8> = px.iter().flatten().copied().collect();
    f.write_tile_srgb8(Rect::new(0, 0, w, h), &bytes).unwrap();
    f.finish().unwrap();
}

/// `px` with the pixels of `rect` (and `extra`) painted magenta.
fn damaged(px: &[[u8; 3]], w: u32, rect: Rect, extra: &[(u32, u32)]) -> Vec<[u8; 3]> {
    let mut px = px.to_vec();
    for y in rect.y..rect.y + rect.h {
        for x in rect.x..rect.x + rect.w {
            px[(y * w + x) as usize] = [255, 0, 255];
        }
    }
    for &(x, y) in extra {
        px[(y * w + x) as usize] = [255, 0, 255];
    }
    px
}

fn output(c: &Coordinator, id: u64, name: &str) -> PathBuf {
    c.data.join("jobs").join(id.to_string()).join(name)
}

#[test]
fn a_still_requeued_whole_and_by_rect_is_the_one_shot_bytes() {
    let dir = Dir::new();
    let scene = dir.write("still.xml", QUICK_STILL);
    let expected = embedded(&dir, &scene, "alone.png");
    let want = pixels(&dir.path().join("alone.png"));
    // Leases of one tile while a lease takes over 0.1 s (the slow worker's
    // below): a running job stays running long enough to be looked at.
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--lease-target-ms", "100"],
        &[],
    );
    let w = worker_with(&dir, &c.url, "worker0", &[], &[]);
    let rt = runtime();
    let id = detach(&dir, &c, &scene, &["--tile", "16"]);
    let s = wait_state(&dir, &rt, &c, id, pb::JobState::Done, 120);
    assert_eq!(s.tiles_total, 12);
    let out = output(&c, id, "still.png");
    assert_eq!(std::fs::read(&out).unwrap(), expected, "{}", dir.logs());
    let ids = id.to_string();

    // Whole: the output, broken on disk, is rendered again in place.
    std::fs::write(&out, b"not a png").unwrap();
    let said = ok(&dir, &c, &["requeue", &ids]);
    assert!(said.trim_start().starts_with(&ids), "{said}");
    wait_state(&dir, &rt, &c, id, pb::JobState::Done, 120);
    assert_eq!(std::fs::read(&out).unwrap(), expected, "{}", dir.logs());
    let fetched = dir.path().join("fetched.png");
    ok(&dir, &c, &["fetch", &ids, "-o", fetched.to_str().unwrap()]);
    assert_eq!(std::fs::read(&fetched).unwrap(), expected);

    // A rect: its tiles are rendered again (the damage inside goes), the
    // others' pixels are the old file's, and the bytes are the one-shot
    // render's.
    let rect = Rect::new(20, 18, 5, 3); // Inside tile (1, 1).
    write_png(
        &out,
        64,
        48,
        &damaged(&want, 64, Rect::new(16, 16, 16, 16), &[]),
    );
    assert_ne!(std::fs::read(&out).unwrap(), expected);
    ok(&dir, &c, &["requeue", &ids, "--rect", "20,18,5,3"]);
    let s = wait_state(&dir, &rt, &c, id, pb::JobState::Done, 120);
    assert_eq!(s.tiles_done, 12, "{s:?}");
    assert_eq!(
        std::fs::read(&out).unwrap(),
        expected,
        "a rect requeued: not the one-shot bytes\n{}",
        dir.logs()
    );
    // Damage outside the rect's tiles stays: those are not rendered again.
    write_png(&out, 64, 48, &damaged(&want, 64, rect, &[(0, 0), (63, 47)]));
    ok(&dir, &c, &["requeue", &ids, "--rect", "17,30,15,3"]); // Tiles (1,1), (1,2).
    wait_state(&dir, &rt, &c, id, pb::JobState::Done, 120);
    let got = pixels(&out);
    let mut hoped = want.clone();
    hoped[0] = [255, 0, 255];
    hoped[(47 * 64 + 63) as usize] = [255, 0, 255];
    assert!(got == hoped, "only the rect's tiles are rendered again");

    // Hostile input: refused with a clear message, the output untouched.
    let before = std::fs::read(&out).unwrap();
    let long = "1,".repeat(40);
    let hostile: [(&[&str], &str); 7] = [
        (&["--rect", "60,40,10,10"], "not inside the 64x48 frame"),
        (&["--rect", "0,0,0,5"], "is empty"),
        (
            &["--rect", "4294967295,4294967295,4294967295,1"],
            "not inside",
        ),
        (&["--rect", "1,2,3"], "expected X,Y,W,H"),
        (&["--rect", "99999999999,0,1,1"], "expected X,Y,W,H"),
        (&["--rect", &long], "longer than 64"),
        (&["--frames", "1-2"], "--frames takes a sequence"),
    ];
    for (args, says) in hostile {
        refused(&dir, &c, &[&["requeue", &ids][..], args].concat(), says);
    }
    refused(&dir, &c, &["requeue", "999"], "no job 999");
    refused(&dir, &c, &["retry", &ids], "retry takes a failed job");
    assert_eq!(std::fs::read(&out).unwrap(), before);
    assert_eq!(job(&rt, &c, id).state, pb::JobState::Done as i32);

    // An EXR is requeued whole, never patched.
    let exr = dir.write("exr.xml", &QUICK_STILL.replace("still.png", "still.exr"));
    let exr_id = detach(&dir, &c, &exr, &["--tile", "16"]);
    wait_state(&dir, &rt, &c, exr_id, pb::JobState::Done, 120);
    let exr_ = exr_id.to_string();
    refused(
        &dir,
        &c,
        &["requeue", &exr_, "--rect", "0,0,8,8"],
        "--rect patches a PNG output",
    );
    ok(&dir, &c, &["requeue", &exr_]);
    wait_state(&dir, &rt, &c, exr_id, pb::JobState::Done, 120);

    // A running still is refused; so is a progressive job.
    drop(w);
    let slow = dir.write("slow.xml", SLOW_SCENE);
    let delay = [("TREVI_TEST_LEASE_DELAY_MS", "500")];
    let _slow_worker = worker_with(&dir, &c.url, "worker1", &[], &delay);
    let running = detach(&dir, &c, &slow, &["--tile", "16"]);
    wait_state(&dir, &rt, &c, running, pb::JobState::Running, 120);
    refused(
        &dir,
        &c,
        &["requeue", &running.to_string()],
        "a still is requeued once it has ended",
    );
    let progressive = detach(&dir, &c, &scene, &["--samples", "2"]);
    refused(
        &dir,
        &c,
        &["requeue", &progressive.to_string()],
        "is a progressive job",
    );
}

#[test]
fn a_failed_sequence_retried_keeps_its_done_frames_and_requeued_frames_are_rendered_again() {
    let dir = Dir::new();
    let scene = dir.write("frames.xml", FRAMES);
    let alone = dir.path().join("alone/shot.####.png");
    ok_alone(&dir, &scene, &alone);
    let reference =
        |n: u32| std::fs::read(dir.path().join(format!("alone/shot.{n:04}.png"))).unwrap();
    assert_ne!(reference(1), reference(2));
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--frames-in-progress", "1"],
        &[],
    );
    // Frame 3 cannot be filed: a directory stands where its file goes.
    let seq_dir = c.data.join("jobs/1");
    std::fs::create_dir_all(seq_dir.join("shot.0003.png")).unwrap();
    let rt = runtime();
    let id = detach(&dir, &c, &scene, &["--tile", "16"]);
    assert_eq!(id, 1);
    let _w = worker_with(&dir, &c.url, "worker0", &[], &[]);
    let s = wait_state(&dir, &rt, &c, id, pb::JobState::Failed, 120);
    assert!(s.error.contains("frame 3"), "{s:?}");
    let frame = |n: u32| seq_dir.join(format!("shot.{n:04}.png"));
    assert_eq!(std::fs::read(frame(2)).unwrap(), reference(2));
    assert!(!frame(4).exists(), "frame 4 was never queued");

    // Retried: the frames not done (3, 4) are rendered, the done ones are
    // kept (frame 1, damaged on disk, stays damaged).
    std::fs::remove_dir(frame(3)).unwrap();
    std::fs::write(frame(1), b"kept").unwrap();
    let ids = id.to_string();
    refused(
        &dir,
        &c,
        &["requeue", &ids, "--frames", "0-2"],
        "not within job 1's frames 1-4",
    );
    ok(&dir, &c, &["retry", &ids]);
    let s = wait_state(&dir, &rt, &c, id, pb::JobState::Done, 120);
    assert_eq!(s.frames_done, 4, "{s:?}");
    assert_eq!(std::fs::read(frame(1)).unwrap(), b"kept");
    for n in 2..=4 {
        assert_eq!(
            std::fs::read(frame(n)).unwrap(),
            reference(n),
            "frame {n}\n{}",
            dir.logs()
        );
    }

    // Requeued: frame 1 is rendered again, its file replaced.
    ok(&dir, &c, &["requeue", &ids, "--frames", "1-1"]);
    let s = wait_state(&dir, &rt, &c, id, pb::JobState::Done, 120);
    assert_eq!(s.frames_done, 4, "{s:?}");
    for n in 1..=4 {
        assert_eq!(
            std::fs::read(frame(n)).unwrap(),
            reference(n),
            "frame {n}\n{}",
            dir.logs()
        );
    }

    // Hostile input.
    let hostile: [(&[&str], &str); 5] = [
        (&["--frames", "5-9"], "not within"),
        (&["--frames", "3-2"], "expected A-B"),
        (&["--frames", "1-99999999999"], "expected A-B"),
        (&[], "say which frames"),
        (
            &["--frames", "1-1", "--rect", "0,0,1,1"],
            "--rect patches a still",
        ),
    ];
    for (args, says) in hostile {
        refused(&dir, &c, &[&["requeue", &ids][..], args].concat(), says);
    }
    refused(&dir, &c, &["retry", &ids], "retry takes a failed job");
}

/// Renders the sequence with `trevi-submit` alone into `pattern`.
fn ok_alone(dir: &Dir, scene: &Path, pattern: &Path) {
    let o = submit(
        dir,
        &[
            scene.to_str().unwrap(),
            "-o",
            pattern.to_str().unwrap(),
            "--tile",
            "16",
            "-q",
        ],
    );
    assert!(o.status.success(), "{}", dir.logs());
}

#[test]
fn frames_of_a_running_sequence_are_queued_again() {
    let dir = Dir::new();
    let scene = dir.write("frames.xml", FRAMES);
    let alone = dir.path().join("alone/shot.####.png");
    ok_alone(&dir, &scene, &alone);
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--frames-in-progress", "1"],
        &[],
    );
    let rt = runtime();
    let id = detach(&dir, &c, &scene, &["--tile", "16"]);
    let ids = id.to_string();
    // Slow leases: frame 1 is done long before frame 4.
    let delay = [("TREVI_TEST_LEASE_DELAY_MS", "700")];
    let _w = worker_with(&dir, &c.url, "worker0", &["--tiles-in-flight", "1"], &delay);
    wait_for(&dir, "frame 1 done", 120, || {
        job(&rt, &c, id).frames_done >= 1
    });
    let frame1 = c.data.join(format!("jobs/{id}/shot.0001.png"));
    std::fs::write(&frame1, b"damaged").unwrap();
    refused(
        &dir,
        &c,
        &["requeue", &ids, "--frames", "4-4"],
        "rendering or queued already",
    );
    let s = job(&rt, &c, id);
    assert_ne!(s.state, pb::JobState::Done as i32, "too quick: {s:?}");
    ok(&dir, &c, &["requeue", &ids, "--frames", "1-1"]);
    let s = wait_state(&dir, &rt, &c, id, pb::JobState::Done, 120);
    assert_eq!(s.frames_done, 4, "{s:?}");
    for n in 1..=4u32 {
        let got = std::fs::read(c.data.join(format!("jobs/{id}/shot.{n:04}.png"))).unwrap();
        let want = std::fs::read(dir.path().join(format!("alone/shot.{n:04}.png"))).unwrap();
        assert!(got == want, "frame {n}\n{}", dir.logs());
    }
}
