//! Where an expired lease is re-queued, and the other ways a lease ends
//! before its tile is done: heartbeats renew leases
//! ([`Scheduler::heartbeat`]); a lease past its deadline puts its tile back
//! in the queue ([`Scheduler::expire`]); a worker gives a lease back or
//! declines it for memory. Each end is counted against the tile and the
//! worker by the failure rules ([`Release`]): a tile that fails or loses its
//! worker too often fails its job, and so does a job every live worker is
//! kept from or none can hold ([`Scheduler::take_failed`]).

use super::blocks::{TileFault, MAX_PENDING_FAULTS};
use super::failure::JobFailure;
use super::types::{JobId, LeaseId, SchedError};
use super::window::TileState;
use super::Scheduler;
use crate::workers::{WorkerId, Workers};
use std::time::{Duration, Instant};

/// Why a lease ends before its tile is done.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Release {
    /// It ran out: the worker holding it was lost.
    Lost,
    /// Its result was invalid, or the worker's render failed.
    Failed,
    /// The worker gave it back unrendered (it is stopping): no one's fault.
    Returned,
}

/// How a job's error names the workers `ids`: by name and id, the first
/// eight, then how many more.
fn name_workers(workers: &Workers, ids: &[WorkerId]) -> String {
    let mut named: Vec<String> = ids
        .iter()
        .take(8)
        .map(|&w| match workers.name_of(w).unwrap_or_default() {
            "" => format!("worker {w}"),
            n => format!("{n} (worker {w})"),
        })
        .collect();
    if ids.len() > 8 {
        named.push(format!("{} more", ids.len() - 8));
    }
    named.join(", ")
}

/// The earlier of `bound` (if any) and `deadline`.
pub(super) fn earliest(bound: Option<Instant>, deadline: Instant) -> Instant {
    bound.map_or(deadline, |d| d.min(deadline))
}

impl Scheduler {
    /// Renews `worker`'s leases; returns those it should drop.
    pub fn heartbeat(
        &mut self,
        worker: WorkerId,
        leases: &[LeaseId],
        now: Instant,
    ) -> Result<Vec<LeaseId>, SchedError> {
        self.touch(worker, now)?;
        let ttl = self.cfg.lease_ttl;
        let mut dropped = Vec::new();
        let mut renewed = false;
        for &l in leases {
            if self.leases.renew(l, worker, now, now + ttl) {
                renewed = true;
            } else {
                dropped.push(l);
            }
        }
        if renewed {
            // Later than the renewed deadlines unless the clock went back.
            self.earliest_deadline = Some(earliest(self.earliest_deadline, now + ttl));
        }
        Ok(dropped)
    }

    /// Re-queues the tiles of leases past their deadline; returns how many.
    /// Also forgets long-silent workers and fails the jobs no live worker
    /// can take (what the farm's reaper runs a few times a lease lifetime).
    pub fn expire(&mut self, now: Instant) -> usize {
        let expired = self.expire_leases(now);
        // Workers silent for ten lease lifetimes are forgotten; one that
        // comes back is told to register again.
        let forget = (self.cfg.lease_ttl * 10).max(Duration::from_secs(60));
        self.workers.forget_silent(forget, now);
        let workers = &self.workers;
        self.sizer.retain_workers(|w| workers.threads(w).is_some());
        self.fail_stranded_jobs(now);
        self.fail_jobs_too_big(now);
        expired
    }

    /// Re-queues the tiles of leases past their deadline; returns how many.
    /// Scans the leases only when the earliest deadline has passed.
    pub(super) fn expire_leases(&mut self, now: Instant) -> usize {
        if self.earliest_deadline.is_none_or(|d| d >= now) {
            return 0;
        }
        let (expired, first) = self.leases.expired(now);
        self.earliest_deadline = first;
        for &id in &expired {
            let Some((worker, job, tile)) = self.leases.get(id).map(|e| (e.worker, e.job, e.tile))
            else {
                continue;
            };
            tracing::warn!(
                worker,
                lease = id,
                job,
                tile,
                "lease expired: the worker went silent (lost); its tile is re-queued"
            );
            let cause = format!("lease expired (worker {worker} went silent)");
            self.release(id, &cause, Release::Lost);
        }
        self.counters.lease_expiries += expired.len() as u64;
        expired.len()
    }

