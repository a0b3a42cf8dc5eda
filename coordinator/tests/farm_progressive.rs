//! Progressive jobs in the coordinator without a network, with the core
//! rendering each lease as a worker would: passes in order, each lease a
//! sample range continuing the state the coordinator kept, and the output
//! after the last pass byte for byte the one-shot render's, whether the job
//! ran through, was extended, or the coordinator restarted mid-pass; the
//! noise target and the time limit stop it between passes.

use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Duration;
use trevi_coordinator::farm::progressive::Progressive;
use trevi_coordinator::scheduler::StopReason;
use trevi_coordinator::{Farm, FarmConfig, JobSpec, JobState, LeaseResult, WorkerOptions};
use trevi_core::passes::TileState;
use trevi_core::scene::aisxml::parse_scene_str;
use trevi_core::{Bundle, Rect, Scene};

const SCENE: &str = r#"<scene version="1">
  <sphere id="s" center="0 0 0" radius="1"><surface diffuse="0.8 0.3 0.2"/></sphere>
  <plane id="p" point="0 -1 0" normal="0 1 0"><surface diffuse="0.5 0.5 0.5"/></plane>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1" radius="1.5"/>
  <camera id="cam" position="0 0.5 5" lookat="0 0 0" up="0 1 0" fov="40">
    <render width="24" height="16" supersample="2" shadow-samples="1" output="p.exr"/>
  </camera>
</scene>"#;

/// The scene rendering `total` samples per pixel of its own.
fn scene(total: u32) -> Scene {
    let bundle = Bundle {
        scene: "s.xml".into(),
        files: Default::default(),
    };
    let mut s = Scene::build(parse_scene_str("s.xml", SCENE, &bundle).unwrap());
    s.set_samples(0, total);
    s
}

/// [`scene`] at frame `frame` of a sequence, when given.
fn scene_at(total: u32, frame: Option<u32>) -> Scene {
    let mut s = scene(total);
    if let Some(f) = frame {
        s.set_frame(0, f).unwrap();
    }
    s
}

fn spec(name: &str) -> JobSpec {
    JobSpec {
        frame: None,
        bundle_hash: "0".repeat(64),
        camera: "cam".into(),
        priority: 0,
        width: 24,
        height: 16,
        tile_size: 8,
        output_name: name.into(),
        scene: String::new(),
        submitter: String::new(),
        samples: None,
        aovs: trevi_core::Aovs::NONE,
    }
}

fn farm(dir: &Path) -> Farm {
    Farm::new(FarmConfig::new(dir)).unwrap()
}

/// Renders leases as a worker would until nothing is left or `stop` says
/// so; returns the sample ranges of the leases in the order they came.
fn work(f: &Farm, mut stop: impl FnMut(&Farm) -> bool) -> Vec<(u32, u32)> {
    let worker = f.register_worker(WorkerOptions::default()).unwrap().id;
    let never = AtomicBool::new(false);
    let mut ranges = Vec::new();
    while !stop(f) {
        let Some(l) = f.lease(worker).unwrap() else {
            break;
        };
        let r = l.samples.expect("a pass's lease names its samples");
        ranges.push((r.start, r.end));
        let mut state = if r.start == 0 {
            TileState::new(l.rect)
        } else {
            let (file, rect, next) = f.state_source(worker, l.id).unwrap();
            assert_eq!((rect, next), (l.rect, r.start));
            let mut bytes = Vec::new();
            file.read_encoded(rect, next, |p| {
                bytes.extend(p);
                Ok(())
            })
            .unwrap();
            TileState::decode(&bytes).unwrap()
        };
        state
            .render(&scene_at(r.total, l.frame), 0, r.start..r.end, &never)
            .unwrap();
        f.put_state(l.job, l.rect, &[l.rect], Some(&state.encode()))
            .unwrap();
        f.put_tile(LeaseResult {
            lease: l.id,
            job: l.job,
            rect: l.rect,
            rays: 1,
            pixels: &state.finish(),
            worker: Some(worker),
        })
        .unwrap();
    }
    ranges
}

