//! The coordinator without the network: bundles, the [`Scheduler`], result
//! validation and stitching into each job's output.
//!
//! The gRPC services in [`crate::grpc`] are thin wrappers around [`Farm`];
//! tests drive it directly with synthetic pixels. Beside this file, in
//! `farm/`: `checks.rs` (what is refused before it is taken in),
//! `restore.rs` (picking up after a restart), `previews.rs` (each job's
//! live preview), `segments.rs` (leases uploaded as encoded PNG segments),
//! `retention.rs` (how long ended jobs are kept) and
//! `upkeep.rs` (the periodic lease reaper and bundle collector).
//!
//! Locking: `state` (scheduler, watchers) is held only for bookkeeping; each
//! job's output has its own lock, taken after `state` is released, so
//! encoding one job's rows never stalls leasing. The order is always
//! output → state, never the reverse.

pub mod admission;
mod checks;
mod outputs;
mod previews;
mod registrations;
mod restore;
mod retention;
pub mod segments;
pub mod sequences;
mod upkeep;

use checks::output_name;
pub use checks::{output_name_as, validate_pixels};
use outputs::Output;
pub use previews::PreviewImage;
pub use retention::{BadDuration, BadRetention, Retention, MAX_KEEP_ENDED_FOR, MIN_KEEP_ENDED_FOR};
pub use segments::{SegmentPlan, SegmentUpload};
pub use upkeep::Upkeep;

use crate::bundles::BundleStore;
use crate::error::FarmError;
use crate::limits::Limits;
use crate::metrics::{FarmSnapshot, Metrics};
use crate::preview::Preview;
use crate::scheduler::{
    ray_shares, Accepted, JobId, JobInfo, JobSpec, JobState, Lease, LeaseId, QueueDepth, Scheduler,
    WorkerId,
};
use crate::sink::TileSink;
use crate::store::{SeqLink, Store, StoredJob};
use crate::summaries::Summaries;
use crate::timed_lock::TimedLock;
use crate::workers::WorkerInfo;
use std::collections::{HashMap, HashSet, VecDeque};
use std::path::PathBuf;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};
use tokio::sync::{watch, Notify};
use trevi_core::Rect;

/// Coordinator settings.
#[derive(Debug, Clone)]
pub struct FarmConfig {
    pub data_dir: PathBuf,
    /// Tile edge used when a submission does not ask for one.
    pub default_tile: u32,
    /// Keep jobs and accepted tiles in `data_dir/state.db`, and pick up the
    /// unfinished jobs found there on start (see [`crate::store`]).
    pub durable: bool,
    pub limits: Limits,
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

/// What became of a valid tile result.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TileOutcome {
    Accepted,
    /// Late or duplicate: another result won, or the job is over.
    Ignored,
}

/// Makes a job's [`TileSink`] once its id is known.
pub type MakeSink<'a> = Box<dyn FnOnce(JobId) -> Result<Box<dyn TileSink>, FarmError> + 'a>;

/// How [`Farm::submit`] queues a job.
#[derive(Default)]
pub struct SubmitOptions<'a> {
    /// Who submits (a client's address), who may have at most
    /// [`Limits::max_jobs_per_submitter`] unfinished jobs; empty for
    /// in-process callers, who share one count.
    pub who: &'a str,
    /// Where the job's tiles go; `None`: a [`trevi_core::FrameWriter`] writing
    /// [`Farm::output_path`].
    pub sink: Option<MakeSink<'a>>,
}

/// How [`Farm::register_worker`] registers a worker.
#[derive(Debug, Clone, Copy, Default)]
pub struct WorkerOptions<'a> {
    /// The name the worker gave (kept short).
    pub name: &'a str,
    /// The render threads it said it has.
    pub threads: u32,
    /// Give it a session secret from the operating system's random source,
    /// which its every later call must present (see [`Farm::check_session`]),
    /// so one worker cannot act under another's id. Without one (an
    /// in-process worker) no secret matches it.
    pub session: bool,
    /// It renders leases of several adjacent tiles (see
    /// [`crate::scheduler::lease_size`]); without it, one tile per lease.
    pub multi_tile: bool,
    /// The most memory it lets a scene take, in bytes (`--max-memory`);
    /// 0: no limit (see [`crate::scheduler::memory`]).
    pub max_memory: u64,
    /// It encodes PNG segments with this coordinator's encoder (its
    /// `png_encoder` equals [`trevi_core::output::PNG_ENCODER`]): its
    /// leases may ask for encoded segments (see [`Farm::put_segments`]),
    /// and only such a worker's are taken.
    pub png_segments: bool,
    /// The client address it registered from, which may have at most
    /// [`Limits::max_workers_per_address`] workers registered; empty for
    /// in-process callers, who are not counted by address.
    pub addr: &'a str,
}

