//! `trevi-worker --coordinator URL [--threads N]`: a stateless render worker.
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

mod names;

use anyhow::{Context, Result};
use clap::Parser;
use std::num::{IntErrorKind, NonZeroU64, NonZeroUsize, ParseIntError};
use trevi_worker::pause::ActiveHours;
use trevi_worker::{MaxMemory, PauseConfig, Priority, WorkerConfig};

#[derive(Parser, Debug)]
#[command(name = "trevi-worker", version, about = "A Trevi render farm worker")]
struct Args {
    /// The coordinator, like http://host:50051 (https:// for TLS).
    #[arg(long, env = "TREVI_COORDINATOR")]
    coordinator: String,
    /// Render threads (default: every core).
    #[arg(long, env = "TREVI_THREADS", default_value_t = 0)]
    threads: usize,
    /// Built scenes kept in memory (at least 1).
    #[arg(long, env = "TREVI_SCENE_CACHE", default_value_t = trevi_worker::SCENE_CACHE,
          value_parser = at_least_one::<NonZeroUsize>)]
    scene_cache: NonZeroUsize,
    /// Tiles rendered at once (sharing the threads), hiding network latency
    /// (at least 1).
    #[arg(long, env = "TREVI_TILES_IN_FLIGHT", default_value_t = trevi_worker::TILES_IN_FLIGHT,
          value_parser = at_least_one::<NonZeroUsize>)]
    tiles_in_flight: NonZeroUsize,
    /// Name shown in the coordinator's logs (default: host-pid).
    #[arg(long, env = "TREVI_WORKER_NAME")]
    name: Option<String>,
    /// The coordinator's worker token (its --worker-token; sent as
    /// `authorization: Bearer`). TREVI_TOKEN is no longer read: it named
    /// trevi-submit's token too.
    #[arg(long, env = "TREVI_WORKER_TOKEN", hide_env_values = true)]
    token: Option<String>,
    /// Read the token from this file instead (TREVI_TOKEN_FILE, its old
    /// name, is still read, with a warning).
    #[arg(long, env = "TREVI_WORKER_TOKEN_FILE", conflicts_with = "token")]
    token_file: Option<std::path::PathBuf>,
    /// For an https:// coordinator: trust this PEM CA certificate instead of
    /// the system roots (a farm with its own CA, see deploy/make-certs.sh).
    #[arg(long, env = "TREVI_TLS_CA")]
    tls_ca: Option<std::path::PathBuf>,
    /// For an https:// coordinator: the name its certificate must carry, if
    /// not the URL's host.
    #[arg(long, env = "TREVI_TLS_DOMAIN")]
    tls_domain: Option<String>,
    /// How often a rendering tile's lease is heartbeated, and the longest
    /// wait for a lease, in milliseconds (at least 1): how soon a cancelled
    /// job or a stop (SIGTERM) ends a render.
    #[arg(long, env = "TREVI_POLL_MS", default_value_t = poll_ms_default(),
          value_parser = at_least_one::<NonZeroU64>)]
    poll_ms: NonZeroU64,
    /// The render threads' CPU priority: `idle` (only the CPU time nothing
    /// else on the machine wants: Linux's SCHED_IDLE, else nice 19) or
    /// `normal` (for machines that do nothing but render) [default: idle].
    /// Not a job's priority (trevi-submit --priority). Old names, still
    /// read: --priority, TREVI_PRIORITY (with a warning).
    #[arg(long, env = "TREVI_CPU_PRIORITY", alias = "priority")]
    cpu_priority: Option<Priority>,
    /// Step aside while the machine is busy: when other programs keep more
    /// than --busy-threshold cores busy for --busy-for-ms, stop the tiles in
    /// hand, give their leases back and take none until the load has stayed
    /// below the threshold for --quiet-for-ms (reads /proc; Linux only).
    #[arg(long, env = "TREVI_YIELD_WHEN_BUSY")]
    yield_when_busy: bool,
    /// With --yield-when-busy: cores of CPU load from other programs (not
    /// this worker) above which the machine is busy.
    #[arg(long, env = "TREVI_BUSY_THRESHOLD", default_value_t = trevi_worker::pause::BUSY_THRESHOLD,
          value_parser = positive_cores)]
    busy_threshold: f64,
    /// With --yield-when-busy: milliseconds the load must stay above the
    /// threshold before the worker pauses.
    #[arg(long, env = "TREVI_BUSY_FOR_MS", default_value_t = ms(trevi_worker::pause::BUSY_FOR))]
    busy_for_ms: u64,
    /// With --yield-when-busy: milliseconds the load must stay below the
    /// threshold before a paused worker works again.
    #[arg(long, env = "TREVI_QUIET_FOR_MS", default_value_t = ms(trevi_worker::pause::QUIET_FOR))]
    quiet_for_ms: u64,
    /// How often the load and the clock are checked, in milliseconds (at
    /// least 1): a pause stops the tiles in hand within about this long.
    #[arg(long, env = "TREVI_SAMPLE_MS", default_value_t = nonzero_ms(trevi_worker::pause::SAMPLE),
          value_parser = at_least_one::<NonZeroU64>)]
    sample_ms: NonZeroU64,
    /// With --yield-when-busy: also count keyboard and mouse input (Linux:
    /// the PS/2 and I2C-HID interrupts of /proc/interrupts, not USB): the
    /// machine is in use, and the worker paused ("in use"), until no input
    /// came for this long (1s to 7d, like 5m). Default: input not watched.
    #[arg(long = "idle-after", env = "TREVI_IDLE_AFTER", requires = "yield_when_busy",
          value_parser = idle_after)]
    idle_after: Option<std::time::Duration>,
    /// Work only within these hours of local time, like 19:00-07:00 (a
    /// range that ends before it starts runs over midnight); outside them
    /// the worker is paused ("outside hours").
    #[arg(long, env = "TREVI_ACTIVE_HOURS")]
    active_hours: Option<ActiveHours>,
    /// The most memory one scene may take, like 2G or 512M (powers of
    /// 1024; 0: no limit). A scene whose estimated size is larger is
    /// declined before it is built, and the coordinator leases its job to
    /// workers that can hold it. Default: half of the machine's RAM.
    #[arg(long, env = "TREVI_MAX_MEMORY",
          default_value_t = MaxMemory::default_for_this_machine())]
    max_memory: MaxMemory,
}

