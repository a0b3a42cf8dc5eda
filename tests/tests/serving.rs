//! The coordinator serving many users at once, as real processes (issue 36):
//! queued jobs hold no files, so a coordinator short of descriptors still
//! finishes them; one data directory has one coordinator; one worker's word
//! about memory cannot fail a job another worker can hold; registrations
//! are bounded; a job's status says what is wrong when a download cannot be
//! served.

mod common;

use common::*;
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use trevi_proto::pb;

/// Uploads `scene` as a bundle; returns its hash.
fn upload_scene(rt: &tokio::runtime::Runtime, c: &Coordinator, scene: &str) -> String {
    rt.block_on(async {
        upload(&mut bundles(c, None).await, vec![bundle_of(scene).encode()])
            .await
            .expect("upload")
    })
}

/// Starts `trevi-coordinator` with at most `files` open files (soft and
/// hard limit, so it cannot raise it), like [`coordinator_with`].
fn coordinator_with_files(dir: &Dir, files: u32, args: &[&str]) -> Coordinator {
    let data = dir.path().join("data");
    let mut cmd = Command::new("sh");
    cmd.arg("-c")
        .arg(format!("ulimit -n {files} && exec \"$0\" \"$@\""))
        .arg(bin("trevi-coordinator"))
        .args(["--listen", "127.0.0.1:0", "--tile-size", "16"])
        .arg("--data-dir")
        .arg(&data)
        .args(args)
        .env("RUST_LOG", "info")
        .env_remove("TREVI_SUBMIT_TOKEN")
        .env_remove("TREVI_WORKER_TOKEN")
        .env_remove("TREVI_TLS_CERT")
        .env_remove("TREVI_TLS_KEY")
        .stdout(Stdio::piped())
        .stderr(dir.log("coordinator"));
    let mut child = cmd.spawn().expect("start trevi-coordinator");
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    out.read_line(&mut line).unwrap();
    let addr = line
        .trim()
        .strip_prefix("listening on ")
        .unwrap_or_else(|| panic!("coordinator said {line:?}\n{}", dir.logs()))
        .to_string();
    Coordinator {
        proc: Proc(child),
        url: format!("http://{addr}"),
        addr,
        http: None,
        data,
        tls: trevi_proto::ClientTls::default(),
    }
}

/// Every job's state, by listing them all.
fn states(rt: &tokio::runtime::Runtime, c: &Coordinator) -> Vec<(u64, i32, String)> {
    rt.block_on(async {
        let mut client = jobs(c, None).await;
        let mut all = Vec::new();
        let mut token = String::new();
        loop {
            let r = client
                .list_jobs(pb::ListJobsRequest {
                    limit: 1000,
                    page_token: token.clone(),
                })
                .await
                .unwrap()
                .into_inner();
            all.extend(r.jobs.into_iter().map(|j| (j.id, j.state, j.error)));
            if r.next_page_token.is_empty() {
                return all;
            }
            token = r.next_page_token;
        }
    })
}

/// Issue 36: each queued job held its output's temporary file open twice;
/// with 1024 descriptors, 504 of 600 queued jobs failed when a worker
/// connected. Under 128 descriptors, 200 queued jobs (400 descriptors
/// before the fix) are taken and all finish once a worker comes.
#[test]
fn queued_jobs_hold_no_files_so_a_coordinator_short_of_descriptors_finishes_them_all() {
    let dir = Dir::new();
    let rt = runtime();
    let c = coordinator_with_files(&dir, 128, &[]);
    let hash = upload_scene(&rt, &c, &tiny_scene(3));
    const JOBS: usize = 200;
    rt.block_on(async {
        let mut client = jobs(&c, None).await;
        for i in 0..JOBS {
            client
                .submit_job(pb::SubmitJobRequest {
                    bundle_hash: hash.clone(),
                    ..Default::default()
                })
                .await
                .unwrap_or_else(|s| panic!("job {i} of {JOBS} refused: {s:?}\n{}", dir.logs()));
        }
    });
    let queued = states(&rt, &c);
    assert_eq!(queued.len(), JOBS);
    let _w = worker_with(&dir, &c.url, "worker", &[], &[]);
    wait_for(&dir, "every job to end", 600, || {
        states(&rt, &c).iter().all(|(_, s, _)| {
            *s != pb::JobState::Queued as i32 && *s != pb::JobState::Running as i32
        })
    });
    let failed: Vec<_> = states(&rt, &c)
        .into_iter()
        .filter(|(_, s, _)| *s != pb::JobState::Done as i32)
        .collect();
    assert!(
        failed.is_empty(),
        "{} failed: {:?}\n{}",
        failed.len(),
        &failed[..failed.len().min(3)],
        dir.logs()
    );
}

