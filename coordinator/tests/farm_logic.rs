//! The coordinator's rules without a network: scheduling, validation and
//! stitching through the real `FrameWriter`, with synthetic pixels.

mod common;

use std::path::Path;
use std::time::{Duration, Instant};
use trevi_coordinator::scheduler::Lease;
use trevi_coordinator::{
    Farm, FarmConfig, FarmError, JobSpec, JobState, LeaseResult, Limits, SubmitOptions,
    TileOutcome, WorkerOptions,
};
use trevi_core::output::decode_png;
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

fn farm(dir: &Path, ttl: Duration, window_bytes: u64) -> Farm {
    Farm::new(FarmConfig {
        data_dir: dir.to_path_buf(),
        limits: Limits {
            lease_ttl: ttl,
            window_bytes,
            ..Limits::default()
        },
        default_tile: 16,
        ..FarmConfig::new(dir)
    })
    .unwrap()
}

fn spec(w: u32, h: u32, tile: u32, name: &str, priority: i32) -> JobSpec {
    JobSpec {
        priority,
        ..common::spec(w, h, tile, name)
    }
}

/// The same frame written in band order straight through a FrameWriter.
fn reference(dir: &Path, w: u32, h: u32, name: &str) -> Vec<u8> {
    let path = dir.join("reference").join(name);
    let mut fw = FrameWriter::create(&path, w, h).unwrap();
    for r in trevi_core::tile::band_order_tiles(w, h, 8) {
        fw.write_tile(r, &pixels(r)).unwrap();
    }
    fw.finish().unwrap();
    std::fs::read(path).unwrap()
}

fn lease_all(farm: &Farm, worker: u64) -> Vec<Lease> {
    std::iter::from_fn(|| farm.lease(worker).unwrap()).collect()
}

#[test]
fn tiles_in_any_order_stitch_to_the_same_file_moved_into_place_at_the_end() {
    for name in ["out.png", "out.exr"] {
        let dir = tempfile::tempdir().unwrap();
        let f = farm(dir.path(), Duration::from_secs(60), 1 << 30);
        let job = f
            .submit(spec(50, 37, 16, name, 0), SubmitOptions::default())
            .unwrap()
            .id;
        let out = f.output_path(job, name);
        let w = f.register_worker(WorkerOptions::default()).unwrap().id;
        let mut leases = lease_all(&f, w);
        assert_eq!(leases.len(), 4 * 3);
        leases.reverse(); // Results arrive in the worst order.
        for (i, l) in leases.iter().enumerate() {
            assert!(!out.exists(), "the output appears only when complete");
            assert_eq!(f.info(job).unwrap().tiles_done, i as u64);
            assert_eq!(
                f.put_tile(LeaseResult {
                    lease: l.id,
                    job,
                    rect: l.rect,
                    rays: 10,
                    pixels: &pixels(l.rect),
                    worker: None
                })
                .unwrap(),
                TileOutcome::Accepted
            );
        }
        let info = f.info(job).unwrap();
        assert_eq!(
            (info.state, info.rays, info.finish_order),
            (JobState::Done, 120, 1)
        );
        assert_eq!(f.output_file(job).unwrap(), out);
        assert_eq!(
            std::fs::read(&out).unwrap(),
            reference(dir.path(), 50, 37, name)
        );
        // No temporary files are left beside it.
        assert_eq!(std::fs::read_dir(out.parent().unwrap()).unwrap().count(), 1);
    }
}

