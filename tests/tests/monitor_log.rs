//! The monitor's tile log and blocklists: over HTTP (`GET
//! /api/jobs/{id}/log`, `POST /api/jobs/{id}/unblock`, the blocked workers
//! in `/api/state`), and in headless Chromium (see [`common::browser`]): a
//! click on a tile of the preview shows that tile's log, the job card lists
//! the worker kept from the job with an "unblock" button and the job's
//! errors. The screenshot is kept as `monitor-log.png` in
//! `target/test-artifacts` (or `$TREVI_ARTIFACTS_DIR`).

mod common;

use common::browser::{self, poll};
use common::http::{get as http_get, post as http_post};
use common::*;
use serde_json::{json, Value};

const TOKEN: &str = "submit-s3cret";

/// A 384×256 frame in 24 tiles of 64, cheap to render.
fn scene() -> String {
    let s = SLOW_SCENE.replace(
        r#"width="96" height="64" supersample="6" shadow-samples="8" ao-samples="16""#,
        r#"width="384" height="256" supersample="1" shadow-samples="2" ao-samples="2""#,
    );
    assert!(s.contains(r#"width="384""#), "the shared scene changed");
    s
}

/// A farm with the monitor where `bad` fails every tile of the one job
/// submitted and `good` renders it slowly (3 s a lease, so that it runs
/// while the test looks at it); returns the farm, its workers and the job.
fn farm(dir: &Dir) -> (Coordinator, Proc, Proc, u64) {
    let c = coordinator_with(
        dir,
        "127.0.0.1:0",
        "coordinator",
        &[
            "--http",
            "127.0.0.1:0",
            "--submit-token",
            TOKEN,
            "--max-worker-failures",
            "2",
            "--max-tile-failures",
            "100",
            "--lease-target-ms",
            "100",
        ],
        &[],
    );
    let path = dir.write("s.xml", &scene());
    let o = submit(
        dir,
        &[
            path.to_str().unwrap(),
            "--coordinator",
            &c.url,
            "--token",
            TOKEN,
            "--detach",
            "--tile",
            "64",
        ],
    );
    assert!(o.status.success(), "{}", dir.logs());
    let job: u64 = String::from_utf8_lossy(&o.stdout).trim().parse().unwrap();
    let good = worker_with(
        dir,
        &c.url,
        "good",
        &[],
        &[("TREVI_TEST_LEASE_DELAY_MS", "3000")],
    );
    let bad = worker_with(
        dir,
        &c.url,
        "bad",
        &[],
        &[("TREVI_TEST_FAIL_JOB", &job.to_string())],
    );
    (c, good, bad, job)
}

/// `GET path` on the monitor with the token, as JSON.
fn api(c: &Coordinator, path: &str) -> (u16, Value) {
    let (code, body) = http_get(c.http.as_deref().unwrap(), path, Some(TOKEN));
    (code, serde_json::from_str(&body).unwrap_or(Value::Null))
}

/// The top-left corner of a tile `bad` failed that `good` then rendered,
/// once there is one.
fn retried_tile(c: &Coordinator, job: u64) -> Option<(u64, u64)> {
    let (_, log) = api(c, &format!("/api/jobs/{job}/log"));
    let entries = log["entries"].as_array()?;
    let at = |e: &Value, k: &str| e[k].as_u64().unwrap_or(0);
    entries
        .iter()
        .filter(|e| !e["error"].is_null())
        .find_map(|f| {
            let (x, y) = (at(f, "x"), at(f, "y"));
            entries
                .iter()
                .any(|e| {
                    e["error"].is_null()
                        && (at(e, "x")..at(e, "x") + at(e, "w")).contains(&x)
                        && (at(e, "y")..at(e, "y") + at(e, "h")).contains(&y)
                })
                .then_some((x, y))
        })
}

#[test]
fn the_api_gives_the_log_and_unblocks_and_refuses_what_is_wrong() {
    let dir = Dir::new();
    let (c, _good, _bad, job) = farm(&dir);
    let http = c.http.clone().unwrap();
    wait_for(&dir, "a retried tile", 120, || {
        retried_tile(&c, job).is_some()
    });
    let (_, state) = api(&c, "/api/state");
    let card = state["jobs"]
        .as_array()
        .unwrap()
        .iter()
        .find(|j| j["id"] == job)
        .unwrap()
        .clone();
    assert_eq!(card["blocked"][0]["name"], "bad", "{card}");
    assert!(card["blocked"][0]["last_error"]
        .as_str()
        .unwrap()
        .contains("test fault"));
    // The tile at pixel (0, 0) and the failures only.
    let (code, log) = api(&c, &format!("/api/jobs/{job}/log?x=0&y=0"));
    assert_eq!(code, 200, "{log}");
    for e in log["entries"].as_array().unwrap() {
        assert_eq!(
            (e["x"].as_u64(), e["y"].as_u64()),
            (Some(0), Some(0)),
            "{e}"
        );
    }
    let (_, errors) = api(&c, &format!("/api/jobs/{job}/log?errors=1"));
    let errors = errors["entries"].as_array().unwrap().clone();
    assert!(errors.len() >= 2);
    assert!(
        errors.iter().all(|e| e["worker_name"] == "bad"),
        "{errors:?}"
    );
    // Bad queries and unblocks are refused, naming why.
    for (path, code) in [
        (format!("/api/jobs/{job}/log?tile=1"), 400),
        (format!("/api/jobs/{job}/log?x=1"), 400),
        (
            format!("/api/jobs/{job}/log?{}", "errors=1&".repeat(20)),
            400,
        ),
        ("/api/jobs/999999/log".to_string(), 404),
    ] {
        assert_eq!(api(&c, &path).0, code, "{path}");
    }
    assert_eq!(
        http_get(&http, &format!("/api/jobs/{job}/log"), None).0,
        401
    );
    let json_auth = [
        "Content-Type: application/json".to_string(),
        format!("Authorization: Bearer {TOKEN}"),
    ];
    let h: Vec<&str> = json_auth.iter().map(String::as_str).collect();
    let unblock =
        |id: u64, body: &str| http_post(&http, &format!("/api/jobs/{id}/unblock"), &h, body);
    assert_eq!(unblock(job, r#"{"worker": ""}"#).0, 400);
    assert_eq!(unblock(999_999, r#"{"worker": "bad"}"#).0, 404);
    let (code, body) = unblock(job, r#"{"worker": "good"}"#);
    assert_eq!(code, 409, "{body}");
    assert!(body.contains("no worker"), "{body}");
    // Unblocked, bad takes the job's tiles (and fails them) again.
    let (code, body) = unblock(job, &json!({ "worker": "bad" }).to_string());
    assert_eq!(code, 200, "{body}");
    wait_for(&dir, "bad to fail again", 120, || {
        let (_, l) = api(&c, &format!("/api/jobs/{job}/log?errors=1"));
        l["entries"].as_array().map_or(0, Vec::len) > errors.len()
    });
}

/// Returns the viewport position, in CSS pixels, of frame pixel (`x`, `y`)
/// of a `width`×`height` frame in the preview image `id` (scrolled into
/// view first), once the image has loaded.
const PREVIEW_POINT_JS: &str = r#"
const [id, x, y, width, height] = arguments;
const img = document.getElementById(id);
if (!img || !img.naturalWidth) return null;
img.scrollIntoView({ block: "center" });
const r = img.getBoundingClientRect();
return [r.left + (x + 0.5) / width * r.width, r.top + (y + 0.5) / height * r.height];
"#;

#[test]
fn clicking_a_preview_tile_shows_its_log_and_the_card_lists_blocks_and_errors() {
    let Some((chromium, chromedriver)) = browser::browser() else {
        common::skip(browser::SKIP_MESSAGE);
        return;
    };
    let dir = Dir::new();
    let (c, _good, _bad, job) = farm(&dir);
    wait_for(&dir, "a retried tile", 120, || {
        retried_tile(&c, job).is_some()
    });
    let (tx, ty) = retried_tile(&c, job).unwrap();
    let http = c.http.clone().unwrap();
    let shot = browser::with_browser(&dir, &chromium, &chromedriver, |b| {
        let http = http.clone();
        async move { drive(&b, &http, job, (tx + 8, ty + 8)).await }
    });
    let shot = shot.unwrap_or_else(|e| panic!("{e}\n{}", dir.logs()));
    browser::keep_screenshot("monitor-log.png", &shot);
}

/// The browser part: returns the screenshot, or what went wrong.
async fn drive(
    b: &fantoccini::Client,
    http: &str,
    job: u64,
    (x, y): (u64, u64),
) -> Result<Vec<u8>, String> {
    use fantoccini::actions::{InputSource, MouseActions, PointerAction, MOUSE_BUTTON_LEFT};
    browser::open_monitor(b, http, TOKEN).await?;
    let card = format!("#job-{job}");
    poll(b, "the card to list bad as blocked", |b| {
        let css = format!("{card} .bl-blocked li");
        async move {
            browser::text_of(&b, &css)
                .await
                .filter(|t| t.contains("bad #"))
        }
    })
    .await?;
    let at = poll(b, "the preview to load", |b| async move {
        let v = b
            .execute(
                PREVIEW_POINT_JS,
                vec![
                    json!(format!("preview-{job}")),
                    json!(x),
                    json!(y),
                    json!(384),
                    json!(256),
                ],
            )
            .await
            .ok()?;
        Some((v.get(0)?.as_f64()?, v.get(1)?.as_f64()?))
    })
    .await?;
    // A real click on the tile.
    let click = MouseActions::new("mouse".into())
        .then(PointerAction::MoveTo {
            duration: None,
            x: at.0.round(),
            y: at.1.round(),
        })
        .then(PointerAction::Down {
            button: MOUSE_BUTTON_LEFT,
        })
        .then(PointerAction::Up {
            button: MOUSE_BUTTON_LEFT,
        });
    b.perform_actions(click)
        .await
        .map_err(browser::err("clicking the preview"))?;
    let rows = poll(b, "the tile's log in the panel", |b| async move {
        let t = browser::text_of(&b, "#tile-log-rows").await?;
        (t.contains("good #") && t.contains("test fault")).then_some(t)
    })
    .await?;
    let title = browser::text_of(b, "#tile-log-title")
        .await
        .unwrap_or_default();
    // The title is upper-cased by the page's CSS (text-transform).
    if !title.to_lowercase().contains(&format!("job {job}")) {
        return Err(format!("the panel's title is {title:?}; rows {rows:?}"));
    }
    // The card's errors, once opened.
    browser::click(b, &format!("{card} .bl-errors summary")).await?;
    poll(b, "the card's errors", |b| {
        let css = format!("{card} .bl-errors li");
        async move {
            browser::text_of(&b, &css)
                .await
                .filter(|t| t.contains("test fault"))
        }
    })
    .await?;
    let shot = b
        .screenshot()
        .await
        .map_err(browser::err("the screenshot"))?;
    // The unblock button reaches the coordinator: bad is let back (and is
    // soon kept from the job again, failing two more tiles).
    let before = errors(http, job);
    browser::click(b, &format!("{card} .bl-blocked button.unblock")).await?;
    poll(b, "bad to fail the job's tiles again", |_| async move {
        (errors(http, job) > before).then_some(())
    })
    .await?;
    Ok(shot)
}

/// How many failures job `job`'s log holds.
fn errors(http: &str, job: u64) -> usize {
    let (_, body) = http_get(http, &format!("/api/jobs/{job}/log?errors=1"), Some(TOKEN));
    serde_json::from_str::<Value>(&body)
        .ok()
        .and_then(|v| v["entries"].as_array().map(Vec::len))
        .unwrap_or(0)
}
