//! The Trevi worker: a stateless tile renderer around `trevi_core::render_tile`.
//!
//! [`run`] loops: connect (with exponential backoff), register, lease a tile,
//! fetch its scene bundle by hash (verifying the SHA-256, keeping the last few
//! built scenes), render the tile on a rayon pool of `threads` threads while
//! heartbeating the lease, and stream the pixels back. It keeps nothing that
//! matters: kill it at any moment and the coordinator re-queues its tile when
//! the lease runs out. It survives a coordinator restart by reconnecting and
//! registering again. When `shutdown` turns true it finishes the tile in
//! hand, sends it, and returns.

use std::sync::Arc;
use std::time::Duration;
use tokio::sync::watch;
use tonic::Code;
use trevi_core::{Bundle, Rect, Scene};
use trevi_proto::pb::{self, bundles_client::BundlesClient, workers_client::WorkersClient};
use trevi_proto::{pixels_to_bytes, rect_from, AuthChannel, Bearer, CHUNK_SIZE, MAX_MESSAGE_SIZE};

/// Worker settings.
#[derive(Debug, Clone)]
pub struct WorkerConfig {
    /// Like `http://host:50051`.
    pub coordinator: String,
    /// Render threads (0: every core).
    pub threads: usize,
    /// How the worker introduces itself in the coordinator's logs.
    pub name: String,
    /// How many built scenes to keep.
    pub cache_size: usize,
    /// Tiles in flight at once (each leased, rendered and sent by its own
    /// loop, all sharing the render threads), so the threads stay busy
    /// while a result travels and the next lease arrives.
    pub tiles_in_flight: usize,
    /// The coordinator's worker token, if it has one.
    pub token: Option<String>,
    /// The CA to trust and the name to expect for an `https://` coordinator.
    pub tls: trevi_proto::ClientTls,
}

impl WorkerConfig {
    pub fn new(coordinator: impl Into<String>) -> Self {
        WorkerConfig {
            coordinator: coordinator.into(),
            threads: 0,
            name: default_name(),
            cache_size: 4,
            tiles_in_flight: 2,
            token: None,
            tls: trevi_proto::ClientTls::default(),
        }
    }
}

fn default_name() -> String {
    let host = std::fs::read_to_string("/etc/hostname")
        .ok()
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
        .or_else(|| std::env::var("HOSTNAME").ok())
        .unwrap_or_else(|| "worker".into());
    format!("{host}-{}", std::process::id())
}

#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    #[error(transparent)]
    Endpoint(#[from] trevi_proto::EndpointError),
    /// The coordinator's TLS certificate is not trusted or not for its name:
    /// retrying cannot help.
    #[error("cannot connect to {0}: {1}")]
    Certificate(String, String),
    #[error("cannot start {0} render threads: {1}")]
    Pool(usize, String),
    #[error("{0}")]
    Token(String),
}

/// Why a session with the coordinator ended.
enum End {
    Shutdown,
    /// Connection lost or coordinator restarted: connect and register again.
    Reconnect(String),
}

/// Scenes built from bundles, most recently used last.
struct SceneCache {
    cap: usize,
    scenes: Vec<(String, Arc<Scene>)>,
}

impl SceneCache {
    fn get(&mut self, hash: &str) -> Option<Arc<Scene>> {
        let i = self.scenes.iter().position(|(h, _)| h == hash)?;
        let e = self.scenes.remove(i);
        let s = e.1.clone();
        self.scenes.push(e);
        Some(s)
    }
    fn put(&mut self, hash: String, scene: Arc<Scene>) {
        if self.scenes.len() >= self.cap.max(1) {
            self.scenes.remove(0);
        }
        self.scenes.push((hash, scene));
    }
}

