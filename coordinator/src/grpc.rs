//! The `trevi.v1` gRPC services: thin wrappers around [`Farm`], one struct
//! per service holding it behind an `Arc`. Server streams are a task feeding
//! a channel wrapped in `ReceiverStream`.

use crate::auth::{self, Auth, Need, Tokens};
use crate::farm::{Farm, SegmentUpload, SubmitOptions, TileOutcome, TileResult, WorkerOptions};
use crate::scheduler::{JobInfo, JobState};
use crate::FarmError;
use std::future::Future;
use std::sync::Arc;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::sync::{mpsc, Semaphore};
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};
use trevi_proto::pb::{self, tile_upload::Part};
use trevi_proto::{pixels_from_bytes, rect_from, CHUNK_SIZE};

fn join_error(e: tokio::task::JoinError) -> Status {
    Status::internal(format!("task failed: {e}"))
}

/// Runs `f` on the blocking pool.
async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> Result<T, FarmError> + Send + 'static,
) -> Result<T, Status> {
    Ok(tokio::task::spawn_blocking(f).await.map_err(join_error)??)
}

pub fn job_status(info: &JobInfo) -> pb::JobStatus {
    let state = match info.state {
        JobState::Queued => pb::JobState::Queued,
        JobState::Running => pb::JobState::Running,
        JobState::Done => pb::JobState::Done,
        JobState::Failed => pb::JobState::Failed,
        JobState::Cancelled => pb::JobState::Cancelled,
    };
    pb::JobStatus {
        id: info.id,
        state: state as i32,
        camera: info.spec.camera.clone(),
        priority: info.spec.priority,
        width: info.spec.width,
        height: info.spec.height,
        tiles_total: info.tiles_total,
        tiles_done: info.tiles_done,
        rays: info.rays,
        output_name: info.spec.output_name.clone(),
        elapsed_ms: info.elapsed.as_millis() as u64,
        queued_ms: info.queued.as_millis() as u64,
        render_ms: info.render().as_millis() as u64,
        scene: info.spec.scene.clone(),
        submitter: info.spec.submitter.clone(),
        error: info.error.clone().unwrap_or_default(),
        finish_order: info.finish_order,
        bundle_hash: info.spec.bundle_hash.clone(),
        frames: info.frames.map(|f| pb::FrameRange {
            first: f.first,
            last: f.last,
        }),
        frames_done: info.frames.map_or(0, |f| f.done),
        current_frame: info.frames.and_then(|f| f.current.map(|c| c.0)),
        current_tiles_done: info.frames.and_then(|f| f.current).map_or(0, |c| c.1),
        current_tiles_total: info.frames.and_then(|f| f.current).map_or(0, |c| c.2),
        frames_in_progress: info.frames.map_or(0, |f| f.in_progress),
    }
}

/// `trevi.v1.Bundles`.
///
/// An upload streams to a temporary file as its chunks arrive (see
/// [`crate::bundles`]), so the memory it takes is a chunk or two, whatever
/// the bundle's size. At most [`Limits::max_uploads`] run at once (one more
/// is refused with `RESOURCE_EXHAUSTED`); one that sends nothing for
/// [`Limits::upload_idle`] is dropped (`DEADLINE_EXCEEDED`); the size limit
/// is enforced as the bytes come. A download streams from the stored file
/// after checking its hash; a damaged or missing copy fails the jobs that
/// render it, with that reason.
///
/// [`Limits::max_uploads`]: crate::limits::Limits::max_uploads
/// [`Limits::upload_idle`]: crate::limits::Limits::upload_idle
pub struct BundlesService {
    pub farm: Arc<Farm>,
    /// One permit per upload in progress.
    pub uploads: Arc<Semaphore>,
}

impl BundlesService {
    pub fn new(farm: Arc<Farm>) -> Self {
        let n = farm.config().limits.max_uploads;
        BundlesService {
            farm,
            uploads: Arc::new(Semaphore::new(n)),
        }
    }
}

