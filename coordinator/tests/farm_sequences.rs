//! Sequences in the coordinator without a network: frames queued in order
//! with at most `Limits::frames_in_progress` in progress, each frame's leases
//! carrying its frame number, each frame's output its own file, and a
//! restart mid-sequence keeping the frames done and the stored tiles of the
//! frame in progress.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use trevi_coordinator::farm::sequences::DEFAULT_FRAMES_IN_PROGRESS as FRAMES_IN_PROGRESS;
use trevi_coordinator::{
    Farm, FarmConfig, JobSpec, JobState, LeaseResult, Limits, SubmitOptions, WorkerOptions,
};
use trevi_core::Rect;

fn spec() -> JobSpec {
    JobSpec {
        frame: None,
        bundle_hash: "0".repeat(64),
        camera: "cam".into(),
        priority: 0,
        // Two tiles a frame.
        width: 32,
        height: 16,
        tile_size: 16,
        output_name: "shot.png".into(),
        scene: String::new(),
        submitter: String::new(),
        samples: None,
        aovs: trevi_core::Aovs::NONE,
    }
}

/// Each frame's pixels: a grey of its own.
fn pixels(frame: u32, r: Rect) -> Vec<[f32; 3]> {
    vec![[frame as f32 / 16.0; 3]; r.pixel_count()]
}

fn farm(dir: &Path) -> Farm {
    Farm::new(FarmConfig::new(dir)).unwrap()
}

/// Leases and renders tiles until `stop` says so or nothing is left;
/// returns the tiles leased per frame. Checks the bound on frames in
/// progress at every lease.
fn run(f: &Farm, seq: u64, mut stop: impl FnMut(&Farm) -> bool) -> BTreeMap<u32, usize> {
    let worker = f.register_worker(WorkerOptions::default()).unwrap().id;
    let mut leased = BTreeMap::new();
    while !stop(f) {
        let Some(l) = f.lease(worker).unwrap() else {
            break;
        };
        let frame = l.frame.expect("a frame's lease carries its frame");
        *leased.entry(frame).or_default() += 1;
        let fr = f.info(seq).unwrap().frames.unwrap();
        assert!(fr.in_progress as usize <= FRAMES_IN_PROGRESS, "{fr:?}");
        f.put_tile(LeaseResult {
            lease: l.id,
            job: l.job,
            rect: l.rect,
            rays: 1,
            pixels: &pixels(frame, l.rect),
            worker: None,
        })
        .unwrap();
    }
    leased
}

#[test]
fn frames_go_in_order_two_at_a_time_and_a_restart_loses_no_frame_or_tile() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    let info = f.submit_sequence(spec(), 3, 7, "me").unwrap();
    let seq = info.id;
    let fr = info.frames.unwrap();
    assert_eq!((fr.first, fr.last, fr.done), (3, 7, 0));
    assert_eq!(info.tiles_total, 5 * 2);
    assert_eq!(info.spec.output_name, "shot.####.png");
    // Frames 3 and 4 are queued, not more.
    assert_eq!(fr.in_progress as usize, FRAMES_IN_PROGRESS);
    // One job in the list: the sequence.
    let listed: Vec<u64> = f.list_from(0, 100).0.iter().map(|j| j.id).collect();
    assert_eq!(listed, [seq]);

    // Frames 3 and 4 done, and one tile of frame 5.
    let leased = run(&f, seq, |f| {
        let i = f.info(seq).unwrap();
        i.tiles_done >= 5
    });
    assert_eq!(leased.keys().copied().collect::<Vec<_>>(), [3, 4, 5]);
    let before = f.info(seq).unwrap();
    assert_eq!(before.frames.unwrap().done, 2);
    assert!(f.frame_file(seq, Some(3)).unwrap().is_file());
    assert!(f.frame_file(seq, Some(5)).is_err(), "frame 5 is not done");
    drop(f); // The coordinator stops (its state is on disk).

    let f = farm(dir.path());
    let after = f.info(seq).unwrap();
    assert_eq!(after.frames.unwrap().done, 2, "{after:?}");
    assert_eq!(after.tiles_done, 5, "the stored tile of frame 5 is kept");
    let leased = run(&f, seq, |_| false);
    assert_eq!(
        leased.get(&5),
        Some(&1),
        "frame 5's stored tile went out again"
    );
    assert_eq!(leased.keys().copied().collect::<Vec<_>>(), [5, 6, 7]);
    let done = f.info(seq).unwrap();
    assert_eq!(done.state, JobState::Done);
    assert_eq!(done.frames.unwrap().done, 5);
    assert_eq!(done.tiles_done, 10);

    // Each frame's file is the still made of the same pixels.
    let other = tempfile::tempdir().unwrap();
    let g = farm(other.path());
    let worker = g.register_worker(WorkerOptions::default()).unwrap().id;
    let mut seen = BTreeSet::new();
    for frame in 3..=7 {
        let still = g.submit(spec(), SubmitOptions::default()).unwrap().id;
        while let Some(l) = g.lease(worker).unwrap() {
            g.put_tile(LeaseResult {
                lease: l.id,
                job: l.job,
                rect: l.rect,
                rays: 1,
                pixels: &pixels(frame, l.rect),
                worker: None,
            })
            .unwrap();
        }
        let want = std::fs::read(g.output_file(still).unwrap()).unwrap();
        let path = f.frame_file(seq, Some(frame)).unwrap();
        assert!(path.ends_with(format!("shot.{frame:04}.png")), "{path:?}");
        assert_eq!(std::fs::read(&path).unwrap(), want, "frame {frame}");
        seen.insert(want);
    }
    assert_eq!(seen.len(), 5, "the frames differ");
}