    /// Fails the jobs no live worker can hold once their grace has passed
    /// (see [`memory`]).
    ///
    /// [`memory`]: super::memory
    fn fail_jobs_too_big(&mut self, now: Instant) {
        let live = self.workers.live(self.cfg.lease_ttl, now);
        let limits: Vec<u64> = live.iter().map(|&w| self.workers.memory_limit(w)).collect();
        let queued: Vec<JobId> = self.queue.iter().map(|&(_, id)| id).collect();
        for id in queued {
            if self.failed.iter().any(|(f, _)| *f == id) {
                continue;
            }
            if let Some(msg) = self.memory.too_big(id, &limits, self.cfg.memory_grace, now) {
                self.failed.push((id, JobFailure::Memory(msg)));
            }
        }
    }

    /// `worker` declines `lease` because its scene needs about `bytes`,
    /// more than its memory limit: the tile is re-queued without counting
    /// a failure, the job keeps the estimate (so it is not leased to
    /// workers that small again), and the worker shows as paused for
    /// "memory" until it takes a tile. The claim proves only that the
    /// scene needs more than the worker's own registered limit, so the
    /// estimate rises to just above that limit, no further (one worker's
    /// word cannot keep a job from a bigger one). A claim its own limit
    /// contradicts (no limit, or one that holds `bytes`) is false: the
    /// tile is re-queued and the failure counted against the worker on
    /// that job, not against the tile. False when the claim was false.
    pub fn decline_lease(
        &mut self,
        worker: WorkerId,
        lease: LeaseId,
        bytes: u64,
        now: Instant,
    ) -> Result<bool, SchedError> {
        let limit = self.workers.memory_limit(worker);
        let honest = limit > 0 && bytes > limit;
        if let Some(e) = self.leases.get(lease).filter(|e| e.worker == worker) {
            if honest {
                self.memory
                    .set(e.job, bytes.min(limit.saturating_add(1)), now);
            } else if let Some(j) = self.jobs.get_mut(&e.job) {
                j.count_failure(
                    worker,
                    &format!("worker {worker}: declined a tile for memory its limit holds"),
                );
            }
        }
        self.return_lease(worker, lease, None, now)?;
        if honest {
            self.workers.set_paused(worker, Some("memory"));
        }
        Ok(honest)
    }

    /// Fails the jobs that every live worker is kept from (each failed too
    /// many of their tiles): they would otherwise wait for ever, although no
    /// single tile reached its failure limit. Lost workers do not count, so
    /// a job whose workers all crashed waits for new ones.
    fn fail_stranded_jobs(&mut self, now: Instant) {
        let ttl = self.cfg.lease_ttl;
        let live = self.workers.live(ttl, now);
        if live.is_empty() {
            return;
        }
        let max = self.cfg.max_worker_failures.max(1);
        for &(_, id) in &self.queue {
            let j = &self.jobs[&id];
            let benched = |w: &WorkerId| j.worker_failures.get(w).is_some_and(|&n| n >= max);
            if !live.iter().all(benched)
                || self.leases.holds_job(id)
                || self.failed.iter().any(|(f, _)| *f == id)
            {
                continue;
            }
            let last = j
                .failures
                .iter()
                .max_by_key(|(tile, (n, _, _))| (*n, std::cmp::Reverse(**tile)))
                .map(|(tile, (n, _, cause))| {
                    format!("; tile {tile} failed {n} times, last: {cause}")
                })
                .unwrap_or_default();
            let msg = format!(
                "every live worker ({}) failed {max} or more tiles of this job and is kept \
                 from it{last}",
                name_workers(&self.workers, &live)
            );
            self.failed.push((id, JobFailure::Tiles(msg)));
        }
    }

