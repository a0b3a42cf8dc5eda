//! `trevi-coordinator --listen ADDR --data-dir DIR`: the farm's coordinator.

use anyhow::{Context, Result};
use clap::Parser;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;
use trevi_coordinator::{Farm, FarmConfig, SchedulerConfig};

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
    /// Where bundles and job outputs are kept.
    #[arg(long, env = "TREVI_DATA_DIR", default_value = "trevi-data")]
    data_dir: PathBuf,
    /// How long a tile lease lives without a heartbeat, in milliseconds.
    #[arg(long, env = "TREVI_LEASE_TTL_MS", default_value_t = 10_000)]
    lease_ttl_ms: u64,
    /// Default tile edge in pixels.
    #[arg(long, env = "TREVI_TILE_SIZE", default_value_t = 64)]
    tile_size: u32,
    /// Budget for the rows each job's writer may hold, in MiB.
    #[arg(long, env = "TREVI_WINDOW_MIB", default_value_t = 16)]
    window_mib: u64,
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
    anyhow::ensure!(args.tile_size > 0, "--tile-size must be at least 1");
    anyhow::ensure!(args.lease_ttl_ms > 0, "--lease-ttl-ms must be at least 1");
    let cfg = FarmConfig {
        data_dir: args.data_dir.clone(),
        sched: SchedulerConfig {
            lease_ttl: Duration::from_millis(args.lease_ttl_ms),
            window_bytes: args.window_mib.max(1) << 20,
        },
        default_tile: args.tile_size,
    };
    let farm =
        Arc::new(Farm::new(cfg).with_context(|| {
            format!("cannot use the data directory {}", args.data_dir.display())
        })?);
    let listener = tokio::net::TcpListener::bind(&args.listen)
        .await
        .with_context(|| format!("cannot listen on {}", args.listen))?;
    let addr = listener.local_addr()?;
    println!("listening on {addr}");
    tracing::info!(%addr, data_dir = %args.data_dir.display(), "coordinator up");
    trevi_coordinator::grpc::serve(farm, listener, shutdown_signal())
        .await
        .context("the gRPC server failed")?;
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
