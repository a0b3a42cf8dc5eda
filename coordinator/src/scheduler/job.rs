//! A job as the scheduler keeps it: its spec, its tiles' band window, its
//! progress, and the failures and past leases of its tiles and workers.

use super::lease_table::LeaseEntry;
use super::types::{JobId, JobSpec, JobState, LeaseId};
use super::window::BandWindow;
use crate::workers::WorkerId;
use std::collections::HashMap;
use std::time::Instant;

/// A job: its spec, its tiles' [`BandWindow`], its progress and the
/// failures of its tiles and workers.
pub(super) struct Job {
    pub(super) spec: JobSpec,
    pub(super) state: JobState,
    pub(super) window: BandWindow,
    pub(super) done: u64,
    pub(super) rays: u64,
    pub(super) submitted: Instant,
    /// When its first tile was leased.
    pub(super) started: Option<Instant>,
    pub(super) finished: Option<Instant>,
    pub(super) error: Option<String>,
    pub(super) finish_order: u64,
    /// Failures of tiles not done yet: how many, how many of them were
    /// lost workers, and the last cause.
    pub(super) failures: HashMap<u32, (u32, u32, String)>,
    /// Failures per worker on this job.
    pub(super) worker_failures: HashMap<WorkerId, u32>,
    /// What each worker that failed here said last (see `blocks.rs`).
    pub(super) worker_errors: HashMap<WorkerId, String>,
    /// Blocks read back from the database, by worker name, not yet
    /// matched to a worker registered since (see `blocks.rs`).
    pub(super) restored_blocks: HashMap<String, (u32, String)>,
    /// Leases that ran out or were refused while their tile is not done
    /// yet: a late result under one of them still counts.
    pub(super) past_leases: HashMap<LeaseId, (u32, WorkerId)>,
    /// Out of the queue (paused, or waiting for other jobs; see
    /// `parking.rs`): none of its tiles are leased.
    pub(super) parked: bool,
}

impl Job {
    /// Who holds tile `idx` of this job (`job`) under lease `id`: the
    /// worker of `live` (the lease table's entry for `id`) when it is that
    /// tile's, else the worker of a lease that ran out or was refused while
    /// the tile stayed undone (a late result under it still counts).
    pub(super) fn holder(
        &self,
        job: JobId,
        idx: u32,
        id: LeaseId,
        live: Option<LeaseEntry>,
    ) -> Option<WorkerId> {
        match live {
            Some(e) if e.job == job && e.tile == idx => Some(e.worker),
            _ => self
                .past_leases
                .get(&id)
                .filter(|(t, _)| *t == idx)
                .map(|&(_, w)| w),
        }
    }

    /// Marks a tile done: it has no failures or past leases any more.
    pub(super) fn set_done(&mut self, idx: u32) {
        self.window.set_done(idx);
        self.failures.remove(&idx);
        self.past_leases.retain(|_, (t, _)| *t != idx);
    }

    /// Drops the bookkeeping only a running job needs.
    pub(super) fn retire(&mut self) {
        self.window.retire();
        self.failures = HashMap::new();
        self.worker_failures = HashMap::new();
        self.worker_errors = HashMap::new();
        self.restored_blocks = HashMap::new();
        self.past_leases = HashMap::new();
    }
}
