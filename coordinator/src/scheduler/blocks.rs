//! Blocklists: a worker that failed `max_worker_failures` tiles of a job is
//! kept from that job's tiles (Flamenco's rule: per job, not farm-wide; the
//! rule is applied in `lease.rs`, and `expiry.rs` fails a job every live
//! worker is kept from). Here: whether a worker is kept from a job
//! ([`Job::blocks`]), the blocked workers of a job with what each said last
//! ([`Blocked`], what `status` shows), [`Scheduler::unblock`], which lets
//! one take the job's tiles again, and the failures the tile log records
//! ([`TileFault`], taken by the farm with [`Scheduler::take_faults`]).
//!
//! Blocks survive a restart with their job: worker ids change with every
//! coordinator run, so the farm stores a block under the worker's name, and
//! a block read back ([`Scheduler::restore_block`]) goes to the first worker
//! of that name that asks for a lease.

use super::job::Job;
use super::types::{JobId, SchedError};
use super::Scheduler;
use crate::workers::WorkerId;
use trevi_core::tile::Rect;

/// A worker kept from a job: it failed `failures` of its tiles, at least
/// `max_worker_failures`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Blocked {
    /// Its id; `None` for a block read back after a restart that no worker
    /// of its name has asked for a lease since.
    pub worker: Option<WorkerId>,
    /// The name it registered with.
    pub name: String,
    /// Tiles of the job it failed.
    pub failures: u32,
    /// Why its last one failed (the worker's error text, or what the
    /// coordinator saw: an invalid result, a lease that ran out).
    pub last_error: String,
    /// For a frame of a sequence: the frame (set by the farm).
    pub frame: Option<u32>,
}

/// A lease of one tile that ended in a failure, for the tile log and the
/// stored blocks.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TileFault {
    /// The tile's job (a frame's or a pass's own job).
    pub job: JobId,
    /// The tile.
    pub rect: Rect,
    /// The worker that held it, and its name.
    pub worker: WorkerId,
    /// See `worker`.
    pub name: String,
    /// Why it failed.
    pub cause: String,
    /// The worker's failures on the job with this one.
    pub failures: u32,
    /// The worker is kept from the job now.
    pub blocked: bool,
}

/// Most faults held for the farm between two [`Scheduler::take_faults`]
/// (the reaper takes them a few times a lease lifetime); more are not
/// logged.
pub const MAX_PENDING_FAULTS: usize = 4096;

impl Job {
    /// Whether `worker` (registered as `name`) is kept from this job, after
    /// `max` failures. A block read back after a restart under its name
    /// becomes its own here.
    pub(super) fn blocks(&mut self, worker: WorkerId, name: Option<&str>, max: u32) -> bool {
        if !self.restored_blocks.is_empty() {
            if let Some((n, why)) = name.and_then(|n| self.restored_blocks.remove(n)) {
                let f = self.worker_failures.entry(worker).or_default();
                *f = (*f).max(n);
                self.worker_errors.entry(worker).or_insert(why);
            }
        }
        self.worker_failures.get(&worker).is_some_and(|&n| n >= max)
    }

    /// Counts a failure of `worker` on this job, for `cause`; its failures
    /// now.
    pub(super) fn count_failure(&mut self, worker: WorkerId, cause: &str) -> u32 {
        let n = self.worker_failures.entry(worker).or_default();
        *n += 1;
        self.worker_errors.insert(worker, cause.to_string());
        *n
    }
}

impl Scheduler {
    /// The workers kept from `job` now, by name then id (none for an ended
    /// job, or one the scheduler does not hold).
    pub fn blocked(&self, job: JobId) -> Vec<Blocked> {
        let max = self.cfg.max_worker_failures.max(1);
        let Some(j) = self.jobs.get(&job) else {
            return Vec::new();
        };
        let mut out: Vec<Blocked> = j
            .worker_failures
            .iter()
            .filter(|(_, &n)| n >= max)
            .map(|(&w, &n)| Blocked {
                worker: Some(w),
                name: self.workers.name_of(w).unwrap_or_default().to_string(),
                failures: n,
                last_error: j.worker_errors.get(&w).cloned().unwrap_or_default(),
                frame: j.spec.frame,
            })
            .chain(
                j.restored_blocks
                    .iter()
                    .filter(|(_, (n, _))| *n >= max)
                    .map(|(name, (n, why))| Blocked {
                        worker: None,
                        name: name.clone(),
                        failures: *n,
                        last_error: why.clone(),
                        frame: j.spec.frame,
                    }),
            )
            .collect();
        out.sort_by(|a, b| (&a.name, a.worker).cmp(&(&b.name, b.worker)));
        out
    }

