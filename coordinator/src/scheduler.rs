//! The job queue and the tile leases: pure bookkeeping, no I/O, and time is
//! passed in, so every rule can be unit-tested without a network or a clock.
//!
//! Rules:
//! - Jobs run by priority (higher first), then in submission order; several
//!   jobs run at once when the first cannot use an idle worker.
//! - A job's tiles are leased in band order (top band first), and never
//!   further ahead of the first band that is not complete than the job's
//!   window (`Limits::window_bytes`) allows, counting a band leased as
//!   floats at 12 bytes a pixel and one leased only as encoded PNG segments
//!   at the encoder's worst case (see `scheduler/window.rs`), so the
//!   stitcher holds a bounded number of bytes whatever the height.
//! - A worker that takes spans gets several tiles in one lease: adjacent
//!   tiles of one band, or whole full-width bands, several while they are
//!   wholly pending; whole bands of a PNG frame that are whole 16-row
//!   segments go to a worker with the coordinator's encoder as a segment
//!   lease ([`Lease::png_segments`]); see [`lease_size`].
//! - A lease lives `lease_ttl` past its last heartbeat; an expired lease puts
//!   its tile back in the queue (ahead of later tiles of the same job).
//! - The first valid result for a tile wins; later and duplicate results are
//!   ignored. An invalid result re-queues the tile at once.
//! - A tile that fails too often fails its job, naming the tile: after
//!   `max_tile_failures` failures of any kind, or sooner, after
//!   `max_tile_losses` times its lease ran out (the worker holding it crashed,
//!   hung or was cut off), so a tile that kills every worker that takes it
//!   cannot keep its job running for ever. A lease the worker gives back
//!   without an error (it is stopping) re-queues the tile and counts nothing.
//!
//! Where each part lives:
//! - `scheduler/types.rs`: the values (jobs, leases, states, errors,
//!   counters);
//! - `scheduler/job.rs`: a job as the scheduler keeps it;
//! - `scheduler/jobs.rs`: where a job is submitted, restored, reprioritised
//!   and ended;
//! - `scheduler/lease.rs`: where a lease is granted, and what it covers;
//! - `scheduler/parking.rs`: where a job is taken out of the queue (paused,
//!   or waiting for other jobs) and put back;
//! - `scheduler/expiry.rs`: where an expired lease is re-queued, and the
//!   failure rules; `scheduler/blocks.rs`: the workers kept from a job, and
//!   unblocking one;
//! - `scheduler/results.rs`: where a tile result is accepted
//!   (`scheduler/whole_span.rs` for a span taken whole);
//! - `scheduler/report.rs`: where job status is reported (job info, lists,
//!   counters, workers);
//! - `scheduler/window.rs`, `scheduler/lease_size.rs`,
//!   `scheduler/lease_table.rs`, `scheduler/memory.rs`: a job's band
//!   window, how big a lease is, the table of live leases, and which
//!   workers can hold which jobs.
//!
//! This file holds the [`Scheduler`] itself and the workers' registration.

mod blocks;
mod expiry;
mod failure;
mod job;
mod jobs;
mod lease;
pub mod lease_size;
mod lease_table;
pub mod memory;
mod parking;
mod report;
mod results;
mod types;
mod whole_span;
mod window;

pub use crate::workers::WorkerId;
pub use blocks::{describe as describe_blocked, Blocked, TileFault, MAX_PENDING_FAULTS};
pub use failure::{JobFailure, Outcome};
pub use results::ray_shares;
pub use types::{
    Accepted, Counters, FramesInfo, JobId, JobInfo, JobSpec, JobState, Lease, LeaseId, PassesInfo,
    QueueDepth, Restored, SampleRange, SchedError, StopReason, FRAME_IDS,
};
pub use whole_span::SpanCheck;
pub use window::{
    band_bytes, encoded_rows_bound, encoder_bytes, segment_band_bytes, ENCODER_ROWS,
    SEGMENT_FRAMING_BYTES, TILE_BOOKKEEPING_BYTES,
};

use crate::limits::Limits;
use crate::workers::Workers;
use job::Job;
use lease_size::LeaseSizer;
use lease_table::LeaseTable;
use memory::MemoryGate;
use std::cmp::Reverse;
use std::collections::{BTreeSet, HashMap};
use std::time::Instant;

/// For the scheduler's tests: a still of `width` × `height` in tiles of
/// `tile`, written to `output` (its extension picks the format), of bundle
/// "h" and camera "c", priority 0. Tests that need other fields override
/// them with `..test_spec(…)`.
#[cfg(test)]
pub(crate) fn test_spec(width: u32, height: u32, tile: u32, output: &str) -> JobSpec {
    JobSpec {
        bundle_hash: "h".into(),
        camera: "c".into(),
        priority: 0,
        width,
        height,
        tile_size: tile,
        output_name: output.into(),
        frame: None,
        scene: "scene.xml".into(),
        submitter: String::new(),
        samples: None,
        aovs: trevi_core::Aovs::NONE,
    }
}

