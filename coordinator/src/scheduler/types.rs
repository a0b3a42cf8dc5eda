//! The scheduler's values: what a job renders ([`JobSpec`]) and where it
//! stands ([`JobState`], [`JobInfo`], [`FramesInfo`]), what a worker is
//! handed ([`Lease`]), what became of a result ([`Accepted`]), a job of an
//! earlier run ([`Restored`]), why something was refused ([`SchedError`]),
//! and the totals for `/metrics` ([`Counters`], [`QueueDepth`]).

use crate::workers::WorkerId;
use std::time::{Duration, Instant};
use trevi_core::tile::Rect;
use trevi_proto::pb;

/// A job's number, unique for the coordinator's database: stills and
/// sequences count from 1, the frames of sequences from [`FRAME_IDS`].
pub type JobId = u64;
/// A lease's number, one per tile leased (a span of `n` tiles takes `n`
/// consecutive ids); unique while the coordinator runs.
pub type LeaseId = u64;

/// Where a job is in its life.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JobState {
    /// Submitted, no tile leased yet.
    Queued,
    /// At least one tile leased or done, not finished.
    Running,
    /// Every tile done and the output in place.
    Done,
    /// Given up on (see the job's `error`).
    Failed,
    /// Stopped by a user's cancel.
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

    /// Every state, in life order (the metrics count jobs per state; a
    /// stored state name is read back by finding it here).
    pub const ALL: [JobState; 5] = [
        JobState::Queued,
        JobState::Running,
        JobState::Done,
        JobState::Failed,
        JobState::Cancelled,
    ];

    /// The state's name, as the database, the API and the metrics use it:
    /// the wire state's label, so the two are one table (the database keeps
    /// these words: they never change).
    pub fn name(self) -> &'static str {
        pb::JobState::from(self).label()
    }
}

/// The state on the wire (whose label is the state's name).
impl From<JobState> for pb::JobState {
    fn from(s: JobState) -> Self {
        match s {
            JobState::Queued => pb::JobState::Queued,
            JobState::Running => pb::JobState::Running,
            JobState::Done => pb::JobState::Done,
            JobState::Failed => pb::JobState::Failed,
            JobState::Cancelled => pb::JobState::Cancelled,
        }
    }
}

/// What a job renders: one camera's frame of one bundle.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct JobSpec {
    /// The scene bundle's content hash (hex), as the bundle store names it.
    pub bundle_hash: String,
    /// The id of the scene's camera that is rendered.
    pub camera: String,
    /// Higher runs first; jobs of equal priority run in submission order.
    pub priority: i32,
    /// The frame's size in pixels, from the camera (both ≥ 1 once queued).
    pub width: u32,
    /// See `width`.
    pub height: u32,
    /// The edge of the square tiles, in pixels (the last column and row may
    /// be smaller); 0 at submission means the coordinator's `--tile-size`.
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
    /// For one pass of a progressive job: the samples its workers render
    /// (see `crate::farm::progressive`); `None` for every other job.
    pub samples: Option<SampleRange>,
    /// The render passes the workers render with the beauty and the
    /// output writes as layers or files beside it (`trevi_core::aov`);
    /// none for a plain render. A job with passes is leased as floats,
    /// never as encoded PNG segments.
    pub aovs: trevi_core::Aovs,
}

/// One pass of a progressive job: sample indices `start..end` of every
/// pixel, continuing the state the previous pass left.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SampleRange {
    /// Which pass (0 first): which of the job's two state files it reads
    /// and writes (`crate::farm::pass_states`).
    pub pass: u32,
    /// The first sample index rendered.
    pub start: u32,
    /// One past the last sample index rendered.
    pub end: u32,
    /// The job's own samples per pixel (`--samples`), rendered as
    /// `min-samples = max-samples` adaptive sampling; 0: the scene's.
    pub total: u32,
}

/// The first id of the frame jobs of sequences. Stills and sequences take
/// ids from 1 on, one after the other; a sequence's frames are jobs of
/// their own, numbered from here so they use none of those ids up.
pub const FRAME_IDS: JobId = 1 << 40;

