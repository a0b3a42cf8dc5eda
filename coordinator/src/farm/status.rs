//! What the farm tells about itself: a job's status and its changes, the
//! list of jobs, a finished job's output file, the queue, the workers and
//! the figures the monitor shows.

use super::{lock, Farm};
use crate::error::FarmError;
use crate::metrics::{FarmSnapshot, Metrics};
use crate::scheduler::{JobId, JobInfo, JobState, QueueDepth};
use crate::store::Store;
use crate::workers::WorkerInfo;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::watch;

impl Farm {
    /// A job's or a sequence's status now.
    pub fn info(&self, job: JobId) -> Result<JobInfo, FarmError> {
        self.state
            .lock()
            .info(job, Instant::now())
            .ok_or(FarmError::UnknownJob(job))
    }

    /// Every job the scheduler holds, by id, ended ones included (see
    /// [`Scheduler::list`](crate::scheduler::Scheduler::list)).
    pub fn list(&self) -> Vec<JobInfo> {
        self.state.lock().sched.list(Instant::now())
    }

    /// Up to `limit` jobs by id from id `from` on, and where the next page
    /// starts (`None`: this was the last).
    /// Frames of sequences are not listed: their sequence is.
    pub fn list_from(&self, from: JobId, limit: usize) -> (Vec<JobInfo>, Option<JobId>) {
        self.state.lock().list_from(from, limit, Instant::now())
    }

    /// Progress of a job: the current status, then every change.
    pub fn watch(&self, job: JobId) -> Result<watch::Receiver<JobInfo>, FarmError> {
        self.state
            .lock()
            .watchers
            .get(&job)
            .map(|tx| tx.subscribe())
            .ok_or(FarmError::UnknownJob(job))
    }

    /// The finished output file of a job that is done (a frame of a
    /// sequence: in its sequence's directory). Call off the async threads.
    pub fn output_file(&self, job: JobId) -> Result<PathBuf, FarmError> {
        let frame_of = {
            let st = self.state.lock();
            if st.seqs.contains_key(&job) {
                drop(st);
                return self.frame_file(job, None);
            }
            st.ended.frame_of(job)
        };
        let info = self.info(job)?;
        if let (Some((seq, f)), JobState::Done) = (frame_of, info.state) {
            return self.frame_file(seq, Some(f));
        }
        if info.state != JobState::Done {
            return Err(FarmError::NoOutput(
                job,
                format!("it is {:?}", info.state).to_lowercase(),
            ));
        }
        Ok(self.output_path(job, &info.spec.output_name))
    }

    /// Unfinished jobs and their tiles waiting for a worker.
    pub fn queue_depth(&self) -> QueueDepth {
        self.state.lock().sched.queue_depth()
    }

    /// Every known worker.
    pub fn workers(&self) -> Vec<WorkerInfo> {
        self.state.lock().sched.workers(Instant::now())
    }

    /// Counters, queue, jobs and workers at one instant.
    pub fn snapshot(&self) -> FarmSnapshot {
        let now = Instant::now();
        let st = self.state.lock();
        FarmSnapshot {
            counters: st.sched.counters(),
            queue: st.sched.queue_depth(),
            jobs: st.list_from(0, usize::MAX, now).0,
            workers: st.sched.workers(now),
            rays_per_second: st.sched.rays_per_second(now),
            state_lock_held: self.state.held(),
            store_lock_held: self.store.as_ref().map_or(Duration::ZERO, Store::lock_held),
        }
    }

    /// Request latencies and other figures only the servers see.
    pub fn metrics(&self) -> &Arc<Metrics> {
        &self.metrics
    }

    /// Most rows the job's output held at once (while it is running).
    pub fn max_rows_held(&self, job: JobId) -> Option<usize> {
        let out = self.state.lock().outputs.get(&job).cloned()?;
        let m = lock(&out).max_rows_held;
        Some(m)
    }
}
