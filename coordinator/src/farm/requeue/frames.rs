//! Requeueing frames of a sequence (`requeue ID --frames A-B`) and
//! retrying a failed sequence (`retry ID`).
//!
//! A frame is rendered again as a new frame job of the sequence (its
//! `again` set, queued before the frames not reached yet); once done, its
//! file is renamed over the old one in the sequence's directory, so a
//! failure leaves the old file, and the file is the bytes of a fresh
//! render.
//!
//! - An ended sequence (done, failed or cancelled): frames A-B are
//!   rendered again, and so are the frames it had not finished (those
//!   before the last one queued whose file is missing: a failed or
//!   cancelled sequence's failed and cancelled frames); the frames never
//!   queued are queued as usual. Its count of frames done is those left.
//! - A running sequence: frames A-B already done are queued again; those in
//!   progress or not reached yet are rendered anyway.
//! - Retrying a failed (or cancelled) sequence is a requeue of no frame:
//!   the frames not done, keeping the done ones.
//!
//! A restart while a sequence renders frames again resumes its frames in
//! progress and then queues frames by its count of frames done, as for
//! any sequence: the frames chosen again may then be others (their files
//! are the same bytes; a frame whose file is missing can be requeued).

use super::super::Farm;
use crate::error::FarmError;
use crate::scheduler::{JobId, JobInfo, JobState};
use std::collections::BTreeSet;
use trevi_core::scene::animation::frame_output;
use trevi_core::Rect;

impl Farm {
    /// Requeues `frames` (all not done when `None`) of sequence `seq`.
    pub(super) fn requeue_frames(
        &self,
        seq: JobId,
        frames: Option<(u32, u32)>,
        rect: Option<Rect>,
    ) -> Result<JobInfo, FarmError> {
        if rect.is_some() {
            return Err(FarmError::Invalid(format!(
                "--rect patches a still; job {seq} is a sequence: requeue whole frames with \
                 --frames"
            )));
        }
        let (first, last, next, pattern, state) = {
            let st = self.state.lock();
            let s = st.seqs.get(&seq).ok_or(FarmError::UnknownJob(seq))?;
            (s.first, s.last, s.next, s.spec.output_name.clone(), s.state)
        };
        let Some((a, b)) = frames.or((state == JobState::Failed).then_some((1, 0))) else {
            return Err(FarmError::Invalid(format!(
                "job {seq} is a sequence: say which frames to render again with --frames A-B \
                 (its frames are {first}-{last})"
            )));
        };
        if a <= b && (a < first || b > last) {
            return Err(FarmError::Invalid(format!(
                "--frames {a}-{b} is not within job {seq}'s frames {first}-{last}"
            )));
        }
        // Frames to render again: those asked for and, of an ended
        // sequence, those queued before whose file is missing (looked for
        // before the lock: it reads the disk).
        let mut again: BTreeSet<u32> = (a..=b).collect();
        let missing: BTreeSet<u32> = if state.is_final() {
            (first..next.min(last.saturating_add(1)))
                .filter(|&f| !self.output_path(seq, &frame_output(&pattern, f)).is_file())
                .collect()
        } else {
            BTreeSet::new()
        };
        again.extend(&missing);
        let mut st = self.state.lock();
        let who = {
            let s = st.seqs.get(&seq).ok_or(FarmError::UnknownJob(seq))?;
            if s.state != state || s.next != next {
                return Err(FarmError::Conflict(format!(
                    "job {seq} changed meanwhile: try again"
                )));
            }
            s.spec.submitter.clone()
        };
        if state.is_final() {
            Self::check_submitter(&st, &who, self.cfg.limits.max_jobs_per_submitter)?;
        }
        let s = st.seqs.get_mut(&seq).expect("checked above");
        // Frames in progress, and those not reached yet, render anyway.
        again.retain(|f| *f < s.next && !s.running.contains_key(f) && !s.again.contains(f));
        if again.is_empty() && !state.is_final() {
            return Err(FarmError::Conflict(format!(
                "job {seq} has none of frames {a}-{b} done: they are rendering or queued already"
            )));
        }
        // Of those, the frames done (an ended sequence's missing ones are not).
        let redone = again.iter().filter(|f| !missing.contains(f)).count() as u32;
        let done = s.done.saturating_sub(redone);
        if let Some(store) = &self.store {
            store.requeue_frames(seq, done, state.is_final())?;
        }
        let n = again.len();
        s.done = done;
        s.again.extend(again);
        if state.is_final() {
            s.state = JobState::Queued;
            s.finished = None;
            s.error = None;
            s.failed = None;
            st.submitters.insert(seq, who);
            self.events.restored(seq);
        }
        st.publish(seq);
        drop(st);
        tracing::info!(job = seq, frames = n, "sequence frames requeued");
        self.advance(seq);
        self.info(seq)
    }

    /// Retries failed job `id`: a still with the tiles it finished
    /// (`retry.rs`), a sequence with the frames it finished.
    pub fn retry_job(&self, id: JobId) -> Result<JobInfo, FarmError> {
        let seq = {
            let st = self.state.lock();
            st.seqs.get(&id).map(|s| (s.passes.is_some(), s.state))
        };
        match seq {
            None => self.retry(id),
            Some((true, _)) => Err(FarmError::Conflict(format!(
                "job {id} is a progressive job: it cannot be retried (submit it again)"
            ))),
            Some((false, JobState::Failed)) => self.requeue_frames(id, None, None),
            Some((false, s)) => Err(FarmError::Conflict(format!(
                "job {id} is {}: retry takes a failed job",
                s.name()
            ))),
        }
    }
}