#[tonic::async_trait]
impl pb::bundles_server::Bundles for BundlesService {
    async fn upload_bundle(
        &self,
        req: Request<Streaming<pb::BundleChunk>>,
    ) -> Result<Response<pb::BundleRef>, Status> {
        auth::granted(&req).need_submitter("uploading a bundle")?;
        let limits = self.farm.config().limits;
        let _permit = self.uploads.clone().try_acquire_owned().map_err(|_| {
            Status::resource_exhausted(format!(
                "{} bundle uploads are in progress, the coordinator's limit (--max-uploads); \
                 try again shortly",
                limits.max_uploads
            ))
        })?;
        let max = limits.max_bundle_bytes;
        let mut s = req.into_inner();
        let farm = self.farm.clone();
        // Dropped on any early return (or if this call is dropped), the
        // upload removes its temporary file.
        let mut up = blocking(move || farm.bundles().begin_upload()).await?;
        loop {
            let chunk = match tokio::time::timeout(limits.upload_idle, s.message()).await {
                Ok(c) => c?,
                Err(_) => {
                    tracing::warn!(received = up.size(), "bundle upload stalled; dropped");
                    return Err(Status::deadline_exceeded(format!(
                        "the upload sent nothing for {} ms, the coordinator's limit \
                         (--upload-idle-ms); dropped after {} bytes",
                        limits.upload_idle.as_millis(),
                        up.size()
                    )));
                }
            };
            let Some(c) = chunk else { break };
            if up.size() + c.data.len() as u64 > max {
                return Err(Status::resource_exhausted(format!(
                    "the bundle is larger than the coordinator's limit of {max} bytes \
                     (--max-bundle-mib)"
                )));
            }
            up = blocking(move || {
                up.write(&c.data)?;
                Ok(up)
            })
            .await?;
        }
        let size = up.size();
        let farm = self.farm.clone();
        let hash = blocking(move || {
            let max_files = farm.config().limits.max_bundle_files;
            farm.bundles().finish_upload(up, max_files)
        })
        .await?;
        tracing::info!(%hash, size, "bundle stored");
        Ok(Response::new(pb::BundleRef { hash, size }))
    }

    type DownloadBundleStream = ReceiverStream<Result<pb::BundleChunk, Status>>;

    async fn download_bundle(
        &self,
        req: Request<pb::BundleRef>,
    ) -> Result<Response<Self::DownloadBundleStream>, Status> {
        let hash = req.into_inner().hash;
        // An error other than a missing or damaged copy (out of file
        // descriptors, a failing disk) may pass: tried again a few times,
        // then named to the worker, failing no job.
        let mut opened;
        let mut wait = Duration::from_millis(50);
        loop {
            let farm = self.farm.clone();
            let h = hash.clone();
            opened = tokio::task::spawn_blocking(move || farm.bundles().open_verified(&h))
                .await
                .map_err(join_error)?;
            match &opened {
                Err(e @ FarmError::Io { .. }) if wait < BUNDLE_RETRY_WAIT => {
                    tracing::warn!(bundle = %hash, error = %e, "cannot open a stored bundle; trying again");
                    tokio::time::sleep(wait).await;
                    wait *= 4;
                }
                _ => break,
            }
        }
        let file = match opened {
            Ok((file, _size)) => file,
            Err(e @ (FarmError::BadBundle(_) | FarmError::UnknownBundle(_))) => {
                // No worker can render the jobs on this bundle: fail them
                // now, saying why, rather than let their tiles fail one
                // lease at a time.
                let why = e.to_string();
                let farm = self.farm.clone();
                let failed = {
                    let hash = hash.clone();
                    blocking(move || Ok(farm.fail_bundle_jobs(&hash, &why))).await?
                };
                if !failed.is_empty() {
                    tracing::error!(bundle = %hash, jobs = ?failed, error = %e,
                        "the jobs rendering a bundle failed: its stored copy cannot be served");
                }
                return Err(e.into());
            }
            Err(e @ FarmError::Io { .. }) => {
                let mut status = Status::from(e);
                status = Status::new(
                    status.code(),
                    format!("{} ({NOT_SERVED})", status.message()),
                );
                return Err(status);
            }
            Err(e) => return Err(e.into()),
        };
        Ok(Response::new(stream_file(
            tokio::fs::File::from_std(file),
            |data, _| pb::BundleChunk { data },
        )))
    }
}

