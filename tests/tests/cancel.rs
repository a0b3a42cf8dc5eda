//! Cancellation reaches inside a pixel (issue 36): one pixel may be hours of
//! work (supersample 65535 × max-bounces 10000), and Ctrl-C, SIGTERM and a
//! farm's cancel must stop it within a second, in real processes. And what
//! `trevi-submit` says and does around a farm job it leaves: Ctrl-C names
//! the job and the commands that follow (`wait`) or stop (`cancel`) it;
//! `cancel` of a job that has ended says so.

mod common;

use common::*;
use std::path::Path;
use std::time::{Duration, Instant};
use trevi_proto::pb;

/// One pixel of about 2³² path-traced camera samples: days of work on one
/// thread. Nothing but a cancellation inside the pixel stops it soon.
const ONE_PIXEL_OF_DAYS: &str = r#"<scene version="1">
  <sphere id="s" center="0 0 0" radius="1"> <surface diffuse="0.8 0.8 0.8"/> </sphere>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1"/>
  <camera id="c" position="0 0 5" lookat="0 0 0" up="0 1 0" fov="10">
    <render width="1" height="1" supersample="65535" integrator="path"
            max-bounces="10000" output="days.png"/>
  </camera>
</scene>
"#;

/// A single 16×16 tile, quick.
const QUICK: &str = r#"<scene version="1">
  <sphere id="ball" center="0 1 0" radius="1"> <surface diffuse="0.8 0.3 0.2"/> </sphere>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1"/>
  <camera id="main" position="0 2 6" lookat="0 1 0" up="0 1 0" fov="50">
    <render width="16" height="16" output="quick.png"/>
  </camera>
</scene>
"#;

/// CPU time (user + system, in clock ticks) process `pid` has used.
fn cpu_ticks(pid: u32) -> u64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    // Fields after the command's closing parenthesis: state is field 3,
    // utime and stime fields 14 and 15.
    let rest = stat.rsplit_once(')').map_or("", |r| r.1);
    let f: Vec<u64> = rest
        .split_whitespace()
        .map(|w| w.parse().unwrap_or(0))
        .collect();
    f.get(11).copied().unwrap_or(0) + f.get(12).copied().unwrap_or(0)
}

/// Waits until process `pid` has spent another half second of CPU from
/// now: it is inside the pixel (the scene is tiny; only the pixel burns CPU).
fn burning(dir: &Dir, pid: u32) {
    let from = cpu_ticks(pid);
    wait_for(dir, "the pixel to burn CPU", 120, || {
        cpu_ticks(pid) >= from + 50
    });
}

/// Ctrl-C and SIGTERM stop a local render inside its one pixel of days, in
/// well under a second of the pixel's time: exit 130 / 143, no output.
#[cfg(target_os = "linux")]
#[test]
fn a_local_render_stops_inside_a_pixel_of_days_on_sigint_and_sigterm() {
    let dir = Dir::new();
    let scene = dir.write("days.xml", ONE_PIXEL_OF_DAYS);
    for (sig, code) in [("INT", 130), ("TERM", 143)] {
        let child = submit_cmd(&[scene.to_str().unwrap(), "--threads", "1", "-q"])
            .current_dir(dir.path())
            .stderr(dir.log(&format!("submit-{sig}")))
            .spawn()
            .unwrap();
        let mut p = Proc(child);
        // Starting costs a few milliseconds of CPU: half a second more is
        // the embedded worker inside the pixel.
        burning(&dir, p.0.id());
        let t0 = Instant::now();
        signal(&p, sig);
        let status = wait_child(&dir, &mut p.0, 60);
        let took = t0.elapsed();
        assert_eq!(status.code(), Some(code), "SIG{sig}\n{}", dir.logs());
        assert!(took < Duration::from_secs(5), "SIG{sig}: took {took:?}");
        assert!(!dir.path().join("days.png").exists());
        let err = dir.read_log(&format!("submit-{sig}"));
        assert!(err.contains(&format!("interrupted by SIG{sig}")), "{err}");
    }
}

