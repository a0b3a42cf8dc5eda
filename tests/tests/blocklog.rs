//! Blocklists and the per-tile log with real processes: a worker that fails
//! every tile of one job (`TREVI_TEST_FAIL_JOB`) is kept from it while it
//! renders another job; `status` shows it and why, `unblock` lets it back,
//! `log` shows the workers, the error texts and the retries; a job every
//! live worker is kept from fails naming them; and a worker sending a 1 MiB
//! error text per tile leaves a log within its bounds. Every wait is for a
//! state, never for a time.

mod common;

use common::farm::{detach, job, jobs, wait_state};
use common::*;
use trevi_proto::pb;

/// `trevi-submit ARGS --coordinator URL`: its exit status and stdout, or
/// stderr when it failed.
fn run(dir: &Dir, c: &Coordinator, args: &[&str]) -> (bool, String) {
    let mut all = args.to_vec();
    all.extend(["--coordinator", &c.url]);
    let o = submit(dir, &all);
    let text = if o.status.success() {
        &o.stdout
    } else {
        &o.stderr
    };
    (
        o.status.success(),
        String::from_utf8_lossy(text).into_owned(),
    )
}

/// Job `id`'s tile log over gRPC (`errors`: only the failures).
fn log(rt: &tokio::runtime::Runtime, c: &Coordinator, id: u64, errors: bool) -> pb::TileLog {
    rt.block_on(async {
        jobs(c, None)
            .await
            .get_tile_log(pb::TileLogRequest {
                id,
                errors_only: errors,
                ..Default::default()
            })
            .await
            .unwrap_or_else(|s| panic!("log of job {id}: {s:?}"))
            .into_inner()
    })
}

#[test]
fn a_worker_failing_one_job_is_blocked_from_it_shown_logged_and_let_back() {
    let dir = Dir::new();
    // A: 6 × 4 tiles of 16; B: 2 × 2 tiles, quick.
    let a_scene = dir.write("a.xml", SLOW_SCENE);
    let b_scene = dir.write("b.xml", &tiny_scene(3));
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &[
            "--max-worker-failures",
            "2",
            "--max-tile-failures",
            "100",
            "--lease-target-ms",
            "100",
            "--lease-ttl-ms",
            "3000",
        ],
        &[],
    );
    let rt = runtime();
    let a = detach(&dir, &c, &a_scene, &["--tile", "16"]);
    let b = detach(&dir, &c, &b_scene, &["--tile", "16"]);
    let fail_a = a.to_string();
    // `good` renders A slowly (1.5 s a lease), so that A is still
    // running while the test looks at it; `bad` fails each of A's tiles.
    let good = worker_with(
        &dir,
        &c.url,
        "good",
        &[],
        &[("TREVI_TEST_LEASE_DELAY_MS", "1500")],
    );
    let _bad = worker_with(
        &dir,
        &c.url,
        "bad",
        &[],
        &[("TREVI_TEST_FAIL_JOB", &fail_a)],
    );

    // bad is kept from A after two failures, and renders B meanwhile.
    wait_for(&dir, "bad blocked from A", 120, || {
        !job(&rt, &c, a).blocked.is_empty()
    });
    wait_state(&dir, &rt, &c, b, pb::JobState::Done, 120);
    let s = job(&rt, &c, a);
    assert_eq!(s.state, pb::JobState::Running as i32, "{s:?}");
    let blocked = &s.blocked[0];
    assert_eq!(
        (blocked.name.as_str(), blocked.failures),
        ("bad", 2),
        "{s:?}"
    );
    assert!(
        blocked
            .last_error
            .contains(&format!("every tile of job {a} fails")),
        "the worker's own error text: {blocked:?}"
    );
    let b_log = log(&rt, &c, b, false);
    assert!(
        b_log.entries.iter().any(|e| e.worker_name == "bad")
            && b_log.entries.iter().all(|e| e.error.is_empty()),
        "bad rendered B: {b_log:?}"
    );

    // `status` names it and why.
    let (ok, status) = run(&dir, &c, &["status", &a.to_string()]);
    assert!(ok, "{status}");
    assert!(
        status.contains("blocked: bad (worker") && status.contains("2 tiles failed"),
        "{status}"
    );
    assert!(status.contains("test fault: every tile of job"), "{status}");

    // `log` shows each failure with its worker and text, and the retries
    // of a tile good rendered after bad failed it.
    wait_for(&dir, "a retried tile rendered", 120, || {
        log(&rt, &c, a, false)
            .entries
            .iter()
            .any(|e| e.error.is_empty() && e.retries >= 1 && e.worker_name == "good")
    });
    let (ok, table) = run(&dir, &c, &["log", &a.to_string()]);
    assert!(ok, "{table}");
    assert!(table.starts_with("TILE"), "{table}");
    let failures: Vec<&str> = table
        .lines()
        .filter(|l| l.contains("test fault: every tile of job"))
        .collect();
    assert_eq!(failures.len(), 2, "{table}");
    assert!(failures.iter().all(|l| l.contains("bad (")), "{table}");
    let (ok, errors) = run(&dir, &c, &["log", &a.to_string(), "--errors"]);
    assert!(ok && errors.lines().count() == 3, "{errors}");
    let (ok, one) = run(&dir, &c, &["log", &a.to_string(), "--tile", "0,0"]);
    assert!(ok, "{one}");
    assert!(
        one.lines().skip(1).all(|l| l.starts_with("0,0 ")),
        "only the tile at (0, 0): {one}"
    );

    // Unblocking someone who is not blocked, or on an unknown job, fails
    // clearly; unblocking bad lets it fail A's tiles again.
    let (ok, why) = run(&dir, &c, &["unblock", &a.to_string(), "good"]);
    assert!(
        !ok && why.contains("no worker \"good\" is blocked"),
        "{why}"
    );
    assert!(why.contains("bad (worker"), "names who is: {why}");
    let (ok, why) = run(&dir, &c, &["unblock", "999999", "bad"]);
    assert!(!ok && why.contains("999999"), "{why}");
    let (ok, said) = run(&dir, &c, &["unblock", &a.to_string(), "bad"]);
    assert!(ok, "{said}");
    assert!(!said.contains("blocked:"), "{said}");
    wait_for(&dir, "bad to fail A's tiles again", 120, || {
        log(&rt, &c, a, true).entries.len() >= 4
    });

    // With good gone, every live worker is kept from A: it fails naming bad.
    drop(good);
    let s = wait_state(&dir, &rt, &c, a, pb::JobState::Failed, 120);
    assert!(
        s.error.contains("every live worker (bad (worker"),
        "{}\n{}",
        s.error,
        dir.logs()
    );
}