#[test]
fn wrong_size_and_nan_results_are_rejected_and_the_tile_requeued() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path(), Duration::from_secs(60), 1 << 30);
    let job = f
        .submit(spec(32, 16, 16, "o.png", 0), SubmitOptions::default())
        .unwrap()
        .id;
    let (bad, good) = (
        f.register_worker(WorkerOptions::default()).unwrap().id,
        f.register_worker(WorkerOptions::default()).unwrap().id,
    );
    let l = f.lease(bad).unwrap().unwrap();
    let mut short = pixels(l.rect);
    short.pop();
    let e = f
        .put_tile(LeaseResult {
            lease: l.id,
            job,
            rect: l.rect,
            rays: 1,
            pixels: &short,
            worker: None,
        })
        .unwrap_err();
    assert!(matches!(e, FarmError::BadTile(_)), "{e}");
    // Re-queued at once, ahead of the rest of the frame.
    let l2 = f.lease(bad).unwrap().unwrap();
    assert_eq!(l2.rect, l.rect);
    let mut nan = pixels(l.rect);
    nan[5][1] = f32::NAN;
    assert!(matches!(
        f.put_tile(LeaseResult {
            lease: l2.id,
            job,
            rect: l2.rect,
            rays: 1,
            pixels: &nan,
            worker: None
        }),
        Err(FarmError::BadTile(_))
    ));
    let mut inf = pixels(l.rect);
    inf[0][0] = f32::INFINITY;
    assert!(f
        .put_tile(LeaseResult {
            lease: l2.id,
            job,
            rect: l2.rect,
            rays: 1,
            pixels: &inf,
            worker: None
        })
        .is_err());
    // A rectangle that is not a tile of the job.
    let odd = Rect::new(1, 0, 16, 16);
    assert!(f
        .put_tile(LeaseResult {
            lease: l2.id,
            job,
            rect: odd,
            rays: 1,
            pixels: &pixels(odd),
            worker: None
        })
        .is_err());
    assert_eq!(f.info(job).unwrap().tiles_done, 0);
    for l in lease_all(&f, good) {
        f.put_tile(LeaseResult {
            lease: l.id,
            job,
            rect: l.rect,
            rays: 1,
            pixels: &pixels(l.rect),
            worker: None,
        })
        .unwrap();
    }
    assert_eq!(f.info(job).unwrap().state, JobState::Done);
    assert_eq!(
        std::fs::read(f.output_file(job).unwrap()).unwrap(),
        reference(dir.path(), 32, 16, "o.png")
    );
}

#[test]
fn missed_deadline_requeues_and_the_late_result_is_then_ignored() {
    let dir = tempfile::tempdir().unwrap();
    // Long enough that the second worker asks well within it, even on a
    // busy machine; then the test waits for the expiry, not for a time.
    let f = farm(dir.path(), Duration::from_secs(2), 1 << 30);
    let job = f
        .submit(spec(16, 16, 16, "o.png", 0), SubmitOptions::default())
        .unwrap()
        .id;
    let (slow, fast) = (
        f.register_worker(WorkerOptions::default()).unwrap().id,
        f.register_worker(WorkerOptions::default()).unwrap().id,
    );
    let l = f.lease(slow).unwrap().unwrap();
    assert_eq!(f.lease(fast).unwrap(), None);
    let give_up = Instant::now() + Duration::from_secs(60);
    loop {
        match f.expire() {
            0 => assert!(Instant::now() < give_up, "the lease never expired"),
            n => break assert_eq!(n, 1),
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let l2 = f.lease(fast).unwrap().unwrap();
    assert_eq!(l2.rect, l.rect);
    assert_eq!(f.heartbeat(slow, &[l.id]).unwrap(), vec![l.id]);
    f.put_tile(LeaseResult {
        lease: l2.id,
        job,
        rect: l2.rect,
        rays: 1,
        pixels: &pixels(l2.rect),
        worker: None,
    })
    .unwrap();
    assert_eq!(
        f.put_tile(LeaseResult {
            lease: l.id,
            job,
            rect: l.rect,
            rays: 1,
            pixels: &pixels(l.rect),
            worker: None
        })
        .unwrap(),
        TileOutcome::Ignored
    );
    assert_eq!(f.info(job).unwrap().state, JobState::Done);
}

#[test]
fn heartbeats_keep_a_lease_alive_past_its_first_deadline() {
    // Every step is judged by the times measured around it: a heartbeat
    // sent less than `ttl` after the one before (or the lease) must find
    // the lease alive. A machine so busy that a step took longer proves
    // nothing either way: the lease is taken again and the test goes on.
    let ttl = Duration::from_millis(500);
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path(), ttl, 1 << 30);
    f.submit(spec(16, 16, 16, "o.png", 0), SubmitOptions::default())
        .unwrap();
    let w = f.register_worker(WorkerOptions::default()).unwrap().id;
    let give_up = Instant::now() + Duration::from_secs(120);
    'lease: loop {
        assert!(
            Instant::now() < give_up,
            "no run of heartbeats within {ttl:?} of each other in 2 minutes"
        );
        // The deadline is set inside these calls: at least `ttl` after
        // `renewed`, at most `ttl` after `leased`.
        let mut renewed = Instant::now();
        let Some(l) = f.lease(w).unwrap() else {
            // Our earlier lease, given up after a stall, has yet to expire.
            f.expire();
            std::thread::sleep(ttl / 10);
            continue;
        };
        let first_deadline = Instant::now() + ttl;
        loop {
            std::thread::sleep(ttl / 5);
            let before = Instant::now();
            let lost = f.heartbeat(w, &[l.id]).unwrap();
            let expired = f.expire();
            if Instant::now() - renewed >= ttl {
                continue 'lease;
            }
            assert!(lost.is_empty(), "a lease renewed within its time was lost");
            assert_eq!(expired, 0);
            if before > first_deadline {
                return;
            }
            renewed = before;
        }
    }
}

