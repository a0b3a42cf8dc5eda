//! How a job ends: done (its output finished), failed (a tile failed too
//! often, its bundle is damaged, its output could not be written) or
//! cancelled. An end is recorded in the database before anyone sees it;
//! a frame's end moves its sequence on (see `sequences.rs`).

use super::{lock, Farm};
use crate::error::FarmError;
use crate::scheduler::{JobFailure, JobId, JobInfo, JobState, Outcome};
use crate::store::{SeqLink, StoredJob, StoredPasses};
use std::time::Instant;

impl Farm {
    /// Fails every unfinished job rendering `bundle` with `why` (its stored
    /// copy is damaged or gone, so no worker can render them). Returns them.
    pub fn fail_bundle_jobs(&self, bundle: &str, why: &str) -> Vec<JobId> {
        let doomed: Vec<JobId> = self
            .list()
            .into_iter()
            .filter(|j| !j.state.is_final() && j.spec.bundle_hash == bundle)
            .map(|j| j.id)
            .collect();
        for &job in &doomed {
            self.end_job(job, Err(JobFailure::Bundle(why.to_string())));
        }
        doomed
    }

    /// Ends jobs whose tiles failed too often.
    pub(super) fn fail_jobs(&self, failed: Vec<(JobId, JobFailure)>) {
        for (job, why) in failed {
            self.end_job(job, Err(why));
        }
    }

    /// Ends a job. Its end is recorded in the database before anyone can
    /// see it, so what a client is told is what a restart finds. When the
    /// database does not take it (a full disk), the job stays as stored:
    /// unfinished, taking no more work; [`Farm::expire`] records the end
    /// later, and a restart meanwhile resumes the job from its stored tiles.
    pub(super) fn end_job(&self, job: JobId, mut result: Outcome) {
        let image = self.final_preview(job);
        // A pass of a progressive job: the frame's noise after it (read
        // before the lock: it may read the disk).
        let noise = if result.is_ok() {
            self.pass_noise(job)
        } else {
            None
        };
        let mut st = self.state.lock();
        let now = Instant::now();
        let Some(mut ending) = st.sched.finish_info(job, &result, now) else {
            return; // Over already (cancelled meanwhile).
        };
        // A frame of a sequence: its output joins the sequence's.
        let parent = st.parent_of.get(&job).copied();
        let mut seq_done = None;
        if let Some(seq) = parent {
            if result.is_ok() {
                if let Err(e) = self.file_frame(seq, job, &ending.spec) {
                    result = Err(JobFailure::Output(e.to_string()));
                    ending = st
                        .sched
                        .finish_info(job, &result, now)
                        .expect("checked above");
                }
            }
            if result.is_ok() {
                let done = st.seqs.get(&seq).map_or(0, |s| s.done) + 1;
                seq_done = Some((seq, done));
            }
        }
        // A pass done: its job's passes after it, recorded with the count.
        let passes = match (seq_done, ending.spec.samples) {
            (Some((seq, _)), Some(range)) => {
                st.seqs.get(&seq).and_then(|s| s.passes.as_ref()).map(|p| {
                    let mut p = p.clone();
                    p.samples_done = range.end;
                    p.error = noise.map(|n| n.relative_error());
                    p.noise.clear();
                    p.resize(range.end - range.start, ending.render());
                    p
                })
            }
            _ => None,
        };
        let stored = passes.as_ref().map(|p| p.stored());
        if let Err(e) = self.persist_frame_end(&ending, seq_done, stored.as_ref()) {
            if st.unrecorded.insert(job, result).is_none() {
                st.sched.hold(job);
                tracing::error!(job, error = %e,
                    "cannot record the end of the job; it stays unfinished until it is recorded");
            }
            return;
        }
        match &result {
            Ok(()) => tracing::info!(job, "job done"),
            Err(e) => tracing::error!(job, error = %e, "job failed"),
        }
        st.unrecorded.remove(&job);
        self.usage_ended(parent.unwrap_or(job), &ending);
        self.events.ended(job, &result);
        st.sched.finish(job, result, now);
        st.outputs.remove(&job);
        st.submitters.remove(&job);
        st.keep_final_preview(job, image, self.cfg.limits.kept_previews);
        if let Some(seq) = parent {
            if let (Some(p), Some(s)) = (passes, st.seqs.get_mut(&seq)) {
                s.passes = Some(p);
            }
            st.frame_ended(seq, job, &ending, seq_done.is_some());
            if seq_done.is_some() {
                self.events.frame_done(seq, ending.spec.frame)
            }
        }
        st.publish(job);
        drop(st);
        if let Some(seq) = parent {
            self.advance(seq);
        }
        self.release_waiters(job);
        self.prune();
    }

    /// Records a job's end in the database (and drops its tiles there).
    pub(super) fn persist_end(&self, info: &JobInfo) -> Result<(), FarmError> {
        self.persist_frame_end(info, None, None)
    }

    /// Like [`Farm::persist_end`], with a sequence's count of frames done
    /// and a progressive job's passes (see
    /// [`Store::finish_frame`](crate::store::Store::finish_frame)).
    pub(super) fn persist_frame_end(
        &self,
        info: &JobInfo,
        seq: Option<(JobId, u32)>,
        passes: Option<&StoredPasses>,
    ) -> Result<(), FarmError> {
        let Some(store) = &self.store else {
            return Ok(());
        };
        let j = StoredJob {
            id: info.id,
            spec: info.spec.clone(),
            state: info.state,
            submitted_ms: 0,
            elapsed: Some(info.elapsed),
            render: Some(info.elapsed.saturating_sub(info.queued)),
            error: info.error.clone(),
            finish_order: info.finish_order,
            tiles_done: info.tiles_done,
            rays: info.rays,
            seq: SeqLink {
                frames_done: info
                    .frames
                    .map(|f| f.done)
                    .or(info.passes.as_ref().map(|p| p.done))
                    .unwrap_or(0),
                ..SeqLink::default()
            },
        };
        store.finish_frame(&j, seq, passes)
    }

    /// Cancels a job: no more leases, workers drop theirs at the next
    /// heartbeat, and the partial output is removed.
    /// The cancellation is recorded first: when the database does not take
    /// it, the job goes on and the caller gets the error.
    pub fn cancel(&self, job: JobId) -> Result<JobInfo, FarmError> {
        if self.state.lock().seqs.contains_key(&job) {
            return self.cancel_sequence(job);
        }
        let image = self.final_preview(job);
        let mut st = self.state.lock();
        let now = Instant::now();
        if let Some(ending) = st.sched.cancel_info(job, now) {
            self.persist_end(&ending).map_err(|e| {
                FarmError::io(format!("cannot record the cancellation of job {job}"), e)
            })?;
            st.unrecorded.remove(&job);
            self.usage_ended(job, &ending);
        }
        let state = st.sched.cancel(job, now)?;
        st.submitters.remove(&job);
        let out = if state == JobState::Cancelled {
            st.outputs.remove(&job)
        } else {
            None
        };
        if out.is_some() {
            st.keep_final_preview(job, image, self.cfg.limits.kept_previews);
        }
        st.publish(job);
        drop(st);
        if let Some(out) = out {
            // Dropping an unfinished writer removes its temporary file.
            self.events.cancelled(job);
            lock(&out).close();
            let dir = self.cfg.data_dir.join("jobs").join(job.to_string());
            let _ = std::fs::remove_dir(dir);
            tracing::info!(job, "job cancelled");
            self.release_waiters(job);
            // What it became, even if the retention forgets it at once.
            let info = self.info(job);
            self.prune();
            return info;
        }
        self.info(job)
    }
}
