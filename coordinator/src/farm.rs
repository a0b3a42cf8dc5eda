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
use crate::scheduler::{
    Accepted, JobId, JobInfo, JobSpec, JobState, Lease, LeaseId, Scheduler, SchedulerConfig,
    WorkerId,
};
use std::collections::HashMap;
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

/// Coordinator settings.
#[derive(Debug, Clone)]
pub struct FarmConfig {
    pub data_dir: PathBuf,
    pub sched: SchedulerConfig,
    /// Tile edge used when a submission does not ask for one.
    pub default_tile: u32,
}

impl FarmConfig {
    pub fn new(data_dir: impl Into<PathBuf>) -> Self {
        FarmConfig {
            data_dir: data_dir.into(),
            sched: SchedulerConfig::default(),
            default_tile: 64,
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
}

struct State {
    sched: Scheduler,
    outputs: HashMap<JobId, Arc<Mutex<Output>>>,
    watchers: HashMap<JobId, watch::Sender<JobInfo>>,
}

impl State {
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
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic while holding a lock is a bug; keep serving what we can.
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Checks a result's pixels against its rectangle: right count, all finite.
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
        Ok(Farm {
            state: Mutex::new(State {
                sched: Scheduler::new(cfg.sched, base),
                outputs: HashMap::new(),
                watchers: HashMap::new(),
            }),
            work: Notify::new(),
            bundles,
            cfg,
        })
    }

    pub fn config(&self) -> &FarmConfig {
        &self.cfg
    }

    pub fn bundles(&self) -> &BundleStore {
        &self.bundles
    }

    /// Reads a stored bundle's scene and describes the job rendering
    /// `camera` (empty: the first camera). Parses meshes: call off the async
    /// threads.
    pub fn job_spec(
        &self,
        bundle_hash: &str,
        camera: &str,
        priority: i32,
        tile_size: u32,
    ) -> Result<JobSpec, FarmError> {
        let bundle = self.bundles.get(bundle_hash)?;
        let desc = trevi_core::scene::aisxml::parse_scene(&bundle.scene, &bundle)
            .map_err(|e| FarmError::BadScene(e.to_string()))?;
        let cam = if camera.is_empty() {
            desc.cameras.first()
        } else {
            desc.cameras.iter().find(|c| c.id == camera)
        }
        .ok_or_else(|| {
            FarmError::BadScene(if camera.is_empty() {
                "the scene has no camera".to_string()
            } else {
                format!("the scene has no camera \"{camera}\"")
            })
        })?;
        let output_name = output_name(&cam.render.output)?;
        Ok(JobSpec {
            bundle_hash: bundle_hash.to_string(),
            camera: cam.id.clone(),
            priority,
            width: cam.render.width,
            height: cam.render.height,
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
        let name = spec.output_name.clone();
        let (w, h) = (spec.width, spec.height);
        self.submit_with_sink(spec, |id| {
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
        if spec.width == 0 || spec.height == 0 {
            return Err(FarmError::BadScene("the frame is empty".into()));
        }
        let mut st = lock(&self.state);
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
        st.outputs.insert(
            id,
            Arc::new(Mutex::new(Output {
                sink: Some(sink),
                written: 0,
                total: info.tiles_total,
                max_rows_held: 0,
            })),
        );
        st.watchers.insert(id, watch::channel(info.clone()).0);
        drop(st);
        tracing::info!(job = id, camera = %info.spec.camera, width = info.spec.width,
            height = info.spec.height, priority = info.spec.priority, "job queued");
        self.work.notify_waiters();
        Ok(info)
    }

    pub fn register_worker(&self) -> WorkerId {
        lock(&self.state).sched.register_worker(Instant::now())
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
        let n = lock(&self.state).sched.expire(Instant::now());
        if n > 0 {
            tracing::warn!(tiles = n, "leases expired; tiles re-queued");
            self.work.notify_waiters();
        }
        n
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
        let valid = validate_pixels(rect, pixels);
        let mut st = lock(&self.state);
        let valid = valid.and_then(|()| Ok(st.sched.check_tile(job, rect)?));
        if let Err(e) = valid {
            st.sched.reject_tile(lease);
            drop(st);
            tracing::warn!(job, lease, error = %e, "tile rejected and re-queued");
            self.work.notify_waiters();
            return Err(e);
        }
        match st.sched.accept_tile(job, rect, rays)? {
            Accepted::Ignored => return Ok(TileOutcome::Ignored),
            Accepted::New { .. } => {}
        }
        st.publish(job);
        let Some(out) = st.outputs.get(&job).cloned() else {
            return Ok(TileOutcome::Ignored);
        };
        drop(st);
        self.work.notify_waiters();

        let mut guard = lock(&out);
        let o = &mut *guard;
        let Some(sink) = o.sink.as_mut() else {
            return Ok(TileOutcome::Ignored); // Cancelled meanwhile.
        };
        if let Err(e) = sink.write_tile(rect, pixels) {
            o.sink = None;
            self.end_job(job, Err(format!("writing the output: {e}")));
            return Err(FarmError::Io(e));
        }
        o.max_rows_held = o.max_rows_held.max(sink.rows_held());
        o.written += 1;
        if o.written == o.total {
            let sink = o.sink.take().expect("checked above");
            let result = sink.finish();
            self.end_job(
                job,
                result.map_err(|e| format!("finishing the output: {e}")),
            );
        }
        Ok(TileOutcome::Accepted)
    }

    fn end_job(&self, job: JobId, result: Result<(), String>) {
        match &result {
            Ok(()) => tracing::info!(job, "job done"),
            Err(e) => tracing::error!(job, error = %e, "job failed"),
        }
        let mut st = lock(&self.state);
        st.sched.finish(job, result, Instant::now());
        st.outputs.remove(&job);
        st.publish(job);
    }

    /// Cancels a job: no more leases, workers drop theirs at the next
    /// heartbeat, and the partial output is removed.
    pub fn cancel(&self, job: JobId) -> Result<JobInfo, FarmError> {
        let mut st = lock(&self.state);
        let state = st.sched.cancel(job, Instant::now())?;
        let out = if state == JobState::Cancelled {
            st.outputs.remove(&job)
        } else {
            None
        };
        st.publish(job);
        drop(st);
        if let Some(out) = out {
            // Dropping an unfinished writer removes its temporary file.
            lock(&out).sink = None;
            let dir = self.cfg.data_dir.join("jobs").join(job.to_string());
            let _ = std::fs::remove_dir(dir);
            tracing::info!(job, "job cancelled");
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

    /// Most rows the job's output held at once (while it is running).
    pub fn max_rows_held(&self, job: JobId) -> Option<usize> {
        let out = lock(&self.state).outputs.get(&job).cloned()?;
        let m = lock(&out).max_rows_held;
        Some(m)
    }
}

/// The file name of a camera's `output`, checked to be PNG or EXR.
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