#[test]
fn jobs_finish_in_priority_order() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path(), Duration::from_secs(60), 1 << 30);
    let low = f
        .submit(spec(32, 32, 16, "low.png", 0), SubmitOptions::default())
        .unwrap()
        .id;
    let high = f
        .submit(spec(32, 32, 16, "high.png", 9), SubmitOptions::default())
        .unwrap()
        .id;
    let w = f.register_worker(WorkerOptions::default()).unwrap().id;
    while let Some(l) = f.lease(w).unwrap() {
        f.put_tile(LeaseResult {
            lease: l.id,
            job: l.job,
            rect: l.rect,
            rays: 1,
            pixels: &pixels(l.rect),
            worker: None,
        })
        .unwrap();
    }
    assert_eq!(f.info(high).unwrap().finish_order, 1);
    assert_eq!(f.info(low).unwrap().finish_order, 2);
}

#[test]
fn a_cancelled_job_takes_no_more_work_and_leaves_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path(), Duration::from_secs(60), 1 << 30);
    let job = f
        .submit(spec(64, 64, 16, "c.png", 0), SubmitOptions::default())
        .unwrap()
        .id;
    let w = f.register_worker(WorkerOptions::default()).unwrap().id;
    let leases = lease_all(&f, w);
    for l in &leases[..6] {
        f.put_tile(LeaseResult {
            lease: l.id,
            job,
            rect: l.rect,
            rays: 1,
            pixels: &pixels(l.rect),
            worker: None,
        })
        .unwrap();
    }
    assert_eq!(f.cancel(job).unwrap().state, JobState::Cancelled);
    assert_eq!(f.lease(w).unwrap(), None);
    assert_eq!(f.heartbeat(w, &[leases[7].id]).unwrap(), vec![leases[7].id]);
    let l = &leases[7];
    assert_eq!(
        f.put_tile(LeaseResult {
            lease: l.id,
            job,
            rect: l.rect,
            rays: 1,
            pixels: &pixels(l.rect),
            worker: None
        })
        .unwrap(),
        TileOutcome::Ignored
    );
    assert!(matches!(f.output_file(job), Err(FarmError::NoOutput(..))));
    let jobs = dir.path().join("jobs");
    let leftovers: Vec<_> = walk(&jobs);
    assert!(leftovers.is_empty(), "left behind: {leftovers:?}");
}

fn walk(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    if let Ok(rd) = std::fs::read_dir(dir) {
        for e in rd.flatten() {
            let p = e.path();
            if p.is_dir() {
                out.extend(walk(&p));
            } else {
                out.push(p);
            }
        }
    }
    out
}

