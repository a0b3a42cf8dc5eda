//! The `trevi.v1` gRPC services: thin wrappers around [`Farm`], one struct
//! per service holding it behind an `Arc`. Server streams are a task feeding
//! a channel wrapped in `ReceiverStream`.
//!
//! One file for each service in `grpc/`: `bundles.rs`, `jobs.rs` (with
//! `log.rs`: blocklists and the tile log) and `workers.rs`; here what they share (running work off the async threads,
//! streaming a file) and [`serve`], which serves them.

mod bundles;
mod jobs;
mod log;
mod workers;

pub use bundles::{BundlesService, NOT_SERVED};
pub use jobs::{job_status, JobsService};
pub use log::{check_unblock_worker, MAX_UNBLOCK_WORKER_CHARS};
pub use workers::WorkersService;

use crate::auth::{Auth, Need, Tokens};
use crate::farm::Farm;
use crate::FarmError;
use std::future::Future;
use std::sync::Arc;
use tokio::net::TcpListener;
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tonic::Status;
use trevi_proto::pb;
use trevi_proto::CHUNK_SIZE;

pub(super) fn join_error(e: tokio::task::JoinError) -> Status {
    Status::internal(format!("task failed: {e}"))
}

/// Runs `f` on the blocking pool.
pub(super) async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> Result<T, FarmError> + Send + 'static,
) -> Result<T, Status> {
    Ok(tokio::task::spawn_blocking(f).await.map_err(join_error)??)
}

/// Sends a file in chunks made by `make` (`size` is the file's size on the
/// first chunk, 0 after; at least one chunk, empty for an empty file),
/// reading a chunk at a time.
pub(super) fn stream_file<T: Send + 'static>(
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
