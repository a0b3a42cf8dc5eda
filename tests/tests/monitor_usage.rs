//! The monitor's usage page in a real browser: a real coordinator and
//! worker render a job, and headless Chromium (over WebDriver, see
//! [`common::browser`]) opens `/usage`, types the submit token, and finds
//! the job's row in the table and its CPU time as a bar of the chart; then
//! the same by worker.
//!
//! The screenshot is kept as `monitor-usage.png` in
//! `target/test-artifacts` (or `$TREVI_ARTIFACTS_DIR`).

mod common;

use common::browser::{self, err, poll, text_of};
use common::{coordinator_with, submit, worker_with, Dir};
use fantoccini::Locator;

const SUBMIT_TOKEN: &str = "usage-page-submit";
const WORKER_TOKEN: &str = "usage-page-worker";

#[test]
fn the_usage_page_shows_the_job_s_row_and_its_cpu_time_in_the_chart() {
    let Some((chromium, chromedriver)) = browser::browser() else {
        common::skip(browser::SKIP_MESSAGE);
        return;
    };
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
    let _worker = worker_with(&dir, &c.url, "render-01", &["--token", WORKER_TOKEN], &[]);
    let scene = dir.write("slow.xml", common::SLOW_SCENE);
    let out = dir.path().join("slow.png");
    let o = submit(
        &dir,
        &[
            scene.to_str().unwrap(),
            // 96×64 in tiles of 16: the 24 tiles the row must count.
            "--tile",
            "16",
            "--quiet",
            "-o",
            out.to_str().unwrap(),
            "--coordinator",
            &c.url,
            "--token",
            SUBMIT_TOKEN,
        ],
    );
    assert!(o.status.success(), "the render failed\n{}", dir.logs());
    let http = c.http.clone().expect("--http");

    let shot = browser::with_browser(&dir, &chromium, &chromedriver, |b| async move {
        b.goto(&format!("http://{http}/"))
            .await
            .map_err(err("opening the monitor"))?;
        // The monitor links to the usage page.
        browser::click(&b, "header a[href='/usage']").await?;
        poll(&b, "the page to ask for the token", |b| async move {
            text_of(&b, "#message")
                .await
                .filter(|m| m.contains("submit token"))
        })
        .await?;
        let input = b
            .find(Locator::Id("token"))
            .await
            .map_err(err("the token field"))?;
        input
            .send_keys(SUBMIT_TOKEN)
            .await
            .map_err(err("typing the token"))?;
        browser::click(&b, "header h1").await?;
        // Job 1's row, with its CPU time, and a bar for it.
        let cells = poll(&b, "job 1's row", |b| async move {
            let row = b.find(Locator::Css("tr[data-key='1']")).await.ok()?;
            let cells = row.find_all(Locator::Css("td")).await.ok()?;
            let mut texts = Vec::new();
            for cell in cells {
                texts.push(cell.text().await.ok()?);
            }
            Some(texts)
        })
        .await?;
        let core_seconds: f64 = cells[2]
            .parse()
            .map_err(|e| format!("core-seconds {:?}: {e}", cells[2]))?;
        if core_seconds <= 0.0 || cells[3] != "24" {
            return Err(format!("job 1's row says {cells:?}"));
        }
        let bars = b
            .find_all(Locator::Css("#chart rect.bar"))
            .await
            .map_err(err("the chart's bars"))?;
        if bars.is_empty() {
            return Err("the chart has no bar".into());
        }
        let shot = b.screenshot().await.map_err(err("the screenshot"))?;
        // By worker: one row, the worker's name.
        b.find(Locator::Id("by"))
            .await
            .map_err(err("the by selector"))?
            .select_by_value("worker")
            .await
            .map_err(err("choosing by worker"))?;
        poll(&b, "the worker's row", |b| async move {
            b.find(Locator::Css("tr[data-key='render-01']")).await.ok()
        })
        .await?;
        Ok(shot)
    });
    let shot = shot.unwrap_or_else(|e| panic!("{e}\n{}", dir.logs()));
    browser::keep_screenshot("monitor-usage.png", &shot);
}
