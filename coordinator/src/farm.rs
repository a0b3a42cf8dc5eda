//! The coordinator without the network: bundles, the [`Scheduler`], result
//! validation and stitching into each job's output file.
//!
//! The gRPC services in [`crate::grpc`] are thin wrappers around [`Farm`];
//! tests drive it directly with synthetic pixels.
//!
//! Locking: `state` (scheduler, watchers) is held only for bookkeeping; each
//! job's output has its own lock, taken after `state` is released, so
//! encoding one job's rows never stalls leasing. The order is always
//! output → state, never the reverse.

use crate::bundles::BundleStore;
use crate::error::FarmError;
use crate::metrics::Metrics;
use crate::preview::{encode_png, Preview};
use crate::scheduler::{
    Accepted, Counters, JobId, JobInfo, JobSpec, JobState, Lease, LeaseId, QueueDepth, Restored,
    Scheduler, SchedulerConfig, WorkerId,
};
use crate::store::{wall_ms, Store, StoredJob};
use crate::summaries::{SceneSummary, Summaries};
use crate::workers::WorkerInfo;
use std::collections::{HashMap, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};
use tokio::sync::{watch, Notify};
use trevi_core::{FrameWriter, Rect};

/// Where a job's tiles go: normally a [`FrameWriter`]; tests and benchmarks
/// may plug in their own.
pub trait TileSink: Send {
    fn write_tile(&mut self, rect: Rect, pixels: &[[f32; 3]]) -> Result<(), String>;
    /// Completes the output (for a file: moves it into place).
    fn finish(self: Box<Self>) -> Result<(), String>;
    /// Rows buffered right now.
    fn rows_held(&self) -> usize;
}

impl TileSink for FrameWriter {
    fn write_tile(&mut self, rect: Rect, pixels: &[[f32; 3]]) -> Result<(), String> {
        FrameWriter::write_tile(self, rect, pixels).map_err(|e| e.to_string())
    }
    fn finish(self: Box<Self>) -> Result<(), String> {
        FrameWriter::finish(*self).map_err(|e| e.to_string())
    }
    fn rows_held(&self) -> usize {
        FrameWriter::rows_held(self)
    }
}

/// What the coordinator accepts at most. Exceeding a limit is a clear error
/// (`RESOURCE_EXHAUSTED`), never a crash.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    /// Size of an uploaded bundle (the scene and every file it references).
    pub max_bundle_bytes: u64,
    /// Files in a bundle.
    pub max_bundle_files: usize,
    /// Size of one gRPC message the coordinator decodes.
    pub max_message_bytes: usize,
    /// width × height × samples per pixel (supersample²) of a job's frame.
    pub max_image_samples: u64,
    /// Unfinished jobs one submitter (one client address) may have queued.
    pub max_jobs_per_submitter: usize,
    /// Bundle uploads in progress at once; one more is refused.
    pub max_uploads: usize,
    /// How long an upload may go without a chunk before it is dropped.
    pub upload_idle: Duration,
}

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
            upload_idle: Duration::from_secs(30),
        }
    }
}

/// How long ended jobs (done, failed, cancelled) are kept: their status,
/// their output and their row in the database. A job is forgotten when
/// either rule says so; an unfinished job is never forgotten.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Retention {
    /// Ended jobs kept at most (the newest by the time they ended).
    pub keep_ended: usize,
    /// Ended jobs are forgotten this long after they ended; `None`: never.
    pub keep_ended_for: Option<Duration>,
}

impl Default for Retention {
    fn default() -> Self {
        Retention {
            keep_ended: 1000,
            keep_ended_for: Some(Duration::from_secs(7 * 24 * 3600)),
        }
    }
}

