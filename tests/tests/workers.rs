//! Workers and their leases, end to end with real processes: a tile that
//! kills every worker that takes it, a render that panics, cancel and
//! SIGTERM during a very expensive tile, leases held by tiles not being
//! rendered, and workers acting under each other's ids.

mod common;

use common::fake_worker::grey;
use common::*;
use std::path::Path;
use std::time::Duration;
use tonic::Code;
use trevi_proto::pb;

/// One 64×64 tile that takes tens of seconds on one thread: SLOW_SCENE at
/// 2304 samples a pixel instead of 36.
fn expensive_scene() -> String {
    let from = r#"width="96" height="64" supersample="6""#;
    assert!(SLOW_SCENE.contains(from), "SLOW_SCENE changed");
    SLOW_SCENE.replace(from, r#"width="64" height="64" supersample="48""#)
}

/// A single 16×16 tile, quick.
const ONE_TILE: &str = r#"<scene version="1">
  <settings background="0.1 0.1 0.2" ambient="0.1 0.1 0.1"/>
  <sphere id="ball" center="0 1 0" radius="1"> <surface diffuse="0.8 0.3 0.2"/> </sphere>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1"/>
  <camera id="main" position="0 2 6" lookat="0 1 0" up="0 1 0" fov="50">
    <render width="16" height="16" output="one.png"/>
  </camera>
</scene>
"#;

/// Submits `scene` without waiting, in tiles of `tile` pixels; returns the
/// job id.
fn detach(dir: &Dir, c: &Coordinator, scene: &Path, tile: &str, priority: &str) -> u64 {
    common::detach(dir, c, scene, &["--tile", tile, "--priority", priority])
}

#[test]
fn a_tile_that_kills_every_worker_fails_its_job_naming_the_tile() {
    let dir = Dir::new();
    let scene = dir.write("scene/tiny.xml", &tiny_scene(0));
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--lease-ttl-ms", "1000"],
        &[],
    );
    // The renderer crashes the process (like a stack overflow) on the tile
    // at (16, 0) of the 24×20 frame; every worker that takes it dies.
    let abort = [("TREVI_TEST_ABORT_ON_TILE", "16,0")];
    let mut workers: Vec<Proc> = (0..3)
        .map(|i| worker_with(&dir, &c.url, &format!("crash{i}"), &[], &abort))
        .collect();
    let rt = runtime();
    let id = detach(&dir, &c, &scene, "16", "0");
    let s = wait_state(&dir, &rt, &c, id, pb::JobState::Failed, 60);
    assert!(
        s.error.contains("tile 1 (8x16 at (16, 0))")
            && s.error.contains("lost the worker rendering it 3 times"),
        "{}\n{}",
        s.error,
        dir.logs()
    );
    // It was the tile that killed them.
    for (i, w) in workers.iter_mut().enumerate() {
        let status = wait_child(&dir, &mut w.0, 10);
        assert!(!status.success(), "crash{i} exited normally");
        assert!(dir
            .read_log(&format!("crash{i}"))
            .contains("aborting on the tile at (16, 0)"));
    }
}

#[test]
fn a_panic_in_one_tile_is_reported_and_the_worker_lives_on() {
    let dir = Dir::new();
    let scene = dir.write("scene/tiny.xml", &tiny_scene(0));
    let one = dir.write("scene/one.xml", ONE_TILE);
    // Leases live long: only the worker's own report can fail the tile
    // within the test's time.
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--lease-ttl-ms", "60000", "--max-worker-failures", "10"],
        &[],
    );
    let panic = [("TREVI_TEST_PANIC_ON_TILE", "16,0")];
    let mut w = worker_with(&dir, &c.url, "panicky", &[], &panic);
    let rt = runtime();
    let id = detach(&dir, &c, &scene, "16", "0");
    let s = wait_state(&dir, &rt, &c, id, pb::JobState::Failed, 30);
    assert!(
        s.error.contains("tile 1 (8x16 at (16, 0)) failed 5 times")
            && s.error
                .contains("the render panicked: test fault: panic on the tile at (16, 0)"),
        "{}\n{}",
        s.error,
        dir.logs()
    );
    assert!(
        w.0.try_wait().unwrap().is_none(),
        "the worker died\n{}",
        dir.logs()
    );
    // Still the same registration, and still working.
    submit_and_wait(
        &dir,
        &rt,
        &c,
        &one,
        &["--tile", "16", "--priority", "0"],
        20,
    );
    let log = dir.read_log("panicky");
    assert_eq!(log.matches("registered").count(), 1, "{log}");
}

