//! The per-tile log, the farm's side: a lease rendered
//! ([`Farm::log_rendered`], from the upload's header) or failed (the
//! scheduler's [`TileFault`]s, taken after every call that can fail a
//! lease) becomes an entry of its user job's log in the database
//! ([`crate::store::LogEntry`]; a frame's or a pass's under its sequence,
//! with its frame or pass), and [`Farm::tile_log`] reads it back. Failures
//! that keep a worker from a job are stored as blocks too (see `blocks.rs`).
//! A coordinator without a database (`durable` off) keeps no log.

use super::Farm;
use crate::error::FarmError;
use crate::scheduler::{JobId, TileFault, WorkerId};
use crate::store::{wall_ms, JobLog, LogBounds, LogEntry, LogFilter, StoredBlock};
use std::collections::BTreeMap;
use trevi_core::tile::Rect;

/// A lease whose result the farm accepted, for [`Farm::log_rendered`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RenderedLease {
    /// The tiles' job (a frame's or a pass's own job).
    pub job: JobId,
    /// The worker that rendered it.
    pub worker: WorkerId,
    /// Its pixels, and how many tiles they are.
    pub rect: Rect,
    /// See `rect`.
    pub tiles: u32,
    /// Rays traced.
    pub rays: u64,
    /// The render time the worker reported.
    pub render_micros: Option<u64>,
    /// The CPU time the worker reported, if it reports one.
    pub cpu_micros: Option<u64>,
}

impl Farm {
    /// The log's bounds per job (`--tile-log-entries`, `--tile-log-error-kib`).
    fn log_bounds(&self) -> LogBounds {
        let l = &self.cfg.limits;
        LogBounds {
            entries: u64::from(l.tile_log_entries.max(1)),
            error_bytes: l.tile_log_error_bytes.max(1),
        }
    }

    /// The user job `job` logs under (itself, or its sequence), and its
    /// frame and pass; `None` for a job the scheduler does not hold.
    fn log_place(
        &self,
        st: &super::State,
        job: JobId,
    ) -> Option<(JobId, Option<u32>, Option<u32>)> {
        let spec = st.sched.spec_of(job)?;
        let user = st.parent_of.get(&job).copied().unwrap_or(job);
        Some((user, spec.frame, spec.samples.map(|s| s.pass)))
    }

    /// Logs a lease the farm accepted. A log the database does not take
    /// is not worth failing the tile for: it is only warned about.
    pub fn log_rendered(&self, r: &RenderedLease) {
        let Some(store) = &self.store else {
            return;
        };
        let (user, entry) = {
            let st = self.state.lock();
            let Some((user, frame, pass)) = self.log_place(&st, r.job) else {
                return;
            };
            let entry = LogEntry {
                at_ms: wall_ms(),
                worker: r.worker,
                worker_name: st.sched.worker_name(r.worker),
                frame,
                pass,
                rect: r.rect,
                tiles: r.tiles,
                render_micros: r.render_micros,
                cpu_micros: r.cpu_micros,
                rays: r.rays,
                retries: 0,
                error: None,
            };
            (user, entry)
        };
        if let Err(e) = store.log_append(user, &[entry], self.log_bounds()) {
            tracing::warn!(job = user, error = %e, "the tile log did not take an entry");
        }
    }

    /// Logs the leases that failed since the last call (the scheduler's
    /// faults), and stores the blocks they made.
    pub(super) fn log_faults(&self) {
        let Some(store) = &self.store else {
            // Nothing keeps them: the scheduler holds no more than its cap.
            self.state.lock().sched.take_faults();
            return;
        };
        let mut by_job: BTreeMap<JobId, Vec<LogEntry>> = BTreeMap::new();
        let mut blocks = Vec::new();
        {
            let mut st = self.state.lock();
            let faults: Vec<TileFault> = st.sched.take_faults();
            let now = wall_ms();
            for f in faults {
                let Some((user, frame, pass)) = self.log_place(&st, f.job) else {
                    continue;
                };
                if f.blocked {
                    blocks.push(StoredBlock {
                        job: f.job,
                        name: f.name.clone(),
                        failures: f.failures,
                        last_error: f.cause.clone(),
                    });
                }
                by_job.entry(user).or_default().push(LogEntry {
                    at_ms: now,
                    worker: f.worker,
                    worker_name: f.name,
                    frame,
                    pass,
                    rect: f.rect,
                    tiles: 1,
                    render_micros: None,
                    cpu_micros: None,
                    rays: 0,
                    retries: 0,
                    error: Some(f.cause),
                });
            }
        }
        for (job, entries) in by_job {
            if let Err(e) = store.log_append(job, &entries, self.log_bounds()) {
                tracing::warn!(job, error = %e, "the tile log did not take the failures");
            }
        }
        for b in blocks {
            if let Err(e) = store.set_block(&b) {
                tracing::warn!(job = b.job, error = %e, "a block was not stored");
            }
        }
    }

    /// Job `job`'s tile log as `filter` picks it. A frame's or a pass's
    /// own job id names its sequence's log, that frame's entries.
    pub fn tile_log(&self, job: JobId, filter: LogFilter) -> Result<JobLog, FarmError> {
        let (user, filter) = {
            let st = self.state.lock();
            if st.info(job, std::time::Instant::now()).is_none() {
                return Err(FarmError::UnknownJob(job));
            }
            match st.parent_of.get(&job) {
                Some(&seq) => {
                    let frame = st.sched.spec_of(job).and_then(|s| s.frame);
                    (
                        seq,
                        LogFilter {
                            frame: frame.or(filter.frame),
                            ..filter
                        },
                    )
                }
                None => (job, filter),
            }
        };
        let Some(store) = &self.store else {
            return Err(FarmError::Conflict(
                "this coordinator keeps no database, where the tile log is kept".into(),
            ));
        };
        store.tile_log(user, &filter)
    }
}
