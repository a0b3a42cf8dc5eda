//! Job control with real processes: `trevi-submit pause` and `resume`
//! around a worker killed while the job is paused (the output is the
//! one-shot render's bytes), and `--after` chains (a job waits, shown as
//! `waiting`, and fails naming the cause when what it waits for fails).
//! Every wait is for a state, never for a time.

mod common;

use common::farm::{detach, job, wait_state};
use common::*;
use trevi_proto::pb;

/// `trevi-submit ARGS --coordinator URL`, which must succeed; its stdout.
fn control(dir: &Dir, c: &Coordinator, args: &[&str]) -> String {
    let mut all = args.to_vec();
    all.extend(["--coordinator", &c.url]);
    let o = submit(dir, &all);
    assert!(o.status.success(), "trevi-submit {args:?}\n{}", dir.logs());
    String::from_utf8_lossy(&o.stdout).into_owned()
}

#[test]
fn pause_now_and_resume_around_a_killed_worker_give_the_one_shot_bytes() {
    let dir = Dir::new();
    // 6 × 4 tiles of 16, slow enough to pause in the middle.
    let scene = dir.write("s.xml", SLOW_SCENE);
    let expected = embedded(&dir, &scene, "embedded.png");
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--lease-target-ms", "100"],
        &[],
    );
    // A lease takes at least a tenth of a second: the job lasts long
    // enough to be paused in the middle.
    let delay = [("TREVI_TEST_LEASE_DELAY_MS", "100")];
    let first = worker_with(&dir, &c.url, "worker0", &[], &delay);
    let rt = runtime();
    let id = detach(&dir, &c, &scene, &["--tile", "16"]);
    let total = 6 * 4;
    wait_for(&dir, "3 tiles done", 120, || {
        job(&rt, &c, id).tiles_done >= 3
    });
    let said = control(&dir, &c, &["pause", &id.to_string(), "--now"]);
    assert!(said.contains("paused"), "{said}");
    // The worker dies while the job is paused; its tiles were returned.
    drop(first);
    let s = job(&rt, &c, id);
    assert!(s.paused && s.tiles_done < total, "{s:?}");
    let status = control(&dir, &c, &["status", &id.to_string()]);
    assert!(status.contains("paused"), "{status}");
    // Resuming a job that is paused; a second resume is refused.
    let said = control(&dir, &c, &["resume", &id.to_string()]);
    assert!(!said.contains("paused"), "{said}");
    let again = submit(&dir, &["resume", &id.to_string(), "--coordinator", &c.url]);
    assert!(!again.status.success());
    assert!(
        String::from_utf8_lossy(&again.stderr).contains("is not paused"),
        "{}",
        dir.logs()
    );
    let _second = worker_with(&dir, &c.url, "worker1", &[], &[]);
    wait_state(&dir, &rt, &c, id, pb::JobState::Done, 180);
    let out = dir.path().join("farm.png");
    control(
        &dir,
        &c,
        &["fetch", &id.to_string(), "-o", out.to_str().unwrap()],
    );
    assert_eq!(
        std::fs::read(&out).unwrap(),
        expected,
        "paused, resumed and rendered by another worker, the bytes differ\n{}",
        dir.logs()
    );
}

/// A single 16×16 tile, quick; it has no tile at (16, 0).
const ONE_TILE: &str = r#"<scene version="1">
  <settings background="0.1 0.1 0.2" ambient="0.1 0.1 0.1"/>
  <sphere id="ball" center="0 1 0" radius="1"> <surface diffuse="0.8 0.3 0.2"/> </sphere>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1"/>
  <camera id="main" position="0 2 6" lookat="0 1 0" up="0 1 0" fov="50">
    <render width="16" height="16" output="one.png"/>
  </camera>
</scene>
"#;

#[test]
fn a_chain_of_three_fails_naming_the_cause_and_a_chain_that_holds_runs_in_order() {
    let dir = Dir::new();
    // 24 × 20: its tile at (16, 0) panics on the worker below, five times.
    let failing = dir.write("scene/tiny.xml", &tiny_scene(0));
    let fine = dir.write("scene/one.xml", ONE_TILE);
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--max-worker-failures", "10"],
        &[],
    );
    let rt = runtime();
    // Submitted before any worker runs: each waits for the one before.
    let a = detach(&dir, &c, &failing, &["--tile", "16"]);
    let a_ = a.to_string();
    let b = detach(&dir, &c, &fine, &["--after", &a_]);
    let b_ = b.to_string();
    let third = detach(&dir, &c, &fine, &["--after", &b_]);
    let ok = detach(&dir, &c, &fine, &[]);
    let after_ok = detach(&dir, &c, &fine, &["--after", &ok.to_string()]);
    let status = control(&dir, &c, &["status", &third.to_string()]);
    assert!(
        status.contains("waiting") && status.contains(&format!("waiting for {b}")),
        "{status}"
    );
    let list = control(&dir, &c, &["list"]);
    let row = list
        .lines()
        .find(|l| l.split_whitespace().next() == Some(b_.as_str()))
        .unwrap_or_else(|| panic!("{list}"));
    assert!(
        row.contains("waiting") && row.contains(&format!("waiting for {a}")),
        "{row}"
    );
    // Unknown ids and ids of jobs not submitted yet are refused.
    let o = submit(
        &dir,
        &[
            fine.to_str().unwrap(),
            "--coordinator",
            &c.url,
            "--detach",
            "--after",
            "999",
        ],
    );
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("no job 999"),
        "{}",
        dir.logs()
    );
    let panic = [("TREVI_TEST_PANIC_ON_TILE", "16,0")];
    let _w = worker_with(&dir, &c.url, "worker0", &[], &panic);
    let s = wait_state(&dir, &rt, &c, third, pb::JobState::Failed, 120);
    assert!(
        s.error.contains(&format!("job {b}")) && s.error.contains(&format!("job {a}")),
        "{}\n{}",
        s.error,
        dir.logs()
    );
    assert_eq!(job(&rt, &c, a).state, pb::JobState::Failed as i32);
    assert_eq!(job(&rt, &c, b).state, pb::JobState::Failed as i32);
    // The chain whose first job is done runs to the end.
    wait_state(&dir, &rt, &c, after_ok, pb::JobState::Done, 120);
    let status = control(&dir, &c, &["status", &third.to_string()]);
    assert!(
        status.contains("failed") && !status.contains("waiting"),
        "{status}"
    );
}
