//! The coordinator's inputs under load, with real processes: bundle uploads
//! (memory, concurrency, stalls, leftovers, garbage collection, damaged
//! copies), the monitor's connections (idle floods, the open-files limit)
//! and cross-site requests to its API.

mod common;

use common::*;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use tonic::Code;
use trevi_proto::pb::{self, bundles_client::BundlesClient};
use trevi_proto::AuthChannel;

/// Uploads `data` as one chunk.
async fn upload_one(c: &Coordinator, data: Vec<u8>) -> Result<pb::BundleRef, tonic::Status> {
    bundles(c, None)
        .await
        .upload_bundle(tokio_stream::iter([pb::BundleChunk { data }]))
        .await
        .map(|r| r.into_inner())
}

const MIB: usize = 1 << 20;

/// The chunks of a valid bundle encoding holding the scene `s.xml` and a
/// file `big.bin` of `mib` MiB (its bytes depend on `seed`), made one at a
/// time as the upload asks for them. Also returns the encoding's size.
fn big_bundle_chunks(seed: u8, mib: usize) -> (impl Iterator<Item = pb::BundleChunk>, u64) {
    fn put(out: &mut Vec<u8>, data: &[u8]) {
        out.extend_from_slice(&(data.len() as u64).to_le_bytes());
        out.extend_from_slice(data);
    }
    let scene = tiny_scene(seed as u32);
    let mut head = b"TREVIBN1".to_vec();
    put(&mut head, b"s.xml");
    head.extend_from_slice(&2u64.to_le_bytes());
    put(&mut head, b"big.bin");
    head.extend_from_slice(&((mib * MIB) as u64).to_le_bytes());
    let mut tail = Vec::new();
    put(&mut tail, b"s.xml");
    put(&mut tail, scene.as_bytes());
    let size = (head.len() + mib * MIB + tail.len()) as u64;
    let body = (0..mib).map(move |i| vec![seed.wrapping_mul(31).wrapping_add(i as u8); MIB]);
    let chunks = std::iter::once(head)
        .chain(body)
        .chain(std::iter::once(tail))
        .map(|data| pb::BundleChunk { data });
    (chunks, size)
}

/// Files in the coordinator's bundle directory whose name starts with
/// `prefix`.
fn bundle_files(c: &Coordinator, prefix: &str) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(c.data.join("bundles"))
        .map(|d| {
            d.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with(prefix))
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

#[test]
fn many_concurrent_large_uploads_stream_to_disk_within_a_memory_bound() {
    if !Path::new("/proc/self/status").exists() {
        return skip("no /proc to read the coordinator's memory from");
    }
    const UPLOADS: usize = 8;
    const EACH_MIB: usize = 48;
    let dir = Dir::new();
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--max-uploads", "8", "--max-bundle-mib", "64"],
        &[],
    );
    let pid = c.proc.0.id();
    let before = proc_kib(pid, "VmRSS");
    let rt = runtime();
    let results = rt.block_on(async {
        let mut set = tokio::task::JoinSet::new();
        for i in 0..UPLOADS {
            let mut b = bundles(&c, None).await;
            set.spawn(async move {
                let (chunks, size) = big_bundle_chunks(i as u8, EACH_MIB);
                let r = b.upload_bundle(tokio_stream::iter(chunks)).await;
                (r.map(|r| r.into_inner()), size)
            });
        }
        set.join_all().await
    });
    let peak_kib = proc_kib(pid, "VmHWM");
    for (r, size) in results {
        let r = r.unwrap_or_else(|e| panic!("upload failed: {e:?}\n{}", dir.logs()));
        assert_eq!(r.size, size);
        let stored = std::fs::metadata(c.data.join("bundles").join(&r.hash)).unwrap();
        assert_eq!(stored.len(), size, "the stored copy is the whole upload");
    }
    let total_mib = UPLOADS * EACH_MIB;
    eprintln!(
        "{UPLOADS} concurrent uploads of {EACH_MIB} MiB: coordinator RSS {} MiB before, \
         peak {} MiB",
        before / 1024,
        peak_kib / 1024
    );
    // Holding the uploads in memory would take at least their total
    // (384 MiB); streamed to disk they take a few chunks each.
    assert!(
        peak_kib < 160 * 1024,
        "peak RSS {} MiB for {total_mib} MiB of concurrent uploads\n{}",
        peak_kib / 1024,
        dir.logs()
    );
    assert_eq!(bundle_files(&c, ".upload-"), Vec::<String>::new());
}