#[test]
fn cancel_and_priority_reach_the_frames_in_progress() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    let seq = f.submit_sequence(spec(), 0, 9, "").unwrap().id;
    let still = f.submit(spec(), SubmitOptions::default()).unwrap().id;
    // Raised above the still: its frames get the workers first.
    f.set_priority(seq, 5).unwrap();
    let worker = f.register_worker(WorkerOptions::default()).unwrap().id;
    let l = f.lease(worker).unwrap().unwrap();
    assert_eq!(l.frame, Some(0));
    assert_ne!(l.job, still);
    let cancelled = f.cancel(seq).unwrap();
    assert_eq!(cancelled.state, JobState::Cancelled);
    assert_eq!(f.info(l.job).unwrap().state, JobState::Cancelled);
    // Only the still is left to lease.
    while let Some(l) = f.lease(worker).unwrap() {
        assert_eq!(l.job, still);
        assert_eq!(l.frame, None);
    }
    assert!(
        f.submit_sequence(spec(), 5, 2, "").is_err(),
        "a reversed range"
    );
}

/// With `--frames-in-progress N`, a worker that takes every tile it can get
/// (holding them all, rendering none) gets tiles of exactly N frames, the
/// next N in frame order once those are done: never more frames at once,
/// whatever the status counter says.
#[test]
fn frames_in_progress_is_the_most_frames_a_sequence_leases_at_once() {
    for n in [1usize, 3, 7] {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = FarmConfig::new(dir.path());
        cfg.limits = Limits {
            frames_in_progress: n,
            ..Limits::default()
        };
        let f = Farm::new(cfg).unwrap();
        // 20 frames of two tiles each.
        let seq = f.submit_sequence(spec(), 0, 19, "").unwrap().id;
        let worker = f.register_worker(WorkerOptions::default()).unwrap().id;
        let mut next = 0u32;
        while next < 20 {
            let mut held = Vec::new();
            while let Some(l) = f.lease(worker).unwrap() {
                held.push(l);
            }
            let frames: BTreeSet<u32> = held.iter().map(|l| l.frame.unwrap()).collect();
            let want: BTreeSet<u32> = (next..(next + n as u32).min(20)).collect();
            assert_eq!(frames, want, "N = {n}");
            assert_eq!(held.len(), 2 * want.len(), "N = {n}");
            let fr = f.info(seq).unwrap().frames.unwrap();
            assert_eq!(fr.in_progress as usize, want.len(), "N = {n}");
            for l in held {
                f.put_tile(LeaseResult {
                    lease: l.id,
                    job: l.job,
                    rect: l.rect,
                    rays: 1,
                    pixels: &pixels(l.frame.unwrap(), l.rect),
                    worker: None,
                })
                .unwrap();
            }
            next += want.len() as u32;
        }
        let done = f.info(seq).unwrap();
        assert_eq!(done.state, JobState::Done, "N = {n}");
        assert_eq!(done.frames.unwrap().done, 20);
    }
}