/// The output of a job of `total` samples rendered in one pass, by tiles
/// of the one-shot renderer.
fn one_shot(total: u32) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    let job = f.submit(spec("p.exr"), Default::default()).unwrap().id;
    render_at_once(&f, total);
    std::fs::read(f.output_file(job).unwrap()).unwrap()
}

/// Renders every lease of `f` by the one-shot renderer at `total`
/// samples (a frame's lease at its frame).
fn render_at_once(f: &Farm, total: u32) {
    let worker = f.register_worker(WorkerOptions::default()).unwrap().id;
    while let Some(l) = f.lease(worker).unwrap() {
        let pixels = trevi_core::tile::render_tile(&scene_at(total, l.frame), 0, l.rect).pixels;
        f.put_tile(LeaseResult {
            lease: l.id,
            job: l.job,
            rect: l.rect,
            rays: 1,
            pixels: &pixels,
            worker: Some(worker),
        })
        .unwrap();
    }
}

fn progressive(samples: u32, pass: u32) -> Progressive {
    Progressive {
        samples,
        pass,
        ..Progressive::default()
    }
}

#[test]
fn passes_go_in_order_and_end_as_the_one_shot_render() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    let info = f
        .submit_progressive(spec("p.exr"), progressive(20, 8), "me")
        .unwrap();
    let job = info.id;
    let p = info.passes.clone().unwrap();
    assert_eq!((p.done, p.samples_total, p.pass), (0, 20, 8));
    assert_eq!(info.tiles_total, 6, "a pass's tiles");
    let ranges = work(&f, |_| false);
    // Every tile of a pass before any of the next: 6 tiles a pass.
    let want: Vec<(u32, u32)> = [(0, 8), (8, 16), (16, 20)]
        .iter()
        .flat_map(|&r| std::iter::repeat_n(r, 6))
        .collect();
    assert_eq!(ranges, want);
    let info = f.info(job).unwrap();
    assert_eq!(info.state, JobState::Done);
    let p = info.passes.unwrap();
    assert_eq!((p.done, p.samples_done), (3, 20));
    let e = p
        .error
        .expect("an error estimate after passes of 2+ samples");
    assert!(e > 0.0 && e < 1.0, "{e}");
    let out = std::fs::read(f.output_file(job).unwrap()).unwrap();
    assert_eq!(out, one_shot(20), "the one-shot render's bytes");
}

#[test]
fn the_output_is_a_whole_image_after_every_pass() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    let job = f
        .submit_progressive(spec("p.exr"), progressive(8, 4), "me")
        .unwrap()
        .id;
    assert!(f.output_file(job).is_err(), "no output before a pass");
    // Through the first pass only.
    work(&f, |f| f.info(job).unwrap().passes.unwrap().done == 1);
    let after_one = std::fs::read(f.output_file(job).unwrap()).unwrap();
    assert_eq!(after_one, one_shot(4), "4 samples of 8: the 4-sample image");
    work(&f, |_| false);
    assert_eq!(
        std::fs::read(f.output_file(job).unwrap()).unwrap(),
        one_shot(8)
    );
}

#[test]
fn an_extended_job_is_the_one_shot_render_of_its_new_total() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    let job = f
        .submit_progressive(spec("p.exr"), progressive(6, 3), "me")
        .unwrap()
        .id;
    work(&f, |_| false);
    assert_eq!(f.info(job).unwrap().state, JobState::Done);
    let info = f.extend(job, 10, Progressive::default()).unwrap();
    assert_eq!(info.passes.unwrap().samples_total, 16);
    let ranges = work(&f, |_| false);
    assert_eq!(ranges.first(), Some(&(6, 9)), "from where it stopped");
    let info = f.info(job).unwrap();
    assert_eq!(info.state, JobState::Done);
    assert_eq!(info.passes.unwrap().samples_done, 16);
    assert_eq!(
        std::fs::read(f.output_file(job).unwrap()).unwrap(),
        one_shot(16)
    );
    // A job of the scene's own samples does not extend; nor does a still.
    let own = f
        .submit_progressive(spec("q.exr"), progressive(0, 1), "me")
        .unwrap()
        .id;
    let e = f
        .extend(own, 4, Progressive::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("finished") || e.contains("--samples"), "{e}");
}