/// A snapshot of a job, for status and progress.
#[derive(Debug, Clone, PartialEq)]
pub struct JobInfo {
    /// The job's number.
    pub id: JobId,
    /// What it renders (its `priority` as it is now).
    pub spec: JobSpec,
    /// Where it is in its life.
    pub state: JobState,
    /// The tiles of its frame.
    pub tiles_total: u64,
    /// Tiles with an accepted result.
    pub tiles_done: u64,
    /// Rays the workers traced for its accepted tiles (saturating).
    pub rays: u64,
    /// From submission to the end, or to now while unfinished: `queued`
    /// and then the render.
    pub elapsed: Duration,
    /// The part of `elapsed` spent waiting in the queue: until the first
    /// tile was leased (all of it for a job that never started).
    pub queued: Duration,
    /// Why it failed; `None` unless `state` is [`JobState::Failed`].
    pub error: Option<String>,
    /// 1 for the first job to finish, and so on; 0 while unfinished.
    pub finish_order: u64,
    /// For a sequence: its frames' progress.
    pub frames: Option<FramesInfo>,
    /// For a progressive job: its passes' progress.
    pub passes: Option<PassesInfo>,
    /// Paused by a user (`trevi-submit pause`): none of its tiles are
    /// leased until it is resumed. Always false once it has ended.
    pub paused: bool,
    /// The jobs it waits for (`--after`) that have not ended yet: none of
    /// its tiles are leased until they are done. Empty once it has ended.
    pub waiting_for: Vec<JobId>,
    /// The workers kept from it (see `scheduler/blocks.rs`); for a
    /// sequence, from its frames in progress. Empty once it has ended.
    pub blocked: Vec<super::Blocked>,
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
    /// The first frame number of the sequence.
    pub first: u32,
    /// The last frame number (inclusive).
    pub last: u32,
    /// Frames finished.
    pub done: u32,
    /// Frames rendering now.
    pub in_progress: u32,
    /// The earliest frame in progress: its number, tiles done and tiles.
    pub current: Option<(u32, u64, u64)>,
}

/// A progressive job's progress (see `crate::farm::progressive`).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PassesInfo {
    /// Passes finished: the output holds the last one's image.
    pub done: u32,
    /// Samples per pixel in the output now.
    pub samples_done: u32,
    /// Samples per pixel asked for: the job ends with this many unless a
    /// stop condition ends it first.
    pub samples_total: u32,
    /// Samples per pixel in each pass.
    pub pass: u32,
    /// The frame's estimated relative error after the last pass, once it
    /// is known (every pixel has two samples).
    pub error: Option<f64>,
    /// A stop condition: no pass starts after this much rendering.
    pub time_limit: Option<Duration>,
    /// A stop condition: the job stops once `error` is at most this.
    pub noise_target: Option<f64>,
    /// Why it ended before its total.
    pub stopped_by: Option<StopReason>,
}

/// Why a progressive job ended before its total samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopReason {
    /// It had rendered for its time limit when a pass ended.
    TimeLimit,
    /// Its estimated error fell to its noise target.
    NoiseTarget,
}

impl StopReason {
    /// The words the API, the database and `status` use.
    pub fn label(self) -> &'static str {
        match self {
            StopReason::TimeLimit => "time limit",
            StopReason::NoiseTarget => "noise target",
        }
    }

    /// The reason named by [`StopReason::label`].
    pub fn from_label(s: &str) -> Option<StopReason> {
        [StopReason::TimeLimit, StopReason::NoiseTarget]
            .into_iter()
            .find(|r| r.label() == s)
    }
}

/// A tile handed to a worker, or a span (see [`lease_size`]): adjacent
/// tiles of one band, or whole full-width bands one after the other. Then
/// `rect` is their union and their leases are `id`, `id + 1`, … `id +
/// tiles - 1`, in band order (band by band, left to right).
///
/// [`lease_size`]: super::lease_size
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Lease {
    /// The lease of the first tile (see above for a span's other tiles).
    pub id: LeaseId,
    /// The job the tiles belong to.
    pub job: JobId,
    /// The job's scene bundle (see [`JobSpec::bundle_hash`]).
    pub bundle_hash: String,
    /// The job's camera (see [`JobSpec::camera`]).
    pub camera: String,
    /// The pixels to render, in frame coordinates.
    pub rect: Rect,
    /// How many tiles `rect` covers (1 for one tile).
    pub tiles: u32,
    /// The job's memory estimate in bytes, 0 if none (see [`memory`]).
    ///
    /// [`memory`]: super::memory
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
    ///
    /// [`Limits::max_segment_lease_pixels`]: crate::limits::Limits::max_segment_lease_pixels
    /// [`SEGMENT_ROWS`]: trevi_core::output::SEGMENT_ROWS
    /// [`Scheduler::allow_segments`]: super::Scheduler::allow_segments
    pub png_segments: bool,
    /// For a pass of a progressive job: the samples to render, from the
    /// state `FetchState` serves (the job's [`JobSpec::samples`]).
    pub samples: Option<SampleRange>,
    /// The job's render passes ([`JobSpec::aovs`]), uploaded with the
    /// pixels.
    pub aovs: trevi_core::Aovs,
}