#[test]
fn rows_held_do_not_grow_with_the_image_height() {
    // Four workers; each keeps four tiles in flight and returns them out of
    // order. The writer's buffered rows stay within the band window whatever
    // the height.
    let mut peaks = Vec::new();
    for height in [256u32, 4096] {
        let dir = tempfile::tempdir().unwrap();
        let width = 256;
        let tile = 16;
        // Room for four bands.
        let f = farm(
            dir.path(),
            Duration::from_secs(60),
            4 * (width * tile * 12) as u64,
        );
        let job = f
            .submit(
                spec(width, height, tile, "tall.png", 0),
                SubmitOptions::default(),
            )
            .unwrap()
            .id;
        let workers: Vec<u64> = (0..4)
            .map(|_| f.register_worker(WorkerOptions::default()).unwrap().id)
            .collect();
        let mut in_flight: Vec<Lease> = Vec::new();
        let mut peak = 0;
        loop {
            for &w in &workers {
                while in_flight.len() < 16 {
                    match f.lease(w).unwrap() {
                        Some(l) => in_flight.push(l),
                        None => break,
                    }
                }
            }
            if in_flight.is_empty() {
                break;
            }
            // Return the newest first: the worst case for the writer.
            let l = in_flight.pop().unwrap();
            f.put_tile(LeaseResult {
                lease: l.id,
                job,
                rect: l.rect,
                rays: 1,
                pixels: &pixels(l.rect),
                worker: None,
            })
            .unwrap();
            peak = peak.max(f.max_rows_held(job).unwrap_or(peak));
        }
        assert_eq!(f.info(job).unwrap().state, JobState::Done);
        peaks.push(peak);
    }
    assert!(peaks[1] <= 4 * 16, "rows held: {peaks:?}");
    assert_eq!(
        peaks[0], peaks[1],
        "rows held depend on the height: {peaks:?}"
    );
}

#[test]
fn a_restarted_farm_resumes_from_its_database_with_the_same_bytes() {
    for name in ["r.png", "r.exr"] {
        let dir = tempfile::tempdir().unwrap();
        let job;
        let first_half;
        {
            let f = farm(dir.path(), Duration::from_secs(60), 1 << 30);
            job = f
                .submit(spec(50, 37, 16, name, 0), SubmitOptions::default())
                .unwrap()
                .id;
            let w = f.register_worker(WorkerOptions::default()).unwrap().id;
            let leases = lease_all(&f, w);
            first_half = leases.len() / 2;
            // Out of order, so rows are pending in the writer at the "crash".
            for l in leases[..first_half].iter().rev() {
                f.put_tile(LeaseResult {
                    lease: l.id,
                    job,
                    rect: l.rect,
                    rays: 10,
                    pixels: &pixels(l.rect),
                    worker: None,
                })
                .unwrap();
            }
            // Dropped with leases out and the output half written.
        }
        let f = farm(dir.path(), Duration::from_secs(60), 1 << 30);
        let info = f.info(job).unwrap();
        assert_eq!(info.tiles_done, first_half as u64);
        assert_eq!(info.rays, 10 * first_half as u64);
        // The preview is rebuilt from the stored tiles too.
        assert_eq!(f.preview(job).unwrap().tiles, first_half as u64);
        let w = f.register_worker(WorkerOptions::default()).unwrap().id;
        let rest = lease_all(&f, w);
        assert_eq!(
            rest.len(),
            12 - first_half,
            "stored tiles are not leased again"
        );
        for l in &rest {
            f.put_tile(LeaseResult {
                lease: l.id,
                job,
                rect: l.rect,
                rays: 10,
                pixels: &pixels(l.rect),
                worker: None,
            })
            .unwrap();
        }
        assert_eq!(f.info(job).unwrap().state, JobState::Done);
        assert_eq!(
            std::fs::read(f.output_file(job).unwrap()).unwrap(),
            reference(dir.path(), 50, 37, name)
        );
        drop(f);
        // Finished jobs stay listed, and new ids follow the old ones.
        let f = farm(dir.path(), Duration::from_secs(60), 1 << 30);
        assert_eq!(f.info(job).unwrap().state, JobState::Done);
        assert!(f.output_file(job).unwrap().exists());
        assert_eq!(
            f.submit(spec(16, 16, 16, "n.png", 0), SubmitOptions::default())
                .unwrap()
                .id,
            job + 1
        );
    }
}