/// A finished progressive job can be extended as long as the farm keeps
/// it, so its bundle must outlive its pass jobs: here every pass job of the
/// first job is forgotten (`--keep-ended 1` counts pass jobs apart, and a
/// second job's pass ends after them) and the bundle is past its grace, yet
/// the collector keeps it and the extension runs.
#[test]
fn a_finished_extendable_job_keeps_its_bundle_after_its_pass_jobs_are_forgotten() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = FarmConfig::new(dir.path());
    cfg.retention.keep_ended = 1;
    cfg.retention.bundle_grace = Duration::ZERO;
    let f = Farm::new(cfg).unwrap();
    let bundle = Bundle {
        scene: "s.xml".into(),
        files: [("s.xml".to_string(), SCENE.as_bytes().to_vec())].into(),
    };
    let mut up = f.bundles().begin_upload().unwrap();
    up.write(&bundle.encode()).unwrap();
    let hash = f.bundles().finish_upload(up, usize::MAX).unwrap();
    let stored = dir.path().join("bundles").join(&hash);
    let long_ago = std::time::SystemTime::now() - Duration::from_secs(3600);
    let age = |p: &Path| {
        std::fs::File::options()
            .write(true)
            .open(p)
            .unwrap()
            .set_modified(long_ago)
            .unwrap()
    };

    let job = f
        .submit_progressive(
            JobSpec {
                bundle_hash: hash.clone(),
                ..spec("p.exr")
            },
            progressive(4, 2),
            "me",
        )
        .unwrap()
        .id;
    work(&f, |_| false);
    let other = f
        .submit_progressive(spec("q.exr"), progressive(2, 2), "me")
        .unwrap()
        .id;
    work(&f, |_| false);
    assert_eq!(f.info(other).unwrap().state, JobState::Done);
    assert!(
        f.list().iter().all(|j| j.spec.bundle_hash != hash),
        "the first job's pass jobs are forgotten"
    );

    age(&stored);
    f.collect_bundles();
    assert!(stored.exists(), "the extendable job's bundle was collected");
    assert!(f.bundles().get(&hash).is_ok());
    f.extend(job, 4, Progressive::default()).unwrap();
    work(&f, |_| false);
    assert_eq!(
        std::fs::read(f.output_file(job).unwrap()).unwrap(),
        one_shot(8)
    );
}

#[test]
fn a_restart_mid_pass_resumes_from_the_kept_states() {
    let dir = tempfile::tempdir().unwrap();
    let job = {
        let f = farm(dir.path());
        let job = f
            .submit_progressive(spec("p.exr"), progressive(12, 4), "me")
            .unwrap()
            .id;
        // The first pass and half of the second.
        let mut leases = 0;
        work(&f, |_| {
            leases += 1;
            leases > 9
        });
        job
    };
    let f = farm(dir.path());
    let info = f.info(job).unwrap();
    assert_eq!(info.passes.unwrap().done, 1);
    work(&f, |_| false);
    let info = f.info(job).unwrap();
    assert_eq!(info.state, JobState::Done);
    assert_eq!(info.passes.unwrap().samples_done, 12);
    assert_eq!(
        std::fs::read(f.output_file(job).unwrap()).unwrap(),
        one_shot(12)
    );
}