/// A worker [`Farm::register_worker`] registered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Registration {
    pub id: WorkerId,
    /// Its session secret, when [`WorkerOptions::session`] asked for one.
    pub session: Option<[u8; 32]>,
}

/// A result for one leased tile, for [`Farm::put_tile`].
#[derive(Debug, Clone, Copy)]
pub struct TileResult<'a> {
    pub lease: LeaseId,
    pub job: JobId,
    pub rect: Rect,
    /// Rays the worker traced for it.
    pub rays: u64,
    pub pixels: &'a [[f32; 3]],
    /// When given, `lease` must be this worker's lease on that tile: a
    /// result under someone else's lease, or a made-up one, is refused and
    /// changes nothing.
    pub worker: Option<WorkerId>,
}

/// A running job's output, shared by the uploads writing to it.
type SharedOutput = Arc<Mutex<Output>>;

/// A tile result the scheduler took, on its way to the store and the output.
struct Admitted<P> {
    idx: u32,
    rect: Rect,
    rays: u64,
    pixels: P,
    out: SharedOutput,
}

struct State {
    sched: Scheduler,
    outputs: HashMap<JobId, Arc<Mutex<Output>>>,
    watchers: HashMap<JobId, watch::Sender<JobInfo>>,
    /// Who submitted each unfinished job.
    submitters: HashMap<JobId, String>,
    /// The last previews of jobs that ended, oldest first.
    final_previews: VecDeque<(JobId, Arc<previews::FinalPreview>)>,
    /// Jobs that ended but whose end the database did not take (a full
    /// disk): held unfinished, as stored, until [`Farm::expire`] records it.
    unrecorded: HashMap<JobId, Result<(), String>>,
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
}

