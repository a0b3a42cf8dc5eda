//! Workers on spare machines, end to end with real processes: a worker
//! that steps aside while its machine is busy (its tiles are finished by
//! another worker, the image is the local render's, and it comes back when
//! the machine is quiet again), and a worker that keeps to its hours. The
//! busy machine's load is made up by the test, so that the machine running
//! the test may be as busy as it likes.

mod common;

use common::farm::job;
use common::http::{get, monitor_worker};
use common::*;
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use trevi_proto::pb;

/// SLOW_SCENE at 576 samples a pixel: a few seconds on one thread in tiles
/// of 16, so the spare worker is still at it when the machine turns busy.
fn long_scene() -> String {
    let from = r#"supersample="6""#;
    assert!(SLOW_SCENE.contains(from), "SLOW_SCENE changed");
    SLOW_SCENE.replace(from, r#"supersample="24""#)
}

/// Minutes after local midnight, as `date` tells.
fn local_minute() -> u32 {
    let o = Command::new("date").arg("+%H %M").output().unwrap();
    let t = String::from_utf8(o.stdout).unwrap();
    let (h, m) = t.trim().split_once(' ').unwrap();
    h.parse::<u32>().unwrap() * 60 + m.parse::<u32>().unwrap()
}

/// The machine's load as the spare worker sees it: a file in
/// `/proc/stat`'s format (the worker reads it in place of `/proc/stat`,
/// `TREVI_TEST_PROC_STAT`) for a machine of [`FAKE_CORES`] cores, whose
/// counters a thread advances with the real time, every core busy while
/// [`FakeLoad::busy`] is set and idle otherwise. Whatever else the machine
/// running the test is doing (a busy CI machine, two CPU hogs), the worker
/// sees exactly the load the test decides. Stops when dropped.
struct FakeLoad {
    path: std::path::PathBuf,
    busy: Arc<AtomicBool>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

/// Cores of the made-up machine: far more than the worker's own threads, so
/// its own CPU time (left out of the load) never brings "all busy" below
/// the threshold, nor raises "all idle" above it.
const FAKE_CORES: u64 = 64;

impl FakeLoad {
    fn new(dir: &Dir) -> FakeLoad {
        let path = dir.path().join("proc-stat");
        let busy = Arc::new(AtomicBool::new(false));
        let stop = Arc::new(AtomicBool::new(false));
        let write = |path: &std::path::Path, user: u64, idle: u64| {
            let per_core = |v: u64| v / FAKE_CORES;
            let mut text = format!("cpu  {user} 0 0 {idle} 0 0 0 0 0 0\n");
            for i in 0..FAKE_CORES {
                text += &format!(
                    "cpu{i} {} 0 0 {} 0 0 0 0 0 0\n",
                    per_core(user),
                    per_core(idle)
                );
            }
            // Whole or not at all: written beside, then renamed over.
            let tmp = path.with_extension("tmp");
            std::fs::write(&tmp, text).unwrap();
            std::fs::rename(&tmp, path).unwrap();
        };
        write(&path, 0, 0);
        let thread = {
            let (path, busy, stop) = (path.clone(), busy.clone(), stop.clone());
            std::thread::spawn(move || {
                // Clock ticks (100 a second) of every core since the start.
                let (mut user, mut idle) = (0u64, 0u64);
                let mut last = Instant::now();
                while !stop.load(Ordering::Relaxed) {
                    std::thread::sleep(Duration::from_millis(20));
                    let now = Instant::now();
                    let ticks = ((now - last).as_secs_f64() * 100.0) as u64 * FAKE_CORES;
                    if ticks == 0 {
                        continue;
                    }
                    last = now;
                    if busy.load(Ordering::Relaxed) {
                        user += ticks;
                    } else {
                        idle += ticks;
                    }
                    write(&path, user, idle);
                }
            })
        };
        FakeLoad {
            path,
            busy,
            stop,
            thread: Some(thread),
        }
    }

    fn set_busy(&self, busy: bool) {
        self.busy.store(busy, Ordering::Relaxed);
    }
}

impl Drop for FakeLoad {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The `trevi_worker_paused` line of worker `name` on `/metrics`, if any.
fn paused_line(c: &Coordinator, name: &str) -> Option<String> {
    let (code, text) = get(c.http.as_deref().unwrap(), "/metrics", None);
    assert_eq!(code, 200, "{text}");
    text.lines()
        .find(|l| l.starts_with("trevi_worker_paused{") && l.contains(&format!("name=\"{name}\"")))
        .map(str::to_string)
}

/// The worker `name`'s state on the monitor's `/api/state`.
fn monitor_state(c: &Coordinator, name: &str) -> (String, Option<String>) {
    let w = monitor_worker(c, name);
    (
        w["state"].as_str().unwrap().to_string(),
        w["paused"].as_str().map(str::to_string),
    )
}

#[test]
fn a_busy_machine_hands_its_tiles_to_another_worker_and_comes_back_when_quiet() {
    let dir = Dir::new();
    let scene = dir.write("scene/long.xml", &long_scene());
    let want = embedded(&dir, &scene, "local.png");
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--http", "127.0.0.1:0"],
        &[],
    );
    // Busy means most of the (made-up) machine's cores taken by other
    // programs.
    let load = FakeLoad::new(&dir);
    let threshold = format!("{}", FAKE_CORES / 2);
    let spare = worker_with(
        &dir,
        &c.url,
        "spare",
        &[
            "--yield-when-busy",
            "--busy-threshold",
            &threshold,
            "--busy-for-ms",
            "1000",
            "--quiet-for-ms",
            "1000",
            "--sample-ms",
            "200",
        ],
        &[
            ("TREVI_PRIORITY", ""),
            ("TREVI_TEST_PROC_STAT", load.path.to_str().unwrap()),
        ],
    );
    let rt = runtime();
    let id = detach(&dir, &c, &scene, &["--tile", "16"]);
    wait_for(&dir, "the spare worker's first tile", 120, || {
        job(&rt, &c, id).tiles_done >= 1
    });
    let total = job(&rt, &c, id).tiles_total;
    load.set_busy(true);
    wait_for(&dir, "the spare worker to pause", 120, || {
        dir.read_log("spare").contains("paused (busy")
    });
    wait_for(&dir, "/metrics to show the pause", 60, || {
        paused_line(&c, "spare").is_some_and(|l| l.contains("reason=\"busy\""))
    });
    assert_eq!(
        monitor_state(&c, "spare"),
        ("paused".to_string(), Some("busy".to_string()))
    );
    // A paused worker holds nothing and takes nothing: the job is finished
    // by a worker that stays.
    let done_by_spare = job(&rt, &c, id).tiles_done;
    let _other = worker_with(&dir, &c.url, "other", &[], &[]);
    let s = wait_state(&dir, &rt, &c, id, pb::JobState::Done, 180);
    assert_eq!(s.tiles_done, total);
    assert!(done_by_spare < total, "{}", dir.logs());
    let got = rt.block_on(download(&c, id, None));
    assert!(
        got == want,
        "the farm's image differs from the local render"
    );
    // The other programs end: the machine is quiet again and the worker
    // comes back.
    load.set_busy(false);
    wait_for(&dir, "the spare worker to resume", 120, || {
        dir.read_log("spare")
            .contains("resumed: the machine has been quiet")
    });
    wait_for(&dir, "/metrics to drop the pause", 60, || {
        paused_line(&c, "spare").is_none() && monitor_state(&c, "spare").0 == "idle"
    });
    drop(spare);
}

#[test]
fn outside_its_hours_a_worker_takes_nothing_and_says_why() {
    let dir = Dir::new();
    let scene = dir.write("scene/tiny.xml", &tiny_scene(3));
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--http", "127.0.0.1:0"],
        &[],
    );
    // Hours that exclude the present minute, whatever the time zone: the
    // minute after now's until now's.
    let now = local_minute();
    let hm = |m: u32| format!("{:02}:{:02}", m / 60, m % 60);
    let hours = format!("{}-{}", hm((now + 2) % 1440), hm((now + 1439) % 1440));
    let _night = worker_with(&dir, &c.url, "night", &["--active-hours", &hours], &[]);
    wait_for(&dir, "the worker to pause", 60, || {
        dir.read_log("night").contains("paused (outside hours)")
    });
    let rt = runtime();
    let id = detach(&dir, &c, &scene, &["--tile", "16"]);
    wait_for(&dir, "the monitor to show the pause", 60, || {
        monitor_state(&c, "night") == ("paused".to_string(), Some("outside hours".to_string()))
    });
    assert!(paused_line(&c, "night").is_some_and(|l| l.contains("reason=\"outside hours\"")));
    assert_eq!(job(&rt, &c, id).tiles_done, 0, "{}", dir.logs());
    // A malformed range is refused, naming the flag.
    let o = Command::new(bin("trevi-worker"))
        .args(["--coordinator", &c.url, "--active-hours", "7pm-7am"])
        .env_clear()
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("--active-hours") && err.contains("HH:MM"),
        "{err}"
    );
}