/// A scheduler for tests: leases live 5 s, the window has room for any
/// test frame, and `limits` gives the rest (`Limits::default()` for none).
#[cfg(test)]
pub(crate) fn test_scheduler(limits: Limits) -> Scheduler {
    Scheduler::new(
        Limits {
            lease_ttl: std::time::Duration::from_secs(5),
            window_bytes: 1 << 30,
            ..limits
        },
        100,
    )
}

/// The job queue and leases.
pub struct Scheduler {
    cfg: Limits,
    jobs: HashMap<JobId, Job>,
    /// Unfinished jobs in the order they get workers.
    queue: BTreeSet<(Reverse<i32>, JobId)>,
    /// The tiles' leases, one entry a span (see [`lease_table`]).
    leases: LeaseTable,
    /// No lease's deadline is earlier (`None`: no lease), so that expiry
    /// scans the lease table only when one may have run out: every lease
    /// call checks for expired ones, and a farm of a thousand workers
    /// holds thousands of spans.
    earliest_deadline: Option<Instant>,
    workers: Workers,
    counters: Counters,
    next_job: JobId,
    /// The next id of a sequence's frame job (from [`FRAME_IDS`] on).
    next_frame: JobId,
    next_lease: LeaseId,
    finished: u64,
    /// Jobs failed by their tiles' failures, for the caller to wind up.
    failed: Vec<(JobId, JobFailure)>,
    /// Leases that failed, for the farm's tile log (see [`blocks`]).
    faults: Vec<TileFault>,
    sizer: LeaseSizer,
    /// Which workers can hold which jobs (see [`memory`]).
    memory: MemoryGate,
}

impl Scheduler {
    /// `worker_id_base` keeps worker ids of different coordinator runs apart,
    /// so a worker that outlived a restart is told to register again.
    pub fn new(cfg: Limits, worker_id_base: u64) -> Self {
        Scheduler {
            cfg,
            jobs: HashMap::new(),
            queue: BTreeSet::new(),
            leases: LeaseTable::default(),
            earliest_deadline: None,
            workers: Workers::new(worker_id_base),
            counters: Counters::default(),
            next_job: 1,
            next_frame: FRAME_IDS,
            // Like worker ids: a result under a lease of an earlier run
            // never matches a lease of this one.
            next_lease: worker_id_base.max(1),
            finished: 0,
            failed: Vec::new(),
            faults: Vec::new(),
            sizer: LeaseSizer::default(),
            memory: MemoryGate::default(),
        }
    }

    /// Registers a worker; with a `session`, its every later call must
    /// present that secret.
    pub fn register_worker(&mut self, now: Instant, session: Option<[u8; 32]>) -> WorkerId {
        self.workers.register(now, session)
    }

    /// Whether `presented` is `worker`'s session secret (`None`: no such
    /// worker).
    pub fn session_is(&self, worker: WorkerId, presented: &[u8]) -> Option<bool> {
        self.workers.session_is(worker, presented)
    }

    /// Records what a worker said about itself when it registered.
    pub fn describe_worker(&mut self, worker: WorkerId, name: &str, threads: u32) {
        self.workers.describe(worker, name, threads);
    }

    /// Records why `worker` takes no tiles for now (`None`: it works).
    pub fn set_paused(&mut self, worker: WorkerId, why: Option<&str>) {
        self.workers.set_paused(worker, why);
    }

    /// Records the memory limit `worker` registered with (0: none); see
    /// [`memory`].
    pub fn set_memory_limit(&mut self, worker: WorkerId, bytes: u64) {
        self.workers.set_memory_limit(worker, bytes);
    }

    /// `worker` takes leases of several adjacent tiles (it said so when it
    /// registered; see [`lease_size`]).
    pub fn allow_spans(&mut self, worker: WorkerId) {
        if self.workers.threads(worker).is_some() {
            self.sizer.allow_spans(worker);
        }
    }

    /// `worker` encodes PNG segments with the coordinator's own encoder (it
    /// said so when it registered): its leases of PNG frames may ask for
    /// them ([`Lease::png_segments`]).
    pub fn allow_segments(&mut self, worker: WorkerId) {
        if self.workers.threads(worker).is_some() {
            self.sizer.allow_segments(worker);
        }
    }

    fn touch(&mut self, worker: WorkerId, now: Instant) -> Result<(), SchedError> {
        if self.workers.touch(worker, now) {
            Ok(())
        } else {
            Err(SchedError::UnknownWorker(worker))
        }
    }
}

#[cfg(test)]
mod span_tests;

#[cfg(test)]
mod tests;
