//! Where a job is submitted and ended: a job's life in the queue, from
//! [`Scheduler::submit`] (or [`Scheduler::restore`] for a job of an earlier
//! run) through its memory estimate and priority to
//! [`Scheduler::finish`], [`Scheduler::cancel`] or [`Scheduler::hold`],
//! and [`Scheduler::remove`] once it has ended; and the job ids.

use super::failure::Outcome;
use super::job::Job;
use super::types::{JobId, JobInfo, JobSpec, JobState, Restored, SchedError, FRAME_IDS};
use super::window::BandWindow;
use super::Scheduler;
use std::cmp::Reverse;
use std::collections::HashMap;
use std::time::Instant;

/// Two jobs render the same shot: the same bundle and camera (frames of a
/// sequence, the same scene again), so one's measured cost is the other's
/// first estimate.
pub(super) fn same_shot(a: &JobSpec, b: &JobSpec) -> bool {
    a.bundle_hash == b.bundle_hash && a.camera == b.camera
}

impl Scheduler {
    /// Records that `job`'s scene needs about `bytes` once built (the
    /// larger of what is known wins); see [`memory`].
    ///
    /// [`memory`]: super::memory
    pub fn set_memory_estimate(&mut self, job: JobId, bytes: u64, now: Instant) {
        if self.jobs.contains_key(&job) {
            self.memory.set(job, bytes, now);
        }
    }

    /// `job`'s memory estimate in bytes (0: none).
    pub fn memory_estimate(&self, job: JobId) -> u64 {
        self.memory.estimate(job)
    }

    /// The measured cost of `job` in core-seconds per pixel, if any.
    pub fn measured_cost(&self, job: JobId) -> Option<f64> {
        self.sizer.cost(job)
    }

    /// Queues a job. `spec.tile_size`, `width` and `height` must be ≥ 1.
    /// A frame of a sequence (`spec.frame` set) or a pass of a progressive
    /// job (`spec.samples`) takes its id from [`FRAME_IDS`] on, so the ids
    /// users see (stills and sequences) follow one another.
    pub fn submit(&mut self, spec: JobSpec, now: Instant) -> JobId {
        let id = if spec.frame.is_some() || spec.samples.is_some() {
            self.next_frame += 1;
            self.next_frame - 1
        } else {
            self.next_job += 1;
            self.next_job - 1
        };
        // An unfinished job of the same scene and camera that has a
        // measured cost (another frame of a sequence, the same scene again)
        // gives the new one its first estimate (see [`lease_size`]).
        let seed = self.queue.iter().find_map(|&(_, other)| {
            let o = self.jobs.get(&other)?;
            same_shot(&o.spec, &spec)
                .then(|| self.sizer.cost(other))
                .flatten()
        });
        if let Some(cost) = seed {
            self.sizer.seed(id, cost);
        }
        let job = self.new_job(spec, now);
        self.queue.insert((Reverse(job.spec.priority), id));
        self.jobs.insert(id, job);
        self.counters.jobs_submitted += 1;
        id
    }

    /// Puts back a job of an earlier run (see [`Restored`]).
    pub fn restore(&mut self, r: Restored, now: Instant) {
        let mut job = self.new_job(r.spec, r.submitted.min(now));
        self.skip_ids_through(r.id);
        if r.state.is_final() {
            self.finished = self.finished.max(r.finish_order);
            job.state = r.state;
            job.done = r.tiles_done;
            job.rays = r.rays;
            job.error = r.error;
            job.finish_order = r.finish_order;
            let end = job.submitted + r.elapsed.unwrap_or_default();
            job.finished = Some(end);
            job.started = r
                .render
                .map(|d| end.checked_sub(d).unwrap_or(job.submitted));
            job.retire();
            self.jobs.insert(r.id, job);
            return;
        }
        let mut done: Vec<u32> = r
            .done_tiles
            .into_iter()
            .filter(|&i| i < job.window.tiles_total())
            .collect();
        done.sort_unstable();
        done.dedup();
        if !done.is_empty() {
            job.window.restore(&done);
            job.state = JobState::Running;
        }
        job.done = done.len() as u64;
        job.rays = r.rays;
        self.queue.insert((Reverse(job.spec.priority), r.id));
        self.jobs.insert(r.id, job);
    }

    fn new_job(&self, spec: JobSpec, now: Instant) -> Job {
        let tile = spec.tile_size.max(1);
        let spec = JobSpec {
            tile_size: tile,
            ..spec
        };
        Job {
            state: JobState::Queued,
            window: BandWindow::new(&spec, self.cfg.window_bytes),
            done: 0,
            rays: 0,
            submitted: now,
            started: None,
            finished: None,
            error: None,
            finish_order: 0,
            failures: HashMap::new(),
            worker_failures: HashMap::new(),
            worker_errors: HashMap::new(),
            restored_blocks: HashMap::new(),
            past_leases: HashMap::new(),
            parked: false,
            spec,
        }
    }

