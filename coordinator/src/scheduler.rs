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

pub mod lease_size;
mod lease_table;
pub mod memory;
mod whole_span;
mod window;

use lease_size::{LeaseSizer, MAX_SPAN_TILES};
use lease_table::{LeaseEntry, LeaseTable, NewSpan};
use memory::MemoryGate;
pub use whole_span::SpanCheck;
pub use window::{
    band_bytes, encoded_rows_bound, encoder_bytes, segment_band_bytes, ENCODER_ROWS,
    SEGMENT_FRAMING_BYTES, TILE_BOOKKEEPING_BYTES,
};
use window::{BandWindow, TileState};

use crate::limits::Limits;
use crate::workers::{WorkerInfo, Workers};
use std::cmp::Reverse;
use std::collections::{BTreeSet, HashMap};
use std::path::Path;
use std::time::{Duration, Instant};
use trevi_core::output::{Format, SEGMENT_ROWS};
use trevi_core::tile::Rect;

pub type JobId = u64;
pub type LeaseId = u64;
pub use crate::workers::WorkerId;

/// Where a job is in its life.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JobState {
    Queued,
    Running,
    Done,
    Failed,
    Cancelled,
}

impl JobState {
    /// Whether the job will not change any more.
    pub fn is_final(self) -> bool {
        matches!(
            self,
            JobState::Done | JobState::Failed | JobState::Cancelled
        )
    }

    pub const ALL: [JobState; 5] = [
        JobState::Queued,
        JobState::Running,
        JobState::Done,
        JobState::Failed,
        JobState::Cancelled,
    ];

    /// The state's name, as the database, the API and the metrics use it.
    pub fn name(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Done => "done",
            JobState::Failed => "failed",
            JobState::Cancelled => "cancelled",
        }
    }
}

/// What a job renders: one camera's frame of one bundle.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct JobSpec {
    pub bundle_hash: String,
    pub camera: String,
    pub priority: i32,
    pub width: u32,
    pub height: u32,
    pub tile_size: u32,
    /// File name of the output; its extension selects the format.
    pub output_name: String,
    /// For one frame of a sequence: the frame the workers render (see
    /// `crate::farm::sequences`); `None` for a still.
    pub frame: Option<u32>,
    /// The scene file's name in its bundle (what `list` shows).
    pub scene: String,
    /// Who submitted the job: the client's address, as the farm counts
    /// jobs per submitter (empty when unknown).
    pub submitter: String,
}

/// The first id of the frame jobs of sequences. Stills and sequences take
/// ids from 1 on, one after the other; a sequence's frames are jobs of
/// their own, numbered from here so they use none of those ids up.
pub const FRAME_IDS: JobId = 1 << 40;

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
    }
}

/// A scheduler for tests: leases live 5 s, the window has room for any
/// test frame, and `limits` gives the rest (`Limits::default()` for none).
#[cfg(test)]
pub(crate) fn test_scheduler(limits: Limits) -> Scheduler {
    Scheduler::new(
        Limits {
            lease_ttl: Duration::from_secs(5),
            window_bytes: 1 << 30,
            ..limits
        },
        100,
    )
}

/// A snapshot of a job, for status and progress.
#[derive(Debug, Clone, PartialEq)]
pub struct JobInfo {
    pub id: JobId,
    pub spec: JobSpec,
    pub state: JobState,
    pub tiles_total: u64,
    pub tiles_done: u64,
    pub rays: u64,
    /// From submission to the end, or to now while unfinished: `queued`
    /// and then the render.
    pub elapsed: Duration,
    /// The part of `elapsed` spent waiting in the queue: until the first
    /// tile was leased (all of it for a job that never started).
    pub queued: Duration,
    pub error: Option<String>,
    /// 1 for the first job to finish, and so on; 0 while unfinished.
    pub finish_order: u64,
    /// For a sequence: its frames' progress.
    pub frames: Option<FramesInfo>,
}

impl JobInfo {
    /// The part of `elapsed` spent rendering: from the first tile leased to
    /// the end, or to now while unfinished (zero for a job still queued).
    pub fn render(&self) -> Duration {
        self.elapsed.saturating_sub(self.queued)
    }
}

/// A sequence's progress (see `crate::farm::sequences`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FramesInfo {
    pub first: u32,
    pub last: u32,
    /// Frames finished.
    pub done: u32,
    /// Frames rendering now.
    pub in_progress: u32,
    /// The earliest frame in progress: its number, tiles done and tiles.
    pub current: Option<(u32, u64, u64)>,
}

/// A tile handed to a worker, or a span (see [`lease_size`]): adjacent
/// tiles of one band, or whole full-width bands one after the other. Then
/// `rect` is their union and their leases are `id`, `id + 1`, … `id +
/// tiles - 1`, in band order (band by band, left to right).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Lease {
    pub id: LeaseId,
    pub job: JobId,
    pub bundle_hash: String,
    pub camera: String,
    pub rect: Rect,
    /// How many tiles `rect` covers (1 for one tile).
    pub tiles: u32,
    /// The job's memory estimate in bytes, 0 if none (see [`memory`]).
    pub memory_estimate: u64,
    /// The job's frame, for a frame of a sequence.
    pub frame: Option<u32>,
    /// The worker is to upload `rect` as encoded PNG segments (see
    /// [`Scheduler::allow_segments`]). Set when the worker encodes with the
    /// coordinator's encoder and takes spans, the job's output is a PNG
    /// (its name's extension), and `rect` is whole full-width bands whose
    /// rows are whole segments: from a multiple of
    /// [`SEGMENT_ROWS`] to a multiple of it or the frame's bottom (every
    /// run of bands when the tile size is a multiple of 16). Such a lease
    /// is at most [`Limits::max_segment_lease_pixels`]; any other is
    /// floats, as before.
    pub png_segments: bool,
}

/// A span's `rays` shared among its tiles by their pixels (`pixels`, one
/// count a tile, in order): each share rounded down, the last tile the
/// remainder, so the shares add up to `rays` exactly.
pub fn ray_shares(rays: u64, pixels: &[u64]) -> Vec<u64> {
    let whole = pixels.iter().map(|&p| u128::from(p)).sum::<u128>().max(1);
    let mut left = rays;
    pixels
        .iter()
        .enumerate()
        .map(|(k, &p)| {
            if k + 1 == pixels.len() {
                left
            } else {
                let share = ((u128::from(rays) * u128::from(p) / whole) as u64).min(left);
                left -= share;
                share
            }
        })
        .collect()
}

/// What became of a result handed to [`Scheduler::accept_tile`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Accepted {
    /// The tile is now done; `last` says it was the job's last tile.
    New { last: bool },
    /// Late or duplicate (the tile was already done, or the job is over).
    Ignored,
}

/// A job of an earlier run, as the coordinator's database kept it.
#[derive(Debug, Clone)]
pub struct Restored {
    pub id: JobId,
    pub spec: JobSpec,
    pub state: JobState,
    pub submitted: Instant,
    /// For a finished job: how long it took.
    pub elapsed: Option<Duration>,
    /// For a finished job: how much of `elapsed` it rendered (the rest it
    /// waited in the queue).
    pub render: Option<Duration>,
    pub error: Option<String>,
    pub finish_order: u64,
    /// For a finished job: how many tiles it had done.
    pub tiles_done: u64,
    pub rays: u64,
    /// For an unfinished job: the tiles already stored (not leased again).
    pub done_tiles: Vec<u32>,
}

/// Why the scheduler refused something.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SchedError {
    #[error("no job {0}")]
    UnknownJob(JobId),
    #[error("unknown worker {0}")]
    UnknownWorker(WorkerId),
    #[error("{0:?} is not a tile of job {1}")]
    NotATile(Rect, JobId),
    #[error("lease {0} is not worker {1}'s lease on tile {2:?} of job {3}")]
    NotYourLease(LeaseId, WorkerId, Rect, JobId),
    #[error("job {0} is over")]
    JobOver(JobId),
}

/// Running totals since the coordinator started (for `/metrics`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    pub jobs_submitted: u64,
    pub leases_granted: u64,
    /// First valid results (each tile is counted once).
    pub tiles_accepted: u64,
    /// Valid results that lost to an earlier one, or came after the job ended.
    pub tiles_ignored: u64,
    /// Invalid results (wrong size, not finite, wrong tile).
    pub tiles_rejected: u64,
    /// Tiles put back in the queue (an expired lease or an invalid result).
    pub tiles_requeued: u64,
    pub lease_expiries: u64,
    /// Rays of the accepted tiles.
    pub rays: u64,
}

/// Work waiting in the queue.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct QueueDepth {
    /// Jobs not finished (queued or running).
    pub jobs: u64,
    /// Their tiles neither done nor leased.
    pub tiles: u64,
}

/// A job: its spec, its tiles' [`BandWindow`], its progress and the
/// failures of its tiles and workers.
struct Job {
    spec: JobSpec,
    state: JobState,
    window: BandWindow,
    done: u64,
    rays: u64,
    submitted: Instant,
    /// When its first tile was leased.
    started: Option<Instant>,
    finished: Option<Instant>,
    error: Option<String>,
    finish_order: u64,
    /// Failures of tiles not done yet: how many, how many of them were
    /// lost workers, and the last cause.
    failures: HashMap<u32, (u32, u32, String)>,
    /// Failures per worker on this job.
    worker_failures: HashMap<WorkerId, u32>,
    /// Leases that ran out or were refused while their tile is not done
    /// yet: a late result under one of them still counts.
    past_leases: HashMap<LeaseId, (u32, WorkerId)>,
}