#[test]
fn a_tile_failing_too_often_fails_its_job_and_a_failing_worker_is_benched() {
    let dir = tempfile::tempdir().unwrap();
    let f = Farm::new(FarmConfig {
        limits: Limits {
            lease_ttl: Duration::from_secs(60),
            window_bytes: 1 << 30,
            max_tile_failures: 3,
            max_worker_failures: 2,
            max_tile_losses: 3,
            ..Limits::default()
        },
        ..FarmConfig::new(dir.path())
    })
    .unwrap();
    let job = f
        .submit(spec(32, 16, 16, "o.png", 0), SubmitOptions::default())
        .unwrap()
        .id;
    let bad: Vec<u64> = (0..3)
        .map(|_| f.register_worker(WorkerOptions::default()).unwrap().id)
        .collect();
    let mut nan = pixels(Rect::new(0, 0, 16, 16));
    nan[0][0] = f32::NAN;
    // bad[0] fails the first tile twice and is then kept off the job.
    for _ in 0..2 {
        let l = f.lease(bad[0]).unwrap().unwrap();
        assert_eq!(l.rect, Rect::new(0, 0, 16, 16));
        assert!(f
            .put_tile(LeaseResult {
                lease: l.id,
                job,
                rect: l.rect,
                rays: 1,
                pixels: &nan,
                worker: None
            })
            .is_err());
    }
    assert_eq!(f.lease(bad[0]).unwrap(), None, "benched");
    let l = f.lease(bad[1]).unwrap().unwrap();
    assert!(f
        .put_tile(LeaseResult {
            lease: l.id,
            job,
            rect: l.rect,
            rays: 1,
            pixels: &nan,
            worker: None
        })
        .is_err());
    let info = f.info(job).unwrap();
    assert_eq!(info.state, JobState::Failed);
    let e = info.error.unwrap();
    assert!(
        e.contains("tile 0") && e.contains("3 times") && e.contains("not finite"),
        "{e}"
    );
    assert!(!f.output_path(job, "o.png").exists());
    assert_eq!(f.lease(bad[2]).unwrap(), None);
}

#[test]
fn a_result_under_someone_elses_lease_is_refused_and_changes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path(), Duration::from_secs(60), 1 << 30);
    let job = f
        .submit(spec(32, 16, 16, "o.png", 0), SubmitOptions::default())
        .unwrap()
        .id;
    let (a, b) = (
        f.register_worker(WorkerOptions::default()).unwrap().id,
        f.register_worker(WorkerOptions::default()).unwrap().id,
    );
    let la = f.lease(a).unwrap().unwrap();
    let lb = f.lease(b).unwrap().unwrap();
    // b sends a tile under a's lease, then under a lease that never was.
    let e = f
        .put_tile(LeaseResult {
            lease: la.id,
            job,
            rect: la.rect,
            rays: 1,
            pixels: &pixels(la.rect),
            worker: Some(b),
        })
        .unwrap_err();
    assert!(matches!(e, FarmError::NotYourLease(_)), "{e}");
    let e = f
        .put_tile(LeaseResult {
            lease: 987_654,
            job,
            rect: lb.rect,
            rays: 1,
            pixels: &pixels(lb.rect),
            worker: Some(b),
        })
        .unwrap_err();
    assert!(matches!(e, FarmError::NotYourLease(_)), "{e}");
    // A span under the last lease id there is: its second tile's id would
    // be past u64::MAX. Refused, not an overflow.
    let whole = Rect::new(0, 0, 32, 16);
    let e = f
        .put_span(
            LeaseResult {
                lease: u64::MAX,
                job,
                rect: whole,
                rays: 1,
                pixels: &pixels(whole),
                worker: Some(b),
            },
            &[la.rect, lb.rect],
        )
        .unwrap_err();
    assert!(matches!(e, FarmError::NotYourLease(_)), "{e}");
    // a bad result under a's lease from b does not re-queue a's tile.
    assert!(f
        .put_tile(LeaseResult {
            lease: la.id,
            job,
            rect: la.rect,
            rays: 1,
            pixels: &[],
            worker: Some(b)
        })
        .is_err());
    assert!(f.heartbeat(a, &[la.id]).unwrap().is_empty());
    assert_eq!(f.info(job).unwrap().tiles_done, 0);
    f.put_tile(LeaseResult {
        lease: la.id,
        job,
        rect: la.rect,
        rays: 1,
        pixels: &pixels(la.rect),
        worker: Some(a),
    })
    .unwrap();
    f.put_tile(LeaseResult {
        lease: lb.id,
        job,
        rect: lb.rect,
        rays: 1,
        pixels: &pixels(lb.rect),
        worker: Some(b),
    })
    .unwrap();
    assert_eq!(f.info(job).unwrap().state, JobState::Done);
}