    /// Lets the workers `who` names (a worker id, or a name: every blocked
    /// worker of that name) take `job`'s tiles again, their failures on it
    /// forgotten; returns them. Refused for an unknown or ended job, and
    /// when `who` names no worker blocked from it.
    pub fn unblock(&mut self, job: JobId, who: &str) -> Result<Vec<Blocked>, SchedError> {
        let j = self.jobs.get(&job).ok_or(SchedError::UnknownJob(job))?;
        if j.state.is_final() {
            return Err(SchedError::JobOver(job));
        }
        let blocked = self.blocked(job);
        let id = who.trim().parse::<WorkerId>().ok();
        let (hit, rest): (Vec<Blocked>, Vec<Blocked>) = blocked
            .into_iter()
            .partition(|b| b.name == who || (id.is_some() && b.worker == id));
        if hit.is_empty() {
            let names: Vec<String> = rest.iter().map(describe).collect();
            return Err(SchedError::NotBlocked {
                job,
                who: who.chars().take(64).collect(),
                blocked: if names.is_empty() {
                    "none".into()
                } else {
                    names.join(", ")
                },
            });
        }
        let j = self.jobs.get_mut(&job).expect("looked up above");
        for b in &hit {
            match b.worker {
                Some(w) => {
                    j.worker_failures.remove(&w);
                    j.worker_errors.remove(&w);
                }
                None => {
                    j.restored_blocks.remove(&b.name);
                }
            }
        }
        Ok(hit)
    }

    /// Gives unfinished `job` a block read back from the database: the
    /// worker named `name` failed `failures` of its tiles, the last for
    /// `last_error`. Ignored for a job the scheduler does not hold.
    pub fn restore_block(&mut self, job: JobId, name: &str, failures: u32, last_error: &str) {
        if let Some(j) = self.jobs.get_mut(&job).filter(|j| !j.state.is_final()) {
            j.restored_blocks
                .insert(name.to_string(), (failures, last_error.to_string()));
        }
    }

    /// The failed leases since the last call, oldest first (at most
    /// [`MAX_PENDING_FAULTS`]).
    pub fn take_faults(&mut self) -> Vec<TileFault> {
        std::mem::take(&mut self.faults)
    }
}

/// How `status` and errors name a blocked worker: its name and id.
pub fn describe(b: &Blocked) -> String {
    match (b.worker, b.name.is_empty()) {
        (Some(w), true) => format!("worker {w}"),
        (Some(w), false) => format!("{} (worker {w})", b.name),
        (None, _) => format!("{} (before the restart)", b.name),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::limits::Limits;
    use crate::scheduler::{test_scheduler, test_spec};
    use std::time::Instant;

    fn farm(max: u32) -> (Scheduler, JobId, WorkerId, WorkerId, Instant) {
        let now = Instant::now();
        let mut s = test_scheduler(Limits {
            max_worker_failures: max,
            max_tile_failures: 100,
            ..Limits::default()
        });
        let job = s.submit(test_spec(8, 8, 4, "o.png"), now);
        let bad = s.register_worker(now, None);
        s.describe_worker(bad, "bad", 1);
        let good = s.register_worker(now, None);
        s.describe_worker(good, "good", 1);
        (s, job, bad, good, now)
    }

    /// `worker` leases a tile of the job and gives it back with `why`.
    fn fail(s: &mut Scheduler, w: WorkerId, why: &str, now: Instant) -> bool {
        match s.lease(w, now).unwrap() {
            Some(l) => {
                s.return_lease(w, l.id, Some(why), now).unwrap();
                true
            }
            None => false,
        }
    }

    #[test]
    fn a_worker_failing_its_limit_is_blocked_shown_and_unblocked() {
        let (mut s, job, bad, good, now) = farm(2);
        assert!(fail(&mut s, bad, "boom 1", now));
        assert!(s.blocked(job).is_empty(), "one failure of two");
        assert!(fail(&mut s, bad, "boom 2", now));
        let b = s.blocked(job);
        assert_eq!(b.len(), 1, "{b:?}");
        assert_eq!(
            (b[0].worker, b[0].name.as_str(), b[0].failures),
            (Some(bad), "bad", 2)
        );
        assert!(b[0].last_error.contains("boom 2"), "{}", b[0].last_error);
        assert!(s.lease(bad, now).unwrap().is_none(), "kept from the job");
        assert!(s.lease(good, now).unwrap().is_some(), "others are not");
        // Every failure is there for the log, the second one blocking.
        let faults = s.take_faults();
        assert_eq!(faults.len(), 2);
        assert_eq!((faults[1].failures, faults[1].blocked), (2, true));
        assert!(!faults[0].blocked);

        let e = s.unblock(job, "good").unwrap_err().to_string();
        assert!(e.contains("bad (worker"), "names who is blocked: {e}");
        assert!(matches!(
            s.unblock(job + 99, "bad"),
            Err(SchedError::UnknownJob(_))
        ));
        let freed = s.unblock(job, &bad.to_string()).unwrap();
        assert_eq!(freed.len(), 1);
        assert!(s.blocked(job).is_empty());
        assert!(
            s.lease(bad, now).unwrap().is_some(),
            "it may take tiles again"
        );
    }

    #[test]
    fn a_block_read_back_goes_to_the_worker_of_its_name() {
        let (mut s, job, bad, good, now) = farm(2);
        s.restore_block(job, "bad", 2, "boom");
        let b = s.blocked(job);
        assert_eq!((b.len(), b[0].worker), (1, None), "{b:?}");
        assert!(s.lease(good, now).unwrap().is_some());
        assert!(s.lease(bad, now).unwrap().is_none(), "its name's block");
        let b = s.blocked(job);
        assert_eq!((b[0].worker, b[0].last_error.as_str()), (Some(bad), "boom"));
        // Unblocked by name.
        assert_eq!(s.unblock(job, "bad").unwrap().len(), 1);
        assert!(s.lease(bad, now).unwrap().is_some());
    }
}
