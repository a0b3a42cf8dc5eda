//! `trevi-coordinator --listen ADDR --data-dir DIR`: the farm's coordinator.

use anyhow::{Context, Result};
use clap::Parser;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;
use trevi_coordinator::auth::{token_from, Tokens};
use trevi_coordinator::farm::Retention;
use trevi_coordinator::farm::BUNDLE_GRACE;
use trevi_coordinator::grpc::ServeOptions;
use trevi_coordinator::http::HttpLimits;
use trevi_coordinator::{Farm, FarmConfig, Limits, SchedulerConfig};

#[derive(Parser, Debug)]
#[command(
    name = "trevi-coordinator",
    version,
    about = "The Trevi render farm coordinator"
)]
struct Args {
    /// Address to listen on (port 0 picks a free port; the address in use is
    /// printed as `listening on ADDR`).
    #[arg(long, env = "TREVI_LISTEN", default_value = "0.0.0.0:50051")]
    listen: String,
    /// Serve the web monitor, `/metrics` and `/healthz` over HTTP on this
    /// address (printed as `monitor on http://ADDR/`); off when not given.
    #[arg(long, env = "TREVI_HTTP")]
    http: Option<String>,
    /// Where bundles and job outputs are kept.
    #[arg(long, env = "TREVI_DATA_DIR", default_value = "trevi-data")]
    data_dir: PathBuf,
    /// How long a tile lease lives without a heartbeat, in milliseconds.
    #[arg(long, env = "TREVI_LEASE_TTL_MS", default_value_t = 10_000)]
    lease_ttl_ms: u64,
    /// Default tile edge in pixels.
    #[arg(long, env = "TREVI_TILE_SIZE", default_value_t = 64)]
    tile_size: u32,
    /// Budget per job, in MiB, for the rows its writer holds and the
    /// bookkeeping of its tiles in flight; a frame whose one band of tiles
    /// does not fit is refused at submission.
    #[arg(long, env = "TREVI_WINDOW_MIB", default_value_t = SchedulerConfig::default().window_bytes >> 20)]
    window_mib: u64,
    /// A tile failing this many times (lease expired, invalid result) fails
    /// its job.
    #[arg(long, env = "TREVI_MAX_TILE_FAILURES", default_value_t = 5)]
    max_tile_failures: u32,
    /// A worker failing this many tiles of a job gets no more of its tiles.
    #[arg(long, env = "TREVI_MAX_WORKER_FAILURES", default_value_t = 3)]
    max_worker_failures: u32,
    /// A tile whose lease runs out this many times (the worker holding it
    /// crashed, hung or was cut off) fails its job, naming the tile.
    #[arg(long, env = "TREVI_MAX_TILE_LOSSES", default_value_t = SchedulerConfig::default().max_tile_losses)]
    max_tile_losses: u32,
    /// Token submitters must present (`trevi-submit --token`); without it
    /// anyone who reaches the coordinator may submit and read jobs.
    #[arg(long, env = "TREVI_SUBMIT_TOKEN", hide_env_values = true)]
    submit_token: Option<String>,
    /// Read the submit token from this file.
    #[arg(long, env = "TREVI_SUBMIT_TOKEN_FILE")]
    submit_token_file: Option<PathBuf>,
    /// Token workers must present (`trevi-worker --token`); without it
    /// anyone who reaches the coordinator may take tiles.
    #[arg(long, env = "TREVI_WORKER_TOKEN", hide_env_values = true)]
    worker_token: Option<String>,
    /// Read the worker token from this file.
    #[arg(long, env = "TREVI_WORKER_TOKEN_FILE")]
    worker_token_file: Option<PathBuf>,
    /// Largest scene bundle accepted, in MiB.
    #[arg(long, env = "TREVI_MAX_BUNDLE_MIB", default_value_t = Limits::default().max_bundle_bytes >> 20)]
    max_bundle_mib: u64,
    /// Most files in a bundle.
    #[arg(long, env = "TREVI_MAX_BUNDLE_FILES", default_value_t = 10_000)]
    max_bundle_files: usize,
    /// Largest gRPC message decoded, in KiB.
    #[arg(long, env = "TREVI_MAX_MESSAGE_KIB", default_value_t = 4096)]
    max_message_kib: usize,
    /// Most samples in a frame: width × height × supersample².
    #[arg(long, env = "TREVI_MAX_IMAGE_SAMPLES", default_value_t = Limits::default().max_image_samples)]
    max_image_samples: u64,
    /// Most unfinished jobs per submitter (per client address).
    #[arg(long, env = "TREVI_MAX_JOBS_PER_SUBMITTER", default_value_t = 1000)]
    max_jobs_per_submitter: usize,
    /// Ended jobs (done, failed, cancelled) kept at most, with their outputs;
    /// older ones are forgotten and their outputs deleted.
    #[arg(long, env = "TREVI_KEEP_ENDED", default_value_t = Retention::default().keep_ended)]
    keep_ended: usize,
    /// Forget ended jobs and delete their outputs this long after they
    /// ended: 90s, 30m, 12h, 7d, or never.
    #[arg(long, env = "TREVI_KEEP_ENDED_FOR",
        default_value_t = Retention::format_duration(Retention::default().keep_ended_for))]
    keep_ended_for: String,
    /// Most bundle uploads in progress at once; one more is refused.
    #[arg(long, env = "TREVI_MAX_UPLOADS", default_value_t = Limits::default().max_uploads)]
    max_uploads: usize,
    /// Drop a bundle upload that sends nothing for this long, in milliseconds.
    #[arg(long, env = "TREVI_UPLOAD_IDLE_MS",
          default_value_t = Limits::default().upload_idle.as_millis() as u64)]
    upload_idle_ms: u64,
    /// Remove a bundle no job uses once it was last uploaded or used this
    /// long ago, in seconds.
    #[arg(long, env = "TREVI_BUNDLE_GRACE_SECS", default_value_t = BUNDLE_GRACE.as_secs())]
    bundle_grace_secs: u64,
    /// Close a monitor connection that takes longer than this to send a
    /// request's headers (or to finish its TLS handshake), in milliseconds.
    #[arg(long, env = "TREVI_HTTP_HEADER_TIMEOUT_MS",
          default_value_t = HttpLimits::default().header_timeout.as_millis() as u64)]
    http_header_timeout_ms: u64,
    /// Most monitor connections open at once; more are closed at once.
    #[arg(long, env = "TREVI_HTTP_MAX_CONNECTIONS",
          default_value_t = HttpLimits::default().max_connections)]
    http_max_connections: usize,
    /// Serve gRPC over TLS with this PEM certificate chain (needs --tls-key).
    #[arg(long, env = "TREVI_TLS_CERT")]
    tls_cert: Option<PathBuf>,
    /// The PEM private key of --tls-cert.
    #[arg(long, env = "TREVI_TLS_KEY")]
    tls_key: Option<PathBuf>,
}