/// What became of a result handed to [`Scheduler::accept_tile`].
///
/// [`Scheduler::accept_tile`]: super::Scheduler::accept_tile
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Accepted {
    /// The tile is now done.
    New {
        /// It was the job's last tile: the job is complete.
        last: bool,
    },
    /// Late or duplicate (the tile was already done, or the job is over).
    Ignored,
}

/// A job of an earlier run, as the coordinator's database kept it.
#[derive(Debug, Clone)]
pub struct Restored {
    /// The job's number, kept across runs.
    pub id: JobId,
    /// What it renders.
    pub spec: JobSpec,
    /// Its state when the database last recorded it.
    pub state: JobState,
    /// When it was submitted, moved onto this run's clock (from the wall
    /// time kept in the database; now if that is in the future).
    pub submitted: Instant,
    /// For a finished job: how long it took.
    pub elapsed: Option<Duration>,
    /// For a finished job: how much of `elapsed` it rendered (the rest it
    /// waited in the queue).
    pub render: Option<Duration>,
    /// For a failed job: why.
    pub error: Option<String>,
    /// For a finished job: its place in the finishing order (see
    /// [`JobInfo::finish_order`]); 0 otherwise.
    pub finish_order: u64,
    /// For a finished job: how many tiles it had done.
    pub tiles_done: u64,
    /// Rays traced for its done tiles.
    pub rays: u64,
    /// For an unfinished job: the tiles already stored (not leased again).
    pub done_tiles: Vec<u32>,
}

/// Why the scheduler refused something.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SchedError {
    /// No job has this id (never submitted, or forgotten).
    #[error("no job {0}")]
    UnknownJob(JobId),
    /// No registered worker has this id (never registered, or dropped since).
    #[error("unknown worker {0}")]
    UnknownWorker(WorkerId),
    /// A result's rectangle is not one of the job's tiles.
    #[error("{0:?} is not a tile of job {1}")]
    NotATile(Rect, JobId),
    /// A result names a lease that is not the worker's current lease on
    /// that tile (expired and leased again, or someone else's).
    #[error("lease {0} is not worker {1}'s lease on tile {2:?} of job {3}")]
    NotYourLease(LeaseId, WorkerId, Rect, JobId),
    /// The worker does not hold this lease (it expired, was released, or
    /// was never granted to it).
    #[error("lease {0} is not a lease worker {1} holds")]
    NotHeld(LeaseId, WorkerId),
    /// The job is finished, failed or cancelled: nothing about it changes.
    #[error("job {0} is over")]
    JobOver(JobId),
    /// An unblock names no worker kept from the job.
    #[error("no worker \"{who}\" is blocked from job {job} (blocked: {blocked})")]
    NotBlocked {
        /// The job.
        job: JobId,
        /// The worker as the request named it (an id or a name).
        who: String,
        /// The workers that are blocked, as `status` names them.
        blocked: String,
    },
}

/// Running totals since the coordinator started (for `/metrics`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    /// Jobs queued (each frame of a sequence is a job of its own).
    pub jobs_submitted: u64,
    /// Tile leases handed out (a span of `n` tiles counts `n`).
    pub leases_granted: u64,
    /// First valid results (each tile is counted once).
    pub tiles_accepted: u64,
    /// Valid results that lost to an earlier one, or came after the job ended.
    pub tiles_ignored: u64,
    /// Invalid results (wrong size, not finite, wrong tile).
    pub tiles_rejected: u64,
    /// Tiles put back in the queue (an expired lease or an invalid result).
    pub tiles_requeued: u64,
    /// Leases whose worker went silent past the lease's time.
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
