//! Headless Chromium driven over WebDriver (`chromedriver`, through the
//! `fantoccini` client), for the monitor's browser tests: find the browser,
//! start a session, type the submit token as a user would, poll the page for
//! a state, and keep screenshots.
//!
//! The browser tests need Debian's `chromium` and `chromium-driver`
//! packages; `.ci/run` installs them and sets `TREVI_REQUIRE_ALL=1`, so in
//! CI a missing browser fails the test. Elsewhere [`browser`] returns `None`
//! and the test skips with [`SKIP_MESSAGE`].

use super::{Dir, Proc};
use serde_json::json;
use std::net::TcpStream;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// What a browser test says when it skips.
pub const SKIP_MESSAGE: &str = "the browser test needs chromium and chromedriver \
                                (apt-get install chromium chromium-driver)";

/// Where chromium and chromedriver are, if installed.
pub fn browser() -> Option<(PathBuf, PathBuf)> {
    let find = |names: &[&str]| {
        names.iter().find_map(|n| {
            std::env::var_os("PATH").and_then(|paths| {
                std::env::split_paths(&paths)
                    .map(|d| d.join(n))
                    .find(|p| p.is_file())
            })
        })
    };
    Some((
        find(&["chromium", "chromium-browser", "google-chrome"])?,
        find(&["chromedriver"])?,
    ))
}

/// Where screenshots are kept: `$TREVI_ARTIFACTS_DIR`, else
/// `target/test-artifacts`.
pub fn artifacts_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("TREVI_ARTIFACTS_DIR") {
        return PathBuf::from(d);
    }
    // target/<profile>/deps/this-test → target/test-artifacts
    let exe = std::env::current_exe().unwrap();
    exe.ancestors()
        .nth(3)
        .expect("target directory")
        .join("test-artifacts")
}

/// Writes a screenshot as `NAME` in [`artifacts_dir`] and returns its path.
pub fn keep_screenshot(name: &str, png: &[u8]) -> PathBuf {
    assert!(png.starts_with(b"\x89PNG"), "the screenshot is a PNG");
    let dir = artifacts_dir();
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(name);
    std::fs::write(&path, png).unwrap();
    eprintln!("screenshot: {}", path.display());
    path
}

/// Starts chromedriver (its log in `dir`), opens a headless Chromium session
/// 1280×1000, runs `drive` with it and closes it. `drive`'s error (what it
/// waited for in vain) is returned as it is.
pub fn with_browser<T, F, Fut>(
    dir: &Dir,
    chromium: &std::path::Path,
    chromedriver: &std::path::Path,
    drive: F,
) -> Result<T, String>
where
    F: FnOnce(fantoccini::Client) -> Fut,
    Fut: std::future::Future<Output = Result<T, String>>,
{
    // chromedriver on a free port.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let dlog = std::fs::File::create(dir.path().join("chromedriver.log")).unwrap();
    let _driver = Proc(
        Command::new(chromedriver)
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(dlog)
            .spawn()
            .unwrap(),
    );
    let driver_addr = format!("127.0.0.1:{port}");
    super::wait_for(dir, "chromedriver", 30, || {
        TcpStream::connect(&driver_addr).is_ok()
    });

    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let mut caps = serde_json::Map::new();
        caps.insert(
            "goog:chromeOptions".into(),
            json!({
                "binary": chromium,
                "args": ["--headless=new", "--no-sandbox", "--disable-dev-shm-usage",
                         "--disable-gpu", "--window-size=1280,1000"],
            }),
        );
        let client = fantoccini::ClientBuilder::new(
            hyper_util::client::legacy::connect::HttpConnector::new(),
        )
        .capabilities(caps)
        .connect(&format!("http://{driver_addr}"))
        .await
        .expect("a WebDriver session with headless Chromium");
        let result = drive(client.clone()).await;
        let _ = client.close().await;
        result
    })
}

/// Turns a WebDriver error into the sentence a failed test shows.
pub fn err(what: &str) -> impl Fn(fantoccini::error::CmdError) -> String {
    let what = what.to_string();
    move |e| format!("{what}: {e}")
}

/// Opens the monitor at `http` (host:port) and, once the page asks for it,
/// types the submit token into its field as a user would (leaving the field
/// applies it).
pub async fn open_monitor(c: &fantoccini::Client, http: &str, token: &str) -> Result<(), String> {
    use fantoccini::Locator;
    c.goto(&format!("http://{http}/"))
        .await
        .map_err(err("opening the monitor"))?;
    let message = poll(c, "the page to ask for the token", |c| async move {
        let m = c
            .find(Locator::Id("message"))
            .await
            .ok()?
            .text()
            .await
            .ok()?;
        m.contains("token").then_some(m)
    })
    .await?;
    if !message.contains("submit token") {
        return Err(format!("the page asks for the token as {message:?}"));
    }
    let input = c
        .find(Locator::Id("token"))
        .await
        .map_err(err("the token field"))?;
    input
        .send_keys(token)
        .await
        .map_err(err("typing the token"))?;
    c.find(Locator::Css("header h1"))
        .await
        .map_err(err("the header"))?
        .click()
        .await
        .map_err(err("leaving the token field"))?;
    Ok(())
}

/// Clicks the element `css` selects. The monitor redraws a job's card as
/// the job changes, so the element found may be replaced before the click
/// lands ("stale element reference"): then it is found again and clicked,
/// for up to two minutes, as [`poll`] waits.
pub async fn click(c: &fantoccini::Client, css: &str) -> Result<(), String> {
    let start = Instant::now();
    loop {
        let clicked = match c.find(fantoccini::Locator::Css(css)).await {
            Ok(e) => e.click().await,
            Err(e) => return Err(err(&format!("finding {css}"))(e)),
        };
        match clicked {
            Err(e)
                if e.is_stale_element_reference() && start.elapsed() < Duration::from_secs(120) =>
            {
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
            r => return r.map_err(err(&format!("clicking {css}"))),
        }
    }
}

/// The text of the element `css` selects, if it is on the page.
pub async fn text_of(c: &fantoccini::Client, css: &str) -> Option<String> {
    c.find(fantoccini::Locator::Css(css))
        .await
        .ok()?
        .text()
        .await
        .ok()
}

/// Polls `f` against the page every 200 ms for up to two minutes.
pub async fn poll<T, F, Fut>(c: &fantoccini::Client, what: &str, mut f: F) -> Result<T, String>
where
    F: FnMut(fantoccini::Client) -> Fut,
    Fut: std::future::Future<Output = Option<T>>,
{
    let start = Instant::now();
    loop {
        if let Some(v) = f(c.clone()).await {
            return Ok(v);
        }
        if start.elapsed() > Duration::from_secs(120) {
            return Err(format!("timed out waiting for {what}"));
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}
