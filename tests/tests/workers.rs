//! Workers and their leases, end to end with real processes: a tile that
//! kills every worker that takes it, a render that panics, cancel and
//! SIGTERM during a very expensive tile, leases held by tiles not being
//! rendered, and workers acting under each other's ids.

mod common;

use common::*;
use std::path::Path;
use std::time::{Duration, Instant};
use tonic::transport::Channel;
use tonic::Code;
use trevi_proto::pb::{self, jobs_client::JobsClient, workers_client::WorkersClient};

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

/// Submits `scene` without waiting; returns the job id.
fn detach(dir: &Dir, url: &str, scene: &Path, tile: &str, priority: &str) -> u64 {
    let o = submit(
        dir,
        &[
            scene.to_str().unwrap(),
            "--coordinator",
            url,
            "--detach",
            "--tile",
            tile,
            "--priority",
            priority,
        ],
    );
    assert!(o.status.success(), "{}", dir.logs());
    String::from_utf8_lossy(&o.stdout)
        .trim()
        .parse()
        .unwrap_or_else(|_| panic!("--detach printed {:?}", String::from_utf8_lossy(&o.stdout)))
}

fn job(rt: &tokio::runtime::Runtime, url: &str, id: u64) -> pb::JobStatus {
    rt.block_on(async {
        JobsClient::connect(url.to_string())
            .await
            .unwrap()
            .get_job(pb::JobId { id })
            .await
            .unwrap()
            .into_inner()
    })
}

fn cancel(rt: &tokio::runtime::Runtime, url: &str, id: u64) {
    rt.block_on(async {
        JobsClient::connect(url.to_string())
            .await
            .unwrap()
            .cancel_job(pb::JobId { id })
            .await
            .unwrap();
    });
}

/// Waits until job `id` is in `state`; returns its status.
fn wait_state(
    dir: &Dir,
    rt: &tokio::runtime::Runtime,
    url: &str,
    id: u64,
    state: pb::JobState,
    secs: u64,
) -> pb::JobStatus {
    let mut last = None;
    wait_for(dir, &format!("job {id} to be {state:?}"), secs, || {
        let s = job(rt, url, id);
        let hit = s.state == state as i32;
        last = Some(s);
        hit
    });
    last.unwrap()
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
    let id = detach(&dir, &c.url, &scene, "16", "0");
    let s = wait_state(&dir, &rt, &c.url, id, pb::JobState::Failed, 60);
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
    let id = detach(&dir, &c.url, &scene, "16", "0");
    let s = wait_state(&dir, &rt, &c.url, id, pb::JobState::Failed, 30);
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
    let next = detach(&dir, &c.url, &one, "16", "0");
    wait_state(&dir, &rt, &c.url, next, pb::JobState::Done, 20);
    let log = dir.read_log("panicky");
    assert_eq!(log.matches("registered").count(), 1, "{log}");
}