/// Said by a bundle download the coordinator could not serve for a reason
/// of its own (out of descriptors, a failing disk); a worker that returns
/// its tile with an error naming it (it passes the status's message on) is
/// not held to fault.
pub const NOT_SERVED: &str = "the coordinator could not serve the bundle; not the job's fault";

/// How long a download of a bundle whose stored copy cannot be opened for
/// a reason other than its absence (out of descriptors, a failing disk)
/// waits between tries at most: 50, 200 and 800 ms, then the error.
const BUNDLE_RETRY_WAIT: Duration = Duration::from_millis(1000);

/// Sends a file in chunks made by `make` (`size` is the file's size on the
/// first chunk, 0 after; at least one chunk, empty for an empty file),
/// reading a chunk at a time.
fn stream_file<T: Send + 'static>(
    mut file: tokio::fs::File,
    make: impl Fn(Vec<u8>, u64) -> T + Send + 'static,
) -> ReceiverStream<Result<T, Status>> {
    use tokio::io::AsyncReadExt;
    let (tx, rx) = mpsc::channel(4);
    tokio::spawn(async move {
        let size = file.metadata().await.map(|m| m.len()).unwrap_or(0);
        let mut first = true;
        loop {
            let mut buf = vec![0u8; CHUNK_SIZE];
            let n = match file.read(&mut buf).await {
                Ok(n) => n,
                Err(e) => {
                    let _ = tx
                        .send(Err(Status::internal(format!("reading: {e}"))))
                        .await;
                    break;
                }
            };
            if n == 0 && !first {
                break;
            }
            buf.truncate(n);
            let chunk = make(buf, if first { size } else { 0 });
            first = false;
            if tx.send(Ok(chunk)).await.is_err() || n == 0 {
                break;
            }
        }
    });
    ReceiverStream::new(rx)
}

/// `trevi.v1.Jobs`.
pub struct JobsService {
    pub farm: Arc<Farm>,
}

#[tonic::async_trait]
impl pb::jobs_server::Jobs for JobsService {
    async fn submit_job(
        &self,
        req: Request<pb::SubmitJobRequest>,
    ) -> Result<Response<pb::JobStatus>, Status> {
        // Submitters are told apart by their address (see Limits).
        let who = req
            .remote_addr()
            .map(|a| a.ip().to_string())
            .unwrap_or_default();
        let r = req.into_inner();
        let farm = self.farm.clone();
        let info = blocking(move || {
            let mut spec = farm.job_spec(&r.bundle_hash, &r.camera, r.priority, r.tile_size)?;
            spec.output_name = crate::farm::output_name_as(&spec.output_name, &r.output_format)?;
            match r.frames {
                Some(f) => farm.submit_sequence(spec, f.first, f.last, &who),
                None => farm.submit(
                    spec,
                    SubmitOptions {
                        who: &who,
                        ..SubmitOptions::default()
                    },
                ),
            }
        })
        .await?;
        Ok(Response::new(job_status(&info)))
    }

    type WatchJobStream = ReceiverStream<Result<pb::JobStatus, Status>>;

    async fn watch_job(
        &self,
        req: Request<pb::JobId>,
    ) -> Result<Response<Self::WatchJobStream>, Status> {
        let mut rx = self.farm.watch(req.into_inner().id)?;
        let (tx, out) = mpsc::channel(4);
        tokio::spawn(async move {
            loop {
                let info = rx.borrow_and_update().clone();
                let fin = info.state.is_final();
                if tx.send(Ok(job_status(&info))).await.is_err() || fin {
                    break;
                }
                // Coalesce bursts of tiles into at most ~20 updates a second.
                tokio::time::sleep(Duration::from_millis(50)).await;
                if rx.changed().await.is_err() {
                    break;
                }
            }
        });
        Ok(Response::new(ReceiverStream::new(out)))
    }

    async fn get_job(&self, req: Request<pb::JobId>) -> Result<Response<pb::JobStatus>, Status> {
        Ok(Response::new(job_status(
            &self.farm.info(req.into_inner().id)?,
        )))
    }

