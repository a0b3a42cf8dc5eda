//! Tests of the scheduler's rules: queue order, leases, expiry, failures,
//! results, counters and reports.

use super::*;
use crate::workers::WorkerState;
use std::time::{Duration, Instant};
use trevi_core::tile::Rect;

/// The sentence of a job failed by its tiles (any other cause fails the
/// test).
fn tiles(f: &JobFailure) -> &str {
    match f {
        JobFailure::Tiles(m) => m,
        other => panic!("not a failure of tiles: {other:?}"),
    }
}

fn spec(priority: i32, w: u32, h: u32, tile: u32) -> JobSpec {
    JobSpec {
        priority,
        ..test_spec(w, h, tile, "out.png")
    }
}

/// Shares by pixels, against hand-computed closed forms: rounded
/// down, the remainder to the last tile, never more than there is,
/// and no overflow for the largest counts.
#[test]
fn rays_are_shared_by_pixels_and_add_up() {
    assert_eq!(ray_shares(1000, &[100, 100, 200]), [250, 250, 500]);
    assert_eq!(ray_shares(10, &[1, 1, 1]), [3, 3, 4]);
    assert_eq!(ray_shares(7, &[5]), [7]);
    assert_eq!(ray_shares(0, &[4, 4]), [0, 0]);
    assert_eq!(ray_shares(5, &[0, 0]), [0, 5]);
    assert!(ray_shares(5, &[]).is_empty());
    let big = ray_shares(u64::MAX, &[u64::MAX, u64::MAX]);
    assert_eq!(big, [u64::MAX / 2, u64::MAX - u64::MAX / 2]);
}

fn sched() -> (Scheduler, Instant, WorkerId) {
    let now = Instant::now();
    let mut s = test_scheduler(Limits::default());
    let w = s.register_worker(now, None);
    (s, now, w)
}

use trevi_core::tile::band_order_tiles;

/// The database keeps these words, and the API and the metrics show them:
/// they are the wire states' labels, and must never change.
#[test]
fn job_state_names_are_the_stored_words() {
    assert_eq!(
        JobState::ALL.map(JobState::name),
        ["queued", "running", "done", "failed", "cancelled"]
    );
}

#[test]
fn jobs_run_by_priority_then_submission_order() {
    let (mut s, now, w) = sched();
    let low = s.submit(spec(0, 4, 4, 4), now);
    let high = s.submit(spec(5, 4, 4, 4), now);
    let low2 = s.submit(spec(0, 4, 4, 4), now);
    let order: Vec<JobId> = (0..3)
        .map(|_| s.lease(w, now).unwrap().unwrap().job)
        .collect();
    assert_eq!(order, vec![high, low, low2]);
    assert_eq!(s.lease(w, now).unwrap(), None);
}

#[test]
fn tiles_go_out_in_band_order_and_idle_workers_take_the_next_job() {
    let (mut s, now, w) = sched();
    let a = s.submit(spec(1, 20, 10, 8), now);
    let b = s.submit(spec(0, 8, 8, 8), now);
    let rects: Vec<Rect> = (0..6)
        .map(|_| s.lease(w, now).unwrap().unwrap())
        .filter(|l| l.job == a)
        .map(|l| l.rect)
        .collect();
    assert_eq!(rects, band_order_tiles(20, 10, 8));
    assert_eq!(s.lease(w, now).unwrap().unwrap().job, b);
    assert_eq!(s.info(a, now).unwrap().state, JobState::Running);
}

