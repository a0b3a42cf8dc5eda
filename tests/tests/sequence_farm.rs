//! Sequences on the farm, end to end with real processes: a 24-frame
//! animated scene (a box turning and moving, the camera rising) submitted
//! to a coordinator with three workers; one worker is killed and the
//! coordinator is killed (SIGKILL) and restarted on the same data directory
//! mid-sequence. Every frame must be byte-identical to the same frame
//! rendered by `trevi-submit` alone, no frame or stored tile may be lost
//! (the restarted coordinator still counts the frames done, and the
//! workers render few tiles twice), and the finished sequence is listed as
//! one job and can be fetched again later.

mod common;

use common::*;
use trevi_proto::pb;

const WORKERS: usize = 3;
const FRAMES: u64 = 24;
/// 64×48 in tiles of 16.
const TILES_PER_FRAME: u64 = 4 * 3;
/// The most a lease of several tiles covers: spans run over whole bands
/// while they are wholly pending, so a lease may be a whole frame (three
/// bands of four tiles): once one frame is measured, every other frame
/// starts from its cost, so even a frame's first lease can be that big.
const MOST_PER_LEASE: usize = TILES_PER_FRAME as usize;

/// Soft shadows and ambient occlusion (random samples, so the frame
/// number in the sample seed shows), slow enough that the kills land
/// mid-sequence.
fn animated() -> String {
    r#"<scene version="1">
  <settings background="0.1 0.1 0.2" ambient="0.2 0.2 0.2"/>
  <mesh id="box">
    <vertices>-1 -1 -1  1 -1 -1  1 1 -1  -1 1 -1  -1 -1 1  1 -1 1  1 1 1  -1 1 1</vertices>
    <triangles>0 2 1 0 3 2 4 5 6 4 6 7 0 1 5 0 5 4 3 6 2 3 7 6 0 4 7 0 7 3 1 2 6 1 6 5</triangles>
  </mesh>
  <plane id="ground" point="0 -1 0" normal="0 1 0"> <surface diffuse="0.5 0.5 0.5"/> </plane>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1" radius="0.5"/>
  <model id="m" mesh="box">
    <transform><scale v="0.7"/></transform>
    <animate channel="rotate" times="0 2" values="0 1 0 0  0 1 0 180"/>
    <animate channel="translate" times="0 2" values="-1 0 0  1 0 0"/>
  </model>
  <camera id="c" position="0 1 6" lookat="0 0 0" fov="45">
    <animate channel="position" times="0 2" values="0 1 6  1 3 5"/>
    <render width="64" height="48" supersample="4" shadow-samples="8" ao-samples="8"
            frames="1-24" fps="12" output="shot.####.png"/>
  </camera>
</scene>
"#
    .to_string()
}

fn frame(dir: &Dir, sub: &str, n: u64) -> Vec<u8> {
    let p = dir.path().join(format!("{sub}/shot.{n:04}.png"));
    std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}\n{}", p.display(), dir.logs()))
}

