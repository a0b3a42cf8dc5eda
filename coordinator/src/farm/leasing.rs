//! A worker's side of the farm: registering ([`Farm::register_worker`],
//! its session secret checked on every later call), being granted a lease
//! ([`Farm::lease`], [`Farm::lease_wait`]), keeping it with heartbeats, and
//! giving it back: returned, declined for memory, or run out
//! ([`Farm::expire`]). The bounds on registering are in `registrations.rs`;
//! which tiles a lease gets is the scheduler's (see [`crate::scheduler`]).

use super::Farm;
use crate::error::FarmError;
use crate::scheduler::{JobId, Lease, LeaseId, WorkerId};
use std::time::{Duration, Instant};

/// How [`Farm::register_worker`] registers a worker.
#[derive(Debug, Clone, Copy, Default)]
pub struct WorkerOptions<'a> {
    /// The name the worker gave (kept short).
    pub name: &'a str,
    /// The render threads it said it has.
    pub threads: u32,
    /// Give it a session secret from the operating system's random source,
    /// which its every later call must present (see [`Farm::check_session`]),
    /// so one worker cannot act under another's id. Without one (an
    /// in-process worker) no secret matches it.
    pub session: bool,
    /// It renders leases of several adjacent tiles (see
    /// [`crate::scheduler::lease_size`]); without it, one tile per lease.
    pub multi_tile: bool,
    /// The most memory it lets a scene take, in bytes (`--max-memory`);
    /// 0: no limit (see [`crate::scheduler::memory`]).
    pub max_memory: u64,
    /// It encodes PNG segments with this coordinator's encoder (its
    /// `png_encoder` equals [`trevi_core::output::PNG_ENCODER`]): its
    /// leases may ask for encoded segments (see [`Farm::put_segments`]),
    /// and only such a worker's are taken.
    pub png_segments: bool,
    /// The client address it registered from, which may have at most
    /// [`Limits::max_workers_per_address`](crate::limits::Limits::max_workers_per_address) workers registered; empty for
    /// in-process callers, who are not counted by address.
    pub addr: &'a str,
}

/// A worker [`Farm::register_worker`] registered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Registration {
    /// The worker's id, which its later calls name.
    pub id: WorkerId,
    /// Its session secret, when [`WorkerOptions::session`] asked for one.
    pub session: Option<[u8; 32]>,
}

impl Farm {
    /// Registers a worker as `opts` says.
    pub fn register_worker(&self, opts: WorkerOptions) -> Result<Registration, FarmError> {
        let session = if opts.session {
            let mut secret = [0u8; 32];
            getrandom::getrandom(&mut secret)
                .map_err(|e| FarmError::io("no random session secret", e))?;
            Some(secret)
        } else {
            None
        };
        let mut st = self.state.lock();
        let l = &self.cfg.limits;
        st.check_registration(opts.addr, l.max_workers, l.max_workers_per_address)?;
        let id = st.sched.register_worker(Instant::now(), session);
        st.registered(id, opts.addr);
        st.sched.describe_worker(id, opts.name, opts.threads);
        if opts.multi_tile {
            st.sched.allow_spans(id);
        }
        if opts.png_segments {
            st.sched.allow_segments(id);
            st.segment_workers.insert(id);
        }
        st.sched.set_memory_limit(id, opts.max_memory);
        Ok(Registration { id, session })
    }

    /// `worker` declines `lease`: its scene needs about `bytes`, more than
    /// the worker's memory limit. Re-queued at once, not counted as a
    /// failure; the job keeps the estimate (see
    /// [`Scheduler::decline_lease`](crate::scheduler::Scheduler::decline_lease)).
    pub fn decline_tile(
        &self,
        worker: WorkerId,
        lease: LeaseId,
        bytes: u64,
    ) -> Result<(), FarmError> {
        let honest = self
            .state
            .lock()
            .sched
            .decline_lease(worker, lease, bytes, Instant::now())?;
        let needs = trevi_core::scene::estimate::human_bytes(bytes);
        if honest {
            tracing::info!(worker, lease, %needs,
                "tile declined: the scene needs more memory than the worker's --max-memory; re-queued");
        } else {
            tracing::warn!(worker, lease, %needs,
                "tile declined for memory its registered limit holds; re-queued, counted against the worker");
        }
        self.work.notify_waiters();
        Ok(())
    }