/// Runs the worker until `shutdown` turns true.
pub async fn run(
    cfg: WorkerConfig,
    mut shutdown: watch::Receiver<bool>,
) -> Result<(), WorkerError> {
    let endpoint = trevi_proto::endpoint(&cfg.coordinator, &cfg.tls)?
        .connect_timeout(Duration::from_secs(5))
        .tcp_nodelay(true);
    let bearer = Bearer::new(cfg.token.as_deref()).map_err(WorkerError::Token)?;
    let threads = if cfg.threads == 0 {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    } else {
        cfg.threads
    };
    let pool = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("trevi-render-{i}"))
            .build()
            .map_err(|e| WorkerError::Pool(threads, e.to_string()))?,
    );
    let cache = Arc::new(tokio::sync::Mutex::new(SceneCache {
        cap: cfg.cache_size,
        scenes: Vec::new(),
    }));
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
                };
                s.serve(&cfg, &cache, &shutdown, &mut backoff).await
            }
            Err(e) if trevi_proto::connect::is_certificate_error(&e) => {
                let why = trevi_proto::connect::error_chain(&e);
                return Err(WorkerError::Certificate(cfg.coordinator.clone(), why));
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

#[derive(Clone)]
struct Session {
    workers: WorkersClient<AuthChannel>,
    bundles: BundlesClient<AuthChannel>,
    pool: Arc<rayon::ThreadPool>,
    threads: usize,
}

fn reconnect(what: &str, s: tonic::Status) -> End {
    let mut why = format!("{what}: {}: {}", s.code(), s.message());
    // A transport failure's cause (a TLS alert, a reset) is under the status.
    if let Some(cause) = std::error::Error::source(&s) {
        let cause = trevi_proto::connect::error_chain(cause);
        if !why.contains(&cause) {
            why = format!("{why}: {cause}");
        }
    }
    End::Reconnect(why)
}

impl Session {
    async fn serve(
        &mut self,
        cfg: &WorkerConfig,
        cache: &Arc<tokio::sync::Mutex<SceneCache>>,
        shutdown: &watch::Receiver<bool>,
        backoff: &mut Duration,
    ) -> End {
        let reg = match self
            .workers
            .register(pb::RegisterRequest {
                name: cfg.name.clone(),
                threads: self.threads as u32,
            })
            .await
        {
            Ok(r) => r.into_inner(),
            Err(s) => return reconnect("register", s),
        };
        *backoff = Duration::from_millis(100);
        let worker = reg.worker_id;
        let beat = Duration::from_millis((reg.lease_ttl_ms / 3).max(10));
        tracing::info!(worker, coordinator = %cfg.coordinator, threads = self.threads, "registered");
        let mut slots = tokio::task::JoinSet::new();
        for _ in 0..cfg.tiles_in_flight.max(1) {
            let mut slot = self.clone();
            let (cache, shutdown) = (cache.clone(), shutdown.clone());
            slots.spawn(async move { slot.work(worker, beat, cache, shutdown).await });
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
        end
    }

    /// One lease → render → send loop.
    async fn work(
        &mut self,
        worker: u64,
        beat: Duration,
        cache: Arc<tokio::sync::Mutex<SceneCache>>,
        shutdown: watch::Receiver<bool>,
    ) -> End {
        loop {
            if *shutdown.borrow() {
                return End::Shutdown;
            }
            // Not interrupted by `shutdown`: a lease granted while the answer
            // is on its way would be lost until it expires. The call returns
            // within the coordinator's short wait, and a tile it brings is
            // finished before stopping.
            let lease = self
                .workers
                .lease_tile(pb::LeaseRequest { worker_id: worker })
                .await;
            let lease = match lease {
                Ok(r) => match r.into_inner().lease {
                    Some(l) => l,
                    None => continue,
                },
                Err(s) => return reconnect("lease", s),
            };
            let rect = match rect_from(lease.rect) {
                Ok(r) => r,
                Err(e) => {
                    tracing::error!(lease = lease.lease_id, "bad lease: {e}");
                    continue;
                }
            };
            let scene = {
                let mut cache = cache.lock().await;
                self.scene(&mut cache, &lease.bundle_hash).await
            };
            let scene = match scene {
                Ok(s) => s,
                Err(e) => {
                    // The lease runs out and the tile goes to someone else;
                    // pause so a broken bundle is not fetched in a tight loop.
                    tracing::error!(bundle = %lease.bundle_hash, "cannot load the scene: {e}");
                    tokio::time::sleep(Duration::from_secs(1)).await;
                    continue;
                }
            };
            let Some(camera) = scene.camera_index(&lease.camera) else {
                tracing::error!(camera = %lease.camera, "the scene has no such camera");
                tokio::time::sleep(Duration::from_secs(1)).await;
                continue;
            };
            match self.render(worker, &lease, scene, camera, rect, beat).await {
                Ok(Some((pixels, rays))) => {
                    tracing::debug!(
                        lease = lease.lease_id,
                        job = lease.job_id,
                        x = rect.x,
                        y = rect.y,
                        "tile rendered"
                    );
                    if let Err(s) = self.send(worker, &lease, rect, rays, &pixels).await {
                        if s.code() == Code::InvalidArgument {
                            tracing::error!(
                                lease = lease.lease_id,
                                "tile rejected: {}",
                                s.message()
                            );
                        } else {
                            return reconnect("sending a tile", s);
                        }
                    }
                }
                Ok(None) => {
                    tracing::info!(lease = lease.lease_id, "lease dropped by the coordinator")
                }
                Err(end) => return end,
            }
        }
    }

    /// The built scene for `hash`, from the cache or fetched and built.
    async fn scene(&mut self, cache: &mut SceneCache, hash: &str) -> Result<Arc<Scene>, String> {
        if let Some(s) = cache.get(hash) {
            return Ok(s);
        }
        let mut stream = self
            .bundles
            .download_bundle(pb::BundleRef {
                hash: hash.to_string(),
                size: 0,
            })
            .await
            .map_err(|s| s.message().to_string())?
            .into_inner();
        let mut bytes = Vec::new();
        while let Some(c) = stream
            .message()
            .await
            .map_err(|s| s.message().to_string())?
        {
            bytes.extend_from_slice(&c.data);
        }
        let want = hash.to_string();
        let scene = tokio::task::spawn_blocking(move || -> Result<Scene, String> {
            let got = trevi_core::bundle::sha256_hex(&bytes);
            if got != want {
                return Err(format!("bundle {want} arrived with hash {got}"));
            }
            let bundle = Bundle::decode(&bytes)?;
            Scene::from_bundle(&bundle).map_err(|e| e.to_string())
        })
        .await
        .map_err(|e| e.to_string())??;
        let scene = Arc::new(scene);
        tracing::info!(bundle = %hash, "scene built");
        cache.put(hash.to_string(), scene.clone());
        Ok(scene)
    }

    /// Renders while heartbeating; `None` when the coordinator dropped the lease.
    async fn render(
        &mut self,
        worker: u64,
        lease: &pb::Lease,
        scene: Arc<Scene>,
        camera: usize,
        rect: Rect,
        beat: Duration,
    ) -> Result<Option<(Vec<[f32; 3]>, u64)>, End> {
        let pool = self.pool.clone();
        let mut job = tokio::task::spawn_blocking(move || {
            pool.install(|| trevi_core::render_tile(&scene, camera, rect))
        });
        let mut dropped = false;
        let mut tick = tokio::time::interval(beat);
        tick.tick().await;
        loop {
            tokio::select! {
                r = &mut job => {
                    let r = r.map_err(|e| End::Reconnect(format!("render task failed: {e}")))?;
                    return Ok((!dropped).then_some((r.pixels, r.rays)));
                }
                _ = tick.tick(), if !dropped => {
                    let hb = self.workers.heartbeat(pb::HeartbeatRequest {
                        worker_id: worker,
                        lease_ids: vec![lease.lease_id],
                    }).await;
                    match hb {
                        // Finish the tile anyway (it cannot be interrupted),
                        // but do not send it.
                        Ok(r) => dropped = !r.into_inner().dropped.is_empty(),
                        Err(s) if s.code() == Code::Unauthenticated => dropped = true,
                        Err(s) => tracing::warn!("heartbeat failed: {}", s.message()),
                    }
                }
            }
        }
    }

    async fn send(
        &mut self,
        worker: u64,
        lease: &pb::Lease,
        rect: Rect,
        rays: u64,
        pixels: &[[f32; 3]],
    ) -> Result<bool, tonic::Status> {
        let msgs = tile_messages(worker, lease, rect, rays, pixels);
        let ack = self
            .workers
            .submit_tile(tokio_stream::iter(msgs))
            .await?
            .into_inner();
        Ok(ack.accepted)
    }
}

/// The messages of a tile upload: the header, then the pixels in chunks.
pub fn tile_messages(
    worker: u64,
    lease: &pb::Lease,
    rect: Rect,
    rays: u64,
    pixels: &[[f32; 3]],
) -> Vec<pb::TileUpload> {
    use pb::tile_upload::Part;
    let bytes = pixels_to_bytes(pixels);
    let mut msgs = vec![pb::TileUpload {
        part: Some(Part::Header(pb::TileHeader {
            worker_id: worker,
            lease_id: lease.lease_id,
            job_id: lease.job_id,
            rect: Some(rect.into()),
            rays,
        })),
    }];
    msgs.extend(bytes.chunks(CHUNK_SIZE).map(|c| pb::TileUpload {
        part: Some(Part::Pixels(c.to_vec())),
    }));
    msgs
}
