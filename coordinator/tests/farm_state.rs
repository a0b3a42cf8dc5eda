//! The coordinator's per-job state without a network: what a frame may cost
//! (refused at submission when one band does not fit the window), how long
//! ended jobs are kept, paged listing, job ids never reused, and the end of a
//! job recorded before anyone is told of it.

mod common;

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use trevi_coordinator::farm::Retention;
use trevi_coordinator::scheduler::{band_bytes, encoder_bytes};
use trevi_coordinator::{
    Farm, FarmConfig, FarmError, JobSpec, JobState, LeaseResult, Limits, SinkError, SubmitOptions,
    TileOutcome, TileSink, WorkerOptions,
};
use trevi_core::Rect;

fn spec(w: u32, h: u32, tile: u32) -> JobSpec {
    common::spec(w, h, tile, "out.png")
}

fn config(dir: &Path, durable: bool, retention: Retention) -> FarmConfig {
    FarmConfig {
        durable,
        retention,
        ..FarmConfig::new(dir)
    }
}

fn pixels(r: Rect) -> Vec<[f32; 3]> {
    vec![[0.25, 0.5, 0.75]; r.pixel_count()]
}

#[test]
fn a_frame_whose_one_band_does_not_fit_the_window_is_refused_at_submission() {
    let dir = tempfile::tempdir().unwrap();
    let f = Farm::new(config(dir.path(), false, Retention::default())).unwrap();
    // The frame: one band of 64-pixel tiles is 77 GB.
    let e = f
        .submit(spec(100_000_000, 64, 64), SubmitOptions::default())
        .unwrap_err();
    assert!(matches!(e, FarmError::Limit(_)), "{e:?}");
    let msg = e.to_string();
    assert!(
        msg.contains("100000000x64") && msg.contains("--window-mib") && msg.contains("32 MiB"),
        "{msg}"
    );
    // Nothing was queued for it, and no output was started.
    assert!(f.list().is_empty());
    assert!(!dir.path().join("jobs").join("1").exists());
    // Smaller tiles make the band fit; so does a bigger window.
    f.submit(spec(16384, 64, 16), SubmitOptions::default())
        .unwrap();
    let big = FarmConfig {
        limits: Limits {
            window_bytes: 64 << 20,
            ..Limits::default()
        },
        ..config(&dir.path().join("big"), false, Retention::default())
    };
    let g = Farm::new(big).unwrap();
    g.submit(spec(32768, 100, 64), SubmitOptions::default())
        .unwrap();
    assert!(f
        .submit(spec(32768, 100, 64), SubmitOptions::default())
        .is_err());
    // More tiles than a job can number.
    let e = g
        .submit(spec(100_000, 100_000, 1), SubmitOptions::default())
        .unwrap_err();
    assert!(e.to_string().contains("more than a job may have"), "{e}");
}

#[test]
fn the_window_bounds_the_rows_of_a_wide_frame_to_one_band() {
    // A frame so wide that two bands do not fit: one band at a time, and
    // the rows held never exceed it.
    let dir = tempfile::tempdir().unwrap();
    let (w, h, tile) = (4096u32, 64u32, 16u32);
    let s = spec(w, h, tile);
    // Room for one band and a half.
    let window = band_bytes(&s) * 3 / 2 + encoder_bytes(&s);
    let f = Farm::new(FarmConfig {
        limits: Limits {
            window_bytes: window,
            ..Limits::default()
        },
        ..config(dir.path(), false, Retention::default())
    })
    .unwrap();
    let job = f.submit(s, SubmitOptions::default()).unwrap().id;
    let worker = f.register_worker(WorkerOptions::default()).unwrap().id;
    loop {
        let leases: Vec<_> = std::iter::from_fn(|| f.lease(worker).unwrap()).collect();
        if leases.is_empty() {
            break;
        }
        assert!(
            leases.iter().all(|l| l.rect.y == leases[0].rect.y),
            "more than one band in flight"
        );
        for l in leases.iter().rev() {
            f.put_tile(LeaseResult {
                lease: l.id,
                job,
                rect: l.rect,
                rays: 1,
                pixels: &pixels(l.rect),
                worker: None,
            })
            .unwrap();
            if let Some(rows) = f.max_rows_held(job) {
                assert!(rows as u32 <= tile, "{rows} rows held");
            }
        }
    }
    assert_eq!(f.info(job).unwrap().state, JobState::Done);
}