/// Whether a result for `rect` of `job` under `lease` may come from
/// `worker` (anyone when `None`), `holder` being who holds the lease
/// ([`Job::holder`]); the error says it is not `worker`'s.
fn check_holder(
    holder: Option<WorkerId>,
    worker: Option<WorkerId>,
    lease: LeaseId,
    rect: Rect,
    job: JobId,
) -> Result<(), SchedError> {
    match (holder, worker) {
        (Some(h), Some(w)) if h == w => Ok(()),
        (Some(_), None) => Ok(()),
        _ => Err(SchedError::NotYourLease(
            lease,
            worker.unwrap_or_default(),
            rect,
            job,
        )),
    }
}

impl Job {
    /// Who holds tile `idx` of this job (`job`) under lease `id`: the
    /// worker of `live` (the lease table's entry for `id`) when it is that
    /// tile's, else the worker of a lease that ran out or was refused while
    /// the tile stayed undone (a late result under it still counts).
    fn holder(
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
    fn set_done(&mut self, idx: u32) {
        self.window.set_done(idx);
        self.failures.remove(&idx);
        self.past_leases.retain(|_, (t, _)| *t != idx);
    }

    /// Drops the bookkeeping only a running job needs.
    fn retire(&mut self) {
        self.window.retire();
        self.failures = HashMap::new();
        self.worker_failures = HashMap::new();
        self.past_leases = HashMap::new();
    }
}

/// Why a lease ends before its tile is done.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Release {
    /// It ran out: the worker holding it was lost.
    Lost,
    /// Its result was invalid, or the worker's render failed.
    Failed,
    /// The worker gave it back unrendered (it is stopping): no one's fault.
    Returned,
}

/// How a lease that starts at a job's pending tile is made up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SpanPlan {
    /// That many whole full-width bands from the tile's (the first tile of
    /// its band), as encoded PNG segments or as floats.
    Bands { bands: u32, segments: bool },
    /// Up to `want` adjacent tiles of the tile's band, from it on, as floats.
    InBand { want: u32 },
}

/// Whether `spec`'s output is a PNG (its name's extension).
fn is_png(spec: &JobSpec) -> bool {
    Format::from_path(Path::new(&spec.output_name)) == Some(Format::Png)
}

/// Whether rows `y0..y1` of a `height`-row frame are whole PNG segments:
/// they start on a multiple of [`SEGMENT_ROWS`] and end on one or at the
/// frame's bottom.
fn whole_segments(y0: u32, y1: u32, height: u32) -> bool {
    y0 % SEGMENT_ROWS == 0 && (y1 % SEGMENT_ROWS == 0 || y1 == height)
}

/// The earlier of `bound` (if any) and `deadline`.
fn earliest(bound: Option<Instant>, deadline: Instant) -> Instant {
    bound.map_or(deadline, |d| d.min(deadline))
}

/// Two jobs render the same shot: the same bundle and camera (frames of a
/// sequence, the same scene again), so one's measured cost is the other's
/// first estimate.
fn same_shot(a: &JobSpec, b: &JobSpec) -> bool {
    a.bundle_hash == b.bundle_hash && a.camera == b.camera
}