#[test]
fn a_worker_sending_a_mebibyte_of_error_per_tile_leaves_a_bounded_log() {
    let dir = Dir::new();
    let scene = dir.write("a.xml", SLOW_SCENE);
    // At most 6 entries and 1 KiB of error text a job.
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &[
            "--max-worker-failures",
            "1000",
            "--max-tile-failures",
            "1000",
            "--tile-log-entries",
            "6",
            "--tile-log-error-kib",
            "1",
        ],
        &[],
    );
    let rt = runtime();
    let a = detach(&dir, &c, &scene, &["--tile", "16"]);
    let hostile = format!("{a},{}", 1 << 20);
    let _bad = worker_with(
        &dir,
        &c.url,
        "bad",
        &[],
        &[("TREVI_TEST_FAIL_JOB", &hostile)],
    );
    wait_for(&dir, "errors dropped from the log", 120, || {
        log(&rt, &c, a, false).errors_dropped >= 3
    });
    let l = log(&rt, &c, a, false);
    assert!(l.entries.len() <= 6, "{}", l.entries.len());
    let bytes: usize = l.entries.iter().map(|e| e.error.len()).sum();
    assert!(bytes <= 1024, "{bytes} bytes of error text kept");
    for e in &l.entries {
        // The coordinator keeps 500 characters of a worker's error, after
        // the "worker ID: " it names the worker with.
        let prefix = "worker 18446744073709551615: ".len();
        assert!(
            !e.error.is_empty() && e.error.chars().count() <= 500 + prefix,
            "{}",
            e.error.len()
        );
        assert!(e.error.contains("test fault: every tile of job"));
    }
    // The job's error and status stay small too.
    let s = job(&rt, &c, a);
    assert!(s.error.len() < 4096, "{}", s.error.len());
    let (ok, table) = run(&dir, &c, &["log", &a.to_string()]);
    assert!(ok, "{table}");
    assert!(table.contains("oldest entries dropped"), "{table}");
}