/// `--busy-threshold`: a finite number of cores, not negative.
fn positive_cores(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        Ok(_) => Err("must be a number of cores, 0 or more".to_string()),
        Err(e) => Err(e.to_string()),
    }
}

fn ms(d: std::time::Duration) -> u64 {
    d.as_millis() as u64
}

fn nonzero_ms(d: std::time::Duration) -> NonZeroU64 {
    NonZeroU64::new(ms(d)).expect("a default that is not zero")
}

/// A number that must be at least 1 (a `NonZero` integer): clap refuses 0,
/// naming the flag, rather than the worker quietly taking 1.
fn at_least_one<T: std::str::FromStr<Err = ParseIntError>>(s: &str) -> Result<T, String> {
    s.parse().map_err(|e: ParseIntError| match e.kind() {
        IntErrorKind::Zero => "must be at least 1".to_string(),
        _ => e.to_string(),
    })
}

/// `--poll-ms`'s default: [`trevi_worker::POLL`].
fn poll_ms_default() -> NonZeroU64 {
    NonZeroU64::new(trevi_worker::POLL.as_millis() as u64).expect("POLL is not zero")
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
    let mut cfg = WorkerConfig::new(args.coordinator);
    cfg.threads = args.threads;
    cfg.cache_size = args.scene_cache;
    cfg.tiles_in_flight = args.tiles_in_flight;
    cfg.poll = std::time::Duration::from_millis(args.poll_ms.get());
    cfg.priority = match args.cpu_priority {
        Some(p) => p,
        None => match names::deprecated_env("TREVI_CPU_PRIORITY", "TREVI_PRIORITY") {
            Some(v) => v
                .parse()
                .map_err(|e| anyhow::anyhow!("TREVI_PRIORITY={v:?}: {e}"))?,
            None => Priority::default(),
        },
    };
    cfg.max_memory = args.max_memory;
    if args.max_memory == MaxMemory::NONE {
        tracing::info!("no memory limit (--max-memory 0, or the machine's RAM is unknown)");
    } else {
        tracing::info!(
            "scenes of up to {} (--max-memory {})",
            trevi_core::scene::estimate::human_bytes(args.max_memory.0),
            args.max_memory
        );
    }
    cfg.pause = PauseConfig {
        yield_when_busy: args.yield_when_busy,
        busy_threshold: args.busy_threshold,
        busy_for: std::time::Duration::from_millis(args.busy_for_ms),
        quiet_for: std::time::Duration::from_millis(args.quiet_for_ms),
        sample: std::time::Duration::from_millis(args.sample_ms.get()),
        active_hours: args.active_hours,
        idle_after: args.idle_after,
    };
    // Hooks for the end-to-end tests: a tile that crashes the renderer.
    #[cfg(feature = "test-hooks")]
    {
        use trevi_worker::{TestFault, ABORT_ON_TILE, PANIC_ON_TILE};
        cfg.test_fault = TestFault::from_env(ABORT_ON_TILE, true)
            .or_else(|| TestFault::from_env(PANIC_ON_TILE, false));
    }
    cfg.tls = trevi_proto::ClientTls {
        ca_file: args.tls_ca,
        domain: args.tls_domain,
    };
    if let Some(n) = args.name {
        cfg.name = n;
    }
    names::refuse_ambiguous_token(args.token.is_some() || args.token_file.is_some())?;
    let token_file = args.token_file.or_else(|| {
        names::deprecated_env("TREVI_WORKER_TOKEN_FILE", "TREVI_TOKEN_FILE").map(Into::into)
    });
    cfg.token = match &token_file {
        Some(f) => Some(
            std::fs::read_to_string(f)
                .with_context(|| format!("cannot read {}", f.display()))?
                .trim_end_matches(['\n', '\r'])
                .to_string(),
        ),
        None => args.token,
    };
    let (tx, rx) = tokio::sync::watch::channel(false);
    tokio::spawn(async move {
        trevi_proto::signal::shutdown().await;
        tracing::info!("stopping: cancelling the tile in hand");
        let _ = tx.send(true);
    });
    trevi_worker::run(cfg, rx)
        .await
        .context("the worker failed")?;
    tracing::info!("worker stopped");
    Ok(())
}

/// `--idle-after`: a duration (`trevi_proto::duration`) from 1 s to 7 days.
fn idle_after(s: &str) -> Result<std::time::Duration, String> {
    let d = trevi_proto::duration::parse(s).map_err(|e| e.to_string())?;
    if d.is_zero() || d > std::time::Duration::from_secs(7 * 86400) {
        return Err(format!("\"{s}\" is not an idle time from 1s to 7d"));
    }
    Ok(d)
}
