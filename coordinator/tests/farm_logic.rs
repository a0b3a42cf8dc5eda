//! The coordinator's rules without a network: scheduling, validation and
//! stitching through the real `FrameWriter`, with synthetic pixels.

use std::path::Path;
use std::time::Duration;
use trevi_coordinator::scheduler::Lease;
use trevi_coordinator::{
    Farm, FarmConfig, FarmError, JobSpec, JobState, SchedulerConfig, TileOutcome,
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

fn farm(dir: &Path, ttl: Duration, window_bytes: u64) -> Farm {
    Farm::new(FarmConfig {
        data_dir: dir.to_path_buf(),
        sched: SchedulerConfig {
            lease_ttl: ttl,
            window_bytes,
        },
        default_tile: 16,
    })
    .unwrap()
}

fn spec(w: u32, h: u32, tile: u32, name: &str, priority: i32) -> JobSpec {
    JobSpec {
        bundle_hash: "0".repeat(64),
        camera: "cam".into(),
        priority,
        width: w,
        height: h,
        tile_size: tile,
        output_name: name.into(),
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
        let job = f.submit(spec(50, 37, 16, name, 0)).unwrap().id;
        let out = f.output_path(job, name);
        let w = f.register_worker();
        let mut leases = lease_all(&f, w);
        assert_eq!(leases.len(), 4 * 3);
        leases.reverse(); // Results arrive in the worst order.
        for (i, l) in leases.iter().enumerate() {
            assert!(!out.exists(), "the output appears only when complete");
            assert_eq!(f.info(job).unwrap().tiles_done, i as u64);
            assert_eq!(
                f.put_tile(l.id, job, l.rect, 10, &pixels(l.rect)).unwrap(),
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
    let job = f.submit(spec(32, 16, 16, "o.png", 0)).unwrap().id;
    let (bad, good) = (f.register_worker(), f.register_worker());
    let l = f.lease(bad).unwrap().unwrap();
    let mut short = pixels(l.rect);
    short.pop();
    let e = f.put_tile(l.id, job, l.rect, 1, &short).unwrap_err();
    assert!(matches!(e, FarmError::BadTile(_)), "{e}");
    // Re-queued at once, ahead of the rest of the frame.
    let l2 = f.lease(bad).unwrap().unwrap();
    assert_eq!(l2.rect, l.rect);
    let mut nan = pixels(l.rect);
    nan[5][1] = f32::NAN;
    assert!(matches!(
        f.put_tile(l2.id, job, l2.rect, 1, &nan),
        Err(FarmError::BadTile(_))
    ));
    let mut inf = pixels(l.rect);
    inf[0][0] = f32::INFINITY;
    assert!(f.put_tile(l2.id, job, l2.rect, 1, &inf).is_err());
    // A rectangle that is not a tile of the job.
    let odd = Rect::new(1, 0, 16, 16);
    assert!(f.put_tile(l2.id, job, odd, 1, &pixels(odd)).is_err());
    assert_eq!(f.info(job).unwrap().tiles_done, 0);
    for l in lease_all(&f, good) {
        f.put_tile(l.id, job, l.rect, 1, &pixels(l.rect)).unwrap();
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
    let f = farm(dir.path(), Duration::from_millis(30), 1 << 30);
    let job = f.submit(spec(16, 16, 16, "o.png", 0)).unwrap().id;
    let (slow, fast) = (f.register_worker(), f.register_worker());
    let l = f.lease(slow).unwrap().unwrap();
    assert_eq!(f.lease(fast).unwrap(), None);
    std::thread::sleep(Duration::from_millis(60));
    assert_eq!(f.expire(), 1);
    let l2 = f.lease(fast).unwrap().unwrap();
    assert_eq!(l2.rect, l.rect);
    assert_eq!(f.heartbeat(slow, &[l.id]).unwrap(), vec![l.id]);
    f.put_tile(l2.id, job, l2.rect, 1, &pixels(l2.rect))
        .unwrap();
    assert_eq!(
        f.put_tile(l.id, job, l.rect, 1, &pixels(l.rect)).unwrap(),
        TileOutcome::Ignored
    );
    assert_eq!(f.info(job).unwrap().state, JobState::Done);
}

#[test]
fn heartbeats_keep_a_lease_alive_past_its_first_deadline() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path(), Duration::from_millis(400), 1 << 30);
    f.submit(spec(16, 16, 16, "o.png", 0)).unwrap();
    let w = f.register_worker();
    let l = f.lease(w).unwrap().unwrap();
    for _ in 0..5 {
        std::thread::sleep(Duration::from_millis(100));
        assert!(f.heartbeat(w, &[l.id]).unwrap().is_empty());
        assert_eq!(f.expire(), 0);
    }
}

#[test]
fn jobs_finish_in_priority_order() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path(), Duration::from_secs(60), 1 << 30);
    let low = f.submit(spec(32, 32, 16, "low.png", 0)).unwrap().id;
    let high = f.submit(spec(32, 32, 16, "high.png", 9)).unwrap().id;
    let w = f.register_worker();
    while let Some(l) = f.lease(w).unwrap() {
        f.put_tile(l.id, l.job, l.rect, 1, &pixels(l.rect)).unwrap();
    }
    assert_eq!(f.info(high).unwrap().finish_order, 1);
    assert_eq!(f.info(low).unwrap().finish_order, 2);
}

#[test]
fn a_cancelled_job_takes_no_more_work_and_leaves_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path(), Duration::from_secs(60), 1 << 30);
    let job = f.submit(spec(64, 64, 16, "c.png", 0)).unwrap().id;
    let w = f.register_worker();
    let leases = lease_all(&f, w);
    for l in &leases[..6] {
        f.put_tile(l.id, job, l.rect, 1, &pixels(l.rect)).unwrap();
    }
    assert_eq!(f.cancel(job).unwrap().state, JobState::Cancelled);
    assert_eq!(f.lease(w).unwrap(), None);
    assert_eq!(f.heartbeat(w, &[leases[7].id]).unwrap(), vec![leases[7].id]);
    let l = &leases[7];
    assert_eq!(
        f.put_tile(l.id, job, l.rect, 1, &pixels(l.rect)).unwrap(),
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
            .submit(spec(width, height, tile, "tall.png", 0))
            .unwrap()
            .id;
        let workers: Vec<u64> = (0..4).map(|_| f.register_worker()).collect();
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
            f.put_tile(l.id, job, l.rect, 1, &pixels(l.rect)).unwrap();
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
