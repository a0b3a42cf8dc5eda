//! The usage history end to end: a real coordinator and worker render a
//! job, and the CPU time the history says it took agrees within 2 % with
//! the worker process's own counters (`/proc/PID/stat` utime + stime); the
//! figures outlive the job's retention and a restart; the CSV and table
//! outputs parse; every input of `trevi-submit usage`, `/api/usage` and
//! `Jobs.Usage` is bounded.
//!
//! What the comparison leaves in: the worker's CPU time from just before
//! the job is submitted to the end of the job, so its idle polling and its
//! uploads (on the async threads, not counted by the history) are in the
//! process's figure and not in the history's. The test measures what the
//! worker spends idle over the same kind of interval and prints it; the job
//! is made long enough (a few CPU-seconds) that these stay well under the
//! 2 % the comparison allows.

mod common;

use common::http::get as http_get;
use common::{coordinator_with, cpu_time, submit, wait_for, worker_with, Coordinator, Dir, Proc};
use serde_json::Value;
use trevi_proto::pb;

const SUBMIT_TOKEN: &str = "usage-submit-token";
const WORKER_TOKEN: &str = "usage-worker-token";

/// The shared slow scene at four times its pixels: a few CPU-seconds on
/// one render thread.
fn measured_scene() -> String {
    let scene =
        common::SLOW_SCENE.replace(r#"width="96" height="64""#, r#"width="192" height="128""#);
    assert!(scene.contains(r#"width="192""#), "the shared scene changed");
    scene
}

fn start_coordinator(dir: &Dir) -> Coordinator {
    coordinator_with(
        dir,
        "127.0.0.1:0",
        "coordinator",
        &[
            "--http",
            "127.0.0.1:0",
            "--submit-token",
            SUBMIT_TOKEN,
            "--worker-token",
            WORKER_TOKEN,
            // One ended job kept: the second job's end forgets the first.
            "--keep-ended",
            "1",
        ],
        &[],
    )
}

/// `trevi-submit ARGS --coordinator URL --token T`: its standard output,
/// after checking that it succeeded.
fn run(dir: &Dir, c: &Coordinator, args: &[&str]) -> String {
    let mut all = args.to_vec();
    all.extend(["--coordinator", &c.url, "--token", SUBMIT_TOKEN]);
    let out = submit(dir, &all);
    assert!(
        out.status.success(),
        "trevi-submit {args:?} failed: {}\n{}",
        String::from_utf8_lossy(&out.stderr),
        dir.logs()
    );
    String::from_utf8(out.stdout).unwrap()
}

fn usage_json(dir: &Dir, c: &Coordinator, by: &str) -> Value {
    let out = run(dir, c, &["usage", "--by", by, "--format", "json"]);
    serde_json::from_str(&out).unwrap_or_else(|e| panic!("{e}: {out}"))
}

fn row<'a>(v: &'a Value, key: &str) -> &'a Value {
    v["rows"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["key"] == key)
        .unwrap_or_else(|| panic!("no row {key} in {v}"))
}

fn render(dir: &Dir, c: &Coordinator, scene: &str, out: &str) {
    let scene = dir.write(&format!("{out}.xml"), scene);
    let out = dir.path().join(out);
    run(
        dir,
        c,
        &[
            scene.to_str().unwrap(),
            "--quiet",
            "--tile",
            "32",
            "-o",
            out.to_str().unwrap(),
        ],
    );
}

#[test]
fn core_seconds_agree_with_the_worker_s_own_cpu_counters_and_outlive_the_job() {
    let dir = Dir::new();
    let mut c = start_coordinator(&dir);
    let worker: Proc = worker_with(&dir, &c.url, "worker", &["--token", WORKER_TOKEN], &[]);
    let pid = worker.0.id();
    wait_for(&dir, "the worker to register", 60, || {
        dir.read_log("worker").contains("registered")
    });
    // What the worker spends idle (polling for leases, heartbeats): over
    // the time the coordinator takes to answer a few requests, as a rate.
    let (idle_cpu0, idle_t0) = (cpu_time(pid), std::time::Instant::now());
    for _ in 0..3 {
        run(&dir, &c, &["list"]);
    }
    let idle_rate = (cpu_time(pid).saturating_sub(idle_cpu0)).as_secs_f64()
        / idle_t0.elapsed().as_secs_f64().max(1e-3);

    // The measured job: the worker's CPU from just before it is submitted
    // (after its start-up) to its end.
    let before = cpu_time(pid);
    let t0 = std::time::Instant::now();
    render(&dir, &c, &measured_scene(), "measured.png");
    let wall = t0.elapsed().as_secs_f64();
    let spent = cpu_time(pid).saturating_sub(before).as_secs_f64();
    let by_worker = usage_json(&dir, &c, "worker");
    let counted = row(&by_worker, "worker")["core_seconds"].as_f64().unwrap();
    eprintln!(
        "worker CPU over the job: {spent:.3} s; usage history: {counted:.3} core-seconds; \
         idle rate {:.4} CPU-s a second over {wall:.1} s (about {:.3} s of it)",
        idle_rate,
        idle_rate * wall
    );
    assert!(
        spent > 1.0,
        "the job took {spent} s of CPU: too little to compare"
    );
    assert!(
        (counted - spent).abs() <= 0.02 * spent,
        "the usage history says {counted:.3} core-seconds, the worker's own counters \
         {spent:.3} s (more than 2 % apart)\n{}",
        dir.logs()
    );
    let job = row(&usage_json(&dir, &c, "job"), "1").clone();
    assert_eq!(
        job["core_seconds"],
        row(&by_worker, "worker")["core_seconds"]
    );
    // 192×128 in tiles of 32: 24 tiles; its wall time, first lease to end.
    assert_eq!(job["tiles"], 24, "{job}");
    assert!(job["rays"].as_u64().unwrap() > 0);
    let job_wall = job["wall_seconds"].as_f64().unwrap();
    assert!(job_wall > 0.0 && job_wall <= wall, "{job}");
    // No submitter token name: without a name the submitter is the address.
    let subs = usage_json(&dir, &c, "submitter");
    assert_eq!(row(&subs, "127.0.0.1")["core_seconds"], job["core_seconds"]);

    // CSV and the table parse, and say the same.
    let csv = run(
        &dir,
        &c,
        &[
            "usage",
            "--by",
            "job",
            "--format",
            "csv",
            "--cost-per-core-hour",
            "3600",
        ],
    );
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(header[0], "job");
    assert_eq!(*header.last().unwrap(), "cost");
    let fields: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(fields.len(), header.len(), "{csv}");
    assert_eq!(fields[0], "1");
    let secs: f64 = fields[1].parse().unwrap();
    assert!(
        (secs - job["core_seconds"].as_f64().unwrap()).abs() < 1e-5,
        "{csv}"
    );
    // At 3600 a core-hour, a core-second costs 1.
    let cost: f64 = fields[header.len() - 1].parse().unwrap();
    assert!((cost - secs).abs() < 1e-5, "{csv}");
    let table = run(&dir, &c, &["usage"]);
    let mut rows = table.lines();
    assert!(rows.next().unwrap().starts_with("JOB "), "{table}");
    let first: Vec<&str> = rows.next().unwrap().split_whitespace().collect();
    assert_eq!(first[0], "1", "{table}");
    let shown: f64 = first[1].parse().unwrap();
    assert!((shown - secs).abs() < 0.006, "{table}");

    // A second job: with --keep-ended 1 its end forgets the first...
    render(&dir, &c, &common::tiny_scene(3), "tiny.png");
    wait_for(&dir, "job 1 to be forgotten", 60, || {
        let out = submit(
            &dir,
            &[
                "status",
                "1",
                "--coordinator",
                &c.url,
                "--token",
                SUBMIT_TOKEN,
            ],
        );
        !out.status.success()
    });
    // ...but not its usage, nor after a restart (SIGTERM writes what was
    // gathered; the rows are in the database).
    let kept = row(&usage_json(&dir, &c, "job"), "1").clone();
    assert_eq!(kept, job);
    common::signal(&c.proc, "TERM");
    common::wait_child(&dir, &mut c.proc.0, 60);
    let c = start_coordinator(&dir);
    let again = usage_json(&dir, &c, "job");
    assert_eq!(*row(&again, "1"), job);
    assert!(row(&again, "2")["tiles"].as_u64().unwrap() > 0);
    drop(worker);
}

#[test]
fn every_usage_input_is_bounded() {
    let dir = Dir::new();
    let c = start_coordinator(&dir);
    // The command line: refused before anything is sent, naming the flag.
    for (flag, value) in [
        ("--since", "0s"),
        ("--since", "3651d"),
        ("--since", "7 days"),
        ("--by", "hostname"),
        ("--format", "xml"),
        ("--cost-per-core-hour", "-1"),
        ("--cost-per-core-hour", "NaN"),
        ("--cost-per-core-hour", "1e300"),
    ] {
        let out = submit(
            &dir,
            &[
                "usage",
                flag,
                value,
                "--coordinator",
                &c.url,
                "--token",
                SUBMIT_TOKEN,
            ],
        );
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{flag} {value}: {err}");
        assert!(err.contains(flag), "{flag} {value}: {err}");
    }
    // The HTTP API: 400 naming the parameter; the token is needed.
    let http = c.http.as_deref().unwrap();
    for (query, says) in [
        ("since=1s", "since"),
        ("since=99999999999999999999d", "since"),
        ("by=hostname", "by"),
        ("cost=-5", "cost"),
        ("limit=10", "unknown parameter"),
        ("by=job&by=worker", "twice"),
    ] {
        let (code, body) = http_get(http, &format!("/api/usage?{query}"), Some(SUBMIT_TOKEN));
        assert_eq!(code, 400, "{query}: {body}");
        assert!(body.contains(says), "{query}: {body}");
    }
    let long = format!("/api/usage?{}", "by=job&".repeat(100));
    assert_eq!(http_get(http, &long, Some(SUBMIT_TOKEN)).0, 400);
    assert_eq!(http_get(http, "/api/usage", None).0, 401);
    let (code, body) = http_get(http, "/api/usage?since=7d&by=worker", Some(SUBMIT_TOKEN));
    assert_eq!(code, 200, "{body}");
    let v: Value = serde_json::from_str(&body).unwrap();
    assert_eq!(
        (v["by"].as_str(), v["rows"].as_array().map(Vec::len)),
        (Some("worker"), Some(0))
    );
    // The page is open (it holds no data); its API is not.
    let (code, page) = http_get(http, "/usage", None);
    assert_eq!(code, 200);
    assert!(page.contains("/api/usage"));
    // gRPC: the same bounds, INVALID_ARGUMENT.
    let rt = common::runtime();
    rt.block_on(async {
        let mut jobs = common::farm::jobs(&c, Some(SUBMIT_TOKEN)).await;
        for (since_s, by) in [(u64::MAX, "job"), (1, "job"), (3600, "hostname")] {
            let e = jobs
                .usage(pb::UsageRequest {
                    since_s,
                    by: by.into(),
                })
                .await
                .unwrap_err();
            assert_eq!(
                e.code(),
                tonic::Code::InvalidArgument,
                "{since_s} {by}: {e}"
            );
        }
        let ok = jobs
            .usage(pb::UsageRequest {
                since_s: 0,
                by: String::new(),
            })
            .await
            .unwrap()
            .into_inner();
        assert!(ok.rows.is_empty() && ok.bucket_seconds == 3600);
        let mut open = common::farm::jobs(&c, None).await;
        let e = open.usage(pb::UsageRequest::default()).await.unwrap_err();
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
    });
}

/// Named submit tokens (`--submit-tokens-file`): each job records the name
/// of the token it came with, and the history groups by it; a tokens file
/// with a bad line stops the coordinator naming the line.
#[test]
fn named_tokens_name_the_submitter_in_status_and_usage() {
    let dir = Dir::new();
    let tokens = dir.write(
        "submit.tokens",
        "# who  token\nalice tok-alice-1\nbob.render tok-bob-2\n",
    );
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &[
            "--submit-tokens-file",
            tokens.to_str().unwrap(),
            "--worker-token",
            WORKER_TOKEN,
        ],
        &[],
    );
    let _worker: Proc = worker_with(&dir, &c.url, "worker", &["--token", WORKER_TOKEN], &[]);
    let scene =
        common::SLOW_SCENE.replace(r#"width="96" height="64""#, r#"width="32" height="16""#);
    assert!(scene.contains(r#"width="32""#), "the shared scene changed");
    let scene = dir.write("small.xml", &scene);
    let as_token = |token: &str, args: &[&str]| {
        let mut all = args.to_vec();
        all.extend(["--coordinator", &c.url, "--token", token]);
        submit(&dir, &all)
    };
    for (token, out) in [
        ("tok-alice-1", "a.png"),
        ("tok-bob-2", "b.png"),
        ("tok-alice-1", "c.png"),
    ] {
        let out = dir.path().join(out);
        let o = as_token(
            token,
            &[
                scene.to_str().unwrap(),
                "--quiet",
                "-o",
                out.to_str().unwrap(),
            ],
        );
        assert!(
            o.status.success(),
            "{}\n{}",
            String::from_utf8_lossy(&o.stderr),
            dir.logs()
        );
    }
    // A token not in the file submits nothing.
    let o = as_token("tok-carol-3", &[scene.to_str().unwrap(), "--quiet"]);
    assert!(!o.status.success());
    // The jobs' submitters are the names; the history groups by them.
    let o = as_token(
        "tok-bob-2",
        &["usage", "--by", "submitter", "--format", "json"],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    // Two jobs of alice's, one of bob's, all of one scene.
    let tiles = |k: &str| row(&v, k)["tiles"].as_u64().unwrap();
    assert!(tiles("bob.render") > 0, "{v}");
    assert_eq!(tiles("alice"), 2 * tiles("bob.render"), "{v}");
    assert!(
        v["rows"]
            .as_array()
            .unwrap()
            .iter()
            .all(|r| r["key"] != "127.0.0.1"),
        "{v}"
    );
    // `status` names each job's submitter.
    let o = as_token("tok-alice-1", &["status", "2"]);
    let status = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success() && status.contains("by bob.render"),
        "{status}"
    );

    // A bad line: the coordinator says where, and does not start.
    let bad = dir.write("bad.tokens", "alice tok-1\nbob\n");
    let out = std::process::Command::new(common::bin("trevi-coordinator"))
        .args(["--listen", "127.0.0.1:0", "--submit-tokens-file"])
        .arg(&bad)
        .arg("--data-dir")
        .arg(dir.path().join("data-bad"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("bad.tokens:2") && err.contains("NAME TOKEN"),
        "{err}"
    );
}
