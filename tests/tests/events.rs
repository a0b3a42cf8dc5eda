//! Job events end to end: a real coordinator (`--events-url`,
//! `--events-secret-file`, `--http`), a real worker and `trevi-submit
//! --notify`, with a webhook receiver on 127.0.0.1 in the test that is down
//! (its port closed) while the job runs and opens afterwards. Every event
//! must arrive once, signed, in order; the monitor's `GET /events` streams
//! the same events.

mod common;

use common::{coordinator_with, submit, tiny_scene, wait_for, worker_with, Dir};
use serde_json::Value;
use std::collections::HashMap;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::{Arc, Mutex};
use std::time::Duration;

const SECRET: &str = "hook-s3cret";

/// One POST the receiver took: its path, lowercased headers and body.
#[derive(Debug, Clone)]
struct Got {
    path: String,
    headers: HashMap<String, String>,
    body: String,
}

/// A webhook receiver: takes each POST on `listener` and answers 200.
fn receive(listener: TcpListener, got: Arc<Mutex<Vec<Got>>>) {
    std::thread::spawn(move || {
        for conn in listener.incoming() {
            let Ok(conn) = conn else { continue };
            conn.set_read_timeout(Some(Duration::from_secs(10)))
                .unwrap();
            let mut r = BufReader::new(conn);
            let mut line = String::new();
            if r.read_line(&mut line).is_err() {
                continue;
            }
            let path = line.split_whitespace().nth(1).unwrap_or("").to_string();
            let mut headers = HashMap::new();
            loop {
                let mut h = String::new();
                if r.read_line(&mut h).is_err() || h.trim().is_empty() {
                    break;
                }
                if let Some((k, v)) = h.split_once(':') {
                    headers.insert(k.trim().to_ascii_lowercase(), v.trim().to_string());
                }
            }
            let len: usize = headers
                .get("content-length")
                .and_then(|l| l.parse().ok())
                .unwrap_or(0);
            let mut body = vec![0; len];
            if r.read_exact(&mut body).is_err() {
                continue;
            }
            got.lock().unwrap().push(Got {
                path,
                headers,
                body: String::from_utf8_lossy(&body).into_owned(),
            });
            let _ = r
                .into_inner()
                .write_all(b"HTTP/1.1 200 OK\r\ncontent-length: 0\r\nconnection: close\r\n\r\n");
        }
    });
}

/// A counter of the coordinator's `/metrics`.
fn metric(http: &str, name: &str) -> u64 {
    let (code, text) = common::http::get(http, "/metrics", None);
    assert_eq!(code, 200, "{text}");
    text.lines()
        .find_map(|l| l.strip_prefix(name)?.strip_prefix(' ')?.parse().ok())
        .unwrap_or_else(|| panic!("no {name} in /metrics:\n{text}"))
}

