//! `trevi-coordinator --listen ADDR --data-dir DIR`: the farm's coordinator.
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

use anyhow::{Context, Result};
use clap::Parser;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;
use trevi_coordinator::auth::{read_named_tokens, token_from, Tokens};
use trevi_coordinator::events::EventsConfig;
use trevi_coordinator::farm::Retention;
use trevi_coordinator::grpc::ServeOptions;
use trevi_coordinator::limits::{MAX_FRAMES_IN_PROGRESS, MIN_MESSAGE_BYTES};
use trevi_coordinator::{Farm, FarmConfig, Limits};

/// The defaults of every flag below come from these.
fn defaults() -> FarmConfig {
    FarmConfig::default()
}

/// A whole number of at least `min` (a count, a size or a time that would
/// make no sense as 0): anything less is refused, naming the flag.
fn at_least<T>(min: u64) -> clap::builder::RangedU64ValueParser<T>
where
    T: TryFrom<u64> + Clone + Send + Sync + 'static,
    <T as TryFrom<u64>>::Error: std::error::Error + Send + Sync + 'static,
{
    clap::builder::RangedU64ValueParser::<T>::new().range(min..)
}

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
    #[arg(long, env = "TREVI_DATA_DIR", default_value_os_t = defaults().data_dir)]
    data_dir: PathBuf,
    /// How long a tile lease lives without a heartbeat, in milliseconds.
    #[arg(long, env = "TREVI_LEASE_TTL_MS", value_parser = at_least::<u64>(1),
          default_value_t = defaults().limits.lease_ttl.as_millis() as u64)]
    lease_ttl_ms: u64,
    /// Default tile edge in pixels.
    #[arg(long, env = "TREVI_TILE_SIZE", value_parser = at_least::<u32>(1),
          default_value_t = defaults().default_tile)]
    tile_size: u32,
    /// Budget per job, in MiB, for the rows its writer holds and the
    /// bookkeeping of its tiles in flight; a frame whose one band of tiles
    /// does not fit is refused at submission.
    #[arg(long, env = "TREVI_WINDOW_MIB", value_parser = at_least::<u64>(1),
          default_value_t = defaults().limits.window_bytes >> 20)]
    window_mib: u64,
    /// A tile failing this many times (lease expired, invalid result) fails
    /// its job.
    #[arg(long, env = "TREVI_MAX_TILE_FAILURES", value_parser = at_least::<u32>(1),
          default_value_t = defaults().limits.max_tile_failures)]
    max_tile_failures: u32,
    /// A worker failing this many tiles of a job gets no more of its tiles.
    #[arg(long, env = "TREVI_MAX_WORKER_FAILURES", value_parser = at_least::<u32>(1),
          default_value_t = defaults().limits.max_worker_failures)]
    max_worker_failures: u32,
    /// Most entries of a job's tile log (`trevi-submit log`; 1 to
    /// 20000); past it the oldest are dropped and counted.
    #[arg(long, env = "TREVI_TILE_LOG_ENTRIES",
          value_parser = clap::builder::RangedU64ValueParser::<u32>::new().range(1..=20_000),
          default_value_t = defaults().limits.tile_log_entries)]
    tile_log_entries: u32,
    /// Most KiB of error text in a job's tile log (1 to 1024); past it
    /// the oldest errors are dropped and counted.
    #[arg(long, env = "TREVI_TILE_LOG_ERROR_KIB",
          value_parser = clap::builder::RangedU64ValueParser::<u64>::new().range(1..=1024),
          default_value_t = defaults().limits.tile_log_error_bytes >> 10)]
    tile_log_error_kib: u64,
    /// A tile whose lease runs out this many times (the worker holding it
    /// crashed, hung or was cut off) fails its job, naming the tile.
    #[arg(long, env = "TREVI_MAX_TILE_LOSSES", value_parser = at_least::<u32>(1),
          default_value_t = defaults().limits.max_tile_losses)]
    max_tile_losses: u32,
    /// How long, in milliseconds, a job whose scene no live worker has the
    /// memory for (by their --max-memory) waits for a bigger worker to
    /// register before it fails, naming its estimate and the largest limit.
    #[arg(long, env = "TREVI_MEMORY_GRACE_MS",
          default_value_t = defaults().limits.memory_grace.as_millis() as u64)]
    memory_grace_ms: u64,
    /// Most frames of one sequence in progress at once (1 to 256): the next
    /// frame is queued when one ends. Each holds what a still in progress
    /// holds (up to --window-mib plus a 4 MiB preview); a big farm on a
    /// cheap sequence needs more than the default to keep its workers busy.
    #[arg(long, env = "TREVI_FRAMES_IN_PROGRESS",
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new()
              .range(1..=MAX_FRAMES_IN_PROGRESS as u64),
          default_value_t = defaults().limits.frames_in_progress)]
    frames_in_progress: usize,
    /// How much of a worker's time one lease of several tiles aims at, in
    /// milliseconds (docs/farm.md, "Lease sizing"): longer leases cost the
    /// coordinator less a pixel, shorter ones lose less to a killed worker.
    #[arg(long, env = "TREVI_LEASE_TARGET_MS", value_parser = at_least::<u64>(1),
          default_value_t = defaults().limits.lease_target.as_millis() as u64)]
    lease_target_ms: u64,
    /// Token submitters must present (`trevi-submit --token`); without it
    /// anyone who reaches the coordinator may submit and read jobs.
    #[arg(long, env = "TREVI_SUBMIT_TOKEN", hide_env_values = true)]
    submit_token: Option<String>,
    /// Read the submit token from this file.
    #[arg(long, env = "TREVI_SUBMIT_TOKEN_FILE")]
    submit_token_file: Option<PathBuf>,
    /// Named submit tokens, one `NAME TOKEN` a line: a job records the name
    /// of the token it was submitted with as its submitter (status, the
    /// per-submitter limit, `trevi-submit usage --by submitter`). At most
    /// 1024 tokens in 64 KiB (docs/farm.md, "Tokens and TLS").
    #[arg(long, env = "TREVI_SUBMIT_TOKENS_FILE")]
    submit_tokens_file: Option<PathBuf>,
    /// Token workers must present (`trevi-worker --token`); without it
    /// anyone who reaches the coordinator may take tiles.
    #[arg(long, env = "TREVI_WORKER_TOKEN", hide_env_values = true)]
    worker_token: Option<String>,
    /// Read the worker token from this file.
    #[arg(long, env = "TREVI_WORKER_TOKEN_FILE")]
    worker_token_file: Option<PathBuf>,
    /// Largest scene bundle accepted, in MiB.
    #[arg(long, env = "TREVI_MAX_BUNDLE_MIB", value_parser = at_least::<u64>(1),
          default_value_t = defaults().limits.max_bundle_bytes >> 20)]
    max_bundle_mib: u64,
    /// Most files in a bundle.
    #[arg(long, env = "TREVI_MAX_BUNDLE_FILES", value_parser = at_least::<usize>(1),
          default_value_t = defaults().limits.max_bundle_files)]
    max_bundle_files: usize,
    /// Largest gRPC message decoded, in KiB (at least a 1 MiB chunk and its
    /// framing).
    #[arg(long, env = "TREVI_MAX_MESSAGE_KIB",
          value_parser = at_least::<usize>(MIN_MESSAGE_BYTES.div_ceil(1024) as u64),
          default_value_t = defaults().limits.max_message_bytes >> 10)]
    max_message_kib: usize,
    /// Most samples in a frame: width × height × supersample².
    #[arg(long, env = "TREVI_MAX_IMAGE_SAMPLES", value_parser = at_least::<u64>(1),
          default_value_t = defaults().limits.max_image_samples)]
    max_image_samples: u64,
    /// Most unfinished jobs per submitter (per named token, else per client address).
    #[arg(long, env = "TREVI_MAX_JOBS_PER_SUBMITTER", value_parser = at_least::<usize>(1),
          default_value_t = defaults().limits.max_jobs_per_submitter)]
    max_jobs_per_submitter: usize,
    /// Ended jobs (done, failed, cancelled; a sequence is one) kept at most,
    /// with their outputs; older ones are forgotten and their outputs
    /// deleted, except outputs not fetched yet (only --keep-ended-for
    /// removes those). At least 1.
    #[arg(long, env = "TREVI_KEEP_ENDED", default_value_t = defaults().retention.keep_ended)]
    keep_ended: usize,
    /// Forget ended jobs and delete their outputs this long after they
    /// ended: 90s, 30m, 12h, 7d (from 1m to 3650d), or never.
    #[arg(long, env = "TREVI_KEEP_ENDED_FOR",
        default_value_t = Retention::format_duration(defaults().retention.keep_ended_for))]
    keep_ended_for: String,
    /// Keep the usage history (CPU time, tiles, rays and wall time per job,
    /// submitter and worker, hour by hour; `trevi-submit usage`) this long,
    /// whatever became of the jobs: from 1h to 3650d.
    #[arg(long, env = "TREVI_USAGE_RETENTION",
        default_value_t = trevi_proto::duration::format(defaults().limits.usage_retention))]
    usage_retention: String,
    /// Most rows of the usage history (one an hour for each job, submitter
    /// and worker; as many for the jobs' wall times); past it the oldest
    /// hour's rows are deleted first.
    #[arg(long, env = "TREVI_MAX_USAGE_ROWS",
          value_parser = clap::builder::RangedU64ValueParser::<u64>::new()
              .range(1..=trevi_coordinator::usage::MAX_USAGE_ROWS),
          default_value_t = defaults().limits.max_usage_rows)]
    max_usage_rows: u64,
    /// Most workers registered at once; one more registration is refused
    /// until a silent one is forgotten.
    #[arg(long, env = "TREVI_MAX_WORKERS", value_parser = at_least::<usize>(1),
          default_value_t = defaults().limits.max_workers)]
    max_workers: usize,
    /// Most workers registered at once from one client address.
    #[arg(long, env = "TREVI_MAX_WORKERS_PER_ADDRESS", value_parser = at_least::<usize>(1),
          default_value_t = defaults().limits.max_workers_per_address)]
    max_workers_per_address: usize,
    /// Most bundle uploads in progress at once; one more is refused.
    #[arg(long, env = "TREVI_MAX_UPLOADS", value_parser = at_least::<usize>(1),
          default_value_t = defaults().limits.max_uploads)]
    max_uploads: usize,
    /// Most scenes read at once to admit a job (the first submission on a
    /// bundle reads its scene, headers only); one more is refused.
    #[arg(long, env = "TREVI_MAX_ADMISSIONS", value_parser = at_least::<usize>(1),
          default_value_t = defaults().limits.max_admissions)]
    max_admissions: usize,
    /// Memory the admissions in progress may be counted at together, in
    /// MiB (each at 4 times its bundle's size plus 8 MiB; one alone always
    /// fits); one more that does not fit is refused.
    #[arg(long, env = "TREVI_ADMISSION_MIB", value_parser = at_least::<u64>(1),
          default_value_t = defaults().limits.admission_bytes >> 20)]
    admission_mib: u64,
    /// Tile uploads from workers received at once; more wait their turn,
    /// unread. Bounds what uploads hold whatever the number of workers.
    #[arg(long, env = "TREVI_MAX_TILE_UPLOADS", value_parser = at_least::<usize>(1),
          default_value_t = defaults().limits.max_tile_uploads)]
    max_tile_uploads: usize,
    /// Drop an upload (a bundle, or a worker's tile) that sends nothing for
    /// this long, in milliseconds.
    #[arg(long, env = "TREVI_UPLOAD_IDLE_MS", value_parser = at_least::<u64>(1),
          default_value_t = defaults().limits.upload_idle.as_millis() as u64)]
    upload_idle_ms: u64,
    /// Remove a bundle no job uses once it was last uploaded or used this
    /// long ago, in seconds.
    #[arg(long, env = "TREVI_BUNDLE_GRACE_SECS",
          default_value_t = defaults().retention.bundle_grace.as_secs())]
    bundle_grace_secs: u64,
    /// Close a monitor connection that takes longer than this to send a
    /// request's headers (or to finish its TLS handshake), in milliseconds.
    #[arg(long, env = "TREVI_HTTP_HEADER_TIMEOUT_MS", value_parser = at_least::<u64>(1),
          default_value_t = defaults().limits.http_header_timeout.as_millis() as u64)]
    http_header_timeout_ms: u64,
    /// Most monitor connections open at once; more are closed at once.
    #[arg(long, env = "TREVI_HTTP_MAX_CONNECTIONS", value_parser = at_least::<usize>(1),
          default_value_t = defaults().limits.http_max_connections)]
    http_max_connections: usize,
    /// POST every job's events (submitted, started, frame done, done, ...)
    /// as JSON to this http:// or https:// URL; repeat for more (at most 4).
    /// See docs/farm.md, "Events".
    #[arg(long = "events-url", env = "TREVI_EVENTS_URL", value_delimiter = ',')]
    events_url: Vec<String>,
    /// Sign each event POST with HMAC-SHA256 under the secret in this file
    /// (header `X-Trevi-Signature: sha256=<hex>`); without it events are
    /// sent unsigned.
    #[arg(long, env = "TREVI_EVENTS_SECRET_FILE")]
    events_secret_file: Option<PathBuf>,
    /// Serve gRPC over TLS with this PEM certificate chain (needs --tls-key).
    #[arg(long, env = "TREVI_TLS_CERT")]
    tls_cert: Option<PathBuf>,
    /// The PEM private key of --tls-cert.
    #[arg(long, env = "TREVI_TLS_KEY")]
    tls_key: Option<PathBuf>,
}

