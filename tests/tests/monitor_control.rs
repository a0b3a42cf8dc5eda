//! The monitor's job control (docs/farm.md, "Running a farm"): over HTTP
//! (`POST /api/jobs/{id}/requeue` and `.../retry`, their hostile input),
//! and in headless Chromium (see [`common::browser`]): the job card's
//! Pause, Resume, Retry and Requeue buttons reach the coordinator. The
//! screenshot is kept as `monitor-control.png` in `target/test-artifacts`
//! (or `$TREVI_ARTIFACTS_DIR`).

mod common;

use common::browser::{self, poll};
use common::http::{get as http_get, post as http_post};
use common::*;
use serde_json::Value;
use std::path::{Path, PathBuf};
use trevi_core::{FrameWriter, Rect};

const TOKEN: &str = "submit-s3cret";

fn farm(dir: &Dir) -> Coordinator {
    coordinator_with(
        dir,
        "127.0.0.1:0",
        "coordinator",
        // Leases of one tile while a lease takes over 0.1 s: the slow
        // worker's job runs while the browser pauses it.
        &[
            "--http",
            "127.0.0.1:0",
            "--submit-token",
            TOKEN,
            "--lease-target-ms",
            "100",
        ],
        &[],
    )
}

/// Submits `scene` (tiles of 16) with the token; its id.
fn submit_job(dir: &Dir, c: &Coordinator, scene: &Path) -> u64 {
    let o = submit(
        dir,
        &[
            scene.to_str().unwrap(),
            "--coordinator",
            &c.url,
            "--token",
            TOKEN,
            "--detach",
            "--tile",
            "16",
        ],
    );
    assert!(o.status.success(), "{}", dir.logs());
    String::from_utf8_lossy(&o.stdout).trim().parse().unwrap()
}

/// Job `id`'s card in `/api/state`.
fn card(c: &Coordinator, id: u64) -> Value {
    let (_, body) = http_get(c.http.as_deref().unwrap(), "/api/state", Some(TOKEN));
    let state: Value = serde_json::from_str(&body).unwrap_or(Value::Null);
    state["jobs"]
        .as_array()
        .and_then(|jobs| jobs.iter().find(|j| j["id"] == id).cloned())
        .unwrap_or(Value::Null)
}

fn wait_card(dir: &Dir, c: &Coordinator, id: u64, what: &str, f: impl Fn(&Value) -> bool) {
    wait_for(dir, &format!("job {id} {what}"), 120, || f(&card(c, id)));
}

fn output(c: &Coordinator, id: u64) -> PathBuf {
    c.data.join(format!("jobs/{id}/still.png"))
}

/// Job `id`'s output with the pixels of tile (1, 1) painted over.
fn damage(c: &Coordinator, id: u64) {
    let path = output(c, id);
    let (w, h, px) = trevi_core::output::read_png_rgb8(&path).unwrap();
    let mut bytes: Vec<u8> = px.iter().flatten().copied().collect();
    for y in 16..32 {
        for x in 16..32 {
            let i = 3 * (y * w as usize + x);
            bytes[i..i + 3].copy_from_slice(&[255, 0, 255]);
        }
    }
    let mut f = FrameWriter::create(&path, w, h).unwrap();
    f.write_tile_srgb8(Rect::new(0, 0, w, h), &bytes).unwrap();
    f.finish().unwrap();
}