#[test]
fn a_sequence_survives_a_worker_and_the_coordinator_killed_mid_way_byte_for_byte() {
    let dir = Dir::new();
    let scene = dir.write("anim.xml", &animated());
    // The reference: every frame rendered by trevi-submit alone.
    let reference = dir.path().join("alone/shot.####.png");
    let o = submit(
        &dir,
        &[
            scene.to_str().unwrap(),
            "-o",
            reference.to_str().unwrap(),
            "--tile",
            "16",
            "-q",
        ],
    );
    assert!(o.status.success(), "{}", dir.logs());
    assert_ne!(frame(&dir, "alone", 1), frame(&dir, "alone", 2));

    let mut c = coordinator_with(&dir, "127.0.0.1:0", "coordinator0", &[], &[]);
    let (url, addr) = (c.url.clone(), c.addr.clone());
    let mut workers: Vec<Option<Proc>> = (0..WORKERS)
        .map(|i| {
            Some(worker_with(
                &dir,
                &url,
                &format!("worker{i}"),
                &["--tiles-in-flight", "1"],
                &[],
            ))
        })
        .collect();
    let out = dir.path().join("farm/shot.####.png");
    let mut sub = spawn_farm_submit(&dir, &url, &scene, &out, 16);
    let rt = runtime();
    let seq = 1;
    wait_for(&dir, "3 frames done", 120, || {
        try_job(&rt, &c, seq).is_some_and(|s| s.frames_done >= 3)
    });
    let s = try_job(&rt, &c, seq).unwrap();
    assert_eq!(s.frames, Some(pb::FrameRange { first: 1, last: 24 }));
    assert_eq!(s.tiles_total, FRAMES * TILES_PER_FRAME);
    assert!(s.frames_in_progress <= 2, "{s:?}");
    workers[0] = None; // SIGKILL, holding a lease or about to.

    wait_for(&dir, "8 frames done", 120, || {
        try_job(&rt, &c, seq).is_some_and(|s| s.frames_done >= 8)
    });
    let before = try_job(&rt, &c, seq).unwrap();
    assert!(
        (before.frames_done as u64) < FRAMES,
        "the sequence ended before the coordinator was killed; make the scene slower\n{}",
        dir.logs()
    );
    drop(c); // SIGKILL
    c = coordinator_with(&dir, &addr, "coordinator1", &[], &[]);
    let after = try_job(&rt, &c, seq).expect("the sequence survived the restart");
    assert!(
        after.frames_done >= before.frames_done,
        "frames lost in the restart: {before:?} -> {after:?}\n{}",
        dir.logs()
    );
    assert!(
        after.tiles_done >= before.tiles_done,
        "tiles lost in the restart: {before:?} -> {after:?}\n{}",
        dir.logs()
    );

    let status = wait_child(&dir, &mut sub, 240);
    assert!(status.success(), "submit failed\n{}", dir.logs());
    for n in 1..=FRAMES {
        assert!(
            frame(&dir, "farm", n) == frame(&dir, "alone", n),
            "frame {n} differs from trevi-submit alone\n{}",
            dir.logs()
        );
    }
    let s = try_job(&rt, &c, seq).unwrap();
    assert_eq!(s.state, pb::JobState::Done as i32, "{s:?}");
    assert_eq!(s.frames_done as u64, FRAMES);
    assert_eq!(s.tiles_done, FRAMES * TILES_PER_FRAME);
    // Finished tiles are not rendered again: only what the killed worker
    // held and what each worker had in flight at the coordinator's kill.
    let n = tiles_rendered(&dir, WORKERS);
    let total = (FRAMES * TILES_PER_FRAME) as usize;
    let bound = total + (1 + WORKERS) * MOST_PER_LEASE;
    assert!(
        n <= bound,
        "rendered {n} tiles for {total}, more than {bound}\n{}",
        dir.logs()
    );

    // Listed as one job (its frames are not), and fetched again later.
    let o = submit(&dir, &["list", "--coordinator", &c.url]);
    let list = String::from_utf8_lossy(&o.stdout).into_owned();
    assert_eq!(list.lines().count(), 1, "{list}");
    assert!(list.contains("frames 1-24: 24 done"), "{list}");
    let o = submit(
        &dir,
        &[
            "fetch",
            "1",
            "--coordinator",
            &c.url,
            "-o",
            dir.path().join("fetched").to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "fetch failed\n{}", dir.logs());
    for n in 1..=FRAMES {
        assert!(
            frame(&dir, "fetched", n) == frame(&dir, "alone", n),
            "fetched frame {n} differs"
        );
    }
}

/// Cancelling a sequence stops it: its frames in progress are dropped, it
/// is listed as cancelled, and the workers take no more of its tiles.
#[test]
fn a_cancelled_sequence_stops() {
    let dir = Dir::new();
    let scene = dir.write("anim.xml", &animated());
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let _w = worker_with(&dir, &c.url, "worker0", &[], &[]);
    let id = detach(&dir, &c, &scene, &["--priority", "3"]);
    let rt = runtime();
    wait_for(&dir, "a frame done", 120, || {
        try_job(&rt, &c, id).is_some_and(|s| s.frames_done >= 1)
    });
    let s = try_job(&rt, &c, id).unwrap();
    assert_eq!(s.priority, 3);
    cancel(&rt, &c, id);
    let s = wait_state(&dir, &rt, &c, id, pb::JobState::Cancelled, 30);
    assert!((s.frames_done as u64) < FRAMES, "{s:?}");
    let o = submit(&dir, &["status", &id.to_string(), "--coordinator", &c.url]);
    assert!(
        String::from_utf8_lossy(&o.stdout).contains("cancelled"),
        "{}",
        dir.logs()
    );
}