/// Waits until worker `name` (process `w`) is rendering the job's single
/// tile: the job runs, the worker has built its scene, and it has spent a
/// little CPU time since (a state, not a time: a busy machine only makes
/// the wait longer).
fn rendering(
    dir: &Dir,
    rt: &tokio::runtime::Runtime,
    c: &Coordinator,
    id: u64,
    w: &Proc,
    name: &str,
) {
    wait_state(dir, rt, c, id, pb::JobState::Running, 60);
    wait_for(dir, "the worker to build the scene", 60, || {
        dir.read_log(name).contains("scene built")
    });
    let built = cpu_time(w.0.id());
    wait_for(dir, "the worker to spend CPU on the tile", 120, || {
        cpu_time(w.0.id()) >= built + Duration::from_millis(300)
    });
    assert_eq!(
        job(rt, c, id).tiles_done,
        0,
        "the tile is not expensive enough"
    );
}

/// What "within a second" means on a busy machine: the worker's CPU time
/// between the request and the stop (one render thread and the threads
/// that talk to the coordinator). On a quiet machine that is about the
/// wall-clock time; a busy one stretches the wall-clock time, not this.
const STOP_CPU: Duration = Duration::from_millis(1500);

#[test]
fn cancel_stops_a_tile_in_progress_within_a_second() {
    let dir = Dir::new();
    let expensive = dir.write("scene/expensive.xml", &expensive_scene());
    let one = dir.write("scene/one.xml", ONE_TILE);
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--lease-ttl-ms", "10000"],
        &[],
    );
    let w = worker_with(&dir, &c.url, "worker", &[], &[]);
    let rt = runtime();
    let id = detach(&dir, &c, &expensive, "64", "0");
    rendering(&dir, &rt, &c, id, &w, "worker");
    let cpu0 = cpu_time(w.0.id());
    cancel(&rt, &c, id);
    wait_for(&dir, "the worker to stop rendering", 60, || {
        dir.read_log("worker").contains("render cancelled")
    });
    let spent = cpu_time(w.0.id()) - cpu0;
    assert!(
        spent < STOP_CPU,
        "{spent:?} of CPU between the cancel and the stop\n{}",
        dir.logs()
    );
    // The worker is free for the next job at once: its single render
    // thread is no longer on the cancelled tile.
    let next = detach(&dir, &c, &one, "16", "0");
    wait_state(&dir, &rt, &c, next, pb::JobState::Done, 60);
    assert_eq!(job(&rt, &c, id).tiles_done, 0, "{}", dir.logs());
}

#[test]
fn sigterm_stops_a_worker_within_a_second_and_gives_its_tile_back() {
    let dir = Dir::new();
    let expensive = dir.write("scene/expensive.xml", &expensive_scene());
    // Leases live long: the tile comes back at once only if it is given back.
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--lease-ttl-ms", "60000"],
        &[],
    );
    let mut w = worker_with(&dir, &c.url, "worker", &[], &[]);
    let rt = runtime();
    let id = detach(&dir, &c, &expensive, "64", "0");
    rendering(&dir, &rt, &c, id, &w, "worker");
    let pid = w.0.id();
    let cpu0 = cpu_time(pid);
    signal(&w, "TERM");
    // Its CPU time is read once it has exited, before it is reaped.
    wait_for(&dir, "the worker to exit", 60, || exited(pid));
    let spent = cpu_time(pid) - cpu0;
    let status = wait_child(&dir, &mut w.0, 10);
    assert!(status.success(), "{status:?}\n{}", dir.logs());
    assert!(
        spent < STOP_CPU,
        "{spent:?} of CPU between SIGTERM and the exit\n{}",
        dir.logs()
    );
    // Well before the 60-second lease would have expired.
    wait_for(&dir, "the coordinator to re-queue the tile", 20, || {
        dir.read_log("coordinator")
            .contains("tile returned unrendered; re-queued")
    });
    // Another worker takes it now, not when the lease would have expired.
    let _w2 = worker_with(&dir, &c.url, "worker2", &[], &[]);
    wait_for(&dir, "the second worker to take the tile", 10, || {
        dir.read_log("worker2").contains("scene built")
    });
    cancel(&rt, &c, id);
}

