//! Where the usage history is fed and read (see [`crate::usage`]): each
//! accepted result counted under its hour, job (as its submitter sees it),
//! submitter and worker ([`Farm::count_usage`]); each job's wall time at
//! its end ([`Farm::usage_ended`]); what was gathered flushed to the
//! database ([`Farm::flush_usage`], by the upkeep and before each query);
//! and the queries ([`Farm::usage`]).

use super::Farm;
use crate::error::FarmError;
use crate::scheduler::{JobId, JobInfo, WorkerId};
use crate::store::wall_ms;
use crate::usage::{
    submitter_label, worker_label, JobWall, Usage, UsageAgg, UsageKey, UsageQuery, UsageReport,
    HOUR_MS,
};

/// The usage history of a farm: in the store's database (`durable`), or in
/// an in-memory database with the same tables.
pub(super) fn history(durable: bool) -> Result<Usage, FarmError> {
    if durable {
        return Ok(Usage::new(None));
    }
    let conn = rusqlite::Connection::open_in_memory()
        .and_then(|c| crate::store::usage_tables(&c).map(|()| c))
        .map_err(|e| FarmError::io("usage history", e))?;
    Ok(Usage::new(Some(conn)))
}

impl Farm {
    /// Counts an accepted result of `tiles` tiles of `job` from `worker`:
    /// `cpu_micros` as the worker said (`None`: it did not), and its rays.
    pub fn count_usage(
        &self,
        job: JobId,
        worker: WorkerId,
        cpu_micros: Option<u64>,
        tiles: u64,
        rays: u64,
    ) {
        let now = wall_ms();
        let key = {
            let st = self.state.lock();
            // A frame's (or a pass's) sequence; its last tile ends it, so
            // it may be an ended frame by now.
            let shown = st
                .parent_of
                .get(&job)
                .copied()
                .or_else(|| st.ended.frame_of(job).map(|(seq, _)| seq))
                .unwrap_or(job);
            let Some((submitter, name)) = st.sched.usage_owner(job, worker) else {
                return;
            };
            UsageKey {
                hour_ms: now - now % HOUR_MS,
                job: shown,
                submitter: submitter_label(submitter).to_string(),
                worker: worker_label(name, worker),
            }
        };
        if self
            .usage
            .add(key, UsageAgg::result(cpu_micros, tiles, rays))
        {
            self.flush_usage();
        }
    }

    /// Records the wall time of `info`, a job that just ended (a frame or
    /// a pass under its sequence's id).
    pub(super) fn usage_ended(&self, shown: JobId, info: &JobInfo) {
        // Never leased (cancelled in the queue): no wall time to speak of.
        if info.tiles_done == 0 && info.elapsed <= info.queued {
            return;
        }
        let ended_ms = wall_ms();
        let wall = info.elapsed.saturating_sub(info.queued).as_millis() as u64;
        self.usage.ended(JobWall {
            job: shown,
            submitter: submitter_label(&info.spec.submitter).to_string(),
            started_ms: ended_ms.saturating_sub(wall),
            ended_ms,
        });
    }

    /// Writes what was gathered to the database (the store's, or the one in
    /// memory), first deleting what is past `--usage-retention`; on an
    /// error it is kept for the next try.
    pub fn flush_usage(&self) {
        if let Err(e) = self.try_flush_usage(false) {
            tracing::error!(error = %e, "cannot write the usage history; kept for the next try");
        }
    }

    /// `force`: also when nothing waits (the retention is applied then too).
    fn try_flush_usage(&self, force: bool) -> Result<(), FarmError> {
        let (_guard, pending) = self.usage.take();
        if pending.is_empty() && !force {
            return Ok(());
        }
        let l = &self.cfg.limits;
        let cutoff = wall_ms().saturating_sub(l.usage_retention.as_millis() as u64);
        let written = match (&self.store, &self.usage.memory) {
            (Some(store), _) => store.add_usage(&pending, l.max_usage_rows, cutoff),
            (None, Some(mem)) => {
                let mut conn = mem.lock().unwrap_or_else(|p| p.into_inner());
                crate::store::add_usage(&mut conn, &pending, l.max_usage_rows, cutoff)
                    .map_err(|e| FarmError::io("usage history", e))
            }
            (None, None) => Ok(0),
        };
        match written {
            Ok(0) => Ok(()),
            Ok(evicted) => {
                tracing::warn!(
                    evicted,
                    max = l.max_usage_rows,
                    "usage history full (--max-usage-rows): its oldest rows were deleted"
                );
                Ok(())
            }
            Err(e) => {
                self.usage.put_back(pending);
                Err(e)
            }
        }
    }

    /// Answers a usage query (what was gathered is flushed first).
    pub fn usage(&self, q: &UsageQuery) -> Result<UsageReport, FarmError> {
        self.try_flush_usage(true)?;
        let now = wall_ms();
        match (&self.store, &self.usage.memory) {
            (Some(store), _) => store.query_usage(q, now),
            (None, Some(mem)) => {
                let conn = mem.lock().unwrap_or_else(|p| p.into_inner());
                crate::store::query_usage(&conn, q, now)
                    .map_err(|e| FarmError::io("usage history", e))
            }
            (None, None) => Ok(UsageReport::default()),
        }
    }
}