#[test]
fn the_preview_fills_in_tile_by_tile_and_outlives_the_job() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path(), Duration::from_secs(60), 1 << 30);
    // 1100×40: the preview is shrunk by 3 to 367×14.
    let job = f
        .submit(spec(1100, 40, 64, "wide.png", 0), SubmitOptions::default())
        .unwrap()
        .id;
    let opaque = |png: &[u8]| {
        decode_png(png)
            .unwrap()
            .2
            .chunks(4)
            .filter(|p| p[3] == 255)
            .count()
    };
    let p = f.preview(job).unwrap();
    assert_eq!((p.width, p.height, p.tiles), (367, 14, 0));
    assert_eq!(opaque(&p.png), 0, "a queued job's preview is empty");
    let w = f.register_worker(WorkerOptions::default()).unwrap().id;
    let leases = lease_all(&f, w);
    assert_eq!(leases.len(), 18);
    let mut seen = 0;
    for (i, l) in leases.iter().enumerate() {
        f.put_tile(LeaseResult {
            lease: l.id,
            job,
            rect: l.rect,
            rays: 1,
            pixels: &pixels(l.rect),
            worker: None,
        })
        .unwrap();
        let p = f.preview(job).unwrap();
        assert_eq!(p.tiles, i as u64 + 1);
        let now = opaque(&p.png);
        assert!(now > seen, "tile {i} must show in the preview");
        seen = now;
    }
    assert_eq!(f.info(job).unwrap().state, JobState::Done);
    // Done: the last preview is still there, complete, and matches the
    // frame's pixels averaged over 3×3 blocks.
    let (pw, ph, rgba) = decode_png(&f.preview(job).unwrap().png).unwrap();
    assert_eq!(opaque(&f.preview(job).unwrap().png), (pw * ph) as usize);
    let (px, py) = (100u32, 5u32);
    let mut mean = [0f32; 3];
    for y in py * 3..py * 3 + 3 {
        for x in px * 3..px * 3 + 3 {
            for (m, v) in mean.iter_mut().zip(pixel(x, y)) {
                *m += v / 9.0;
            }
        }
    }
    let i = ((py * pw + px) * 4) as usize;
    for c in 0..3 {
        let want = trevi_core::output::linear_to_srgb8(mean[c]);
        assert!(rgba[i + c].abs_diff(want) <= 1, "{} vs {want}", rgba[i + c]);
    }
}

#[test]
fn metrics_count_the_job_s_tiles_and_priority_changes_reorder_jobs() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path(), Duration::from_secs(60), 1 << 30);
    let a = f
        .submit(spec(32, 32, 16, "a.png", 0), SubmitOptions::default())
        .unwrap()
        .id;
    let b = f
        .submit(spec(32, 16, 16, "b.png", 0), SubmitOptions::default())
        .unwrap()
        .id;
    assert_eq!(f.set_priority(b, 3).unwrap().spec.priority, 3);
    let w = f
        .register_worker(WorkerOptions {
            name: "w1",
            threads: 4,
            ..WorkerOptions::default()
        })
        .unwrap()
        .id;
    // b now goes first: its two tiles, then a's four.
    let leases = lease_all(&f, w);
    let jobs: Vec<u64> = leases.iter().map(|l| l.job).collect();
    assert_eq!(jobs, [b, b, a, a, a, a]);
    for l in &leases {
        f.put_tile(LeaseResult {
            lease: l.id,
            job: l.job,
            rect: l.rect,
            rays: 100,
            pixels: &pixels(l.rect),
            worker: None,
        })
        .unwrap();
    }
    let text = trevi_coordinator::metrics::render(&f.snapshot(), f.metrics());
    let value = |name: &str| -> f64 {
        text.lines()
            .find_map(|l| l.strip_prefix(name)?.strip_prefix(' ')?.parse().ok())
            .unwrap_or_else(|| panic!("no {name} in\n{text}"))
    };
    assert_eq!(value("trevi_tiles_rendered_total"), 6.0);
    assert_eq!(value("trevi_rays_total"), 600.0);
    assert_eq!(value("trevi_leases_granted_total"), 6.0);
    assert_eq!(value("trevi_jobs{state=\"done\"}"), 2.0);
    assert_eq!(value("trevi_workers{state=\"idle\"}"), 1.0);
    assert_eq!(value("trevi_queue_depth_jobs"), 0.0);
    // Both locks were held for that work (printed to the microsecond).
    for lock in ["state", "store"] {
        let held = value(&format!("trevi_{lock}_lock_held_seconds_total"));
        assert!(held > 0.0 && held < 60.0, "{lock}: {held}");
    }
    assert!(matches!(f.set_priority(a, 1), Err(FarmError::JobOver(_))));
}