    /// Removes a lease, counts a failure of its tile and worker (unless it
    /// was returned), and puts the tile back in the queue if it is not done.
    /// A tile failing too often fails its job (see
    /// [`Scheduler::take_failed`]).
    pub(super) fn release(&mut self, lease: LeaseId, cause: &str, why: Release) {
        let Some(e) = self.leases.remove(lease) else {
            return;
        };
        let Some(job) = self.jobs.get_mut(&e.job) else {
            return;
        };
        if job.state.is_final() || job.window.tile_state(e.tile) != TileState::Leased(lease) {
            return;
        }
        job.window.requeue(e.tile);
        self.counters.tiles_requeued += 1;
        job.past_leases.insert(lease, (e.tile, e.worker));
        if why == Release::Returned {
            return;
        }
        let failures = job.count_failure(e.worker, cause);
        let r = job.window.rect(e.tile);
        if self.faults.len() < MAX_PENDING_FAULTS {
            self.faults.push(TileFault {
                job: e.job,
                rect: r,
                worker: e.worker,
                name: self.workers.name_of(e.worker).unwrap_or_default().into(),
                cause: cause.to_string(),
                failures,
                blocked: failures >= self.cfg.max_worker_failures.max(1),
            });
        }
        let f = job.failures.entry(e.tile).or_insert((0, 0, String::new()));
        f.0 += 1;
        if why == Release::Lost {
            f.1 += 1;
        }
        f.2 = cause.to_string();
        let tile = format!("tile {} ({}x{} at ({}, {}))", e.tile, r.w, r.h, r.x, r.y);
        let msg = if f.1 >= self.cfg.max_tile_losses.max(1) {
            format!(
                "{tile} lost the worker rendering it {} times (it crashed, hung or was cut \
                 off while holding the tile); last: {}",
                f.1, f.2
            )
        } else if f.0 >= self.cfg.max_tile_failures.max(1) {
            format!("{tile} failed {} times; last: {}", f.0, f.2)
        } else {
            return;
        };
        // Several tiles may reach their limit at once (a worker lost while
        // holding more than one): the job's error names them all.
        match self.failed.iter_mut().find(|(j, _)| *j == e.job) {
            Some((_, JobFailure::Tiles(m))) => {
                m.push_str("; also ");
                m.push_str(&msg);
            }
            Some(_) => {}
            None => self.failed.push((e.job, JobFailure::Tiles(msg))),
        }
    }

    /// `worker` gives `lease` back before its tile is done: without `error`
    /// (it is stopping) the tile is re-queued and nothing is counted; with
    /// one (its render failed) the failure counts against the tile and the
    /// worker like an invalid result. A lease that is not `worker`'s, or is
    /// gone already, is refused or left alone.
    pub fn return_lease(
        &mut self,
        worker: WorkerId,
        lease: LeaseId,
        error: Option<&str>,
        now: Instant,
    ) -> Result<(), SchedError> {
        self.touch(worker, now)?;
        match self.leases.get(lease) {
            Some(e) if e.worker != worker => {
                let (job, rect) = (e.job, self.jobs[&e.job].window.rect(e.tile));
                Err(SchedError::NotYourLease(lease, worker, rect, job))
            }
            Some(_) => {
                match error {
                    None => self.release(lease, "returned", Release::Returned),
                    Some(e) => {
                        let cause = format!("worker {worker}: {e}");
                        self.release(lease, &cause, Release::Failed);
                    }
                }
                Ok(())
            }
            None => Ok(()),
        }
    }

    /// Jobs that failed because a tile failed too often, with the reason;
    /// the caller ends them with [`Scheduler::finish`].
    pub fn take_failed(&mut self) -> Vec<(JobId, JobFailure)> {
        std::mem::take(&mut self.failed)
    }
}
