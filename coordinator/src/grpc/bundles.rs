//! `trevi.v1.Bundles`: uploading a scene bundle, streamed to a temporary
//! file, and downloading a stored one, its hash checked first.

use super::{blocking, join_error, stream_file};
use crate::auth;
use crate::farm::Farm;
use crate::FarmError;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::Semaphore;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};
use trevi_proto::pb;

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
    /// The coordinator the service answers for.
    pub farm: Arc<Farm>,
    /// One permit per upload in progress.
    pub uploads: Arc<Semaphore>,
}

impl BundlesService {
    /// The service over `farm`, with its
    /// [`Limits::max_uploads`] upload permits.
    ///
    /// [`Limits::max_uploads`]: crate::limits::Limits::max_uploads
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