#[test]
fn a_lease_is_held_only_by_a_tile_being_rendered() {
    // One worker is busy with a very expensive tile. A second job's tiles
    // must go to the worker that is free, not sit leased (and heartbeated)
    // by the busy one until its tile is done.
    let dir = Dir::new();
    let expensive = dir.write("scene/expensive.xml", &expensive_scene());
    let tiny = dir.write("scene/tiny.xml", &tiny_scene(1));
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--lease-ttl-ms", "10000"],
        &[],
    );
    let busy = worker_with(&dir, &c.url, "busy", &["--tiles-in-flight", "2"], &[]);
    let rt = runtime();
    let big = detach(&dir, &c, &expensive, "64", "1");
    rendering(&dir, &rt, &c, big, &busy, "busy");
    let small = detach(&dir, &c, &tiny, "16", "0");
    // Give the busy worker's other loop time to (wrongly) take a tile.
    std::thread::sleep(Duration::from_millis(1500));
    let _free = worker_with(&dir, &c.url, "free", &[], &[]);
    wait_state(&dir, &rt, &c, small, pb::JobState::Done, 60);
    assert_eq!(
        job(&rt, &c, big).state,
        pb::JobState::Running as i32,
        "inconclusive: the expensive tile finished first"
    );
    cancel(&rt, &c, big);
}

#[test]
fn a_worker_cannot_act_under_another_workers_id() {
    let dir = Dir::new();
    let scene = dir.write("scene/tiny.xml", &tiny_scene(2));
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--lease-ttl-ms", "60000"],
        &[],
    );
    let rt = runtime();
    let id = detach(&dir, &c, &scene, "16", "0");
    rt.block_on(async {
        let client = workers(&c, None).await;
        let mut a = FakeWorker::register(&client, "a").await;
        let mut b = FakeWorker::register(&client, "b").await;
        assert_eq!(a.session.len(), 32);
        assert_ne!(a.session, b.session);
        let lease = a.try_lease().await.expect("a tile for a");
        // b, knowing a's id (ids are sequential) but not its secret.
        for session in [b.session.clone(), Vec::new()] {
            let w = &mut b.client;
            let e = w
                .lease_tile(pb::LeaseRequest {
                    worker_id: a.id,
                    session: session.clone(),
                    ..Default::default()
                })
                .await
                .unwrap_err();
            assert_eq!(e.code(), Code::PermissionDenied, "lease: {e:?}");
            let e = w
                .heartbeat(pb::HeartbeatRequest {
                    worker_id: a.id,
                    lease_ids: vec![lease.lease_id],
                    session: session.clone(),
                    ..Default::default()
                })
                .await
                .unwrap_err();
            assert_eq!(e.code(), Code::PermissionDenied, "heartbeat: {e:?}");
            let e = w
                .return_tile(pb::TileReturn {
                    worker_id: a.id,
                    session: session.clone(),
                    lease_id: lease.lease_id,
                    error: "forged".into(),
                    ..Default::default()
                })
                .await
                .unwrap_err();
            assert_eq!(e.code(), Code::PermissionDenied, "return: {e:?}");
            let rect: trevi_core::Rect = lease.rect.unwrap().into();
            let forged = pb::TileHeader {
                job_id: id,
                session: session.clone(),
                ..a.header(&lease)
            };
            let e = b
                .send(forged, vec![grey(rect.pixel_count())])
                .await
                .unwrap_err();
            assert_eq!(e.code(), Code::PermissionDenied, "submit: {e:?}");
        }
        // a's lease is untouched and a, with its secret, may go on.
        let hb = a
            .client
            .heartbeat(pb::HeartbeatRequest {
                worker_id: a.id,
                lease_ids: vec![lease.lease_id],
                session: a.session.clone(),
                ..Default::default()
            })
            .await
            .unwrap()
            .into_inner();
        assert!(hb.dropped.is_empty(), "{:?}", hb.dropped);
    });
    let s = job(&rt, &c, id);
    assert_eq!(s.tiles_done, 0, "a forged result was taken");
}