#[test]
fn every_event_arrives_once_signed_and_in_order_after_the_receiver_was_down() {
    let dir = Dir::new();
    // A port with nothing listening: the receiver is down (refusing).
    let port = TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let secret = dir.write("secret", &format!("{SECRET}\n"));
    let all_url = format!("http://127.0.0.1:{port}/all");
    let job_url = format!("http://127.0.0.1:{port}/job");
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &[
            "--http",
            "127.0.0.1:0",
            "--events-url",
            &all_url,
            "--events-secret-file",
            secret.to_str().unwrap(),
        ],
        &[],
    );
    let http = c.http.clone().unwrap();
    // The monitor's event stream, open before anything happens.
    let mut sse = TcpStream::connect(&http).unwrap();
    sse.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
    write!(sse, "GET /events HTTP/1.1\r\nHost: {http}\r\n\r\n").unwrap();
    let _w = worker_with(&dir, &c.url, "worker0", &[], &[]);
    let scene = dir.write("scene.xml", &tiny_scene(1));
    let out = dir.path().join("shot.####.png");
    let o = submit(
        &dir,
        &[
            scene.to_str().unwrap(),
            "--coordinator",
            &c.url,
            "--frames",
            "1-3",
            "-o",
            out.to_str().unwrap(),
            "--notify",
            &job_url,
        ],
    );
    assert!(o.status.success(), "the render failed\n{}", dir.logs());
    // The job is over and the receiver was tried: its events wait.
    wait_for(&dir, "a failed delivery attempt", 60, || {
        metric(&http, "trevi_events_failed_attempts_total") >= 1
    });
    assert_eq!(metric(&http, "trevi_events_delivered_total"), 0);
    // The receiver opens on the same port.
    let got = Arc::new(Mutex::new(Vec::new()));
    let listener = TcpListener::bind(("127.0.0.1", port))
        .unwrap_or_else(|e| panic!("cannot listen on port {port} again: {e}"));
    receive(listener, got.clone());
    let finished = |path: &str| {
        got.lock()
            .unwrap()
            .iter()
            .any(|g| g.path == path && g.body.contains("\"event\":\"done\""))
    };
    wait_for(&dir, "both URLs' done events", 60, || {
        finished("/all") && finished("/job")
    });
    let got = got.lock().unwrap().clone();
    let mut by_path: HashMap<&str, Vec<Value>> = HashMap::new();
    for g in &got {
        // Signed: the body's HMAC-SHA256 under the secret.
        let sig = &g.headers["x-trevi-signature"];
        assert!(
            trevi_coordinator::events::verify(SECRET.as_bytes(), g.body.as_bytes(), sig),
            "bad signature {sig} of {}",
            g.body
        );
        let v: Value = serde_json::from_str(&g.body).unwrap();
        assert_eq!(g.headers["x-trevi-seq"], v["seq"].to_string());
        assert_eq!(g.headers["x-trevi-event"], v["event"].as_str().unwrap());
        by_path.entry(g.path.as_str()).or_default().push(v);
    }
    let all = &by_path["/all"];
    // Once each, in order: the sequence numbers 1, 2, ... as emitted.
    let seqs: Vec<u64> = all.iter().map(|v| v["seq"].as_u64().unwrap()).collect();
    assert_eq!(seqs, (1..=all.len() as u64).collect::<Vec<_>>(), "{all:?}");
    let kinds: Vec<&str> = all.iter().map(|v| v["event"].as_str().unwrap()).collect();
    assert_eq!(
        kinds,
        [
            "submitted",
            "started",
            "frame_done",
            "frame_done",
            "frame_done",
            "done"
        ],
        "{all:?}"
    );
    let job = all[0]["job"].as_u64().unwrap();
    assert!(all.iter().all(|v| v["job"] == job), "{all:?}");
    let mut frames: Vec<u64> = all.iter().filter_map(|v| v["frame"].as_u64()).collect();
    frames.sort();
    assert_eq!(frames, [1, 2, 3]);
    // The job's own URL got the same events.
    assert_eq!(&by_path["/job"], all);
    assert_eq!(got.len(), 2 * all.len());
    assert_eq!(metric(&http, "trevi_events_dropped_total"), 0);
    assert_eq!(
        metric(&http, "trevi_events_delivered_total"),
        got.len() as u64
    );
    // The monitor's stream carried the same events, numbered alike.
    let mut seen = String::new();
    let mut buf = [0u8; 4096];
    while !seen.contains("event: done") {
        let n = sse.read(&mut buf).unwrap();
        assert!(n > 0, "the event stream ended: {seen}");
        seen.push_str(&String::from_utf8_lossy(&buf[..n]));
    }
    let streamed: Vec<Value> = seen
        .lines()
        .filter_map(|l| l.trim_end().strip_prefix("data: "))
        .map(|d| serde_json::from_str(d).unwrap())
        .collect();
    assert_eq!(&streamed, all, "{seen}");
    for v in all {
        let id = format!("id: {}", v["seq"]);
        assert!(seen.contains(&id), "no {id} in the stream:\n{seen}");
    }
}

#[test]
fn a_notify_url_that_is_not_http_is_refused_and_nothing_is_queued() {
    let dir = Dir::new();
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let scene = dir.write("scene.xml", &tiny_scene(2));
    let long = format!("http://example.com/{}", "a".repeat(3000));
    for (url, says) in [
        ("file:///etc/passwd", "only http:// and https://"),
        ("ftp://example.com/x", "only http:// and https://"),
        (long.as_str(), "more than the 2048 allowed"),
    ] {
        let o = submit(
            &dir,
            &[
                scene.to_str().unwrap(),
                "--coordinator",
                &c.url,
                "--detach",
                "--notify",
                url,
            ],
        );
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{url} was taken\n{}", dir.logs());
        assert!(err.contains("--notify") && err.contains(says), "{err}");
    }
    let rt = common::runtime();
    let list = rt.block_on(async {
        common::jobs(&c, None)
            .await
            .list_jobs(trevi_proto::pb::ListJobsRequest::default())
            .await
            .unwrap()
            .into_inner()
    });
    assert!(list.jobs.is_empty(), "{list:?}");
}