    async fn list_jobs(
        &self,
        req: Request<pb::ListJobsRequest>,
    ) -> Result<Response<pb::ListJobsResponse>, Status> {
        let req = req.into_inner();
        let from = if req.page_token.is_empty() {
            0
        } else {
            req.page_token.parse::<u64>().map_err(|_| {
                Status::invalid_argument(format!(
                    "page_token \"{}\" is not one this coordinator gave",
                    req.page_token.chars().take(40).collect::<String>()
                ))
            })?
        };
        let limits = self.farm.config().limits;
        let limit = match req.limit {
            0 => limits.list_page_default,
            n => (n as usize).min(limits.list_page_max),
        };
        let (page, mut next) = self.farm.list_from(from, limit);
        // Errors make statuses long: stop a page at about list_page_bytes.
        let mut jobs = Vec::with_capacity(page.len());
        let mut bytes = 0;
        for info in &page {
            let s = job_status(info);
            // The numbers take at most ~100 bytes; the strings their length.
            bytes +=
                100 + s.camera.len() + s.output_name.len() + s.error.len() + s.bundle_hash.len();
            if bytes > limits.list_page_bytes && !jobs.is_empty() {
                next = Some(info.id);
                break;
            }
            jobs.push(s);
        }
        Ok(Response::new(pb::ListJobsResponse {
            jobs,
            next_page_token: next.map(|id| id.to_string()).unwrap_or_default(),
        }))
    }

    async fn cancel_job(&self, req: Request<pb::JobId>) -> Result<Response<pb::JobStatus>, Status> {
        let id = req.into_inner().id;
        let farm = self.farm.clone();
        let info = blocking(move || farm.cancel(id)).await?;
        Ok(Response::new(job_status(&info)))
    }

    async fn get_preview(&self, req: Request<pb::JobId>) -> Result<Response<pb::Preview>, Status> {
        let id = req.into_inner().id;
        let farm = self.farm.clone();
        let p = blocking(move || farm.preview(id)).await?;
        Ok(Response::new(pb::Preview {
            png: p.png.as_ref().clone(),
            width: p.width,
            height: p.height,
            tiles: p.tiles,
        }))
    }

    type DownloadOutputStream = ReceiverStream<Result<pb::OutputChunk, Status>>;

    async fn download_output(
        &self,
        req: Request<pb::JobId>,
    ) -> Result<Response<Self::DownloadOutputStream>, Status> {
        let r = req.into_inner();
        let (id, frame) = (r.id, r.frame);
        // Finding and opening the file touches the disk: off the async
        // threads, like every file system call (issue 36: a lookup that
        // stat'ed every frame of a long sequence here held a runtime
        // thread for half a minute and let leases expire).
        let farm = self.farm.clone();
        let file = blocking(move || {
            let path = match frame {
                Some(f) => farm.frame_file(id, Some(f))?,
                None => farm.output_file(id)?,
            };
            let file = std::fs::File::open(&path)
                .map_err(|e| FarmError::io(format!("opening the output of job {id}"), e))?;
            farm.fetched(id, frame);
            Ok(file)
        })
        .await?;
        Ok(Response::new(stream_file(
            tokio::fs::File::from_std(file),
            |data, size| pb::OutputChunk { data, size },
        )))
    }
}

/// `trevi.v1.Workers`.
pub struct WorkersService {
    pub farm: Arc<Farm>,
    /// One permit per tile upload being received
    /// ([`Limits::max_tile_uploads`]).
    ///
    /// [`Limits::max_tile_uploads`]: crate::limits::Limits::max_tile_uploads
    pub tile_uploads: Arc<Semaphore>,
}

impl WorkersService {
    pub fn new(farm: Arc<Farm>) -> Self {
        let n = farm.config().limits.max_tile_uploads;
        WorkersService {
            farm,
            tile_uploads: Arc::new(Semaphore::new(n)),
        }
    }

    /// The next message of a tile upload, or `DEADLINE_EXCEEDED` once the
    /// worker has sent nothing for [`Limits::upload_idle`]: an upload
    /// holds one of the few [`Limits::max_tile_uploads`] permits, so a
    /// stalled one must not keep it.
    ///
    /// [`Limits::upload_idle`]: crate::limits::Limits::upload_idle
    /// [`Limits::max_tile_uploads`]: crate::limits::Limits::max_tile_uploads
    async fn next_part(
        &self,
        s: &mut Streaming<pb::TileUpload>,
    ) -> Result<Option<pb::TileUpload>, Status> {
        let idle = self.farm.config().limits.upload_idle;
        match tokio::time::timeout(idle, s.message()).await {
            Ok(m) => m,
            Err(_) => Err(Status::deadline_exceeded(format!(
                "the tile upload sent nothing for {} ms, the coordinator's limit \
                 (--upload-idle-ms); dropped",
                idle.as_millis()
            ))),
        }
    }