/// The kernel's scheduling policy and nice value of each of process
/// `pid`'s threads named `trevi-render-*` (fields 41 and 19 of
/// /proc/PID/task/TID/stat).
#[cfg(target_os = "linux")]
fn render_threads(pid: u32) -> Vec<(i64, i64)> {
    let mut out = Vec::new();
    for task in std::fs::read_dir(format!("/proc/{pid}/task")).unwrap() {
        let task = task.unwrap().path();
        let comm = std::fs::read_to_string(task.join("comm")).unwrap_or_default();
        if !comm.starts_with("trevi-render-") {
            continue;
        }
        let stat = std::fs::read_to_string(task.join("stat")).unwrap();
        let f: Vec<&str> = stat[stat.rfind(')').unwrap() + 2..].split(' ').collect();
        out.push((f[41 - 3].parse().unwrap(), f[19 - 3].parse().unwrap()));
    }
    out
}

/// A worker on a spare machine renders only with CPU time nobody else
/// wants: its render threads run under SCHED_IDLE (5) by default; with
/// `--priority normal` (dedicated nodes) they keep the default policy (0)
/// and the nice value the worker started with.
#[cfg(target_os = "linux")]
#[test]
fn render_threads_run_at_idle_priority_unless_asked_for_normal() {
    let dir = Dir::new();
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    // No flag and no TREVI_PRIORITY: the worker's default.
    let idle = worker_with(&dir, &c.url, "idle", &[], &[("TREVI_PRIORITY", "")]);
    let normal = worker_with(
        &dir,
        &c.url,
        "normal",
        &["--priority", "normal"],
        &[("TREVI_PRIORITY", "")],
    );
    for name in ["idle", "normal"] {
        wait_for(
            &dir,
            &format!("worker {name} to start its render threads"),
            20,
            || dir.read_log(name).contains("render threads at"),
        );
    }
    assert!(
        dir.read_log("idle").contains("idle priority (SCHED_IDLE)"),
        "{}",
        dir.logs()
    );
    let threads = render_threads(idle.0.id());
    assert_eq!(threads.len(), 1, "{}", dir.logs());
    for (policy, _) in threads {
        assert_eq!(policy, 5, "SCHED_IDLE\n{}", dir.logs());
    }
    // The nice value the worker started with (this test's own: `nice cargo
    // test` starts everything at 10), not lowered.
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap();
    let own_nice: i64 = stat[stat.rfind(')').unwrap() + 2..]
        .split(' ')
        .nth(19 - 3)
        .unwrap()
        .parse()
        .unwrap();
    let threads = render_threads(normal.0.id());
    assert_eq!(threads.len(), 1, "{}", dir.logs());
    for t in threads {
        assert_eq!(
            t,
            (0, own_nice),
            "SCHED_OTHER at the nice value it started with\n{}",
            dir.logs()
        );
    }
    // The flag's name, and the old one (a hidden alias), both name the
    // flag in the refusal.
    for flag in ["--cpu-priority", "--priority"] {
        let o = std::process::Command::new(common::bin("trevi-worker"))
            .args(["--coordinator", &c.url, flag, "low"])
            .env_clear()
            .output()
            .unwrap();
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains("--cpu-priority") && err.contains("idle or normal"),
            "{err}"
        );
    }
}
