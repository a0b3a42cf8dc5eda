//! Which workers may take a job, by memory: a job carries the estimate of
//! what its scene needs once built ([`trevi_core::scene::estimate`], made
//! when the job is submitted, or told by a worker that declined it), a
//! worker the limit it registered with (`trevi-worker --max-memory`; none
//! said means no limit). A job is leased only to workers whose limit is at
//! least its estimate.
//!
//! A job that no live worker can hold waits [`Limits::memory_grace`] from
//! the time its estimate became known or, later, the last time a live
//! worker could hold it (or no worker was live), so that a bigger worker
//! can still register (a farm starting up, a worker's service
//! restarting); after that, while the live workers still cannot hold it,
//! it fails with a message naming the estimate and the largest limit. With
//! no live worker at all the job waits, like any job.
//!
//! [`Limits::memory_grace`]: crate::limits::Limits::memory_grace

use super::JobId;
use std::collections::HashMap;
use std::time::{Duration, Instant};
use trevi_core::scene::estimate::human_bytes;

/// The estimates of the jobs that have one, and since when no live worker
/// could hold them (as far as [`MemoryGate::too_big`] has seen).
#[derive(Debug, Default)]
pub struct MemoryGate {
    jobs: HashMap<JobId, (u64, Instant)>,
}

impl MemoryGate {
    /// Records that `job` needs about `bytes` (a larger estimate wins; 0
    /// says nothing).
    pub fn set(&mut self, job: JobId, bytes: u64, now: Instant) {
        if bytes == 0 {
            return;
        }
        let e = self.jobs.entry(job).or_insert((bytes, now));
        e.0 = e.0.max(bytes);
    }

    /// The estimate of `job` in bytes (0: none).
    pub fn estimate(&self, job: JobId) -> u64 {
        self.jobs.get(&job).map_or(0, |e| e.0)
    }

    /// Whether a worker with `limit` (0: none) may take `job`.
    pub fn fits(&self, job: JobId, limit: u64) -> bool {
        fits(self.estimate(job), limit)
    }

    /// Forgets `job` (it ended).
    pub fn remove(&mut self, job: JobId) {
        self.jobs.remove(&job);
    }

    /// Why `job` must fail, if the workers live now (their limits in
    /// `limits`) cannot hold it and its grace has passed. Called
    /// periodically; a live worker that can hold it (or none live)
    /// restarts the grace.
    pub fn too_big(
        &mut self,
        job: JobId,
        limits: &[u64],
        grace: Duration,
        now: Instant,
    ) -> Option<String> {
        let (bytes, since) = self.jobs.get_mut(&job)?;
        let bytes = *bytes;
        if limits.is_empty() || limits.iter().any(|&l| fits(bytes, l)) {
            *since = (*since).max(now);
            return None;
        }
        if now.saturating_duration_since(*since) < grace {
            return None;
        }
        let largest = limits.iter().copied().max().unwrap_or(0);
        Some(message(bytes, largest, limits.len()))
    }
}

/// Whether a scene of estimate `bytes` (0: unknown) fits a worker of
/// `limit` (0: none).
pub fn fits(bytes: u64, limit: u64) -> bool {
    limit == 0 || bytes <= limit
}

/// The error of a job no worker can hold.
pub fn message(bytes: u64, largest: u64, workers: usize) -> String {
    let whose = if workers == 1 {
        "the only live worker's limit is".to_string()
    } else {
        format!("the largest limit of the {workers} live workers is")
    };
    format!(
        "the scene needs about {} of memory; {whose} {} (trevi-worker --max-memory)",
        human_bytes(bytes),
        human_bytes(largest)
    )
}

#[cfg(test)]
mod tests {
    use super::super::{JobSpec, Scheduler};
    use super::*;
    use crate::limits::Limits;
    use crate::workers::WorkerState;

    const GIB: u64 = 1 << 30;