/// `trevi-submit cancel` of a job whose one pixel is days of work: the
/// worker stops inside the pixel, gives the lease back and takes the next
/// job at once. A second cancel says the job had already ended.
#[cfg(target_os = "linux")]
#[test]
fn a_farm_cancel_stops_a_worker_inside_a_pixel_of_days() {
    let dir = Dir::new();
    let days = dir.write("scene/days.xml", ONE_PIXEL_OF_DAYS);
    let quick = dir.write("scene/quick.xml", QUICK);
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--lease-ttl-ms", "600000"],
        &[],
    );
    let w = worker_with(&dir, &c.url, "worker", &[], &[]);
    let rt = runtime();
    let id = detach(&dir, &c, &days, &[]);
    wait_state(&dir, &rt, &c, id, pb::JobState::Running, 60);
    wait_for(&dir, "the worker to build the scene", 60, || {
        dir.read_log("worker").contains("scene built")
    });
    burning(&dir, w.0.id());
    let t0 = Instant::now();
    let o = submit(&dir, &["cancel", &id.to_string(), "--coordinator", &c.url]);
    assert!(o.status.success(), "{}", dir.logs());
    assert!(String::from_utf8_lossy(&o.stdout).contains("cancelled"));
    wait_for(&dir, "the worker to stop rendering", 30, || {
        dir.read_log("worker").contains("render cancelled")
    });
    let took = t0.elapsed();
    assert!(
        took < Duration::from_secs(5),
        "took {took:?}\n{}",
        dir.logs()
    );
    // The worker is free: the next job is done long before the lease (10
    // minutes) could have run out.
    let next = detach(&dir, &c, &quick, &[]);
    wait_state(&dir, &rt, &c, next, pb::JobState::Done, 60);
    // Cancelling again, or cancelling a finished job, changes nothing and
    // says so.
    for (job, state) in [(id, "cancelled"), (next, "done")] {
        let o = submit(&dir, &["cancel", &job.to_string(), "--coordinator", &c.url]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert!(
            err.contains(&format!("job {job} had already ended ({state})")),
            "{err}"
        );
    }
}

/// Ctrl-C on a farm submission leaves the job running and says so, with
/// the commands that follow and cancel it; `wait ID` follows it to its end
/// and downloads the image the submission would have written.
#[cfg(target_os = "linux")]
#[test]
fn ctrl_c_on_a_farm_submit_names_the_job_and_wait_reattaches() {
    let dir = Dir::new();
    let quick = dir.write("scene/quick.xml", QUICK);
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let rt = runtime();
    // No worker yet: the job stays queued while the submitter follows it.
    let out = dir.path().join("out.png");
    let child = submit_cmd(&[
        quick.to_str().unwrap(),
        "--coordinator",
        &c.url,
        "-o",
        out.to_str().unwrap(),
    ])
    .stderr(dir.log("submit"))
    .spawn()
    .unwrap();
    let mut p = Proc(child);
    wait_for(&dir, "the job to be queued", 60, || {
        dir.read_log("submit").contains("job 1 queued")
    });
    signal(&p, "INT");
    let status = wait_child(&dir, &mut p.0, 30);
    assert_eq!(status.code(), Some(130), "{}", dir.logs());
    let err = dir.read_log("submit");
    for said in [
        "interrupted by SIGINT",
        "job 1 keeps running on the farm",
        &format!("trevi-submit wait 1 --coordinator {}", c.url),
        &format!("trevi-submit cancel 1 --coordinator {}", c.url),
    ] {
        assert!(err.contains(said), "{said:?} missing: {err}");
    }
    assert_eq!(job(&rt, &c, 1).state, pb::JobState::Queued as i32);
    assert!(!out.exists());
    // Re-attached (under its other name too), it ends with the image.
    let _w = worker_with(&dir, &c.url, "worker", &[], &[]);
    for verb in ["wait", "attach"] {
        let _ = std::fs::remove_file(&out);
        let args = [verb, "1", "--coordinator", &c.url];
        let o = submit(
            &dir,
            &[&args[..], &["-o", out.to_str().unwrap(), "-q"]].concat(),
        );
        assert!(o.status.success(), "{verb}: {}", dir.logs());
        assert!(is_png(&out), "{verb}");
    }
    let local = embedded(&dir, &quick, "local.png");
    assert!(
        std::fs::read(&out).unwrap() == local,
        "farm and local differ"
    );
}

fn is_png(p: &Path) -> bool {
    std::fs::read(p).is_ok_and(|b| b.starts_with(b"\x89PNG"))
}
