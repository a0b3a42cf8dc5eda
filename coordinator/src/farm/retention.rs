//! How long ended jobs are kept ([`Retention`]) and the pruning that
//! forgets the ones it no longer keeps: from the database, from memory and
//! from the data directory.

use super::Farm;
use crate::scheduler::JobId;
use std::time::{Duration, Instant};

/// How long ended jobs (done, failed, cancelled) are kept: their status,
/// their output and their row in the database. A job is forgotten when
/// either rule says so; an unfinished job is never forgotten. Also how long
/// a bundle no job uses is kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Retention {
    /// Ended jobs kept at most (the newest by the time they ended).
    pub keep_ended: usize,
    /// Ended jobs are forgotten this long after they ended; `None`: never.
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

/// A duration `--keep-ended-for` cannot read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("\"{0}\" is not a duration like 90s, 30m, 12h, 7d or never")]
pub struct BadDuration(pub String);

impl Retention {
    /// Reads `--keep-ended-for`: a whole number with `s`, `m`, `h` or `d`
    /// (`90m`, `7d`), or `never`.
    pub fn parse_duration(s: &str) -> Result<Option<Duration>, BadDuration> {
        let s = s.trim();
        if s == "never" {
            return Ok(None);
        }
        let bad = || BadDuration(s.to_string());
        let unit = match s.chars().last().ok_or_else(bad)? {
            's' => 1,
            'm' => 60,
            'h' => 3600,
            'd' => 86400,
            _ => return Err(bad()),
        };
        let n: u64 = s[..s.len() - 1].parse().map_err(|_| bad())?;
        Ok(Some(Duration::from_secs(
            n.checked_mul(unit).ok_or_else(bad)?,
        )))
    }

    /// The inverse of [`Retention::parse_duration`] (the flag's default).
    pub fn format_duration(d: Option<Duration>) -> String {
        let Some(d) = d else {
            return "never".into();
        };
        let s = d.as_secs();
        for (unit, n) in [("d", 86400), ("h", 3600), ("m", 60)] {
            if s > 0 && s % n == 0 {
                return format!("{}{unit}", s / n);
            }
        }
        format!("{s}s")
    }
}

impl Farm {
    /// Forgets the ended jobs [`Retention`] no longer keeps: from the
    /// database first, then from memory, then their output directories.
    pub(super) fn prune(&self) {
        let r = self.cfg.retention;
        let now = Instant::now();
        let doomed: Vec<JobId> = self
            .state
            .lock()
            .ended()
            .into_iter()
            .enumerate()
            .filter(|&(i, (_, ended))| {
                i >= r.keep_ended
                    || r.keep_ended_for
                        .is_some_and(|d| now.saturating_duration_since(ended) > d)
            })
            .map(|(_, (id, _))| id)
            .collect();
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