    #[test]
    fn a_job_goes_to_workers_that_can_hold_it() {
        let t0 = Instant::now();
        let mut g = MemoryGate::default();
        assert!(g.fits(1, 1), "no estimate: any worker");
        g.set(1, 3 * GIB, t0);
        assert!(!g.fits(1, 2 * GIB));
        assert!(g.fits(1, 3 * GIB));
        assert!(g.fits(1, 0), "a worker without a limit takes anything");
        // A worker's larger figure wins; a smaller or zero one changes nothing.
        g.set(1, 4 * GIB, t0);
        g.set(1, GIB, t0);
        g.set(1, 0, t0);
        assert_eq!(g.estimate(1), 4 * GIB);
        g.remove(1);
        assert_eq!(g.estimate(1), 0);
    }

    #[test]
    fn a_job_no_live_worker_can_hold_fails_after_the_grace() {
        let t0 = Instant::now();
        let grace = Duration::from_secs(30);
        let mut g = MemoryGate::default();
        g.set(7, 3_328_599_654, t0);
        let small = [GIB, 2 * GIB];
        let t1 = t0 + grace / 2;
        assert_eq!(g.too_big(7, &small, grace, t1), None, "in its grace");
        assert_eq!(g.too_big(8, &small, grace, t0 + grace), None, "no estimate");
        // A worker that can hold it, or one without a limit, or no live
        // worker at all: it waits, and its grace starts again from there.
        assert_eq!(g.too_big(7, &[GIB, 4 * GIB], grace, t1), None);
        assert_eq!(g.too_big(7, &[GIB, 0], grace, t1), None);
        assert_eq!(g.too_big(7, &[], grace, t1), None);
        assert_eq!(
            g.too_big(7, &small, grace, t0 + grace),
            None,
            "grace from t1"
        );
        let late = t1 + grace;
        assert_eq!(
            g.too_big(7, &small, grace, late).as_deref(),
            Some(
                "the scene needs about 3.1 GiB of memory; the largest limit of the 2 live \
                 workers is 2.0 GiB (trevi-worker --max-memory)"
            )
        );
        assert!(g
            .too_big(7, &[GIB], grace, late)
            .unwrap()
            .contains("the only live worker's limit is 1.0 GiB"));
    }

    fn spec(hash: &str) -> JobSpec {
        JobSpec {
            bundle_hash: hash.into(),
            ..crate::scheduler::test_spec(64, 32, 16, "out.png")
        }
    }

    #[test]
    fn the_scheduler_leases_a_big_scene_only_to_the_big_worker_and_fails_one_too_big_for_all() {
        let t0 = Instant::now();
        let grace = Duration::from_secs(5);
        let mut s = Scheduler::new(
            Limits {
                memory_grace: grace,
                ..Limits::default()
            },
            1,
        );
        let small = s.register_worker(t0, None);
        let big = s.register_worker(t0, None);
        s.set_memory_limit(small, GIB);
        s.set_memory_limit(big, 4 * GIB);
        let job = s.submit(spec("a"), t0);
        s.set_memory_estimate(job, 2 * GIB, t0);

        // The small worker gets nothing and shows why.
        assert_eq!(s.lease(small, t0).unwrap(), None);
        let w = s.workers(t0);
        assert_eq!(w[0].state, WorkerState::Paused);
        assert_eq!(w[0].paused.as_deref(), Some("memory"));
        assert_eq!(w[0].memory_limit, GIB);
        // Every tile goes to the big one, with the estimate.
        let mut tiles = 0;
        while let Some(l) = s.lease(big, t0).unwrap() {
            assert_eq!(l.memory_estimate, 2 * GIB);
            tiles += l.tiles;
        }
        assert_eq!(tiles, 8);
        s.expire(t0 + grace + Duration::from_secs(1));
        assert!(s.take_failed().is_empty(), "the big worker can hold it");

        // Too big for both: it waits out its grace, then fails.
        let huge = s.submit(spec("b"), t0);
        s.set_memory_estimate(huge, 5 * GIB, t0);
        let t1 = t0 + grace / 2;
        s.heartbeat(small, &[], t1).unwrap();
        s.heartbeat(big, &[], t1).unwrap();
        s.expire(t1);
        assert!(s.take_failed().is_empty(), "within its grace");
        let t2 = t0 + grace + Duration::from_millis(1);
        s.heartbeat(small, &[], t2).unwrap();
        s.heartbeat(big, &[], t2).unwrap();
        s.expire(t2);
        let failed = s.take_failed();
        assert_eq!(failed.len(), 1);
        assert_eq!(failed[0].0, huge);
        let crate::scheduler::JobFailure::Memory(why) = &failed[0].1 else {
            panic!("{:?}", failed[0].1);
        };
        assert!(
            why.contains("5.0 GiB") && why.contains("is 4.0 GiB"),
            "{why}"
        );
    }

