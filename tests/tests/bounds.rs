//! What one job, or many, may cost the coordinator, with real processes: a
//! frame too wide for the per-job window is refused at once (by a farm's
//! coordinator and by `trevi-submit`'s local mode); thousands of jobs list
//! past the 4 MiB message limit page by page, and `/api/state` stays small.

mod common;

use common::*;
use std::process::Stdio;
use std::time::{Duration, Instant};
use trevi_proto::pb;

/// A frame as wide as a scene may be (65536, the format's limit): one band
/// of 64-pixel tiles is 48 MiB of rows, over the default 32 MiB window.
/// (A wider one, like the report's 100000000-pixel frame, is refused by the
/// scene parser at its `width` attribute; see
/// `the_reported_100000000_pixel_frame_is_a_located_scene_error`.)
fn wide_scene(dir: &Dir, width: u32) -> std::path::PathBuf {
    dir.write(
        "wide.xml",
        &tiny_scene(1).replace(
            r#"width="24" height="20""#,
            &format!(r#"width="{width}" height="64""#),
        ),
    )
}

/// Peak memory the coordinator may reach in these tests.
const RSS_BOUND_KIB: u64 = 200 * 1024;

#[test]
fn a_frame_whose_one_band_exceeds_the_window_is_refused_at_once_by_a_coordinator() {
    let dir = Dir::new();
    let scene = wide_scene(&dir, 65536);
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let _worker = worker_with(&dir, &c.url, "worker", &[], &[]);
    let t = Instant::now();
    let mut child = submit_cmd(&[
        scene.to_str().unwrap(),
        "--coordinator",
        &c.url,
        "--quiet",
        "-o",
        dir.path().join("wide.png").to_str().unwrap(),
    ])
    .stdout(Stdio::null())
    .stderr(dir.log("submit"))
    .spawn()
    .unwrap();
    let status = wait_child(&dir, &mut child, 30);
    let err = dir.read_log("submit");
    assert!(
        !status.success(),
        "the wide frame was accepted\n{}",
        dir.logs()
    );
    assert!(
        err.contains("--window-mib") && err.contains("65536x64"),
        "no clear refusal: {err}"
    );
    // "At once": long before a job of this size could have been rendered;
    // generous for a busy machine.
    assert!(t.elapsed() < Duration::from_secs(60), "{:?}", t.elapsed());
    // Nothing was allocated for it: no job, and the coordinator stayed small.
    std::thread::sleep(Duration::from_secs(1));
    let peak = proc_kib(c.proc.0.id(), "VmHWM");
    assert!(peak < RSS_BOUND_KIB, "coordinator peak RSS {peak} KiB");
    let jobs = runtime().block_on(async {
        jobs(&c, None)
            .await
            .list_jobs(pb::ListJobsRequest::default())
            .await
            .unwrap()
            .into_inner()
            .jobs
    });
    assert!(jobs.is_empty(), "{jobs:?}");
}

#[test]
fn the_reported_100000000_pixel_frame_is_a_located_scene_error() {
    let dir = Dir::new();
    let scene = wide_scene(&dir, 100_000_000);
    let out = submit_cmd(&[scene.to_str().unwrap(), "--quiet"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "accepted: {err}");
    assert!(
        err.contains("wide.xml:8:") && err.contains("\"width\"") && err.contains("65536"),
        "no located error: {err}"
    );
}

#[test]
fn a_frame_whose_one_band_exceeds_the_window_is_refused_at_once_in_local_mode() {
    let dir = Dir::new();
    let scene = wide_scene(&dir, 65536);
    // The first `bin` call of a test process may build the binaries: not
    // part of the time measured.
    let _ = bin("trevi-submit");
    let t = Instant::now();
    let mut child = submit_cmd(&[
        scene.to_str().unwrap(),
        "--threads",
        "1",
        "--quiet",
        "-o",
        dir.path().join("wide.png").to_str().unwrap(),
    ])
    .stdout(Stdio::null())
    .stderr(dir.log("submit"))
    .spawn()
    .unwrap();
    // Sample its memory while it runs (it should not run for long).
    let mut peak = 0;
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if let Ok(text) = std::fs::read_to_string(format!("/proc/{}/status", child.id())) {
            if let Some(v) = text.lines().find_map(|l| l.strip_prefix("VmHWM:")) {
                peak = peak.max(v.trim().trim_end_matches("kB").trim().parse().unwrap_or(0));
            }
        }
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "still running\n{}",
            dir.logs()
        );
        std::thread::sleep(Duration::from_millis(10));
    };
    let err = dir.read_log("submit");
    assert!(
        !status.success(),
        "the wide frame was accepted\n{}",
        dir.logs()
    );
    assert!(
        err.contains("--window-mib") && err.contains("65536x64"),
        "no clear refusal: {err}"
    );
    assert!(peak < RSS_BOUND_KIB, "trevi-submit peak RSS {peak} KiB");
    assert!(!dir.path().join("wide.png").exists());
}

