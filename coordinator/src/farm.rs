//! The coordinator without the network: bundles, the [`Scheduler`], result
//! validation and stitching into each job's output.
//!
//! The gRPC services in [`crate::grpc`] are thin wrappers around [`Farm`];
//! tests drive it directly with synthetic pixels. This file holds the
//! farm's configuration, its locked `State` and [`Farm::new`]; beside it,
//! in `farm/`, one file for each part of a job's and a worker's life:
//!
//! - `submit.rs`: where a job is made from a camera, submitted (queued)
//!   and moved in the queue (what is read of a bundle's scene to admit it
//!   is [`crate::summaries::summarize`], under the bounds of
//!   [`crate::admission`]).
//! - `registrations.rs`: the bounds on registering workers; `leasing.rs`:
//!   where a worker registers and is granted, keeps, returns or loses a
//!   lease.
//! - `checks.rs`: what is refused before it is taken in; `results.rs`:
//!   where a tile result is checked and taken; `segments.rs`: leases
//!   uploaded as encoded PNG segments; `stitch.rs`: where a taken tile is
//!   stored and stitched into its job's output (`outputs.rs`: that output);
//!   `aovs.rs`: the render passes a job carries with its tiles.
//! - `tile_log.rs`: the per-tile log (leases rendered and failed);
//!   `blocks.rs`: workers kept from a job, unblocked, restored.
//! - `ending.rs`: where a job ends (done, failed or cancelled);
//!   `control.rs`: jobs paused, resumed, and waiting for others;
//!   `retry.rs`: a failed still queued again with its finished tiles;
//!   `requeue.rs`: part of a job rendered again, its output rewritten in
//!   place (`patch.rs`: a still's output patched with a rect's tiles);
//!   `sequences.rs`: animations rendered as one job per frame;
//!   `retention.rs`: how long ended jobs are kept; `restore.rs`: picking
//!   up after a restart; `usage.rs`: the usage history fed and read.
//! - `status.rs`: what the farm reports (status, lists, outputs, figures);
//!   `job_previews.rs`: the PNG previews of running and ended jobs;
//!   `upkeep.rs`: the periodic lease reaper and bundle collector.
//!
//! Locking: `state` (scheduler, watchers) is held only for bookkeeping; each
//! job's output has its own lock, taken after `state` is released, so
//! encoding one job's rows never stalls leasing. The order is always
//! output → state, never the reverse.

mod aovs;
mod blocks;
mod checks;
mod control;
mod ending;
mod job_previews;
mod leasing;
mod outputs;
pub mod pass_states;
mod passes;
mod patch;
pub mod progressive;
mod registrations;
mod requeue;
mod restore;
mod results;
mod retention;
mod retry;
pub mod segments;
pub mod sequences;
mod status;
mod stitch;
mod submit;
mod tile_log;
mod upkeep;
mod usage;

pub use aovs::{aovs_from, apply_aovs, MAX_AOVS_BYTES};
pub use checks::{output_name_as, validate_aovs, validate_pixels};
pub use control::{Hold, MAX_AFTER};
pub use job_previews::PreviewImage;
pub use leasing::{Registration, WorkerOptions};
use outputs::Output;
pub use progressive::Progressive;
pub use requeue::check_rect;
pub use results::{LeaseResult, TileOutcome};
pub use retention::{BadDuration, BadRetention, Retention, MAX_KEEP_ENDED_FOR, MIN_KEEP_ENDED_FOR};
pub use segments::{SegmentPlan, SegmentUpload};
pub use submit::{MakeSink, SubmitOptions};
pub use tile_log::RenderedLease;
pub use upkeep::Upkeep;

use crate::bundles::BundleStore;
use crate::error::FarmError;
use crate::events::Events;
use crate::limits::Limits;
use crate::metrics::Metrics;
use crate::scheduler::{JobId, JobInfo, Outcome, Scheduler, WorkerId};
use crate::store::Store;
use crate::summaries::Summaries;
use crate::timed_lock::TimedLock;
use std::collections::{HashMap, HashSet, VecDeque};
use std::path::PathBuf;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;
use tokio::sync::{watch, Notify};

