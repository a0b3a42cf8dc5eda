//! Helpers shared by the farm tests that start real processes: binaries,
//! working directories with logs, children killed on drop, polling; and in
//! their own files the coordinator's clients and jobs ([`farm`]), a worker
//! made by hand ([`fake_worker`]), raw HTTP to the monitor ([`http`]) and
//! headless Chromium for the monitor's browser tests ([`browser`]).
#![allow(dead_code)]

pub mod browser;
pub mod fake_worker;
pub mod farm;
pub mod http;

// Each test crate uses a few of these.
#[allow(unused_imports)]
pub use fake_worker::FakeWorker;
#[allow(unused_imports)]
pub use farm::{
    bundles, cancel, channel, detach, download, job, jobs, submit_and_wait, submit_job, try_job,
    upload, wait_state, workers,
};

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// A scene whose tiles take tens of milliseconds each on one thread.
pub const SLOW_SCENE: &str = r#"<scene version="1">
  <settings background="0.1 0.1 0.2" ambient="0.2 0.2 0.2"/>
  <sphere id="ball" center="0 1 0" radius="1">
    <surface diffuse="0.8 0.3 0.2" specular="0.5 0.5 0.5" reflectivity="0.2"/>
  </sphere>
  <plane id="ground" point="0 0 0" normal="0 1 0"> <surface diffuse="0.5 0.5 0.5"/> </plane>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1" radius="0.5"/>
  <camera id="main" position="0 2 6" lookat="0 1 0" up="0 1 0" fov="50">
    <render width="96" height="64" supersample="6" shadow-samples="8" ao-samples="16" output="slow.png"/>
  </camera>
</scene>
"#;

/// A 64 × 48 still: 4 × 3 tiles of 16, quick (soft shadows, so that a
/// pixel rendered with the wrong sample seed shows).
pub const QUICK_STILL: &str = r#"<scene version="1">
  <settings background="0.1 0.1 0.2" ambient="0.2 0.2 0.2"/>
  <sphere id="ball" center="0 1 0" radius="1"> <surface diffuse="0.8 0.3 0.2"/> </sphere>
  <plane id="ground" point="0 0 0" normal="0 1 0"> <surface diffuse="0.5 0.5 0.5"/> </plane>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1" radius="0.5"/>
  <camera id="main" position="0 2 6" lookat="0 1 0" up="0 1 0" fov="50">
    <render width="64" height="48" shadow-samples="4" output="still.png"/>
  </camera>
</scene>
"#;

/// A tiny scene: a 16×16 frame, one tile of 16, quick to render.
pub fn tiny_scene(seed: u32) -> String {
    format!(
        r#"<scene version="1">
  <settings background="0.1 0.1 0.2" ambient="0.1 0.1 0.1"/>
  <sphere id="ball" center="0 1 0" radius="{r}">
    <surface diffuse="0.8 0.3 0.2"/>
  </sphere>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1"/>
  <camera id="main" position="0 2 6" lookat="0 1 0" up="0 1 0" fov="50">
    <render width="24" height="20" output="tiny.png"/>
  </camera>
</scene>
"#,
        r = 0.5 + (seed % 10) as f32 * 0.1
    )
}

/// The workspace's binaries the end-to-end tests start.
pub const BINARIES: [&str; 3] = ["trevi-coordinator", "trevi-worker", "trevi-submit"];

/// The path of workspace binary `name` (one of [`BINARIES`]), up to date.
///
/// `cargo test` builds a package's binaries only for that package's own
/// integration tests, so the first call in each test process runs
/// `cargo build` for [`BINARIES`] with the profile the tests were built with
/// (target/debug holds the `test` profile's artifacts under `cargo test`),
/// into the same target directory: a no-op when they are up to date. Cargo
/// has released its lock on the target directory by the time tests run.
pub fn bin(name: &str) -> PathBuf {
    assert!(
        BINARIES.contains(&name),
        "{name} is not one of {BINARIES:?}"
    );
    let dir = BUILT.get_or_init(build_binaries);
    let dir = match dir {
        Ok(d) => d,
        Err(e) => panic!("{e}"),
    };
    dir.join(format!("{name}{}", std::env::consts::EXE_SUFFIX))
}

