//! Where a job is taken out of the queue and put back: a job paused by a
//! user, or waiting for other jobs to end (`crate::farm::control` decides
//! which; here both are one thing, a *parked* job). A parked job keeps its
//! state, its tiles done and its window; none of its tiles are leased. Its
//! tiles out either finish (their results are taken as usual) or, when
//! parked with `return_leases`, are re-queued at once as if their workers
//! had given them back (no failure is counted), and the workers are told
//! to drop them at their next heartbeat, as for a cancelled job.

use super::expiry::Release;
use super::types::{JobId, SchedError};
use super::Scheduler;
use std::cmp::Reverse;

impl Scheduler {
    /// Takes unfinished `job` out of the queue: no more of its tiles are
    /// leased. With `return_leases` its tiles out are re-queued now (a
    /// result that still comes for one is taken if it is the first);
    /// without, they finish. Returns how many tiles were re-queued.
    pub fn park(&mut self, job: JobId, return_leases: bool) -> Result<u32, SchedError> {
        let j = self.jobs.get_mut(&job).ok_or(SchedError::UnknownJob(job))?;
        if j.state.is_final() {
            return Err(SchedError::JobOver(job));
        }
        j.parked = true;
        self.queue.remove(&(Reverse(j.spec.priority), job));
        if !return_leases {
            return Ok(0);
        }
        let out: Vec<_> = j.window.leases().collect();
        for &lease in &out {
            self.release(lease, "paused", Release::Returned);
        }
        Ok(out.len() as u32)
    }

    /// Puts parked `job` back in the queue, in its place by priority and
    /// submission order.
    pub fn unpark(&mut self, job: JobId) -> Result<(), SchedError> {
        let j = self.jobs.get_mut(&job).ok_or(SchedError::UnknownJob(job))?;
        if j.state.is_final() {
            return Err(SchedError::JobOver(job));
        }
        j.parked = false;
        self.queue.insert((Reverse(j.spec.priority), job));
        Ok(())
    }

    /// Whether `job` is parked (`false` for no such job).
    pub fn is_parked(&self, job: JobId) -> bool {
        self.jobs.get(&job).is_some_and(|j| j.parked)
    }
}

#[cfg(test)]
mod tests {
    use super::super::{test_scheduler, test_spec, Accepted, JobState, Scheduler};
    use crate::limits::Limits;
    use crate::workers::WorkerId;
    use std::time::Instant;

    fn sched() -> (Scheduler, Instant, WorkerId) {
        let now = Instant::now();
        let mut s = test_scheduler(Limits::default());
        let w = s.register_worker(now, None);
        (s, now, w)
    }

    /// Parked without returning its leases: no new tile goes out, the
    /// tile out finishes and counts, and unparking leases the rest.
    #[test]
    fn a_parked_job_leases_nothing_and_its_tiles_out_finish() {
        let (mut s, t0, w) = sched();
        let j = s.submit(test_spec(8, 4, 4, "out.png"), t0);
        let l = s.lease(w, t0).unwrap().unwrap();
        assert_eq!(s.park(j, false), Ok(0));
        assert!(s.is_parked(j));
        assert_eq!(s.lease(w, t0).unwrap(), None);
        // Still the worker's: the heartbeat keeps it.
        assert!(s.heartbeat(w, &[l.id], t0).unwrap().is_empty());
        assert_eq!(
            s.accept_tile(j, l.rect, 3, t0),
            Ok(Accepted::New { last: false })
        );
        assert_eq!(s.info(j, t0).unwrap().state, JobState::Running);
        s.unpark(j).unwrap();
        let next = s.lease(w, t0).unwrap().unwrap();
        assert_ne!(next.rect, l.rect);
        assert_eq!(
            s.accept_tile(j, next.rect, 3, t0),
            Ok(Accepted::New { last: true })
        );
    }

    /// Parked returning its leases: the worker is told to drop the tile
    /// at its next heartbeat, the tile is pending again (leased first
    /// after unparking), and no failure is counted against it.
    #[test]
    fn parking_now_returns_the_tiles_out_without_a_failure() {
        let (mut s, t0, w) = sched();
        let j = s.submit(test_spec(8, 4, 4, "out.png"), t0);
        let l = s.lease(w, t0).unwrap().unwrap();
        assert_eq!(s.park(j, true), Ok(1));
        assert_eq!(s.heartbeat(w, &[l.id], t0).unwrap(), vec![l.id]);
        assert_eq!(s.lease(w, t0).unwrap(), None);
        assert_eq!(s.counters().tiles_requeued, 1);
        s.unpark(j).unwrap();
        let again = s.lease(w, t0).unwrap().unwrap();
        assert_eq!(again.rect, l.rect);
        assert!(s.jobs[&j].failures.is_empty());
        assert!(s.jobs[&j].worker_failures.is_empty());
    }

    /// A priority change of a parked job does not put it back in the
    /// queue; unparking puts it in its new place.
    #[test]
    fn a_parked_job_stays_out_of_the_queue_when_its_priority_changes() {
        let (mut s, t0, w) = sched();
        let a = s.submit(test_spec(4, 4, 4, "a.png"), t0);
        let b = s.submit(test_spec(4, 4, 4, "b.png"), t0);
        s.park(a, false).unwrap();
        s.set_priority(a, 5).unwrap();
        assert_eq!(s.lease(w, t0).unwrap().unwrap().job, b);
        let c = s.submit(test_spec(4, 4, 4, "c.png"), t0);
        s.unpark(a).unwrap();
        // Priority 5 first, whatever its submission order.
        assert_eq!(s.lease(w, t0).unwrap().unwrap().job, a);
        assert_eq!(s.lease(w, t0).unwrap().unwrap().job, c);
    }

    #[test]
    fn an_ended_or_unknown_job_is_not_parked() {
        let (mut s, t0, _) = sched();
        let j = s.submit(test_spec(4, 4, 4, "a.png"), t0);
        s.cancel(j, t0).unwrap();
        assert_eq!(s.park(j, false), Err(super::SchedError::JobOver(j)));
        assert_eq!(s.unpark(j), Err(super::SchedError::JobOver(j)));
        assert_eq!(s.park(99, true), Err(super::SchedError::UnknownJob(99)));
    }
}