    /// Moves an unfinished job to priority `priority` (its place among jobs
    /// of equal priority stays its submission order).
    pub fn set_priority(&mut self, job: JobId, priority: i32) -> Result<(), SchedError> {
        let j = self.jobs.get_mut(&job).ok_or(SchedError::UnknownJob(job))?;
        if j.state.is_final() {
            return Err(SchedError::JobOver(job));
        }
        self.queue.remove(&(Reverse(j.spec.priority), job));
        j.spec.priority = priority;
        if !j.parked {
            self.queue.insert((Reverse(priority), job));
        }
        Ok(())
    }

    /// Ends a job: `Ok` when its output is in place, `Err` when it failed.
    pub fn finish(&mut self, job: JobId, result: Outcome, now: Instant) {
        let Some(j) = self.jobs.get_mut(&job) else {
            return;
        };
        if j.state.is_final() {
            return;
        }
        self.finished += 1;
        j.finish_order = self.finished;
        j.finished = Some(now);
        match result {
            Ok(()) => j.state = JobState::Done,
            Err(e) => {
                j.state = JobState::Failed;
                j.error = Some(e.message());
            }
        }
        self.retire(job);
    }

    /// What [`Scheduler::finish`] would make of `job` (`None` when there is
    /// no such job or it is over already), for recording before it is done.
    pub fn finish_info(&self, job: JobId, result: &Outcome, now: Instant) -> Option<JobInfo> {
        let mut info = self.info(job, now).filter(|i| !i.state.is_final())?;
        info.finish_order = self.finished + 1;
        match result {
            Ok(()) => info.state = JobState::Done,
            Err(e) => {
                info.state = JobState::Failed;
                info.error = Some(e.message());
            }
        }
        Some(info)
    }

    /// What [`Scheduler::cancel`] would make of `job`, like
    /// [`Scheduler::finish_info`].
    pub fn cancel_info(&self, job: JobId, now: Instant) -> Option<JobInfo> {
        let mut info = self.info(job, now).filter(|i| !i.state.is_final())?;
        info.state = JobState::Cancelled;
        Some(info)
    }

    /// Stops handing out `job`'s tiles and drops its leases, leaving its
    /// state as it is (its end could not be recorded yet).
    pub fn hold(&mut self, job: JobId) {
        if let Some(j) = self.jobs.get(&job) {
            self.queue.remove(&(Reverse(j.spec.priority), job));
            self.drop_leases(job);
        }
    }

    /// Forgets an ended job (retention); an unfinished one stays.
    pub fn remove(&mut self, job: JobId) -> bool {
        if self.jobs.get(&job).is_some_and(|j| j.state.is_final()) {
            self.jobs.remove(&job);
            true
        } else {
            false
        }
    }

    /// Ended jobs with when they ended, newest first.
    pub fn ended(&self) -> Vec<(JobId, Instant)> {
        let mut v: Vec<(JobId, Instant)> = self
            .jobs
            .iter()
            .filter(|(_, j)| j.state.is_final())
            .map(|(&id, j)| (id, j.finished.unwrap_or(j.submitted)))
            .collect();
        v.sort_unstable_by_key(|&(id, t)| Reverse((t, id)));
        v
    }

    /// Takes the next job id for something that is not a scheduler job (a
    /// sequence, whose frames are jobs).
    pub fn reserve_id(&mut self) -> JobId {
        let id = self.next_job;
        self.next_job += 1;
        id
    }

    /// Never gives an id up to `id` (ids of an earlier run, or whose output
    /// directory exists).
    pub fn skip_ids_through(&mut self, id: JobId) {
        let next = if id >= FRAME_IDS {
            &mut self.next_frame
        } else {
            &mut self.next_job
        };
        *next = (*next).max(id.saturating_add(1));
    }

    /// Cancels an unfinished job; its leases are dropped at the workers' next
    /// heartbeat. Returns the state the job is in afterwards.
    pub fn cancel(&mut self, job: JobId, now: Instant) -> Result<JobState, SchedError> {
        let j = self.jobs.get_mut(&job).ok_or(SchedError::UnknownJob(job))?;
        if !j.state.is_final() {
            j.state = JobState::Cancelled;
            j.finished = Some(now);
            self.retire(job);
        }
        Ok(self.jobs[&job].state)
    }

    fn retire(&mut self, job: JobId) {
        self.sizer.forget_job(job);
        self.memory.remove(job);
        self.drop_leases(job);
        let j = self.jobs.get_mut(&job).expect("job exists");
        self.queue.remove(&(Reverse(j.spec.priority), job));
        j.retire();
    }

    /// Forgets the leases of `job`'s tiles. Its window names them: a lease
    /// is kept only while its tile is out under it (done or re-queued, the
    /// lease goes), so this never scans the farm's lease table for the
    /// job's few.
    fn drop_leases(&mut self, job: JobId) {
        if let Some(j) = self.jobs.get(&job) {
            for l in j.window.leases() {
                self.leases.remove(l);
            }
        }
    }
}