#[test]
fn seven_thousand_jobs_list_past_the_4_mib_message_limit() {
    let dir = Dir::new();
    // Long camera and output names: each job's status is about 700 bytes,
    // so 7,000 of them are about 5 MB, over the clients' 4 MiB limit.
    let camera = "c".repeat(400);
    let scene = dir.write(
        "s.xml",
        &tiny_scene(2)
            .replace(r#"id="main""#, &format!(r#"id="{camera}""#))
            .replace("tiny.png", &format!("{}.png", "o".repeat(200))),
    );
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--keep-ended", "100000", "--http", "127.0.0.1:0"],
        &[],
    );
    let o = submit(
        &dir,
        &[scene.to_str().unwrap(), "--coordinator", &c.url, "--detach"],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    const JOBS: u64 = 7000;
    runtime().block_on(async {
        let mut j = jobs(&c, None).await;
        let first = j
            .get_job(pb::JobId { id: 1, frame: None })
            .await
            .unwrap()
            .into_inner();
        let mut tasks = Vec::new();
        for _ in 0..8 {
            let mut j = j.clone();
            let hash = first.bundle_hash.clone();
            let camera = camera.clone();
            tasks.push(tokio::spawn(async move {
                for _ in 0..JOBS / 8 {
                    let s = j
                        .submit_job(pb::SubmitJobRequest {
                            bundle_hash: hash.clone(),
                            camera: camera.clone(),
                            ..Default::default()
                        })
                        .await
                        .unwrap()
                        .into_inner();
                    j.cancel_job(pb::JobId {
                        id: s.id,
                        frame: None,
                    })
                    .await
                    .unwrap();
                }
            }));
        }
        for t in tasks {
            t.await.unwrap();
        }
    });
    let total = 1 + (JOBS / 8) * 8;
    let o = submit(&dir, &["list", "--coordinator", &c.url]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "list failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert_eq!(
        out.lines().count() as u64,
        total,
        "{}",
        &out[..out.len().min(2000)]
    );
    // Every id once, in order.
    let ids: Vec<u64> = out
        .lines()
        .map(|l| {
            l.split(|ch: char| !ch.is_ascii_digit())
                .find(|w| !w.is_empty())
                .unwrap()
                .parse()
                .unwrap()
        })
        .collect();
    assert_eq!(ids, (1..=total).collect::<Vec<_>>());
    let o = submit(&dir, &["list", "--coordinator", &c.url, "--limit", "10"]);
    assert_eq!(String::from_utf8_lossy(&o.stdout).lines().count(), 10);
    // The monitor's poll shows the newest few, not all of them.
    let (code, body) = http::get(c.http.as_deref().unwrap(), "/api/state", None);
    assert_eq!(code, 200, "{body}");
    assert!(body.len() < 256 << 10, "/api/state is {} bytes", body.len());
    let v: serde_json::Value = serde_json::from_str(&body).unwrap();
    // Job 1 (submitted by trevi-submit) is still queued: it and the 50
    // newest ended ones.
    assert_eq!(v["jobs"].as_array().unwrap().len(), 1 + 50);
    assert_eq!(v["jobs_queued"].as_u64(), Some(1));
    assert_eq!(v["jobs"][0]["id"].as_u64(), Some(total));
    assert_eq!(v["jobs_ended"].as_u64(), Some(total - 1));
}