/// Issue 36: two coordinators started on one `--data-dir` and handed out
/// the same job id. The second is refused, naming the first's PID.
#[test]
fn a_second_coordinator_on_one_data_directory_is_refused_naming_the_first() {
    let dir = Dir::new();
    let c = coordinator_with(&dir, "127.0.0.1:0", "first", &[], &[]);
    let mut second = Command::new(bin("trevi-coordinator"))
        .args(["--listen", "127.0.0.1:0", "--data-dir"])
        .arg(&c.data)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut status = None;
    wait_for(&dir, "the second coordinator to give up", 60, || {
        status = second.try_wait().unwrap();
        status.is_some()
    });
    let mut err = String::new();
    std::io::Read::read_to_string(&mut second.stderr.take().unwrap(), &mut err).unwrap();
    assert!(!status.unwrap().success(), "{err}");
    let pid = format!("PID {}", c.proc.0.id());
    assert!(
        err.contains(&pid) && err.contains("--data-dir") && err.contains("another coordinator"),
        "{err}"
    );
}

/// Issue 36: one `ReturnTile(memory_needed = 2^64 - 1)` from any worker
/// raised the job's estimate past every worker and failed the job while a
/// worker with 12 GiB was attached. The claim proves only that the scene
/// needs more than the claimant's own limit: the big worker renders it.
#[test]
fn one_worker_s_memory_claim_cannot_fail_a_job_a_bigger_worker_can_hold() {
    let dir = Dir::new();
    let rt = runtime();
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--memory-grace-ms", "200"],
        &[],
    );
    let hash = upload_scene(&rt, &c, &tiny_scene(4));
    let id = rt.block_on(submit_job(&c, &hash)).unwrap().id;
    rt.block_on(async {
        let client = workers(&c, None).await;
        for (name, limit) in [("liar", 1u64 << 30), ("unlimited-liar", 0)] {
            let mut w = FakeWorker::register(&client, name).await;
            // Registered again with a limit (FakeWorker gives none).
            let reg = w
                .client
                .register(pb::RegisterRequest {
                    name: name.into(),
                    threads: 1,
                    max_memory: limit,
                    ..Default::default()
                })
                .await
                .unwrap()
                .into_inner();
            w.id = reg.worker_id;
            w.session = reg.session;
            let l = w.lease().await;
            w.client
                .return_tile(pb::TileReturn {
                    worker_id: w.id,
                    session: w.session.clone(),
                    lease_id: l.lease_id,
                    error: String::new(),
                    memory_needed: u64::MAX,
                })
                .await
                .unwrap();
        }
    });
    let _big = worker_with(&dir, &c.url, "big", &["--max-memory", "12G"], &[]);
    let end = wait_for_end(&dir, &rt, &c, id);
    assert_eq!(
        end.state,
        pb::JobState::Done as i32,
        "{}\n{}",
        end.error,
        dir.logs()
    );
    let log = dir.read_log("coordinator");
    assert!(log.contains("counted against the worker"), "{log}");
}

/// Waits for job `id` to end; returns its status.
fn wait_for_end(
    dir: &Dir,
    rt: &tokio::runtime::Runtime,
    c: &Coordinator,
    id: u64,
) -> pb::JobStatus {
    let mut last = None;
    wait_for(dir, &format!("job {id} to end"), 300, || {
        let s = job(rt, c, id);
        let over =
            s.state != pb::JobState::Queued as i32 && s.state != pb::JobState::Running as i32;
        last = Some(s);
        over
    });
    last.unwrap()
}

/// Issue 36: 40,000 `Register` calls took 76 MB and made 40,000 series. One
/// address registers at most `--max-workers-per-address` workers; the
/// refusal says which limit; a registration never followed by a call is
/// forgotten, freeing its place.
#[test]
fn registrations_from_one_address_are_bounded_and_silent_ones_forgotten() {
    let dir = Dir::new();
    let rt = runtime();
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        // Forgotten after a tenth of ten lease lifetimes (at least 6 s).
        &["--max-workers-per-address", "5", "--lease-ttl-ms", "100"],
        &[],
    );
    rt.block_on(async {
        let mut client = workers(&c, None).await;
        for _ in 0..5 {
            register(&mut client).await.unwrap();
        }
        let e = register(&mut client).await.unwrap_err();
        assert_eq!(e.code(), tonic::Code::ResourceExhausted, "{e:?}");
        assert!(e.message().contains("--max-workers-per-address"), "{e:?}");
        // They never called again: forgotten, and their places free.
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(120);
        loop {
            match register(&mut client).await {
                Ok(_) => break,
                Err(e) if e.code() == tonic::Code::ResourceExhausted => {
                    assert!(
                        std::time::Instant::now() < deadline,
                        "never freed\n{}",
                        dir.logs()
                    );
                    tokio::time::sleep(std::time::Duration::from_millis(100)).await;
                }
                Err(e) => panic!("{e:?}"),
            }
        }
    });
    assert!(dir
        .read_log("coordinator")
        .contains("never called after registering"));
}

/// Registers a worker named "w" with one thread.
async fn register(
    client: &mut pb::workers_client::WorkersClient<trevi_proto::AuthChannel>,
) -> Result<pb::RegisterResponse, tonic::Status> {
    client
        .register(pb::RegisterRequest {
            name: "w".into(),
            threads: 1,
            ..Default::default()
        })
        .await
        .map(|r| r.into_inner())
}