/// Expiry scans the leases only once the earliest deadline has passed;
/// that bound must never hide a lease past its deadline. A seeded
/// random run of leases, heartbeats (with the clock also set back) and
/// expiries against a model that checks every deadline each time.
#[test]
fn expiry_finds_every_lease_past_its_deadline_whatever_the_heartbeats() {
    let t0 = Instant::now();
    let ttl = Duration::from_secs(5);
    let mut s = test_scheduler(Limits {
        max_tile_losses: u32::MAX,
        max_tile_failures: u32::MAX,
        max_worker_failures: u32::MAX,
        ..Limits::default()
    });
    assert_eq!(s.cfg.lease_ttl, ttl);
    let workers = [s.register_worker(t0, None), s.register_worker(t0, None)];
    s.submit(spec(0, 32, 32, 1), t0);
    // The model: lease id -> (worker, deadline).
    let mut model: HashMap<LeaseId, (WorkerId, Instant)> = HashMap::new();
    let expire_model = |model: &mut HashMap<LeaseId, (WorkerId, Instant)>, now| {
        let before = model.len();
        model.retain(|_, (_, d)| *d >= now);
        before - model.len()
    };
    let mut rng = 0x2545_f491_4f6c_dd1du64;
    let mut next = move |n: u64| {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        rng % n
    };
    let mut ms: u64 = 0;
    let (mut expired_total, mut renewed_total) = (0, 0);
    for _ in 0..3000 {
        // Mostly forward, sometimes back (never before t0).
        ms = (ms + next(1500)).saturating_sub(next(400));
        let now = t0 + Duration::from_millis(ms);
        let w = workers[next(2) as usize];
        match next(3) {
            0 => {
                expire_model(&mut model, now);
                if let Some(l) = s.lease(w, now).unwrap() {
                    model.insert(l.id, (w, now + ttl));
                }
            }
            1 => {
                let mine: Vec<LeaseId> = model
                    .iter()
                    .filter(|(_, (o, _))| *o == w)
                    .map(|(&id, _)| id)
                    .collect();
                let mut dropped = s.heartbeat(w, &mine, now).unwrap();
                dropped.sort();
                let mut want = Vec::new();
                for id in mine {
                    let e = model.get_mut(&id).unwrap();
                    if e.1 >= now {
                        e.1 = now + ttl;
                        renewed_total += 1;
                    } else {
                        want.push(id);
                    }
                }
                want.sort();
                assert_eq!(dropped, want, "at {ms} ms");
            }
            _ => {
                let n = expire_model(&mut model, now);
                expired_total += n;
                assert_eq!(s.expire(now), n, "at {ms} ms");
            }
        }
    }
    // The run did both things many times.
    assert!(
        expired_total > 100 && renewed_total > 100,
        "{expired_total} {renewed_total}"
    );
}

#[test]
fn heartbeats_renew_and_missed_deadlines_requeue_first() {
    let (mut s, t0, w) = sched();
    let j = s.submit(spec(0, 8, 4, 4), t0);
    let l1 = s.lease(w, t0).unwrap().unwrap();
    let l2 = s.lease(w, t0).unwrap().unwrap();
    let t1 = t0 + Duration::from_secs(4);
    assert_eq!(s.heartbeat(w, &[l2.id], t1).unwrap(), Vec::<LeaseId>::new());
    let t2 = t0 + Duration::from_secs(6);
    // l1 missed its deadline, l2 was renewed until t1+5.
    assert_eq!(s.expire(t2), 1);
    assert_eq!(s.heartbeat(w, &[l1.id, l2.id], t2).unwrap(), vec![l1.id]);
    let again = s.lease(w, t2).unwrap().unwrap();
    assert_eq!((again.job, again.rect), (j, l1.rect));
    assert_ne!(again.id, l1.id);
    // An unknown worker is told so.
    assert_eq!(s.lease(999, t2), Err(SchedError::UnknownWorker(999)));
}

#[test]
fn first_valid_result_wins_late_and_duplicate_ignored() {
    let (mut s, t0, w) = sched();
    let w2 = s.register_worker(t0, None);
    let j = s.submit(spec(0, 4, 4, 4), t0);
    let l1 = s.lease(w, t0).unwrap().unwrap();
    let t1 = t0 + Duration::from_secs(6);
    s.expire(t1);
    let l2 = s.lease(w2, t1).unwrap().unwrap();
    assert_eq!(l2.rect, l1.rect);
    // The late worker finishes first: its result counts.
    assert_eq!(
        s.accept_tile(j, l1.rect, 7, t1),
        Ok(Accepted::New { last: true })
    );
    assert_eq!(s.accept_tile(j, l2.rect, 7, t1), Ok(Accepted::Ignored));
    // w2's lease is gone.
    assert_eq!(s.heartbeat(w2, &[l2.id], t1).unwrap(), vec![l2.id]);
    assert_eq!(s.info(j, t1).unwrap().rays, 7);
    assert_eq!(
        s.accept_tile(j, Rect::new(1, 0, 3, 4), 0, t1),
        Err(SchedError::NotATile(Rect::new(1, 0, 3, 4), j))
    );
}