/// Coordinator settings.
#[derive(Debug, Clone)]
pub struct FarmConfig {
    /// Where the coordinator keeps its files: the bundles (`bundles/`), the
    /// database and the tile files (see [`crate::store`]), the outputs.
    pub data_dir: PathBuf,
    /// Tile edge used when a submission does not ask for one.
    pub default_tile: u32,
    /// Keep jobs and accepted tiles in `data_dir/state.db`, and pick up the
    /// unfinished jobs found there on start (see [`crate::store`]).
    pub durable: bool,
    /// Every bound the coordinator works within.
    pub limits: Limits,
    /// How long, and how many, ended jobs' outputs are kept.
    pub retention: Retention,
}

impl Default for FarmConfig {
    fn default() -> Self {
        FarmConfig {
            data_dir: PathBuf::from("trevi-data"),
            default_tile: 64,
            durable: true,
            limits: Limits::default(),
            retention: Retention::default(),
        }
    }
}

impl FarmConfig {
    /// The defaults, keeping bundles, outputs and the database in `data_dir`.
    pub fn new(data_dir: impl Into<PathBuf>) -> Self {
        FarmConfig {
            data_dir: data_dir.into(),
            ..FarmConfig::default()
        }
    }
}

struct State {
    sched: Scheduler,
    outputs: HashMap<JobId, Arc<Mutex<Output>>>,
    watchers: HashMap<JobId, watch::Sender<JobInfo>>,
    /// Who submitted each unfinished job.
    submitters: HashMap<JobId, String>,
    /// The last previews of jobs that ended, oldest first.
    final_previews: VecDeque<(JobId, Arc<job_previews::FinalPreview>)>,
    /// Jobs that ended but whose end the database did not take (a full
    /// disk): held unfinished, as stored, until [`Farm::expire`] records it.
    unrecorded: HashMap<JobId, Outcome>,
    /// Sequences, by id (their frames are jobs of `sched`).
    seqs: HashMap<JobId, sequences::Sequence>,
    /// Each frame job's sequence.
    parent_of: HashMap<JobId, JobId>,
    /// Workers that registered with this coordinator's PNG encoder.
    segment_workers: HashSet<WorkerId>,
    /// Which ended jobs were fetched or were frames (see `retention`).
    ended: retention::Ended,
    /// Where each worker registered from (see `registrations`).
    registrations: registrations::Registrations,
    /// Jobs paused or waiting for others, by id (see `control`).
    holds: HashMap<JobId, Hold>,
    /// Tiles taken from workers but not yet in the database, by job: a
    /// status counts only what a restart would find (see [`State::info`]).
    unstored: HashMap<JobId, u64>,
    /// Jobs ended whose waiters are still to be looked at, and whether
    /// someone is looking (see `control`).
    ended_deps: Vec<JobId>,
    draining: bool,
    /// A restart is restoring jobs: holds are looked at once it is done.
    restoring: bool,
}

impl State {
    /// Counts `tiles` of `job` taken but not yet stored (only with a
    /// database: without one nothing survives a restart anyway).
    fn taking(&mut self, job: JobId, tiles: u64, durable: bool) {
        if durable && tiles > 0 {
            *self.unstored.entry(job).or_default() += tiles;
        }
    }

    /// `tiles` of `job` counted by [`State::taking`] are stored (or the job
    /// ended): its status counts them again.
    fn stored(&mut self, job: JobId, tiles: u64) {
        if let Some(n) = self.unstored.get_mut(&job) {
            *n = n.saturating_sub(tiles);
            if *n == 0 {
                self.unstored.remove(&job);
            }
            self.publish(job);
        }
    }

