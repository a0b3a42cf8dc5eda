//! Job control: a job paused and resumed by a user
//! ([`Farm::pause`], [`Farm::resume`]), and a job that waits for others to
//! be done before it starts (`SubmitOptions::after`, `--after`).
//!
//! Both are a *hold* on a job as users see it (a still, a sequence or a
//! progressive job), kept by id in the farm's state and in the database
//! (`store/holds.rs`) before it takes effect. A held job's scheduler jobs
//! (a still itself, a sequence's frames or passes in progress, and those
//! queued while it is held) are *parked* (`scheduler/parking.rs`): none of
//! their tiles are leased, and their tiles done, stored and stitched stay
//! as they are, so a resumed job continues where it stopped and its output
//! is the bytes of a render never paused. A restart reads the holds back
//! before anything is queued.
//!
//! Waiting: a job names the jobs it waits for when it is submitted; they
//! must exist then, so a job can only wait for jobs submitted before it
//! and no cycle can form (nor can a job wait for itself: its id is given
//! after the check). When one of them is done it is struck off the list;
//! when the list is empty (and the job is not paused) the job is queued.
//! When one fails or is cancelled, the waiting job fails naming it and its
//! cause, and so does, in turn, every job waiting for that one.

use super::{Farm, State};
use crate::error::FarmError;
use crate::scheduler::{JobFailure, JobId, JobInfo, JobState, FRAME_IDS};
use crate::store::StoredHold;
use std::time::Instant;

/// Most jobs one submission may wait for (`--after`).
pub const MAX_AFTER: usize = 64;

/// Why a job is held: paused, and the jobs it still waits for.
pub type Hold = StoredHold;

/// What a submission's options give the user job it makes (a still, a
/// sequence or a progressive job), applied under the state lock that gives
/// it its id: the hold it starts under (`--after`), so no tile of it can be
/// leased before it is held, and its own event URLs (`--notify`), so no
/// event of it goes out before they are known.
#[derive(Debug, Default)]
pub(super) struct Incoming {
    pub(super) hold: Option<Hold>,
    pub(super) notify: Vec<String>,
}

impl State {
    /// The scheduler jobs user job `id` runs as: a sequence's frames (or
    /// passes) in progress, or the job itself.
    fn runs(&self, id: JobId) -> Vec<JobId> {
        match self.seqs.get(&id) {
            Some(s) => s.running.values().copied().collect(),
            None => vec![id],
        }
    }

    /// Whether user job `id` is held (paused or waiting).
    pub(super) fn held(&self, id: JobId) -> bool {
        self.holds.get(&id).is_some_and(Hold::holds)
    }

    /// Parks or unparks `id`'s scheduler jobs as its hold says; with
    /// `return_leases` a parked job's tiles out are re-queued at once.
    fn apply_hold(&mut self, id: JobId, return_leases: bool) {
        let held = self.held(id);
        for run in self.runs(id) {
            // A run that ended meanwhile is over: nothing to park.
            let _ = if held {
                self.sched.park(run, return_leases).map(drop)
            } else {
                self.sched.unpark(run)
            };
        }
    }

    /// Adds the hold of user job `id` to its status (unfinished only).
    pub(super) fn show_hold(&self, id: JobId, info: &mut JobInfo) {
        if let Some(h) = self.holds.get(&id).filter(|_| !info.state.is_final()) {
            info.paused = h.paused;
            info.waiting_for = h.after.clone();
        }
    }

    /// New user job `id` (a still, a sequence or a progressive job) takes
    /// the hold `incoming` brings, if any: recorded in the database, then
    /// in the state (neither when the database refuses it).
    pub(super) fn hold_incoming(
        &mut self,
        id: JobId,
        incoming: &Incoming,
        store: Option<&crate::store::Store>,
    ) -> Result<(), FarmError> {
        let Some(hold) = &incoming.hold else {
            return Ok(());
        };
        if let Some(store) = store {
            store.set_hold(id, hold)?;
        }
        self.holds.insert(id, hold.clone());
        Ok(())
    }

    /// Parks new scheduler job `id` when its user job (itself, or the
    /// sequence `parent` it is a frame or pass of) is held.
    pub(super) fn park_if_held(&mut self, id: JobId, parent: Option<JobId>) {
        if self.held(parent.unwrap_or(id)) {
            let _ = self.sched.park(id, false);
        }
    }

