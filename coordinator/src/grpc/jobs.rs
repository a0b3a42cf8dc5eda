//! `trevi.v1.Jobs`: submitting, watching, listing, pausing, resuming,
//! retrying and cancelling jobs, unblocking workers and reading the tile
//! log (`log.rs`), their previews and their finished outputs, the usage
//! history; and
//! [`job_status`], a job's status as the wire carries it.

use super::{blocking, stream_file};
use crate::auth;
use crate::farm::{Farm, Progressive, SubmitOptions};
use crate::scheduler::{JobInfo, JobState};
use crate::usage::{usage_to_pb, UsageQuery};
use crate::FarmError;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status};
use trevi_proto::pb;

/// A job's status as the wire carries it (what `SubmitJob`, `GetJob`,
/// `WatchJob`, `ListJobs` and the others answer).
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
        passes: info.passes.as_ref().map(|p| pb::PassesInfo {
            done: p.done,
            samples_done: p.samples_done,
            samples_total: p.samples_total,
            error: p.error,
            pass: p.pass,
            time_limit_ms: p.time_limit.map_or(0, |d| d.as_millis() as u64),
            noise_target: p.noise_target.unwrap_or(0.0),
            stopped_by: p.stopped_by.map_or("", |r| r.label()).to_string(),
        }),
        paused: info.paused,
        waiting_for: info.waiting_for.clone(),
        blocked: super::log::blocked_status(&info.blocked),
        aovs: info.spec.aovs.to_string(),
    }
}

/// A request's progressive settings (0: not set, each).
pub fn progressive_from(p: &pb::Progressive) -> Progressive {
    Progressive {
        samples: p.samples,
        pass: p.pass,
        time_limit: (p.time_limit_ms > 0).then(|| Duration::from_millis(p.time_limit_ms)),
        noise_target: (p.noise_target != 0.0).then_some(p.noise_target),
    }
}

/// `trevi.v1.Jobs`.
pub struct JobsService {
    /// The coordinator the service answers for.
    pub farm: Arc<Farm>,
}