impl State {
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
        match self.seqs.get(&job) {
            Some(seq) => Some(seq.info(job, &self.sched, now)),
            None => self.sched.info(job, now),
        }
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
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic while holding a lock is a bug; keep serving what we can.
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl Farm {
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
            }),
            work: Notify::new(),
            bundles,
            summaries: Summaries::new(&cfg.limits),
            store,
            metrics: Arc::default(),
            cfg,
        };
        farm.restore()?;
        farm.skip_used_ids()?;
        farm.prune();
        Ok(farm)
    }

    pub fn config(&self) -> &FarmConfig {
        &self.cfg
    }

    pub fn bundles(&self) -> &BundleStore {
        &self.bundles
    }

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
            self.end_job(job, Err(why.to_string()));
        }
        doomed
    }

    /// Removes the bundles no job uses that are older than
    /// [`Retention::bundle_grace`]; returns how many went.
    pub fn collect_bundles(&self) -> usize {
        let mut keep: std::collections::HashSet<String> = self
            .list()
            .into_iter()
            .map(|j| j.spec.bundle_hash)
            .collect();
        keep.extend(
            self.state
                .lock()
                .seqs
                .values()
                .filter(|s| !s.state.is_final())
                .map(|s| s.spec.bundle_hash.clone()),
        );
        self.bundles.collect(&keep, self.cfg.retention.bundle_grace)
    }

    /// The scene summaries of stored bundles (see [`Summaries::prime`]).
    pub fn summaries(&self) -> &Summaries {
        &self.summaries
    }

    /// Describes the job rendering `camera` (empty: the first camera) of a
    /// stored bundle's scene. The scene is read the first time a bundle is
    /// asked about, headers only and within the admission bounds (see
    /// [`admission`]; it reads the bundle: call off the async threads), then
    /// its summary is kept (see [`Summaries`]).
    pub fn job_spec(
        &self,
        bundle_hash: &str,
        camera: &str,
        priority: i32,
        tile_size: u32,
    ) -> Result<JobSpec, FarmError> {
        let summary = match self.summaries.get(bundle_hash) {
            // Cached, but the stored copy must still be there and intact
            // (this also marks it used); checking it reads and hashes the
            // file but parses nothing.
            Some(summary) => {
                self.bundles.open_verified(bundle_hash)?;
                summary
            }
            None => self.summaries.get_or_admit(bundle_hash, |ticket| {
                admission::summarize(&self.bundles, bundle_hash, ticket)
            })?,
        };
        let cam = if camera.is_empty() {
            summary.cameras.first()
        } else {
            summary.cameras.iter().find(|c| c.id == camera)
        }
        .ok_or_else(|| {
            FarmError::BadScene(if camera.is_empty() {
                "the scene has no camera".to_string()
            } else {
                format!("the scene has no camera \"{camera}\"")
            })
        })?;
        let output_name = output_name(&cam.output)?;
        let samples = cam.width as u64 * cam.height as u64 * (cam.supersample.max(1) as u64).pow(2);
        let max = self.cfg.limits.max_image_samples;
        if samples > max {
            return Err(FarmError::Limit(format!(
                "camera \"{}\": {}x{} at supersample {} is {samples} samples, more than the \
                 coordinator's limit of {max} (--max-image-samples)",
                cam.id, cam.width, cam.height, cam.supersample
            )));
        }
        Ok(JobSpec {
            frame: None,
            bundle_hash: bundle_hash.to_string(),
            camera: cam.id.clone(),
            priority,
            width: cam.width,
            height: cam.height,
            tile_size: if tile_size == 0 {
                self.cfg.default_tile
            } else {
                tile_size
            },
            output_name,
            scene: summary.scene.clone(),
            submitter: String::new(),
        })
    }

    /// Where job `job`'s finished output lives.
    pub fn output_path(&self, job: JobId, name: &str) -> PathBuf {
        self.cfg
            .data_dir
            .join("jobs")
            .join(job.to_string())
            .join(name)
    }

    /// Queues a job; its tiles go where `opts` says.
    pub fn submit(&self, spec: JobSpec, opts: SubmitOptions) -> Result<JobInfo, FarmError> {
        let SubmitOptions { who, sink: make } = opts;
        let spec = JobSpec {
            submitter: who.to_string(),
            ..spec
        };
        if spec.width == 0 || spec.height == 0 {
            return Err(FarmError::BadScene("the frame is empty".into()));
        }
        self.check_memory(&spec)?;
        let mut st = self.state.lock();
        Self::check_submitter(&st, who, self.cfg.limits.max_jobs_per_submitter)?;
        let info = self.submit_locked(&mut st, spec, make, who, None)?;
        drop(st);
        self.work.notify_waiters();
        Ok(info)
    }

    /// Refuses a submission from `who` when it has `max` unfinished jobs.
    fn check_submitter(st: &State, who: &str, max: usize) -> Result<(), FarmError> {
        let mine = st.submitters.values().filter(|s| s.as_str() == who).count();
        if mine >= max {
            let who = if who.is_empty() {
                "this submitter"
            } else {
                who
            };
            return Err(FarmError::Limit(format!(
                "{who} already has {mine} unfinished jobs, the coordinator's limit \
                 (--max-jobs-per-submitter)"
            )));
        }
        Ok(())
    }

    /// Queues a job with the state locked; a frame of sequence `parent` is
    /// not counted against its submitter (its sequence is).
    fn submit_locked(
        &self,
        st: &mut State,
        spec: JobSpec,
        make: Option<MakeSink<'_>>,
        who: &str,
        parent: Option<JobId>,
    ) -> Result<JobInfo, FarmError> {
        let now = Instant::now();
        // The scene's memory estimate, from the summary `job_spec` made.
        let memory = self
            .summaries
            .get(&spec.bundle_hash)
            .map_or(0, |s| s.memory);
        let id = st.sched.submit(spec, now);
        st.sched.set_memory_estimate(id, memory, now);
        let info = st.sched.info(id, now).expect("just submitted");
        // The default output file is opened at the job's first tile (see
        // `outputs`); a sink given by the caller is made now.
        let out = match make {
            None => Output::deferred(
                self.output_path(id, &info.spec.output_name),
                &info.spec,
                info.tiles_total,
            ),
            Some(make) => match make(id) {
                Ok(sink) => Output::new(sink, &info.spec, info.tiles_total),
                Err(e) => {
                    st.sched.finish(id, Err(e.to_string()), now);
                    return Err(e);
                }
            },
        };
        if let Some(store) = &self.store {
            let seq = SeqLink {
                parent,
                ..SeqLink::default()
            };
            let stored = StoredJob::submitted(id, info.spec.clone(), info.state, seq);
            if let Err(e) = store.insert_job(&stored) {
                st.sched.finish(id, Err(e.to_string()), now);
                return Err(e);
            }
        }
        st.outputs.insert(id, Arc::new(Mutex::new(out)));
        st.watchers.insert(id, watch::channel(info.clone()).0);
        match parent {
            None => {
                st.submitters.insert(id, who.to_string());
            }
            Some(seq) => {
                st.parent_of.insert(id, seq);
            }
        }
        tracing::info!(job = id, camera = %info.spec.camera, width = info.spec.width,
            height = info.spec.height, priority = info.spec.priority, frame = ?info.spec.frame,
            "job queued");
        Ok(info)
    }

    /// Registers a worker as `opts` says.
    pub fn register_worker(&self, opts: WorkerOptions) -> Result<Registration, FarmError> {
        let session = if opts.session {
            let mut secret = [0u8; 32];
            getrandom::getrandom(&mut secret)
                .map_err(|e| FarmError::io("no random session secret", e))?;
            Some(secret)
        } else {
            None
        };
        let mut st = self.state.lock();
        let l = &self.cfg.limits;
        st.check_registration(opts.addr, l.max_workers, l.max_workers_per_address)?;
        let id = st.sched.register_worker(Instant::now(), session);
        st.registered(id, opts.addr);
        st.sched.describe_worker(id, opts.name, opts.threads);
        if opts.multi_tile {
            st.sched.allow_spans(id);
        }
        if opts.png_segments {
            st.sched.allow_segments(id);
            st.segment_workers.insert(id);
        }
        st.sched.set_memory_limit(id, opts.max_memory);
        Ok(Registration { id, session })
    }

    /// `worker` declines `lease`: its scene needs about `bytes`, more than
    /// the worker's memory limit. Re-queued at once, not counted as a
    /// failure; the job keeps the estimate (see
    /// [`Scheduler::decline_lease`]).
    pub fn decline_tile(
        &self,
        worker: WorkerId,
        lease: LeaseId,
        bytes: u64,
    ) -> Result<(), FarmError> {
        let honest = self
            .state
            .lock()
            .sched
            .decline_lease(worker, lease, bytes, Instant::now())?;
        let needs = trevi_core::scene::estimate::human_bytes(bytes);
        if honest {
            tracing::info!(worker, lease, %needs,
                "tile declined: the scene needs more memory than the worker's --max-memory; re-queued");
        } else {
            tracing::warn!(worker, lease, %needs,
                "tile declined for memory its registered limit holds; re-queued, counted against the worker");
        }
        self.work.notify_waiters();
        Ok(())
    }

    /// Checks that `session` is the secret `worker` registered with: an
    /// unknown worker must register (again), a wrong secret is refused.
    pub fn check_session(&self, worker: WorkerId, session: &[u8]) -> Result<(), FarmError> {
        match self.state.lock().sched.session_is(worker, session) {
            None => Err(FarmError::UnknownWorker(worker)),
            Some(true) => Ok(()),
            Some(false) => Err(FarmError::NotYourLease(format!(
                "the session secret is not worker {worker}'s (a worker may only act under \
                 the id its own registration gave it)"
            ))),
        }
    }

    /// `worker` gives `lease` back unfinished: re-queued at once, and with
    /// `error` (its render failed) counted against the tile, which may fail
    /// the job (see [`Scheduler::return_lease`]).
    pub fn return_tile(
        &self,
        worker: WorkerId,
        lease: LeaseId,
        error: Option<&str>,
    ) -> Result<(), FarmError> {
        let failed = {
            let mut st = self.state.lock();
            st.sched
                .return_lease(worker, lease, error, Instant::now())?;
            st.sched.take_failed()
        };
        match error {
            Some(e) => tracing::warn!(worker, lease, error = %e, "tile failed; re-queued"),
            None => tracing::info!(worker, lease, "tile returned unrendered; re-queued"),
        }
        self.work.notify_waiters();
        self.fail_jobs(failed);
        Ok(())
    }

    pub fn lease(&self, worker: WorkerId) -> Result<Option<Lease>, FarmError> {
        Ok(self.state.lock().sched.lease(worker, Instant::now())?)
    }

    /// Like [`Farm::lease`], waiting up to `wait` for a tile to become available.
    pub async fn lease_wait(
        &self,
        worker: WorkerId,
        wait: Duration,
    ) -> Result<Option<Lease>, FarmError> {
        let deadline = tokio::time::Instant::now() + wait;
        loop {
            let notified = self.work.notified();
            tokio::pin!(notified);
            notified.as_mut().enable();
            if let Some(l) = self.lease(worker)? {
                return Ok(Some(l));
            }
            if tokio::time::timeout_at(deadline, notified).await.is_err() {
                return Ok(None);
            }
        }
    }

    /// Checks that `rect` is one of `job`'s tiles (before reading a result).
    pub fn check_tile(&self, job: JobId, rect: Rect) -> Result<(), FarmError> {
        Ok(self.state.lock().sched.check_tile(job, rect)?)
    }

    /// Checks that `rect` is one of `job`'s tiles or a span of them (before
    /// reading a result); returns the tiles, left to right (see
    /// [`Scheduler::span_tiles`]).
    pub fn span_tiles(&self, job: JobId, rect: Rect) -> Result<Vec<Rect>, FarmError> {
        Ok(self.state.lock().sched.span_tiles(job, rect)?)
    }

    /// [`Farm::span_tiles`] with the cap of the upload's kind: encoded
    /// segments or floats (see [`Scheduler::span_tiles_as`]).
    pub fn span_tiles_as(
        &self,
        job: JobId,
        rect: Rect,
        png_segments: bool,
    ) -> Result<Vec<Rect>, FarmError> {
        Ok(self
            .state
            .lock()
            .sched
            .span_tiles_as(job, rect, png_segments)?)
    }

    /// Takes the result of a lease of several tiles: `r.rect` is their
    /// union, `parts` its tiles in row-major order (band by band, left to
    /// right: [`Farm::span_tiles`]), whose leases are `r.lease`,
    /// `r.lease + 1`, …. Each tile is checked and
    /// taken as [`Farm::put_tile`] takes one, with its own pixels and its
    /// share of the rays (by pixels); the new ones are then stored in one
    /// transaction and written. Accepted when every tile is; the first
    /// error otherwise, after every tile was tried.
    pub fn put_span(&self, r: TileResult, parts: &[Rect]) -> Result<TileOutcome, FarmError> {
        self.put_span_rendered(r, parts, None)
    }

    /// [`Farm::put_span`] with the time the worker said it spent rendering
    /// the lease (`None`: it did not say), which measures the job's cost
    /// for lease sizing (see [`Scheduler::accept_rendered`]).
    pub fn put_span_rendered(
        &self,
        r: TileResult,
        parts: &[Rect],
        render: Option<Duration>,
    ) -> Result<TileOutcome, FarmError> {
        if let [only] = parts {
            return self.put_one(TileResult { rect: *only, ..r }, render);
        }
        let pixels: Vec<u64> = parts.iter().map(|p| p.pixel_count() as u64).collect();
        let shares = ray_shares(r.rays, &pixels);
        let mut outcome = Ok(TileOutcome::Accepted);
        let mut admitted = Vec::with_capacity(parts.len());
        for (i, &part) in parts.iter().enumerate() {
            let mut pixels = Vec::with_capacity(part.pixel_count());
            // A result of the wrong size stays wrong: every part is refused.
            // A span may cover several full-width bands (its tiles in
            // row-major order): each part is cut at its x and y offset.
            if r.pixels.len() == r.rect.pixel_count() {
                let w = r.rect.w as usize;
                let dx = (part.x - r.rect.x) as usize;
                let dy = (part.y - r.rect.y) as usize;
                for row in r.pixels.chunks_exact(w).skip(dy).take(part.h as usize) {
                    pixels.extend_from_slice(&row[dx..dx + part.w as usize]);
                }
            }
            let one = self.admit(
                TileResult {
                    lease: r.lease.wrapping_add(i as u64),
                    rect: part,
                    rays: shares[i],
                    pixels: &pixels,
                    ..r
                },
                render,
            );
            let one = match one {
                Ok(Some((idx, out))) => {
                    admitted.push(Admitted {
                        idx,
                        rect: part,
                        rays: shares[i],
                        pixels,
                        out,
                    });
                    Ok(TileOutcome::Accepted)
                }
                Ok(None) => Ok(TileOutcome::Ignored),
                Err(e) => Err(e),
            };
            outcome = match (outcome, one) {
                (Err(e), _) | (Ok(_), Err(e)) => Err(e),
                (Ok(TileOutcome::Accepted), Ok(o)) => Ok(o),
                (Ok(o), Ok(_)) => Ok(o),
            };
        }
        // The span's new tiles are stored in one transaction, then written.
        let written = self.store_and_write(r.job, &admitted);
        match (outcome, written) {
            (Err(e), _) | (Ok(_), Err(e)) => Err(e),
            (Ok(_), Ok(false)) => Ok(TileOutcome::Ignored), // Cancelled meanwhile.
            (Ok(o), Ok(true)) => Ok(o),
        }
    }

    pub fn heartbeat(
        &self,
        worker: WorkerId,
        leases: &[LeaseId],
    ) -> Result<Vec<LeaseId>, FarmError> {
        Ok(self
            .state
            .lock()
            .sched
            .heartbeat(worker, leases, Instant::now())?)
    }

    /// Records why `worker` takes no tiles for now (`None`: it works); see
    /// [`crate::workers::WorkerState::Paused`].
    pub fn set_paused(&self, worker: WorkerId, why: Option<&str>) {
        let mut st = self.state.lock();
        st.sched.set_paused(worker, why);
    }

    /// Re-queues tiles whose leases ran out.
    pub fn expire(&self) -> usize {
        let (n, failed) = {
            let mut st = self.state.lock();
            let n = st.sched.expire(Instant::now());
            (n, st.sched.take_failed())
        };
        if n > 0 {
            tracing::warn!(tiles = n, "leases expired; tiles re-queued");
            self.work.notify_waiters();
        }
        self.fail_jobs(failed);
        let unrecorded: Vec<(JobId, Result<(), String>)> = self
            .state
            .lock()
            .unrecorded
            .iter()
            .map(|(&j, r)| (j, r.clone()))
            .collect();
        for (job, result) in unrecorded {
            self.end_job(job, result);
        }
        self.prune();
        n
    }

    /// Ends jobs whose tiles failed too often.
    fn fail_jobs(&self, failed: Vec<(JobId, String)>) {
        for (job, why) in failed {
            self.end_job(job, Err(why));
        }
    }

    /// Takes a tile result: validates it, and writes it if it is the first
    /// valid one for its tile. An invalid result re-queues the tile.
    pub fn put_tile(&self, r: TileResult) -> Result<TileOutcome, FarmError> {
        self.put_one(r, None)
    }

    /// [`Farm::put_tile`] with the worker's render time, if it said.
    fn put_one(&self, r: TileResult, render: Option<Duration>) -> Result<TileOutcome, FarmError> {
        let Some((idx, out)) = self.admit(r, render)? else {
            return Ok(TileOutcome::Ignored);
        };
        let one = Admitted {
            idx,
            rect: r.rect,
            rays: r.rays,
            pixels: r.pixels,
            out,
        };
        Ok(
            match self.store_and_write(r.job, std::slice::from_ref(&one))? {
                true => TileOutcome::Accepted,
                false => TileOutcome::Ignored, // Cancelled meanwhile.
            },
        )
    }

    /// Validates a result and records it with the scheduler: the tile's
    /// index and the job's output when it is the first valid result for
    /// its tile (`None`: late, duplicate, or the job is over). An invalid
    /// result re-queues the tile and is the error.
    fn admit(
        &self,
        r: TileResult,
        render: Option<Duration>,
    ) -> Result<Option<(u32, SharedOutput)>, FarmError> {
        let TileResult {
            lease,
            job,
            rect,
            rays,
            pixels,
            worker,
        } = r;
        let valid = validate_pixels(rect, pixels);
        let mut st = self.state.lock();
        st.sched.check_lease(job, rect, lease, worker)?;
        let valid = valid.and_then(|()| Ok(st.sched.check_tile(job, rect)?));
        if let Err(e) = valid {
            st.sched.reject_tile(lease, &format!("invalid result: {e}"));
            let failed = st.sched.take_failed();
            drop(st);
            tracing::warn!(job, lease, error = %e, "tile rejected and re-queued");
            self.work.notify_waiters();
            self.fail_jobs(failed);
            return Err(e);
        }
        match st
            .sched
            .accept_rendered(job, rect, rays, render, Instant::now())?
        {
            Accepted::Ignored => return Ok(None),
            Accepted::New { .. } => {}
        }
        let idx = st
            .sched
            .tile_index(job, rect)
            .expect("accepted tiles are tiles");
        st.publish(job);
        let Some(out) = st.outputs.get(&job).cloned() else {
            return Ok(None);
        };
        drop(st);
        self.work.notify_waiters();
        Ok(Some((idx, out)))
    }

    /// Stores admitted tiles of `job` (one transaction: committed before
    /// they are acknowledged, so after a crash they are replayed, not
    /// rendered again), then writes each to the job's output and preview.
    /// False when the output was gone (the job was cancelled meanwhile).
    fn store_and_write<P: AsRef<[[f32; 3]]>>(
        &self,
        job: JobId,
        tiles: &[Admitted<P>],
    ) -> Result<bool, FarmError> {
        let Some(first) = tiles.first() else {
            return Ok(true);
        };
        if let Some(store) = &self.store {
            let rows: Vec<_> = tiles
                .iter()
                .map(|t| {
                    (
                        t.idx,
                        t.rays,
                        trevi_proto::pixels_as_bytes(t.pixels.as_ref()),
                    )
                })
                .collect();
            if let Err(e) = store.put_tiles(job, &rows) {
                lock(&first.out).close();
                self.end_job(job, Err(format!("storing tile {}: {e}", first.idx)));
                return Err(e);
            }
        }
        let mut all = true;
        for t in tiles {
            all &= self.write_out(job, &t.out, t.rect, t.pixels.as_ref())?;
        }
        Ok(all)
    }

    /// Writes a stored tile to the job's output and preview; finishes the
    /// output with its last tile. False when the output is gone (the job
    /// was cancelled meanwhile).
    fn write_out(
        &self,
        job: JobId,
        out: &Mutex<Output>,
        rect: Rect,
        pixels: &[[f32; 3]],
    ) -> Result<bool, FarmError> {
        self.write_output(job, out, 1, |sink, preview| {
            sink.write_tile(rect, pixels)?;
            preview.add_tile(rect, pixels);
            Ok(())
        })
    }

    /// Writes to `job`'s output with `write` (given the sink and the
    /// preview: it adds to the preview what it wrote) and counts `tiles`
    /// more tiles written; the output's last tile finishes it. A write error
    /// drops the output and fails the job. False when the output is gone
    /// (the job was cancelled meanwhile).
    fn write_output(
        &self,
        job: JobId,
        out: &Mutex<Output>,
        tiles: u64,
        write: impl FnOnce(&mut dyn TileSink, &mut Preview) -> Result<(), crate::sink::SinkError>,
    ) -> Result<bool, FarmError> {
        let mut guard = lock(out);
        let o = &mut *guard;
        let opened = o.open();
        let Some(sink) = o.sink.as_mut() else {
            return match opened {
                Ok(_) => Ok(false),
                Err(e) => {
                    drop(guard); // end_job takes the output's lock for its preview.
                    let e = FarmError::io(format!("creating the output of job {job}"), e);
                    self.end_job(job, Err(e.to_string()));
                    Err(e)
                }
            };
        };
        if let Err(e) = write(sink.as_mut(), &mut o.preview) {
            o.close();
            drop(guard); // end_job takes the output's lock for its preview.
            let e = FarmError::io(format!("writing the output of job {job}"), e);
            self.end_job(job, Err(e.to_string()));
            return Err(e);
        }
        o.max_rows_held = o.max_rows_held.max(sink.rows_held());
        o.written += tiles;
        if o.written == o.total {
            let sink = o.sink.take().expect("checked above");
            let result = sink.finish();
            drop(guard);
            self.end_job(
                job,
                result.map_err(|e| format!("finishing the output: {e}")),
            );
        }
        Ok(true)
    }

    /// Ends a job. Its end is recorded in the database before anyone can
    /// see it, so what a client is told is what a restart finds. When the
    /// database does not take it (a full disk), the job stays as stored:
    /// unfinished, taking no more work; [`Farm::expire`] records the end
    /// later, and a restart meanwhile resumes the job from its stored tiles.
    fn end_job(&self, job: JobId, mut result: Result<(), String>) {
        let image = self.final_preview(job);
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
                    result = Err(e.to_string());
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
        if let Err(e) = self.persist_frame_end(&ending, seq_done) {
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
        st.sched.finish(job, result, now);
        st.outputs.remove(&job);
        st.submitters.remove(&job);
        st.keep_final_preview(job, image, self.cfg.limits.kept_previews);
        if let Some(seq) = parent {
            st.frame_ended(seq, job, &ending, seq_done.is_some());
        }
        st.publish(job);
        drop(st);
        if let Some(seq) = parent {
            self.advance(seq);
        }
        self.prune();
    }

    /// Records a job's end in the database (and drops its tiles there).
    fn persist_end(&self, info: &JobInfo) -> Result<(), FarmError> {
        self.persist_frame_end(info, None)
    }

    /// Like [`Farm::persist_end`], with a sequence's count of frames done
    /// (see [`Store::finish_frame`]).
    fn persist_frame_end(
        &self,
        info: &JobInfo,
        seq: Option<(JobId, u32)>,
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
                frames_done: info.frames.map_or(0, |f| f.done),
                ..SeqLink::default()
            },
        };
        store.finish_frame(&j, seq)
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
            lock(&out).close();
            let dir = self.cfg.data_dir.join("jobs").join(job.to_string());
            let _ = std::fs::remove_dir(dir);
            tracing::info!(job, "job cancelled");
            // What it became, even if the retention forgets it at once.
            let info = self.info(job);
            self.prune();
            return info;
        }
        self.info(job)
    }

    pub fn info(&self, job: JobId) -> Result<JobInfo, FarmError> {
        self.state
            .lock()
            .info(job, Instant::now())
            .ok_or(FarmError::UnknownJob(job))
    }

    pub fn list(&self) -> Vec<JobInfo> {
        self.state.lock().sched.list(Instant::now())
    }

    /// Up to `limit` jobs by id from id `from` on, and where the next page
    /// starts (`None`: this was the last).
    /// Frames of sequences are not listed: their sequence is.
    pub fn list_from(&self, from: JobId, limit: usize) -> (Vec<JobInfo>, Option<JobId>) {
        self.state.lock().list_from(from, limit, Instant::now())
    }

    /// Progress of a job: the current status, then every change.
    pub fn watch(&self, job: JobId) -> Result<watch::Receiver<JobInfo>, FarmError> {
        self.state
            .lock()
            .watchers
            .get(&job)
            .map(|tx| tx.subscribe())
            .ok_or(FarmError::UnknownJob(job))
    }

    /// The finished output file of a job that is done (a frame of a
    /// sequence: in its sequence's directory). Call off the async threads.
    pub fn output_file(&self, job: JobId) -> Result<PathBuf, FarmError> {
        let frame_of = {
            let st = self.state.lock();
            if st.seqs.contains_key(&job) {
                drop(st);
                return self.frame_file(job, None);
            }
            st.ended.frame_of(job)
        };
        let info = self.info(job)?;
        if let (Some((seq, f)), JobState::Done) = (frame_of, info.state) {
            return self.frame_file(seq, Some(f));
        }
        if info.state != JobState::Done {
            return Err(FarmError::NoOutput(
                job,
                format!("it is {:?}", info.state).to_lowercase(),
            ));
        }
        Ok(self.output_path(job, &info.spec.output_name))
    }

    /// Moves an unfinished job to another priority (higher runs first).
    pub fn set_priority(&self, job: JobId, priority: i32) -> Result<JobInfo, FarmError> {
        if self.state.lock().seqs.contains_key(&job) {
            return self.set_sequence_priority(job, priority);
        }
        let mut st = self.state.lock();
        // Checked, stored, then applied: a change the database did not
        // take is not made.
        match st.sched.info(job, Instant::now()) {
            None => return Err(FarmError::UnknownJob(job)),
            Some(i) if i.state.is_final() || st.unrecorded.contains_key(&job) => {
                return Err(FarmError::JobOver(job))
            }
            Some(_) => {}
        }
        if let Some(store) = &self.store {
            store.set_priority(job, priority)?;
        }
        st.sched.set_priority(job, priority)?;
        st.publish(job);
        drop(st);
        tracing::info!(job, priority, "job priority changed");
        // A job moved up may now take a worker waiting for work.
        self.work.notify_waiters();
        self.info(job)
    }

    /// Unfinished jobs and their tiles waiting for a worker.
    pub fn queue_depth(&self) -> QueueDepth {
        self.state.lock().sched.queue_depth()
    }

    /// Every known worker.
    pub fn workers(&self) -> Vec<WorkerInfo> {
        self.state.lock().sched.workers(Instant::now())
    }

    /// Counters, queue, jobs and workers at one instant.
    pub fn snapshot(&self) -> FarmSnapshot {
        let now = Instant::now();
        let st = self.state.lock();
        FarmSnapshot {
            counters: st.sched.counters(),
            queue: st.sched.queue_depth(),
            jobs: st.list_from(0, usize::MAX, now).0,
            workers: st.sched.workers(now),
            rays_per_second: st.sched.rays_per_second(now),
            state_lock_held: self.state.held(),
            store_lock_held: self.store.as_ref().map_or(Duration::ZERO, Store::lock_held),
        }
    }

    /// Request latencies and other figures only the servers see.
    pub fn metrics(&self) -> &Arc<Metrics> {
        &self.metrics
    }

    /// Most rows the job's output held at once (while it is running).
    pub fn max_rows_held(&self, job: JobId) -> Option<usize> {
        let out = self.state.lock().outputs.get(&job).cloned()?;
        let m = lock(&out).max_rows_held;
        Some(m)
    }
}
