//! Workers on spare machines, end to end with real processes: a worker
//! that steps aside while a CPU hog keeps its machine busy (its tiles are
//! finished by another worker, the image is the local render's, and it
//! comes back when the hog ends), and a worker that keeps to its hours.

mod common;

use common::farm::job;
use common::http::{get, monitor_worker};
use common::*;
use std::process::{Command, Stdio};
use trevi_proto::pb;

/// SLOW_SCENE at 576 samples a pixel: a few seconds on one thread in tiles
/// of 16, so the spare worker is still at it when the hog starts.
fn long_scene() -> String {
    let from = r#"supersample="6""#;
    assert!(SLOW_SCENE.contains(from), "SLOW_SCENE changed");
    SLOW_SCENE.replace(from, r#"supersample="24""#)
}

/// The cores `/proc/stat` counts (`cpu0`, `cpu1`...).
fn cores() -> usize {
    let stat = std::fs::read_to_string("/proc/stat").unwrap();
    stat.lines()
        .filter(|l| l.starts_with("cpu") && l.as_bytes().get(3).is_some_and(u8::is_ascii_digit))
        .count()
        .max(1)
}

/// Minutes after local midnight, as `date` tells.
fn local_minute() -> u32 {
    let o = Command::new("date").arg("+%H %M").output().unwrap();
    let t = String::from_utf8(o.stdout).unwrap();
    let (h, m) = t.trim().split_once(' ').unwrap();
    h.parse::<u32>().unwrap() * 60 + m.parse::<u32>().unwrap()
}

/// One busy-loop process per core, at normal priority: the machine's owner
/// compiling something. Killed when dropped.
fn hog(n: usize) -> Vec<Proc> {
    (0..n)
        .map(|_| {
            Proc(
                Command::new("sh")
                    .args(["-c", "while :; do :; done"])
                    .stdout(Stdio::null())
                    .spawn()
                    .expect("start a busy loop"),
            )
        })
        .collect()
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
    let n = cores();
    // Busy means nearly every core taken by other programs: the hog takes
    // them all, while the build jobs of a shared CI machine come and go.
    let threshold = format!("{}", n as f64 - 0.5);
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
        &[("TREVI_PRIORITY", "")],
    );
    let rt = runtime();
    let id = detach(&dir, &c, &scene, &["--tile", "16"]);
    wait_for(&dir, "the spare worker's first tile", 120, || {
        job(&rt, &c, id).tiles_done >= 1
    });
    let total = job(&rt, &c, id).tiles_total;
    let hogs = hog(n);
    wait_for(&dir, "the spare worker to pause", 60, || {
        dir.read_log("spare").contains("paused (busy")
    });
    wait_for(&dir, "/metrics to show the pause", 10, || {
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
    // The hog ends: the machine is quiet again and the worker comes back.
    drop(hogs);
    wait_for(&dir, "the spare worker to resume", 60, || {
        dir.read_log("spare")
            .contains("resumed: the machine has been quiet")
    });
    wait_for(&dir, "/metrics to drop the pause", 20, || {
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
    wait_for(&dir, "the worker to pause", 30, || {
        dir.read_log("night").contains("paused (outside hours)")
    });
    let rt = runtime();
    let id = detach(&dir, &c, &scene, &["--tile", "16"]);
    wait_for(&dir, "the monitor to show the pause", 10, || {
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
