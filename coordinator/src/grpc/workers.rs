//! `trevi.v1.Workers`: registering, leasing tiles, heartbeats, and taking
//! results back (floats or encoded PNG segments) or tiles returned
//! unrendered.

use super::{blocking, NOT_SERVED};
use crate::farm::{Farm, LeaseResult, RenderedLease, SegmentUpload, TileOutcome, WorkerOptions};
use crate::FarmError;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::mpsc;
use tokio::sync::Semaphore;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};
use trevi_core::passes::TileState;
use trevi_proto::pb::{self, tile_upload::Part};
use trevi_proto::{pixels_from_bytes, rect_from, CHUNK_SIZE};

/// Adds a piece of an upload's accumulation state, refusing more than a
/// state of `rect` can be ([`TileState::encoded_len`]) before holding it.
fn add_state(
    state: &mut Option<Vec<u8>>,
    piece: &[u8],
    rect: trevi_core::Rect,
) -> Result<(), String> {
    let most = TileState::encoded_len(rect);
    let have = state.as_ref().map_or(0, Vec::len);
    if have + piece.len() > most {
        return Err(format!(
            "the accumulation state is longer than the {most} bytes a state of {}x{} pixels is",
            rect.w, rect.h
        ));
    }
    state
        .get_or_insert_with(|| Vec::with_capacity(most.min(64 << 20)))
        .extend_from_slice(piece);
    Ok(())
}

/// `trevi.v1.Workers`.
pub struct WorkersService {
    /// The coordinator the service answers for.
    pub farm: Arc<Farm>,
    /// One permit per tile upload being received
    /// ([`Limits::max_tile_uploads`]).
    ///
    /// [`Limits::max_tile_uploads`]: crate::limits::Limits::max_tile_uploads
    pub tile_uploads: Arc<Semaphore>,
}

impl WorkersService {
    /// The service over `farm`, with its
    /// [`Limits::max_tile_uploads`] upload permits.
    ///
    /// [`Limits::max_tile_uploads`]: crate::limits::Limits::max_tile_uploads
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
        let mut state: Option<Vec<u8>> = None;
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
                Some(Part::State(b)) if sums.is_some() => {
                    if let Err(why) = add_state(&mut state, &b, rect) {
                        return refuse(why).await;
                    }
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
        let (cpu, tiles) = (header.cpu_micros, parts.len() as u64);
        let outcome = blocking(move || {
            if let Err(e) = farm.put_state(job, rect, &parts, state.as_deref()) {
                return Err(match e {
                    FarmError::BadTile(why) => {
                        farm.reject_segments(lease, job, &parts, Some(worker), why)
                    }
                    e => e,
                });
            }
            let outcome = farm.put_segments(
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
            )?;
            if outcome == TileOutcome::Accepted {
                farm.count_usage(job, worker, cpu, tiles, rays);
            }
            Ok(outcome)
        })
        .await?;
        self.log_rendered(&header, rect, tiles as usize, outcome)
            .await;
        Ok(Response::new(pb::TileAck {
            accepted: outcome == TileOutcome::Accepted,
        }))
    }

    /// Logs a lease whose result was accepted in its job's tile log (see
    /// `crate::farm::tile_log`).
    async fn log_rendered(
        &self,
        h: &pb::TileHeader,
        rect: trevi_core::Rect,
        tiles: usize,
        outcome: TileOutcome,
    ) {
        if outcome != TileOutcome::Accepted {
            return;
        }
        let r = RenderedLease {
            job: h.job_id,
            worker: h.worker_id,
            rect,
            tiles: tiles as u32,
            rays: h.rays,
            render_micros: h.render_micros,
            cpu_micros: header_cpu_micros(h),
        };
        let farm = self.farm.clone();
        let _ = tokio::task::spawn_blocking(move || farm.log_rendered(&r)).await;
    }
}