    fn publish(&self, job: JobId) {
        if let (Some(tx), Some(info)) = (self.watchers.get(&job), self.info(job, Instant::now())) {
            tx.send_replace(info);
        }
        if let Some(&seq) = self.parent_of.get(&job) {
            self.publish(seq);
        }
    }

    /// A job's or a sequence's status.
    fn info(&self, job: JobId, now: Instant) -> Option<JobInfo> {
        let mut info = match self.seqs.get(&job) {
            Some(seq) => seq.info(job, &self.sched, now),
            None => self.sched.info(job, now)?,
        };
        if let Some(&n) = self.unstored.get(&job).filter(|_| !info.state.is_final()) {
            info.tiles_done = info.tiles_done.saturating_sub(n);
        }
        self.show_hold(job, &mut info);
        Some(info)
    }
}

/// The coordinator's state and rules.
pub struct Farm {
    cfg: FarmConfig,
    state: TimedLock<State>,
    /// Woken when there may be new tiles to lease.
    work: Notify,
    bundles: BundleStore,
    /// The cameras of each bundle's scene, parsed once per bundle.
    summaries: Summaries,
    store: Option<Store>,
    metrics: Arc<Metrics>,
    /// Job events, to webhooks and the monitor (see [`crate::events`]).
    events: Events,
    /// The usage history gathered, and kept when there is no store (see
    /// [`crate::usage`]).
    usage: crate::usage::Usage,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic while holding a lock is a bug; keep serving what we can.
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl Farm {
    /// Opens the farm on `cfg.data_dir`: the bundle store, and when
    /// `durable` the database, whose unfinished jobs are queued again.
    pub fn new(cfg: FarmConfig) -> Result<Self, FarmError> {
        let bundles = BundleStore::open(&cfg.data_dir.join("bundles"))?;
        let base = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_millis() as u64)
            .unwrap_or(1)
            << 12;
        let store = if cfg.durable {
            Some(Store::open(&cfg.data_dir)?)
        } else {
            None
        };
        let farm = Farm {
            state: TimedLock::new(State {
                sched: Scheduler::new(cfg.limits, base),
                outputs: HashMap::new(),
                watchers: HashMap::new(),
                submitters: HashMap::new(),
                final_previews: VecDeque::new(),
                unrecorded: HashMap::new(),
                seqs: HashMap::new(),
                parent_of: HashMap::new(),
                segment_workers: HashSet::new(),
                ended: retention::Ended::default(),
                registrations: registrations::Registrations::default(),
                holds: HashMap::new(),
                unstored: HashMap::new(),
                ended_deps: Vec::new(),
                draining: false,
                restoring: false,
            }),
            work: Notify::new(),
            bundles,
            summaries: Summaries::new(&cfg.limits),
            store,
            metrics: Arc::default(),
            events: Events::default(),
            usage: usage::history(cfg.durable)?,
            cfg,
        };
        farm.restore()?;
        farm.restore_blocks()?;
        // The unfinished jobs found there have events again.
        farm.state
            .lock()
            .submitters
            .keys()
            .for_each(|&j| farm.events.restored(j));
        farm.skip_used_ids()?;
        farm.prune();
        Ok(farm)
    }

    /// The settings the farm was opened with.
    pub fn config(&self) -> &FarmConfig {
        &self.cfg
    }

    /// The job events: where the farm emits them, and their subscribers.
    pub fn events(&self) -> &Events {
        &self.events
    }

    /// The uploaded scene bundles on disk.
    pub fn bundles(&self) -> &BundleStore {
        &self.bundles
    }

    /// The scene summaries of stored bundles (see [`Summaries::prime`]).
    pub fn summaries(&self) -> &Summaries {
        &self.summaries
    }

    /// Where job `job`'s finished output lives.
    pub fn output_path(&self, job: JobId, name: &str) -> PathBuf {
        self.cfg
            .data_dir
            .join("jobs")
            .join(job.to_string())
            .join(name)
    }
}