#[test]
fn the_noise_target_and_the_time_limit_stop_between_passes() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    let loose = Progressive {
        noise_target: Some(0.9),
        ..progressive(64, 4)
    };
    let job = f.submit_progressive(spec("p.exr"), loose, "me").unwrap().id;
    work(&f, |_| false);
    let p = f.info(job).unwrap().passes.unwrap();
    assert_eq!(p.stopped_by, Some(StopReason::NoiseTarget));
    assert_eq!((p.done, p.samples_done), (1, 4), "met after the first pass");
    assert!(p.error.unwrap() <= 0.9);
    let strict = Progressive {
        noise_target: Some(1e-9),
        ..progressive(8, 4)
    };
    let job = f
        .submit_progressive(spec("q.exr"), strict, "me")
        .unwrap()
        .id;
    work(&f, |_| false);
    let p = f.info(job).unwrap().passes.unwrap();
    assert_eq!(
        (p.stopped_by, p.samples_done),
        (None, 8),
        "never met: all passes"
    );
    // A time limit already passed after the first pass: no second pass.
    let quick = Progressive {
        time_limit: Some(Duration::from_nanos(1)),
        ..progressive(8, 4)
    };
    let job = f.submit_progressive(spec("r.exr"), quick, "me").unwrap().id;
    work(&f, |_| false);
    let info = f.info(job).unwrap();
    let p = info.passes.unwrap();
    assert_eq!(info.state, JobState::Done);
    assert_eq!(
        (p.stopped_by, p.samples_done),
        (Some(StopReason::TimeLimit), 4)
    );
    assert_eq!(
        std::fs::read(f.output_file(job).unwrap()).unwrap(),
        one_shot(4)
    );
}

#[test]
fn states_that_do_not_fit_the_lease_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    f.submit_progressive(spec("p.exr"), progressive(4, 2), "me")
        .unwrap();
    let worker = f.register_worker(WorkerOptions::default()).unwrap().id;
    let l = f.lease(worker).unwrap().unwrap();
    let job = l.job;
    let never = AtomicBool::new(false);
    let mut state = TileState::new(l.rect);
    state.render(&scene(4), 0, 0..1, &never).unwrap();
    for (bytes, why) in [
        (state.encode(), "at sample 1"),
        (TileState::new(Rect::new(0, 0, 1, 1)).encode(), "is Rect"),
        (vec![1, 2, 3], "header"),
    ] {
        let e = f
            .put_state(job, l.rect, &[l.rect], Some(&bytes))
            .unwrap_err()
            .to_string();
        assert!(e.contains(why), "{e}");
    }
    let e = f.put_state(job, l.rect, &[l.rect], None).unwrap_err();
    assert!(e.to_string().contains("carry"), "{e}");
    // A still's results carry none.
    let still = f.submit(spec("s.exr"), Default::default()).unwrap().id;
    let e = f
        .put_state(still, l.rect, &[l.rect], Some(&state.encode()))
        .unwrap_err();
    assert!(e.to_string().contains("not a pass"), "{e}");
    // A first pass has no state to fetch.
    let e = f.state_source(worker, l.id).unwrap_err();
    assert!(e.to_string().contains("does not continue"), "{e}");
}

/// The frames `0..frames` of a sequence of `total` samples rendered at
/// once, by tiles of the one-shot renderer.
fn one_shot_frames(total: u32, frames: u32) -> Vec<Vec<u8>> {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    let seq = f
        .submit_sequence(spec("shot.exr"), 0, frames - 1, "me")
        .unwrap()
        .id;
    render_at_once(&f, total);
    (0..frames)
        .map(|n| std::fs::read(f.frame_file(seq, Some(n)).unwrap()).unwrap())
        .collect()
}