/// The test target `exe` was built from: its file name without cargo's
/// `-<hash>` suffix (target/<profile>/deps/denoise_cli-2fd636e68d8353dd is
/// `denoise_cli`).
fn test_target_name(exe: &Path) -> Result<String, String> {
    exe.file_stem()
        .and_then(|s| s.to_str())
        .and_then(|s| s.rsplit_once('-'))
        .map(|(name, _hash)| name.to_string())
        .ok_or_else(|| format!("{} is not named TEST-HASH", exe.display()))
}

static BUILT: std::sync::OnceLock<Result<PathBuf, String>> = std::sync::OnceLock::new();

/// Builds [`BINARIES`] once per test process; returns the directory they
/// are in (the test executable's target/<profile>).
fn build_binaries() -> Result<PathBuf, String> {
    let exe = std::env::current_exe().map_err(|e| format!("current_exe: {e}"))?;
    // target/<profile>/deps/<test>-<hash>
    let profile_dir = exe
        .parent()
        .and_then(Path::parent)
        .ok_or("the test does not run from target/<profile>/deps")?
        .to_path_buf();
    let target_dir = profile_dir
        .parent()
        .ok_or("the test's target/<profile> has no parent")?;
    // The profile whose artifacts live in this directory: `cargo test`
    // builds with `test` into target/debug, `cargo test --release` with
    // `release`, `--profile NAME` into target/NAME.
    let profile = match profile_dir.file_name().and_then(|n| n.to_str()) {
        Some("debug") => "test",
        Some(other) => other,
        None => return Err(format!("unexpected {}", profile_dir.display())),
    };
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR")).join("../Cargo.toml");
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let mut cmd = Command::new(&cargo);
    cmd.arg("build")
        .arg("--manifest-path")
        .arg(&manifest)
        .arg("--target-dir")
        .arg(target_dir)
        .args(["--profile", profile]);
    for b in BINARIES {
        cmd.args(["--bin", b]);
    }
    // The targets `cargo test --workspace` builds (tests and examples of
    // every member) come along so that cargo resolves the same features:
    // the dependencies' artifacts are then the test run's, up to date, and
    // only the binaries are compiled (a narrower build would rebuild the
    // dependencies with other features over the same files). With this
    // package's tests selected, its dev-dependency on trevi-worker turns on
    // the worker's `test-hooks` feature, so trevi-worker is built with the
    // hooks these tests drive (TREVI_TEST_*), as in the test run.
    //
    // The features of the outer `cargo test --features … --test NAME`,
    // which a test cannot see, are given again in TREVI_BUILD_FEATURES
    // (CI's denoise run, tests/tests/denoise_cli.rs), else the nested build
    // would rebuild the binaries without them. That run selects one test,
    // so the nested build selects the same one (this executable's name
    // without cargo's hash): the same features resolve (a test target turns
    // the dev-dependencies on either way), and the other tests and examples
    // are not compiled a second time with the features, which doubled the
    // target directory and filled CI's disk.
    let features = std::env::var("TREVI_BUILD_FEATURES")
        .ok()
        .filter(|f| !f.trim().is_empty());
    match &features {
        None => cmd.args(["--workspace", "--tests", "--examples"]),
        Some(f) => cmd
            .args(["--workspace", "--features", f.trim(), "--test"])
            .arg(test_target_name(&exe)?),
    };
    // Cargo runs this test with the test package's own variables set
    // (CARGO_MANIFEST_DIR, CARGO_PKG_NAME, ...). Build scripts such as
    // ring's ask to run again when those change (rerun-if-env-changed), so
    // passing them on made every nested build rebuild the TLS and gRPC stack
    // and every later `cargo test` rebuild it back: the nested build gets
    // the environment the user's `cargo test` had.
    for (key, _) in std::env::vars_os() {
        let k = key.to_string_lossy();
        let set_by_cargo_for_this_test = [
            "CARGO_PKG_",
            "CARGO_MANIFEST_",
            "CARGO_CFG_",
            "CARGO_FEATURE_",
            "CARGO_CRATE_",
            "CARGO_BIN_",
        ]
        .iter()
        .any(|p| k.starts_with(p))
            || ["CARGO_PRIMARY_PACKAGE", "CARGO_TARGET_TMPDIR", "OUT_DIR"].contains(&&*k);
        if set_by_cargo_for_this_test {
            cmd.env_remove(&key);
        }
    }
    eprintln!("building the binaries the test starts: {cmd:?}");
    let out = cmd
        .output()
        .map_err(|e| format!("cannot run {}: {e}", Path::new(&cargo).display()))?;
    if !out.status.success() {
        return Err(format!(
            "{cmd:?} failed ({})\n{}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    for b in BINARIES {
        let p = profile_dir.join(format!("{b}{}", std::env::consts::EXE_SUFFIX));
        if !p.is_file() {
            return Err(format!("{cmd:?} succeeded but left no {}", p.display()));
        }
    }
    Ok(profile_dir)
}

/// A test's working directory; its logs are shown when an assertion fails.
pub struct Dir {
    tmp: tempfile::TempDir,
}

impl Dir {
    pub fn new() -> Dir {
        Dir {
            tmp: tempfile::Builder::new()
                .prefix("trevi-e2e-")
                .tempdir()
                .unwrap(),
        }
    }

    pub fn path(&self) -> &Path {
        self.tmp.path()
    }

    pub fn write(&self, rel: &str, text: &str) -> PathBuf {
        let p = self.path().join(rel);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(&p, text).unwrap();
        p
    }

    pub fn log(&self, name: &str) -> std::fs::File {
        std::fs::File::create(self.path().join(format!("{name}.log"))).unwrap()
    }

    pub fn read_log(&self, name: &str) -> String {
        std::fs::read_to_string(self.path().join(format!("{name}.log"))).unwrap_or_default()
    }

    /// The tail of every log, for failure messages.
    pub fn logs(&self) -> String {
        let mut out = format!("working directory {}\n", self.path().display());
        let mut entries: Vec<_> = std::fs::read_dir(self.path())
            .unwrap()
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.extension().is_some_and(|e| e == "log"))
            .collect();
        entries.sort();
        for p in entries {
            let text = std::fs::read_to_string(&p).unwrap_or_default();
            let tail: Vec<&str> = text.lines().rev().take(40).collect();
            out.push_str(&format!("--- {}\n", p.display()));
            for l in tail.into_iter().rev() {
                out.push_str(l);
                out.push('\n');
            }
        }
        out
    }
}

/// A child process killed (SIGKILL) when dropped.
pub struct Proc(pub Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

pub struct Coordinator {
    pub proc: Proc,
    /// `http://127.0.0.1:PORT` (or `https://localhost:PORT`).
    pub url: String,
    pub addr: String,
    /// The monitor's `host:port` when started with `--http` (HTTPS when
    /// started with `--tls-cert`).
    pub http: Option<String>,
    pub data: PathBuf,
    /// How test clients reach it over TLS (the CA to trust); set by the
    /// test that started it with `--tls-cert`.
    pub tls: trevi_proto::ClientTls,
}

/// Starts `trevi-coordinator` on `listen` with `args` and `envs`; its data
/// directory is `dir/data`. With `--tls-cert` among `args` its URL is
/// `https://localhost:PORT` (the name in the certificates of
/// `deploy/make-certs.sh`).
pub fn coordinator_with(
    dir: &Dir,
    listen: &str,
    name: &str,
    args: &[&str],
    envs: &[(&str, &str)],
) -> Coordinator {
    let data = dir.path().join("data");
    let mut cmd = Command::new(bin("trevi-coordinator"));
    cmd.args(["--listen", listen, "--tile-size", "16"])
        .arg("--data-dir")
        .arg(&data)
        .args(args)
        .env("RUST_LOG", "info")
        .env_remove("TREVI_SUBMIT_TOKEN")
        .env_remove("TREVI_WORKER_TOKEN")
        .env_remove("TREVI_TLS_CERT")
        .env_remove("TREVI_TLS_KEY")
        .stdout(Stdio::piped())
        .stderr(dir.log(name));
    for (k, v) in envs {
        cmd.env(k, v);
    }
    let mut child = cmd.spawn().expect("start trevi-coordinator");
    // `listening on ADDR`, then with --http `monitor on http://ADDR/`.
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    out.read_line(&mut line).unwrap();
    let addr = line
        .trim()
        .strip_prefix("listening on ")
        .unwrap_or_else(|| panic!("coordinator said {line:?}\n{}", dir.logs()))
        .to_string();
    let http = args.contains(&"--http").then(|| {
        line.clear();
        out.read_line(&mut line).unwrap();
        let l = line.trim();
        l.strip_prefix("monitor on http://")
            .or_else(|| l.strip_prefix("monitor on https://"))
            .unwrap_or_else(|| panic!("coordinator said {line:?}\n{}", dir.logs()))
            .trim_end_matches('/')
            .to_string()
    });
    let url = if args.contains(&"--tls-cert") {
        let port = addr.rsplit(':').next().unwrap_or_default();
        format!("https://localhost:{port}")
    } else {
        format!("http://{addr}")
    };
    Coordinator {
        proc: Proc(child),
        url,
        addr,
        http,
        data,
        tls: trevi_proto::ClientTls::default(),
    }
}

/// The one switch that turns every "SKIPPED" into a failure: set
/// `TREVI_REQUIRE_ALL=1` (`.ci/run` does) and a test whose tool (chromium,
/// openssl, curl) or data is missing fails instead of passing without
/// having checked anything.
pub const REQUIRE_ALL: &str = "TREVI_REQUIRE_ALL";

/// Whether [`REQUIRE_ALL`] is set to `1`.
pub fn require_all() -> bool {
    std::env::var_os(REQUIRE_ALL).is_some_and(|v| v == "1")
}

/// Says that a test cannot run because of `why` and returns, so the caller
/// can return early; panics instead under [`REQUIRE_ALL`].
pub fn skip(why: &str) {
    if require_all() {
        panic!("{why} ({REQUIRE_ALL}=1: nothing may be skipped)");
    }
    eprintln!("SKIPPED: {why} (set {REQUIRE_ALL}=1 to fail instead)");
}

/// Whether `cmd ARG` runs; if not, says that the test needing it for `what`
/// is skipped (see [`skip`]: under [`REQUIRE_ALL`] it fails).
pub fn have_command(cmd: &str, arg: &str, what: &str) -> bool {
    let ok = Command::new(cmd)
        .arg(arg)
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        skip(&format!(
            "the {cmd} command is missing, so {what} cannot run"
        ));
    }
    ok
}

/// Certificates for a local farm made by `deploy/make-certs.sh` in
/// `dir/NAME` (`ca.pem`, `coordinator.pem`, `coordinator.key`, for
/// localhost and 127.0.0.1); `None`, after saying why, when the `openssl`
/// command is missing.
pub fn make_certs(dir: &Dir, name: &str) -> Option<PathBuf> {
    if !have_command("openssl", "version", "deploy/make-certs.sh") {
        return None;
    }
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/make-certs.sh");
    let out_dir = dir.path().join(name);
    let o = Command::new("sh")
        .arg(&script)
        .arg(&out_dir)
        .output()
        .expect("run sh");
    assert!(
        o.status.success(),
        "{} failed\n{}{}",
        script.display(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    for f in ["ca.pem", "ca.key", "coordinator.pem", "coordinator.key"] {
        assert!(out_dir.join(f).is_file(), "make-certs.sh wrote no {f}");
    }
    Some(out_dir)
}

/// Starts a worker with one render thread. Its threads run at normal
/// priority (`TREVI_PRIORITY=normal`), so that tests timing a worker do not
/// depend on what else the machine runs; an `envs` entry with an empty
/// value removes that variable instead (the worker's own default).
pub fn worker_with(dir: &Dir, url: &str, name: &str, args: &[&str], envs: &[(&str, &str)]) -> Proc {
    let mut cmd = Command::new(bin("trevi-worker"));
    cmd.args(["--coordinator", url, "--threads", "1", "--name", name])
        .args(args)
        .env("RUST_LOG", "info,trevi_worker=debug")
        .env("TREVI_PRIORITY", "normal")
        .env_remove("TREVI_TOKEN")
        .env_remove("TREVI_TLS_CA")
        .env_remove("TREVI_TLS_DOMAIN")
        .stdout(Stdio::null())
        .stderr(dir.log(name));
    for (k, v) in envs {
        if v.is_empty() {
            cmd.env_remove(k);
        } else {
            cmd.env(k, v);
        }
    }
    Proc(cmd.spawn().expect("start trevi-worker"))
}

pub fn submit_cmd(args: &[&str]) -> Command {
    let mut c = Command::new(bin("trevi-submit"));
    c.args(args)
        .env_remove("TREVI_COORDINATOR")
        .env_remove("TREVI_TOKEN")
        .env_remove("TREVI_TLS_CA")
        .env_remove("TREVI_TLS_DOMAIN");
    c
}

/// Runs `trevi-submit` to the end, keeping its output as a log.
pub fn submit(dir: &Dir, args: &[&str]) -> Output {
    submit_env(dir, args, &[])
}

pub fn submit_env(dir: &Dir, args: &[&str], envs: &[(&str, &str)]) -> Output {
    static RUNS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = RUNS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let mut cmd = submit_cmd(args);
    for (k, v) in envs {
        cmd.env(k, v);
    }
    let out = cmd.output().expect("run trevi-submit");
    std::fs::write(
        dir.path().join(format!("submit-{n:03}.log")),
        [&out.stdout[..], &out.stderr[..]].concat(),
    )
    .unwrap();
    out
}

/// Renders `scene` on the farm at `url` with `trevi-submit --coordinator`
/// into `dir/out` in tiles of `tile` pixels, and returns the file's bytes
/// (the counterpart of [`embedded`]).
pub fn farm_render(dir: &Dir, url: &str, scene: &Path, out: &str, tile: u32) -> Vec<u8> {
    let out = dir.path().join(out);
    let args = farm_args(url, scene, &out, tile);
    let o = submit(dir, &args.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(o.status.success(), "farm render failed\n{}", dir.logs());
    std::fs::read(out).unwrap()
}

/// `scene --coordinator url -o out --tile tile`: a render on the farm.
fn farm_args(url: &str, scene: &Path, out: &Path, tile: u32) -> Vec<String> {
    vec![
        scene.to_str().unwrap().into(),
        "--coordinator".into(),
        url.into(),
        "-o".into(),
        out.to_str().unwrap().into(),
        "--tile".into(),
        tile.to_string(),
    ]
}

/// Starts `trevi-submit scene --coordinator url -o out --tile tile`, which
/// waits for the job (its stderr in the log "submit"); the caller kills or
/// waits for it.
pub fn spawn_farm_submit(dir: &Dir, url: &str, scene: &Path, out: &Path, tile: u32) -> Child {
    let args = farm_args(url, scene, out, tile);
    submit_cmd(&args.iter().map(String::as_str).collect::<Vec<_>>())
        .stderr(dir.log("submit"))
        .spawn()
        .unwrap()
}

/// Tiles the workers `worker0` .. `worker{workers - 1}` rendered, from their
/// logs (one "tile rendered" line per tile).
pub fn tiles_rendered(dir: &Dir, workers: usize) -> usize {
    (0..workers)
        .map(|i| {
            dir.read_log(&format!("worker{i}"))
                .matches("tile rendered")
                .count()
        })
        .sum()
}

/// The embedded (one-process) render of a scene.
pub fn embedded(dir: &Dir, scene: &Path, out: &str) -> Vec<u8> {
    let out = dir.path().join(out);
    let o = submit(
        dir,
        &[
            scene.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--tile",
            "16",
            "--quiet",
        ],
    );
    assert!(
        o.status.success(),
        "embedded render failed\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    std::fs::read(out).unwrap()
}

pub fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
}

/// Polls `cond` until it holds; fails with the logs after `secs` seconds.
pub fn wait_for(dir: &Dir, what: &str, secs: u64, mut cond: impl FnMut() -> bool) {
    let end = Instant::now() + Duration::from_secs(secs);
    while !cond() {
        assert!(
            Instant::now() < end,
            "timed out waiting for {what}\n{}",
            dir.logs()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

pub fn wait_child(dir: &Dir, child: &mut Child, secs: u64) -> std::process::ExitStatus {
    let end = Instant::now() + Duration::from_secs(secs);
    loop {
        if let Some(s) = child.try_wait().unwrap() {
            return s;
        }
        assert!(
            Instant::now() < end,
            "a process did not finish\n{}",
            dir.logs()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A field of `/proc/PID/status` in KiB (`VmHWM`: peak resident memory,
/// `VmRSS`: resident now).
pub fn proc_kib(pid: u32, field: &str) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    status
        .lines()
        .find_map(|l| l.strip_prefix(field)?.strip_prefix(':'))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .unwrap_or_else(|| panic!("no {field} in /proc/{pid}/status"))
}

/// Sends `kill -SIGNAL` (`"TERM"`, `"INT"`) to a child.
pub fn signal(p: &Proc, signal: &str) {
    let ok = Command::new("kill")
        .args([&format!("-{signal}"), &p.0.id().to_string()])
        .status()
        .expect("run kill")
        .success();
    assert!(ok, "kill -{signal} {} failed", p.0.id());
}

/// A bundle of one scene file, `s.xml`, for tests that speak gRPC directly.
pub fn bundle_of(scene: &str) -> trevi_core::Bundle {
    let mut files = std::collections::BTreeMap::new();
    files.insert("s.xml".to_string(), scene.as_bytes().to_vec());
    trevi_core::Bundle {
        scene: "s.xml".into(),
        files,
    }
}

/// The CPU time process `pid` has used (user + system, all its threads),
/// from `/proc/PID/stat`; also readable while it is a zombie, before it is
/// reaped. What a process did in CPU time does not stretch on a busy
/// machine as its wall-clock time does: tests bound the work done between
/// two events with it.
pub fn cpu_time(pid: u32) -> Duration {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .unwrap_or_else(|e| panic!("/proc/{pid}/stat: {e}"));
    // The command name may hold spaces: fields are counted from the last ')'.
    let rest = &stat[stat.rfind(')').expect("a /proc stat line") + 1..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    // After the name: state (0) ... utime (11), stime (12), in clock ticks.
    let ticks: u64 = f[11].parse::<u64>().unwrap() + f[12].parse::<u64>().unwrap();
    Duration::from_secs_f64(ticks as f64 / clock_ticks() as f64)
}

/// Whether process `pid` has exited (a zombie not yet reaped, or gone).
pub fn exited(pid: u32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        Ok(stat) => stat[stat.rfind(')').unwrap_or(0) + 1..]
            .split_whitespace()
            .next()
            .is_some_and(|s| s == "Z" || s == "X"),
        Err(_) => true,
    }
}

/// The kernel's clock ticks a second (`getconf CLK_TCK`; 100 on Linux).
fn clock_ticks() -> u64 {
    static TICKS: std::sync::OnceLock<u64> = std::sync::OnceLock::new();
    *TICKS.get_or_init(|| {
        Command::new("getconf")
            .arg("CLK_TCK")
            .output()
            .ok()
            .and_then(|o| String::from_utf8(o.stdout).ok()?.trim().parse().ok())
            .unwrap_or(100)
    })
}

/// The image of `scene`'s first camera as core renders it with no farm
/// code: `trevi_core::render_tile` over the whole frame, in this process,
/// written by core's `FrameWriter` to `dir/out` (its extension names the
/// format). An independent check of what the farm (and the embedded farm
/// of `trevi-submit`, the same code) delivers.
pub fn core_render(dir: &Dir, scene: &Path, out: &str) -> Vec<u8> {
    let bundle = trevi_core::Bundle::from_scene_file(scene).unwrap_or_else(|e| panic!("{e}"));
    let scene = trevi_core::Scene::from_bundle(&bundle).unwrap_or_else(|e| panic!("{e}"));
    let r = &scene.desc.cameras[0].render;
    let rect = trevi_core::Rect::new(0, 0, r.width, r.height);
    let pixels = trevi_core::render_tile(&scene, 0, rect).pixels;
    let path = dir.path().join(out);
    let mut fw = trevi_core::FrameWriter::create(&path, r.width, r.height).unwrap();
    fw.write_tile(rect, &pixels).unwrap();
    fw.finish().unwrap();
    std::fs::read(path).unwrap()
}

/// Asserts that two encoded images (PNG or EXR) hold the same pixels,
/// decoded (so that a difference of encoder settings alone would not
/// count, and any pixel's would).
pub fn assert_same_pixels(got: &[u8], want: &[u8], what: &str) {
    let decode = |b: &[u8]| {
        let t = trevi_core::texture::Texture::decode(b).unwrap_or_else(|e| panic!("{what}: {e}"));
        let l = &t.levels[0];
        (l.width, l.height, l.texels.clone())
    };
    let (gw, gh, g) = decode(got);
    let (ww, wh, w) = decode(want);
    assert_eq!((gw, gh), (ww, wh), "{what}: sizes differ");
    if let Some(k) = (0..g.len()).find(|&k| g[k] != w[k]) {
        panic!(
            "{what}: pixel ({}, {}) is {} where core renders {}",
            k as u32 % gw,
            k as u32 / gw,
            g[k],
            w[k]
        );
    }
}