#[tokio::main]
async fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let args = Args::parse();
    // Many clients need many descriptors: use all the operator allows.
    match trevi_coordinator::listen::raise_fd_limit() {
        Ok(n) => tracing::debug!(open_files = n, "open-files limit"),
        Err(e) => tracing::warn!(error = %e, "cannot raise the open-files limit"),
    }
    anyhow::ensure!(args.tile_size > 0, "--tile-size must be at least 1");
    anyhow::ensure!(args.lease_ttl_ms > 0, "--lease-ttl-ms must be at least 1");
    let retention = Retention {
        keep_ended: args.keep_ended,
        keep_ended_for: Retention::parse_duration(&args.keep_ended_for)
            .map_err(|e| anyhow::anyhow!("--keep-ended-for: {e}"))?,
    };
    let cfg = FarmConfig {
        data_dir: args.data_dir.clone(),
        sched: SchedulerConfig {
            lease_ttl: Duration::from_millis(args.lease_ttl_ms),
            window_bytes: args.window_mib.max(1) << 20,
            max_tile_failures: args.max_tile_failures.max(1),
            max_worker_failures: args.max_worker_failures.max(1),
            max_tile_losses: args.max_tile_losses.max(1),
        },
        default_tile: args.tile_size,
        durable: true,
        limits: Limits {
            max_bundle_bytes: args.max_bundle_mib.max(1) << 20,
            max_bundle_files: args.max_bundle_files.max(1),
            // A pixel chunk (1 MiB) plus framing must fit.
            max_message_bytes: (args.max_message_kib << 10).max(trevi_proto::CHUNK_SIZE + 4096),
            max_image_samples: args.max_image_samples,
            max_jobs_per_submitter: args.max_jobs_per_submitter,
            max_uploads: args.max_uploads.max(1),
            upload_idle: Duration::from_millis(args.upload_idle_ms.max(1)),
        },
        retention,
        bundle_grace: Duration::from_secs(args.bundle_grace_secs),
    };
    let http_limits = HttpLimits {
        header_timeout: Duration::from_millis(args.http_header_timeout_ms.max(1)),
        max_connections: args.http_max_connections.max(1),
    };
    let submit_token = token_from(args.submit_token.clone(), args.submit_token_file.as_deref())
        .map_err(|e| anyhow::anyhow!("submit token: {e}"))?;
    let worker_token = token_from(args.worker_token.clone(), args.worker_token_file.as_deref())
        .map_err(|e| anyhow::anyhow!("worker token: {e}"))?;
    if submit_token.is_some() && submit_token == worker_token {
        anyhow::bail!("the submit and worker tokens must differ");
    }
    let tokens = Tokens::new(submit_token.as_deref(), worker_token.as_deref())
        .map_err(|e| anyhow::anyhow!(e))?;
    if tokens.is_open() {
        tracing::warn!("no tokens: anyone who can reach this coordinator may submit and take work");
    }
    let http_tokens = tokens.clone();
    let tls =
        trevi_coordinator::tls::server_tls(args.tls_cert.as_deref(), args.tls_key.as_deref())?;
    if tls.is_none() && !tokens.is_open() {
        tracing::warn!("no TLS: tokens and pixels cross the network in the clear");
    }
    let opts = ServeOptions { tokens, tls };
    let farm =
        Arc::new(Farm::new(cfg).with_context(|| {
            format!("cannot use the data directory {}", args.data_dir.display())
        })?);
    let listener = tokio::net::TcpListener::bind(&args.listen)
        .await
        .with_context(|| format!("cannot listen on {}", args.listen))?;
    let addr = listener.local_addr()?;
    println!("listening on {addr}");
    tracing::info!(%addr, data_dir = %args.data_dir.display(), tls = opts.tls.is_some(), "coordinator up");
    // The HTTP server stops with the gRPC one: both wait on this.
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    let http = match &args.http {
        Some(http_addr) => {
            let l = tokio::net::TcpListener::bind(http_addr)
                .await
                .with_context(|| format!("cannot listen on {http_addr} (--http)"))?;
            let https = match (&args.tls_cert, &args.tls_key) {
                (Some(c), Some(k)) => Some(trevi_coordinator::tls::https_acceptor(c, k)?),
                _ => None,
            };
            let scheme = if https.is_some() { "https" } else { "http" };
            println!("monitor on {scheme}://{}/", l.local_addr()?);
            let mut stop = stop_rx.clone();
            let stopped = async move {
                let _ = stop.wait_for(|&s| s).await;
            };
            let farm = farm.clone();
            Some(tokio::spawn(trevi_coordinator::http::serve(
                farm,
                http_tokens,
                l,
                https,
                http_limits,
                stopped,
            )))
        }
        None => None,
    };
    let shutdown = async move {
        shutdown_signal().await;
        let _ = stop_tx.send(true);
    };
    trevi_coordinator::grpc::serve_with(farm, listener, shutdown, opts)
        .await
        .context("the gRPC server failed")?;
    if let Some(h) = http {
        h.await
            .context("the HTTP server task failed")?
            .context("the HTTP server failed")?;
    }
    tracing::info!("coordinator stopped");
    Ok(())
}

async fn shutdown_signal() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        let mut term = signal(SignalKind::terminate()).expect("SIGTERM handler");
        tokio::select! {
            _ = term.recv() => {}
            _ = tokio::signal::ctrl_c() => {}
        }
    }
    #[cfg(not(unix))]
    let _ = tokio::signal::ctrl_c().await;
}
