//! Every bound the coordinator works within, in one value: what it accepts
//! at most (bundles, messages, frames, jobs per submitter, uploads and
//! monitor connections), how long it waits, and the per-job memory window
//! and failure counts the scheduler enforces.
//!
//! The defaults are [`Limits::default`]; `trevi-coordinator`'s flags take
//! theirs from it. Exceeding a limit is a clear error (`RESOURCE_EXHAUSTED`
//! over gRPC), never a crash.

use std::time::Duration;

/// What the coordinator accepts at most, and how long it waits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Size of an uploaded bundle (the scene and every file it references).
    pub max_bundle_bytes: u64,
    /// Files in a bundle.
    pub max_bundle_files: usize,
    /// Size of one gRPC message the coordinator decodes.
    pub max_message_bytes: usize,
    /// width × height × samples per pixel (supersample²) of a job's frame.
    pub max_image_samples: u64,
    /// Unfinished jobs one submitter (one named token, else one client
    /// address) may have queued.
    pub max_jobs_per_submitter: usize,
    /// Bundle uploads in progress at once; one more is refused.
    pub max_uploads: usize,
    /// Scenes read at once to admit a job (the first submission on a
    /// bundle; see [`crate::admission`]); one more is refused.
    pub max_admissions: usize,
    /// Memory the admissions in progress may be counted at together, in
    /// bytes (each at [`crate::admission::admission_cost`] of its
    /// bundle's size; one admission alone always fits); one more that does
    /// not fit is refused.
    pub admission_bytes: u64,
    /// How long an upload (a bundle's, or a worker's tile or segments) may
    /// go without a message before it is dropped.
    pub upload_idle: Duration,
    /// Workers registered at once (all of them: a farm has one worker
    /// token); one more registration is refused until one is forgotten.
    pub max_workers: usize,
    /// Workers registered at once from one client address.
    pub max_workers_per_address: usize,
    /// Tile uploads (floats or encoded segments) the coordinator receives
    /// at once; more wait, unread, until one ends. Each holds at most one
    /// lease's pixels (12 bytes a pixel of [`Limits::max_lease_pixels`], or
    /// about 4.5 of [`Limits::max_segment_lease_pixels`]), so what uploads
    /// hold is bounded by this count whatever the number of workers; a
    /// waiting one holds at most its HTTP/2 stream window
    /// ([`TILE_UPLOAD_WINDOW`]). See [`DEFAULT_MAX_TILE_UPLOADS`].
    pub max_tile_uploads: usize,

    /// How long a lease lives without a heartbeat.
    pub lease_ttl: Duration,
    /// Budget per job, in bytes, for what the writer holds of the bands in
    /// flight and the bookkeeping of their tiles: after
    /// [`crate::scheduler::encoder_bytes`], the bands from the first one
    /// not complete to the last one leased must fit, each at
    /// [`crate::scheduler::band_bytes`] (rows at 12 bytes a pixel) if any
    /// of its tiles went out as floats, at
    /// [`crate::scheduler::segment_band_bytes`] (encoded segments, at most
    /// about 4.5 bytes a pixel) if it went out only as segments. The first
    /// band not complete is always allowed; a frame whose one band does not
    /// fit at 12 bytes a pixel is refused at submission. The job's preview
    /// (at most 512×512, [`crate::preview`]) comes on top.
    pub window_bytes: u64,
    /// A tile that fails this many times (its lease runs out, or its result
    /// is invalid) fails its job.
    pub max_tile_failures: u32,
    /// A worker that fails this many tiles of a job takes no more of them.
    pub max_worker_failures: u32,
    /// A tile whose lease runs out this many times (the worker holding it
    /// was lost) fails its job; these count towards `max_tile_failures` too.
    pub max_tile_losses: u32,

    /// Time a monitor client has to send a request's headers (counted from
    /// the connection, or from the end of its previous request) and to
    /// finish a TLS handshake.
    pub http_header_timeout: Duration,
    /// Monitor connections open at once; one more is closed at once.
    pub http_max_connections: usize,

    /// How long a `LeaseTile` call waits for work before answering "none"
    /// (a worker may ask for less).
    pub lease_wait: Duration,
    /// Jobs in a `ListJobs` reply when the request does not say.
    pub list_page_default: usize,
    /// Most jobs in a `ListJobs` reply.
    pub list_page_max: usize,
    /// A `ListJobs` reply stops at about this many bytes (well under the
    /// 4 MiB message limit of the clients).
    pub list_page_bytes: usize,
    /// Characters of a worker's render error kept (in the log and the job's
    /// error).
    pub max_return_error_chars: usize,
    /// Final previews kept for jobs that have ended (the newest ones).
    pub kept_previews: usize,
    /// Most entries of a job's tile log (`crate::store::tile_log`); past
    /// it the oldest are dropped and counted.
    pub tile_log_entries: u32,
    /// Most bytes of error text in a job's tile log; past it the oldest
    /// errors are dropped and counted.
    pub tile_log_error_bytes: u64,

    /// How much of a worker's time one lease aims at, for workers that take
    /// leases of several tiles (see [`crate::scheduler::lease_size`]).
    pub lease_target: Duration,
    /// Most pixels in one lease of several tiles (a single tile may be
    /// bigger): bounds what one upload makes the coordinator hold, at 12
    /// bytes a pixel.
    pub max_lease_pixels: u64,
    /// Most pixels in one lease of encoded PNG segments (whole full-width
    /// bands; see [`crate::scheduler::Lease::png_segments`]). Such an
    /// upload is at most about 4.5 bytes a pixel
    /// ([`crate::scheduler::encoded_rows_bound`]), a cheap scene's about
    /// 0.55, instead of 12, so the cap is larger than
    /// [`Limits::max_lease_pixels`]: see [`DEFAULT_MAX_SEGMENT_LEASE_PIXELS`].
    pub max_segment_lease_pixels: u64,
    /// How long a job that no live worker has the memory for waits for a
    /// bigger worker to register before it fails (counted from when its
    /// estimate became known; see [`crate::scheduler::memory`]).
    pub memory_grace: Duration,
    /// Most frames of one sequence in progress at once (1 ..=
    /// [`MAX_FRAMES_IN_PROGRESS`]); each holds what a still in progress
    /// holds (see [`crate::farm::sequences`]).
    pub frames_in_progress: usize,
    /// Most pixels in one lease of a progressive job (see
    /// [`crate::farm::progressive`]), whose upload carries the rect's
    /// accumulation state at 64 bytes a pixel on top of its pixels, and
    /// whose fetch serves as much: see [`DEFAULT_MAX_STATE_LEASE_PIXELS`].
    /// A progressive job's tiles must fit (checked at submission).
    pub max_state_lease_pixels: u64,
    /// Most bytes a progressive job's accumulation states may take on the
    /// coordinator's disk: 128 bytes a pixel of its frame (two state files
    /// of 64, see `crate::farm::progressive`); a larger frame is refused at
    /// submission. 16 GiB by default: an 11585-pixel square frame.
    pub max_job_state_bytes: u64,

    /// How long the usage history keeps an hour's rows (`--usage-retention`;
    /// between [`crate::usage::MIN_USAGE_RETENTION`] and
    /// [`crate::usage::MAX_USAGE_RETENTION`]), whatever became of the jobs.
    pub usage_retention: Duration,
    /// Rows the usage history keeps at most (`--max-usage-rows`, one a
    /// job, submitter and worker per hour): past it the oldest hour's rows
    /// go first. At least 1, at most [`crate::usage::MAX_USAGE_ROWS`].
    pub max_usage_rows: u64,
}

