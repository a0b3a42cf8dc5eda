//! How long ended jobs are kept ([`Retention`]) and the pruning that
//! forgets the ones it no longer keeps: from the database, from memory and
//! from the data directory.
//!
//! The count of `--keep-ended` is of jobs as their submitters see them: a
//! still or a sequence is one, whatever its frames (the frames' own ended
//! jobs hold no output, their frames being in the sequence's directory, and
//! are kept up to the same number apart, and never beyond their sequence).
//! An output that was never fetched is never removed by the count, only by
//! age (`--keep-ended-for`): one user's many jobs cannot delete another's
//! finished, unfetched output.

use super::{Farm, State};
use crate::scheduler::{JobId, JobState};
use std::collections::{HashMap, HashSet};
use std::time::{Duration, Instant};

/// How long ended jobs (done, failed, cancelled) are kept: their status,
/// their output and their row in the database. A job is forgotten when
/// either rule says so, except that the count never forgets an output no
/// one fetched; an unfinished job is never forgotten. Also how long a
/// bundle no job uses is kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Retention {
    /// Ended jobs kept at most (the newest by the time they ended), not
    /// counting outputs not fetched yet; a sequence is one job. At least 1.
    pub keep_ended: usize,
    /// Ended jobs are forgotten this long after they ended; `None`: never.
    /// At least [`MIN_KEEP_ENDED_FOR`], at most [`MAX_KEEP_ENDED_FOR`].
    pub keep_ended_for: Option<Duration>,
    /// A bundle no job uses is removed once it was last uploaded or used
    /// this long ago (see [`crate::bundles::BundleStore::collect`]).
    pub bundle_grace: Duration,
}

impl Default for Retention {
    fn default() -> Self {
        Retention {
            keep_ended: 1000,
            keep_ended_for: Some(Duration::from_secs(7 * 24 * 3600)),
            bundle_grace: Duration::from_secs(3600),
        }
    }
}

/// The shortest `--keep-ended-for`: an output must outlive the client
/// that waits for its job, to be fetched.
pub const MIN_KEEP_ENDED_FOR: Duration = Duration::from_secs(60);
/// The longest `--keep-ended-for` but `never`: ten years (a longer one is
/// a typo; `never` says it).
pub const MAX_KEEP_ENDED_FOR: Duration = Duration::from_secs(3650 * 86400);

/// Retention settings that make no sense.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BadRetention {
    /// `--keep-ended 0`.
    #[error("--keep-ended 0 would delete every output the moment its job ends; keep at least 1")]
    KeepNone,
    #[error(
        "--keep-ended-for {0} is shorter than the shortest, {min}: outputs would be deleted \
         before their submitters can fetch them",
        min = Retention::format_duration(Some(MIN_KEEP_ENDED_FOR))
    )]
    /// A `--keep-ended-for` below [`MIN_KEEP_ENDED_FOR`] (as given).
    TooShort(String),
    #[error(
        "--keep-ended-for {0} is longer than the longest, {max}; say `never` to keep ended \
         jobs until the count forgets them",
        max = Retention::format_duration(Some(MAX_KEEP_ENDED_FOR))
    )]
    /// A `--keep-ended-for` above [`MAX_KEEP_ENDED_FOR`] (as given).
    TooLong(String),
}

/// Ended jobs' retention bookkeeping: which outputs were fetched, and the
/// sequence and frame of each ended frame job.
#[derive(Debug, Default)]
pub(super) struct Ended {
    fetched: HashSet<JobId>,
    frames: HashMap<JobId, (JobId, u32)>,
}

impl Ended {
    /// Records that ended job `job` was frame `frame` of sequence `seq`.
    pub(super) fn frame(&mut self, job: JobId, seq: JobId, frame: u32) {
        self.frames.insert(job, (seq, frame));
    }

    /// The sequence and frame of an ended frame job.
    pub(super) fn frame_of(&self, job: JobId) -> Option<(JobId, u32)> {
        self.frames.get(&job).copied()
    }
}

/// A duration `--keep-ended-for` cannot read (the farm's grammar,
/// [`trevi_proto::duration`], or `never`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("\"{0}\" is not a duration like 90s, 30m, 12h, 7d or never")]
pub struct BadDuration(pub String);

impl Retention {
    /// Reads `--keep-ended-for`: a duration (`90m`, `7d`), or `never`.
    pub fn parse_duration(s: &str) -> Result<Option<Duration>, BadDuration> {
        if s.trim() == "never" {
            return Ok(None);
        }
        trevi_proto::duration::parse(s)
            .map(Some)
            .map_err(|_| BadDuration(s.trim().to_string()))
    }