/// The CPU time a worker reports for a lease, in microseconds (`None`
/// from workers too old to say): the one place the tile log reads it.
fn header_cpu_micros(h: &pb::TileHeader) -> Option<u64> {
    h.cpu_micros
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
                samples: l.samples.map(|r| pb::SampleRange {
                    start: r.start,
                    end: r.end,
                    total: r.total,
                }),
                aovs: l.aovs.to_string(),
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
        let mut state: Option<Vec<u8>> = None;
        // Render pass values: read up to the most any job's passes have (7
        // channels a pixel); their exact count is the job's, checked when
        // the tiles are admitted (`checks::validate_aovs`).
        let most_aovs = rect
            .pixel_count()
            .saturating_mul(trevi_core::Aovs::ALL.channels() * 4);
        let mut aovs: Vec<u8> = Vec::new();
        let mut next = first;
        while let Some(m) = next {
            match m.part {
                Some(Part::Aovs(_)) if state.is_some() => {
                    return Err(Status::invalid_argument(
                        "a tile upload's render passes come before its state",
                    ))
                }
                Some(Part::Aovs(a)) if !oversized => {
                    if aovs.len() + a.len() > most_aovs {
                        // Stop reading: the size check rejects it.
                        oversized = true;
                        break;
                    }
                    aovs.extend_from_slice(&a);
                }
                Some(Part::Pixels(_)) if !aovs.is_empty() => {
                    return Err(Status::invalid_argument(
                        "a tile upload's render passes come after all of its pixels",
                    ))
                }
                Some(Part::State(b)) if !oversized => {
                    if let Err(why) = add_state(&mut state, &b, rect) {
                        let farm = self.farm.clone();
                        let (lease, job, worker) =
                            (header.lease_id, header.job_id, header.worker_id);
                        let e = blocking(move || {
                            Ok(farm.reject_segments(lease, job, &parts, Some(worker), why))
                        })
                        .await?;
                        return Err(e.into());
                    }
                }
                Some(Part::Pixels(_)) if state.is_some() => {
                    return Err(Status::invalid_argument(
                        "a tile upload's state comes after all of its pixels",
                    ))
                }
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
        // Pass values that are not whole floats are of the wrong size too.
        let aovs = trevi_proto::floats_from_bytes(&aovs);
        let pixels = match pixels_from_bytes(&bytes) {
            Ok(p) if !oversized && aovs.is_some() => p,
            _ => Vec::new(), // Wrong size: validation rejects and re-queues.
        };
        let aovs = aovs.unwrap_or_default();
        let farm = self.farm.clone();
        let (worker, lease, job, rays) = (
            header.worker_id,
            header.lease_id,
            header.job_id,
            header.rays,
        );
        let render = header.render_micros.map(Duration::from_micros);
        let (cpu, tiles) = (header.cpu_micros, parts.len() as u64);
        let outcome = blocking(move || {
            if !pixels.is_empty() {
                if let Err(e) = farm.put_state(job, rect, &parts, state.as_deref()) {
                    return Err(match e {
                        FarmError::BadTile(why) => {
                            farm.reject_segments(lease, job, &parts, Some(worker), why)
                        }
                        e => e,
                    });
                }
            }
            let outcome = farm.put_span_aovs(
                LeaseResult {
                    lease,
                    job,
                    rect,
                    rays,
                    pixels: &pixels,
                    worker: Some(worker),
                },
                &aovs,
                &parts,
                render,
            )?;
            // Counted in the usage history once accepted (a late or
            // duplicate result is the farm's cost, not the job's).
            if outcome == TileOutcome::Accepted {
                farm.count_usage(job, worker, cpu, tiles, rays);
            }
            Ok(outcome)
        })
        .await?;
        self.log_rendered(&header, rect, tiles as usize, outcome)
            .await;
        Ok(Response::new(pb::TileAck {
            accepted: outcome == TileOutcome::Accepted,
        }))
    }

    type FetchStateStream = ReceiverStream<Result<pb::StateChunk, Status>>;

    /// The state a pass's lease continues, read from the state file a few
    /// rows at a time (what is held is at most a chunk and a row, and the
    /// two chunks in the channel).
    async fn fetch_state(
        &self,
        req: Request<pb::StateRequest>,
    ) -> Result<Response<Self::FetchStateStream>, Status> {
        let r = req.into_inner();
        self.farm.check_session(r.worker_id, &r.session)?;
        let farm = self.farm.clone();
        let (file, rect, next) =
            blocking(move || farm.state_source(r.worker_id, r.lease_id)).await?;
        let (tx, rx) = mpsc::channel(2);
        tokio::task::spawn_blocking(move || {
            let mut chunk = Vec::with_capacity(CHUNK_SIZE);
            let closed = || FarmError::Invalid("the worker stopped reading".into());
            let sent = file
                .read_encoded(rect, next, |piece| {
                    chunk.extend_from_slice(&piece);
                    while chunk.len() >= CHUNK_SIZE {
                        let rest = chunk.split_off(CHUNK_SIZE);
                        let full = std::mem::replace(&mut chunk, rest);
                        tx.blocking_send(Ok(pb::StateChunk { data: full }))
                            .map_err(|_| closed())?;
                    }
                    Ok(())
                })
                .and_then(|()| {
                    tx.blocking_send(Ok(pb::StateChunk { data: chunk }))
                        .map_err(|_| closed())
                });
            if let Err(e) = sent {
                let _ = tx.blocking_send(Err(e.into()));
            }
        });
        Ok(Response::new(ReceiverStream::new(rx)))
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