/// [`Limits::max_state_lease_pixels`] by default: 2¹⁸ pixels, 16 MiB of
/// state (and 3 MiB of floats) in one upload; a 16-row band of a
/// 16384-pixel-wide frame, so a segment lease of one 16-row band still
/// fits the widest frame the default `--max-image-samples` lets through.
pub const DEFAULT_MAX_STATE_LEASE_PIXELS: u64 = 1 << 18;

/// [`Limits::max_segment_lease_pixels`] by default: 2²² pixels (4 Mi). A
/// second of a 16-thread worker on the cheap scene of docs/benchmarks.md
/// (4,734 ns a pixel on one core) is 16 / 4,734 ns = 3.4 Mpixel, which
/// fits, so a lease of about [`Limits::lease_target`] is not cut short
/// there; the coordinator then takes about one lease a second from each
/// worker, what 1,000 workers need. One upload is then at most 18 MiB of
/// segments at the encoder's worst (4.5 bytes a pixel), 2.3 MiB at the
/// cheap scene's 0.55, where a float lease at [`Limits::max_lease_pixels`]
/// is 12 MiB.
pub const DEFAULT_MAX_SEGMENT_LEASE_PIXELS: u64 = 1 << 22;

/// [`Limits::max_tile_uploads`] by default. Receiving is a copy, a check
/// and two file writes a byte, so a few uploads at once keep every core
/// busy; 1,000 workers uploading at once held 2.6 GiB on one core, which
/// spent about a quarter of its time faulting in and zeroing fresh pages
/// (docs/benchmarks.md, "Stage 4"). 32 uploads hold at most 32 × 18 MiB
/// of segments at the encoder's worst, 32 × 12 MiB of floats.
pub const DEFAULT_MAX_TILE_UPLOADS: usize = 32;

/// The HTTP/2 stream window the coordinator grants (each stream may send
/// this much before it is read): an upload waiting for one of
/// [`Limits::max_tile_uploads`] holds at most this much of the
/// coordinator's memory.
pub const TILE_UPLOAD_WINDOW: u32 = 256 << 10;

/// Most streams open at once on one HTTP/2 connection (a client opening
/// more waits). Workers behind one proxy, or simulated ones, share a
/// connection; see [`CONNECTION_WINDOW`].
pub const MAX_STREAMS_PER_CONNECTION: u32 = 256;

