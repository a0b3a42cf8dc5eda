//! Job control in the coordinator without a network: a job paused (its
//! tiles out finishing, or returned at once) and resumed, across a
//! restart; jobs waiting for others, queued when those are done and
//! failed, in a chain, when one fails or is cancelled; and the bounds on
//! what a request may name.

mod common;

use std::path::Path;
use trevi_coordinator::farm::MAX_AFTER;
use trevi_coordinator::scheduler::Lease;
use trevi_coordinator::{
    Farm, FarmConfig, FarmError, JobInfo, JobSpec, JobState, LeaseResult, SubmitOptions,
    TileOutcome, WorkerOptions,
};
use trevi_core::{FrameWriter, Rect};

fn pixel(x: u32, y: u32) -> [f32; 3] {
    [
        x as f32 / 97.0,
        y as f32 / 61.0,
        ((x * 7 + y * 3) % 11) as f32 / 10.0,
    ]
}

fn pixels(r: Rect) -> Vec<[f32; 3]> {
    (r.y..r.y + r.h)
        .flat_map(|y| (r.x..r.x + r.w).map(move |x| pixel(x, y)))
        .collect()
}

fn farm(dir: &Path) -> Farm {
    Farm::new(FarmConfig::new(dir)).unwrap()
}

/// A 48 × 32 still in 16-pixel tiles: six tiles.
fn spec(name: &str) -> JobSpec {
    common::spec(48, 32, 16, name)
}

/// The frame written in band order straight through a FrameWriter: the
/// bytes of a render never paused.
fn reference(dir: &Path, name: &str) -> Vec<u8> {
    let path = dir.join("reference").join(name);
    let mut fw = FrameWriter::create(&path, 48, 32).unwrap();
    for r in trevi_core::tile::band_order_tiles(48, 32, 16) {
        fw.write_tile(r, &pixels(r)).unwrap();
    }
    fw.finish().unwrap();
    std::fs::read(path).unwrap()
}

fn submit(f: &Farm, name: &str) -> u64 {
    f.submit(spec(name), SubmitOptions::default()).unwrap().id
}

/// Submits a job waiting for `after`, at a higher priority than the jobs
/// of [`submit`]: were it not held, its tiles would go out first.
fn submit_after(f: &Farm, name: &str, after: &[u64]) -> Result<JobInfo, FarmError> {
    let first = JobSpec {
        priority: 5,
        ..spec(name)
    };
    f.submit(
        first,
        SubmitOptions {
            after: after.to_vec(),
            ..SubmitOptions::default()
        },
    )
}

fn put(f: &Farm, l: &Lease) -> TileOutcome {
    f.put_tile(LeaseResult {
        lease: l.id,
        job: l.job,
        rect: l.rect,
        rays: 1,
        pixels: &pixels(l.rect),
        worker: None,
    })
    .unwrap()
}

/// Leases and renders every tile there is now.
fn render_all(f: &Farm, worker: u64) {
    while let Some(l) = f.lease(worker).unwrap() {
        put(f, &l);
    }
}

fn worker(f: &Farm) -> u64 {
    f.register_worker(WorkerOptions::default()).unwrap().id
}

#[test]
fn a_paused_job_leases_nothing_its_tiles_out_finish_and_it_resumes_to_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    let job = submit(&f, "a.png");
    let w = worker(&f);
    let first = f.lease(w).unwrap().unwrap();
    let out = f.lease(w).unwrap().unwrap();
    put(&f, &first);
    let info = f.pause(job, false).unwrap();
    assert!(info.paused);
    assert_eq!(info.state, JobState::Running);
    assert_eq!(f.lease(w).unwrap(), None, "a paused job leases nothing");
    // The tile out is still the worker's, and its result counts.
    assert!(f.heartbeat(w, &[out.id]).unwrap().is_empty());
    assert_eq!(put(&f, &out), TileOutcome::Accepted);
    assert_eq!(f.info(job).unwrap().tiles_done, 2);
    // Pausing again changes nothing.
    assert!(f.pause(job, false).unwrap().paused);
    let info = f.resume(job).unwrap();
    assert!(!info.paused);
    render_all(&f, w);
    let info = f.info(job).unwrap();
    assert_eq!((info.state, info.tiles_done), (JobState::Done, 6));
    assert!(!info.paused);
    assert_eq!(
        std::fs::read(f.output_path(job, "a.png")).unwrap(),
        reference(dir.path(), "a.png")
    );
}

#[test]
fn pausing_now_returns_the_tiles_out_and_the_workers_drop_them() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    let job = submit(&f, "a.png");
    let w = worker(&f);
    let out = f.lease(w).unwrap().unwrap();
    f.pause(job, true).unwrap();
    assert_eq!(f.heartbeat(w, &[out.id]).unwrap(), vec![out.id]);
    assert_eq!(f.lease(w).unwrap(), None);
    f.resume(job).unwrap();
    // The returned tile goes out first again.
    let again = f.lease(w).unwrap().unwrap();
    assert_eq!(again.rect, out.rect);
    put(&f, &again);
    render_all(&f, w);
    assert_eq!(f.info(job).unwrap().state, JobState::Done);
    assert_eq!(
        std::fs::read(f.output_path(job, "a.png")).unwrap(),
        reference(dir.path(), "a.png")
    );
}