    /// Checks that `session` is the secret `worker` registered with: an
    /// unknown worker must register (again), a wrong secret is refused.
    pub fn check_session(&self, worker: WorkerId, session: &[u8]) -> Result<(), FarmError> {
        match self.state.lock().sched.session_is(worker, session) {
            None => Err(FarmError::UnknownWorker(worker)),
            Some(true) => Ok(()),
            Some(false) => Err(FarmError::NotYourLease(format!(
                "the session secret is not worker {worker}'s (a worker may only act under \
                 the id its own registration gave it)"
            ))),
        }
    }

    /// `worker` gives `lease` back unfinished: re-queued at once, and with
    /// `error` (its render failed) counted against the tile, which may fail
    /// the job (see [`Scheduler::return_lease`](crate::scheduler::Scheduler::return_lease)).
    pub fn return_tile(
        &self,
        worker: WorkerId,
        lease: LeaseId,
        error: Option<&str>,
    ) -> Result<(), FarmError> {
        let failed = {
            let mut st = self.state.lock();
            st.sched
                .return_lease(worker, lease, error, Instant::now())?;
            st.sched.take_failed()
        };
        match error {
            Some(e) => tracing::warn!(worker, lease, error = %e, "tile failed; re-queued"),
            None => tracing::info!(worker, lease, "tile returned unrendered; re-queued"),
        }
        self.work.notify_waiters();
        self.fail_jobs(failed);
        self.log_faults();
        Ok(())
    }

    /// The next tile (or span) for `worker`, if any job has one it may
    /// hand out now; `None` when there is none.
    pub fn lease(&self, worker: WorkerId) -> Result<Option<Lease>, FarmError> {
        let mut st = self.state.lock();
        let lease = st.sched.lease(worker, Instant::now())?;
        // The job's first lease starts it (a frame's: its sequence).
        if let Some(l) = &lease {
            self.events
                .leased(st.parent_of.get(&l.job).copied().unwrap_or(l.job));
        }
        Ok(lease)
    }

    /// Like [`Farm::lease`], waiting up to `wait` for a tile to become available.
    pub async fn lease_wait(
        &self,
        worker: WorkerId,
        wait: Duration,
    ) -> Result<Option<Lease>, FarmError> {
        let deadline = tokio::time::Instant::now() + wait;
        loop {
            let notified = self.work.notified();
            tokio::pin!(notified);
            notified.as_mut().enable();
            if let Some(l) = self.lease(worker)? {
                return Ok(Some(l));
            }
            if tokio::time::timeout_at(deadline, notified).await.is_err() {
                return Ok(None);
            }
        }
    }

    /// Renews `worker`'s `leases` for another lease lifetime; returns those
    /// it no longer holds and should drop (expired, or dropped when their
    /// job ended).
    pub fn heartbeat(
        &self,
        worker: WorkerId,
        leases: &[LeaseId],
    ) -> Result<Vec<LeaseId>, FarmError> {
        Ok(self
            .state
            .lock()
            .sched
            .heartbeat(worker, leases, Instant::now())?)
    }

    /// Records why `worker` takes no tiles for now (`None`: it works); see
    /// [`crate::workers::WorkerState::Paused`].
    pub fn set_paused(&self, worker: WorkerId, why: Option<&str>) {
        let mut st = self.state.lock();
        st.sched.set_paused(worker, why);
    }

    /// Re-queues tiles whose leases ran out.
    pub fn expire(&self) -> usize {
        let (n, failed) = {
            let mut st = self.state.lock();
            let n = st.sched.expire(Instant::now());
            (n, st.sched.take_failed())
        };
        if n > 0 {
            tracing::warn!(tiles = n, "leases expired; tiles re-queued");
            self.work.notify_waiters();
        }
        self.fail_jobs(failed);
        self.log_faults();
        let unrecorded: Vec<(JobId, crate::scheduler::Outcome)> = self
            .state
            .lock()
            .unrecorded
            .iter()
            .map(|(&j, r)| (j, r.clone()))
            .collect();
        for (job, result) in unrecorded {
            self.end_job(job, result);
        }
        self.prune();
        n
    }
}