/// The HTTP/2 connection window: more than every stream of a connection
/// can hold unread ([`MAX_STREAMS_PER_CONNECTION`] ×
/// [`TILE_UPLOAD_WINDOW`]). Uploads waiting for their turn then never use
/// up the window the upload being received (or a heartbeat) on the same
/// connection needs, which would stop it for good: with hyper's default of
/// 1 MiB, four waiting uploads on a connection did.
pub const CONNECTION_WINDOW: u32 = MAX_STREAMS_PER_CONNECTION * TILE_UPLOAD_WINDOW + (1 << 20);

/// [`Limits::max_admissions`] by default: reading a scene's headers is
/// quick (its cost is reading and hashing the stored bundle), so two at
/// once keep a submission burst moving without letting it hold much.
pub const DEFAULT_MAX_ADMISSIONS: usize = 2;

/// [`Limits::admission_bytes`] by default, in MiB: what two admissions of
/// bundles of 100 MiB are counted at, and more than one of the largest
/// bundle accepted by default (256 MiB, counted at 1 GiB + 8 MiB, which
/// alone always fits).
pub const DEFAULT_ADMISSION_MIB: u64 = 1024;

/// Frames of one sequence in progress at once by default: a second frame
/// lets idle workers start on it while the first one's last tiles are out.
pub const DEFAULT_FRAMES_IN_PROGRESS: usize = 2;

/// The most frames of one sequence in progress that may be asked for. Each
/// frame in progress holds up to `window_bytes` of rows and tile
/// bookkeeping plus its preview (at most 4 MiB): with the default window,
/// 256 frames are about 9 GiB, more than a coordinator should hold for one
/// sequence; a farm that needs more work in flight than that per frame
/// wants bigger frames or a bigger window, not more frames.
pub const MAX_FRAMES_IN_PROGRESS: usize = 256;

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_bundle_bytes: trevi_core::bundle::DEFAULT_MAX_BUNDLE_BYTES,
            max_bundle_files: 10_000,
            max_message_bytes: trevi_proto::MAX_MESSAGE_SIZE,
            // A 16384×16384 frame at supersample 8.
            max_image_samples: 16384 * 16384 * 64,
            max_jobs_per_submitter: 1000,
            max_uploads: 4,
            max_admissions: DEFAULT_MAX_ADMISSIONS,
            admission_bytes: DEFAULT_ADMISSION_MIB << 20,
            upload_idle: Duration::from_secs(30),
            max_tile_uploads: DEFAULT_MAX_TILE_UPLOADS,
            max_workers: 10_000,
            max_workers_per_address: 1_000,

            lease_ttl: Duration::from_secs(10),
            // A 16384-pixel-wide frame in 64-pixel tiles: two bands.
            window_bytes: 32 << 20,
            max_tile_failures: 5,
            max_worker_failures: 3,
            max_tile_losses: 3,

            http_header_timeout: Duration::from_secs(10),
            http_max_connections: 256,

            lease_wait: Duration::from_secs(2),
            list_page_default: 500,
            list_page_max: 1000,
            list_page_bytes: 1 << 20,
            max_return_error_chars: 500,
            kept_previews: 32,
            tile_log_entries: 10_000,
            tile_log_error_bytes: 512 << 10,

            lease_target: Duration::from_secs(1),
            // 12 MiB of pixels: a 4096-pixel-wide band of 64-pixel tiles
            // is a quarter of it.
            max_lease_pixels: 1 << 20,
            max_segment_lease_pixels: DEFAULT_MAX_SEGMENT_LEASE_PIXELS,
            // Long enough for a worker started with the job (or restarted
            // by its service manager) to register.
            memory_grace: Duration::from_secs(30),
            frames_in_progress: DEFAULT_FRAMES_IN_PROGRESS,
            max_state_lease_pixels: DEFAULT_MAX_STATE_LEASE_PIXELS,
            max_job_state_bytes: 16 << 30,
            usage_retention: crate::usage::DEFAULT_USAGE_RETENTION,
            max_usage_rows: crate::usage::DEFAULT_MAX_USAGE_ROWS,
        }
    }
}

impl Limits {
    /// The bounds a lease of a job with a state (`state`: a pass of a
    /// progressive job) is sized within: the lease caps no larger than
    /// [`Limits::max_state_lease_pixels`].
    pub fn for_state(&self, state: bool) -> Limits {
        if !state {
            return *self;
        }
        Limits {
            max_lease_pixels: self.max_lease_pixels.min(self.max_state_lease_pixels),
            max_segment_lease_pixels: self
                .max_segment_lease_pixels
                .min(self.max_state_lease_pixels),
            ..*self
        }
    }
}

/// The smallest `max_message_bytes` that works: a pixel or bundle chunk
/// plus its framing must fit in one message.
pub const MIN_MESSAGE_BYTES: usize = trevi_proto::CHUNK_SIZE + 4096;
