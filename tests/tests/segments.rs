//! The segment path end to end: real `trevi-worker`s encode their leases'
//! PNG segments (`Lease.png_segments`), the coordinator only appends them,
//! and the file is byte for byte what `trevi-submit` writes alone; also
//! after the coordinator is killed (SIGKILL) mid-frame and restarted on the
//! same data directory, and a worker is killed. The coordinator's
//! `trevi_png_segments_total` (segments it took encoded from workers)
//! proves the segment path ran.

mod common;

use common::http::get;
use common::*;
use trevi_proto::pb;

/// A frame of `width` × `height` of the slow scene, its ambient occlusion
/// at `ao` samples.
fn scene(width: u32, height: u32, ao: u32) -> String {
    SLOW_SCENE
        .replace(
            r#"width="96" height="64""#,
            &format!(r#"width="{width}" height="{height}""#),
        )
        .replace(r#"ao-samples="16""#, &format!(r#"ao-samples="{ao}""#))
}

/// 120×168: tiles of 16 leave an 8-pixel column on the right and an
/// 8-row band at the bottom, so the last segment is short (the rect of a
/// segment lease ends at the frame's bottom there). About 0.7 s on one
/// thread.
const SMALL: (u32, u32) = (120, 168);
/// For the kill test: 240×336 (the same short last segment) at 64 AO
/// samples, about 8 s on one thread, so that the coordinator's kill after
/// the first segments lands mid-frame, and so does the worker's after the
/// restart (at 0.7 s the frame ended before the first poll saw a segment).
const KILLED: (u32, u32) = (240, 336);

/// 16-row segments of a frame (the last one may be short).
fn segments((_, h): (u32, u32)) -> u64 {
    h.div_ceil(16).into()
}

/// Tiles of 16 of a frame.
fn tiles((w, h): (u32, u32)) -> u64 {
    (w.div_ceil(16) * h.div_ceil(16)).into()
}

/// The coordinator's `trevi_png_segments_total` (summed over its label
/// sets, if any); `None` when /metrics does not have it.
fn segments_taken(c: &Coordinator) -> Option<f64> {
    let (code, text) = get(c.http.as_deref().unwrap(), "/metrics", None);
    assert_eq!(code, 200, "{text}");
    let values: Vec<f64> = text
        .lines()
        .filter(|l| {
            l.strip_prefix("trevi_png_segments_total")
                .is_some_and(|rest| rest.starts_with(' ') || rest.starts_with('{'))
        })
        .filter_map(|l| l.rsplit(' ').next()?.parse().ok())
        .collect();
    (!values.is_empty()).then(|| values.iter().sum())
}

fn start_coordinator(dir: &Dir, addr: &str, name: &str) -> Coordinator {
    // A short lease life, so that the killed worker's leases come back soon.
    coordinator_with(
        dir,
        addr,
        name,
        // Leases of 50 ms (a band or two): one-second leases would bring
        // most of this small frame at once, and the kill would not land
        // mid-frame.
        &[
            "--http",
            "127.0.0.1:0",
            "--lease-ttl-ms",
            "3000",
            "--lease-target-ms",
            "50",
        ],
        &[],
    )
}

#[test]
fn workers_encode_segments_and_the_file_is_trevi_submits() {
    let dir = Dir::new();
    let scene = dir.write("s.xml", &scene(SMALL.0, SMALL.1, 16));
    let expected = embedded(&dir, &scene, "embedded.png");
    let c = start_coordinator(&dir, "127.0.0.1:0", "coordinator");
    let workers: Vec<Proc> = (0..3)
        .map(|i| worker_with(&dir, &c.url, &format!("worker{i}"), &[], &[]))
        .collect();
    let got = farm_render(&dir, &c.url, &scene, "farm.png", 16);
    assert!(
        got == expected,
        "the farm's PNG differs from trevi-submit alone\n{}",
        dir.logs()
    );
    let taken = segments_taken(&c);
    // Every segment is taken once at most (no fault here), and the ones
    // not taken encoded came as floats (the first leases of a job, before
    // its cost is measured, are single tiles).
    let most = segments(SMALL);
    assert!(
        taken.is_some_and(|n| n > 0.0 && n <= most as f64),
        "trevi_png_segments_total is {taken:?}, not 1 ..= {most}: the segment path did not run\n{}",
        dir.logs()
    );
    drop(workers);
}

#[test]
fn a_coordinator_killed_mid_frame_and_a_worker_killed_change_no_byte() {
    let dir = Dir::new();
    let scene = dir.write("s.xml", &scene(KILLED.0, KILLED.1, 64));
    let expected = embedded(&dir, &scene, "embedded.png");
    let mut c = start_coordinator(&dir, "127.0.0.1:0", "coordinator0");
    let (url, addr) = (c.url.clone(), c.addr.clone());
    let mut workers: Vec<Option<Proc>> = (0..3)
        .map(|i| Some(worker_with(&dir, &url, &format!("worker{i}"), &[], &[])))
        .collect();
    let out = dir.path().join("farm.png");
    let mut sub = spawn_farm_submit(&dir, &url, &scene, &out, 16);
    let rt = runtime();

    // Some segments taken, the frame not finished: kill the coordinator.
    let mut ended = false;
    wait_for(&dir, "segments taken or the job's end", 120, || {
        ended = try_job(&rt, &c, 1).is_some_and(|s| s.state == pb::JobState::Done as i32);
        ended || segments_taken(&c).is_some_and(|n| n >= 1.0)
    });
    let before = try_job(&rt, &c, 1).expect("the job");
    assert!(
        !ended && before.tiles_done < before.tiles_total,
        "the frame ended before the kill ({:?} segments taken): {}\n{}",
        segments_taken(&c),
        if segments_taken(&c).is_some_and(|n| n >= 1.0) {
            "make the scene slower"
        } else {
            "the segment path did not run"
        },
        dir.logs()
    );
    assert_eq!(before.tiles_total, tiles(KILLED));
    drop(c); // SIGKILL
    c = start_coordinator(&dir, &addr, "coordinator1");
    let resumed = try_job(&rt, &c, 1).expect("the job survived the restart");
    assert!(
        resumed.tiles_done >= before.tiles_done,
        "{resumed:?} after {before:?}\n{}",
        dir.logs()
    );

    // Once the restarted coordinator has taken work again and the third
    // worker has registered with it, kill that worker (SIGKILL: its leases
    // come back when they run out).
    wait_for(&dir, "work on the restarted coordinator", 120, || {
        dir.read_log("worker2").matches("registered").count() >= 2
            && try_job(&rt, &c, 1).is_some_and(|s| s.tiles_done > resumed.tiles_done)
    });
    let s = try_job(&rt, &c, 1).unwrap();
    assert!(
        s.tiles_done < s.tiles_total,
        "the frame ended before the worker was killed; make the scene slower\n{}",
        dir.logs()
    );
    drop(workers[2].take());

    let status = wait_child(&dir, &mut sub, 180);
    assert!(status.success(), "submit failed\n{}", dir.logs());
    assert!(
        std::fs::read(&out).unwrap() == expected,
        "the farm's PNG differs from trevi-submit alone after the kills\n{}",
        dir.logs()
    );
    let s = try_job(&rt, &c, 1).unwrap();
    assert_eq!(s.state, pb::JobState::Done as i32);
    assert_eq!(s.tiles_done, tiles(KILLED));

    // The stored output survives one more restart, the same bytes.
    drop(c);
    let c = start_coordinator(&dir, &addr, "coordinator2");
    let again = rt.block_on(download(&c, 1, None));
    assert!(again == expected, "{}", dir.logs());
    drop(workers);
}