/// Waits until the job's single tile has been rendering a little while.
fn rendering(dir: &Dir, rt: &tokio::runtime::Runtime, url: &str, id: u64) {
    wait_state(dir, rt, url, id, pb::JobState::Running, 20);
    std::thread::sleep(Duration::from_millis(700));
    assert_eq!(
        job(rt, url, id).tiles_done,
        0,
        "the tile is not expensive enough"
    );
}

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
    let _w = worker_with(&dir, &c.url, "worker", &[], &[]);
    let rt = runtime();
    let id = detach(&dir, &c.url, &expensive, "64", "0");
    rendering(&dir, &rt, &c.url, id);
    let t0 = Instant::now();
    cancel(&rt, &c.url, id);
    wait_for(&dir, "the worker to stop rendering", 5, || {
        dir.read_log("worker").contains("render cancelled")
    });
    let stopped = t0.elapsed();
    assert!(
        stopped < Duration::from_millis(1500),
        "took {stopped:?}\n{}",
        dir.logs()
    );
    // The worker is free for the next job at once.
    let next = detach(&dir, &c.url, &one, "16", "0");
    let t1 = Instant::now();
    wait_state(&dir, &rt, &c.url, next, pb::JobState::Done, 20);
    assert!(
        t1.elapsed() < Duration::from_secs(5),
        "{:?}\n{}",
        t1.elapsed(),
        dir.logs()
    );
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
    let id = detach(&dir, &c.url, &expensive, "64", "0");
    rendering(&dir, &rt, &c.url, id);
    let t0 = Instant::now();
    let kill = std::process::Command::new("kill")
        .args(["-TERM", &w.0.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    let status = wait_child(&dir, &mut w.0, 10);
    let took = t0.elapsed();
    assert!(status.success(), "{status:?}\n{}", dir.logs());
    assert!(
        took < Duration::from_millis(1500),
        "took {took:?}\n{}",
        dir.logs()
    );
    wait_for(&dir, "the coordinator to re-queue the tile", 5, || {
        dir.read_log("coordinator")
            .contains("tile returned unrendered; re-queued")
    });
    // Another worker takes it now, not when the lease would have expired.
    let _w2 = worker_with(&dir, &c.url, "worker2", &[], &[]);
    wait_for(&dir, "the second worker to take the tile", 10, || {
        dir.read_log("worker2").contains("scene built")
    });
    cancel(&rt, &c.url, id);
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
    let _busy = worker_with(&dir, &c.url, "busy", &["--tiles-in-flight", "2"], &[]);
    let rt = runtime();
    let big = detach(&dir, &c.url, &expensive, "64", "1");
    rendering(&dir, &rt, &c.url, big);
    let small = detach(&dir, &c.url, &tiny, "16", "0");
    // Give the busy worker's other loop time to (wrongly) take a tile.
    std::thread::sleep(Duration::from_millis(1500));
    let _free = worker_with(&dir, &c.url, "free", &[], &[]);
    let t0 = Instant::now();
    wait_state(&dir, &rt, &c.url, small, pb::JobState::Done, 10);
    assert_eq!(
        job(&rt, &c.url, big).state,
        pb::JobState::Running as i32,
        "inconclusive: the expensive tile finished first ({:?})",
        t0.elapsed()
    );
    cancel(&rt, &c.url, big);
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
    let id = detach(&dir, &c.url, &scene, "16", "0");
    rt.block_on(async {
        let channel = Channel::from_shared(c.url.clone())
            .unwrap()
            .connect()
            .await
            .unwrap();
        let mut w = WorkersClient::new(channel);
        let register = |name: &str| pb::RegisterRequest {
            name: name.into(),
            threads: 1,
        };
        let a = w.register(register("a")).await.unwrap().into_inner();
        let b = w.register(register("b")).await.unwrap().into_inner();
        assert_eq!(a.session.len(), 32);
        assert_ne!(a.session, b.session);
        let lease = w
            .lease_tile(pb::LeaseRequest {
                worker_id: a.worker_id,
                session: a.session.clone(),
                ..Default::default()
            })
            .await
            .unwrap()
            .into_inner()
            .lease
            .expect("a tile for a");
        // b, knowing a's id (ids are sequential) but not its secret.
        for session in [b.session.clone(), Vec::new()] {
            let e = w
                .lease_tile(pb::LeaseRequest {
                    worker_id: a.worker_id,
                    session: session.clone(),
                    ..Default::default()
                })
                .await
                .unwrap_err();
            assert_eq!(e.code(), Code::PermissionDenied, "lease: {e:?}");
            let e = w
                .heartbeat(pb::HeartbeatRequest {
                    worker_id: a.worker_id,
                    lease_ids: vec![lease.lease_id],
                    session: session.clone(),
                })
                .await
                .unwrap_err();
            assert_eq!(e.code(), Code::PermissionDenied, "heartbeat: {e:?}");
            let e = w
                .return_tile(pb::TileReturn {
                    worker_id: a.worker_id,
                    session: session.clone(),
                    lease_id: lease.lease_id,
                    error: "forged".into(),
                })
                .await
                .unwrap_err();
            assert_eq!(e.code(), Code::PermissionDenied, "return: {e:?}");
            let rect: trevi_core::Rect = lease.rect.unwrap().into();
            let pixels = vec![[0.5f32; 3]; rect.pixel_count()];
            let msgs = vec![
                pb::TileUpload {
                    part: Some(pb::tile_upload::Part::Header(pb::TileHeader {
                        worker_id: a.worker_id,
                        lease_id: lease.lease_id,
                        job_id: id,
                        rect: lease.rect,
                        rays: 1,
                        session: session.clone(),
                    })),
                },
                pb::TileUpload {
                    part: Some(pb::tile_upload::Part::Pixels(trevi_proto::pixels_to_bytes(
                        &pixels,
                    ))),
                },
            ];
            let e = w.submit_tile(tokio_stream::iter(msgs)).await.unwrap_err();
            assert_eq!(e.code(), Code::PermissionDenied, "submit: {e:?}");
        }
        // a's lease is untouched and a, with its secret, may go on.
        let hb = w
            .heartbeat(pb::HeartbeatRequest {
                worker_id: a.worker_id,
                lease_ids: vec![lease.lease_id],
                session: a.session.clone(),
            })
            .await
            .unwrap()
            .into_inner();
        assert!(hb.dropped.is_empty(), "{:?}", hb.dropped);
    });
    let s = job(&rt, &c.url, id);
    assert_eq!(s.tiles_done, 0, "a forged result was taken");
}