    /// The rest of an upload of encoded segments (docs/farm.md, "Encoded
    /// segments"), `first` its first message after the header: segments in
    /// order, then one `preview`. Each part is checked as it comes, before
    /// it is kept: the segment's index is the next of the rect's, its
    /// deflate bytes at most `max_segment_deflate_len` of its rows'
    /// filtered bytes, the sums three a preview cell; so what is held is at
    /// most about 1.5 bytes a pixel of the rect, which
    /// [`Farm::span_tiles`] already bounded. A refusal re-queues the span's
    /// tiles ([`Farm::reject_segments`]); the rest of the checks are
    /// [`Farm::put_segments`]'s.
    async fn submit_segments(
        &self,
        header: pb::TileHeader,
        rect: trevi_core::Rect,
        parts: Vec<trevi_core::Rect>,
        first: Option<pb::TileUpload>,
        mut s: Streaming<pb::TileUpload>,
    ) -> Result<Response<pb::TileAck>, Status> {
        use trevi_core::output::{max_segment_deflate_len, PngSegment};
        let (worker, lease, job) = (header.worker_id, header.lease_id, header.job_id);
        let refuse = |why: String| {
            let farm = self.farm.clone();
            let parts = parts.clone();
            async move {
                let e = blocking(move || {
                    Ok(farm.reject_segments(lease, job, &parts, Some(worker), why))
                })
                .await?;
                Err::<Response<pb::TileAck>, Status>(e.into())
            }
        };
        let plan = match self.farm.segment_plan(job, rect) {
            Ok(p) => p,
            Err(FarmError::BadTile(m)) => return refuse(m).await,
            Err(e) => return Err(e.into()),
        };
        let mut segments: Vec<PngSegment> = Vec::with_capacity(plan.count.min(4096) as usize);
        let mut sums: Option<Vec<f32>> = None;
        let mut next = first;
        while let Some(m) = next {
            match m.part {
                Some(Part::Segment(e)) if sums.is_none() => {
                    let i = segments.len() as u32;
                    if i >= plan.count {
                        return refuse(format!(
                            "more than the {} segments of rows {}..{}",
                            plan.count,
                            rect.y,
                            rect.y + rect.h
                        ))
                        .await;
                    }
                    if e.index != plan.first + i {
                        return refuse(format!(
                            "segment {} came where segment {} was due",
                            e.index,
                            plan.first + i
                        ))
                        .await;
                    }
                    let most = max_segment_deflate_len(plan.filtered_len(i));
                    if e.deflate.len() as u64 > most {
                        return refuse(format!(
                            "segment {} has {} deflate bytes, more than the {most} its rows \
                             can take",
                            e.index,
                            e.deflate.len()
                        ))
                        .await;
                    }
                    segments.push(PngSegment {
                        deflate: e.deflate,
                        adler32: e.adler32,
                        filtered_len: e.filtered_len,
                    });
                }
                Some(Part::Preview(p)) if sums.is_none() => {
                    if p.sums.len() != 3 * plan.cells {
                        return refuse(format!(
                            "{} preview sums uploaded, but the rect overlaps {} preview cells \
                             of {} pixels: {} sums",
                            p.sums.len(),
                            plan.cells,
                            plan.scale,
                            3 * plan.cells
                        ))
                        .await;
                    }
                    sums = Some(p.sums);
                }
                _ => {
                    return refuse(
                        "an upload of segments is its header, its segments in order, then one \
                         preview part, and nothing else"
                            .to_string(),
                    )
                    .await
                }
            }
            next = self.next_part(&mut s).await?;
        }
        let Some(sums) = sums else {
            return refuse("an upload of segments ends with its preview sums".to_string()).await;
        };
        let farm = self.farm.clone();
        let (rays, render) = (header.rays, header.render_micros.map(Duration::from_micros));
        let outcome = blocking(move || {
            farm.put_segments(
                SegmentUpload {
                    lease,
                    job,
                    rect,
                    rays,
                    worker: Some(worker),
                    segments: &segments,
                    sums: &sums,
                },
                &parts,
                render,
            )
        })
        .await?;
        Ok(Response::new(pb::TileAck {
            accepted: outcome == TileOutcome::Accepted,
        }))
    }
}

