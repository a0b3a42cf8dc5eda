//! Talking to a running coordinator the way the end-to-end tests do: its
//! gRPC clients, a job's status, and jobs submitted with `trevi-submit
//! --detach` and waited for.

use super::{submit, wait_for, Coordinator, Dir};
use std::path::Path;
use tonic::transport::Channel;
use trevi_proto::pb::{
    self, bundles_client::BundlesClient, jobs_client::JobsClient, workers_client::WorkersClient,
};
use trevi_proto::{AuthChannel, Bearer};

/// A channel to the coordinator, over TLS when its URL is `https://`
/// (trusting [`Coordinator::tls`]).
pub async fn channel(c: &Coordinator) -> Channel {
    trevi_proto::endpoint(&c.url, &c.tls)
        .unwrap()
        .connect()
        .await
        .unwrap_or_else(|e| panic!("cannot connect to {}: {e}", c.url))
}

/// The Jobs service, sending `token` (`None`: no `authorization` header).
pub async fn jobs(c: &Coordinator, token: Option<&str>) -> JobsClient<AuthChannel> {
    JobsClient::with_interceptor(channel(c).await, Bearer::new(token).unwrap())
}

/// The finished output of job `id` (frame `frame` of a sequence), as the
/// coordinator's `DownloadOutput` streams it.
pub async fn download(c: &Coordinator, id: u64, frame: Option<u32>) -> Vec<u8> {
    let mut s = jobs(c, None)
        .await
        .download_output(pb::JobId { id, frame })
        .await
        .unwrap_or_else(|e| panic!("downloading the output of job {id}: {e}"))
        .into_inner();
    let mut out = Vec::new();
    while let Some(chunk) = s.message().await.unwrap() {
        out.extend_from_slice(&chunk.data);
    }
    out
}

/// The Workers service, sending `token`.
pub async fn workers(c: &Coordinator, token: Option<&str>) -> WorkersClient<AuthChannel> {
    WorkersClient::with_interceptor(channel(c).await, Bearer::new(token).unwrap())
}

/// The Bundles service, sending `token`. It sends messages of up to 64 MiB,
/// so that the coordinator's own limit is the one a test meets.
pub async fn bundles(c: &Coordinator, token: Option<&str>) -> BundlesClient<AuthChannel> {
    BundlesClient::with_interceptor(channel(c).await, Bearer::new(token).unwrap())
        .max_encoding_message_size(64 << 20)
}

/// Uploads a bundle in these chunks (each one message); returns its hash.
pub async fn upload(
    b: &mut BundlesClient<AuthChannel>,
    chunks: Vec<Vec<u8>>,
) -> Result<String, tonic::Status> {
    let msgs: Vec<pb::BundleChunk> = chunks
        .into_iter()
        .map(|data| pb::BundleChunk { data })
        .collect();
    Ok(b.upload_bundle(tokio_stream::iter(msgs))
        .await?
        .into_inner()
        .hash)
}

/// Submits a job for the bundle `hash` (its first camera, the coordinator's
/// default tile) without a token.
pub async fn submit_job(c: &Coordinator, hash: &str) -> Result<pb::JobStatus, tonic::Status> {
    jobs(c, None)
        .await
        .submit_job(pb::SubmitJobRequest {
            bundle_hash: hash.to_string(),
            ..Default::default()
        })
        .await
        .map(|r| r.into_inner())
}

/// Job `id`'s status; `None` while the coordinator cannot be reached or
/// does not know the job (yet, or any more).
pub fn try_job(rt: &tokio::runtime::Runtime, c: &Coordinator, id: u64) -> Option<pb::JobStatus> {
    rt.block_on(async {
        let ch = trevi_proto::endpoint(&c.url, &c.tls)
            .unwrap()
            .connect()
            .await
            .ok()?;
        JobsClient::new(ch)
            .get_job(pb::JobId { id, frame: None })
            .await
            .ok()
            .map(|r| r.into_inner())
    })
}

/// Job `id`'s status.
pub fn job(rt: &tokio::runtime::Runtime, c: &Coordinator, id: u64) -> pb::JobStatus {
    rt.block_on(async {
        jobs(c, None)
            .await
            .get_job(pb::JobId { id, frame: None })
            .await
            .unwrap_or_else(|s| panic!("job {id}: {s:?}"))
            .into_inner()
    })
}

/// Cancels job `id`.
pub fn cancel(rt: &tokio::runtime::Runtime, c: &Coordinator, id: u64) {
    rt.block_on(async {
        jobs(c, None)
            .await
            .cancel_job(pb::JobId { id, frame: None })
            .await
            .unwrap_or_else(|s| panic!("cancel {id}: {s:?}"));
    });
}

/// Waits until job `id` is in `state`; returns its status.
pub fn wait_state(
    dir: &Dir,
    rt: &tokio::runtime::Runtime,
    c: &Coordinator,
    id: u64,
    state: pb::JobState,
    secs: u64,
) -> pb::JobStatus {
    let mut last = None;
    wait_for(dir, &format!("job {id} to be {state:?}"), secs, || {
        let s = job(rt, c, id);
        let hit = s.state == state as i32;
        last = Some(s);
        hit
    });
    last.unwrap()
}

/// `trevi-submit SCENE --coordinator URL --detach ARGS` for a scene of one
/// camera: submits its job without waiting; returns the job's id.
pub fn detach(dir: &Dir, c: &Coordinator, scene: &Path, args: &[&str]) -> u64 {
    let mut all = vec![scene.to_str().unwrap(), "--coordinator", &c.url, "--detach"];
    all.extend(args);
    let o = submit(dir, &all);
    assert!(o.status.success(), "{}", dir.logs());
    let out = String::from_utf8_lossy(&o.stdout);
    out.trim()
        .parse()
        .unwrap_or_else(|_| panic!("--detach printed {out:?}"))
}

/// [`detach`], then waits (up to `secs` seconds) for the job to be done;
/// returns its status.
pub fn submit_and_wait(
    dir: &Dir,
    rt: &tokio::runtime::Runtime,
    c: &Coordinator,
    scene: &Path,
    args: &[&str],
    secs: u64,
) -> pb::JobStatus {
    let id = detach(dir, c, scene, args);
    wait_state(dir, rt, c, id, pb::JobState::Done, secs)
}