#[tonic::async_trait]
impl pb::jobs_server::Jobs for JobsService {
    async fn submit_job(
        &self,
        req: Request<pb::SubmitJobRequest>,
    ) -> Result<Response<pb::JobStatus>, Status> {
        // Submitters are told apart by their named token, else by their
        // address (see Limits and `auth::named`).
        let who = match auth::granted(&req).name {
            Some(name) => name.to_string(),
            None => req
                .remote_addr()
                .map(|a| a.ip().to_string())
                .unwrap_or_default(),
        };
        let r = req.into_inner();
        // Checked before any work.
        let notify = crate::events::check_urls(&r.notify, "--notify")?;
        let progressive = r.progressive.is_some();
        let aovs = crate::farm::aovs_from(r.aovs.as_deref(), progressive)?;
        let farm = self.farm.clone();
        let info = blocking(move || {
            // Checked before the scene is read (the list is bounded).
            farm.check_after(&r.after)?;
            let mut spec = farm.job_spec(&r.bundle_hash, &r.camera, r.priority, r.tile_size)?;
            spec.output_name = crate::farm::output_name_as(&spec.output_name, &r.output_format)?;
            crate::farm::apply_aovs(&mut spec, aovs, progressive);
            let opts = SubmitOptions {
                who: &who,
                after: r.after,
                notify,
                sink: None,
            };
            match (r.frames, r.progressive) {
                (Some(f), Some(p)) => farm.submit_progressive_sequence(
                    spec,
                    f.first,
                    f.last,
                    progressive_from(&p),
                    opts,
                ),
                (None, Some(p)) => farm.submit_progressive(spec, progressive_from(&p), opts),
                (Some(f), None) => farm.submit_sequence(spec, f.first, f.last, opts),
                (None, None) => farm.submit(spec, opts),
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
        // threads, like every file system call (a lookup that stat'ed every
        // frame of a long sequence here once held a runtime thread for half
        // a minute and let leases expire).
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

    type DownloadAovStream = ReceiverStream<Result<pb::OutputChunk, Status>>;

    async fn download_aov(
        &self,
        req: Request<pb::AovFileRequest>,
    ) -> Result<Response<Self::DownloadAovStream>, Status> {
        let r = req.into_inner();
        let farm = self.farm.clone();
        let file = blocking(move || {
            let path = farm.aov_file(r.id, &r.aov, r.frame)?;
            let file = std::fs::File::open(&path).map_err(|e| {
                FarmError::io(format!("opening the {} pass of job {}", r.aov, r.id), e)
            })?;
            Ok(file)
        })
        .await?;
        Ok(Response::new(stream_file(
            tokio::fs::File::from_std(file),
            |data, size| pb::OutputChunk { data, size },
        )))
    }

    async fn extend_job(
        &self,
        req: Request<pb::ExtendJobRequest>,
    ) -> Result<Response<pb::JobStatus>, Status> {
        let r = req.into_inner();
        let farm = self.farm.clone();
        let p = r.passes.as_ref().map(progressive_from).unwrap_or_default();
        let info = blocking(move || farm.extend(r.id, r.samples, p)).await?;
        Ok(Response::new(job_status(&info)))
    }

    async fn pause_job(
        &self,
        req: Request<pb::PauseJobRequest>,
    ) -> Result<Response<pb::JobStatus>, Status> {
        let r = req.into_inner();
        let farm = self.farm.clone();
        let info = blocking(move || farm.pause(r.id, r.now)).await?;
        Ok(Response::new(job_status(&info)))
    }

    async fn resume_job(&self, req: Request<pb::JobId>) -> Result<Response<pb::JobStatus>, Status> {
        let id = req.into_inner().id;
        let farm = self.farm.clone();
        let info = blocking(move || farm.resume(id)).await?;
        Ok(Response::new(job_status(&info)))
    }

    async fn retry_job(&self, req: Request<pb::JobId>) -> Result<Response<pb::JobStatus>, Status> {
        let id = req.into_inner().id;
        let farm = self.farm.clone();
        let info = blocking(move || farm.retry_job(id)).await?;
        Ok(Response::new(job_status(&info)))
    }

    async fn requeue_job(
        &self,
        req: Request<pb::RequeueJobRequest>,
    ) -> Result<Response<pb::JobStatus>, Status> {
        let r = req.into_inner();
        let frames = r.frames.map(|f| (f.first, f.last));
        if let Some((a, b)) = frames.filter(|(a, b)| a > b) {
            return Err(Status::invalid_argument(format!(
                "frames {a}-{b}: the first frame is after the last"
            )));
        }
        let rect = r.rect.map(|q| trevi_core::Rect::new(q.x, q.y, q.w, q.h));
        let farm = self.farm.clone();
        let info = blocking(move || farm.requeue(r.id, frames, rect)).await?;
        Ok(Response::new(job_status(&info)))
    }

    async fn unblock_worker(
        &self,
        req: Request<pb::UnblockWorkerRequest>,
    ) -> Result<Response<pb::JobStatus>, Status> {
        Ok(Response::new(
            super::log::unblock(&self.farm, req.into_inner()).await?,
        ))
    }

    async fn get_tile_log(
        &self,
        req: Request<pb::TileLogRequest>,
    ) -> Result<Response<pb::TileLog>, Status> {
        Ok(Response::new(
            super::log::get_tile_log(&self.farm, req.into_inner()).await?,
        ))
    }

    async fn usage(
        &self,
        req: Request<pb::UsageRequest>,
    ) -> Result<Response<pb::UsageResponse>, Status> {
        let r = req.into_inner();
        // Checked before any work.
        let q = UsageQuery::new(r.since_s, &r.by)
            .map_err(|e| Status::invalid_argument(e.to_string()))?;
        let farm = self.farm.clone();
        let report = blocking(move || farm.usage(&q)).await?;
        Ok(Response::new(usage_to_pb(&report)))
    }
}