#[tonic::async_trait]
impl pb::workers_server::Workers for WorkersService {
    async fn register(
        &self,
        req: Request<pb::RegisterRequest>,
    ) -> Result<Response<pb::RegisterResponse>, Status> {
        // Workers are counted by their address (see Limits).
        let addr = req
            .remote_addr()
            .map(|a| a.ip().to_string())
            .unwrap_or_default();
        let r = req.into_inner();
        let reg = self.farm.register_worker(WorkerOptions {
            addr: &addr,
            name: &r.name,
            threads: r.threads,
            session: true,
            multi_tile: r.multi_tile,
            max_memory: r.max_memory,
            png_segments: r.png_encoder == trevi_core::output::PNG_ENCODER,
        })?;
        tracing::info!(worker = reg.id, name = %r.name, threads = r.threads, "worker registered");
        Ok(Response::new(pb::RegisterResponse {
            worker_id: reg.id,
            lease_ttl_ms: self.farm.config().limits.lease_ttl.as_millis() as u64,
            session: reg.session.map(|s| s.to_vec()).unwrap_or_default(),
        }))
    }

    async fn lease_tile(
        &self,
        req: Request<pb::LeaseRequest>,
    ) -> Result<Response<pb::LeaseResponse>, Status> {
        let r = req.into_inner();
        self.farm.check_session(r.worker_id, &r.session)?;
        let most = self.farm.config().limits.lease_wait;
        let wait = match r.max_wait_ms {
            0 => most,
            ms => Duration::from_millis(ms.into()).min(most),
        };
        let lease = self.farm.lease_wait(r.worker_id, wait).await?;
        let preview_scale = match &lease {
            Some(l) if l.png_segments => self.farm.preview_scale(l.job),
            _ => 0,
        };
        Ok(Response::new(pb::LeaseResponse {
            lease: lease.map(|l| pb::Lease {
                lease_id: l.id,
                job_id: l.job,
                bundle_hash: l.bundle_hash,
                camera: l.camera,
                rect: Some(l.rect.into()),
                tiles: l.tiles,
                memory_estimate: l.memory_estimate,
                frame: l.frame,
                png_segments: l.png_segments,
                preview_scale,
            }),
        }))
    }

    async fn heartbeat(
        &self,
        req: Request<pb::HeartbeatRequest>,
    ) -> Result<Response<pb::HeartbeatResponse>, Status> {
        let r = req.into_inner();
        self.farm.check_session(r.worker_id, &r.session)?;
        let dropped = self.farm.heartbeat(r.worker_id, &r.lease_ids)?;
        let paused = (!r.paused.is_empty()).then_some(r.paused.as_str());
        self.farm.set_paused(r.worker_id, paused);
        Ok(Response::new(pb::HeartbeatResponse { dropped }))
    }