/// An upload call's answer and how long it took.
type UploadCall = tokio::task::JoinHandle<(Result<pb::BundleRef, tonic::Status>, Duration)>;

/// An upload that sends `first` and then nothing, until the returned
/// sender is dropped.
fn stalled_upload(
    mut b: BundlesClient<AuthChannel>,
    first: Vec<u8>,
) -> (tokio::sync::mpsc::Sender<pb::BundleChunk>, UploadCall) {
    let (tx, rx) = tokio::sync::mpsc::channel(2);
    tx.try_send(pb::BundleChunk { data: first }).unwrap();
    let call = tokio::spawn(async move {
        let t = Instant::now();
        let r = b
            .upload_bundle(tokio_stream::wrappers::ReceiverStream::new(rx))
            .await
            .map(|r| r.into_inner());
        (r, t.elapsed())
    });
    (tx, call)
}

#[test]
fn uploads_beyond_the_cap_are_refused_and_a_stalled_one_is_dropped_after_the_idle_timeout() {
    let dir = Dir::new();
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--max-uploads", "2", "--upload-idle-ms", "1500"],
        &[],
    );
    let rt = runtime();
    rt.block_on(async {
        let head = bundle_of(&tiny_scene(1)).encode()[..20].to_vec();
        let (tx1, call1) = stalled_upload(bundles(&c, None).await, head.clone());
        let (tx2, call2) = stalled_upload(bundles(&c, None).await, head.clone());
        let started = Instant::now();
        while bundle_files(&c, ".upload-").len() < 2 {
            assert!(
                started.elapsed() < Duration::from_secs(60),
                "the stalled uploads never started\n{}",
                dir.logs()
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        // A third, while two are in progress: refused at once.
        let good = bundle_of(&tiny_scene(2)).encode();
        let e = upload_one(&c, good.clone()).await.unwrap_err();
        assert_eq!(e.code(), Code::ResourceExhausted, "{e:?}");
        assert!(e.message().contains("--max-uploads"), "{}", e.message());
        // The stalled ones are dropped after the idle timeout, their
        // temporary files with them.
        for call in [call1, call2] {
            // Never dropped would hang here: a generous bound, not a time
            // the test expects.
            let (r, took) = tokio::time::timeout(Duration::from_secs(120), call)
                .await
                .expect("a stalled upload was never dropped")
                .unwrap();
            let e = r.unwrap_err();
            assert_eq!(e.code(), Code::DeadlineExceeded, "{e:?}");
            assert!(e.message().contains("--upload-idle-ms"), "{}", e.message());
            assert!(
                took >= Duration::from_millis(1500),
                "dropped after {took:?}"
            );
        }
        drop((tx1, tx2));
        assert_eq!(bundle_files(&c, ".upload-"), Vec::<String>::new());
        // The slots are free again.
        let r = upload_one(&c, good).await;
        assert!(r.is_ok(), "{r:?}\n{}", dir.logs());
    });
}

/// Sets a file's modification time `ago` in the past.
fn age(path: &Path, ago: Duration) {
    std::fs::File::options()
        .write(true)
        .open(path)
        .unwrap()
        .set_modified(std::time::SystemTime::now() - ago)
        .unwrap();
}

#[test]
fn failed_uploads_leave_no_temporary_file_and_unused_bundles_are_collected() {
    let dir = Dir::new();
    // Left by an earlier run: an unfinished upload and a bundle no job uses.
    let store = dir.path().join("data").join("bundles");
    std::fs::create_dir_all(&store).unwrap();
    std::fs::write(store.join(".upload-4242-7"), b"half an upload").unwrap();
    let orphan = store.join("a".repeat(64));
    std::fs::write(&orphan, b"an old bundle").unwrap();
    age(&orphan, Duration::from_secs(7200));
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--bundle-grace-secs", "5"],
        &[],
    );
    wait_for(&dir, "the start-up sweep", 60, || {
        bundle_files(&c, "").is_empty()
    });
    let rt = runtime();
    rt.block_on(async {
        // Refused content.
        let e = upload_one(&c, b"not a bundle".to_vec()).await.unwrap_err();
        assert_eq!(e.code(), Code::InvalidArgument, "{e:?}");
        // An upload the client abandons half way.
        let (tx, call) = stalled_upload(bundles(&c, None).await, vec![1u8; 4096]);
        let t = Instant::now();
        while bundle_files(&c, ".upload-").len() != 1 {
            assert!(t.elapsed() < Duration::from_secs(60), "{}", dir.logs());
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        call.abort();
        drop(tx);
        let t = Instant::now();
        while !bundle_files(&c, ".upload-").is_empty() {
            assert!(
                t.elapsed() < Duration::from_secs(60),
                "an abandoned upload left {:?}\n{}",
                bundle_files(&c, ".upload-"),
                dir.logs()
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        // One bundle a job uses, one no job uses.
        let used = upload_one(&c, bundle_of(&tiny_scene(1)).encode())
            .await
            .unwrap()
            .hash;
        let young = Instant::now();
        let unused = upload_one(&c, bundle_of(&tiny_scene(2)).encode())
            .await
            .unwrap()
            .hash;
        submit_job(&c, &used).await.unwrap();
        // Young: both stay for now. Both are younger than the grace at
        // least until `young` + 5 s: on a machine so busy that this check
        // comes later, it proves nothing and is left out.
        let files = bundle_files(&c, "");
        if young.elapsed() < Duration::from_secs(5) {
            assert_eq!(files, {
                let mut v = vec![used.clone(), unused.clone()];
                v.sort();
                v
            });
        }
        let t = Instant::now();
        while bundle_files(&c, "") != vec![used.clone()] {
            assert!(
                t.elapsed() < Duration::from_secs(90),
                "bundles {:?} (used {used})\n{}",
                bundle_files(&c, ""),
                dir.logs()
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    });
}

#[test]
fn a_damaged_bundle_fails_its_jobs_by_name_and_uploading_it_again_repairs_it() {
    let dir = Dir::new();
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let rt = runtime();
    let bytes = bundle_of(&tiny_scene(3)).encode();
    let upload = |bytes: Vec<u8>| async { upload_one(&c, bytes).await.unwrap().hash };
    let farm = &c;
    let submit = |hash: String| async move { submit_job(farm, &hash).await };
    let hash = rt.block_on(upload(bytes.clone()));
    let first = rt.block_on(submit(hash.clone())).unwrap().id;
    // Damaged on disk while the job waits for a worker.
    let stored = c.data.join("bundles").join(&hash);
    let mut bad = bytes.clone();
    let mid = bad.len() / 2;
    bad[mid] ^= 0x55;
    std::fs::write(&stored, &bad).unwrap();
    let _w = worker_with(&dir, &c.url, "worker", &[], &[]);
    let get = |id: u64| job(&rt, &c, id);
    wait_for(&dir, "the job on the damaged bundle to fail", 30, || {
        get(first).state == pb::JobState::Failed as i32
    });
    let error = get(first).error;
    assert!(
        error.contains("damaged") && error.contains(&hash),
        "the job's error does not name the damage: {error}"
    );
    assert!(!error.contains("lease expired"), "{error}");
    // Submitting on it again is refused, naming the damage.
    let e = rt.block_on(submit(hash.clone())).unwrap_err();
    assert!(e.message().contains("damaged"), "{e:?}");
    // The right bytes again: the copy is repaired and a job renders.
    assert_eq!(rt.block_on(upload(bytes.clone())), hash);
    assert_eq!(std::fs::read(&stored).unwrap(), bytes);
    let second = rt.block_on(submit(hash.clone())).unwrap().id;
    wait_for(&dir, "the job on the repaired bundle to finish", 60, || {
        let s = get(second).state;
        assert_ne!(
            s,
            pb::JobState::Failed as i32,
            "{:?}\n{}",
            get(second),
            dir.logs()
        );
        s == pb::JobState::Done as i32
    });
}

#[test]
fn cross_site_posts_to_the_monitor_api_are_refused() {
    let dir = Dir::new();
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--http", "127.0.0.1:0"],
        &[],
    );
    let addr = c.http.clone().unwrap();
    let rt = runtime();
    let hash = rt.block_on(async {
        upload_one(&c, bundle_of(&tiny_scene(1)).encode())
            .await
            .unwrap()
            .hash
    });
    let id = rt.block_on(submit_job(&c, &hash)).unwrap().id;
    let cancel = format!("/api/jobs/{id}/cancel");
    let priority = format!("/api/jobs/{id}/priority");
    let json = "Content-Type: application/json";
    let origin = format!("Origin: http://{addr}");
    // What a page on another site can make a browser send.
    let refused: [(Vec<&str>, u16); 6] = [
        // A form post: a simple content type, the other site's origin.
        (
            vec![
                "Origin: http://evil.example",
                "Content-Type: application/x-www-form-urlencoded",
            ],
            403,
        ),
        // A script's request, JSON and all, from another origin.
        (vec!["Origin: http://evil.example", json], 403),
        (vec!["Origin: null", json], 403),
        // No Origin, but a Referer elsewhere.
        (vec!["Referer: http://evil.example/page.html", json], 403),
        // This origin, but a body a form could send.
        (vec![&origin, "Content-Type: text/plain"], 415),
        // No content type at all.
        (vec![], 415),
    ];
    for (headers, code) in &refused {
        for (path, body) in [(&cancel, "{}"), (&priority, r#"{"priority": 5}"#)] {
            let (got, answer) = http::post(&addr, path, headers, body);
            assert_eq!(got, *code, "{path} with {headers:?}: {answer}");
            assert!(answer.contains("refused"), "{answer}");
        }
    }
    let state = |id: u64| job(&rt, &c, id);
    let j = state(id);
    assert_eq!(
        (j.state, j.priority),
        (pb::JobState::Queued as i32, 0),
        "a refused request changed the job"
    );
    // The monitor's own requests (its origin, JSON) and plain clients
    // (no origin, JSON) still work.
    let (got, body) = http::post(&addr, &priority, &[&origin, json], r#"{"priority": 5}"#);
    assert_eq!(got, 200, "{body}");
    assert_eq!(state(id).priority, 5);
    let (got, body) = http::post(&addr, &cancel, &[json], "");
    assert_eq!(got, 200, "{body}");
    assert_eq!(state(id).state, pb::JobState::Cancelled as i32);
}

#[test]
fn idle_monitor_connections_are_closed_and_grpc_keeps_answering_meanwhile() {
    let dir = Dir::new();
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &[
            "--http",
            "127.0.0.1:0",
            "--http-header-timeout-ms",
            "6000",
            "--http-max-connections",
            "100",
        ],
        &[],
    );
    let addr = c.http.clone().unwrap();
    // Many connections that never finish their headers (half send part
    // of one), more than the cap.
    let opened = Instant::now();
    let mut idle: Vec<TcpStream> = (0..400)
        .map(|i| {
            let mut s = TcpStream::connect(&addr).unwrap();
            if i % 2 == 0 {
                let _ = s.write_all(b"GET / HTTP/1.1\r\nHost: x\r\n");
            }
            s
        })
        .collect();
    // gRPC answers all the while: before the header timeout closes the
    // idle connections (a gRPC server blocked by them would answer only
    // then). The timeout is long enough for a process to start and ask on
    // a busy machine.
    let o = submit(&dir, &["list", "--coordinator", &c.url]);
    let took = opened.elapsed();
    assert!(o.status.success(), "{}", dir.logs());
    assert!(
        took < Duration::from_secs(6),
        "trevi-submit list answered {took:?} after the connections were made"
    );
    // Every idle connection is closed by the server: the ones over the cap
    // at once, the others after the header timeout.
    for s in &mut idle {
        s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
        let mut buf = [0u8; 256];
        match s.read(&mut buf) {
            Ok(0) => {}
            Ok(n) => {
                // A 408 or similar before closing is fine; then EOF.
                let _ = n;
                let mut rest = Vec::new();
                s.read_to_end(&mut rest).expect("closed after its answer");
            }
            Err(e) => assert!(
                !matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ),
                "a connection was still open {:?} after it was made\n{}",
                opened.elapsed(),
                dir.logs()
            ),
        }
    }
    let all_closed = opened.elapsed();
    assert!(
        all_closed >= Duration::from_millis(6000),
        "closed too early: {all_closed:?}"
    );
    // And the monitor serves again.
    let (code, body) = http::request(
        &addr,
        &format!("GET /healthz HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"),
    );
    assert_eq!(code, 200, "{body}");
}

/// The `Max open files` soft and hard limits of a process.
fn open_files_limit(pid: u32) -> (String, String) {
    let limits = std::fs::read_to_string(format!("/proc/{pid}/limits")).unwrap();
    let line = limits
        .lines()
        .find(|l| l.starts_with("Max open files"))
        .unwrap()
        .to_string();
    let mut f = line["Max open files".len()..].split_whitespace();
    (f.next().unwrap().into(), f.next().unwrap().into())
}

#[test]
fn the_coordinator_raises_its_open_files_limit_to_the_hard_limit() {
    if !Path::new("/proc/self/limits").exists() {
        return skip("no /proc to read the coordinator's limits from");
    }
    // Anyone may lower a hard limit: an unlimited or very high one is
    // brought down to 4096 for the child, so the test runs wherever the
    // hard limit is above 256.
    let (_, ours) = open_files_limit(std::process::id());
    let hard = match ours.parse::<u64>() {
        Ok(n) if n <= 256 => {
            return skip(&format!(
                "the hard open-files limit ({ours}) leaves nothing to raise"
            ))
        }
        Ok(n) => n.min(4096).to_string(),
        Err(_) => "4096".to_string(),
    };
    let dir = Dir::new();
    let data: PathBuf = dir.path().join("data");
    let mut child = std::process::Command::new("sh")
        .arg("-c")
        .arg(format!(
            "ulimit -Sn 256 && ulimit -Hn {hard} && exec \"$0\" \"$@\""
        ))
        .arg(bin("trevi-coordinator"))
        .args(["--listen", "127.0.0.1:0", "--data-dir"])
        .arg(&data)
        .stdout(std::process::Stdio::piped())
        .stderr(dir.log("coordinator"))
        .spawn()
        .unwrap();
    let mut line = String::new();
    std::io::BufRead::read_line(
        &mut std::io::BufReader::new(child.stdout.take().unwrap()),
        &mut line,
    )
    .unwrap();
    let proc = Proc(child);
    assert!(line.starts_with("listening on"), "{line}\n{}", dir.logs());
    let (soft, now_hard) = open_files_limit(proc.0.id());
    assert_eq!(now_hard, hard);
    assert_eq!(soft, hard, "the soft limit was not raised from 256");
}