#[test]
fn the_api_requeues_and_retries_and_refuses_what_is_wrong() {
    let dir = Dir::new();
    let c = farm(&dir);
    let http = c.http.clone().unwrap();
    let _w = worker_with(&dir, &c.url, "worker0", &[], &[]);
    let scene = dir.write("still.xml", QUICK_STILL);
    let id = submit_job(&dir, &c, &scene);
    wait_card(&dir, &c, id, "done", |j| j["state"] == "done");
    let expected = std::fs::read(output(&c, id)).unwrap();
    let json_auth = [
        "Content-Type: application/json".to_string(),
        format!("Authorization: Bearer {TOKEN}"),
    ];
    let h: Vec<&str> = json_auth.iter().map(String::as_str).collect();
    let post = |path: &str, body: &str| http_post(&http, path, &h, body);
    let requeue = format!("/api/jobs/{id}/requeue");

    // A rect: the damaged tile is rendered again, the bytes the first's.
    damage(&c, id);
    assert_ne!(std::fs::read(output(&c, id)).unwrap(), expected);
    let (code, body) = post(&requeue, r#"{"rect": [20, 18, 5, 3]}"#);
    assert_eq!(code, 200, "{body}");
    wait_for(&dir, "the output mended", 120, || {
        card(&c, id)["state"] == "done" && std::fs::read(output(&c, id)).unwrap() == expected
    });

    // Refused, naming why; the job untouched.
    let big = format!(r#"{{"rect": [0, 0, 1, 1]{}}}"#, " ".repeat(1100));
    let retry = format!("/api/jobs/{id}/retry");
    let requeue = requeue.as_str();
    for (path, body, code, says) in [
        (
            requeue,
            r#"{"rect": [60, 40, 10, 10]}"#,
            400,
            "not inside the 64x48 frame",
        ),
        (requeue, r#"{"rect": [0, 0, 0, 1]}"#, 400, "is empty"),
        (requeue, r#"{"rect": [1, 2, 3]}"#, 400, "four numbers"),
        (
            requeue,
            r#"{"rect": [1, 2, 3, 99999999999]}"#,
            400,
            "whole number",
        ),
        (requeue, r#"{"x": 1}"#, 400, "unknown key"),
        (
            requeue,
            r#"{"frames": "1-2"}"#,
            400,
            "--frames takes a sequence",
        ),
        (requeue, r#"{"frames": "2-1"}"#, 400, "A <= B"),
        (requeue, "not json", 400, "expected '{'"),
        (requeue, big.as_str(), 413, "longer than 1024 bytes"),
        ("/api/jobs/999999/requeue", "{}", 404, "no job 999999"),
        (retry.as_str(), "{}", 409, "retry takes a failed job"),
    ] {
        let (got, text) = post(path, body);
        assert_eq!(got, code, "{path} {body}: {text}");
        assert!(text.contains(says), "{path} {body}: {text}");
    }
    // The token and a JSON body are needed, as for every button.
    let (code, _) = http_post(&http, requeue, &["Content-Type: application/json"], "{}");
    assert_eq!(code, 401);
    let auth = format!("Authorization: Bearer {TOKEN}");
    let (code, _) = http_post(&http, requeue, &[&auth], "{}");
    assert_eq!(code, 415);
    assert_eq!(card(&c, id)["state"], "done");
    assert_eq!(std::fs::read(output(&c, id)).unwrap(), expected);
}

#[test]
fn the_job_cards_buttons_pause_resume_retry_and_requeue() {
    let Some((chromium, chromedriver)) = browser::browser() else {
        common::skip(browser::SKIP_MESSAGE);
        return;
    };
    let dir = Dir::new();
    let c = farm(&dir);
    let still = dir.write("still.xml", QUICK_STILL);
    // Job 1 done; job 2 fails (a directory stands where its file goes);
    // job 3 runs slowly while the browser pauses and resumes it.
    let _w = worker_with(
        &dir,
        &c.url,
        "worker0",
        &[],
        &[("TREVI_TEST_LEASE_DELAY_MS", "1000")],
    );
    let done = submit_job(&dir, &c, &still);
    wait_card(&dir, &c, done, "done", |j| j["state"] == "done");
    let expected = std::fs::read(output(&c, done)).unwrap();
    let failing = done + 1;
    std::fs::create_dir_all(output(&c, failing)).unwrap();
    assert_eq!(submit_job(&dir, &c, &still), failing);
    wait_card(&dir, &c, failing, "failed", |j| j["state"] == "failed");
    let slow = dir.write("slow.xml", SLOW_SCENE);
    let running = submit_job(&dir, &c, &slow);
    let http = c.http.clone().unwrap();
    let shot = browser::with_browser(&dir, &chromium, &chromedriver, |b| {
        let (http, c, dir) = (http.clone(), &c, &dir);
        let expected = expected.clone();
        async move {
            browser::open_monitor(&b, &http, TOKEN).await?;
            // Pause: the job is paused, and its card offers Resume.
            click_visible(&b, &format!("#job-{running} .jc-pause")).await?;
            poll(&b, "the job to be paused", |_| async move {
                (card(c, running)["paused"] == true).then_some(())
            })
            .await?;
            wait_visible(&b, &format!("#job-{running} .jc-resume")).await?;
            // Requeue a rect of the done still: its damaged tile is mended.
            damage(c, done);
            let field = b
                .find(fantoccini::Locator::Css(&format!("#job-{done} .jc-what")))
                .await
                .map_err(browser::err("the requeue field"))?;
            field
                .send_keys("20,18,5,3")
                .await
                .map_err(browser::err("typing"))?;
            click_visible(&b, &format!("#job-{done} .jc-requeue")).await?;
            let expected = &expected;
            poll(&b, "the requeued output", |_| async move {
                (card(c, done)["state"] == "done"
                    && std::fs::read(output(c, done)).ok().as_ref() == Some(expected))
                .then_some(())
            })
            .await?;
            // Retry of the failed still, once what failed it is gone.
            std::fs::remove_dir(output(c, failing)).map_err(|e| e.to_string())?;
            wait_visible(&b, &format!("#job-{failing} .jc-retry")).await?;
            let shot = b
                .screenshot()
                .await
                .map_err(browser::err("the screenshot"))?;
            click_visible(&b, &format!("#job-{failing} .jc-retry")).await?;
            // Resume: the paused job goes on.
            click_visible(&b, &format!("#job-{running} .jc-resume")).await?;
            poll(
                &b,
                "the retried job to be done and the paused one resumed",
                |_| async move {
                    (card(c, failing)["state"] == "done" && card(c, running)["paused"] == false)
                        .then_some(())
                },
            )
            .await?;
            let _ = dir;
            Ok(shot)
        }
    });
    let shot = shot.unwrap_or_else(|e| panic!("{e}\n{}", dir.logs()));
    assert_eq!(std::fs::read(output(&c, failing)).unwrap(), expected);
    browser::keep_screenshot("monitor-control.png", &shot);
}

/// Waits until the element `css` selects is shown.
async fn wait_visible(b: &fantoccini::Client, css: &str) -> Result<(), String> {
    poll(b, &format!("{css} to show"), |b| async move {
        let e = b.find(fantoccini::Locator::Css(css)).await.ok()?;
        e.is_displayed().await.ok()?.then_some(())
    })
    .await
}

/// Clicks `css` once it is shown.
async fn click_visible(b: &fantoccini::Client, css: &str) -> Result<(), String> {
    wait_visible(b, css).await?;
    browser::click(b, css).await
}
