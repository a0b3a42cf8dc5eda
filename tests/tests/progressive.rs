//! Progressive renders end to end with real processes: a job rendered in
//! four passes on three workers, one of them killed while a pass is in
//! flight, is byte for byte the one-shot render of the same samples (the
//! scene written with `min-samples = max-samples`, rendered by
//! `trevi-submit` alone, with no passes); `extend` of a finished 16-sample
//! job by 48 equals a fresh 64-sample render; `--time-limit` stops between
//! passes, and `--noise-target` stops at or below its target measured
//! against a converged reference. A local render with `--samples` keeps its
//! job in the local directory: `extend` without `--coordinator` adds to it
//! (16 + 48 samples equal 64 at once), and refuses a job it does not hold.

mod common;

use common::*;
use trevi_proto::pb;

/// Soft shadows and ambient occlusion on a sphere and a floor: random
/// samples everywhere, `render` the sampling attributes.
fn scene(render: &str, size: &str) -> String {
    format!(
        r#"<scene version="1">
  <settings background="0.1 0.1 0.2" ambient="0.3 0.3 0.3"/>
  <sphere id="s" center="0 0 0" radius="1"><surface diffuse="0.8 0.3 0.2" ambient="0.5 0.5 0.5"/></sphere>
  <plane id="p" point="0 -1 0" normal="0 1 0"><surface diffuse="0.5 0.5 0.5" ambient="0.5 0.5 0.5"/></plane>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1" radius="1.5"/>
  <camera id="c" position="0 0.5 5" lookat="0 0 0" up="0 1 0" fov="45">
    <render {size} {render} shadow-samples="2" ao-samples="2" output="out.exr"/>
  </camera>
</scene>
"#
    )
}