#[test]
fn rejected_result_requeues_only_its_own_lease() {
    let (mut s, t0, w) = sched();
    let w2 = s.register_worker(t0, None);
    s.submit(spec(0, 4, 4, 4), t0);
    let l1 = s.lease(w, t0).unwrap().unwrap();
    s.reject_tile(l1.id, "bad");
    let l2 = s.lease(w2, t0).unwrap().unwrap();
    assert_eq!(l2.rect, l1.rect);
    // A second bad result under the dead lease does not touch w2's.
    s.reject_tile(l1.id, "bad");
    assert_eq!(s.lease(w, t0).unwrap(), None);
    assert_eq!(s.lease_count(), 1);
}

#[test]
fn cancel_stops_leasing_and_drops_leases() {
    let (mut s, t0, w) = sched();
    let j = s.submit(spec(0, 8, 8, 4), t0);
    let l = s.lease(w, t0).unwrap().unwrap();
    assert_eq!(s.cancel(j, t0), Ok(JobState::Cancelled));
    assert_eq!(s.lease(w, t0).unwrap(), None);
    assert_eq!(s.heartbeat(w, &[l.id], t0).unwrap(), vec![l.id]);
    assert_eq!(s.accept_tile(j, l.rect, 1, t0), Ok(Accepted::Ignored));
    assert_eq!(s.cancel(42, t0), Err(SchedError::UnknownJob(42)));
}

/// A retired job's leases are found from its window, not by scanning
/// every lease: with tiles done, re-queued after expiry and leased
/// again, cancelling one job must drop exactly its leases.
#[test]
fn a_cancelled_job_leaves_no_lease_and_the_others_keep_theirs() {
    let (mut s, t0, w) = sched();
    let a = s.submit(spec(0, 16, 16, 4), t0);
    let first: Vec<Lease> = (0..6).map(|_| s.lease(w, t0).unwrap().unwrap()).collect();
    for l in &first[..2] {
        s.accept_tile(a, l.rect, 1, t0).unwrap();
    }
    let t1 = t0 + Duration::from_secs(6);
    assert_eq!(s.expire(t1), 4);
    // Another worker: the tiles `w` lost count against it.
    let w2 = s.register_worker(t1, None);
    let again: Vec<Lease> = (0..3).map(|_| s.lease(w2, t1).unwrap().unwrap()).collect();
    assert!(again.iter().all(|l| l.job == a));
    // A late result under an expired lease, for a tile leased again.
    s.accept_tile(a, first[2].rect, 1, t1).unwrap();
    let b = s.submit(spec(5, 8, 8, 4), t1);
    let on_b: Vec<Lease> = (0..2).map(|_| s.lease(w2, t1).unwrap().unwrap()).collect();
    assert!(on_b.iter().all(|l| l.job == b));
    assert_eq!(s.lease_count(), 2 + 2);
    s.cancel(a, t1).unwrap();
    assert_eq!(s.lease_count(), 2);
    for l in &on_b {
        assert_eq!(
            s.accept_tile(b, l.rect, 1, t1),
            Ok(Accepted::New { last: false })
        );
    }
    assert_eq!(s.lease_count(), 0);
}

#[test]
fn finish_order_is_recorded() {
    let (mut s, t0, _) = sched();
    let a = s.submit(spec(0, 4, 4, 4), t0);
    let b = s.submit(spec(0, 4, 4, 4), t0);
    s.finish(b, Ok(()), t0);
    s.finish(a, Err(JobFailure::Output("disk full".into())), t0);
    let (ia, ib) = (s.info(a, t0).unwrap(), s.info(b, t0).unwrap());
    assert_eq!((ib.state, ib.finish_order), (JobState::Done, 1));
    assert_eq!((ia.state, ia.finish_order), (JobState::Failed, 2));
    assert_eq!(ia.error.as_deref(), Some("disk full"));
}

/// Frames of sequences use none of the ids users see: the still after
/// a sequence's frames gets the next id, also after a restart.
#[test]
fn frames_take_ids_of_their_own() {
    let (mut s, t0, _) = sched();
    let seq = s.reserve_id();
    let frame = |f| JobSpec {
        frame: Some(f),
        ..spec(0, 4, 4, 4)
    };
    let frames: Vec<JobId> = (1..=3).map(|f| s.submit(frame(f), t0)).collect();
    let still = s.submit(spec(0, 4, 4, 4), t0);
    assert_eq!((seq, still), (1, 2));
    assert_eq!(frames, [FRAME_IDS, FRAME_IDS + 1, FRAME_IDS + 2]);
    let mut again = test_scheduler(Limits::default());
    for id in [still, frames[2]] {
        again.skip_ids_through(id);
    }
    assert_eq!(again.submit(spec(0, 4, 4, 4), t0), 3);
    assert_eq!(again.submit(frame(4), t0), FRAME_IDS + 3);
}

