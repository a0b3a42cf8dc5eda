//! The coordinator serving many users at once without a network (issue 36):
//! one user's sequence does not delete another's unfetched output, a queued
//! job holds no file, a download of a long sequence looks at one file, and
//! ids that are not what a request takes them for say what they are.

mod common;

use common::spec;
use std::path::Path;
use std::time::{Duration, Instant};
use trevi_coordinator::farm::Retention;
use trevi_coordinator::{
    Farm, FarmConfig, FarmError, JobSpec, JobState, LeaseResult, SubmitOptions, WorkerOptions,
};
use trevi_core::Rect;

fn farm(dir: &Path, retention: Retention) -> Farm {
    Farm::new(FarmConfig {
        retention,
        ..FarmConfig::new(dir)
    })
    .unwrap()
}

fn grey(r: Rect) -> Vec<[f32; 3]> {
    vec![[0.25; 3]; r.pixel_count()]
}

/// Renders every tile there is to lease.
fn render_all(f: &Farm) {
    let worker = f.register_worker(WorkerOptions::default()).unwrap().id;
    while let Some(l) = f.lease(worker).unwrap() {
        f.put_tile(LeaseResult {
            lease: l.id,
            job: l.job,
            rect: l.rect,
            rays: 1,
            pixels: &grey(l.rect),
            worker: None,
        })
        .unwrap();
    }
}

fn still(f: &Farm) -> u64 {
    f.submit(spec(32, 16, 16, "still.png"), SubmitOptions::default())
        .unwrap()
        .id
}

fn sequence(f: &Farm, first: u32, last: u32) -> u64 {
    let s = JobSpec {
        output_name: "shot.png".into(),
        ..spec(32, 16, 16, "shot.png")
    };
    f.submit_sequence(s, first, last, "").unwrap().id
}

/// Issue 36: each frame of a sequence counted against `--keep-ended`, so
/// one 1000-frame sequence deleted every other user's finished, unfetched
/// output. A sequence is one job; an output no one fetched is kept by the
/// count (only its age removes it); a fetched one goes.
#[test]
fn one_user_s_sequence_does_not_delete_another_s_unfetched_output() {
    let dir = tempfile::tempdir().unwrap();
    let retention = Retention {
        keep_ended: 2,
        keep_ended_for: None,
        ..Retention::default()
    };
    let f = farm(dir.path(), retention);
    let mine = still(&f);
    render_all(&f);
    let mine_out = f.output_file(mine).unwrap();
    assert!(mine_out.is_file());
    // Another user's sequence of 12 frames.
    let seq = sequence(&f, 1, 12);
    render_all(&f);
    assert_eq!(f.info(seq).unwrap().state, JobState::Done);
    assert_eq!(f.info(mine).unwrap().state, JobState::Done, "forgotten");
    assert!(mine_out.is_file(), "another user's sequence deleted it");
    // Three more stills, none fetched: five ended jobs, more than the two
    // kept, but none was fetched, so none goes.
    let more: Vec<u64> = (0..3)
        .map(|_| {
            let id = still(&f);
            render_all(&f);
            id
        })
        .collect();
    for &id in [mine, seq].iter().chain(&more) {
        assert!(f.info(id).is_ok(), "job {id} forgotten unfetched");
    }
    // Once fetched, the count forgets the oldest at the next end.
    f.fetched(mine, None);
    still(&f);
    render_all(&f);
    assert!(matches!(f.info(mine), Err(FarmError::UnknownJob(_))));
    assert!(!mine_out.exists());
    assert!(f.info(seq).is_ok());
}

/// A sequence is one ended job however many frames it has: with
/// `--keep-ended 2`, a fetched still and a 12-frame sequence are two, so the
/// still (fetched, which the count may remove) stays.
#[test]
fn a_sequence_counts_as_one_ended_job_however_many_frames_it_has() {
    let dir = tempfile::tempdir().unwrap();
    let retention = Retention {
        keep_ended: 2,
        keep_ended_for: None,
        ..Retention::default()
    };
    let f = farm(dir.path(), retention);
    let mine = still(&f);
    render_all(&f);
    f.fetched(mine, None);
    let seq = sequence(&f, 1, 12);
    render_all(&f);
    assert_eq!(f.info(seq).unwrap().state, JobState::Done);
    assert!(
        f.info(mine).is_ok(),
        "the sequence's frames were counted as jobs"
    );
    assert!(f.output_file(mine).unwrap().is_file());
}

