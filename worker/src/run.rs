//! The worker's outer loop ([`run`]): start the render threads, connect to
//! the coordinator (again after a lost connection, with exponential
//! backoff), register, and run a session's loops until the connection is
//! lost or `shutdown` turns true.

use crate::config::WorkerConfig;
use crate::cpu::RenderClocks;
use crate::error::WorkerError;
use crate::machine::watch_the_machine;
use crate::priority;
use crate::scene_cache::{Key, SceneCache};
use crate::session::{reconnect, End, Me, Session};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::watch;
use trevi_proto::pb::{self, bundles_client::BundlesClient, workers_client::WorkersClient};
use trevi_proto::{Bearer, MAX_MESSAGE_SIZE};

/// Runs the worker until `shutdown` turns true.
pub async fn run(
    cfg: WorkerConfig,
    mut shutdown: watch::Receiver<bool>,
) -> Result<(), WorkerError> {
    let endpoint = trevi_proto::endpoint(&cfg.coordinator, &cfg.tls)?
        .connect_timeout(Duration::from_secs(5))
        .tcp_nodelay(true);
    let bearer = Bearer::new(cfg.token.as_deref())?;
    let threads = if cfg.threads == 0 {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    } else {
        cfg.threads
    };
    let clocks = RenderClocks::default();
    let pool = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("trevi-render-{i}"))
            .start_handler({
                let (priority, clocks) = (cfg.priority, clocks.clone());
                move |i| {
                    clocks.register_this_thread();
                    let applied = priority::apply_to_this_thread(priority);
                    if i == 0 {
                        tracing::info!(threads, "render threads at {applied}");
                    }
                }
            })
            .build()
            .map_err(|source| WorkerError::Pool { threads, source })?,
    );
    let mut scenes = SceneCache::new(cfg.cache_size);
    for p in &cfg.preloaded {
        scenes.put(Key::still(&p.hash), p.scene.clone());
    }
    let cache = Arc::new(tokio::sync::Mutex::new(scenes));
    let paused = watch_the_machine(&cfg.pause, shutdown.clone());
    let mut backoff = Duration::from_millis(100);
    loop {
        if *shutdown.borrow() {
            return Ok(());
        }
        let channel = tokio::select! {
            c = endpoint.connect() => c,
            _ = shutdown.changed() => continue,
        };
        let end = match channel {
            Ok(channel) => {
                let mut s = Session {
                    workers: WorkersClient::with_interceptor(channel.clone(), bearer.clone())
                        .max_decoding_message_size(MAX_MESSAGE_SIZE),
                    bundles: BundlesClient::with_interceptor(channel, bearer.clone())
                        .max_decoding_message_size(MAX_MESSAGE_SIZE),
                    pool: pool.clone(),
                    threads,
                    clocks: clocks.clone(),
                    render: Arc::new(tokio::sync::Semaphore::new(1)),
                    paused: paused.clone(),
                    max_memory: cfg.max_memory,
                    scenes: cache.clone(),
                    #[cfg(feature = "test-hooks")]
                    fault: cfg.test_fault,
                };
                s.serve(&cfg, &shutdown, &mut backoff).await
            }
            Err(e) if trevi_proto::connect::is_certificate_error(&e) => {
                return Err(WorkerError::Certificate {
                    coordinator: cfg.coordinator.clone(),
                    why: trevi_proto::connect::error_chain(&e),
                });
            }
            Err(e) => End::Reconnect(format!(
                "cannot connect: {}",
                trevi_proto::connect::error_chain(&e)
            )),
        };
        match end {
            End::Shutdown => return Ok(()),
            End::Reconnect(why) => {
                let hint = {
                    let (url, why) = (cfg.coordinator.clone(), why.clone());
                    tokio::task::spawn_blocking(move || trevi_proto::connect::hint(&url, &why))
                        .await
                        .ok()
                        .flatten()
                };
                match hint {
                    Some(hint) => {
                        tracing::warn!(coordinator = %cfg.coordinator, retry_in = ?backoff, "{why} ({hint})")
                    }
                    None => {
                        tracing::warn!(coordinator = %cfg.coordinator, retry_in = ?backoff, "{why}")
                    }
                }
                tokio::select! {
                    _ = tokio::time::sleep(backoff) => {}
                    _ = shutdown.changed() => {}
                }
                backoff = (backoff * 2).min(Duration::from_secs(5));
            }
        }
    }
}

impl Session {
    /// Registers, then runs the session's loops until one of them ends it.
    async fn serve(
        &mut self,
        cfg: &WorkerConfig,
        shutdown: &watch::Receiver<bool>,
        backoff: &mut Duration,
    ) -> End {
        let reg = match self
            .workers
            .register(pb::RegisterRequest {
                name: cfg.name.clone(),
                threads: self.threads as u32,
                multi_tile: true,
                max_memory: self.max_memory.0,
                // Segment leases (`Lease.png_segments`) are encoded by
                // this encoder; see [`segments`].
                png_encoder: trevi_core::output::PNG_ENCODER.into(),
            })
            .await
        {
            Ok(r) => r.into_inner(),
            Err(s) => return reconnect("register", s),
        };
        *backoff = Duration::from_millis(100);
        let me = Me {
            id: reg.worker_id,
            session: reg.session,
        };
        let beat = cfg
            .poll
            .min(Duration::from_millis(reg.lease_ttl_ms / 3))
            .max(Duration::from_millis(10));
        tracing::info!(worker = me.id, coordinator = %cfg.coordinator, threads = self.threads, "registered");
        let mut slots = tokio::task::JoinSet::new();
        for _ in 0..cfg.tiles_in_flight.get() {
            let mut slot = self.clone();
            let (shutdown, me, poll) = (shutdown.clone(), me.clone(), cfg.poll);
            slots.spawn(async move { slot.work(me, beat, poll, shutdown).await });
        }
        {
            let mut s = self.clone();
            let (me, shutdown) = (me.clone(), shutdown.clone());
            slots.spawn(async move { s.report_pauses(me, beat, shutdown).await });
        }
        let mut end = End::Shutdown;
        while let Some(r) = slots.join_next().await {
            if let Ok(End::Reconnect(why)) = r {
                if matches!(end, End::Shutdown) {
                    // The other loops' leases will expire and be re-queued.
                    slots.abort_all();
                    end = End::Reconnect(why);
                }
            }
        }
        if matches!(end, End::Shutdown) {
            // Said last, so the coordinator shows this worker as "left",
            // not "lost" (its leases were handed back above).
            let bye = self.workers.heartbeat(pb::HeartbeatRequest {
                worker_id: me.id,
                lease_ids: Vec::new(),
                session: me.session.clone(),
                paused: "stopping".into(),
            });
            let _ = tokio::time::timeout(Duration::from_secs(1), bye).await;
        }
        end
    }
}