/// A job's time splits at its first lease: before it the job waited
/// in the queue, after it it rendered; a job that never started only
/// waited, and the split survives a restart.
#[test]
fn queue_wait_and_render_time_split_at_the_first_lease() {
    let (mut s, t0, w) = sched();
    let sec = Duration::from_secs;
    let busy = s.submit(spec(5, 4, 4, 4), t0);
    let waiting = s.submit(spec(0, 4, 4, 4), t0);
    let never = s.submit(spec(-1, 4, 4, 4), t0);
    assert_eq!(s.lease(w, t0 + sec(1)).unwrap().unwrap().job, busy);
    assert_eq!(s.lease(w, t0 + sec(4)).unwrap().unwrap().job, waiting);
    s.finish(busy, Ok(()), t0 + sec(9));
    s.finish(waiting, Ok(()), t0 + sec(10));
    let now = t0 + sec(20);
    let (b, wt) = (s.info(busy, now).unwrap(), s.info(waiting, now).unwrap());
    assert_eq!((b.elapsed, b.queued, b.render()), (sec(9), sec(1), sec(8)));
    assert_eq!(
        (wt.elapsed, wt.queued, wt.render()),
        (sec(10), sec(4), sec(6))
    );
    let n = s.info(never, now).unwrap();
    assert_eq!(
        (n.elapsed, n.queued, n.render()),
        (sec(20), sec(20), sec(0))
    );
    // As restored from the database: elapsed and render kept.
    let mut again = test_scheduler(Limits::default());
    again.restore(
        Restored {
            id: waiting,
            spec: spec(0, 4, 4, 4),
            state: JobState::Done,
            submitted: t0,
            elapsed: Some(sec(10)),
            render: Some(sec(6)),
            error: None,
            finish_order: 1,
            tiles_done: 1,
            rays: 0,
            done_tiles: Vec::new(),
        },
        now,
    );
    let r = again.info(waiting, now).unwrap();
    assert_eq!((r.elapsed, r.queued, r.render()), (sec(10), sec(4), sec(6)));
}

#[test]
fn results_for_tiles_never_leased_are_ignored() {
    let (mut s, now, w) = sched();
    let j = s.submit(spec(0, 8, 8, 4), now);
    let l = s.lease(w, now).unwrap().unwrap();
    assert_eq!(
        s.accept_tile(j, Rect::new(4, 4, 4, 4), 1, now),
        Ok(Accepted::Ignored)
    );
    assert_eq!(
        s.accept_tile(j, l.rect, 1, now),
        Ok(Accepted::New { last: false })
    );
    assert!(s.accept_tile(j, Rect::new(8, 0, 4, 4), 1, now).is_err());
    assert_eq!(s.info(j, now).unwrap().tiles_done, 1);
}

#[test]
fn counters_follow_every_tile_event() {
    let (mut s, t0, w) = sched();
    let w2 = s.register_worker(t0, None);
    // 2×2 tiles of 4 pixels.
    let j = s.submit(spec(0, 8, 8, 4), t0);
    let a = s.lease(w, t0).unwrap().unwrap();
    let b = s.lease(w, t0).unwrap().unwrap();
    s.accept_tile(j, a.rect, 10, t0).unwrap();
    // b's lease runs out (ttl 5 s) and its tile goes back in the queue.
    let t1 = t0 + Duration::from_secs(6);
    assert_eq!(s.expire(t1), 1);
    let c = s.lease(w2, t1).unwrap().unwrap();
    assert_eq!(c.rect, b.rect);
    s.reject_tile(c.id, "NaN");
    let d = s.lease(w2, t1).unwrap().unwrap();
    s.accept_tile(j, d.rect, 5, t1).unwrap();
    // The late result under b's expired lease loses to d's.
    assert_eq!(s.accept_tile(j, b.rect, 5, t1), Ok(Accepted::Ignored));
    let want = Counters {
        jobs_submitted: 1,
        leases_granted: 4,
        tiles_accepted: 2,
        tiles_ignored: 1,
        tiles_rejected: 1,
        tiles_requeued: 2,
        lease_expiries: 1,
        rays: 15,
    };
    assert_eq!(s.counters(), want);
    // Two tiles left, neither leased.
    assert_eq!(s.queue_depth(), QueueDepth { jobs: 1, tiles: 2 });
    s.lease(w, t1).unwrap().unwrap();
    assert_eq!(s.queue_depth(), QueueDepth { jobs: 1, tiles: 1 });
}

