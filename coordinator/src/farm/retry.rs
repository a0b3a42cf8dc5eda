//! Retrying a failed still ([`Farm::retry`]): the job is queued again
//! under its id, with the tiles it had finished. A failed still keeps its
//! stored tiles (`Store::finish_frame`) until it is retried or forgotten,
//! so its output is rebuilt from them as after a restart and only the
//! tiles it had not finished are rendered: the file is the bytes of a
//! render that never failed.

use super::{lock, Farm, Output};
use crate::error::FarmError;
use crate::scheduler::{JobFailure, JobId, JobInfo, JobState, Restored, FRAME_IDS};
use std::sync::{Arc, Mutex};
use std::time::Instant;

impl Farm {
    /// The failed still `id`, or why it cannot be retried.
    fn retryable(&self, id: JobId) -> Result<JobInfo, FarmError> {
        let st = self.state.lock();
        if st.seqs.contains_key(&id) {
            return Err(FarmError::Conflict(format!(
                "job {id} is a sequence or a progressive job: retry takes a still (submit the \
                 frames not done again with --frames)"
            )));
        }
        if st.parent_of.contains_key(&id) || id >= FRAME_IDS {
            return Err(FarmError::Conflict(format!(
                "job {id} is a part of a sequence or progressive job: retry takes a still"
            )));
        }
        let info = st
            .info(id, Instant::now())
            .ok_or(FarmError::UnknownJob(id))?;
        if info.state != JobState::Failed || st.unrecorded.contains_key(&id) {
            return Err(FarmError::Conflict(format!(
                "job {id} is {}: retry takes a failed job",
                info.state.name()
            )));
        }
        Ok(info)
    }

    /// Queues failed still `id` again, keeping the tiles it finished (all
    /// of it is rendered again on a coordinator without a database). It
    /// counts again against its submitter's unfinished jobs.
    pub fn retry(&self, id: JobId) -> Result<JobInfo, FarmError> {
        let info = self.retryable(id)?;
        let who = info.spec.submitter.clone();
        Self::check_submitter(
            &self.state.lock(),
            &who,
            self.cfg.limits.max_jobs_per_submitter,
        )?;
        // The output rebuilt from the kept tiles, before the job is queued
        // (a result can only come once it is).
        let (done, out) = match &self.store {
            Some(store) => {
                let done = store.tile_list(id)?;
                let out = if done.is_empty() {
                    None
                } else {
                    Some(self.rebuild_output(store, &info)?)
                };
                (done, out)
            }
            None => (Vec::new(), None),
        };
        let out = out.unwrap_or_else(|| {
            Output::deferred(
                self.output_path(id, &info.spec.output_name),
                &info.spec,
                info.tiles_total,
            )
        });
        let mut st = self.state.lock();
        let now = Instant::now();
        // Checked again: another retry may have been quicker.
        if st.info(id, now).is_none_or(|i| i.state != JobState::Failed) {
            return Err(FarmError::Conflict(format!("job {id} is retried already")));
        }
        if let Some(store) = &self.store {
            store.reopen_job(id)?;
        }
        let rays = done.iter().fold(0u64, |a, t| a.saturating_add(t.1));
        st.sched.restore(
            Restored {
                id,
                spec: info.spec.clone(),
                state: JobState::Queued,
                submitted: now.checked_sub(info.elapsed).unwrap_or(now),
                elapsed: None,
                render: None,
                error: None,
                finish_order: 0,
                tiles_done: 0,
                rays,
                done_tiles: done.iter().map(|t| t.0).collect(),
            },
            now,
        );
        // Every tile kept: it failed finishing its output; finish it now.
        let complete = out.written == out.total;
        let out = Arc::new(Mutex::new(out));
        st.outputs.insert(id, out.clone());
        st.submitters.insert(id, who);
        st.publish(id);
        drop(st);
        tracing::info!(job = id, tiles_kept = done.len(), "job retried");
        if complete {
            if let Some(sink) = lock(&out).sink.take() {
                let result = sink.finish();
                self.end_job(
                    id,
                    result.map_err(|e| JobFailure::Output(format!("finishing the output: {e}"))),
                );
            }
        }
        self.work.notify_waiters();
        self.info(id)
    }
}