#[test]
fn a_paused_job_stays_paused_with_its_tiles_across_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let job = {
        let f = farm(dir.path());
        let job = submit(&f, "a.png");
        let w = worker(&f);
        for _ in 0..3 {
            let l = f.lease(w).unwrap().unwrap();
            put(&f, &l);
        }
        f.pause(job, true).unwrap();
        job
    };
    let f = farm(dir.path());
    let info = f.info(job).unwrap();
    assert!(info.paused, "{info:?}");
    assert_eq!(info.tiles_done, 3);
    let w = worker(&f);
    assert_eq!(f.lease(w).unwrap(), None, "paused after the restart too");
    f.resume(job).unwrap();
    let mut rendered = 0;
    while let Some(l) = f.lease(w).unwrap() {
        put(&f, &l);
        rendered += 1;
    }
    // Only the tiles not done before the pause are rendered again.
    assert_eq!(rendered, 3);
    assert_eq!(f.info(job).unwrap().state, JobState::Done);
    assert_eq!(
        std::fs::read(f.output_path(job, "a.png")).unwrap(),
        reference(dir.path(), "a.png")
    );
    // Resumed is stored too: a second restart leases it (it is done).
    drop(f);
    let f = farm(dir.path());
    assert!(!f.info(job).unwrap().paused);
}

#[test]
fn a_sequence_pauses_its_frames_in_progress_and_those_queued_while_paused() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    let seq = f.submit_sequence(spec("s.png"), 1, 3, "").unwrap().id;
    let w = worker(&f);
    f.pause(seq, true).unwrap();
    assert_eq!(f.lease(w).unwrap(), None);
    f.resume(seq).unwrap();
    // Frame 1's six tiles, then paused: they finish, frame 1 ends, and
    // frame 3, queued then, is parked with frame 2.
    let leases: Vec<Lease> = (0..6).map(|_| f.lease(w).unwrap().unwrap()).collect();
    assert!(leases.iter().all(|l| l.frame == Some(1)), "{leases:?}");
    // A part of it is not controlled on its own.
    let e = f.pause(leases[0].job, false).unwrap_err();
    assert!(matches!(e, FarmError::Conflict(_)), "{e}");
    f.pause(seq, false).unwrap();
    for l in &leases {
        assert_eq!(put(&f, l), TileOutcome::Accepted);
    }
    let fr = f.info(seq).unwrap().frames.unwrap();
    assert_eq!((fr.done, fr.in_progress), (1, 2));
    assert_eq!(f.lease(w).unwrap(), None);
    drop(f);
    let f = farm(dir.path());
    assert!(f.info(seq).unwrap().paused);
    let w = worker(&f);
    assert_eq!(f.lease(w).unwrap(), None);
    f.resume(seq).unwrap();
    render_all(&f, w);
    let info = f.info(seq).unwrap();
    assert_eq!(info.state, JobState::Done, "{info:?}");
}

#[test]
fn a_job_waits_until_what_it_waits_for_is_done() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    let a = submit(&f, "a.png");
    let b = submit(&f, "b.png");
    let c = submit_after(&f, "c.png", &[a, b, a]).unwrap();
    assert_eq!(c.waiting_for, vec![a, b], "repeats are dropped");
    assert_eq!(c.state, JobState::Queued);
    let w = worker(&f);
    // Only a's and b's tiles go out.
    let mut jobs = std::collections::BTreeSet::new();
    while let Some(l) = f.lease(w).unwrap() {
        jobs.insert(l.job);
        put(&f, &l);
        if f.info(a).unwrap().state == JobState::Done {
            break;
        }
    }
    assert_eq!(f.info(c.id).unwrap().waiting_for, vec![b]);
    render_all(&f, w);
    assert!(!jobs.contains(&c.id));
    assert_eq!(f.info(b).unwrap().state, JobState::Done);
    // b done: c ran once a and b were done.
    let info = f.info(c.id).unwrap();
    assert_eq!(info.state, JobState::Done, "{info:?}");
    assert!(info.waiting_for.is_empty());
    // Waiting for a job already done: queued at once.
    let d = submit_after(&f, "d.png", &[a]).unwrap();
    assert!(d.waiting_for.is_empty());
    assert!(f.lease(w).unwrap().is_some());
}