#[test]
fn five_thousand_cancelled_jobs_keep_only_the_newest_and_list_in_pages() {
    let dir = tempfile::tempdir().unwrap();
    let retention = Retention {
        keep_ended: 300,
        keep_ended_for: None,
        ..Retention::default()
    };
    let f = Farm::new(config(dir.path(), false, retention)).unwrap();
    for _ in 0..5_000 {
        let id = f
            .submit(spec(16, 16, 16), SubmitOptions::default())
            .unwrap()
            .id;
        f.cancel(id).unwrap();
    }
    let active = f
        .submit(spec(16, 16, 16), SubmitOptions::default())
        .unwrap()
        .id;
    let jobs = f.list();
    assert_eq!(jobs.len(), 301);
    // The newest ended ones, and the unfinished one.
    assert_eq!(jobs[0].id, 5_000 - 299);
    assert_eq!(jobs.last().unwrap().id, active);
    // Job directories of forgotten jobs are gone.
    let dirs = std::fs::read_dir(dir.path().join("jobs"))
        .map(|d| d.count())
        .unwrap_or(0);
    assert!(dirs <= 301, "{dirs} job directories");
    // Pages of 128 cover every job once, in order.
    let (mut seen, mut from) = (Vec::new(), 0);
    loop {
        let (page, next) = f.list_from(from, 128);
        assert!(page.len() <= 128);
        seen.extend(page.iter().map(|j| j.id));
        match next {
            Some(n) => from = n,
            None => break,
        }
    }
    assert_eq!(seen, jobs.iter().map(|j| j.id).collect::<Vec<_>>());
}

#[test]
fn ended_jobs_are_forgotten_after_their_time_in_the_store_too() {
    // Long enough that `new` cannot age out between its end and the check
    // below, even on a busy machine; `old` is waited for, not slept for.
    let keep = Duration::from_secs(3);
    let dir = tempfile::tempdir().unwrap();
    let retention = Retention {
        keep_ended: 1000,
        keep_ended_for: Some(keep),
        ..Retention::default()
    };
    let f = Farm::new(config(dir.path(), true, retention)).unwrap();
    let old = f
        .submit(spec(16, 16, 16), SubmitOptions::default())
        .unwrap()
        .id;
    f.cancel(old).unwrap();
    // `old` ended before this instant: once `keep` after it has passed, it
    // is past its time.
    let old_ended = Instant::now();
    while Instant::now() <= old_ended + keep + Duration::from_millis(10) {
        std::thread::sleep(Duration::from_millis(50));
    }
    let new = f
        .submit(spec(16, 16, 16), SubmitOptions::default())
        .unwrap()
        .id;
    f.cancel(new).unwrap();
    f.expire();
    let ids: Vec<u64> = f.list().iter().map(|j| j.id).collect();
    assert_eq!(ids, [new]);
    assert!(matches!(f.info(old), Err(FarmError::UnknownJob(_))));
    drop(f);
    // Gone from the database as well; its id is not given again.
    let f = Farm::new(config(dir.path(), true, retention)).unwrap();
    assert!(matches!(f.info(old), Err(FarmError::UnknownJob(_))));
    assert_eq!(f.info(new).unwrap().state, JobState::Cancelled);
    let next = f
        .submit(spec(16, 16, 16), SubmitOptions::default())
        .unwrap()
        .id;
    assert!(next > new, "id {next} given again");
}

#[test]
fn new_jobs_never_take_an_existing_job_directory() {
    let dir = tempfile::tempdir().unwrap();
    let keep_none = Retention {
        keep_ended: 0,
        keep_ended_for: None,
        ..Retention::default()
    };
    {
        let f = Farm::new(config(dir.path(), true, Retention::default())).unwrap();
        for _ in 0..3 {
            f.submit(spec(16, 16, 16), SubmitOptions::default())
                .unwrap();
        }
    }
    // The database is lost; the job directories 1..=3 are still there (a
    // job's directory is made when its output is first written: made here,
    // as rendering would have).
    for f in ["state.db", "state.db-wal", "state.db-shm"] {
        let _ = std::fs::remove_file(dir.path().join(f));
    }
    for d in 1..=3 {
        std::fs::create_dir_all(dir.path().join(format!("jobs/{d}"))).unwrap();
    }
    let f = Farm::new(config(dir.path(), true, keep_none)).unwrap();
    let id = f
        .submit(spec(16, 16, 16), SubmitOptions::default())
        .unwrap()
        .id;
    assert_eq!(id, 4);
    // Every ended job pruned, directories and rows: the ids stay used.
    f.cancel(id).unwrap();
    assert!(f.list().is_empty());
    assert!(!dir.path().join("jobs/4").exists());
    drop(f);
    for d in 1..=3 {
        std::fs::remove_dir_all(dir.path().join(format!("jobs/{d}"))).unwrap();
    }
    let f = Farm::new(config(dir.path(), true, keep_none)).unwrap();
    assert_eq!(
        f.submit(spec(16, 16, 16), SubmitOptions::default())
            .unwrap()
            .id,
        5
    );
}

/// A sink whose disk fills up at the end: `finish` fails, and from then on
/// the database cannot be written either (another connection holds its
/// write lock until the test lets go).
struct DiskFullAtTheEnd {
    db: PathBuf,
    lock: Arc<Mutex<Option<rusqlite::Connection>>>,
}