    /// The inverse of [`Retention::parse_duration`] (the flag's default).
    pub fn format_duration(d: Option<Duration>) -> String {
        d.map_or_else(|| "never".into(), trevi_proto::duration::format)
    }

    /// Refuses settings that make no sense (see [`BadRetention`]).
    pub fn check(&self) -> Result<(), BadRetention> {
        if self.keep_ended == 0 {
            return Err(BadRetention::KeepNone);
        }
        match self.keep_ended_for {
            Some(d) if d < MIN_KEEP_ENDED_FOR => {
                Err(BadRetention::TooShort(Self::format_duration(Some(d))))
            }
            Some(d) if d > MAX_KEEP_ENDED_FOR => {
                Err(BadRetention::TooLong(Self::format_duration(Some(d))))
            }
            _ => Ok(()),
        }
    }
}

impl State {
    /// Whether ended job `id` holds an output no one fetched: a still that
    /// is done, a sequence with a frame done.
    fn unfetched(&self, id: JobId) -> bool {
        if self.ended.fetched.contains(&id) {
            return false;
        }
        match self.seqs.get(&id) {
            Some(s) => s.done > 0,
            None => self
                .sched
                .info(id, Instant::now())
                .is_some_and(|i| i.state == JobState::Done),
        }
    }

    /// The ended jobs `r` no longer keeps at `now`.
    fn doomed(&self, r: Retention, now: Instant) -> Vec<JobId> {
        let old = |ended: Instant| {
            r.keep_ended_for
                .is_some_and(|d| now.saturating_duration_since(ended) > d)
        };
        let (mut jobs, mut frames) = (0usize, 0usize);
        let mut doomed = Vec::new();
        let mut frame_jobs = Vec::new();
        for (id, ended) in self.ended() {
            if let Some((seq, _)) = self.ended.frame_of(id) {
                frame_jobs.push((id, ended, seq));
                continue;
            }
            jobs += 1;
            if old(ended) || (jobs > r.keep_ended && !self.unfetched(id)) {
                doomed.push(id);
            }
        }
        let gone: HashSet<JobId> = doomed.iter().copied().collect();
        for (id, ended, seq) in frame_jobs {
            frames += 1;
            if old(ended)
                || frames > r.keep_ended
                || gone.contains(&seq)
                || !self.seqs.contains_key(&seq)
            {
                doomed.push(id);
            }
        }
        doomed
    }
}

impl Farm {
    /// Records a download of `job`'s output (`frame` of a sequence): once
    /// a still's, or a sequence's last frame done (without a frame, that is
    /// the one sent), was fetched after it ended, the count of
    /// `--keep-ended` may forget it.
    pub fn fetched(&self, job: JobId, frame: Option<u32>) {
        let mut st = self.state.lock();
        let whole = match st.seqs.get(&job) {
            Some(s) => s.state.is_final() && (frame.is_none() || frame == s.latest.map(|l| l.0)),
            None => st
                .info(job, Instant::now())
                .is_some_and(|i| i.state.is_final()),
        };
        if whole {
            st.ended.fetched.insert(job);
        }
    }

    /// Forgets the ended jobs [`Retention`] no longer keeps: from the
    /// database first, then from memory, then their output directories.
    pub(super) fn prune(&self) {
        let r = self.cfg.retention;
        let now = Instant::now();
        let doomed = self.state.lock().doomed(r, now);
        if doomed.is_empty() {
            return;
        }
        if let Some(store) = &self.store {
            if let Err(e) = store.delete_jobs(&doomed) {
                tracing::warn!(error = %e, "cannot forget ended jobs; keeping them");
                return;
            }
        }
        {
            let mut st = self.state.lock();
            for id in &doomed {
                st.sched.remove(*id);
                st.seqs.remove(id);
                st.watchers.remove(id);
                st.ended.fetched.remove(id);
                st.ended.frames.remove(id);
            }
            st.final_previews.retain(|(j, _)| !doomed.contains(j));
        }
        for id in &doomed {
            let dir = self.cfg.data_dir.join("jobs").join(id.to_string());
            if let Err(e) = std::fs::remove_dir_all(&dir) {
                if e.kind() != std::io::ErrorKind::NotFound {
                    tracing::warn!(job = id, error = %e, "cannot remove {}", dir.display());
                }
            }
        }
        tracing::info!(jobs = doomed.len(), "ended jobs forgotten (retention)");
    }
}