/// What a lease starting at pending tile `first` covers (`None`: nothing
/// may go out from there now). `want(cap)` is how many tiles the sizer
/// gives the worker under a cap of `cap` pixels (1 for a worker that takes
/// no spans). From the first tile of a band that is wholly pending, whole
/// bands go out: as encoded segments when `may_encode` (the worker encodes,
/// the output is PNG) and the rows are whole segments, under
/// `max_segment_lease_pixels` and the window at the segment cost; as
/// floats otherwise, under `max_lease_pixels` and the window at the float
/// cost. Failing that (the band is partly taken, or more than the worker's
/// share), adjacent tiles of one band as floats, as before bands were
/// leased whole.
fn span_plan(
    window: &BandWindow,
    spec: &JobSpec,
    first: u32,
    may_encode: bool,
    want: impl Fn(u64) -> u32,
    cfg: &Limits,
) -> Option<SpanPlan> {
    let cols = window.cols();
    let band = first / cols;
    let (width, height) = window.size();
    let tile = spec.tile_size.max(1);
    // Counted as a full band: the last band, shorter, is then under its cap.
    let band_pixels = (width as u64 * tile.min(height) as u64).max(1);
    // The whole bands within what the sizer wants; with `at_least_one` (a
    // segment lease, which can only be whole bands), one band when it
    // wants half a band or more.
    let most_bands = |cap: u64, at_least_one: bool| -> u32 {
        let want = want(cap);
        let by_time = match want / cols {
            0 if at_least_one && want.saturating_mul(2) >= cols => 1,
            n => n,
        };
        let by_pixels = u32::try_from(cap / band_pixels).unwrap_or(u32::MAX);
        by_time.min(by_pixels).min(MAX_SPAN_TILES / cols)
    };
    if first % cols == 0 {
        if may_encode {
            let n = window.whole_bands(band, most_bands(cfg.max_segment_lease_pixels, true), true);
            let y0 = band * tile;
            let whole = (1..=n)
                .rev()
                .find(|&k| whole_segments(y0, (band + k).saturating_mul(tile).min(height), height));
            if let Some(bands) = whole {
                return Some(SpanPlan::Bands {
                    bands,
                    segments: true,
                });
            }
        }
        let n = window.whole_bands(band, most_bands(cfg.max_lease_pixels, false), false);
        if n > 0 {
            return Some(SpanPlan::Bands {
                bands: n,
                segments: false,
            });
        }
    }
    window.band_fits(band, false).then(|| SpanPlan::InBand {
        want: want(cfg.max_lease_pixels).clamp(1, MAX_SPAN_TILES),
    })
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
    failed: Vec<(JobId, String)>,
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

    /// Records that `job`'s scene needs about `bytes` once built (the
    /// larger of what is known wins); see [`memory`].
    pub fn set_memory_estimate(&mut self, job: JobId, bytes: u64, now: Instant) {
        if self.jobs.contains_key(&job) {
            self.memory.set(job, bytes, now);
        }
    }

    /// `job`'s memory estimate in bytes (0: none).
    pub fn memory_estimate(&self, job: JobId) -> u64 {
        self.memory.estimate(job)
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

    /// The measured cost of `job` in core-seconds per pixel, if any.
    pub fn measured_cost(&self, job: JobId) -> Option<f64> {
        self.sizer.cost(job)
    }

    /// Queues a job. `spec.tile_size`, `width` and `height` must be ≥ 1.
    /// A frame of a sequence (`spec.frame` set) takes its id from
    /// [`FRAME_IDS`] on, so the ids users see (stills and sequences) follow
    /// one another.
    pub fn submit(&mut self, spec: JobSpec, now: Instant) -> JobId {
        let id = if spec.frame.is_some() {
            self.next_frame += 1;
            self.next_frame - 1
        } else {
            self.next_job += 1;
            self.next_job - 1
        };
        // An unfinished job of the same scene and camera that has a
        // measured cost (another frame of a sequence, the same scene again)
        // gives the new one its first estimate (see [`lease_size`]).
        let seed = self.queue.iter().find_map(|&(_, other)| {
            let o = self.jobs.get(&other)?;
            same_shot(&o.spec, &spec)
                .then(|| self.sizer.cost(other))
                .flatten()
        });
        if let Some(cost) = seed {
            self.sizer.seed(id, cost);
        }
        let job = self.new_job(spec, now);
        self.queue.insert((Reverse(job.spec.priority), id));
        self.jobs.insert(id, job);
        self.counters.jobs_submitted += 1;
        id
    }

    /// Puts back a job of an earlier run (see [`Restored`]).
    pub fn restore(&mut self, r: Restored, now: Instant) {
        let mut job = self.new_job(r.spec, r.submitted.min(now));
        self.skip_ids_through(r.id);
        if r.state.is_final() {
            self.finished = self.finished.max(r.finish_order);
            job.state = r.state;
            job.done = r.tiles_done;
            job.rays = r.rays;
            job.error = r.error;
            job.finish_order = r.finish_order;
            let end = job.submitted + r.elapsed.unwrap_or_default();
            job.finished = Some(end);
            job.started = r
                .render
                .map(|d| end.checked_sub(d).unwrap_or(job.submitted));
            job.retire();
            self.jobs.insert(r.id, job);
            return;
        }
        let mut done: Vec<u32> = r
            .done_tiles
            .into_iter()
            .filter(|&i| i < job.window.tiles_total())
            .collect();
        done.sort_unstable();
        done.dedup();
        if !done.is_empty() {
            job.window.restore(&done);
            job.state = JobState::Running;
        }
        job.done = done.len() as u64;
        job.rays = r.rays;
        self.queue.insert((Reverse(job.spec.priority), r.id));
        self.jobs.insert(r.id, job);
    }

    fn new_job(&self, spec: JobSpec, now: Instant) -> Job {
        let tile = spec.tile_size.max(1);
        let spec = JobSpec {
            tile_size: tile,
            ..spec
        };
        Job {
            state: JobState::Queued,
            window: BandWindow::new(&spec, self.cfg.window_bytes),
            done: 0,
            rays: 0,
            submitted: now,
            started: None,
            finished: None,
            error: None,
            finish_order: 0,
            failures: HashMap::new(),
            worker_failures: HashMap::new(),
            past_leases: HashMap::new(),
            spec,
        }
    }

    /// The index of `rect` among `job`'s tiles (band order), if it is one.
    pub fn tile_index(&self, job: JobId, rect: Rect) -> Option<u32> {
        self.jobs.get(&job)?.window.tile_index(rect)
    }

    /// The rectangle of tile `idx` of `job`.
    pub fn tile_rect(&self, job: JobId, idx: u32) -> Option<Rect> {
        let j = self.jobs.get(&job)?;
        (idx < j.window.tiles_total()).then(|| j.window.rect(idx))
    }

    /// Whether tile `idx` of `job` is done (`None`: no such job or tile).
    /// For a result that must be taken whole or not at all (encoded
    /// segments covering several tiles).
    pub fn tile_done(&self, job: JobId, idx: u32) -> Option<bool> {
        let j = self.jobs.get(&job)?;
        (idx < j.window.tiles_total()).then(|| j.window.tile_state(idx) == TileState::Done)
    }

    /// The next tile for `worker`, if any job has one it may hand out now.
    pub fn lease(&mut self, worker: WorkerId, now: Instant) -> Result<Option<Lease>, SchedError> {
        self.touch(worker, now)?;
        // Asking for work: no longer paused.
        self.workers.set_paused(worker, None);
        // Expired tiles first; the rest of `expire` is the reaper's.
        self.expire_leases(now);
        let max_fail = self.cfg.max_worker_failures.max(1);
        let limit = self.workers.memory_limit(worker);
        let mut too_small = false;
        for &(_, id) in &self.queue {
            let job = self.jobs.get_mut(&id).expect("queued jobs exist");
            if job
                .worker_failures
                .get(&worker)
                .is_some_and(|&n| n >= max_fail)
            {
                continue;
            }
            let spans = self.sizer.takes_spans(worker);
            // Whether this lease may ask for encoded PNG segments: then the
            // window lets it run further ahead (see [`window`]).
            let may_encode = spans && self.sizer.takes_segments(worker) && is_png(&job.spec);
            if !self.memory.fits(id, limit) {
                too_small |= job.window.next_tile(may_encode).is_some();
                continue;
            }
            let Some(first) = job.window.next_tile(may_encode) else {
                continue;
            };
            // A job not measured yet gets single tiles (they measure it),
            // so never a segment lease: rounded up to a whole band, a
            // frame one or two tiles wide would go whole.
            let measured = self.sizer.cost(id).is_some();
            let plan = span_plan(
                &job.window,
                &job.spec,
                first,
                may_encode && measured,
                |cap| {
                    if !spans {
                        return 1;
                    }
                    let t = job.spec.tile_size as u64;
                    lease_size::tiles_per_lease(
                        self.sizer.cost(id),
                        self.workers.threads(worker).unwrap_or(1),
                        t * t,
                        self.cfg.lease_target,
                        cap,
                    )
                },
                &self.cfg,
            );
            let Some(plan) = plan else {
                // Only a segment lease could go this far ahead, and none
                // fits here.
                continue;
            };
            let (span, rect, segments) = match plan {
                SpanPlan::Bands { bands, segments } => {
                    let cols = job.window.cols();
                    let (width, height) = job.window.size();
                    let y = job.window.rect(first).y;
                    let bottom = job.window.rect(first + bands * cols - 1);
                    let rect = Rect::new(0, y, width, (bottom.y + bottom.h).min(height) - y);
                    let span: Vec<u32> = (first..first + bands * cols).collect();
                    for (i, &tile) in span.iter().enumerate() {
                        job.window
                            .set_leased(tile, self.next_lease + i as u64, segments);
                    }
                    (span, rect, segments)
                }
                SpanPlan::InBand { want } => {
                    // The next tiles while they follow `first` in its band.
                    let mut span = vec![first];
                    let mut rect = job.window.rect(first);
                    job.window.set_leased(first, self.next_lease, false);
                    while (span.len() as u32) < want {
                        let Some(next) = job.window.next_tile(false) else {
                            break;
                        };
                        let r = job.window.rect(next);
                        if next != span[span.len() - 1] + 1
                            || r.y != rect.y
                            || r.x != rect.x + rect.w
                        {
                            break;
                        }
                        span.push(next);
                        rect.w += r.w;
                        job.window
                            .set_leased(next, self.next_lease + span.len() as u64 - 1, false);
                    }
                    (span, rect, false)
                }
            };
            let lease_id = self.next_lease;
            self.next_lease += span.len() as u64;
            self.counters.leases_granted += span.len() as u64;
            if job.state == JobState::Queued {
                job.state = JobState::Running;
            }
            job.started.get_or_insert(now);
            let deadline = now + self.cfg.lease_ttl;
            self.earliest_deadline = Some(earliest(self.earliest_deadline, deadline));
            // A span's tiles are consecutive: the table derives each
            // one's lease from the first's.
            debug_assert!(span.windows(2).all(|t| t[1] == t[0] + 1));
            self.leases.insert_span(NewSpan {
                first: lease_id,
                job: id,
                first_tile: span[0],
                count: span.len() as u32,
                worker,
                deadline,
                granted: now,
                span_pixels: rect.pixel_count() as u64,
            });
            return Ok(Some(Lease {
                id: lease_id,
                job: id,
                bundle_hash: job.spec.bundle_hash.clone(),
                camera: job.spec.camera.clone(),
                rect,
                tiles: span.len() as u32,
                memory_estimate: self.memory.estimate(id),
                frame: job.spec.frame,
                png_segments: segments,
            }));
        }
        if too_small {
            // Work is waiting that this worker cannot hold.
            self.workers.set_paused(worker, Some("memory"));
        }
        Ok(None)
    }

    /// Renews `worker`'s leases; returns those it should drop.
    pub fn heartbeat(
        &mut self,
        worker: WorkerId,
        leases: &[LeaseId],
        now: Instant,
    ) -> Result<Vec<LeaseId>, SchedError> {
        self.touch(worker, now)?;
        let ttl = self.cfg.lease_ttl;
        let mut dropped = Vec::new();
        let mut renewed = false;
        for &l in leases {
            if self.leases.renew(l, worker, now, now + ttl) {
                renewed = true;
            } else {
                dropped.push(l);
            }
        }
        if renewed {
            // Later than the renewed deadlines unless the clock went back.
            self.earliest_deadline = Some(earliest(self.earliest_deadline, now + ttl));
        }
        Ok(dropped)
    }

    /// Re-queues the tiles of leases past their deadline; returns how many.
    /// Also forgets long-silent workers and fails the jobs no live worker
    /// can take (what the farm's reaper runs a few times a lease lifetime).
    pub fn expire(&mut self, now: Instant) -> usize {
        let expired = self.expire_leases(now);
        // Workers silent for ten lease lifetimes are forgotten; one that
        // comes back is told to register again.
        let forget = (self.cfg.lease_ttl * 10).max(Duration::from_secs(60));
        self.workers.forget_silent(forget, now);
        let workers = &self.workers;
        self.sizer.retain_workers(|w| workers.threads(w).is_some());
        self.fail_stranded_jobs(now);
        self.fail_jobs_too_big(now);
        expired
    }

    /// Re-queues the tiles of leases past their deadline; returns how many.
    /// Scans the leases only when the earliest deadline has passed.
    fn expire_leases(&mut self, now: Instant) -> usize {
        if self.earliest_deadline.is_none_or(|d| d >= now) {
            return 0;
        }
        let (expired, first) = self.leases.expired(now);
        self.earliest_deadline = first;
        for &id in &expired {
            let Some((worker, job, tile)) = self.leases.get(id).map(|e| (e.worker, e.job, e.tile))
            else {
                continue;
            };
            tracing::warn!(
                worker,
                lease = id,
                job,
                tile,
                "lease expired: the worker went silent (lost); its tile is re-queued"
            );
            let cause = format!("lease expired (worker {worker} went silent)");
            self.release(id, &cause, Release::Lost);
        }
        self.counters.lease_expiries += expired.len() as u64;
        expired.len()
    }

    /// Fails the jobs no live worker can hold once their grace has passed
    /// (see [`memory`]).
    fn fail_jobs_too_big(&mut self, now: Instant) {
        let live = self.workers.live(self.cfg.lease_ttl, now);
        let limits: Vec<u64> = live.iter().map(|&w| self.workers.memory_limit(w)).collect();
        let queued: Vec<JobId> = self.queue.iter().map(|&(_, id)| id).collect();
        for id in queued {
            if self.failed.iter().any(|(f, _)| *f == id) {
                continue;
            }
            if let Some(msg) = self.memory.too_big(id, &limits, self.cfg.memory_grace, now) {
                self.failed.push((id, msg));
            }
        }
    }

    /// `worker` declines `lease` because its scene needs about `bytes`,
    /// more than its memory limit: the tile is re-queued without counting
    /// a failure, the job keeps the estimate (so it is not leased to
    /// workers that small again), and the worker shows as paused for
    /// "memory" until it takes a tile. The claim proves only that the
    /// scene needs more than the worker's own registered limit, so the
    /// estimate rises to just above that limit, no further (one worker's
    /// word cannot keep a job from a bigger one). A claim its own limit
    /// contradicts (no limit, or one that holds `bytes`) is false: the
    /// tile is re-queued and the failure counted against the worker on
    /// that job, not against the tile. False when the claim was false.
    pub fn decline_lease(
        &mut self,
        worker: WorkerId,
        lease: LeaseId,
        bytes: u64,
        now: Instant,
    ) -> Result<bool, SchedError> {
        let limit = self.workers.memory_limit(worker);
        let honest = limit > 0 && bytes > limit;
        if let Some(e) = self.leases.get(lease).filter(|e| e.worker == worker) {
            if honest {
                self.memory
                    .set(e.job, bytes.min(limit.saturating_add(1)), now);
            } else if let Some(j) = self.jobs.get_mut(&e.job) {
                *j.worker_failures.entry(worker).or_default() += 1;
            }
        }
        self.return_lease(worker, lease, None, now)?;
        if honest {
            self.workers.set_paused(worker, Some("memory"));
        }
        Ok(honest)
    }

    /// Fails the jobs that every live worker is kept from (each failed too
    /// many of their tiles): they would otherwise wait for ever, although no
    /// single tile reached its failure limit. Lost workers do not count, so
    /// a job whose workers all crashed waits for new ones.
    fn fail_stranded_jobs(&mut self, now: Instant) {
        let ttl = self.cfg.lease_ttl;
        let live = self.workers.live(ttl, now);
        if live.is_empty() {
            return;
        }
        let max = self.cfg.max_worker_failures.max(1);
        for &(_, id) in &self.queue {
            let j = &self.jobs[&id];
            let benched = |w: &WorkerId| j.worker_failures.get(w).is_some_and(|&n| n >= max);
            if !live.iter().all(benched)
                || self.leases.holds_job(id)
                || self.failed.iter().any(|(f, _)| *f == id)
            {
                continue;
            }
            let last = j
                .failures
                .iter()
                .max_by_key(|(tile, (n, _, _))| (*n, std::cmp::Reverse(**tile)))
                .map(|(tile, (n, _, cause))| {
                    format!("; tile {tile} failed {n} times, last: {cause}")
                })
                .unwrap_or_default();
            let msg = format!(
                "every live worker ({}) failed {max} or more tiles of this job and is kept \
                 from it{last}",
                live.len()
            );
            self.failed.push((id, msg));
        }
    }

    /// Removes a lease, counts a failure of its tile and worker (unless it
    /// was returned), and puts the tile back in the queue if it is not done.
    /// A tile failing too often fails its job (see
    /// [`Scheduler::take_failed`]).
    fn release(&mut self, lease: LeaseId, cause: &str, why: Release) {
        let Some(e) = self.leases.remove(lease) else {
            return;
        };
        let Some(job) = self.jobs.get_mut(&e.job) else {
            return;
        };
        if job.state.is_final() || job.window.tile_state(e.tile) != TileState::Leased(lease) {
            return;
        }
        job.window.requeue(e.tile);
        self.counters.tiles_requeued += 1;
        job.past_leases.insert(lease, (e.tile, e.worker));
        if why == Release::Returned {
            return;
        }
        *job.worker_failures.entry(e.worker).or_default() += 1;
        let r = job.window.rect(e.tile);
        let f = job.failures.entry(e.tile).or_insert((0, 0, String::new()));
        f.0 += 1;
        if why == Release::Lost {
            f.1 += 1;
        }
        f.2 = cause.to_string();
        let tile = format!("tile {} ({}x{} at ({}, {}))", e.tile, r.w, r.h, r.x, r.y);
        let msg = if f.1 >= self.cfg.max_tile_losses.max(1) {
            format!(
                "{tile} lost the worker rendering it {} times (it crashed, hung or was cut \
                 off while holding the tile); last: {}",
                f.1, f.2
            )
        } else if f.0 >= self.cfg.max_tile_failures.max(1) {
            format!("{tile} failed {} times; last: {}", f.0, f.2)
        } else {
            return;
        };
        // Several tiles may reach their limit at once (a worker lost while
        // holding more than one): the job's error names them all.
        match self.failed.iter_mut().find(|(j, _)| *j == e.job) {
            Some((_, m)) => {
                m.push_str("; also ");
                m.push_str(&msg);
            }
            None => self.failed.push((e.job, msg)),
        }
    }

    /// `worker` gives `lease` back before its tile is done: without `error`
    /// (it is stopping) the tile is re-queued and nothing is counted; with
    /// one (its render failed) the failure counts against the tile and the
    /// worker like an invalid result. A lease that is not `worker`'s, or is
    /// gone already, is refused or left alone.
    pub fn return_lease(
        &mut self,
        worker: WorkerId,
        lease: LeaseId,
        error: Option<&str>,
        now: Instant,
    ) -> Result<(), SchedError> {
        self.touch(worker, now)?;
        match self.leases.get(lease) {
            Some(e) if e.worker != worker => {
                let (job, rect) = (e.job, self.jobs[&e.job].window.rect(e.tile));
                Err(SchedError::NotYourLease(lease, worker, rect, job))
            }
            Some(_) => {
                match error {
                    None => self.release(lease, "returned", Release::Returned),
                    Some(e) => {
                        let cause = format!("worker {worker}: {e}");
                        self.release(lease, &cause, Release::Failed);
                    }
                }
                Ok(())
            }
            None => Ok(()),
        }
    }

    /// Jobs that failed because a tile failed too often, with the reason;
    /// the caller ends them with [`Scheduler::finish`].
    pub fn take_failed(&mut self) -> Vec<(JobId, String)> {
        std::mem::take(&mut self.failed)
    }

    /// Checks that a result for `rect` of `job` comes under a lease that was
    /// given to `worker` (any worker when `None`) for that tile. A result for
    /// a tile already done, or of a job that is over, passes (and is
    /// ignored later).
    pub fn check_lease(
        &self,
        job: JobId,
        rect: Rect,
        lease: LeaseId,
        worker: Option<WorkerId>,
    ) -> Result<(), SchedError> {
        let j = self.jobs.get(&job).ok_or(SchedError::UnknownJob(job))?;
        if j.state.is_final() {
            return Ok(());
        }
        let idx = j
            .window
            .tile_index(rect)
            .ok_or(SchedError::NotATile(rect, job))?;
        if j.window.tile_state(idx) == TileState::Done {
            return Ok(());
        }
        let holder = j.holder(job, idx, lease, self.leases.get(lease));
        check_holder(holder, worker, lease, rect, job)
    }

    /// The tile index of `rect` in `job`, checking that it is one of its tiles.
    pub fn check_tile(&self, job: JobId, rect: Rect) -> Result<(), SchedError> {
        let j = self.jobs.get(&job).ok_or(SchedError::UnknownJob(job))?;
        if j.state.is_final() {
            return Ok(()); // Retired: the result will be ignored anyway.
        }
        j.window
            .tile_index(rect)
            .map(|_| ())
            .ok_or(SchedError::NotATile(rect, job))
    }

    /// The tiles of `job` that a result for `rect` brings, in band order:
    /// `rect` itself when it is one tile, or the tiles of a span: adjacent
    /// tiles of one band, or whole full-width bands one after the other,
    /// band by band and left to right (see [`lease_size`]), at most
    /// [`MAX_SPAN_TILES`] of them. Its pixels are at most
    /// [`Limits::max_segment_lease_pixels`] when it could be a segment lease
    /// (a PNG frame's whole bands that are whole segments,
    /// [`Lease::png_segments`]), [`Limits::max_lease_pixels`] otherwise;
    /// [`Scheduler::span_tiles_as`] applies the cap of the upload's kind
    /// once it is known. A job that is over: `rect` alone (the result will
    /// be ignored anyway).
    pub fn span_tiles(&self, job: JobId, rect: Rect) -> Result<Vec<Rect>, SchedError> {
        self.span_tiles_capped(job, rect, None)
    }

    /// [`Scheduler::span_tiles`] for an upload of encoded segments
    /// (`png_segments`) or of floats: a segment upload must be whole
    /// segments of whole full-width bands of a PNG frame, at most
    /// [`Limits::max_segment_lease_pixels`]; a float upload at most
    /// [`Limits::max_lease_pixels`] (a single tile may be bigger).
    pub fn span_tiles_as(
        &self,
        job: JobId,
        rect: Rect,
        png_segments: bool,
    ) -> Result<Vec<Rect>, SchedError> {
        self.span_tiles_capped(job, rect, Some(png_segments))
    }

    fn span_tiles_capped(
        &self,
        job: JobId,
        rect: Rect,
        kind: Option<bool>,
    ) -> Result<Vec<Rect>, SchedError> {
        let j = self.jobs.get(&job).ok_or(SchedError::UnknownJob(job))?;
        if j.state.is_final() {
            return Ok(vec![rect]);
        }
        let not_a_span = || SchedError::NotATile(rect, job);
        let w = &j.window;
        let (width, height) = w.size();
        let t = j.spec.tile_size;
        let (x1, y1) = (rect.x as u64 + rect.w as u64, rect.y as u64 + rect.h as u64);
        // On the tile grid, inside the frame, ending on the grid or at the
        // frame's edge.
        if rect.w == 0
            || rect.h == 0
            || rect.x % t != 0
            || rect.y % t != 0
            || x1 > width as u64
            || y1 > height as u64
            || (x1 % t as u64 != 0 && x1 != width as u64)
            || (y1 % t as u64 != 0 && y1 != height as u64)
        {
            return Err(not_a_span());
        }
        let (x1, y1) = (x1 as u32, y1 as u32);
        let full_width = rect.x == 0 && x1 == width;
        let (band0, bands) = (rect.y / t, (y1 - rect.y).div_ceil(t));
        if bands > 1 && !full_width {
            return Err(not_a_span());
        }
        let (c0, c1) = (rect.x / t, x1.div_ceil(t));
        let count = bands as u64 * (c1 - c0) as u64;
        let segment_shaped = full_width && is_png(&j.spec) && whole_segments(rect.y, y1, height);
        let cap = match kind {
            Some(true) if !segment_shaped => return Err(not_a_span()),
            Some(true) => self.cfg.max_segment_lease_pixels,
            None if segment_shaped => self
                .cfg
                .max_segment_lease_pixels
                .max(self.cfg.max_lease_pixels),
            // A single tile of any size is its own lease.
            _ if count == 1 => u64::MAX,
            _ => self.cfg.max_lease_pixels,
        };
        if count > MAX_SPAN_TILES as u64 || rect.pixel_count() as u64 > cap {
            return Err(not_a_span());
        }
        let cols = w.cols();
        let mut parts = Vec::with_capacity(count as usize);
        for band in band0..band0 + bands {
            for c in c0..c1 {
                parts.push(w.rect(band * cols + c));
            }
        }
        Ok(parts)
    }

    /// Records a valid result for `rect` of `job`.
    pub fn accept_tile(
        &mut self,
        job: JobId,
        rect: Rect,
        rays: u64,
        now: Instant,
    ) -> Result<Accepted, SchedError> {
        self.accept_rendered(job, rect, rays, None, now)
    }

    /// [`Scheduler::accept_tile`] for a result whose worker said how long
    /// it spent rendering its lease (`render`; `None`: an older worker that
    /// does not say). The job's measured cost comes from that time rather
    /// than from grant to result, which on a busy coordinator is mostly
    /// queueing (see [`lease_size::render_time`]).
    pub fn accept_rendered(
        &mut self,
        job: JobId,
        rect: Rect,
        rays: u64,
        render: Option<Duration>,
        now: Instant,
    ) -> Result<Accepted, SchedError> {
        let measured_before = self.sizer.cost(job).is_some();
        let j = self.jobs.get_mut(&job).ok_or(SchedError::UnknownJob(job))?;
        if j.state.is_final() {
            self.counters.tiles_ignored += 1;
            return Ok(Accepted::Ignored);
        }
        let idx = j
            .window
            .tile_index(rect)
            .ok_or(SchedError::NotATile(rect, job))?;
        let worker = match j.window.tile_state(idx) {
            TileState::Done => None,
            // Never handed out: not a result of this coordinator's leases.
            TileState::Pending if j.window.is_fresh(idx) => None,
            TileState::Leased(l) => Some(self.leases.remove(l).map(|e| {
                let threads = self.workers.threads(e.worker).unwrap_or(1);
                let took =
                    lease_size::render_time(now.saturating_duration_since(e.granted), render);
                self.sizer.observe(job, took, threads, e.span_pixels);
                e.worker
            })),
            // A late result under a lease that ran out.
            TileState::Pending => Some(
                j.past_leases
                    .values()
                    .find(|(t, _)| *t == idx)
                    .map(|&(_, w)| w),
            ),
        };
        let Some(worker) = worker else {
            self.counters.tiles_ignored += 1;
            return Ok(Accepted::Ignored);
        };
        j.set_done(idx);
        j.done += 1;
        // Ray counts come from workers: a huge one saturates, never wraps.
        j.rays = j.rays.saturating_add(rays);
        let last = j.done == j.window.tiles_total() as u64;
        self.counters.tiles_accepted += 1;
        self.counters.rays = self.counters.rays.saturating_add(rays);
        if let Some(w) = worker {
            self.workers.credit(w, rays, now);
        }
        if !measured_before {
            self.seed_unmeasured_like(job);
        }
        Ok(Accepted::New { last })
    }

    /// `job` has just been measured for the first time: its unfinished
    /// siblings (the same scene and camera) not measured yet start from its
    /// cost. Frames submitted together (a sequence's first frames, a batch)
    /// would otherwise each begin with single-tile leases until each has
    /// its own measurement; on a big farm that is thousands of them.
    fn seed_unmeasured_like(&mut self, job: JobId) {
        let (Some(cost), Some(j)) = (self.sizer.cost(job), self.jobs.get(&job)) else {
            return;
        };
        for &(_, other) in &self.queue {
            let like = self
                .jobs
                .get(&other)
                .is_some_and(|o| same_shot(&o.spec, &j.spec));
            if like && self.sizer.cost(other).is_none() {
                self.sizer.seed(other, cost);
            }
        }
    }

    /// An invalid result arrived under `lease`: put the tile back at once
    /// (unless someone else holds it or it is done).
    pub fn reject_tile(&mut self, lease: LeaseId, cause: &str) {
        self.counters.tiles_rejected += 1;
        self.release(lease, cause, Release::Failed);
    }

    /// Moves an unfinished job to priority `priority` (its place among jobs
    /// of equal priority stays its submission order).
    pub fn set_priority(&mut self, job: JobId, priority: i32) -> Result<(), SchedError> {
        let j = self.jobs.get_mut(&job).ok_or(SchedError::UnknownJob(job))?;
        if j.state.is_final() {
            return Err(SchedError::JobOver(job));
        }
        self.queue.remove(&(Reverse(j.spec.priority), job));
        j.spec.priority = priority;
        self.queue.insert((Reverse(priority), job));
        Ok(())
    }

    /// Ends a job: `Ok` when its output is in place, `Err` when it failed.
    pub fn finish(&mut self, job: JobId, result: Result<(), String>, now: Instant) {
        let Some(j) = self.jobs.get_mut(&job) else {
            return;
        };
        if j.state.is_final() {
            return;
        }
        self.finished += 1;
        j.finish_order = self.finished;
        j.finished = Some(now);
        match result {
            Ok(()) => j.state = JobState::Done,
            Err(e) => {
                j.state = JobState::Failed;
                j.error = Some(e);
            }
        }
        self.retire(job);
    }

    /// What [`Scheduler::finish`] would make of `job` (`None` when there is
    /// no such job or it is over already), for recording before it is done.
    pub fn finish_info(
        &self,
        job: JobId,
        result: &Result<(), String>,
        now: Instant,
    ) -> Option<JobInfo> {
        let mut info = self.info(job, now).filter(|i| !i.state.is_final())?;
        info.finish_order = self.finished + 1;
        match result {
            Ok(()) => info.state = JobState::Done,
            Err(e) => {
                info.state = JobState::Failed;
                info.error = Some(e.clone());
            }
        }
        Some(info)
    }

    /// What [`Scheduler::cancel`] would make of `job`, like
    /// [`Scheduler::finish_info`].
    pub fn cancel_info(&self, job: JobId, now: Instant) -> Option<JobInfo> {
        let mut info = self.info(job, now).filter(|i| !i.state.is_final())?;
        info.state = JobState::Cancelled;
        Some(info)
    }

    /// Stops handing out `job`'s tiles and drops its leases, leaving its
    /// state as it is (its end could not be recorded yet).
    pub fn hold(&mut self, job: JobId) {
        if let Some(j) = self.jobs.get(&job) {
            self.queue.remove(&(Reverse(j.spec.priority), job));
            self.drop_leases(job);
        }
    }

    /// Forgets an ended job (retention); an unfinished one stays.
    pub fn remove(&mut self, job: JobId) -> bool {
        if self.jobs.get(&job).is_some_and(|j| j.state.is_final()) {
            self.jobs.remove(&job);
            true
        } else {
            false
        }
    }

    /// Ended jobs with when they ended, newest first.
    pub fn ended(&self) -> Vec<(JobId, Instant)> {
        let mut v: Vec<(JobId, Instant)> = self
            .jobs
            .iter()
            .filter(|(_, j)| j.state.is_final())
            .map(|(&id, j)| (id, j.finished.unwrap_or(j.submitted)))
            .collect();
        v.sort_unstable_by_key(|&(id, t)| Reverse((t, id)));
        v
    }

    /// Takes the next job id for something that is not a scheduler job (a
    /// sequence, whose frames are jobs).
    pub fn reserve_id(&mut self) -> JobId {
        let id = self.next_job;
        self.next_job += 1;
        id
    }

    /// Never gives an id up to `id` (ids of an earlier run, or whose output
    /// directory exists).
    pub fn skip_ids_through(&mut self, id: JobId) {
        let next = if id >= FRAME_IDS {
            &mut self.next_frame
        } else {
            &mut self.next_job
        };
        *next = (*next).max(id.saturating_add(1));
    }

    /// Cancels an unfinished job; its leases are dropped at the workers' next
    /// heartbeat. Returns the state the job is in afterwards.
    pub fn cancel(&mut self, job: JobId, now: Instant) -> Result<JobState, SchedError> {
        let j = self.jobs.get_mut(&job).ok_or(SchedError::UnknownJob(job))?;
        if !j.state.is_final() {
            j.state = JobState::Cancelled;
            j.finished = Some(now);
            self.retire(job);
        }
        Ok(self.jobs[&job].state)
    }

    fn retire(&mut self, job: JobId) {
        self.sizer.forget_job(job);
        self.memory.remove(job);
        self.drop_leases(job);
        let j = self.jobs.get_mut(&job).expect("job exists");
        self.queue.remove(&(Reverse(j.spec.priority), job));
        j.retire();
    }

    /// Forgets the leases of `job`'s tiles. Its window names them: a lease
    /// is kept only while its tile is out under it (done or re-queued, the
    /// lease goes), so this never scans the farm's lease table for the
    /// job's few.
    fn drop_leases(&mut self, job: JobId) {
        if let Some(j) = self.jobs.get(&job) {
            for l in j.window.leases() {
                self.leases.remove(l);
            }
        }
    }

    pub fn info(&self, job: JobId, now: Instant) -> Option<JobInfo> {
        let j = self.jobs.get(&job)?;
        let end = j.finished.unwrap_or(now);
        Some(JobInfo {
            id: job,
            spec: j.spec.clone(),
            state: j.state,
            tiles_total: j.window.tiles_total() as u64,
            tiles_done: j.done,
            rays: j.rays,
            elapsed: end.saturating_duration_since(j.submitted),
            queued: j
                .started
                .unwrap_or(end)
                .min(end)
                .saturating_duration_since(j.submitted),
            error: j.error.clone(),
            finish_order: j.finish_order,
            frames: None,
        })
    }

    /// Every job, by id.
    pub fn list(&self, now: Instant) -> Vec<JobInfo> {
        self.list_from(0, usize::MAX, now).0
    }

    /// Up to `limit` jobs by id from id `from` on, and the id the next page
    /// starts at (`None` after the last job).
    pub fn list_from(
        &self,
        from: JobId,
        limit: usize,
        now: Instant,
    ) -> (Vec<JobInfo>, Option<JobId>) {
        let mut ids: Vec<JobId> = self.jobs.keys().copied().filter(|&id| id >= from).collect();
        ids.sort_unstable();
        let next = ids.get(limit).copied();
        ids.truncate(limit);
        let page = ids
            .into_iter()
            .filter_map(|id| self.info(id, now))
            .collect();
        (page, next)
    }

    /// Number of live leases.
    #[cfg(test)]
    fn lease_count(&self) -> usize {
        self.leases.len()
    }

    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// Unfinished jobs and their tiles that wait for a worker.
    pub fn queue_depth(&self) -> QueueDepth {
        let mut d = QueueDepth::default();
        for &(_, id) in &self.queue {
            let j = &self.jobs[&id];
            d.jobs += 1;
            d.tiles += (j.window.tiles_total() as u64)
                .saturating_sub(j.done)
                .saturating_sub(u64::from(j.window.leased()));
        }
        d
    }

    /// Every known worker, by id, with what it holds and how fast it went
    /// over the last few seconds. What a worker holds is given as few
    /// rects as cover exactly its leased tiles: a span of whole bands is
    /// one rect, not one for each of its (hundreds of) tiles, which the
    /// monitor would list and this would build under the farm's lock.
    pub fn workers(&self, now: Instant) -> Vec<WorkerInfo> {
        let mut held: HashMap<WorkerId, Vec<(JobId, Rect)>> = HashMap::new();
        // Runs of consecutive tiles in lease id order: a span's tiles
        // follow each other, row-major.
        let mut last: Option<(JobId, &Job)> = None;
        for run in self.leases.runs() {
            let job = match last {
                Some((id, job)) if id == run.job => job,
                _ => &self.jobs[&run.job],
            };
            last = Some((run.job, job));
            let list = held.entry(run.worker).or_default();
            let cols = job.window.cols();
            let (mut t, end) = (run.first_tile, run.first_tile + run.len);
            while t < end {
                // The run's tiles in `t`'s band: one rect.
                let stop = end.min((t / cols + 1) * cols);
                let (a, b) = (job.window.rect(t), job.window.rect(stop - 1));
                let rect = Rect::new(a.x, a.y, b.x + b.w - a.x, a.h);
                match list.last_mut() {
                    // The next tiles of the same band: the rect grows right.
                    Some((j, r))
                        if *j == run.job
                            && r.y == rect.y
                            && r.h == rect.h
                            && r.x + r.w == rect.x =>
                    {
                        r.w += rect.w;
                    }
                    _ => list.push((run.job, rect)),
                }
                t = stop;
            }
        }
        for list in held.values_mut() {
            merge_stacked(list);
        }
        self.workers.list(held, self.cfg.lease_ttl, now)
    }

    /// Rays per second of the whole farm over the last few seconds.
    pub fn rays_per_second(&self, now: Instant) -> f64 {
        self.workers.rays_per_second(now)
    }

    fn touch(&mut self, worker: WorkerId, now: Instant) -> Result<(), SchedError> {
        if self.workers.touch(worker, now) {
            Ok(())
        } else {
            Err(SchedError::UnknownWorker(worker))
        }
    }
}

/// Merges rects of one job stacked exactly on top of each other (the same
/// columns, the lower starting where the upper ends) into one, so that the
/// rects still cover exactly the same pixels: the bands of a span become
/// one rect.
fn merge_stacked(list: &mut Vec<(JobId, Rect)>) {
    list.sort_unstable_by_key(|&(j, r)| (j, r.x, r.w, r.y));
    let mut out: Vec<(JobId, Rect)> = Vec::with_capacity(list.len());
    for &(j, r) in list.iter() {
        match out.last_mut() {
            Some((oj, o)) if *oj == j && o.x == r.x && o.w == r.w && o.y + o.h == r.y => {
                o.h += r.h;
            }
            _ => out.push((j, r)),
        }
    }
    *list = out;
}

#[cfg(test)]
mod span_tests;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::workers::WorkerState;

    fn spec(priority: i32, w: u32, h: u32, tile: u32) -> JobSpec {
        JobSpec {
            priority,
            ..test_spec(w, h, tile, "out.png")
        }
    }

    /// Shares by pixels, against hand-computed closed forms: rounded
    /// down, the remainder to the last tile, never more than there is,
    /// and no overflow for the largest counts.
    #[test]
    fn rays_are_shared_by_pixels_and_add_up() {
        assert_eq!(ray_shares(1000, &[100, 100, 200]), [250, 250, 500]);
        assert_eq!(ray_shares(10, &[1, 1, 1]), [3, 3, 4]);
        assert_eq!(ray_shares(7, &[5]), [7]);
        assert_eq!(ray_shares(0, &[4, 4]), [0, 0]);
        assert_eq!(ray_shares(5, &[0, 0]), [0, 5]);
        assert!(ray_shares(5, &[]).is_empty());
        let big = ray_shares(u64::MAX, &[u64::MAX, u64::MAX]);
        assert_eq!(big, [u64::MAX / 2, u64::MAX - u64::MAX / 2]);
    }

    fn sched() -> (Scheduler, Instant, WorkerId) {
        let now = Instant::now();
        let mut s = test_scheduler(Limits::default());
        let w = s.register_worker(now, None);
        (s, now, w)
    }

    use trevi_core::tile::band_order_tiles;

    #[test]
    fn jobs_run_by_priority_then_submission_order() {
        let (mut s, now, w) = sched();
        let low = s.submit(spec(0, 4, 4, 4), now);
        let high = s.submit(spec(5, 4, 4, 4), now);
        let low2 = s.submit(spec(0, 4, 4, 4), now);
        let order: Vec<JobId> = (0..3)
            .map(|_| s.lease(w, now).unwrap().unwrap().job)
            .collect();
        assert_eq!(order, vec![high, low, low2]);
        assert_eq!(s.lease(w, now).unwrap(), None);
    }

    #[test]
    fn tiles_go_out_in_band_order_and_idle_workers_take_the_next_job() {
        let (mut s, now, w) = sched();
        let a = s.submit(spec(1, 20, 10, 8), now);
        let b = s.submit(spec(0, 8, 8, 8), now);
        let rects: Vec<Rect> = (0..6)
            .map(|_| s.lease(w, now).unwrap().unwrap())
            .filter(|l| l.job == a)
            .map(|l| l.rect)
            .collect();
        assert_eq!(rects, band_order_tiles(20, 10, 8));
        assert_eq!(s.lease(w, now).unwrap().unwrap().job, b);
        assert_eq!(s.info(a, now).unwrap().state, JobState::Running);
    }

    /// Expiry scans the leases only once the earliest deadline has passed;
    /// that bound must never hide a lease past its deadline. A seeded
    /// random run of leases, heartbeats (with the clock also set back) and
    /// expiries against a model that checks every deadline each time.
    #[test]
    fn expiry_finds_every_lease_past_its_deadline_whatever_the_heartbeats() {
        let t0 = Instant::now();
        let ttl = Duration::from_secs(5);
        let mut s = test_scheduler(Limits {
            max_tile_losses: u32::MAX,
            max_tile_failures: u32::MAX,
            max_worker_failures: u32::MAX,
            ..Limits::default()
        });
        assert_eq!(s.cfg.lease_ttl, ttl);
        let workers = [s.register_worker(t0, None), s.register_worker(t0, None)];
        s.submit(spec(0, 32, 32, 1), t0);
        // The model: lease id -> (worker, deadline).
        let mut model: HashMap<LeaseId, (WorkerId, Instant)> = HashMap::new();
        let expire_model = |model: &mut HashMap<LeaseId, (WorkerId, Instant)>, now| {
            let before = model.len();
            model.retain(|_, (_, d)| *d >= now);
            before - model.len()
        };
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        let mut next = move |n: u64| {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng % n
        };
        let mut ms: u64 = 0;
        let (mut expired_total, mut renewed_total) = (0, 0);
        for _ in 0..3000 {
            // Mostly forward, sometimes back (never before t0).
            ms = (ms + next(1500)).saturating_sub(next(400));
            let now = t0 + Duration::from_millis(ms);
            let w = workers[next(2) as usize];
            match next(3) {
                0 => {
                    expire_model(&mut model, now);
                    if let Some(l) = s.lease(w, now).unwrap() {
                        model.insert(l.id, (w, now + ttl));
                    }
                }
                1 => {
                    let mine: Vec<LeaseId> = model
                        .iter()
                        .filter(|(_, (o, _))| *o == w)
                        .map(|(&id, _)| id)
                        .collect();
                    let mut dropped = s.heartbeat(w, &mine, now).unwrap();
                    dropped.sort();
                    let mut want = Vec::new();
                    for id in mine {
                        let e = model.get_mut(&id).unwrap();
                        if e.1 >= now {
                            e.1 = now + ttl;
                            renewed_total += 1;
                        } else {
                            want.push(id);
                        }
                    }
                    want.sort();
                    assert_eq!(dropped, want, "at {ms} ms");
                }
                _ => {
                    let n = expire_model(&mut model, now);
                    expired_total += n;
                    assert_eq!(s.expire(now), n, "at {ms} ms");
                }
            }
        }
        // The run did both things many times.
        assert!(
            expired_total > 100 && renewed_total > 100,
            "{expired_total} {renewed_total}"
        );
    }

    #[test]
    fn heartbeats_renew_and_missed_deadlines_requeue_first() {
        let (mut s, t0, w) = sched();
        let j = s.submit(spec(0, 8, 4, 4), t0);
        let l1 = s.lease(w, t0).unwrap().unwrap();
        let l2 = s.lease(w, t0).unwrap().unwrap();
        let t1 = t0 + Duration::from_secs(4);
        assert_eq!(s.heartbeat(w, &[l2.id], t1).unwrap(), Vec::<LeaseId>::new());
        let t2 = t0 + Duration::from_secs(6);
        // l1 missed its deadline, l2 was renewed until t1+5.
        assert_eq!(s.expire(t2), 1);
        assert_eq!(s.heartbeat(w, &[l1.id, l2.id], t2).unwrap(), vec![l1.id]);
        let again = s.lease(w, t2).unwrap().unwrap();
        assert_eq!((again.job, again.rect), (j, l1.rect));
        assert_ne!(again.id, l1.id);
        // An unknown worker is told so.
        assert_eq!(s.lease(999, t2), Err(SchedError::UnknownWorker(999)));
    }

    #[test]
    fn first_valid_result_wins_late_and_duplicate_ignored() {
        let (mut s, t0, w) = sched();
        let w2 = s.register_worker(t0, None);
        let j = s.submit(spec(0, 4, 4, 4), t0);
        let l1 = s.lease(w, t0).unwrap().unwrap();
        let t1 = t0 + Duration::from_secs(6);
        s.expire(t1);
        let l2 = s.lease(w2, t1).unwrap().unwrap();
        assert_eq!(l2.rect, l1.rect);
        // The late worker finishes first: its result counts.
        assert_eq!(
            s.accept_tile(j, l1.rect, 7, t1),
            Ok(Accepted::New { last: true })
        );
        assert_eq!(s.accept_tile(j, l2.rect, 7, t1), Ok(Accepted::Ignored));
        // w2's lease is gone.
        assert_eq!(s.heartbeat(w2, &[l2.id], t1).unwrap(), vec![l2.id]);
        assert_eq!(s.info(j, t1).unwrap().rays, 7);
        assert_eq!(
            s.accept_tile(j, Rect::new(1, 0, 3, 4), 0, t1),
            Err(SchedError::NotATile(Rect::new(1, 0, 3, 4), j))
        );
    }

    #[test]
    fn rejected_result_requeues_only_its_own_lease() {
        let (mut s, t0, w) = sched();
        let w2 = s.register_worker(t0, None);
        s.submit(spec(0, 4, 4, 4), t0);
        let l1 = s.lease(w, t0).unwrap().unwrap();
        s.reject_tile(l1.id, "bad");
        let l2 = s.lease(w2, t0).unwrap().unwrap();
        assert_eq!(l2.rect, l1.rect);
        // A second bad result under the dead lease does not touch w2's.
        s.reject_tile(l1.id, "bad");
        assert_eq!(s.lease(w, t0).unwrap(), None);
        assert_eq!(s.lease_count(), 1);
    }

    #[test]
    fn cancel_stops_leasing_and_drops_leases() {
        let (mut s, t0, w) = sched();
        let j = s.submit(spec(0, 8, 8, 4), t0);
        let l = s.lease(w, t0).unwrap().unwrap();
        assert_eq!(s.cancel(j, t0), Ok(JobState::Cancelled));
        assert_eq!(s.lease(w, t0).unwrap(), None);
        assert_eq!(s.heartbeat(w, &[l.id], t0).unwrap(), vec![l.id]);
        assert_eq!(s.accept_tile(j, l.rect, 1, t0), Ok(Accepted::Ignored));
        assert_eq!(s.cancel(42, t0), Err(SchedError::UnknownJob(42)));
    }

    /// A retired job's leases are found from its window, not by scanning
    /// every lease: with tiles done, re-queued after expiry and leased
    /// again, cancelling one job must drop exactly its leases.
    #[test]
    fn a_cancelled_job_leaves_no_lease_and_the_others_keep_theirs() {
        let (mut s, t0, w) = sched();
        let a = s.submit(spec(0, 16, 16, 4), t0);
        let first: Vec<Lease> = (0..6).map(|_| s.lease(w, t0).unwrap().unwrap()).collect();
        for l in &first[..2] {
            s.accept_tile(a, l.rect, 1, t0).unwrap();
        }
        let t1 = t0 + Duration::from_secs(6);
        assert_eq!(s.expire(t1), 4);
        // Another worker: the tiles `w` lost count against it.
        let w2 = s.register_worker(t1, None);
        let again: Vec<Lease> = (0..3).map(|_| s.lease(w2, t1).unwrap().unwrap()).collect();
        assert!(again.iter().all(|l| l.job == a));
        // A late result under an expired lease, for a tile leased again.
        s.accept_tile(a, first[2].rect, 1, t1).unwrap();
        let b = s.submit(spec(5, 8, 8, 4), t1);
        let on_b: Vec<Lease> = (0..2).map(|_| s.lease(w2, t1).unwrap().unwrap()).collect();
        assert!(on_b.iter().all(|l| l.job == b));
        assert_eq!(s.lease_count(), 2 + 2);
        s.cancel(a, t1).unwrap();
        assert_eq!(s.lease_count(), 2);
        for l in &on_b {
            assert_eq!(
                s.accept_tile(b, l.rect, 1, t1),
                Ok(Accepted::New { last: false })
            );
        }
        assert_eq!(s.lease_count(), 0);
    }

    #[test]
    fn finish_order_is_recorded() {
        let (mut s, t0, _) = sched();
        let a = s.submit(spec(0, 4, 4, 4), t0);
        let b = s.submit(spec(0, 4, 4, 4), t0);
        s.finish(b, Ok(()), t0);
        s.finish(a, Err("disk full".into()), t0);
        let (ia, ib) = (s.info(a, t0).unwrap(), s.info(b, t0).unwrap());
        assert_eq!((ib.state, ib.finish_order), (JobState::Done, 1));
        assert_eq!((ia.state, ia.finish_order), (JobState::Failed, 2));
        assert_eq!(ia.error.as_deref(), Some("disk full"));
    }

    /// Frames of sequences use none of the ids users see: the still after
    /// a sequence's frames gets the next id, also after a restart.
    #[test]
    fn frames_take_ids_of_their_own() {
        let (mut s, t0, _) = sched();
        let seq = s.reserve_id();
        let frame = |f| JobSpec {
            frame: Some(f),
            ..spec(0, 4, 4, 4)
        };
        let frames: Vec<JobId> = (1..=3).map(|f| s.submit(frame(f), t0)).collect();
        let still = s.submit(spec(0, 4, 4, 4), t0);
        assert_eq!((seq, still), (1, 2));
        assert_eq!(frames, [FRAME_IDS, FRAME_IDS + 1, FRAME_IDS + 2]);
        let mut again = test_scheduler(Limits::default());
        for id in [still, frames[2]] {
            again.skip_ids_through(id);
        }
        assert_eq!(again.submit(spec(0, 4, 4, 4), t0), 3);
        assert_eq!(again.submit(frame(4), t0), FRAME_IDS + 3);
    }

    /// A job's time splits at its first lease: before it the job waited
    /// in the queue, after it it rendered; a job that never started only
    /// waited, and the split survives a restart.
    #[test]
    fn queue_wait_and_render_time_split_at_the_first_lease() {
        let (mut s, t0, w) = sched();
        let sec = Duration::from_secs;
        let busy = s.submit(spec(5, 4, 4, 4), t0);
        let waiting = s.submit(spec(0, 4, 4, 4), t0);
        let never = s.submit(spec(-1, 4, 4, 4), t0);
        assert_eq!(s.lease(w, t0 + sec(1)).unwrap().unwrap().job, busy);
        assert_eq!(s.lease(w, t0 + sec(4)).unwrap().unwrap().job, waiting);
        s.finish(busy, Ok(()), t0 + sec(9));
        s.finish(waiting, Ok(()), t0 + sec(10));
        let now = t0 + sec(20);
        let (b, wt) = (s.info(busy, now).unwrap(), s.info(waiting, now).unwrap());
        assert_eq!((b.elapsed, b.queued, b.render()), (sec(9), sec(1), sec(8)));
        assert_eq!(
            (wt.elapsed, wt.queued, wt.render()),
            (sec(10), sec(4), sec(6))
        );
        let n = s.info(never, now).unwrap();
        assert_eq!(
            (n.elapsed, n.queued, n.render()),
            (sec(20), sec(20), sec(0))
        );
        // As restored from the database: elapsed and render kept.
        let mut again = test_scheduler(Limits::default());
        again.restore(
            Restored {
                id: waiting,
                spec: spec(0, 4, 4, 4),
                state: JobState::Done,
                submitted: t0,
                elapsed: Some(sec(10)),
                render: Some(sec(6)),
                error: None,
                finish_order: 1,
                tiles_done: 1,
                rays: 0,
                done_tiles: Vec::new(),
            },
            now,
        );
        let r = again.info(waiting, now).unwrap();
        assert_eq!((r.elapsed, r.queued, r.render()), (sec(10), sec(4), sec(6)));
    }

    #[test]
    fn results_for_tiles_never_leased_are_ignored() {
        let (mut s, now, w) = sched();
        let j = s.submit(spec(0, 8, 8, 4), now);
        let l = s.lease(w, now).unwrap().unwrap();
        assert_eq!(
            s.accept_tile(j, Rect::new(4, 4, 4, 4), 1, now),
            Ok(Accepted::Ignored)
        );
        assert_eq!(
            s.accept_tile(j, l.rect, 1, now),
            Ok(Accepted::New { last: false })
        );
        assert!(s.accept_tile(j, Rect::new(8, 0, 4, 4), 1, now).is_err());
        assert_eq!(s.info(j, now).unwrap().tiles_done, 1);
    }

    #[test]
    fn counters_follow_every_tile_event() {
        let (mut s, t0, w) = sched();
        let w2 = s.register_worker(t0, None);
        // 2×2 tiles of 4 pixels.
        let j = s.submit(spec(0, 8, 8, 4), t0);
        let a = s.lease(w, t0).unwrap().unwrap();
        let b = s.lease(w, t0).unwrap().unwrap();
        s.accept_tile(j, a.rect, 10, t0).unwrap();
        // b's lease runs out (ttl 5 s) and its tile goes back in the queue.
        let t1 = t0 + Duration::from_secs(6);
        assert_eq!(s.expire(t1), 1);
        let c = s.lease(w2, t1).unwrap().unwrap();
        assert_eq!(c.rect, b.rect);
        s.reject_tile(c.id, "NaN");
        let d = s.lease(w2, t1).unwrap().unwrap();
        s.accept_tile(j, d.rect, 5, t1).unwrap();
        // The late result under b's expired lease loses to d's.
        assert_eq!(s.accept_tile(j, b.rect, 5, t1), Ok(Accepted::Ignored));
        let want = Counters {
            jobs_submitted: 1,
            leases_granted: 4,
            tiles_accepted: 2,
            tiles_ignored: 1,
            tiles_rejected: 1,
            tiles_requeued: 2,
            lease_expiries: 1,
            rays: 15,
        };
        assert_eq!(s.counters(), want);
        // Two tiles left, neither leased.
        assert_eq!(s.queue_depth(), QueueDepth { jobs: 1, tiles: 2 });
        s.lease(w, t1).unwrap().unwrap();
        assert_eq!(s.queue_depth(), QueueDepth { jobs: 1, tiles: 1 });
    }

    #[test]
    fn workers_show_their_tiles_state_and_rate() {
        let (mut s, t0, w) = sched();
        let w2 = s.register_worker(t0, None);
        s.describe_worker(w, "render-01", 8);
        let j = s.submit(spec(0, 8, 8, 4), t0);
        let a = s.lease(w, t0).unwrap().unwrap();
        let ws = s.workers(t0);
        assert_eq!(ws.len(), 2);
        assert_eq!(ws[0].id, w);
        assert_eq!((ws[0].name.as_str(), ws[0].threads), ("render-01", 8));
        assert_eq!(ws[0].state, WorkerState::Busy);
        assert_eq!(ws[0].leases, vec![(j, a.rect)]);
        assert_eq!(ws[1].state, WorkerState::Idle);
        // w finishes its tile; w2 says nothing for longer than a lease lives.
        let t1 = t0 + Duration::from_secs(3);
        s.accept_tile(j, a.rect, 400, t1).unwrap();
        let t2 = t0 + Duration::from_secs(6);
        s.heartbeat(w, &[], t2).unwrap();
        let ws = s.workers(t2);
        assert_eq!(ws[0].state, WorkerState::Idle);
        assert_eq!((ws[0].tiles_done, ws[0].rays), (1, 400));
        assert_eq!(ws[1].state, WorkerState::Lost);
        // Averaged over the 10 s window once the second is over.
        let epoch = s.workers.epoch();
        let later = epoch + Duration::from_secs(t1.duration_since(epoch).as_secs() + 1);
        let ws = s.workers(later.max(t2));
        assert!(
            (ws[0].rays_per_s - 40.0).abs() < 1e-9,
            "{}",
            ws[0].rays_per_s
        );
        assert!((s.rays_per_second(later.max(t2)) - 40.0).abs() < 1e-9);
        // Long silence: w2 is forgotten and must register again.
        let t3 = t0 + Duration::from_secs(120);
        s.expire(t3);
        assert_eq!(s.lease(w2, t3), Err(SchedError::UnknownWorker(w2)));
    }

    #[test]
    fn priority_changes_reorder_the_queue() {
        let (mut s, t0, w) = sched();
        let a = s.submit(spec(0, 4, 4, 4), t0);
        let b = s.submit(spec(0, 4, 4, 4), t0);
        s.set_priority(b, 5).unwrap();
        assert_eq!(s.info(b, t0).unwrap().spec.priority, 5);
        assert_eq!(s.lease(w, t0).unwrap().unwrap().job, b);
        assert_eq!(s.lease(w, t0).unwrap().unwrap().job, a);
        s.cancel(a, t0).unwrap();
        assert_eq!(s.set_priority(a, 1), Err(SchedError::JobOver(a)));
        assert_eq!(s.set_priority(99, 1), Err(SchedError::UnknownJob(99)));
    }

    #[test]
    fn a_job_every_live_worker_is_kept_from_fails_instead_of_waiting() {
        let (mut s, t0, w) = sched();
        // max_worker_failures 3, max_tile_failures 5: w fails three
        // different tiles once each, so no tile reaches its limit.
        // While a second worker may still take tiles, nothing fails.
        let w2 = s.register_worker(t0, None);
        let j = s.submit(spec(0, 16, 4, 4), t0);
        for _ in 0..3 {
            let l = s.lease(w, t0).unwrap().unwrap();
            s.reject_tile(l.id, "NaN in pixel (0, 0)");
        }
        assert_eq!(s.lease(w, t0).unwrap(), None, "w is benched");
        s.expire(t0);
        let early = s.take_failed();
        assert!(early.is_empty(), "{early:?}");
        // Once w2 is lost too, the only live worker is benched: the job fails.
        let t1 = t0 + Duration::from_secs(6);
        s.heartbeat(w, &[], t1).unwrap();
        s.expire(t1);
        let failed = s.take_failed();
        assert_eq!(failed.len(), 1, "{failed:?}");
        assert_eq!(failed[0].0, j);
        assert!(
            failed[0].1.contains("every live worker (1)"),
            "{}",
            failed[0].1
        );
        assert!(failed[0].1.contains("NaN in pixel"), "{}", failed[0].1);
        // w2 comes back: too late, the job is over once the farm ends it.
        assert_eq!(s.heartbeat(w2, &[], t1), Ok(vec![]));
    }

    #[test]
    fn a_tile_that_loses_its_worker_three_times_fails_its_job_naming_the_tile() {
        // The scene crashes every worker that renders tile 1: each one's
        // lease runs out. Tile 0 is rendered fine.
        let (mut s, mut now, w) = sched();
        let j = s.submit(spec(0, 8, 4, 4), now);
        let first = s.lease(w, now).unwrap().unwrap();
        s.accept_tile(j, first.rect, 1, now).unwrap();
        for n in 1..=3 {
            let w = s.register_worker(now, None);
            let l = s.lease(w, now).unwrap().unwrap();
            assert_eq!(l.rect, Rect::new(4, 0, 4, 4));
            now += Duration::from_secs(6);
            assert_eq!(s.expire(now), 1);
            let failed = s.take_failed();
            if n < 3 {
                assert!(failed.is_empty(), "after {n} losses: {failed:?}");
            } else {
                assert_eq!(failed.len(), 1, "{failed:?}");
                assert_eq!(failed[0].0, j);
                let m = &failed[0].1;
                assert!(m.contains("tile 1 (4x4 at (4, 0))"), "{m}");
                assert!(m.contains("lost the worker rendering it 3 times"), "{m}");
            }
        }
    }

    #[test]
    fn tiles_lost_together_are_all_named() {
        let now = Instant::now();
        let mut s = Scheduler::new(
            Limits {
                lease_ttl: Duration::from_secs(5),
                max_tile_losses: 1,
                ..Limits::default()
            },
            1,
        );
        let w = s.register_worker(now, None);
        let j = s.submit(spec(0, 8, 4, 4), now);
        s.lease(w, now).unwrap().unwrap();
        s.lease(w, now).unwrap().unwrap();
        s.expire(now + Duration::from_secs(6));
        let failed = s.take_failed();
        assert_eq!(failed.len(), 1, "one entry per job: {failed:?}");
        assert_eq!(failed[0].0, j);
        let m = &failed[0].1;
        assert!(m.contains("at (0, 0)") && m.contains("at (4, 0)"), "{m}");
    }

    #[test]
    fn a_returned_lease_requeues_for_free_and_a_failed_render_counts() {
        let (mut s, t0, w) = sched();
        let w2 = s.register_worker(t0, None);
        let j = s.submit(spec(0, 4, 4, 4), t0);
        // Given back unrendered (the worker is stopping), many times over:
        // the tile is re-queued at once and nothing is counted.
        for _ in 0..10 {
            let l = s.lease(w, t0).unwrap().unwrap();
            assert_eq!(
                s.return_lease(w2, l.id, None, t0),
                Err(SchedError::NotYourLease(l.id, w2, l.rect, j)),
                "only the holder may give a lease back"
            );
            s.return_lease(w, l.id, None, t0).unwrap();
            assert!(s.take_failed().is_empty());
        }
        assert_eq!(s.info(j, t0).unwrap().state, JobState::Running);
        // A render that panicked counts like an invalid result: five fail
        // the job (max_tile_failures), with the worker's own words. Two
        // workers, so neither is benched before the tile's limit (3 each).
        for i in 0..5 {
            let who = if i % 2 == 0 { w } else { w2 };
            let l = s.lease(who, t0).unwrap().unwrap();
            s.return_lease(who, l.id, Some("the render panicked: boom"), t0)
                .unwrap();
        }
        let failed = s.take_failed();
        assert_eq!(failed.len(), 1, "{failed:?}");
        assert!(
            failed[0]
                .1
                .contains("tile 0 (4x4 at (0, 0)) failed 5 times"),
            "{}",
            failed[0].1
        );
        assert!(
            failed[0].1.contains("the render panicked: boom"),
            "{}",
            failed[0].1
        );
        // A lease that is gone already is left alone.
        assert_eq!(s.return_lease(w, 12345, Some("late"), t0), Ok(()));
    }

    #[test]
    fn ray_counts_saturate_instead_of_wrapping() {
        let (mut s, t0, w) = sched();
        let j = s.submit(spec(0, 8, 4, 4), t0);
        for _ in 0..2 {
            let l = s.lease(w, t0).unwrap().unwrap();
            s.accept_tile(j, l.rect, u64::MAX, t0).unwrap();
        }
        assert_eq!(s.info(j, t0).unwrap().rays, u64::MAX);
        assert_eq!(s.counters().rays, u64::MAX);
        assert_eq!(s.workers(t0)[0].rays, u64::MAX);
    }
}