impl Retention {
    /// Reads `--keep-ended-for`: a whole number with `s`, `m`, `h` or `d`
    /// (`90m`, `7d`), or `never`.
    pub fn parse_duration(s: &str) -> Result<Option<Duration>, String> {
        let s = s.trim();
        if s == "never" {
            return Ok(None);
        }
        let bad = || format!("\"{s}\" is not a duration like 90s, 30m, 12h, 7d or never");
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

/// Coordinator settings.
#[derive(Debug, Clone)]
pub struct FarmConfig {
    pub data_dir: PathBuf,
    pub sched: SchedulerConfig,
    /// Tile edge used when a submission does not ask for one.
    pub default_tile: u32,
    /// Keep jobs and accepted tiles in `data_dir/state.db`, and pick up the
    /// unfinished jobs found there on start (see [`crate::store`]).
    pub durable: bool,
    pub limits: Limits,
    pub retention: Retention,
    /// A bundle no job uses is removed once it was last uploaded or used
    /// this long ago (see [`crate::bundles::BundleStore::collect`]).
    pub bundle_grace: Duration,
}

/// [`FarmConfig::bundle_grace`] by default.
pub const BUNDLE_GRACE: Duration = Duration::from_secs(3600);

impl FarmConfig {
    pub fn new(data_dir: impl Into<PathBuf>) -> Self {
        FarmConfig {
            data_dir: data_dir.into(),
            sched: SchedulerConfig::default(),
            default_tile: 64,
            durable: true,
            limits: Limits::default(),
            retention: Retention::default(),
            bundle_grace: BUNDLE_GRACE,
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

struct Output {
    sink: Option<Box<dyn TileSink>>,
    written: u64,
    total: u64,
    max_rows_held: usize,
    preview: Preview,
}

impl Output {
    fn new(sink: Box<dyn TileSink>, spec: &JobSpec, total: u64) -> Output {
        Output {
            sink: Some(sink),
            written: 0,
            total,
            max_rows_held: 0,
            preview: Preview::new(spec.width, spec.height),
        }
    }
}

/// A job's preview as a PNG file, with what it shows.
#[derive(Debug, Clone)]
pub struct PreviewImage {
    pub width: u32,
    pub height: u32,
    /// Tiles of the frame in the preview.
    pub tiles: u64,
    pub png: Arc<Vec<u8>>,
}

/// Final previews kept for jobs that have ended (the newest ones).
const KEPT_PREVIEWS: usize = 32;

/// What `/metrics` reports, read in one go.
#[derive(Debug, Clone)]
pub struct FarmSnapshot {
    pub counters: Counters,
    pub queue: QueueDepth,
    pub jobs: Vec<JobInfo>,
    pub workers: Vec<WorkerInfo>,
    pub rays_per_second: f64,
}

struct State {
    sched: Scheduler,
    outputs: HashMap<JobId, Arc<Mutex<Output>>>,
    watchers: HashMap<JobId, watch::Sender<JobInfo>>,
    /// Who submitted each unfinished job.
    submitters: HashMap<JobId, String>,
    /// The last previews of jobs that ended, oldest first.
    final_previews: VecDeque<(JobId, PreviewImage)>,
    /// Jobs that ended but whose end the database did not take (a full
    /// disk): held unfinished, as stored, until [`Farm::expire`] records it.
    unrecorded: HashMap<JobId, Result<(), String>>,
}

impl State {
    /// Keeps an ended job's last preview, so the monitor still shows it.
    fn keep_final_preview(&mut self, job: JobId, image: Option<PreviewImage>) {
        let Some(image) = image else {
            return;
        };
        self.final_previews.push_back((job, image));
        if self.final_previews.len() > KEPT_PREVIEWS {
            self.final_previews.pop_front();
        }
    }

    fn publish(&self, job: JobId) {
        if let (Some(tx), Some(info)) = (
            self.watchers.get(&job),
            self.sched.info(job, Instant::now()),
        ) {
            tx.send_replace(info);
        }
    }
}

/// The coordinator's state and rules.
pub struct Farm {
    cfg: FarmConfig,
    state: Mutex<State>,
    /// Woken when there may be new tiles to lease.
    work: Notify,
    bundles: BundleStore,
    /// The cameras of each bundle's scene, parsed once per bundle.
    summaries: Summaries,
    store: Option<Store>,
    metrics: Metrics,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic while holding a lock is a bug; keep serving what we can.
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Checks a result's pixels against its rectangle: right count, every
/// component finite and not negative. The renderer only ever produces linear
/// radiance ≥ 0; there is no upper bound short of `f32::MAX`, because a scene
/// may legitimately have lights and colors that large (AISXML allows any
/// finite value ≥ 0), so anything finite and ≥ 0 could be a true result.
pub fn validate_pixels(rect: Rect, pixels: &[[f32; 3]]) -> Result<(), FarmError> {
    if pixels.len() != rect.pixel_count() {
        return Err(FarmError::BadTile(format!(
            "{}x{} tile at ({}, {}) needs {} pixels, got {}",
            rect.w,
            rect.h,
            rect.x,
            rect.y,
            rect.pixel_count(),
            pixels.len()
        )));
    }
    if let Some(i) = pixels.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(FarmError::BadTile(format!(
            "pixel ({}, {}) is not finite: {:?}",
            rect.x + (i as u32 % rect.w),
            rect.y + (i as u32 / rect.w),
            pixels[i]
        )));
    }
    // `-0.0 < 0.0` is false: a negative zero is a zero.
    if let Some(i) = pixels.iter().position(|p| p.iter().any(|&c| c < 0.0)) {
        return Err(FarmError::BadTile(format!(
            "pixel ({}, {}) is negative: {:?} (radiance is never below 0)",
            rect.x + (i as u32 % rect.w),
            rect.y + (i as u32 / rect.w),
            pixels[i]
        )));
    }
    Ok(())
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
            state: Mutex::new(State {
                sched: Scheduler::new(cfg.sched, base),
                outputs: HashMap::new(),
                watchers: HashMap::new(),
                submitters: HashMap::new(),
                final_previews: VecDeque::new(),
                unrecorded: HashMap::new(),
            }),
            work: Notify::new(),
            bundles,
            summaries: Summaries::default(),
            store,
            metrics: Metrics::default(),
            cfg,
        };
        farm.restore()?;
        farm.skip_used_ids()?;
        farm.prune();
        Ok(farm)
    }

    /// Keeps new jobs out of every id given before: the largest the
    /// database remembers, and every `jobs/<id>` directory on disk (a
    /// database lost or replaced must not make two jobs share one).
    fn skip_used_ids(&self) -> Result<(), FarmError> {
        let mut max = match &self.store {
            Some(store) => store.max_job_id()?,
            None => 0,
        };
        let jobs = self.cfg.data_dir.join("jobs");
        if let Ok(entries) = std::fs::read_dir(&jobs) {
            for e in entries.flatten() {
                if let Some(id) = e.file_name().to_str().and_then(|n| n.parse::<u64>().ok()) {
                    max = max.max(id);
                }
            }
        }
        lock(&self.state).sched.skip_ids_through(max);
        Ok(())
    }

    /// Forgets the ended jobs [`Retention`] no longer keeps: from the
    /// database first, then from memory, then their output directories.
    fn prune(&self) {
        let r = self.cfg.retention;
        let now = Instant::now();
        let doomed: Vec<JobId> = lock(&self.state)
            .sched
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
            let mut st = lock(&self.state);
            for id in &doomed {
                st.sched.remove(*id);
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

    /// Picks up the jobs in the database: finished ones for status and
    /// download, unfinished ones by rebuilding their output from the stored
    /// tiles and queueing the rest.
    fn restore(&self) -> Result<(), FarmError> {
        let Some(store) = &self.store else {
            return Ok(());
        };
        let (now, wall) = (Instant::now(), wall_ms());
        for j in store.jobs()? {
            let ago = Duration::from_millis(wall.saturating_sub(j.submitted_ms));
            let submitted = now.checked_sub(ago).unwrap_or(now);
            let done_tiles = if j.state.is_final() {
                Vec::new()
            } else {
                store.tile_list(j.id)?
            };
            let rays = if j.state.is_final() {
                j.rays
            } else {
                done_tiles.iter().fold(0u64, |a, t| a.saturating_add(t.1))
            };
            let id = j.id;
            let mut st = lock(&self.state);
            st.sched.restore(
                Restored {
                    id,
                    spec: j.spec.clone(),
                    state: j.state,
                    submitted,
                    elapsed: j.elapsed,
                    error: j.error.clone(),
                    finish_order: j.finish_order,
                    tiles_done: j.tiles_done,
                    rays,
                    done_tiles: done_tiles.iter().map(|t| t.0).collect(),
                },
                now,
            );
            let info = st.sched.info(id, now).expect("just restored");
            st.watchers.insert(id, watch::channel(info.clone()).0);
            if !j.state.is_final() {
                st.submitters.insert(id, j.submitter.clone());
            }
            drop(st);
            if j.state.is_final() {
                continue;
            }
            tracing::info!(
                job = id,
                tiles_stored = done_tiles.len(),
                tiles_total = info.tiles_total,
                "resuming job"
            );
            match self.rebuild_output(store, &info) {
                Ok(out) => {
                    let complete = out.written == out.total;
                    let out = Arc::new(Mutex::new(out));
                    lock(&self.state).outputs.insert(id, out.clone());
                    if complete {
                        let sink = lock(&out).sink.take().expect("just made");
                        let result = sink.finish();
                        self.end_job(id, result.map_err(|e| format!("finishing the output: {e}")));
                    }
                }
                Err(e) => self.end_job(id, Err(format!("resuming after a restart: {e}"))),
            }
        }
        Ok(())
    }

    /// A fresh output for a resumed job with its stored tiles written into it
    /// in band order.
    fn rebuild_output(&self, store: &Store, info: &JobInfo) -> Result<Output, FarmError> {
        let job = info.id;
        let path = self.output_path(job, &info.spec.output_name);
        // Temporary files of the writer that died with the last run.
        if let Ok(entries) = std::fs::read_dir(path.parent().expect("jobs/<id>/name")) {
            for e in entries.flatten() {
                let name = e.file_name();
                let name = name.to_string_lossy();
                if name.starts_with('.') && name.contains(".trevi-tmp-") {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        }
        let mut writer = FrameWriter::create(&path, info.spec.width, info.spec.height)
            .map_err(|e| FarmError::Io(format!("cannot create the output: {e}")))?;
        let mut preview = Preview::new(info.spec.width, info.spec.height);
        let mut written = 0;
        store.replay_tiles(job, |idx, bytes| {
            let rect = lock(&self.state)
                .sched
                .tile_rect(job, idx)
                .ok_or_else(|| FarmError::Io(format!("stored tile {idx} is not in the frame")))?;
            written += 1;
            // The wire's format; a ragged length reads as no pixels, which
            // the pixel count check then refuses.
            let pixels = trevi_proto::pixels_from_bytes(bytes).unwrap_or_default();
            validate_pixels(rect, &pixels)?;
            preview.add_tile(rect, &pixels);
            writer
                .write_tile(rect, &pixels)
                .map_err(|e| FarmError::Io(format!("writing the output: {e}")))
        })?;
        Ok(Output {
            max_rows_held: writer.rows_held(),
            sink: Some(Box::new(writer)),
            written,
            total: info.tiles_total,
            preview,
        })
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
    /// [`FarmConfig::bundle_grace`]; returns how many went.
    pub fn collect_bundles(&self) -> usize {
        let keep = self
            .list()
            .into_iter()
            .map(|j| j.spec.bundle_hash)
            .collect();
        self.bundles.collect(&keep, self.cfg.bundle_grace)
    }

    /// The scene summaries of stored bundles (see [`Summaries::prime`]).
    pub fn summaries(&self) -> &Summaries {
        &self.summaries
    }

    /// Describes the job rendering `camera` (empty: the first camera) of a
    /// stored bundle's scene. The scene is parsed the first time a bundle
    /// is asked about (which parses meshes: call off the async threads),
    /// then its summary is kept (see [`Summaries`]).
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
            None => self.summaries.get_or_parse(bundle_hash, || {
                let bundle = self.bundles.get(bundle_hash)?;
                let desc = trevi_core::scene::aisxml::parse_scene(&bundle.scene, &bundle)
                    .map_err(|e| FarmError::BadScene(e.to_string()))?;
                Ok::<_, FarmError>(SceneSummary::of(&desc))
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

    /// Queues a job whose output goes to [`Farm::output_path`].
    pub fn submit(&self, spec: JobSpec) -> Result<JobInfo, FarmError> {
        self.submit_as(spec, "")
    }

    /// [`Farm::submit`] on behalf of `who`, who may have at most
    /// [`Limits::max_jobs_per_submitter`] unfinished jobs.
    pub fn submit_as(&self, spec: JobSpec, who: &str) -> Result<JobInfo, FarmError> {
        let name = spec.output_name.clone();
        let (w, h) = (spec.width, spec.height);
        self.submit_inner(spec, who, |id| {
            let path = self.output_path(id, &name);
            let writer = FrameWriter::create(&path, w, h)
                .map_err(|e| FarmError::Io(format!("cannot create the output: {e}")))?;
            Ok(Box::new(writer))
        })
    }

    /// Queues a job whose tiles go to the sink `make` returns.
    pub fn submit_with_sink(
        &self,
        spec: JobSpec,
        make: impl FnOnce(JobId) -> Result<Box<dyn TileSink>, FarmError>,
    ) -> Result<JobInfo, FarmError> {
        self.submit_inner(spec, "", make)
    }

    fn submit_inner(
        &self,
        spec: JobSpec,
        who: &str,
        make: impl FnOnce(JobId) -> Result<Box<dyn TileSink>, FarmError>,
    ) -> Result<JobInfo, FarmError> {
        if spec.width == 0 || spec.height == 0 {
            return Err(FarmError::BadScene("the frame is empty".into()));
        }
        self.check_memory(&spec)?;
        let mut st = lock(&self.state);
        let max = self.cfg.limits.max_jobs_per_submitter;
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
        let now = Instant::now();
        let id = st.sched.submit(spec, now);
        let sink = match make(id) {
            Ok(s) => s,
            Err(e) => {
                st.sched.finish(id, Err(e.to_string()), now);
                return Err(e);
            }
        };
        let info = st.sched.info(id, now).expect("just submitted");
        if let Some(store) = &self.store {
            let stored = StoredJob {
                id,
                spec: info.spec.clone(),
                submitter: who.to_string(),
                state: info.state,
                submitted_ms: wall_ms(),
                elapsed: None,
                error: None,
                finish_order: 0,
                tiles_done: 0,
                rays: 0,
            };
            if let Err(e) = store.insert_job(&stored) {
                st.sched.finish(id, Err(e.to_string()), now);
                return Err(e);
            }
        }
        st.outputs.insert(
            id,
            Arc::new(Mutex::new(Output::new(sink, &info.spec, info.tiles_total))),
        );
        st.watchers.insert(id, watch::channel(info.clone()).0);
        st.submitters.insert(id, who.to_string());
        drop(st);
        tracing::info!(job = id, camera = %info.spec.camera, width = info.spec.width,
            height = info.spec.height, priority = info.spec.priority, "job queued");
        self.work.notify_waiters();
        Ok(info)
    }

    /// Refuses a frame whose one band of tiles, with its bookkeeping and the
    /// encoder's rows, does not fit in the per-job window: everything the
    /// coordinator holds for a job grows with the width, the band height
    /// and the tile count in a band, and only the band count is bounded by
    /// the window otherwise. Also refuses more tiles than a job can number.
    fn check_memory(&self, spec: &JobSpec) -> Result<(), FarmError> {
        let tile = if spec.tile_size == 0 {
            self.cfg.default_tile
        } else {
            spec.tile_size
        }
        .max(1);
        let tiles =
            (spec.width as u64).div_ceil(tile as u64) * (spec.height as u64).div_ceil(tile as u64);
        if tiles > u32::MAX as u64 {
            return Err(FarmError::Limit(format!(
                "a {}x{} frame in {tile}-pixel tiles is {tiles} tiles, more than a job may \
                 have ({}); use larger tiles",
                spec.width,
                spec.height,
                u32::MAX
            )));
        }
        let need = crate::scheduler::band_bytes(&JobSpec {
            tile_size: tile,
            ..spec.clone()
        }) + crate::scheduler::encoder_bytes(spec);
        let window = self.cfg.sched.window_bytes;
        if need > window {
            let mib = |b: u64| b.div_ceil(1 << 20);
            return Err(FarmError::Limit(format!(
                "a {}x{} frame in {tile}-pixel tiles needs {} MiB for one band of tiles, more \
                 than the coordinator's per-job window of {} MiB (--window-mib); use a \
                 narrower frame or smaller tiles, or raise --window-mib",
                spec.width,
                spec.height,
                mib(need),
                mib(window)
            )));
        }
        Ok(())
    }

    pub fn register_worker(&self) -> WorkerId {
        self.register_worker_as("", 0)
    }

    /// Registers a worker under the name and thread count it gave.
    pub fn register_worker_as(&self, name: &str, threads: u32) -> WorkerId {
        let mut st = lock(&self.state);
        let id = st.sched.register_worker(Instant::now());
        st.sched.describe_worker(id, name, threads);
        id
    }

    /// Registers a worker as [`Farm::register_worker_as`] does, with a
    /// session secret from the operating system's random source that its
    /// every later call must present (see [`Farm::check_session`]), so one
    /// worker cannot act under another's id.
    pub fn register_worker_session(
        &self,
        name: &str,
        threads: u32,
    ) -> Result<(WorkerId, [u8; 32]), FarmError> {
        let mut secret = [0u8; 32];
        getrandom::getrandom(&mut secret)
            .map_err(|e| FarmError::Io(format!("no random session secret: {e}")))?;
        let mut st = lock(&self.state);
        let id = st.sched.register_worker_session(Instant::now(), secret);
        st.sched.describe_worker(id, name, threads);
        Ok((id, secret))
    }

    /// Checks that `session` is the secret `worker` registered with: an
    /// unknown worker must register (again), a wrong secret is refused.
    pub fn check_session(&self, worker: WorkerId, session: &[u8]) -> Result<(), FarmError> {
        match lock(&self.state).sched.session_is(worker, session) {
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
            let mut st = lock(&self.state);
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
        Ok(lock(&self.state).sched.lease(worker, Instant::now())?)
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
        Ok(lock(&self.state).sched.check_tile(job, rect)?)
    }

    pub fn heartbeat(
        &self,
        worker: WorkerId,
        leases: &[LeaseId],
    ) -> Result<Vec<LeaseId>, FarmError> {
        Ok(lock(&self.state)
            .sched
            .heartbeat(worker, leases, Instant::now())?)
    }

    /// Re-queues tiles whose leases ran out.
    pub fn expire(&self) -> usize {
        let (n, failed) = {
            let mut st = lock(&self.state);
            let n = st.sched.expire(Instant::now());
            (n, st.sched.take_failed())
        };
        if n > 0 {
            tracing::warn!(tiles = n, "leases expired; tiles re-queued");
            self.work.notify_waiters();
        }
        self.fail_jobs(failed);
        let unrecorded: Vec<(JobId, Result<(), String>)> = lock(&self.state)
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
    pub fn put_tile(
        &self,
        lease: LeaseId,
        job: JobId,
        rect: Rect,
        rays: u64,
        pixels: &[[f32; 3]],
    ) -> Result<TileOutcome, FarmError> {
        self.put_tile_from(None, lease, job, rect, rays, pixels)
    }

    /// Like [`Farm::put_tile`], checking that `lease` is `worker`'s lease on
    /// that tile (when `worker` is given): a result under someone else's
    /// lease, or a made-up one, is refused and changes nothing.
    pub fn put_tile_from(
        &self,
        worker: Option<WorkerId>,
        lease: LeaseId,
        job: JobId,
        rect: Rect,
        rays: u64,
        pixels: &[[f32; 3]],
    ) -> Result<TileOutcome, FarmError> {
        let valid = validate_pixels(rect, pixels);
        let mut st = lock(&self.state);
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
        match st.sched.accept_tile(job, rect, rays, Instant::now())? {
            Accepted::Ignored => return Ok(TileOutcome::Ignored),
            Accepted::New { .. } => {}
        }
        let idx = st
            .sched
            .tile_index(job, rect)
            .expect("accepted tiles are tiles");
        st.publish(job);
        let Some(out) = st.outputs.get(&job).cloned() else {
            return Ok(TileOutcome::Ignored);
        };
        drop(st);
        self.work.notify_waiters();

        // Committed before it is acknowledged: after a crash the tile is
        // replayed, not rendered again.
        if let Some(store) = &self.store {
            if let Err(e) = store.put_tile(job, idx, rays, &trevi_proto::pixels_as_bytes(pixels)) {
                lock(&out).sink = None;
                self.end_job(job, Err(format!("storing tile {idx}: {e}")));
                return Err(e);
            }
        }

        let mut guard = lock(&out);
        let o = &mut *guard;
        let Some(sink) = o.sink.as_mut() else {
            return Ok(TileOutcome::Ignored); // Cancelled meanwhile.
        };
        if let Err(e) = sink.write_tile(rect, pixels) {
            o.sink = None;
            drop(guard); // end_job takes the output's lock for its preview.
            self.end_job(job, Err(format!("writing the output: {e}")));
            return Err(FarmError::Io(e));
        }
        o.max_rows_held = o.max_rows_held.max(sink.rows_held());
        o.written += 1;
        o.preview.add_tile(rect, pixels);
        if o.written == o.total {
            let sink = o.sink.take().expect("checked above");
            let result = sink.finish();
            drop(guard);
            self.end_job(
                job,
                result.map_err(|e| format!("finishing the output: {e}")),
            );
        }
        Ok(TileOutcome::Accepted)
    }

    /// Ends a job. Its end is recorded in the database before anyone can
    /// see it, so what a client is told is what a restart finds. When the
    /// database does not take it (a full disk), the job stays as stored:
    /// unfinished, taking no more work; [`Farm::expire`] records the end
    /// later, and a restart meanwhile resumes the job from its stored tiles.
    fn end_job(&self, job: JobId, result: Result<(), String>) {
        let image = self.final_preview(job);
        let mut st = lock(&self.state);
        let now = Instant::now();
        let Some(ending) = st.sched.finish_info(job, &result, now) else {
            return; // Over already (cancelled meanwhile).
        };
        if let Err(e) = self.persist_end(&ending) {
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
        st.keep_final_preview(job, image);
        st.publish(job);
        drop(st);
        self.prune();
    }

    /// The job's preview as it stands, to keep once the job is over (made
    /// before the job is marked over, so whoever sees it over finds it).
    fn final_preview(&self, job: JobId) -> Option<PreviewImage> {
        let out = lock(&self.state).outputs.get(&job).cloned()?;
        let p = lock(&out).preview.clone();
        preview_image(&p).ok()
    }

    /// Records a job's end in the database (and drops its tiles there).
    fn persist_end(&self, info: &JobInfo) -> Result<(), FarmError> {
        let Some(store) = &self.store else {
            return Ok(());
        };
        let j = StoredJob {
            id: info.id,
            spec: info.spec.clone(),
            submitter: String::new(),
            state: info.state,
            submitted_ms: 0,
            elapsed: Some(info.elapsed),
            error: info.error.clone(),
            finish_order: info.finish_order,
            tiles_done: info.tiles_done,
            rays: info.rays,
        };
        store.finish_job(&j)
    }

    /// Cancels a job: no more leases, workers drop theirs at the next
    /// heartbeat, and the partial output is removed.
    /// The cancellation is recorded first: when the database does not take
    /// it, the job goes on and the caller gets the error.
    pub fn cancel(&self, job: JobId) -> Result<JobInfo, FarmError> {
        let image = self.final_preview(job);
        let mut st = lock(&self.state);
        let now = Instant::now();
        if let Some(ending) = st.sched.cancel_info(job, now) {
            self.persist_end(&ending).map_err(|e| {
                FarmError::Io(format!("cannot record the cancellation of job {job}: {e}"))
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
            st.keep_final_preview(job, image);
        }
        st.publish(job);
        drop(st);
        if let Some(out) = out {
            // Dropping an unfinished writer removes its temporary file.
            lock(&out).sink = None;
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
        lock(&self.state)
            .sched
            .info(job, Instant::now())
            .ok_or(FarmError::UnknownJob(job))
    }

    pub fn list(&self) -> Vec<JobInfo> {
        lock(&self.state).sched.list(Instant::now())
    }

    /// Up to `limit` jobs by id from id `from` on, and where the next page
    /// starts (`None`: this was the last).
    pub fn list_from(&self, from: JobId, limit: usize) -> (Vec<JobInfo>, Option<JobId>) {
        lock(&self.state)
            .sched
            .list_from(from, limit, Instant::now())
    }

    /// Progress of a job: the current status, then every change.
    pub fn watch(&self, job: JobId) -> Result<watch::Receiver<JobInfo>, FarmError> {
        lock(&self.state)
            .watchers
            .get(&job)
            .map(|tx| tx.subscribe())
            .ok_or(FarmError::UnknownJob(job))
    }

    /// The finished output file of a job that is done.
    pub fn output_file(&self, job: JobId) -> Result<PathBuf, FarmError> {
        let info = self.info(job)?;
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
        let mut st = lock(&self.state);
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

    /// The job's preview: filling in while it runs, the last state once it
    /// ended (for the newest few finished jobs).
    pub fn preview(&self, job: JobId) -> Result<PreviewImage, FarmError> {
        let st = lock(&self.state);
        if let Some((_, image)) = st.final_previews.iter().find(|(j, _)| *j == job) {
            return Ok(image.clone());
        }
        let info = st
            .sched
            .info(job, Instant::now())
            .ok_or(FarmError::UnknownJob(job))?;
        let out = st.outputs.get(&job).cloned();
        drop(st);
        match out {
            Some(out) => {
                let p = lock(&out).preview.clone();
                preview_image(&p).map_err(FarmError::Io)
            }
            None if !info.state.is_final() => {
                preview_image(&Preview::new(info.spec.width, info.spec.height))
                    .map_err(FarmError::Io)
            }
            None => Err(FarmError::NoOutput(
                job,
                "its preview is no longer kept".to_string(),
            )),
        }
    }

    /// Unfinished jobs and their tiles waiting for a worker.
    pub fn queue_depth(&self) -> QueueDepth {
        lock(&self.state).sched.queue_depth()
    }

    /// Every known worker.
    pub fn workers(&self) -> Vec<WorkerInfo> {
        lock(&self.state).sched.workers(Instant::now())
    }

    /// Counters, queue, jobs and workers at one instant.
    pub fn snapshot(&self) -> FarmSnapshot {
        let now = Instant::now();
        let st = lock(&self.state);
        FarmSnapshot {
            counters: st.sched.counters(),
            queue: st.sched.queue_depth(),
            jobs: st.sched.list(now),
            workers: st.sched.workers(now),
            rays_per_second: st.sched.rays_per_second(now),
        }
    }

    /// Request latencies and other figures only the servers see.
    pub fn metrics(&self) -> &Metrics {
        &self.metrics
    }

    /// Most rows the job's output held at once (while it is running).
    pub fn max_rows_held(&self, job: JobId) -> Option<usize> {
        let out = lock(&self.state).outputs.get(&job).cloned()?;
        let m = lock(&out).max_rows_held;
        Some(m)
    }
}

fn preview_image(p: &Preview) -> Result<PreviewImage, String> {
    Ok(PreviewImage {
        width: p.width,
        height: p.height,
        tiles: p.tiles,
        png: Arc::new(encode_png(p.width, p.height, &p.to_rgba8())?),
    })
}

/// The file name of a camera's `output`, checked to be PNG or EXR.
/// The output file name `name` (as [`Farm::job_spec`] made it) with the
/// extension of `format` (`png` or `exr`, any case; empty keeps `name`): a
/// submitter's `-o` decides the format, not the scene's `output`.
pub fn output_name_as(name: &str, format: &str) -> Result<String, FarmError> {
    if format.is_empty() {
        return Ok(name.to_string());
    }
    let f = trevi_core::output::Format::from_extension(format).ok_or_else(|| {
        FarmError::BadScene(format!(
            "output format \"{format}\" is not supported (png or exr)"
        ))
    })?;
    Ok(Path::new(name)
        .with_extension(f.extension())
        .to_string_lossy()
        .into_owned())
}

fn output_name(output: &str) -> Result<String, FarmError> {
    let name = Path::new(output)
        .file_name()
        .and_then(|n| n.to_str())
        .ok_or_else(|| FarmError::BadScene(format!("output \"{output}\" names no file")))?;
    let ext = Path::new(name)
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    match ext.as_deref() {
        Some("png") | Some("exr") => Ok(name.to_string()),
        _ => Err(FarmError::BadScene(format!(
            "output \"{output}\" must end in .png or .exr"
        ))),
    }
}
