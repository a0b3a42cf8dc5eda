//! Where job status is reported: a job's [`JobInfo`], the list of jobs by
//! pages, the counters and queue depth for `/metrics`, and the workers with
//! the tiles they hold and their rate.

use super::job::Job;
use super::types::{Counters, JobId, JobInfo, JobSpec, QueueDepth};
use super::Scheduler;
use crate::workers::{WorkerId, WorkerInfo};
use std::collections::HashMap;
use std::time::Instant;
use trevi_core::tile::Rect;

impl Scheduler {
    /// A snapshot of `job` at `now`; `None` when there is no such job.
    pub fn info(&self, job: JobId, now: Instant) -> Option<JobInfo> {
        let j = self.jobs.get(&job)?;
        let end = j.finished.unwrap_or(now);
        Some(JobInfo {
            id: job,
            spec: j.spec.clone(),
            state: j.state,
            tiles_total: j.window.tiles_total() as u64,
            tiles_done: j.done,
            rays: j.rays,
            elapsed: end.saturating_duration_since(j.submitted),
            queued: j
                .started
                .unwrap_or(end)
                .min(end)
                .saturating_duration_since(j.submitted),
            error: j.error.clone(),
            finish_order: j.finish_order,
            frames: None,
            passes: None,
            paused: false,
            waiting_for: Vec::new(),
            blocked: self.blocked(job),
        })
    }

    /// What `job` renders (`None`: no such job).
    pub fn spec_of(&self, job: JobId) -> Option<&JobSpec> {
        self.jobs.get(&job).map(|j| &j.spec)
    }

    /// The name `worker` registered with (empty: none, or no such worker).
    pub fn worker_name(&self, worker: WorkerId) -> String {
        self.workers.name_of(worker).unwrap_or_default().to_string()
    }

    /// Who submitted `job` and the name `worker` registered with, for the
    /// usage history (`None`: no such job; the name is empty for an
    /// unknown worker or one that said none).
    pub fn usage_owner(&self, job: JobId, worker: WorkerId) -> Option<(&str, &str)> {
        let j = self.jobs.get(&job)?;
        Some((
            j.spec.submitter.as_str(),
            self.workers.name_of(worker).unwrap_or_default(),
        ))
    }

    /// Every job, by id.
    pub fn list(&self, now: Instant) -> Vec<JobInfo> {
        self.list_from(0, usize::MAX, now).0
    }

    /// Up to `limit` jobs by id from id `from` on, and the id the next page
    /// starts at (`None` after the last job).
    pub fn list_from(
        &self,
        from: JobId,
        limit: usize,
        now: Instant,
    ) -> (Vec<JobInfo>, Option<JobId>) {
        let mut ids: Vec<JobId> = self.jobs.keys().copied().filter(|&id| id >= from).collect();
        ids.sort_unstable();
        let next = ids.get(limit).copied();
        ids.truncate(limit);
        let page = ids
            .into_iter()
            .filter_map(|id| self.info(id, now))
            .collect();
        (page, next)
    }

    /// Number of live leases.
    #[cfg(test)]
    pub(super) fn lease_count(&self) -> usize {
        self.leases.len()
    }

    /// The running totals since the scheduler was made.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// Unfinished jobs and their tiles that wait for a worker.
    pub fn queue_depth(&self) -> QueueDepth {
        let mut d = QueueDepth::default();
        for &(_, id) in &self.queue {
            let j = &self.jobs[&id];
            d.jobs += 1;
            d.tiles += (j.window.tiles_total() as u64)
                .saturating_sub(j.done)
                .saturating_sub(u64::from(j.window.leased()));
        }
        d
    }

    /// Every known worker, by id, with what it holds and how fast it went
    /// over the last few seconds. What a worker holds is given as few
    /// rects as cover exactly its leased tiles: a span of whole bands is
    /// one rect, not one for each of its (hundreds of) tiles, which the
    /// monitor would list and this would build under the farm's lock.
    pub fn workers(&self, now: Instant) -> Vec<WorkerInfo> {
        let mut held: HashMap<WorkerId, Vec<(JobId, Rect)>> = HashMap::new();
        // Runs of consecutive tiles in lease id order: a span's tiles
        // follow each other, row-major.
        let mut last: Option<(JobId, &Job)> = None;
        for run in self.leases.runs() {
            let job = match last {
                Some((id, job)) if id == run.job => job,
                _ => &self.jobs[&run.job],
            };
            last = Some((run.job, job));
            let list = held.entry(run.worker).or_default();
            let cols = job.window.cols();
            let (mut t, end) = (run.first_tile, run.first_tile + run.len);
            while t < end {
                // The run's tiles in `t`'s band: one rect.
                let stop = end.min((t / cols + 1) * cols);
                let (a, b) = (job.window.rect(t), job.window.rect(stop - 1));
                let rect = Rect::new(a.x, a.y, b.x + b.w - a.x, a.h);
                match list.last_mut() {
                    // The next tiles of the same band: the rect grows right.
                    Some((j, r))
                        if *j == run.job
                            && r.y == rect.y
                            && r.h == rect.h
                            && r.x + r.w == rect.x =>
                    {
                        r.w += rect.w;
                    }
                    _ => list.push((run.job, rect)),
                }
                t = stop;
            }
        }
        for list in held.values_mut() {
            merge_stacked(list);
        }
        self.workers.list(held, self.cfg.lease_ttl, now)
    }

    /// Rays per second of the whole farm over the last few seconds.
    pub fn rays_per_second(&self, now: Instant) -> f64 {
        self.workers.rays_per_second(now)
    }
}

/// Merges rects of one job stacked exactly on top of each other (the same
/// columns, the lower starting where the upper ends) into one, so that the
/// rects still cover exactly the same pixels: the bands of a span become
/// one rect.
fn merge_stacked(list: &mut Vec<(JobId, Rect)>) {
    list.sort_unstable_by_key(|&(j, r)| (j, r.x, r.w, r.y));
    let mut out: Vec<(JobId, Rect)> = Vec::with_capacity(list.len());
    for &(j, r) in list.iter() {
        match out.last_mut() {
            Some((oj, o)) if *oj == j && o.x == r.x && o.w == r.w && o.y + o.h == r.y => {
                o.h += r.h;
            }
            _ => out.push((j, r)),
        }
    }
    *list = out;
}