#[test]
fn workers_show_their_tiles_state_and_rate() {
    let (mut s, t0, w) = sched();
    let w2 = s.register_worker(t0, None);
    s.describe_worker(w, "render-01", 8);
    let j = s.submit(spec(0, 8, 8, 4), t0);
    let a = s.lease(w, t0).unwrap().unwrap();
    let ws = s.workers(t0);
    assert_eq!(ws.len(), 2);
    assert_eq!(ws[0].id, w);
    assert_eq!((ws[0].name.as_str(), ws[0].threads), ("render-01", 8));
    assert_eq!(ws[0].state, WorkerState::Busy);
    assert_eq!(ws[0].leases, vec![(j, a.rect)]);
    assert_eq!(ws[1].state, WorkerState::Idle);
    // w finishes its tile; w2 says nothing for longer than a lease lives.
    let t1 = t0 + Duration::from_secs(3);
    s.accept_tile(j, a.rect, 400, t1).unwrap();
    let t2 = t0 + Duration::from_secs(6);
    s.heartbeat(w, &[], t2).unwrap();
    let ws = s.workers(t2);
    assert_eq!(ws[0].state, WorkerState::Idle);
    assert_eq!((ws[0].tiles_done, ws[0].rays), (1, 400));
    assert_eq!(ws[1].state, WorkerState::Lost);
    // Averaged over the 10 s window once the second is over.
    let epoch = s.workers.epoch();
    let later = epoch + Duration::from_secs(t1.duration_since(epoch).as_secs() + 1);
    let ws = s.workers(later.max(t2));
    assert!(
        (ws[0].rays_per_s - 40.0).abs() < 1e-9,
        "{}",
        ws[0].rays_per_s
    );
    assert!((s.rays_per_second(later.max(t2)) - 40.0).abs() < 1e-9);
    // Long silence: w2 is forgotten and must register again.
    let t3 = t0 + Duration::from_secs(120);
    s.expire(t3);
    assert_eq!(s.lease(w2, t3), Err(SchedError::UnknownWorker(w2)));
}

#[test]
fn priority_changes_reorder_the_queue() {
    let (mut s, t0, w) = sched();
    let a = s.submit(spec(0, 4, 4, 4), t0);
    let b = s.submit(spec(0, 4, 4, 4), t0);
    s.set_priority(b, 5).unwrap();
    assert_eq!(s.info(b, t0).unwrap().spec.priority, 5);
    assert_eq!(s.lease(w, t0).unwrap().unwrap().job, b);
    assert_eq!(s.lease(w, t0).unwrap().unwrap().job, a);
    s.cancel(a, t0).unwrap();
    assert_eq!(s.set_priority(a, 1), Err(SchedError::JobOver(a)));
    assert_eq!(s.set_priority(99, 1), Err(SchedError::UnknownJob(99)));
}

#[test]
fn a_job_every_live_worker_is_kept_from_fails_instead_of_waiting() {
    let (mut s, t0, w) = sched();
    // max_worker_failures 3, max_tile_failures 5: w fails three
    // different tiles once each, so no tile reaches its limit.
    // While a second worker may still take tiles, nothing fails.
    let w2 = s.register_worker(t0, None);
    let j = s.submit(spec(0, 16, 4, 4), t0);
    for _ in 0..3 {
        let l = s.lease(w, t0).unwrap().unwrap();
        s.reject_tile(l.id, "NaN in pixel (0, 0)");
    }
    assert_eq!(s.lease(w, t0).unwrap(), None, "w is benched");
    s.expire(t0);
    let early = s.take_failed();
    assert!(early.is_empty(), "{early:?}");
    // Once w2 is lost too, the only live worker is benched: the job fails.
    let t1 = t0 + Duration::from_secs(6);
    s.heartbeat(w, &[], t1).unwrap();
    s.expire(t1);
    let failed = s.take_failed();
    assert_eq!(failed.len(), 1, "{failed:?}");
    assert_eq!(failed[0].0, j);
    let m = tiles(&failed[0].1);
    assert!(
        m.contains(&format!("every live worker (worker {w})")),
        "{m}"
    );
    assert!(m.contains("NaN in pixel"), "{m}");
    // w2 comes back: too late, the job is over once the farm ends it.
    assert_eq!(s.heartbeat(w2, &[], t1), Ok(vec![]));
}

