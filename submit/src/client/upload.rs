//! Uploading a scene's bundle: encoded and hashed once, sent in chunks, and
//! retried while a busy coordinator has no upload slot free.

use anyhow::{bail, Context, Result};
use std::time::Duration;
use trevi_core::Bundle;
use trevi_proto::{pb, CHUNK_SIZE};

use super::connect::status_error;
use super::Client;

/// How long `trevi-submit` keeps retrying an upload that a coordinator
/// refuses only because all its upload slots (`--max-uploads`) are busy.
const UPLOAD_BUSY_PATIENCE: Duration = Duration::from_secs(300);

/// A bundle as it travels: its encoding and the hash of that encoding,
/// computed once (the local render's embedded farm and the upload share it).
pub struct Encoded {
    pub bytes: Vec<u8>,
    pub hash: String,
}

impl Encoded {
    pub fn new(bundle: &Bundle) -> Encoded {
        let bytes = bundle.encode();
        let hash = trevi_core::bundle::sha256_hex(&bytes);
        Encoded { bytes, hash }
    }
}

impl Client {
    /// Uploads exactly this bundle, in chunks; returns its hash.
    pub async fn upload(&mut self, bundle: &Encoded) -> Result<String> {
        let (bytes, want) = (&bundle.bytes, bundle.hash.clone());
        let chunks: Vec<pb::BundleChunk> = bytes
            .chunks(CHUNK_SIZE)
            .map(|c| pb::BundleChunk { data: c.to_vec() })
            .collect();
        // A busy coordinator (its --max-uploads slots all taken by other
        // submitters) says "try again shortly": wait and retry, doubling
        // the wait to 5 s, for at most UPLOAD_BUSY_PATIENCE.
        let started = std::time::Instant::now();
        let mut backoff = Duration::from_millis(100);
        let got = loop {
            match self
                .bundles
                .upload_bundle(tokio_stream::iter(chunks.clone()))
                .await
            {
                Err(s)
                    if s.code() == tonic::Code::ResourceExhausted
                        && s.message().contains("--max-uploads")
                        && started.elapsed() < UPLOAD_BUSY_PATIENCE =>
                {
                    tokio::time::sleep(backoff).await;
                    backoff = (backoff * 2).min(Duration::from_secs(5));
                }
                r => {
                    break r
                        .map_err(status_error)
                        .context("the coordinator refused the scene bundle")?
                        .into_inner()
                }
            }
        };
        if got.hash != want {
            bail!(
                "the coordinator stored the bundle as {} instead of {want}",
                got.hash
            );
        }
        Ok(want)
    }
}