    async fn submit_tile(
        &self,
        req: Request<Streaming<pb::TileUpload>>,
    ) -> Result<Response<pb::TileAck>, Status> {
        let mut s = req.into_inner();
        let header = match self.next_part(&mut s).await?.and_then(|m| m.part) {
            Some(Part::Header(h)) => h,
            _ => {
                return Err(Status::invalid_argument(
                    "a tile upload starts with its header",
                ))
            }
        };
        self.farm.check_session(header.worker_id, &header.session)?;
        let rect = rect_from(header.rect).map_err(|e| Status::invalid_argument(e.to_string()))?;
        // Its turn: the rest of the upload waits, unread, within its
        // stream window, until fewer than `max_tile_uploads` are received.
        let _permit = self
            .tile_uploads
            .clone()
            .acquire_owned()
            .await
            .map_err(|_| Status::unavailable("the coordinator is stopping"))?;
        // A rectangle that is not one of the job's tiles (or a span of
        // them, at most `max_lease_pixels` for floats and
        // `max_segment_lease_pixels` for segments) is refused before more
        // than the first part (itself within the message size limit) is
        // read, so a huge one cannot make us allocate.
        let first = self.next_part(&mut s).await?;
        let segments = matches!(
            first.as_ref().and_then(|m| m.part.as_ref()),
            Some(Part::Segment(_))
        );
        let parts = self.farm.span_tiles_as(header.job_id, rect, segments)?;
        self.farm.check_frame(header.job_id, header.frame)?;
        if segments {
            return self.submit_segments(header, rect, parts, first, s).await;
        }
        let expected = rect.pixel_count().saturating_mul(12);
        let mut bytes = Vec::with_capacity(expected.min(64 << 20));
        let mut oversized = false;
        let mut next = first;
        while let Some(m) = next {
            match m.part {
                Some(Part::Pixels(p)) => {
                    if bytes.len() + p.len() > expected {
                        // Stop reading: the size check rejects it.
                        oversized = true;
                        break;
                    }
                    bytes.extend_from_slice(&p);
                }
                _ => {
                    return Err(Status::invalid_argument(
                        "a tile upload has one header, then pixels (or segments, then preview \
                         sums)",
                    ))
                }
            }
            next = self.next_part(&mut s).await?;
        }
        let pixels = match pixels_from_bytes(&bytes) {
            Ok(p) if !oversized => p,
            _ => Vec::new(), // Wrong size: validation rejects and re-queues.
        };
        let farm = self.farm.clone();
        let (worker, lease, job, rays) = (
            header.worker_id,
            header.lease_id,
            header.job_id,
            header.rays,
        );
        let render = header.render_micros.map(Duration::from_micros);
        let outcome = blocking(move || {
            farm.put_span_rendered(
                TileResult {
                    lease,
                    job,
                    rect,
                    rays,
                    pixels: &pixels,
                    worker: Some(worker),
                },
                &parts,
                render,
            )
        })
        .await?;
        Ok(Response::new(pb::TileAck {
            accepted: outcome == TileOutcome::Accepted,
        }))
    }

    async fn return_tile(
        &self,
        req: Request<pb::TileReturn>,
    ) -> Result<Response<pb::TileReturnAck>, Status> {
        let r = req.into_inner();
        self.farm.check_session(r.worker_id, &r.session)?;
        // The error comes from the network: keep what is logged short.
        let keep = self.farm.config().limits.max_return_error_chars;
        let error: String = r.error.chars().take(keep).collect();
        let error = (!error.is_empty()).then_some(error);
        // The coordinator's own fault (it could not serve the bundle): the
        // tile is re-queued without counting against it or the worker. A
        // worker that says so falsely gains nothing it could not have by
        // returning the tile without an error.
        if let Some(e) = error.as_deref().filter(|e| e.contains(NOT_SERVED)) {
            tracing::warn!(worker = r.worker_id, lease = r.lease_id, error = %e,
                "tile returned: the coordinator could not serve its bundle; re-queued");
            self.farm.return_tile(r.worker_id, r.lease_id, None)?;
            return Ok(Response::new(pb::TileReturnAck {}));
        }
        if r.memory_needed > 0 && error.is_none() {
            self.farm
                .decline_tile(r.worker_id, r.lease_id, r.memory_needed)?;
            return Ok(Response::new(pb::TileReturnAck {}));
        }
        self.farm
            .return_tile(r.worker_id, r.lease_id, error.as_deref())?;
        Ok(Response::new(pb::TileReturnAck {}))
    }
}

/// How the services are guarded.
#[derive(Clone, Default)]
pub struct ServeOptions {
    /// Tokens for submitters and workers (none: an open farm).
    pub tokens: Tokens,
    /// Serve over TLS with this certificate and key (none: plain gRPC); see
    /// [`crate::tls`].
    pub tls: Option<tonic::transport::ServerTlsConfig>,
}