impl Args {
    /// The farm's settings from the flags (each already checked to make
    /// sense by its parser).
    fn farm_config(&self) -> Result<FarmConfig> {
        let d = defaults();
        Ok(FarmConfig {
            data_dir: self.data_dir.clone(),
            default_tile: self.tile_size,
            durable: true,
            limits: Limits {
                max_bundle_bytes: self.max_bundle_mib << 20,
                max_bundle_files: self.max_bundle_files,
                max_message_bytes: self.max_message_kib << 10,
                max_image_samples: self.max_image_samples,
                max_jobs_per_submitter: self.max_jobs_per_submitter,
                max_uploads: self.max_uploads,
                max_admissions: self.max_admissions,
                admission_bytes: self.admission_mib.saturating_mul(1 << 20),
                upload_idle: Duration::from_millis(self.upload_idle_ms),
                max_tile_uploads: self.max_tile_uploads,
                max_workers: self.max_workers,
                max_workers_per_address: self.max_workers_per_address,
                lease_ttl: Duration::from_millis(self.lease_ttl_ms),
                window_bytes: self.window_mib << 20,
                max_tile_failures: self.max_tile_failures,
                max_worker_failures: self.max_worker_failures,
                max_tile_losses: self.max_tile_losses,
                tile_log_entries: self.tile_log_entries,
                tile_log_error_bytes: self.tile_log_error_kib.saturating_mul(1 << 10),
                memory_grace: Duration::from_millis(self.memory_grace_ms),
                frames_in_progress: self.frames_in_progress,
                lease_target: Duration::from_millis(self.lease_target_ms),
                http_header_timeout: Duration::from_millis(self.http_header_timeout_ms),
                http_max_connections: self.http_max_connections,
                usage_retention: trevi_coordinator::usage::parse_retention(&self.usage_retention)?,
                max_usage_rows: self.max_usage_rows,
                ..d.limits
            },
            retention: Retention {
                keep_ended: self.keep_ended,
                keep_ended_for: Retention::parse_duration(&self.keep_ended_for)
                    .map_err(|e| anyhow::anyhow!("--keep-ended-for: {e}"))?,
                bundle_grace: Duration::from_secs(self.bundle_grace_secs),
            },
        })
        .and_then(|cfg: FarmConfig| {
            cfg.retention.check()?;
            Ok(cfg)
        })
    }
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
    let cfg = args.farm_config()?;
    // Held until the process exits: a second coordinator on this directory
    // is refused, naming this one.
    let _dir_lock = trevi_coordinator::dir_lock::lock_data_dir(&args.data_dir)?;
    let submit_token = token_from(args.submit_token.clone(), args.submit_token_file.as_deref())
        .map_err(|e| anyhow::anyhow!("submit token: {e}"))?;
    let worker_token = token_from(args.worker_token.clone(), args.worker_token_file.as_deref())
        .map_err(|e| anyhow::anyhow!("worker token: {e}"))?;
    if submit_token.is_some() && submit_token == worker_token {
        anyhow::bail!("the submit and worker tokens must differ");
    }
    let mut tokens = Tokens::new(submit_token.as_deref(), worker_token.as_deref())?;
    if let Some(file) = &args.submit_tokens_file {
        let named = read_named_tokens(file).context("--submit-tokens-file")?;
        tracing::info!(tokens = named.len(), file = %file.display(), "named submit tokens");
        tokens = tokens.with_named(&named)?;
    }
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
    let secret = match &args.events_secret_file {
        Some(path) => Some(EventsConfig::read_secret(path).context("--events-secret-file")?),
        None => None,
    };
    if secret.is_none() {
        tracing::warn!("no --events-secret-file: job events are sent unsigned");
    }
    let events = EventsConfig {
        urls: args.events_url.clone(),
        secret,
    };
    farm.events()
        .start(events)
        .context("cannot start the job events")?;
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
                stopped,
            )))
        }
        None => None,
    };
    let shutdown = async move {
        trevi_proto::signal::shutdown().await;
        let _ = stop_tx.send(true);
    };
    let flush = farm.clone();
    trevi_coordinator::grpc::serve_with(farm, listener, shutdown, opts)
        .await
        .context("the gRPC server failed")?;
    // What the usage history gathered since its last write.
    tokio::task::spawn_blocking(move || flush.flush_usage()).await?;
    if let Some(h) = http {
        h.await
            .context("the HTTP server task failed")?
            .context("the HTTP server failed")?;
    }
    tracing::info!("coordinator stopped");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(flags: &[&str]) -> Result<Args, clap::Error> {
        Args::try_parse_from(std::iter::once("trevi-coordinator").chain(flags.iter().copied()))
    }

    #[test]
    fn the_defaults_are_the_library_s() {
        let args = parse(&[]).unwrap();
        let cfg = args.farm_config().unwrap();
        let d = FarmConfig::default();
        assert_eq!(cfg.limits, d.limits);
        assert_eq!(cfg.retention, d.retention);
        assert_eq!(
            (cfg.default_tile, cfg.durable, &cfg.data_dir),
            (d.default_tile, d.durable, &d.data_dir)
        );
    }

    #[test]
    fn a_value_that_makes_no_sense_is_refused_naming_the_flag() {
        for flag in [
            "--window-mib",
            "--tile-size",
            "--lease-ttl-ms",
            "--max-tile-failures",
            "--max-worker-failures",
            "--max-tile-losses",
            "--max-bundle-mib",
            "--max-bundle-files",
            "--max-message-kib",
            "--max-image-samples",
            "--max-jobs-per-submitter",
            "--max-workers",
            "--max-workers-per-address",
            "--max-uploads",
            "--upload-idle-ms",
            "--http-header-timeout-ms",
            "--http-max-connections",
            "--frames-in-progress",
            "--max-usage-rows",
        ] {
            let e = parse(&[flag, "0"]).unwrap_err();
            assert_eq!(e.kind(), clap::error::ErrorKind::ValueValidation, "{flag}");
            assert!(e.to_string().contains(flag), "{flag}: {e}");
        }
        // Too small for a chunk and its framing.
        let e = parse(&["--max-message-kib", "1000"]).unwrap_err();
        assert!(e.to_string().contains("--max-message-kib"), "{e}");
        parse(&["--max-message-kib", "1028", "--window-mib", "1"]).unwrap();
        // Past the documented maximum of frames in progress.
        let over = (MAX_FRAMES_IN_PROGRESS + 1).to_string();
        let e = parse(&["--frames-in-progress", &over]).unwrap_err();
        assert_eq!(e.kind(), clap::error::ErrorKind::ValueValidation);
        assert!(e.to_string().contains("--frames-in-progress"), "{e}");
        let max = MAX_FRAMES_IN_PROGRESS.to_string();
        let cfg = parse(&["--frames-in-progress", &max])
            .unwrap()
            .farm_config()
            .unwrap();
        assert_eq!(cfg.limits.frames_in_progress, MAX_FRAMES_IN_PROGRESS);
        // Keeping no ended job would delete every output as its job ends;
        // a retention of a second, or of a thousand years, is a typo.
        for (flag, value, says) in [
            ("--keep-ended", "0", "keep at least 1"),
            ("--keep-ended-for", "1s", "shorter than the shortest"),
            ("--keep-ended-for", "0d", "shorter than the shortest"),
            ("--keep-ended-for", "365000d", "longer than the longest"),
            ("--usage-retention", "30m", "from 1h to 3650d"),
            ("--usage-retention", "3651d", "from 1h to 3650d"),
            ("--usage-retention", "forever", "from 1h to 3650d"),
        ] {
            let e = parse(&[flag, value]).unwrap().farm_config().unwrap_err();
            let msg = e.to_string();
            assert!(
                msg.contains(flag) && msg.contains(says),
                "{flag} {value}: {msg}"
            );
        }
        // Event URLs: bounded, http(s) only; the check names the flag.
        let dir = tempfile::tempdir().unwrap();
        for (urls, says) in [
            ("ftp://example.com/x", "only http:// and https://"),
            (
                "http://a/,http://b/,http://c/,http://d/,http://e/",
                "5 URLs",
            ),
        ] {
            let args = parse(&["--events-url", urls]).unwrap();
            let farm = Farm::new(FarmConfig::new(dir.path())).unwrap();
            let cfg = EventsConfig {
                urls: args.events_url,
                secret: None,
            };
            let e = tokio::runtime::Runtime::new()
                .unwrap()
                .block_on(async { farm.events().start(cfg) })
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("--events-url") && e.contains(says),
                "{urls}: {e}"
            );
        }
        parse(&["--keep-ended", "1", "--keep-ended-for", "never"])
            .unwrap()
            .farm_config()
            .unwrap();
    }
}
