//! The web monitor end to end: a real coordinator serving `--http`, a real
//! worker, `trevi-submit`, and headless Chromium driven over WebDriver
//! (`chromedriver`, through the `fantoccini` client).
//!
//! The browser test needs Debian's `chromium` and `chromium-driver`
//! packages (see [`common::browser`]).
//!
//! The screenshot the browser test takes is kept in
//! `target/test-artifacts/monitor.png` (or `$TREVI_ARTIFACTS_DIR`).

mod common;

use common::browser::{self, poll};
use common::http::{get as http_get, parse_response};
use common::{coordinator_with, make_certs, submit, worker_with, Coordinator, Dir, Proc};
use serde_json::json;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::Duration;
use trevi_core::output::decode_png;

const SUBMIT_TOKEN: &str = "submit-s3cret";
const WORKER_TOKEN: &str = "worker-s3cret";

/// The shared slow scene made bigger, so that the job is still running while
/// the browser watches it (about two minutes of rendering on this project's
/// 2-core machines): 1200 tiles of 32×32 at supersample 8 with soft shadows
/// and ambient occlusion, on one render thread.
fn browser_scene() -> String {
    let scene = common::SLOW_SCENE.replace(
        r#"width="96" height="64" supersample="6""#,
        r#"width="1280" height="960" supersample="8""#,
    );
    assert!(
        scene.contains(r#"width="1280""#),
        "the shared scene changed"
    );
    scene
}

/// A small frame for the metrics test: 4×3 tiles of 16×16.
const SMALL_SCENE: &str = r#"<scene version="1">
  <settings background="0.1 0.1 0.2" ambient="0.1 0.1 0.1"/>
  <sphere id="ball" center="0 1 0" radius="1"> <surface diffuse="0.8 0.3 0.2"/> </sphere>
  <plane id="ground" point="0 0 0" normal="0 1 0"> <surface diffuse="0.5 0.5 0.5"/> </plane>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1"/>
  <camera id="main" position="0 2 6" lookat="0 1 0" up="0 1 0" fov="50">
    <render width="64" height="48" output="small.png"/>
  </camera>
</scene>
"#;

/// A coordinator with tokens and the HTTP monitor, and one worker with one
/// render thread.
struct Farm {
    dir: Dir,
    c: Coordinator,
    _worker: Proc,
}

impl Farm {
    fn start() -> Farm {
        let dir = Dir::new();
        let c = coordinator_with(
            &dir,
            "127.0.0.1:0",
            "coordinator",
            &[
                "--http",
                "127.0.0.1:0",
                "--submit-token",
                SUBMIT_TOKEN,
                "--worker-token",
                WORKER_TOKEN,
            ],
            &[],
        );
        let worker = worker_with(&dir, &c.url, "worker", &["--token", WORKER_TOKEN], &[]);
        Farm {
            dir,
            c,
            _worker: worker,
        }
    }

    fn http(&self) -> &str {
        self.c.http.as_deref().expect("started with --http")
    }

    /// `trevi-submit ARGS --coordinator URL --token T`; panics with the
    /// logs unless it succeeds; returns its standard output.
    fn submit(&self, args: &[&str]) -> String {
        let mut all = args.to_vec();
        all.extend(["--coordinator", &self.c.url, "--token", SUBMIT_TOKEN]);
        let out = submit(&self.dir, &all);
        assert!(
            out.status.success(),
            "trevi-submit {args:?} failed\n{}",
            self.dir.logs()
        );
        String::from_utf8_lossy(&out.stdout).to_string()
    }
}

#[test]
fn metrics_parse_as_prometheus_text_and_count_the_tiles_and_the_preview_file_shows_the_frame() {
    let farm = Farm::start();
    // Open endpoints: no token needed.
    let (code, body) = http_get(farm.http(), "/healthz", None);
    assert_eq!(code, 200, "{body}");
    assert!(body.starts_with("ok"), "{body}");
    // The API is a submitter's business.
    assert_eq!(http_get(farm.http(), "/api/state", None).0, 401);
    assert_eq!(
        http_get(farm.http(), "/api/state", Some(WORKER_TOKEN)).0,
        403
    );

    let scene = farm.dir.write("small.xml", SMALL_SCENE);
    let out = farm.dir.path().join("small.png");
    let live = farm.dir.path().join("live.png");
    farm.submit(&[
        scene.to_str().unwrap(),
        "--quiet",
        "--tile",
        "16",
        "-o",
        out.to_str().unwrap(),
        "--preview",
        live.to_str().unwrap(),
    ]);
    assert!(out.is_file(), "the image was downloaded");
    // --preview kept the finished job's preview: the whole 64×48 frame
    // (no shrinking below 512 pixels), every pixel reached, and the same
    // picture as the frame itself.
    let (w, h, rgba) = decode_png(&std::fs::read(&live).unwrap()).unwrap();
    assert_eq!((w, h), (64, 48));
    assert!(rgba.chunks(4).all(|p| p[3] == 255));
    let (_, _, frame) = decode_png(&std::fs::read(&out).unwrap()).unwrap();
    let rgb: Vec<u8> = rgba.chunks(4).flat_map(|p| [p[0], p[1], p[2]]).collect();
    assert_eq!(rgb, frame, "at scale 1 the preview is the frame");
    // `status ID --preview FILE` writes the same image once.
    let again = farm.dir.path().join("again.png");
    let said = farm.submit(&["status", "1", "--preview", again.to_str().unwrap()]);
    assert!(said.contains("preview: 64x48, 12 tiles"), "{said}");
    assert_eq!(
        std::fs::read(&again).unwrap(),
        std::fs::read(&live).unwrap()
    );
    let status = farm.submit(&["status", "1"]);
    assert!(status.contains("done"), "{status}");

    // The job as the API sees it.
    let (code, body) = http_get(farm.http(), "/api/state", Some(SUBMIT_TOKEN));
    assert_eq!(code, 200, "{body}");
    let state: serde_json::Value = serde_json::from_str(&body).unwrap();
    let job = &state["jobs"][0];
    assert_eq!(job["state"], "done");
    let tiles = job["tiles_total"].as_u64().unwrap();
    assert_eq!(tiles, 4 * 3);
    let rays = job["rays"].as_u64().unwrap();
    assert!(rays >= 64 * 48, "{rays} rays for 64×48 pixels");

    let (code, text) = http_get(farm.http(), "/metrics", None);
    assert_eq!(code, 200, "{text}");
    // Every line is a comment, or a sample the parser understands.
    for line in text.lines() {
        let info = prometheus_parse::LineInfo::parse(line);
        assert!(
            !matches!(info, prometheus_parse::LineInfo::Ignored),
            "not Prometheus text: {line:?}"
        );
        if let prometheus_parse::LineInfo::Sample { value, .. } = info {
            assert!(value.parse::<f64>().is_ok(), "bad value in {line:?}");
        }
    }
    let scrape = prometheus_parse::Scrape::parse(text.lines().map(|l| Ok(l.to_string()))).unwrap();
    let value = |name: &str, label: Option<(&str, &str)>| -> f64 {
        let s = scrape
            .samples
            .iter()
            .find(|s| s.metric == name && label.is_none_or(|(k, v)| s.labels.get(k) == Some(v)))
            .unwrap_or_else(|| panic!("no {name} {label:?} in\n{text}"));
        match s.value {
            prometheus_parse::Value::Counter(v)
            | prometheus_parse::Value::Gauge(v)
            | prometheus_parse::Value::Untyped(v) => v,
            ref other => panic!("{name} is {other:?}"),
        }
    };
    assert_eq!(value("trevi_tiles_rendered_total", None), tiles as f64);
    assert_eq!(value("trevi_rays_total", None), rays as f64);
    assert!(value("trevi_leases_granted_total", None) >= tiles as f64);
    assert_eq!(value("trevi_jobs_submitted_total", None), 1.0);
    assert_eq!(value("trevi_jobs", Some(("state", "done"))), 1.0);
    assert_eq!(value("trevi_queue_depth_jobs", None), 0.0);
    let workers: f64 = ["busy", "idle", "lost"]
        .iter()
        .map(|s| value("trevi_workers", Some(("state", s))))
        .sum();
    assert_eq!(workers, 1.0);
    // Tile results arrive in SubmitTile calls, timed by the histogram.
    let submit_tile = scrape
        .samples
        .iter()
        .find(|s| {
            s.metric == "trevi_grpc_request_duration_seconds"
                && s.labels.get("method") == Some("trevi.v1.Workers/SubmitTile")
        })
        .expect("SubmitTile latencies");
    let prometheus_parse::Value::Histogram(buckets) = &submit_tile.value else {
        panic!("{:?} is not a histogram", submit_tile.value);
    };
    let inf = buckets
        .iter()
        .find(|b| b.less_than.is_infinite())
        .expect("+Inf bucket");
    // A worker may be leased a span of adjacent tiles (lease sizing) and
    // upload it in one call: at least one call, never more than tiles.
    assert!(
        inf.count >= 1.0 && inf.count <= tiles as f64,
        "{} SubmitTile calls for {tiles} tiles",
        inf.count
    );
    assert!(buckets.windows(2).all(|w| w[0].count <= w[1].count));
}

/// Draws the preview `<img>` on a canvas in the page and counts its opaque
/// pixels: what the browser actually shows, not what the server sent.
const COUNT_OPAQUE_JS: &str = r#"
const img = document.getElementById(arguments[0]);
if (!img || !img.complete || !img.naturalWidth) return [0, 0];
const c = document.createElement("canvas");
c.width = img.naturalWidth; c.height = img.naturalHeight;
const g = c.getContext("2d");
g.drawImage(img, 0, 0);
const d = g.getImageData(0, 0, c.width, c.height).data;
let n = 0;
for (let i = 3; i < d.length; i += 4) if (d[i] === 255) n++;
return [n, c.width * c.height];
"#;

#[test]
fn the_monitor_shows_a_live_preview_and_its_buttons_change_priority_and_cancel() {
    let Some((chromium, chromedriver)) = browser::browser() else {
        common::skip(browser::SKIP_MESSAGE);
        return;
    };
    let farm = Farm::start();
    let scene = farm.dir.write("slow.xml", &browser_scene());
    let out = farm.submit(&[scene.to_str().unwrap(), "--detach", "--tile", "32"]);
    let job: u64 = out.trim().parse().expect("--detach prints the job id");

    let f = &farm;
    let shot = browser::with_browser(&farm.dir, &chromium, &chromedriver, |c| async move {
        drive(&c, f, job).await
    });
    let shot = shot.unwrap_or_else(|e| panic!("{e}\n{}", farm.dir.logs()));
    browser::keep_screenshot("monitor.png", &shot);

    // The coordinator itself says the job is cancelled, and it left no output.
    let status = farm.submit(&["status", &job.to_string()]);
    assert!(status.contains("cancelled"), "{status}");
    let outputs = std::fs::read_dir(farm.c.data.join("jobs").join(job.to_string()))
        .map(|d| d.count())
        .unwrap_or(0);
    assert_eq!(outputs, 0, "a cancelled job leaves no output");
    // And the worker stops working on it: idle again within a heartbeat or two.
    common::wait_for(&farm.dir, "the worker to go idle", 30, || {
        let (_, body) = http_get(farm.http(), "/api/state", Some(SUBMIT_TOKEN));
        serde_json::from_str::<serde_json::Value>(&body)
            .is_ok_and(|s| s["workers"][0]["state"] == "idle")
    });
}

/// The browser part: returns the screenshot, or what went wrong.
async fn drive(c: &fantoccini::Client, farm: &Farm, job: u64) -> Result<Vec<u8>, String> {
    use fantoccini::Locator;
    let err = |what: &str| {
        let what = what.to_string();
        move |e: fantoccini::error::CmdError| format!("{what}: {e}")
    };
    browser::open_monitor(c, farm.http(), SUBMIT_TOKEN).await?;

    let card = format!("job-{job}");
    let progress = |c: fantoccini::Client, card: String| async move {
        let t = c
            .find(Locator::Css(&format!("#{card} .progress")))
            .await
            .ok()?
            .text()
            .await
            .ok()?;
        // "12 / 1200 tiles"
        let (done, rest) = t.split_once(" / ")?;
        let total: u64 = rest.split_whitespace().next()?.parse().ok()?;
        Some((done.parse::<u64>().ok()?, total))
    };
    // The preview shows part of the frame...
    let preview_id = format!("preview-{job}");
    let (shown, total_px) = poll(c, "the preview to show part of the frame", |c| {
        let id = preview_id.clone();
        async move {
            let v = c.execute(COUNT_OPAQUE_JS, vec![json!(id)]).await.ok()?;
            let n = v.get(0)?.as_u64()?;
            let total = v.get(1)?.as_u64()?;
            (n > 0).then_some((n, total))
        }
    })
    .await?;
    assert!(
        shown < total_px,
        "the job must still be running ({shown} of {total_px} pixels)"
    );
    // ...and the progress moves.
    let (first, total) = poll(c, "the progress", |c| progress(c, card.clone())).await?;
    let (later, _) = poll(c, "the progress to move", |c| {
        let card = card.clone();
        async move { progress(c, card).await.filter(|&(d, _)| d > first) }
    })
    .await?;
    assert!(
        later < total,
        "the job finished before the test could cancel it"
    );
    let shot = c.screenshot().await.map_err(err("the screenshot"))?;

    // Raise the priority from the page: the coordinator takes it.
    browser::click(c, &format!("#{card} .prio-up")).await?;
    poll(c, "the coordinator to raise the priority", |_| async {
        let (_, body) = http_get(farm.http(), "/api/state", Some(SUBMIT_TOKEN));
        let s: serde_json::Value = serde_json::from_str(&body).ok()?;
        let j = s["jobs"]
            .as_array()?
            .iter()
            .find(|j| j["id"] == job)?
            .clone();
        (j["priority"] == 1).then_some(())
    })
    .await?;

    // Cancel from the page.
    browser::click(c, &format!("#{card} .cancel")).await?;
    poll(c, "the page to show the job cancelled", |c| {
        let card = card.clone();
        async move {
            let s = c
                .find(Locator::Css(&format!("#{card} .state")))
                .await
                .ok()?
                .text()
                .await
                .ok()?;
            (s == "cancelled").then_some(())
        }
    })
    .await?;
    Ok(shot)
}

/// One HTTP/1.1 GET over TLS to the coordinator's monitor, trusting only
/// `ca` and expecting the certificate to name `localhost`.
async fn https_get(
    addr: &str,
    ca: &std::path::Path,
    path: &str,
    token: Option<&str>,
) -> std::io::Result<(u16, String)> {
    use rustls::pki_types::{pem::PemObject, CertificateDer, ServerName};
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut roots = rustls::RootCertStore::empty();
    for c in CertificateDer::pem_file_iter(ca).unwrap() {
        roots.add(c.unwrap()).unwrap();
    }
    let config = rustls::ClientConfig::builder_with_provider(std::sync::Arc::new(
        rustls::crypto::ring::default_provider(),
    ))
    .with_safe_default_protocol_versions()
    .unwrap()
    .with_root_certificates(roots)
    .with_no_client_auth();
    let connector = tokio_rustls::TlsConnector::from(std::sync::Arc::new(config));
    let tcp = tokio::net::TcpStream::connect(addr).await?;
    let mut tls = connector
        .connect(ServerName::try_from("localhost").unwrap(), tcp)
        .await?;
    let auth = token
        .map(|t| format!("Authorization: Bearer {t}\r\n"))
        .unwrap_or_default();
    tls.write_all(
        format!("GET {path} HTTP/1.1\r\nHost: localhost\r\n{auth}Connection: close\r\n\r\n")
            .as_bytes(),
    )
    .await?;
    let mut raw = Vec::new();
    // A server may close without close_notify; what arrived is enough.
    let _ = tls.read_to_end(&mut raw).await;
    Ok(parse_response(&String::from_utf8_lossy(&raw)))
}

#[test]
fn with_tls_the_monitor_is_served_over_https_with_the_coordinator_s_certificate() {
    let dir = Dir::new();
    let Some(certs) = make_certs(&dir, "certs") else {
        return;
    };
    let s = |f: &str| certs.join(f).to_str().unwrap().to_string();
    let (cert, key) = (s("coordinator.pem"), s("coordinator.key"));
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &[
            "--http",
            "127.0.0.1:0",
            "--tls-cert",
            &cert,
            "--tls-key",
            &key,
            "--submit-token",
            SUBMIT_TOKEN,
        ],
        &[],
    );
    let http = c.http.clone().expect("--http");
    let ca = certs.join("ca.pem");
    let rt = common::runtime();
    rt.block_on(async {
        let (code, body) = https_get(&http, &ca, "/healthz", None).await.unwrap();
        assert_eq!((code, body.starts_with("ok")), (200, true), "{body}");
        let (code, _) = https_get(&http, &ca, "/api/state", None).await.unwrap();
        assert_eq!(code, 401, "the API still wants the token");
        let (code, body) = https_get(&http, &ca, "/api/state", Some(SUBMIT_TOKEN))
            .await
            .unwrap();
        assert_eq!(code, 200, "{body}");
        // A client that does not trust the farm's CA gets no answer.
        let other = make_certs(&dir, "other").unwrap();
        assert!(https_get(&http, &other.join("ca.pem"), "/healthz", None)
            .await
            .is_err());
    });
    // Plain HTTP to the monitor gets no page (the token would travel in
    // the clear).
    let mut s = TcpStream::connect(&http).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(15))).unwrap();
    let _ = write!(
        s,
        "GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
    );
    let mut raw = Vec::new();
    let _ = s.read_to_end(&mut raw);
    assert!(
        !String::from_utf8_lossy(&raw).contains("200 OK"),
        "plain HTTP was served: {}",
        String::from_utf8_lossy(&raw)
    );
    drop(c);
}