#[test]
fn huge_ray_counts_saturate_and_negative_or_infinite_pixels_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path(), Duration::from_secs(60), 1 << 30);
    let job = f
        .submit(spec(32, 16, 16, "o.png", 0), SubmitOptions::default())
        .unwrap()
        .id;
    let w = f.register_worker(WorkerOptions::default()).unwrap().id;
    let l = f.lease(w).unwrap().unwrap();
    for (bad, what) in [(-1e30f32, "negative"), (f32::INFINITY, "not finite")] {
        let mut px = pixels(l.rect);
        px[5][1] = bad;
        let e = f
            .put_tile(LeaseResult {
                lease: l.id,
                job,
                rect: l.rect,
                rays: 1,
                pixels: &px,
                worker: None,
            })
            .unwrap_err();
        assert!(
            matches!(&e, FarmError::BadTile(m) if m.contains(what) && m.contains("(5, 0)")),
            "{e}"
        );
    }
    // A negative zero is a zero: taken. Both tiles claim 2^64-1 rays.
    let again = f.lease(w).unwrap().unwrap();
    assert_eq!(again.rect, l.rect, "the refused tile comes back first");
    let mut px = pixels(again.rect);
    px[0] = [-0.0, 0.0, 0.0];
    f.put_tile(LeaseResult {
        lease: again.id,
        job,
        rect: again.rect,
        rays: u64::MAX,
        pixels: &px,
        worker: None,
    })
    .unwrap();
    let last = f.lease(w).unwrap().unwrap();
    f.put_tile(LeaseResult {
        lease: last.id,
        job,
        rect: last.rect,
        rays: u64::MAX,
        pixels: &pixels(last.rect),
        worker: None,
    })
    .unwrap();
    let info = f.info(job).unwrap();
    assert_eq!((info.state, info.rays), (JobState::Done, u64::MAX));
    let snap = f.snapshot();
    assert_eq!(snap.counters.rays, u64::MAX, "trevi_rays_total wrapped");
    assert_eq!(snap.workers[0].rays, u64::MAX);
}

#[test]
fn a_worker_acts_only_with_its_own_session_secret() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path(), Duration::from_secs(60), 1 << 30);
    let with_session = |name| {
        let r = f
            .register_worker(WorkerOptions {
                name,
                threads: 1,
                session: true,
                multi_tile: false,
                max_memory: 0,
                png_segments: false,
                addr: "",
            })
            .unwrap();
        (r.id, r.session.expect("asked for"))
    };
    let (a, sa) = with_session("a");
    let (b, sb) = with_session("b");
    assert_ne!(sa, sb, "secrets are random");
    assert_ne!(sa, [0u8; 32]);
    f.check_session(a, &sa).unwrap();
    f.check_session(b, &sb).unwrap();
    for wrong in [&sb[..], &[][..], &sa[..31]] {
        let e = f.check_session(a, wrong).unwrap_err();
        assert_eq!(e.code(), tonic::Code::PermissionDenied, "{e}");
    }
    let e = f.check_session(b + 100, &sb).unwrap_err();
    assert_eq!(
        e.code(),
        tonic::Code::Unauthenticated,
        "unknown: register again"
    );
    // A worker registered in-process has no secret: nothing matches it.
    let c = f.register_worker(WorkerOptions::default()).unwrap().id;
    assert!(f.check_session(c, &[0u8; 32]).is_err());
}