    #[test]
    fn a_declined_tile_is_requeued_free_and_the_job_keeps_the_worker_s_estimate() {
        let t0 = Instant::now();
        let mut s = Scheduler::new(Limits::default(), 1);
        let small = s.register_worker(t0, None);
        s.set_memory_limit(small, GIB);
        // No estimate known (a job restored after a restart): leased.
        let job = s.submit(spec("a"), t0);
        let l = s.lease(small, t0).unwrap().expect("a lease");
        assert_eq!(l.memory_estimate, 0);
        assert!(s.decline_lease(small, l.id, 3 * GIB, t0).unwrap());
        // The claim proves no more than "over the worker's 1 GiB".
        assert_eq!(s.memory_estimate(job), GIB + 1);
        assert_eq!(s.workers(t0)[0].paused.as_deref(), Some("memory"));
        assert_eq!(s.counters().tiles_requeued, 1);
        // Not counted as a failure, and not leased to it again.
        assert_eq!(s.lease(small, t0).unwrap(), None);
        let big = s.register_worker(t0, None);
        let again = s.lease(big, t0).unwrap().expect("the big worker takes it");
        assert_eq!((again.job, again.rect), (job, l.rect));
    }

    /// Issue 36: one `ReturnTile(memory_needed = 2^64 - 1)` raised the
    /// job's estimate past every worker and failed it while a 12 GiB
    /// worker was attached.
    #[test]
    fn a_worker_s_memory_claim_cannot_keep_a_job_from_a_bigger_worker() {
        let t0 = Instant::now();
        let mut s = Scheduler::new(Limits::default(), 1);
        let big = s.register_worker(t0, None);
        s.set_memory_limit(big, 12 * GIB);
        let liar = s.register_worker(t0, None);
        s.set_memory_limit(liar, 1);
        let job = s.submit(spec("a"), t0);
        let l = s.lease(liar, t0).unwrap().expect("a lease");
        assert!(s.decline_lease(liar, l.id, u64::MAX, t0).unwrap());
        assert_eq!(s.memory_estimate(job), 2, "no higher than it was proven");
        let again = s.lease(big, t0).unwrap().expect("the big worker takes it");
        assert_eq!((again.job, again.rect), (job, l.rect));
        // A worker with no limit lies: counted against it, not against
        // the tile or the job, and the estimate stays.
        let unlimited = s.register_worker(t0, None);
        let l = s.lease(unlimited, t0).unwrap().expect("a lease");
        assert!(!s.decline_lease(unlimited, l.id, u64::MAX, t0).unwrap());
        assert_eq!(s.memory_estimate(job), 2);
        assert!(s.take_failed().is_empty());
        let w = s.workers(t0);
        assert_eq!(w.iter().find(|w| w.id == unlimited).unwrap().paused, None);
        assert_eq!(s.jobs[&job].worker_failures.get(&unlimited), Some(&1));
    }
}
