//! Reaching a coordinator: the channel (TLS for `https://`), the submit
//! token sent with every call, and what a failed call means (an error that
//! reads well, and whether it may succeed once the coordinator is back).

use anyhow::Result;
use std::time::Duration;
use trevi_proto::pb::{bundles_client::BundlesClient, jobs_client::JobsClient};
use trevi_proto::{Bearer, ClientTls, MAX_MESSAGE_SIZE};

use super::Client;

impl Client {
    /// Connects to `url`, sending `token` (the coordinator's submit token)
    /// with every call.
    pub async fn connect(url: &str, token: Option<&str>) -> Result<Client> {
        Client::connect_with(url, token, &ClientTls::default()).await
    }

    /// [`Client::connect`] with TLS settings for an `https://` coordinator.
    pub async fn connect_with(url: &str, token: Option<&str>, tls: &ClientTls) -> Result<Client> {
        let bearer = Bearer::new(token).map_err(|e| anyhow::anyhow!("--token: {e}"))?;
        let channel = trevi_proto::endpoint(url, tls)?
            .connect_timeout(Duration::from_secs(10))
            .tcp_nodelay(true)
            .connect()
            .await
            .map_err(|e| {
                let why = trevi_proto::connect::error_chain(&e);
                anyhow::anyhow!("cannot reach the coordinator at {url}: {why}")
            })?;
        Ok(Client {
            url: url.to_string(),
            announce: true,
            preview: None,
            denoise_preview: None,
            submitted: Vec::new(),
            pass_output: None,
            jobs: JobsClient::with_interceptor(channel.clone(), bearer.clone())
                .max_decoding_message_size(MAX_MESSAGE_SIZE),
            bundles: BundlesClient::with_interceptor(channel, bearer)
                .max_decoding_message_size(MAX_MESSAGE_SIZE),
        })
    }
}

/// Whether a failed call may succeed once the coordinator is back.
pub(super) fn reconnectable(s: &tonic::Status) -> bool {
    matches!(
        s.code(),
        tonic::Code::Unavailable
            | tonic::Code::Unknown
            | tonic::Code::Internal
            | tonic::Code::Cancelled
    )
}

/// Whether `e` is a failed call that may succeed once the coordinator is
/// back (see [`reconnectable`]).
pub(super) fn reconnectable_error(e: &anyhow::Error) -> bool {
    e.downcast_ref::<StatusError>()
        .is_some_and(|s| reconnectable(&s.0))
}

/// A gRPC status as an error that reads well.
pub(super) fn status_error(s: tonic::Status) -> anyhow::Error {
    anyhow::Error::new(StatusError(s))
}

/// A gRPC status kept inside an `anyhow::Error`, so callers can still look
/// at its code.
#[derive(Debug)]
struct StatusError(tonic::Status);

impl std::fmt::Display for StatusError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ({:?})", self.0.message(), self.0.code())
    }
}

impl std::error::Error for StatusError {
    // What lies under a transport failure (a TLS alert, a reset connection).
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        std::error::Error::source(&self.0)
    }
}
