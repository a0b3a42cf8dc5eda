//! Following a job to its end: its status stream shown as progress (and
//! the `--preview` file kept up to date), through a coordinator that goes
//! away and comes back (it keeps its jobs across a restart).

use anyhow::{bail, Result};
use std::time::Duration;
use trevi_proto::pb;

use super::connect::{reconnectable, status_error};
use super::preview::PreviewFile;
use super::Client;
use crate::progress::{Progress, ProgressView};

/// How long `watch` keeps trying to reach a coordinator that went away.
pub const RECONNECT_FOR: Duration = Duration::from_secs(300);

impl Client {
    /// Follows a job until it ends, showing progress; returns its last status.
    ///
    /// When the coordinator goes away (it keeps its jobs across a restart),
    /// keeps asking again with backoff for up to [`RECONNECT_FOR`].
    pub async fn watch(&mut self, id: u64, progress: Progress) -> Result<pb::JobStatus> {
        let mut view = ProgressView::new(progress);
        let mut last: Option<pb::JobStatus> = None;
        let mut preview = PreviewFile::new(self.preview.clone(), self.denoise_preview);
        let mut backoff = Duration::from_millis(100);
        let mut lost_since: Option<std::time::Instant> = None;
        let mut passes_kept = 0;
        loop {
            let why = match self.jobs.watch_job(pb::JobId { id, frame: None }).await {
                Ok(r) => {
                    let mut stream = r.into_inner();
                    loop {
                        match stream.message().await {
                            Ok(Some(s)) => {
                                lost_since = None;
                                backoff = Duration::from_millis(100);
                                view.show(&s);
                                preview.update(self, &s).await;
                                passes_kept = self.keep_pass(id, &s, passes_kept).await;
                                last = Some(s);
                            }
                            Ok(None) => break "the progress stream ended".to_string(),
                            Err(s) if reconnectable(&s) => break s.message().to_string(),
                            Err(s) => {
                                view.done();
                                return Err(status_error(s));
                            }
                        }
                    }
                }
                Err(s) if reconnectable(&s) => s.message().to_string(),
                Err(s) => {
                    view.done();
                    return Err(status_error(s));
                }
            };
            if let Some(l) = &last {
                if l.state().is_final() {
                    break;
                }
            }
            let since = *lost_since.get_or_insert_with(std::time::Instant::now);
            if since.elapsed() > RECONNECT_FOR {
                view.done();
                match &last {
                    Some(l) => bail!(
                        "lost the coordinator while job {id} was {}: {why}",
                        l.state().label()
                    ),
                    None => bail!("lost the coordinator watching job {id}: {why}"),
                }
            }
            if progress != Progress::Quiet && backoff == Duration::from_millis(100) {
                eprintln!("lost the coordinator ({why}); reconnecting");
            }
            tokio::time::sleep(backoff).await;
            backoff = (backoff * 2).min(Duration::from_secs(2));
        }
        view.done();
        Ok(last.expect("checked above"))
    }

    /// After each new pass of a progressive still that is still running,
    /// its image so far (whole after every pass) to the output being
    /// watched for, through a part file renamed into place; returns the
    /// passes kept. A failed download is left for the final one to report.
    async fn keep_pass(&mut self, id: u64, s: &pb::JobStatus, kept: u32) -> u32 {
        let done = s.passes.as_ref().map_or(0, |p| p.done);
        if done <= kept || s.frames.is_some() || s.state().is_final() {
            return kept;
        }
        if let Some((out, format)) = self.pass_output.clone() {
            let _ = self.download(id, None, &out, format).await;
        }
        done
    }
}