#[test]
fn a_sequence_in_passes_renders_each_frame_s_passes_in_turn() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    let info = f
        .submit_progressive_sequence(spec("shot.exr"), 0, 2, progressive(6, 3), "me")
        .unwrap();
    let seq = info.id;
    assert_eq!(info.tiles_total, 3 * 2 * 6, "frames × passes × tiles");
    let ranges = work(&f, |_| false);
    let want: Vec<(u32, u32)> = (0..3)
        .flat_map(|_| [(0, 3), (3, 6)])
        .flat_map(|r| std::iter::repeat_n(r, 6))
        .collect();
    assert_eq!(ranges, want, "each frame's passes, frame after frame");
    let info = f.info(seq).unwrap();
    assert_eq!(info.state, JobState::Done);
    assert_eq!(info.frames.unwrap().done, 3);
    let once = one_shot_frames(6, 3);
    assert_ne!(once[0], once[1], "frames differ");
    for (n, frame) in once.iter().enumerate() {
        let got = std::fs::read(f.frame_file(seq, Some(n as u32)).unwrap()).unwrap();
        assert!(&got == frame, "frame {n} differs from its one-shot render");
    }
    // A time limit or a noise target would stop mid-frame: refused.
    let e = f
        .submit_progressive_sequence(
            spec("shot.exr"),
            0,
            2,
            Progressive {
                noise_target: Some(0.1),
                ..progressive(6, 3)
            },
            "me",
        )
        .unwrap_err();
    assert!(e.to_string().contains("--samples and --pass only"), "{e}");
    assert!(f.extend(seq, 4, Progressive::default()).is_err());
}

#[test]
fn a_sequence_in_passes_resumes_after_a_restart_mid_frame() {
    let once = one_shot_frames(6, 3);
    for stop_after in [9, 15, 18] {
        let dir = tempfile::tempdir().unwrap();
        let seq = {
            let f = farm(dir.path());
            let seq = f
                .submit_progressive_sequence(spec("shot.exr"), 0, 2, progressive(6, 3), "me")
                .unwrap()
                .id;
            let mut leases = 0;
            work(&f, |_| {
                leases += 1;
                leases > stop_after
            });
            seq
        };
        let f = farm(dir.path());
        work(&f, |_| false);
        let info = f.info(seq).unwrap();
        assert_eq!(info.state, JobState::Done, "stopped after {stop_after}");
        for (n, frame) in once.iter().enumerate() {
            let got = std::fs::read(f.frame_file(seq, Some(n as u32)).unwrap()).unwrap();
            assert!(
                &got == frame,
                "frame {n} after a restart at lease {stop_after}"
            );
        }
    }
}

/// Every bound of a progressive submission is checked before anything is
/// queued: its samples, the frame's samples, its tiles' states, its states
/// on disk, its noise target, an extension past the most samples.
#[test]
fn hostile_progressive_submissions_are_refused_before_anything_is_queued() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    let refused = |spec: JobSpec, p: Progressive, what: &str| {
        let e = f.submit_progressive(spec, p, "me").unwrap_err().to_string();
        assert!(e.contains(what), "{what}: {e}");
    };
    let max = trevi_core::passes::MAX_SAMPLES;
    refused(spec("p.exr"), progressive(max + 1, 0), "a job may ask for");
    // 16384² at 65 samples: one sample a pixel more than the default bound.
    let huge_frame = JobSpec {
        width: 1 << 14,
        height: 1 << 14,
        ..spec("p.exr")
    };
    refused(huge_frame, progressive(65, 1), "--max-image-samples");
    let big_tiles = JobSpec {
        tile_size: 1024,
        ..spec("p.exr")
    };
    refused(big_tiles, progressive(4, 1), "--tile-size");
    for t in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let p = Progressive {
            noise_target: Some(t),
            ..progressive(4, 1)
        };
        refused(spec("p.exr"), p, "noise target");
    }
    // States on disk: a frame under the samples bound but over the state
    // bytes (16 GiB at 128 bytes a pixel is 2^27 pixels).
    let wide = JobSpec {
        width: 1 << 15,
        height: 1 << 13,
        ..spec("p.exr")
    };
    refused(wide, progressive(1, 1), "a job may keep");
    assert!(f.list().is_empty(), "nothing queued");
    // An extension past the most samples a job may have.
    let job = f
        .submit_progressive(spec("p.exr"), progressive(2, 2), "me")
        .unwrap()
        .id;
    work(&f, |_| false);
    let e = f.extend(job, max, Progressive::default()).unwrap_err();
    assert!(e.to_string().contains("a job may have"), "{e}");
    assert_eq!(f.info(job).unwrap().state, JobState::Done, "left as it was");
}