    /// The user job `id` names, for a control request: known, not a frame
    /// or pass of another, not over.
    fn controllable(&self, id: JobId, now: Instant) -> Result<JobInfo, FarmError> {
        if let Some(seq) = self.parent_of.get(&id) {
            return Err(FarmError::Conflict(format!(
                "job {id} is a part of job {seq}: control job {seq}"
            )));
        }
        let info = self.info(id, now).ok_or(FarmError::UnknownJob(id))?;
        if id >= FRAME_IDS && !self.seqs.contains_key(&id) {
            return Err(FarmError::Conflict(format!(
                "job {id} is a part of a sequence or progressive job: control that job"
            )));
        }
        if info.state.is_final() || self.unrecorded.contains_key(&id) {
            return Err(FarmError::JobOver(id));
        }
        Ok(info)
    }
}

impl Farm {
    /// Records `hold` as job `id`'s, in the database first.
    fn store_hold(&self, st: &mut State, id: JobId, hold: Hold) -> Result<(), FarmError> {
        if let Some(store) = &self.store {
            store.set_hold(id, &hold)?;
        }
        if hold.holds() {
            st.holds.insert(id, hold);
        } else {
            st.holds.remove(&id);
        }
        Ok(())
    }

    /// Pauses job `id` (a still, a sequence or a progressive job): none of
    /// its tiles are leased until [`Farm::resume`]. Its tiles out finish,
    /// or with `now` are re-queued at once (their workers drop them at
    /// their next heartbeat, as for a cancel). Pausing a paused job again
    /// changes nothing but, with `now`, returns the tiles still out.
    pub fn pause(&self, id: JobId, now: bool) -> Result<JobInfo, FarmError> {
        let mut st = self.state.lock();
        st.controllable(id, Instant::now())?;
        let mut hold = st.holds.get(&id).cloned().unwrap_or_default();
        let newly = !hold.paused;
        if newly {
            hold.paused = true;
            self.store_hold(&mut st, id, hold)?;
        }
        st.apply_hold(id, now);
        st.publish(id);
        if newly {
            // Under the farm lock, as every event: in order with the job's others.
            self.events.paused(id);
        }
        drop(st);
        tracing::info!(job = id, now, "job paused");
        self.info(id)
    }

    /// Resumes paused job `id`: its tiles are leased again (unless it still
    /// waits for other jobs). Refused for a job that is not paused.
    pub fn resume(&self, id: JobId) -> Result<JobInfo, FarmError> {
        let mut st = self.state.lock();
        st.controllable(id, Instant::now())?;
        let mut hold = st.holds.get(&id).cloned().unwrap_or_default();
        if !hold.paused {
            return Err(FarmError::Conflict(format!("job {id} is not paused")));
        }
        hold.paused = false;
        self.store_hold(&mut st, id, hold)?;
        st.apply_hold(id, false);
        st.publish(id);
        self.events.resumed(id);
        drop(st);
        tracing::info!(job = id, "job resumed");
        self.work.notify_waiters();
        self.info(id)
    }

    /// Checks the jobs a submission is to wait for: at most [`MAX_AFTER`],
    /// each a job (a still, a sequence or a progressive job) that exists,
    /// so submitted before this one. Returns them without repeats.
    pub fn check_after(&self, after: &[JobId]) -> Result<Vec<JobId>, FarmError> {
        if after.len() > MAX_AFTER {
            return Err(FarmError::Invalid(format!(
                "--after names {} jobs; a job may wait for at most {MAX_AFTER}",
                after.len()
            )));
        }
        let st = self.state.lock();
        let now = Instant::now();
        let mut ids = Vec::with_capacity(after.len());
        for &id in after {
            if st.parent_of.contains_key(&id) || (id >= FRAME_IDS && !st.seqs.contains_key(&id)) {
                return Err(FarmError::Invalid(format!(
                    "--after {id}: that is a part of a sequence or progressive job; wait for \
                     that job"
                )));
            }
            if st.info(id, now).is_none() {
                return Err(FarmError::Invalid(format!(
                    "--after {id}: no job {id} (a job can only wait for jobs submitted before \
                     it, so no cycle can form)"
                )));
            }
            if !ids.contains(&id) {
                ids.push(id);
            }
        }
        Ok(ids)
    }

    /// What a submission's `after` and `notify` give its job, checked
    /// ([`Farm::check_after`]) before anything is queued: a job that waits
    /// for others is held from the moment it has an id, and queued once
    /// they are all done ([`Farm::settle_incoming`]).
    pub(super) fn incoming(
        &self,
        after: &[JobId],
        notify: Vec<String>,
    ) -> Result<Incoming, FarmError> {
        let after = self.check_after(after)?;
        Ok(Incoming {
            hold: (!after.is_empty()).then_some(Hold {
                paused: false,
                after,
            }),
            notify,
        })
    }

