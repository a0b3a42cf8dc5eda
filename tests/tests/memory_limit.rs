//! `trevi-worker --max-memory`, end to end with real processes: two
//! workers, one with a small limit. A scene too big for the small one is
//! rendered entirely by the big one (byte-identical to `trevi-submit`
//! alone), while the small one shows as paused for "memory"; a scene too
//! big for both fails, and `trevi-submit` says so, naming the estimate and
//! the largest limit, and exits non-zero. The limits are set from the
//! scenes' own estimates (`trevi_core::scene::estimate`), computed here
//! from the same files.

mod common;

use common::http::{get, monitor_worker};
use common::*;
use std::fmt::Write as _;
use trevi_core::scene::estimate::{estimate, human_bytes};

/// A flat grid of `n × n` quads (2n² triangles) in OBJ.
#[allow(clippy::disallowed_methods)] // test geometry, written to a file both renders read
fn grid_obj(n: usize) -> String {
    let mut s = String::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, z) = (
                i as f64 / n as f64 * 4.0 - 2.0,
                j as f64 / n as f64 * 4.0 - 2.0,
            );
            let y = 0.2 * (x * 3.0).sin() * (z * 2.0).cos();
            let _ = writeln!(s, "v {x:.5} {y:.5} {z:.5}");
        }
    }
    let v = |i: usize, j: usize| j * (n + 1) + i + 1;
    for j in 0..n {
        for i in 0..n {
            let _ = writeln!(s, "f {} {} {}", v(i, j), v(i + 1, j), v(i + 1, j + 1));
            let _ = writeln!(s, "f {} {} {}", v(i, j), v(i + 1, j + 1), v(i, j + 1));
        }
    }
    s
}

fn scene(mesh: &str, output: &str) -> String {
    format!(
        r#"<scene version="1">
  <settings background="0.2 0.3 0.4" ambient="0.1 0.1 0.1"/>
  <mesh id="grid" file="{mesh}"/>
  <model id="g" mesh="grid"><surface diffuse="0.7 0.6 0.3" specular="0.3 0.3 0.3"/></model>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1"/>
  <camera id="main" position="0 3 5" lookat="0 0 0" up="0 1 0" fov="50">
    <render width="64" height="48" output="{output}"/>
  </camera>
</scene>
"#
    )
}

/// The estimate of the scene file at `path`, as the coordinator makes it.
fn estimate_of(path: &std::path::Path) -> u64 {
    let p = trevi_core::ParsedBundle::from_scene_file(path).expect("the scene parses");
    estimate(&p.desc).total()
}

/// The monitor's view of worker `name`: (tiles done, paused reason,
/// memory limit).
fn worker_view(c: &Coordinator, name: &str) -> (u64, Option<String>, Option<u64>) {
    let w = monitor_worker(c, name);
    (
        w["tiles_done"].as_u64().unwrap(),
        w["paused"].as_str().map(str::to_string),
        w["memory_limit"].as_u64(),
    )
}

#[test]
fn a_scene_too_big_for_one_worker_runs_on_the_other_and_one_too_big_for_all_fails_naming_the_limit()
{
    let dir = Dir::new();
    dir.write("scene/medium.obj", &grid_obj(40));
    dir.write("scene/large.obj", &grid_obj(160));
    let medium = dir.write("scene/medium.xml", &scene("medium.obj", "medium.png"));
    let large = dir.write("scene/large.xml", &scene("large.obj", "large.png"));
    let (need_medium, need_large) = (estimate_of(&medium), estimate_of(&large));
    // Whole KiB: the small worker holds half the medium scene, the big
    // one twice it, which is still well under the large scene.
    let small_kib = need_medium / 2 / 1024;
    let big_kib = need_medium * 2 / 1024;
    assert!(
        need_large > (big_kib << 10) * 2,
        "the large scene ({need_large} B) must be far over the big worker's limit ({big_kib} KiB)"
    );
    let want = embedded(&dir, &medium, "local.png");

    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--http", "127.0.0.1:0", "--memory-grace-ms", "4000"],
        &[],
    );
    let small_limit = format!("{small_kib}K");
    let big_limit = format!("{big_kib}K");
    let _small = worker_with(&dir, &c.url, "small", &["--max-memory", &small_limit], &[]);
    let _big = worker_with(&dir, &c.url, "big", &["--max-memory", &big_limit], &[]);
    wait_for(&dir, "both workers to register", 60, || {
        let (code, text) = get(c.http.as_deref().unwrap(), "/api/state", None);
        code == 200 && text.contains("\"small\"") && text.contains("\"big\"")
    });
    assert_eq!(worker_view(&c, "small").2, Some(small_kib << 10));
    assert_eq!(worker_view(&c, "big").2, Some(big_kib << 10));
    let (code, metrics) = get(c.http.as_deref().unwrap(), "/metrics", None);
    assert_eq!(code, 200);
    assert!(
        metrics
            .lines()
            .any(|l| l.starts_with("trevi_worker_memory_limit_bytes{")
                && l.contains("name=\"small\"")
                && l.ends_with(&format!(" {}", small_kib << 10))),
        "{metrics}"
    );

    // Too big for the small worker: every tile is the big one's, and the
    // image is the one-process render's.
    let got = farm_render(&dir, &c.url, &medium, "farm.png", 16);
    assert!(
        got == want,
        "the farm's image differs from trevi-submit alone"
    );
    let tiles = (64u64.div_ceil(16)) * (48u64.div_ceil(16));
    assert_eq!(worker_view(&c, "big").0, tiles, "{}", dir.logs());
    assert_eq!(worker_view(&c, "small").0, 0, "{}", dir.logs());
    assert!(
        !dir.read_log("small").contains("scene built"),
        "the small worker never built the scene:\n{}",
        dir.read_log("small")
    );

    // Too big for both: it waits for a bigger worker (the monitor shows
    // why these two take nothing), then fails naming the limit.
    let mut cmd = submit_cmd(&[large.to_str().unwrap(), "--coordinator", &c.url, "-o"]);
    cmd.arg(dir.path().join("large.png"));
    let child = cmd
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    wait_for(
        &dir,
        "the monitor to show both workers paused for memory",
        30,
        || {
            worker_view(&c, "small").1.as_deref() == Some("memory")
                && worker_view(&c, "big").1.as_deref() == Some("memory")
        },
    );
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "trevi-submit succeeded: {stderr}");
    let largest = human_bytes(big_kib << 10);
    let needs = human_bytes(need_large);
    assert!(
        stderr.contains(&format!("the scene needs about {needs} of memory"))
            && stderr.contains(&format!(
                "the largest limit of the 2 live workers is {largest} (trevi-worker --max-memory)"
            )),
        "{stderr}"
    );
    assert!(!dir.path().join("large.png").exists());
}