/// Serves the coordinator on `listener` until `shutdown` resolves: the three
/// `trevi.v1` services, `grpc.health.v1` and server reflection, with the
/// farm's periodic work ([`Farm::start_upkeep`]) running meanwhile.
/// Connections are accepted
/// through errors such as running out of file descriptors
/// ([`crate::listen::accept`]). No tokens, no TLS.
pub async fn serve(
    farm: Arc<Farm>,
    listener: TcpListener,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<(), tonic::transport::Error> {
    serve_with(farm, listener, shutdown, ServeOptions::default()).await
}

/// [`serve`] with tokens and TLS.
pub async fn serve_with(
    farm: Arc<Farm>,
    listener: TcpListener,
    shutdown: impl Future<Output = ()> + Send,
    opts: ServeOptions,
) -> Result<(), tonic::transport::Error> {
    use pb::{
        bundles_server::BundlesServer, jobs_server::JobsServer, workers_server::WorkersServer,
    };

    // A stream may send `TILE_UPLOAD_WINDOW` before it is read: what an
    // upload waiting for its turn holds (`Limits::max_tile_uploads`);
    // waiting ones never fill the connection's window.
    let mut server = tonic::transport::Server::builder()
        .initial_stream_window_size(crate::limits::TILE_UPLOAD_WINDOW)
        .initial_connection_window_size(crate::limits::CONNECTION_WINDOW)
        .max_concurrent_streams(crate::limits::MAX_STREAMS_PER_CONNECTION);
    if let Some(tls) = opts.tls {
        server = server.tls_config(tls)?;
    }

    let (health, health_service) = tonic_health::server::health_reporter();
    health.set_serving::<JobsServer<JobsService>>().await;
    health.set_serving::<WorkersServer<WorkersService>>().await;
    health.set_serving::<BundlesServer<BundlesService>>().await;
    // Reflection v1 and v1alpha (which grpcurl and most clients still ask).
    let reflecting = || {
        tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(pb::FILE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
    };
    let reflection = reflecting()
        .build_v1()
        .expect("the embedded descriptor sets are valid");
    let reflection_v1alpha = reflecting()
        .build_v1alpha()
        .expect("the embedded descriptor sets are valid");

    let upkeep = farm.start_upkeep();

    // Accepted by a task that rides out accept errors (see
    // `crate::listen`): tonic would retry at once, spinning while file
    // descriptors are short.
    let (conn_tx, conn_rx) = mpsc::channel::<std::io::Result<tokio::net::TcpStream>>(16);
    let acceptor = tokio::spawn(async move {
        loop {
            let (tcp, _) = tokio::select! {
                c = crate::listen::accept(&listener, "gRPC") => c,
                _ = conn_tx.closed() => break,
            };
            // Small messages (leases, acks) must not wait for Nagle's algorithm.
            let _ = tcp.set_nodelay(true);
            if conn_tx.send(Ok(tcp)).await.is_err() {
                break;
            }
        }
    });
    let incoming = ReceiverStream::new(conn_rx);
    let tokens = Arc::new(opts.tokens);
    let guard = |need, service| Auth {
        tokens: tokens.clone(),
        need,
        service,
    };
    let max_msg = farm.config().limits.max_message_bytes;
    let bundles =
        BundlesServer::new(BundlesService::new(farm.clone())).max_decoding_message_size(max_msg);
    let jobs =
        JobsServer::new(JobsService { farm: farm.clone() }).max_decoding_message_size(max_msg);
    let latency = crate::metrics::LatencyLayer {
        metrics: farm.metrics().clone(),
    };
    let workers = WorkersServer::new(WorkersService::new(farm)).max_decoding_message_size(max_msg);
    let result = server
        .layer(latency)
        .add_service(health_service)
        .add_service(reflection)
        .add_service(reflection_v1alpha)
        .add_service(tonic::service::interceptor::InterceptedService::new(
            bundles,
            guard(Need::Either, "trevi.v1.Bundles"),
        ))
        .add_service(tonic::service::interceptor::InterceptedService::new(
            jobs,
            guard(Need::Submitter, "trevi.v1.Jobs"),
        ))
        .add_service(tonic::service::interceptor::InterceptedService::new(
            workers,
            guard(Need::Worker, "trevi.v1.Workers"),
        ))
        .serve_with_incoming_shutdown(incoming, shutdown)
        .await;
    drop(upkeep);
    acceptor.abort();
    result
}
