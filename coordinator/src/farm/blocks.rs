//! Blocklists, the farm's side: [`Farm::unblock`] lets a worker kept from
//! a job take its tiles again (for a sequence, from its frames in
//! progress), and forgets its stored block; a restart gives the unfinished
//! jobs their stored blocks back ([`Farm::restore_blocks`]). The rule itself
//! is the scheduler's (`crate::scheduler::blocks`); the blocks are stored
//! as failures make them, by `tile_log.rs`.

use super::Farm;
use crate::error::FarmError;
use crate::scheduler::{JobId, JobInfo};
use std::time::Instant;

impl Farm {
    /// Lets the worker `who` names (its id, or its name: every blocked
    /// worker of that name) take job `job`'s tiles again; the job's status
    /// after. Refused for an unknown or ended job, or a worker not blocked
    /// from it (the error names those that are).
    pub fn unblock(&self, job: JobId, who: &str) -> Result<JobInfo, FarmError> {
        let mut st = self.state.lock();
        let now = Instant::now();
        let targets: Vec<JobId> = match st.seqs.get(&job) {
            Some(seq) => seq.running.values().copied().collect(),
            None => vec![job],
        };
        let mut freed = Vec::new();
        let mut refused = None;
        for t in targets {
            match st.sched.unblock(t, who) {
                Ok(b) => freed.extend(b.into_iter().map(|b| (t, b.name))),
                Err(e) => refused = Some(e),
            }
        }
        let info = st.info(job, now).ok_or(FarmError::UnknownJob(job))?;
        if freed.is_empty() {
            return Err(match refused {
                Some(e) => e.into(),
                None if info.state.is_final() => FarmError::JobOver(job),
                None => FarmError::Conflict(format!(
                    "no worker \"{}\" is blocked from job {job} (no frame of it is rendering)",
                    who.chars().take(64).collect::<String>()
                )),
            });
        }
        st.publish(job);
        drop(st);
        tracing::info!(job, worker = who, "worker unblocked");
        if let Some(store) = &self.store {
            for (t, name) in &freed {
                store.clear_block(*t, name)?;
            }
        }
        self.work.notify_waiters();
        Ok(info)
    }

    /// Gives the unfinished jobs restored from the database their stored
    /// blocks (what [`Farm::restore`] does not). Blocks of jobs that are
    /// not unfinished any more are ignored.
    pub(super) fn restore_blocks(&self) -> Result<(), FarmError> {
        let Some(store) = &self.store else {
            return Ok(());
        };
        let blocks = store.blocks()?;
        let mut st = self.state.lock();
        for b in blocks {
            st.sched
                .restore_block(b.job, &b.name, b.failures, &b.last_error);
        }
        Ok(())
    }
}