/// The scene's own sampling (a grid), which `--samples` replaces.
fn grid(size: &str) -> String {
    scene(r#"supersample="2" jitter="true""#, size)
}

/// The scene written with exactly `n` samples a pixel, rendered at once.
fn fixed(n: u32, size: &str) -> String {
    scene(
        &format!(r#"noise-threshold="0.5" min-samples="{n}" max-samples="{n}""#),
        size,
    )
}

const SIZE: &str = r#"width="48" height="32""#;

/// `trevi-submit SCENE -o OUT ARGS` on this machine; the output's bytes.
fn alone(dir: &Dir, scene: &std::path::Path, out: &str, args: &[&str]) -> Vec<u8> {
    let out = dir.path().join(out);
    let mut all = vec![scene.to_str().unwrap(), "-o", out.to_str().unwrap(), "-q"];
    all.extend(args);
    let o = submit(dir, &all);
    assert!(o.status.success(), "{}", dir.logs());
    std::fs::read(out).unwrap()
}

fn passes(s: &pb::JobStatus) -> pb::PassesInfo {
    s.passes
        .clone()
        .unwrap_or_else(|| panic!("no passes in {s:?}"))
}

#[test]
fn four_passes_on_three_workers_one_killed_mid_pass_are_the_one_shot_render() {
    let dir = Dir::new();
    let reference = alone(
        &dir,
        &dir.write("fixed.xml", &fixed(16, SIZE)),
        "reference.exr",
        &["--tile", "16"],
    );
    let scene = dir.write("grid.xml", &grid(SIZE));
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let mut workers: Vec<Option<Proc>> = (0..3)
        .map(|i| Some(worker_with(&dir, &c.url, &format!("worker{i}"), &[], &[])))
        .collect();
    let rt = runtime();
    let id = detach(
        &dir,
        &c,
        &scene,
        &["--samples", "16", "--pass", "4", "--tile", "8"],
    );
    // Once the second pass has tiles done (and so tiles in flight), a
    // worker dies.
    wait_for(&dir, "the second pass under way", 240, || {
        let s = job(&rt, &c, id);
        let p = passes(&s);
        p.done >= 2 || (p.done == 1 && s.tiles_done > 0)
    });
    workers[0].take();
    let s = wait_state(&dir, &rt, &c, id, pb::JobState::Done, 240);
    let p = passes(&s);
    assert_eq!((p.done, p.samples_done, p.samples_total), (4, 16, 16));
    assert!(p.error.is_some_and(|e| e > 0.0 && e < 1.0), "{p:?}");
    let got = rt.block_on(download(&c, id, None));
    assert!(
        got == reference,
        "the farm's 4 passes differ from the one-shot render"
    );
    drop(workers);
}

#[test]
fn extending_a_16_sample_job_by_48_equals_a_fresh_64_sample_render() {
    let dir = Dir::new();
    let reference = alone(
        &dir,
        &dir.write("fixed.xml", &fixed(64, SIZE)),
        "reference.exr",
        &[],
    );
    let scene = dir.write("grid.xml", &grid(SIZE));
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let _w = worker_with(&dir, &c.url, "worker0", &[], &[]);
    let rt = runtime();
    let s = submit_and_wait(&dir, &rt, &c, &scene, &["--samples", "16"], 240);
    let sixteen = rt.block_on(download(&c, s.id, None));
    assert_ne!(sixteen, reference);
    let out = dir.path().join("extended.exr");
    let id = s.id.to_string();
    let o = submit(
        &dir,
        &[
            "extend",
            &id,
            "--samples",
            "48",
            "--coordinator",
            &c.url,
            "--wait",
            "-o",
            out.to_str().unwrap(),
            "-q",
        ],
    );
    assert!(o.status.success(), "{}", dir.logs());
    let p = passes(&job(&rt, &c, s.id));
    assert_eq!((p.samples_done, p.samples_total), (64, 64));
    assert!(
        std::fs::read(&out).unwrap() == reference,
        "16 + 48 samples differ from 64 at once"
    );
    // A job rendered without passes does not extend; nor one on the
    // scene's own samples.
    let plain = submit_and_wait(&dir, &rt, &c, &scene, &[], 240);
    let own = submit_and_wait(&dir, &rt, &c, &scene, &["--pass", "2"], 240);
    for (job, why) in [(plain.id, "--samples"), (own.id, "--samples N")] {
        let o = submit(
            &dir,
            &[
                "extend",
                &job.to_string(),
                "--samples",
                "4",
                "--coordinator",
                &c.url,
            ],
        );
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(why), "{err}");
    }
}

#[test]
fn the_time_limit_stops_between_passes() {
    let dir = Dir::new();
    let scene = dir.write("grid.xml", &grid(r#"width="96" height="64""#));
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let _w = worker_with(&dir, &c.url, "worker0", &[], &[]);
    let rt = runtime();
    let s = submit_and_wait(
        &dir,
        &rt,
        &c,
        &scene,
        &["--samples", "8192", "--pass", "2", "--time-limit", "1s"],
        240,
    );
    let p = passes(&s);
    assert_eq!(p.stopped_by, "time limit", "{p:?}");
    assert!(
        p.done >= 1 && p.samples_done == 2 * p.done && p.samples_done < 8192,
        "{p:?}"
    );
    // No pass started after the limit: the passes before the last one
    // ended within it (the last one started within it).
    let per_pass = s.render_ms / u64::from(p.done);
    assert!(
        s.render_ms < 1000 + 2 * per_pass + 1000,
        "{} ms for {} passes",
        s.render_ms,
        p.done
    );
}

/// The relative error of `img` against `reference`: RMS error over RMS
/// value, the quantity `--noise-target` bounds.
fn relative_error(img: &[[f32; 3]], reference: &[[f32; 3]]) -> f64 {
    let (mut e, mut v) = (0.0f64, 0.0f64);
    for (a, b) in img.iter().zip(reference) {
        for c in 0..3 {
            let d = f64::from(a[c]) - f64::from(b[c]);
            e += d * d;
            v += f64::from(b[c]) * f64::from(b[c]);
        }
    }
    (e / v).sqrt()
}

#[test]
fn the_noise_target_stops_at_or_below_its_target() {
    let dir = Dir::new();
    let small = r#"width="24" height="16""#;
    let converged = dir.path().join("converged.exr");
    alone(
        &dir,
        &dir.write("fixed.xml", &fixed(4096, small)),
        "converged.exr",
        &[],
    );
    let scene = dir.write("grid.xml", &grid(small));
    let out = dir.path().join("out.exr");
    let target = 0.03;
    let o = submit(
        &dir,
        &[
            scene.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--samples",
            "4096",
            "--pass",
            "4",
            "--noise-target",
            &target.to_string(),
            "--local-dir",
            dir.path().join("local").to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", dir.logs());
    let said = String::from_utf8_lossy(&o.stderr);
    assert!(said.contains("noise target"), "{said}");
    let read = |p: &std::path::Path| trevi_core::output::read_exr_rgb(p).unwrap().2;
    let e = relative_error(&read(&out), &read(&converged));
    assert!(
        e > 0.0 && e <= target,
        "relative error {e} against the converged render"
    );
}

#[test]
fn a_local_render_s_output_is_written_after_every_pass() {
    let dir = Dir::new();
    let reference = alone(
        &dir,
        &dir.write("fixed.xml", &fixed(24, SIZE)),
        "reference.exr",
        &[],
    );
    let scene = dir.write("grid.xml", &grid(SIZE));
    let out = dir.path().join("out.exr");
    // 24 passes of one sample: the file is there long before the end.
    let mut child = submit_cmd(&[
        scene.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--samples",
        "24",
        "--pass",
        "1",
        "-q",
        "--local-dir",
        dir.path().join("local").to_str().unwrap(),
    ])
    .stderr(dir.log("submit"))
    .spawn()
    .unwrap();
    let mut running = false;
    wait_for(&dir, "the output after a pass", 240, || {
        running = child.try_wait().unwrap().is_none();
        out.is_file() || !running
    });
    assert!(
        running,
        "the render ended before its first pass's image was written"
    );
    let early = std::fs::read(&out).unwrap();
    let status = wait_child(&dir, &mut child, 240);
    assert!(status.success(), "{}", dir.logs());
    let last = std::fs::read(&out).unwrap();
    assert!(
        last == reference,
        "the last pass's image is the one-shot render"
    );
    assert!(
        early != last,
        "the first image written was an earlier pass's"
    );
}

/// The id in "job N is kept in DIR" of a local render's last words.
fn kept_id(said: &str) -> u64 {
    let (_, rest) = said
        .split_once("job ")
        .filter(|(_, r)| r.contains(" is kept in "))
        .unwrap_or_else(|| panic!("no kept job in {said}"));
    rest.split_whitespace().next().unwrap().parse().unwrap()
}

#[test]
fn a_local_16_sample_render_extended_locally_by_48_is_a_fresh_64_sample_render() {
    let dir = Dir::new();
    // The default local directory, under a data home of the test's own.
    let home = dir.path().join("data");
    let kept = home.join("trevi/local");
    let env = [
        ("XDG_DATA_HOME", home.to_str().unwrap()),
        ("HOME", dir.path().to_str().unwrap()),
    ];
    let fixed64 = dir.write("fixed.xml", &fixed(64, SIZE));
    let reference = dir.path().join("reference.exr");
    let o = submit_env(
        &dir,
        &[fixed64.to_str().unwrap(), "-o", reference.to_str().unwrap()],
        &env,
    );
    assert!(o.status.success(), "{}", dir.logs());
    let reference = std::fs::read(reference).unwrap();
    // A render without --samples leaves nothing behind.
    assert!(!home.exists(), "a one-shot render made {}", home.display());
    let scene = dir.write("grid.xml", &grid(SIZE));
    let out = dir.path().join("out.exr");
    let o = submit_env(
        &dir,
        &[
            scene.to_str().unwrap(),
            "--samples",
            "16",
            "-o",
            out.to_str().unwrap(),
        ],
        &env,
    );
    assert!(o.status.success(), "{}", dir.logs());
    let said = String::from_utf8_lossy(&o.stderr);
    let id = kept_id(&said).to_string();
    assert!(
        said.contains(&format!(
            "trevi-submit extend {id} --samples N -o {}",
            out.display()
        )),
        "{said}"
    );
    assert!(kept.is_dir(), "{said}");
    assert_ne!(std::fs::read(&out).unwrap(), reference);
    // Another process, later: the job comes back from the local directory.
    let o = submit_env(
        &dir,
        &[
            "extend",
            &id,
            "--samples",
            "48",
            "-o",
            out.to_str().unwrap(),
        ],
        &env,
    );
    assert!(o.status.success(), "{}", dir.logs());
    assert!(
        std::fs::read(&out).unwrap() == reference,
        "16 + 48 local samples differ from 64 at once"
    );
    let said = String::from_utf8_lossy(&o.stderr);
    assert_eq!(kept_id(&said).to_string(), id, "{said}");

    // Hostile: a job the directory does not hold, a directory that holds
    // none (not made), and a --local-dir that is a file: each refused,
    // exit status 1, the output untouched.
    let before = std::fs::read(&out).unwrap();
    let empty = dir.path().join("empty");
    let file = dir.write("file", "x");
    let cases: [(&[&str], String); 3] = [
        (
            &[
                "extend",
                "999",
                "--samples",
                "4",
                "-o",
                out.to_str().unwrap(),
            ],
            format!("no local job 999 in {}", kept.display()),
        ),
        (
            &[
                "extend",
                &id,
                "--samples",
                "4",
                "--local-dir",
                empty.to_str().unwrap(),
            ],
            format!("no local job {id}: no local render kept a job in"),
        ),
        (
            &[
                scene.to_str().unwrap(),
                "--samples",
                "4",
                "-o",
                out.to_str().unwrap(),
                "--local-dir",
                file.to_str().unwrap(),
            ],
            "not a directory".to_string(),
        ),
    ];
    for (args, want) in cases {
        let o = submit_env(&dir, args, &env);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains(&want), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
    assert!(!empty.exists());
    assert!(std::fs::read(&out).unwrap() == before);
}