impl TileSink for DiskFullAtTheEnd {
    fn write_tile(&mut self, _: Rect, _: &[[f32; 3]]) -> Result<(), SinkError> {
        Ok(())
    }
    fn finish(self: Box<Self>) -> Result<(), SinkError> {
        let c = rusqlite::Connection::open(&self.db).unwrap();
        c.execute_batch("BEGIN EXCLUSIVE").unwrap();
        *self.lock.lock().unwrap() = Some(c);
        // ENOSPC: "No space left on device (os error 28)".
        Err(std::io::Error::from_raw_os_error(28).into())
    }
    fn rows_held(&self) -> usize {
        0
    }
}

/// Runs a 2-tile job whose end cannot be recorded; returns the farm, the
/// job and the database lock.
fn job_ending_on_a_full_disk(dir: &Path) -> (Farm, u64, Arc<Mutex<Option<rusqlite::Connection>>>) {
    let f = Farm::new(config(dir, true, Retention::default())).unwrap();
    let lock = Arc::new(Mutex::new(None));
    let db = dir.join("state.db");
    let l2 = lock.clone();
    let job = f
        .submit(
            spec(32, 16, 16),
            SubmitOptions {
                sink: Some(Box::new(move |_| {
                    Ok(Box::new(DiskFullAtTheEnd { db, lock: l2 }))
                })),
                ..SubmitOptions::default()
            },
        )
        .unwrap()
        .id;
    let w = f.register_worker(WorkerOptions::default()).unwrap().id;
    let a = f.lease(w).unwrap().unwrap();
    let b = f.lease(w).unwrap().unwrap();
    for l in [a, b] {
        let out = f
            .put_tile(LeaseResult {
                lease: l.id,
                job,
                rect: l.rect,
                rays: 1,
                pixels: &pixels(l.rect),
                worker: None,
            })
            .unwrap();
        assert_eq!(out, TileOutcome::Accepted);
    }
    (f, job, lock)
}

#[test]
fn a_job_end_the_database_does_not_take_is_not_told_and_a_restart_agrees() {
    let dir = tempfile::tempdir().unwrap();
    let (f, job, lock) = job_ending_on_a_full_disk(dir.path());
    // The output failed, but that is not recorded: nobody is told "failed".
    let info = f.info(job).unwrap();
    assert!(!info.state.is_final(), "told {:?} unrecorded", info.state);
    assert!(!f.watch(job).unwrap().borrow().state.is_final());
    assert!(f
        .lease(f.register_worker(WorkerOptions::default()).unwrap().id)
        .unwrap()
        .is_none());
    // Space again: the next tick records the end, and then it is shown.
    *lock.lock().unwrap() = None;
    let t = Instant::now();
    f.expire();
    assert!(t.elapsed() < Duration::from_secs(4));
    let info = f.info(job).unwrap();
    assert_eq!(info.state, JobState::Failed);
    assert!(info.error.unwrap().contains("No space left"));
    assert_eq!(f.watch(job).unwrap().borrow().state, JobState::Failed);
    drop(f);
    // A restart finds what the client was told.
    let f = Farm::new(config(dir.path(), true, Retention::default())).unwrap();
    let info = f.info(job).unwrap();
    assert_eq!(info.state, JobState::Failed, "{info:?}");
    assert!(info.error.unwrap().contains("No space left"));
}

#[test]
fn a_restart_before_the_end_is_recorded_resumes_the_job_the_client_saw_running() {
    let dir = tempfile::tempdir().unwrap();
    let (f, job, lock) = job_ending_on_a_full_disk(dir.path());
    assert!(!f.info(job).unwrap().state.is_final());
    drop(f); // Killed before the disk had room again.
    *lock.lock().unwrap() = None;
    let f = Farm::new(config(dir.path(), true, Retention::default())).unwrap();
    // Its tiles were stored: the restart finishes it into a real file.
    let info = f.info(job).unwrap();
    assert_eq!(info.state, JobState::Done, "{info:?}");
    assert!(f.output_file(job).unwrap().is_file());
}

#[test]
fn a_cancellation_the_database_does_not_take_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let f = Farm::new(config(dir.path(), true, Retention::default())).unwrap();
    let job = f
        .submit(spec(16, 16, 16), SubmitOptions::default())
        .unwrap()
        .id;
    let c = rusqlite::Connection::open(dir.path().join("state.db")).unwrap();
    c.execute_batch("BEGIN EXCLUSIVE").unwrap();
    let e = f.cancel(job).unwrap_err();
    assert!(
        e.to_string().contains("cannot record the cancellation"),
        "{e}"
    );
    assert_eq!(f.info(job).unwrap().state, JobState::Queued);
    drop(c);
    assert_eq!(f.cancel(job).unwrap().state, JobState::Cancelled);
    drop(f);
    let f = Farm::new(config(dir.path(), true, Retention::default())).unwrap();
    assert_eq!(f.info(job).unwrap().state, JobState::Cancelled);
}