#[test]
fn a_chain_fails_job_after_job_naming_the_cause() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    let a = submit(&f, "a.png");
    let b = submit_after(&f, "b.png", &[a]).unwrap().id;
    let c = submit_after(&f, "c.png", &[b]).unwrap().id;
    f.cancel(a).unwrap();
    let b_info = f.info(b).unwrap();
    assert_eq!(b_info.state, JobState::Failed);
    let why = b_info.error.unwrap();
    assert!(
        why.contains(&format!("job {a}")) && why.contains("cancelled"),
        "{why}"
    );
    let c_info = f.info(c).unwrap();
    assert_eq!(c_info.state, JobState::Failed);
    let why = c_info.error.unwrap();
    assert!(
        why.contains(&format!("job {b}")) && why.contains("failed"),
        "{why}"
    );
    assert!(
        why.contains(&format!("job {a}")),
        "the cause is named: {why}"
    );
    // Waiting for a job that has failed fails at once.
    let d = submit_after(&f, "d.png", &[b]).unwrap();
    assert_eq!(d.state, JobState::Failed);
}

#[test]
fn waiting_survives_a_restart_and_a_wait_that_ended_meanwhile_moves_on() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = {
        let f = farm(dir.path());
        let a = submit(&f, "a.png");
        let b = submit_after(&f, "b.png", &[a]).unwrap().id;
        (a, b)
    };
    let f = farm(dir.path());
    assert_eq!(f.info(b).unwrap().waiting_for, vec![a]);
    let w = worker(&f);
    while f.info(a).unwrap().state != JobState::Done {
        let l = f.lease(w).unwrap().unwrap();
        assert_eq!(l.job, a, "b waits");
        put(&f, &l);
    }
    // a done, b queued and rendered.
    render_all(&f, w);
    assert_eq!(f.info(b).unwrap().state, JobState::Done);
}

#[test]
fn bad_requests_are_refused_with_what_is_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    let a = submit(&f, "a.png");
    let jobs = f.list().len();
    // Unknown ids, and the id the job itself is about to get.
    for id in [a + 1, 999] {
        let e = submit_after(&f, "b.png", &[id]).unwrap_err().to_string();
        assert!(e.contains(&format!("no job {id}")), "{e}");
    }
    let many = vec![a; MAX_AFTER + 1];
    let e = submit_after(&f, "b.png", &many).unwrap_err().to_string();
    assert!(e.contains("at most 64"), "{e}");
    // Nothing was queued by the refused submissions.
    assert_eq!(f.list().len(), jobs);
    assert!(submit_after(&f, "b.png", &vec![a; MAX_AFTER]).is_ok());
    // A frame of a sequence is not waited for on its own.
    let seq = f.submit_sequence(spec("s.png"), 1, 2, "").unwrap().id;
    let w = worker(&f);
    let frame = loop {
        let l = f.lease(w).unwrap().unwrap();
        if l.job != a {
            break l.job;
        }
    };
    assert_ne!(frame, seq);
    let e = submit_after(&f, "c.png", &[frame]).unwrap_err().to_string();
    assert!(e.contains("part of a sequence"), "{e}");
    // Resuming what is not paused; controlling what is over or unknown.
    let e = f.resume(a).unwrap_err();
    assert!(matches!(e, FarmError::Conflict(_)), "{e}");
    f.cancel(a).unwrap();
    assert!(matches!(f.pause(a, false), Err(FarmError::JobOver(_))));
    assert!(matches!(f.resume(a), Err(FarmError::JobOver(_))));
    assert!(matches!(
        f.pause(12345, false),
        Err(FarmError::UnknownJob(_))
    ));
}

#[test]
fn a_failed_still_is_retried_with_the_tiles_it_had_finished_across_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let failing = || {
        Farm::new(FarmConfig {
            limits: trevi_coordinator::Limits {
                max_tile_failures: 1,
                ..trevi_coordinator::Limits::default()
            },
            ..FarmConfig::new(dir.path())
        })
        .unwrap()
    };
    let job = {
        let f = failing();
        let job = submit(&f, "a.png");
        let w = worker(&f);
        for _ in 0..3 {
            let l = f.lease(w).unwrap().unwrap();
            put(&f, &l);
        }
        let l = f.lease(w).unwrap().unwrap();
        f.return_tile(w, l.id, Some("boom")).unwrap();
        let info = f.info(job).unwrap();
        assert_eq!(info.state, JobState::Failed);
        assert!(info.error.unwrap().contains("boom"));
        // Only a failed job is retried.
        let e = f.retry(submit(&f, "b.png")).unwrap_err();
        assert!(e.to_string().contains("retry takes a failed job"), "{e}");
        job
    };
    let f = failing();
    let info = f.retry(job).unwrap();
    assert_eq!((info.tiles_done, info.error.as_deref()), (3, None));
    assert!(!info.state.is_final());
    let w = worker(&f);
    let mut rendered = 0;
    while let Some(l) = f.lease(w).unwrap() {
        if l.job == job {
            rendered += 1;
        }
        put(&f, &l);
    }
    assert_eq!(rendered, 3, "the finished tiles are not rendered again");
    assert_eq!(f.info(job).unwrap().state, JobState::Done);
    assert_eq!(
        std::fs::read(f.output_path(job, "a.png")).unwrap(),
        reference(dir.path(), "a.png")
    );
    let e = f.retry(job).unwrap_err().to_string();
    assert!(e.contains("is done"), "{e}");
    assert!(matches!(f.retry(4321), Err(FarmError::UnknownJob(4321))));
}