/// Issue 36: each queued job held its output's temporary file open (two
/// descriptors), so 600 queued jobs ran a coordinator with 1024 out of
/// descriptors. A queued job holds no file: none is even created.
#[test]
fn queued_jobs_hold_no_output_file_until_their_first_tile() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path(), Retention::default());
    let ids: Vec<u64> = (0..50).map(|_| still(&f)).collect();
    let seq = sequence(&f, 0, 3);
    let files = |dir: &Path| -> usize {
        std::fs::read_dir(dir.join("jobs"))
            .map(|d| {
                d.flatten()
                    .map(|e| std::fs::read_dir(e.path()).map_or(0, |d| d.count()))
                    .sum()
            })
            .unwrap_or(0)
    };
    assert_eq!(files(dir.path()), 0, "queued jobs made files");
    render_all(&f);
    for id in ids {
        assert_eq!(f.info(id).unwrap().state, JobState::Done);
        assert!(f.output_file(id).unwrap().is_file());
    }
    assert_eq!(f.info(seq).unwrap().state, JobState::Done);
    // A queued job restored after a restart holds none either.
    drop(f);
    let dir2 = tempfile::tempdir().unwrap();
    {
        let f = farm(dir2.path(), Retention::default());
        for _ in 0..5 {
            still(&f);
        }
    }
    let f = farm(dir2.path(), Retention::default());
    assert_eq!(files(dir2.path()), 0, "restored queued jobs made files");
    render_all(&f);
    assert!(f.list().iter().all(|j| j.state == JobState::Done));
}

/// Issue 36: a download without a frame of a 10⁷-frame sequence looked at
/// every frame's file (28.7 s a call, on the async runtime). The highest
/// frame done is known: the answer looks at one file, however long the
/// sequence. (The bound is generous: a scan of the range takes tens of
/// seconds.)
#[test]
fn a_download_of_a_ten_million_frame_sequence_looks_at_one_file() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path(), Retention::default());
    let seq = sequence(&f, 0, trevi_core::scene::animation::MAX_FRAME);
    let e = f.output_file(seq).unwrap_err();
    assert!(e.to_string().contains("no frame is done yet"), "{e}");
    // Frame 0 done (its two tiles), then the rest cancelled.
    let worker = f.register_worker(WorkerOptions::default()).unwrap().id;
    while f.info(seq).unwrap().frames.unwrap().done == 0 {
        let l = f.lease(worker).unwrap().expect("a tile of frame 0 or 1");
        f.put_tile(LeaseResult {
            lease: l.id,
            job: l.job,
            rect: l.rect,
            rays: 1,
            pixels: &grey(l.rect),
            worker: None,
        })
        .unwrap();
    }
    let start = Instant::now();
    let p = f.output_file(seq).unwrap();
    assert!(p.ends_with("shot.0000.png"), "{}", p.display());
    f.cancel(seq).unwrap();
    let p = f.output_file(seq).unwrap();
    assert!(p.ends_with("shot.0000.png"), "{}", p.display());
    let took = start.elapsed();
    assert!(took < Duration::from_secs(5), "two lookups took {took:?}");
}

/// Issue 36: `fetch` of a sequence frame's id said "opening the output of
/// job 5: No such file or directory" while `status 5` showed it done; a
/// still asked for a frame was "no job N"; a finished sequence had no
/// preview.
#[test]
fn ids_that_are_not_what_a_request_takes_them_for_say_what_they_are() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path(), Retention::default());
    let s = still(&f);
    let seq = sequence(&f, 3, 4);
    render_all(&f);
    assert_eq!(f.info(seq).unwrap().state, JobState::Done);
    // A frame's own job id: its file, in its sequence's directory.
    let first = trevi_coordinator::scheduler::FRAME_IDS;
    let frame_job = (first..first + 10)
        .find(|&id| f.info(id).is_ok_and(|i| i.spec.frame == Some(3)))
        .expect("frame 3's job");
    assert_eq!(
        f.output_file(frame_job).unwrap(),
        f.frame_file(seq, Some(3)).unwrap()
    );
    assert!(f.output_file(frame_job).unwrap().is_file());
    let e = f.frame_file(frame_job, Some(3)).unwrap_err().to_string();
    assert!(e.contains(&format!("frame 3 of sequence {seq}")), "{e}");
    // A still asked for a frame.
    let e = f.frame_file(s, Some(3)).unwrap_err();
    assert!(matches!(e, FarmError::NoOutput(..)), "{e:?}");
    assert!(e.to_string().contains("a still, not a sequence"), "{e}");
    // An id that is nothing.
    assert!(matches!(
        f.frame_file(9_999, Some(1)),
        Err(FarmError::UnknownJob(9_999))
    ));
    // The finished sequence's preview is its last frame's.
    let p = f.preview(seq).unwrap();
    assert_eq!((p.width, p.height), (32, 16));
    assert!(p.tiles > 0);
}
