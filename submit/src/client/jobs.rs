//! A farm's jobs as they stand: one job's status, the list of them (every
//! page, by id), cancelling, pausing, resuming or retrying one, extending a
//! progressive one, unblocking a worker from one and reading its tile log.

use anyhow::{Context, Result};
use trevi_proto::pb;

use super::connect::status_error;
use super::Client;

impl Client {
    /// Job `id`'s status.
    pub async fn status(&mut self, id: u64) -> Result<pb::JobStatus> {
        Ok(self
            .jobs
            .get_job(pb::JobId { id, frame: None })
            .await
            .map_err(status_error)?
            .into_inner())
    }

    /// The farm's jobs by id, page by page (at most `limit` of them).
    pub async fn list(&mut self, limit: Option<usize>) -> Result<Vec<pb::JobStatus>> {
        let mut jobs = Vec::new();
        let mut page_token = String::new();
        loop {
            let want = limit.map_or(0, |l| l.saturating_sub(jobs.len()).min(u32::MAX as usize));
            let reply = self
                .jobs
                .list_jobs(pb::ListJobsRequest {
                    limit: want as u32,
                    page_token,
                })
                .await
                .map_err(status_error)?
                .into_inner();
            jobs.extend(reply.jobs);
            if let Some(l) = limit {
                jobs.truncate(l);
                if jobs.len() == l {
                    break;
                }
            }
            if reply.next_page_token.is_empty() {
                break;
            }
            page_token = reply.next_page_token;
        }
        Ok(jobs)
    }

    /// Cancels job `id`; returns its status after.
    pub async fn cancel(&mut self, id: u64) -> Result<pb::JobStatus> {
        Ok(self
            .jobs
            .cancel_job(pb::JobId { id, frame: None })
            .await
            .map_err(status_error)?
            .into_inner())
    }

    /// Pauses job `id` (with `now`, its tiles out go back to the queue at
    /// once); returns its status after.
    pub async fn pause(&mut self, id: u64, now: bool) -> Result<pb::JobStatus> {
        Ok(self
            .jobs
            .pause_job(pb::PauseJobRequest { id, now })
            .await
            .map_err(status_error)?
            .into_inner())
    }

    /// Resumes paused job `id`; returns its status after.
    pub async fn resume(&mut self, id: u64) -> Result<pb::JobStatus> {
        Ok(self
            .jobs
            .resume_job(pb::JobId { id, frame: None })
            .await
            .map_err(status_error)?
            .into_inner())
    }

    /// Queues failed job `id` again with its finished tiles; returns its
    /// status after.
    pub async fn retry(&mut self, id: u64) -> Result<pb::JobStatus> {
        Ok(self
            .jobs
            .retry_job(pb::JobId { id, frame: None })
            .await
            .map_err(status_error)?
            .into_inner())
    }

    /// Renders part of job `id` again (frames of a sequence, the tiles a
    /// rect touches); returns the job's status after.
    pub async fn requeue(
        &mut self,
        id: u64,
        frames: Option<(u32, u32)>,
        rect: Option<[u32; 4]>,
    ) -> Result<pb::JobStatus> {
        Ok(self
            .jobs
            .requeue_job(pb::RequeueJobRequest {
                id,
                frames: frames.map(|(first, last)| pb::FrameRange { first, last }),
                rect: rect.map(|[x, y, w, h]| pb::Rect { x, y, w, h }),
            })
            .await
            .map_err(status_error)?
            .into_inner())
    }

    /// Lets `worker` (an id or a name) take job `id`'s tiles again;
    /// returns the job's status after.
    pub async fn unblock(&mut self, id: u64, worker: &str) -> Result<pb::JobStatus> {
        Ok(self
            .jobs
            .unblock_worker(pb::UnblockWorkerRequest {
                id,
                worker: worker.to_string(),
            })
            .await
            .map_err(status_error)?
            .into_inner())
    }

    /// Job `id`'s tile log as `request` filters it.
    pub async fn tile_log(&mut self, request: pb::TileLogRequest) -> Result<pb::TileLog> {
        Ok(self
            .jobs
            .get_tile_log(request)
            .await
            .map_err(status_error)?
            .into_inner())
    }

    /// Adds samples to finished progressive job `id` (see
    /// [`crate::passes::extend_request`]); returns its status after.
    pub async fn extend(&mut self, request: pb::ExtendJobRequest) -> Result<pb::JobStatus> {
        let id = request.id;
        Ok(self
            .jobs
            .extend_job(request)
            .await
            .map_err(status_error)
            .with_context(|| format!("the coordinator did not extend job {id}"))?
            .into_inner())
    }

    /// The farm's usage history over the last `since` (`None`: the
    /// coordinator's default), grouped `by`.
    pub async fn usage(
        &mut self,
        since: Option<std::time::Duration>,
        by: crate::usage::By,
    ) -> Result<pb::UsageResponse> {
        Ok(self
            .jobs
            .usage(pb::UsageRequest {
                since_s: since.map_or(0, |d| d.as_secs()),
                by: by.name().into(),
            })
            .await
            .map_err(status_error)?
            .into_inner())
    }
}