    /// A job just submitted with a hold from `--after`: if one of the jobs
    /// it waits for has ended meanwhile, it moves on now (queued, or failed
    /// naming it). Returns its status after that.
    pub(super) fn settle_incoming(&self, info: JobInfo, waits: bool) -> Result<JobInfo, FarmError> {
        if !waits {
            return Ok(info);
        }
        self.check_waiting(info.id);
        self.info(info.id)
    }

    /// Job `ended` has ended: the jobs that wait for it move on (struck
    /// off, queued, or failed naming it), and its own hold is dropped.
    /// Iterative: a chain of failures fails one job after the other
    /// without recursing.
    pub(super) fn release_waiters(&self, ended: JobId) {
        let mut st = self.state.lock();
        if st.holds.remove(&ended).is_some() {
            if let Some(store) = &self.store {
                if let Err(e) = store.set_hold(ended, &Hold::default()) {
                    tracing::error!(job = ended, error = %e, "cannot drop the hold of an ended job");
                }
            }
        }
        st.ended_deps.push(ended);
        // Mid-restart, or another call is draining: that one (or the
        // restart's check of every hold) takes it.
        if st.restoring || st.draining {
            return;
        }
        st.draining = true;
        while let Some(dep) = st.ended_deps.pop() {
            let waiters: Vec<JobId> = st
                .holds
                .iter()
                .filter(|(_, h)| h.after.contains(&dep))
                .map(|(&w, _)| w)
                .collect();
            drop(st);
            for w in waiters {
                self.check_waiting(w);
            }
            st = self.state.lock();
        }
        st.draining = false;
    }

    /// Looks at what job `id` waits for: strikes off the jobs done, queues
    /// it when none is left (and it is not paused), fails it when one
    /// failed, was cancelled, or is forgotten.
    pub(super) fn check_waiting(&self, id: JobId) {
        let now = Instant::now();
        let mut st = self.state.lock();
        let Some(hold) = st.holds.get(&id).cloned() else {
            return;
        };
        if st.info(id, now).is_none_or(|i| i.state.is_final()) {
            let _ = self.store_hold(&mut st, id, Hold::default());
            return;
        }
        if st.unrecorded.contains_key(&id) {
            return; // Ended, its end not recorded yet: it takes no work.
        }
        let mut left = Vec::with_capacity(hold.after.len());
        let mut failed = None;
        for &dep in &hold.after {
            let why = match st.info(dep, now) {
                Some(i) if i.state == JobState::Done => continue,
                Some(i) if !i.state.is_final() => {
                    left.push(dep);
                    continue;
                }
                Some(i) if i.state == JobState::Cancelled => "was cancelled".to_string(),
                Some(i) => format!("failed: {}", i.error.unwrap_or_default()),
                None => "is no longer known (forgotten after it ended)".to_string(),
            };
            failed.get_or_insert(format!("job {dep}, which this job waited for, {why}"));
        }
        if left == hold.after && failed.is_none() {
            return;
        }
        let after = if failed.is_some() { Vec::new() } else { left };
        let next = Hold {
            paused: hold.paused && failed.is_none(),
            after,
        };
        if let Err(e) = self.store_hold(&mut st, id, next) {
            // The hold stays as it was; a later end or a restart checks it
            // again.
            tracing::error!(job = id, error = %e, "cannot record what the job waits for");
            return;
        }
        match failed {
            None => {
                st.apply_hold(id, false);
                st.publish(id);
                drop(st);
                self.work.notify_waiters();
            }
            Some(why) => {
                tracing::warn!(job = id, why = %why, "a job it waited for did not finish");
                match st.seqs.get_mut(&id) {
                    // Fails it and cancels its frames, at its next step.
                    Some(s) => {
                        s.failed.get_or_insert(why);
                        drop(st);
                        self.advance(id);
                    }
                    None => {
                        drop(st);
                        self.end_job(id, Err(JobFailure::After(why)));
                    }
                }
            }
        }
    }

    /// After a restart: the stored holds are read back (before any job is
    /// queued, so a held job's tiles are never leased).
    pub(super) fn load_holds(&self) -> Result<(), FarmError> {
        let Some(store) = &self.store else {
            return Ok(());
        };
        let holds = store.holds()?;
        let mut st = self.state.lock();
        st.restoring = true;
        st.holds.extend(holds);
        Ok(())
    }

    /// After a restart, once every job is back: each hold is looked at
    /// again (a job it waited for may have ended just before the restart,
    /// or while it was restored; a job that ended drops its hold).
    pub(super) fn recheck_holds(&self) {
        let ids: Vec<JobId> = {
            let mut st = self.state.lock();
            st.restoring = false;
            st.ended_deps.clear();
            st.holds.keys().copied().collect()
        };
        for id in ids {
            self.check_waiting(id);
        }
    }
}