#[test]
fn a_tile_that_loses_its_worker_three_times_fails_its_job_naming_the_tile() {
    // The scene crashes every worker that renders tile 1: each one's
    // lease runs out. Tile 0 is rendered fine.
    let (mut s, mut now, w) = sched();
    let j = s.submit(spec(0, 8, 4, 4), now);
    let first = s.lease(w, now).unwrap().unwrap();
    s.accept_tile(j, first.rect, 1, now).unwrap();
    for n in 1..=3 {
        let w = s.register_worker(now, None);
        let l = s.lease(w, now).unwrap().unwrap();
        assert_eq!(l.rect, Rect::new(4, 0, 4, 4));
        now += Duration::from_secs(6);
        assert_eq!(s.expire(now), 1);
        let failed = s.take_failed();
        if n < 3 {
            assert!(failed.is_empty(), "after {n} losses: {failed:?}");
        } else {
            assert_eq!(failed.len(), 1, "{failed:?}");
            assert_eq!(failed[0].0, j);
            let m = tiles(&failed[0].1);
            assert!(m.contains("tile 1 (4x4 at (4, 0))"), "{m}");
            assert!(m.contains("lost the worker rendering it 3 times"), "{m}");
        }
    }
}

#[test]
fn tiles_lost_together_are_all_named() {
    let now = Instant::now();
    let mut s = Scheduler::new(
        Limits {
            lease_ttl: Duration::from_secs(5),
            max_tile_losses: 1,
            ..Limits::default()
        },
        1,
    );
    let w = s.register_worker(now, None);
    let j = s.submit(spec(0, 8, 4, 4), now);
    s.lease(w, now).unwrap().unwrap();
    s.lease(w, now).unwrap().unwrap();
    s.expire(now + Duration::from_secs(6));
    let failed = s.take_failed();
    assert_eq!(failed.len(), 1, "one entry per job: {failed:?}");
    assert_eq!(failed[0].0, j);
    let m = tiles(&failed[0].1);
    assert!(m.contains("at (0, 0)") && m.contains("at (4, 0)"), "{m}");
}

#[test]
fn a_returned_lease_requeues_for_free_and_a_failed_render_counts() {
    let (mut s, t0, w) = sched();
    let w2 = s.register_worker(t0, None);
    let j = s.submit(spec(0, 4, 4, 4), t0);
    // Given back unrendered (the worker is stopping), many times over:
    // the tile is re-queued at once and nothing is counted.
    for _ in 0..10 {
        let l = s.lease(w, t0).unwrap().unwrap();
        assert_eq!(
            s.return_lease(w2, l.id, None, t0),
            Err(SchedError::NotYourLease(l.id, w2, l.rect, j)),
            "only the holder may give a lease back"
        );
        s.return_lease(w, l.id, None, t0).unwrap();
        assert!(s.take_failed().is_empty());
    }
    assert_eq!(s.info(j, t0).unwrap().state, JobState::Running);
    // A render that panicked counts like an invalid result: five fail
    // the job (max_tile_failures), with the worker's own words. Two
    // workers, so neither is benched before the tile's limit (3 each).
    for i in 0..5 {
        let who = if i % 2 == 0 { w } else { w2 };
        let l = s.lease(who, t0).unwrap().unwrap();
        s.return_lease(who, l.id, Some("the render panicked: boom"), t0)
            .unwrap();
    }
    let failed = s.take_failed();
    assert_eq!(failed.len(), 1, "{failed:?}");
    let m = tiles(&failed[0].1);
    assert!(m.contains("tile 0 (4x4 at (0, 0)) failed 5 times"), "{m}");
    assert!(m.contains("the render panicked: boom"), "{m}");
    // A lease that is gone already is left alone.
    assert_eq!(s.return_lease(w, 12345, Some("late"), t0), Ok(()));
}

#[test]
fn ray_counts_saturate_instead_of_wrapping() {
    let (mut s, t0, w) = sched();
    let j = s.submit(spec(0, 8, 4, 4), t0);
    for _ in 0..2 {
        let l = s.lease(w, t0).unwrap().unwrap();
        s.accept_tile(j, l.rect, u64::MAX, t0).unwrap();
    }
    assert_eq!(s.info(j, t0).unwrap().rays, u64::MAX);
    assert_eq!(s.counters().rays, u64::MAX);
    assert_eq!(s.workers(t0)[0].rays, u64::MAX);
}
