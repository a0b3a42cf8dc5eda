//! The Trevi worker: a stateless tile renderer around `trevi_core::render_tile`.
//!
//! [`run`] loops: connect (with exponential backoff), register, lease a tile,
//! fetch its scene bundle by hash (verifying the SHA-256, keeping the last few
//! built scenes), render the tile on a rayon pool of `threads` threads while
//! heartbeating the lease, and stream the pixels back. It keeps nothing that
//! matters: kill it at any moment and the coordinator re-queues its tile when
//! the lease runs out. It survives a coordinator restart by reconnecting and
//! registering again.
//!
//! A lease may cover several adjacent tiles of one band (the worker
//! registers with `multi_tile`; the coordinator sizes such spans from the
//! render cost it measures): their union is rendered as one rectangle, which
//! gives the same pixels, and uploaded once.
//!
//! The worker registers with its PNG segment encoder's name
//! (`trevi_core::output::PNG_ENCODER`). A lease with `png_segments` is
//! uploaded as encoded 16-row PNG segments and preview sums instead of
//! floats ([`segments`]): the worker checks the pixels (a pixel not finite
//! and non-negative fails the lease, which goes back with an error naming
//! it) and encodes the segments on the render threads.
//!
//! A lease is held only by a tile being worked on: a loop takes the render
//! threads before it asks for a lease, so no tile waits behind another while
//! its lease is kept alive. A render stops within a pixel once its lease is
//! dropped (the job was cancelled) or `shutdown` turns true; then the worker
//! gives the lease back unrendered and returns. A render that panics is
//! reported to the coordinator (which counts it against the tile) and the
//! worker goes on.
//!
//! The render threads run at idle priority unless told otherwise
//! ([`priority`]): a worker on a spare desk takes only the CPU time its
//! owner leaves unused.
//!
//! A scene whose estimated size exceeds the worker's memory limit
//! ([`memory`], `--max-memory`) is declined, not built: the coordinator
//! learns the limit at registration and leases such jobs elsewhere.

pub mod memory;
pub mod pause;
pub mod priority;
pub use memory::MaxMemory;
pub mod scenes;
pub mod segments;
pub use pause::{Pause, PauseConfig};
pub use priority::Priority;

use std::num::NonZeroUsize;
use std::sync::atomic::{AtomicBool, Ordering};
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
    /// How many built scenes to keep ([`SCENE_CACHE`] by default).
    pub cache_size: NonZeroUsize,
    /// Tiles in flight at once (each leased, rendered and sent by its own
    /// loop, all sharing the render threads), so the threads stay busy
    /// while a result travels and the next lease arrives
    /// ([`TILES_IN_FLIGHT`] by default).
    pub tiles_in_flight: NonZeroUsize,
    /// The coordinator's worker token, if it has one.
    pub token: Option<String>,
    /// The CA to trust and the name to expect for an `https://` coordinator.
    pub tls: trevi_proto::ClientTls,
    /// How often a lease is heartbeated while its tile renders (at most a
    /// third of the lease's lifetime), and the longest one `LeaseTile` call
    /// waits: how soon a cancelled job or a stop ends a render.
    pub poll: Duration,
    /// Scenes already built, with their bundle's hash: they start in the
    /// scene cache, so their bundles are never downloaded or parsed (a
    /// local render hands over the scene it parsed for itself).
    pub preloaded: Vec<Preloaded>,
    /// The render threads' CPU priority ([`Priority::Idle`] by default: a
    /// worker on somebody's desk stays out of its owner's way).
    pub priority: Priority,
    /// When to step aside: the machine is busy, or outside the active
    /// hours (nothing watched by default; see [`pause`]).
    pub pause: PauseConfig,
    /// The most memory one scene may take ([`memory`]); no limit by
    /// default here (an in-process worker renders what its user asked
    /// for), while `trevi-worker` defaults to a share of the machine's RAM
    /// ([`MaxMemory::default_for_this_machine`]).
    pub max_memory: MaxMemory,
    /// Tests only: make the render of one tile fail (see [`TestFault`]).
    #[doc(hidden)]
    pub test_fault: Option<TestFault>,
}

/// A scene built before the worker starts, and the hash of its bundle (see
/// [`WorkerConfig::preloaded`]).
#[derive(Clone)]
pub struct Preloaded {
    pub hash: String,
    pub scene: Arc<Scene>,
}

impl std::fmt::Debug for Preloaded {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Preloaded")
            .field("hash", &self.hash)
            .finish_non_exhaustive()
    }
}

/// The default [`WorkerConfig::poll`].
pub const POLL: Duration = Duration::from_millis(500);

/// The default [`WorkerConfig::cache_size`]: a few scenes, so a farm
/// rendering several jobs at once does not build them again and again.
pub const SCENE_CACHE: NonZeroUsize = NonZeroUsize::new(4).unwrap();

/// The default [`WorkerConfig::tiles_in_flight`]: one rendering, one
/// travelling.
pub const TILES_IN_FLIGHT: NonZeroUsize = NonZeroUsize::new(2).unwrap();

/// Tests only: a deliberate failure when rendering the tile whose top-left
/// corner is at (`x`, `y`), standing in for a scene that crashes the
/// renderer. Set by `trevi-worker` from `TREVI_TEST_ABORT_ON_TILE=x,y` or
/// `TREVI_TEST_PANIC_ON_TILE=x,y`.
#[doc(hidden)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TestFault {
    pub x: u32,
    pub y: u32,
    /// Abort the process (like a stack overflow) rather than panic.
    pub abort: bool,
}

impl TestFault {
    /// Reads `x,y` from `var`; `None` when it is unset or malformed.
    pub fn from_env(var: &str, abort: bool) -> Option<TestFault> {
        let v = std::env::var(var).ok()?;
        let (x, y) = v.split_once(',')?;
        Some(TestFault {
            x: x.trim().parse().ok()?,
            y: y.trim().parse().ok()?,
            abort,
        })
    }

    fn strike(&self, rect: Rect) {
        if (rect.x, rect.y) == (self.x, self.y) {
            if self.abort {
                eprintln!(
                    "test fault: aborting on the tile at ({}, {})",
                    rect.x, rect.y
                );
                std::process::abort();
            }
            panic!("test fault: panic on the tile at ({}, {})", rect.x, rect.y);
        }
    }
}

impl WorkerConfig {
    /// The defaults, working for `coordinator`.
    pub fn new(coordinator: impl Into<String>) -> Self {
        WorkerConfig {
            coordinator: coordinator.into(),
            ..WorkerConfig::default()
        }
    }
}

/// Every setting's default; `coordinator` is empty and must be set (see
/// [`WorkerConfig::new`]).
impl Default for WorkerConfig {
    fn default() -> Self {
        WorkerConfig {
            coordinator: String::new(),
            threads: 0,
            name: default_name(),
            cache_size: SCENE_CACHE,
            tiles_in_flight: TILES_IN_FLIGHT,
            token: None,
            tls: trevi_proto::ClientTls::default(),
            poll: POLL,
            preloaded: Vec::new(),
            priority: Priority::default(),
            pause: PauseConfig::default(),
            max_memory: MaxMemory::NONE,
            test_fault: None,
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

/// Why [`run`] could not start or had to give up.
#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    #[error(transparent)]
    Endpoint(#[from] trevi_proto::EndpointError),
    /// The coordinator's TLS certificate is not trusted or not for its name:
    /// retrying cannot help. `why` is the transport error's chain of causes
    /// on one line, without tonic's repetitions (see
    /// [`trevi_proto::connect::error_chain`]).
    #[error("cannot connect to {coordinator}: {why}")]
    Certificate { coordinator: String, why: String },
    #[error("cannot start {threads} render threads")]
    Pool {
        threads: usize,
        source: rayon::ThreadPoolBuildError,
    },
    #[error(transparent)]
    Token(#[from] trevi_proto::TokenError),
}

/// Why the scene of a leased tile could not be loaded. The worker gives the
/// tile back with this text; the coordinator counts it against the tile.
#[derive(Debug, thiserror::Error)]
pub enum SceneLoadError {
    /// The coordinator refused the download or the stream broke off (the
    /// status's message says why: an unknown or damaged bundle...).
    #[error("{}", .0.message())]
    Download(#[source] tonic::Status),
    /// The bytes that arrived are not the bundle that was asked for.
    #[error("bundle {want} arrived with hash {got}")]
    HashMismatch { want: String, got: String },
    /// The bytes are not a bundle encoding.
    #[error(transparent)]
    Bundle(#[from] trevi_core::bundle::BundleError),
    /// The bundle's scene does not parse or build.
    #[error(transparent)]
    Scene(#[from] trevi_core::SceneError),
    /// The blocking task that builds the scene panicked or was cancelled.
    #[error(transparent)]
    Task(#[from] tokio::task::JoinError),
    /// The scene's estimate exceeds the worker's `--max-memory`: not built.
    #[error("the scene needs about {} of memory, more than --max-memory {}",
        trevi_core::scene::estimate::human_bytes(*.needs), trevi_core::scene::estimate::human_bytes(.limit.0))]
    TooBig { needs: u64, limit: MaxMemory },
    /// The scene cannot be moved to the lease's frame.
    #[error("cannot move the scene to the frame: {0}")]
    Frame(String),
}

/// Why a session with the coordinator ended.
enum End {
    Shutdown,
    /// Connection lost or coordinator restarted: connect and register again.
    Reconnect(String),
}

/// Scenes built from bundles, most recently used last.
struct SceneCache {
    cap: NonZeroUsize,
    scenes: Vec<(String, Arc<Scene>)>,
    /// Scenes at frames of sequences (see [`scenes`]).
    frames: scenes::FrameScenes,
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
        if self.scenes.len() >= self.cap.get() {
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
    let bearer = Bearer::new(cfg.token.as_deref())?;
    let threads = if cfg.threads == 0 {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    } else {
        cfg.threads
    };
    let pool = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("trevi-render-{i}"))
            .start_handler({
                let priority = cfg.priority;
                move |i| {
                    let applied = priority::apply_to_this_thread(priority);
                    if i == 0 {
                        tracing::info!(threads, "render threads at {applied}");
                    }
                }
            })
            .build()
            .map_err(|source| WorkerError::Pool { threads, source })?,
    );
    let mut scenes = SceneCache {
        cap: cfg.cache_size,
        scenes: Vec::new(),
        frames: scenes::FrameScenes::new(cfg.cache_size),
    };
    for p in &cfg.preloaded {
        scenes.put(p.hash.clone(), p.scene.clone());
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
                    render: Arc::new(tokio::sync::Semaphore::new(1)),
                    paused: paused.clone(),
                    max_memory: cfg.max_memory,
                };
                s.serve(&cfg, &cache, &shutdown, &mut backoff).await
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

#[derive(Clone)]
struct Session {
    workers: WorkersClient<AuthChannel>,
    bundles: BundlesClient<AuthChannel>,
    pool: Arc<rayon::ThreadPool>,
    threads: usize,
    /// One permit: the tile that has the render threads. A loop takes it
    /// before leasing and gives it up once its tile is rendered, so the
    /// others send their results meanwhile but never hold a lease they are
    /// not working on.
    render: Arc<tokio::sync::Semaphore>,
    /// Why the worker steps aside now (none: it works); see [`pause`].
    paused: watch::Receiver<Option<Pause>>,
    /// The most memory one scene may take; see [`memory`].
    max_memory: MaxMemory,
}

/// Starts watching the machine as `cfg` says; the receiver tells why the
/// worker should step aside (never anything when nothing is watched).
/// Every change is logged, with its reason.
fn watch_the_machine(
    cfg: &PauseConfig,
    mut shutdown: watch::Receiver<bool>,
) -> watch::Receiver<Option<Pause>> {
    let (tx, rx) = watch::channel(None);
    if !cfg.watches() {
        // Nothing will change; the channel stays open until the end.
        tokio::spawn(async move {
            let _ = shutdown.wait_for(|&s| s).await;
            drop(tx);
        });
        return rx;
    }
    let cores = pause::read_proc_stat()
        .map(|s| pause::count_cores(&s))
        .unwrap_or(0)
        .max(1);
    if cfg.yield_when_busy && pause::sample_now().is_none() {
        tracing::warn!("--yield-when-busy: cannot read /proc/stat and /proc/self/stat; the load is not watched");
    }
    let mut watcher = pause::Watcher::new(cfg.clone(), cores);
    let (every, quiet, hours) = (cfg.sample, cfg.quiet_for, cfg.active_hours);
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(every);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tokio::select! {
                _ = tick.tick() => {}
                _ = shutdown.changed() => return,
            }
            let now = std::time::Instant::now();
            let p = watcher.step(now, pause::sample_now(), pause::local_minute());
            let was = *tx.borrow();
            if was.map(|w| w.reason()) == p.map(|p| p.reason()) {
                continue;
            }
            match (&was, &p) {
                (_, Some(p)) => tracing::info!(
                    reason = p.reason(),
                    "paused ({p}): in-flight tiles handed back, no new ones until it ends"
                ),
                (Some(Pause::Busy { .. }), None) => tracing::info!(
                    "resumed: the machine has been quiet for {} s",
                    quiet.as_secs_f64()
                ),
                (Some(Pause::OutsideHours), None) => tracing::info!(
                    "resumed: within the active hours {}",
                    hours.map(|h| h.to_string()).unwrap_or_default()
                ),
                (None, None) => {}
            }
            if tx.send(p).is_err() {
                return;
            }
        }
    });
    rx
}

/// Who the coordinator registered us as.
#[derive(Clone)]
struct Me {
    id: u64,
    session: Vec<u8>,
}

/// How working on one leased tile ended.
enum TileEnd {
    /// The result, the rays traced, and how long the render itself took
    /// (told to the coordinator, which sizes leases from it).
    Rendered(Payload, u64, Duration),
    /// The coordinator no longer wants it (the job was cancelled or the
    /// lease expired): the render was stopped.
    Dropped,
    /// `shutdown` turned true: the render was stopped.
    Stopped,
    /// The worker stepped aside (see [`pause`]): the render was stopped.
    Paused,
    /// The scene could not be loaded, or the render panicked.
    Failed(String),
    /// The scene needs about this many bytes, more than `--max-memory`:
    /// declined without building it (see [`memory`]).
    Declined(u64),
}

/// What a rendered lease uploads.
enum Payload {
    /// The pixels, as floats.
    Floats(Vec<[f32; 3]>),
    /// For a lease with `png_segments`: the rect's encoded segments and
    /// preview sums (see [`segments`]).
    Segments(segments::EncodedRect),
}

/// Sets a render's cancellation flag when dropped, so a loop aborted midway
/// (the session ends) does not leave its render running.
struct CancelOnDrop(Arc<AtomicBool>);

impl Drop for CancelOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
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

/// The message of a caught panic.
fn panic_message(p: &(dyn std::any::Any + Send)) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".to_string())
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
            let (cache, shutdown, me) = (cache.clone(), shutdown.clone(), me.clone());
            let (poll, fault) = (cfg.poll, cfg.test_fault);
            slots.spawn(async move { slot.work(me, beat, poll, fault, cache, shutdown).await });
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

    /// Tells the coordinator why the worker is paused, at once and then
    /// every `beat` while it is (a paused worker leases nothing, so this
    /// keeps it alive in the coordinator's list and shows the reason).
    async fn report_pauses(
        &mut self,
        me: Me,
        beat: Duration,
        mut shutdown: watch::Receiver<bool>,
    ) -> End {
        let mut tick = tokio::time::interval(beat);
        loop {
            let reason = self.pause_reason();
            if !reason.is_empty() {
                let hb = self
                    .workers
                    .heartbeat(pb::HeartbeatRequest {
                        worker_id: me.id,
                        lease_ids: Vec::new(),
                        session: me.session.clone(),
                        paused: reason,
                    })
                    .await;
                if let Err(s) = hb {
                    tracing::warn!("heartbeat failed: {}", s.message());
                }
            }
            tokio::select! {
                _ = tick.tick() => {}
                r = self.paused.changed() => if r.is_err() {
                    // Nothing is watched (any more): nothing to report.
                    let _ = shutdown.wait_for(|&s| s).await;
                    return End::Shutdown;
                },
                r = shutdown.changed() => if r.is_err() || *shutdown.borrow() { return End::Shutdown },
            }
        }
    }

    /// The reason the coordinator is told (empty: working).
    fn pause_reason(&self) -> String {
        self.paused
            .borrow()
            .map(|p| p.reason().to_string())
            .unwrap_or_default()
    }

    /// One lease → render → send loop.
    async fn work(
        &mut self,
        me: Me,
        beat: Duration,
        poll: Duration,
        fault: Option<TestFault>,
        cache: Arc<tokio::sync::Mutex<SceneCache>>,
        mut shutdown: watch::Receiver<bool>,
    ) -> End {
        loop {
            if *shutdown.borrow() {
                return End::Shutdown;
            }
            if self.paused.borrow_and_update().is_some() {
                // Lease nothing until the pause ends.
                tokio::select! {
                    r = self.paused.changed() => if r.is_err() { return End::Shutdown },
                    r = shutdown.changed() => if r.is_err() { return End::Shutdown },
                }
                continue;
            }
            let permit = tokio::select! {
                p = self.render.clone().acquire_owned() => match p {
                    Ok(p) => p,
                    Err(_) => return End::Shutdown,
                },
                // A closed channel: no one can stop us any more, so stop.
                r = shutdown.changed() => match r {
                    Ok(()) => continue,
                    Err(_) => return End::Shutdown,
                },
            };
            // Not interrupted by `shutdown`: a lease granted while the answer
            // is on its way would be lost until it expires. The call returns
            // within `poll`, and a tile it brings is given back at once.
            let lease = self
                .workers
                .lease_tile(pb::LeaseRequest {
                    worker_id: me.id,
                    session: me.session.clone(),
                    max_wait_ms: poll.as_millis().clamp(1, u32::MAX as u128) as u32,
                })
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
            let end = if *shutdown.borrow() {
                TileEnd::Stopped
            } else if self.paused.borrow().is_some() {
                TileEnd::Paused
            } else if !self.max_memory.allows(lease.memory_estimate) {
                // The coordinator's estimate says no: not even downloaded.
                TileEnd::Declined(lease.memory_estimate)
            } else {
                self.tile(&me, &lease, rect, beat, fault, &cache, &mut shutdown)
                    .await
            };
            drop(permit);
            let (x, y, id) = (rect.x, rect.y, lease.lease_id);
            match end {
                TileEnd::Rendered(payload, rays, took) => {
                    // One line per tile, also for a span of several: the
                    // logs count tiles, not leases.
                    for id in span_ids(&lease) {
                        tracing::debug!(lease = id, job = lease.job_id, x, y, "tile rendered");
                    }
                    let rendered = Rendered { rays, took };
                    if let Err(s) = self.send(&me, &lease, rect, rendered, payload).await {
                        if s.code() == Code::InvalidArgument {
                            tracing::error!(lease = id, "tile rejected: {}", s.message());
                        } else {
                            return reconnect("sending a tile", s);
                        }
                    }
                }
                TileEnd::Dropped => {
                    tracing::info!(
                        lease = id,
                        x,
                        y,
                        "lease dropped by the coordinator; render cancelled"
                    );
                    // The other tiles of a span may still be ours.
                    if lease.tiles > 1 {
                        for id in span_ids(&lease) {
                            self.give_back(&me, id, String::new()).await;
                        }
                    }
                }
                TileEnd::Stopped => {
                    tracing::info!(
                        lease = id,
                        x,
                        y,
                        "stopping: render cancelled, lease given back"
                    );
                    for id in span_ids(&lease) {
                        self.give_back(&me, id, String::new()).await;
                    }
                    return End::Shutdown;
                }
                TileEnd::Paused => {
                    tracing::info!(
                        lease = id,
                        x,
                        y,
                        "paused: render cancelled, lease given back"
                    );
                    for id in span_ids(&lease) {
                        self.give_back(&me, id, String::new()).await;
                    }
                }
                TileEnd::Declined(needs) => {
                    tracing::warn!(
                        lease = id,
                        "{}",
                        memory::declined(lease.job_id, needs, self.max_memory)
                    );
                    for id in span_ids(&lease) {
                        self.decline(&me, id, needs).await;
                    }
                }
                TileEnd::Failed(why) => {
                    tracing::error!(lease = id, job = lease.job_id, x, y, "tile failed: {why}");
                    for id in span_ids(&lease) {
                        self.give_back(&me, id, why.clone()).await;
                    }
                    // Do not take the next tile of a broken job in a tight loop.
                    tokio::select! {
                        _ = tokio::time::sleep(Duration::from_secs(1)) => {}
                        _ = shutdown.changed() => {}
                    }
                }
            }
        }
    }

    /// Returns a lease unfinished (`error` empty: unrendered, no fault).
    async fn give_back(&mut self, me: &Me, lease: u64, error: String) {
        let r = self
            .workers
            .return_tile(pb::TileReturn {
                worker_id: me.id,
                session: me.session.clone(),
                lease_id: lease,
                error,
                memory_needed: 0,
            })
            .await;
        if let Err(s) = r {
            // The lease then runs out on its own.
            tracing::warn!(lease, "cannot give the lease back: {}", s.message());
        }
    }

    /// Declines a lease: its scene needs about `needs` bytes, more than
    /// `--max-memory` (not a failure; the coordinator leases the job to
    /// workers that can hold it).
    async fn decline(&mut self, me: &Me, lease: u64, needs: u64) {
        let r = self
            .workers
            .return_tile(pb::TileReturn {
                worker_id: me.id,
                session: me.session.clone(),
                lease_id: lease,
                error: String::new(),
                memory_needed: needs.max(1),
            })
            .await;
        if let Err(s) = r {
            tracing::warn!(lease, "cannot decline the lease: {}", s.message());
        }
    }

    /// Loads the scene and renders the tile while heartbeating its lease;
    /// stops the render when the lease is dropped or `shutdown` turns true.
    #[allow(clippy::too_many_arguments)]
    async fn tile(
        &mut self,
        me: &Me,
        lease: &pb::Lease,
        rect: Rect,
        beat: Duration,
        fault: Option<TestFault>,
        cache: &Arc<tokio::sync::Mutex<SceneCache>>,
        shutdown: &mut watch::Receiver<bool>,
    ) -> TileEnd {
        let cancel = Arc::new(AtomicBool::new(false));
        let _guard = CancelOnDrop(cancel.clone());
        let work = {
            let mut s = self.clone();
            let (cache, cancel) = (cache.clone(), cancel.clone());
            let (hash, camera) = (lease.bundle_hash.clone(), lease.camera.clone());
            let frame = lease.frame;
            async move {
                let scene = {
                    let mut cache = cache.lock().await;
                    match frame {
                        None => s.scene(&mut cache, &hash).await,
                        Some(f) => s.frame_scene(&mut cache, &hash, &camera, f).await,
                    }
                };
                let scene = match scene {
                    Ok(s) => s,
                    Err(SceneLoadError::TooBig { needs, .. }) => return TileEnd::Declined(needs),
                    Err(e) => return TileEnd::Failed(format!("cannot load the scene: {e}")),
                };
                let Some(camera) = scene.camera_index(&camera) else {
                    return TileEnd::Failed(format!("the scene has no camera \"{camera}\""));
                };
                let pool = s.pool.clone();
                // For a segment lease: the frame's size and the preview's
                // cell edge, to check the rect and encode it.
                let segments = lease.png_segments.then(|| {
                    let r = &scene.desc.cameras[camera].render;
                    (r.width, r.height, lease.preview_scale)
                });
                let job = tokio::task::spawn_blocking(move || {
                    pool.install(|| {
                        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                            if let Some(f) = fault {
                                f.strike(rect);
                            }
                            let start = std::time::Instant::now();
                            let r = trevi_core::tile::render_tile_cancellable(
                                &scene, camera, rect, &cancel,
                            )?;
                            // The encoding counts as the lease's render time:
                            // it is the worker's time that the coordinator
                            // sizes leases from.
                            let payload = match segments {
                                None => Ok(Payload::Floats(r.pixels)),
                                Some((w, h, scale)) => {
                                    segments::encode_rect(rect, w, h, scale, &r.pixels)
                                        .map(Payload::Segments)
                                }
                            };
                            Ok((payload, r.rays, start.elapsed()))
                        }))
                    })
                });
                match job.await {
                    Ok(Ok(Ok((Ok(payload), rays, took)))) => TileEnd::Rendered(payload, rays, took),
                    Ok(Ok(Ok((Err(e), ..)))) => TileEnd::Failed(e.to_string()),
                    Ok(Ok(Err(trevi_core::tile::Cancelled))) => TileEnd::Dropped,
                    Ok(Err(panic)) => TileEnd::Failed(format!(
                        "the render panicked: {}",
                        panic_message(panic.as_ref())
                    )),
                    Err(e) => TileEnd::Failed(format!("the render task failed: {e}")),
                }
            }
        };
        tokio::pin!(work);
        let (mut dropped, mut stopping, mut pausing) = (false, false, false);
        let mut watched = true;
        let mut tick = tokio::time::interval(beat);
        tick.tick().await;
        loop {
            tokio::select! {
                end = &mut work => {
                    return match end {
                        _ if stopping => TileEnd::Stopped,
                        TileEnd::Dropped if pausing => TileEnd::Paused,
                        TileEnd::Rendered(..) if dropped => TileEnd::Dropped,
                        end => end,
                    };
                }
                _ = tick.tick(), if !dropped && !stopping => {
                    let hb = self.workers.heartbeat(pb::HeartbeatRequest {
                        worker_id: me.id,
                        lease_ids: span_ids(lease).collect(),
                        session: me.session.clone(),
                        paused: String::new(),
                    }).await;
                    dropped = match hb {
                        Ok(r) => !r.into_inner().dropped.is_empty(),
                        Err(s) if matches!(s.code(), Code::Unauthenticated | Code::PermissionDenied) => true,
                        Err(s) => {
                            tracing::warn!("heartbeat failed: {}", s.message());
                            false
                        }
                    };
                    if dropped {
                        cancel.store(true, Ordering::Relaxed);
                    }
                }
                r = self.paused.changed(), if !pausing && watched => match r {
                    // The watcher stopped (the worker is stopping).
                    Err(_) => watched = false,
                    Ok(()) => if self.paused.borrow().is_some() {
                        pausing = true;
                        cancel.store(true, Ordering::Relaxed);
                    }
                },
                r = shutdown.changed(), if !stopping => {
                    // A closed channel means the sender is gone: stop too.
                    if r.is_err() || *shutdown.borrow() {
                        stopping = true;
                        cancel.store(true, Ordering::Relaxed);
                    }
                }
            }
        }
    }

    /// The built scene for `hash`, from the cache or fetched and built.
    async fn scene(
        &mut self,
        cache: &mut SceneCache,
        hash: &str,
    ) -> Result<Arc<Scene>, SceneLoadError> {
        if let Some(s) = cache.get(hash) {
            return Ok(s);
        }
        let scene = Arc::new(self.build(hash).await?);
        cache.put(hash.to_string(), scene.clone());
        Ok(scene)
    }

    /// The scene for `hash` at frame `frame` of `camera`: kept from an
    /// earlier lease, or a kept one moved to the frame, or built (see
    /// [`scenes`]).
    async fn frame_scene(
        &mut self,
        cache: &mut SceneCache,
        hash: &str,
        camera: &str,
        frame: u32,
    ) -> Result<Arc<Scene>, SceneLoadError> {
        let mut scene = match cache.frames.take(hash, camera, frame) {
            scenes::Found::Ready(s) => return Ok(s),
            scenes::Found::Reuse(s) => *s,
            scenes::Found::Miss => self.build(hash).await?,
        };
        let cam = scene.camera_index(camera).ok_or_else(|| {
            SceneLoadError::Frame(format!("the scene has no camera \"{camera}\""))
        })?;
        let start = std::time::Instant::now();
        let scene = tokio::task::spawn_blocking(move || {
            scene
                .set_frame(cam, frame)
                .map(|()| scene)
                .map_err(|e| SceneLoadError::Frame(e.to_string()))
        })
        .await??;
        tracing::info!(bundle = %hash, frame, set_up_us = start.elapsed().as_micros() as u64,
            "scene moved to the frame");
        let scene = Arc::new(scene);
        cache.frames.put(hash, camera, frame, scene.clone());
        Ok(scene)
    }

    /// Fetches bundle `hash` and builds its scene.
    async fn build(&mut self, hash: &str) -> Result<Scene, SceneLoadError> {
        let start = std::time::Instant::now();
        let mut stream = self
            .bundles
            .download_bundle(pb::BundleRef {
                hash: hash.to_string(),
                size: 0,
            })
            .await
            .map_err(SceneLoadError::Download)?
            .into_inner();
        let mut bytes = Vec::new();
        while let Some(c) = stream.message().await.map_err(SceneLoadError::Download)? {
            bytes.extend_from_slice(&c.data);
        }
        let want = hash.to_string();
        let limit = self.max_memory;
        let scene = tokio::task::spawn_blocking(move || -> Result<Scene, SceneLoadError> {
            let got = trevi_core::bundle::sha256_hex(&bytes);
            if got != want {
                return Err(SceneLoadError::HashMismatch { want, got });
            }
            let bundle = Bundle::decode(&bytes)?;
            drop(bytes);
            let desc = trevi_core::ParsedBundle::parse(bundle)?.desc;
            // Checked before the build, which is what takes the memory.
            let needs = trevi_core::scene::estimate::estimate(&desc).total();
            if !limit.allows(needs) {
                return Err(SceneLoadError::TooBig { needs, limit });
            }
            Ok(Scene::build(desc))
        })
        .await??;
        let memory = trevi_core::texture::SceneMemory::of(&scene.desc);
        tracing::info!(
            bundle = %hash,
            mesh_bytes = memory.meshes,
            texture_bytes = memory.textures,
            set_up_us = start.elapsed().as_micros() as u64,
            "scene built"
        );
        Ok(scene)
    }

    async fn send(
        &mut self,
        me: &Me,
        lease: &pb::Lease,
        rect: Rect,
        rendered: Rendered,
        payload: Payload,
    ) -> Result<bool, tonic::Status> {
        let msgs = match payload {
            Payload::Floats(pixels) => {
                tile_messages(me.id, &me.session, lease, rect, rendered, &pixels)
            }
            Payload::Segments(encoded) => {
                segments::segment_messages(me.id, &me.session, lease, rect, rendered, encoded)
            }
        };
        let ack = self
            .workers
            .submit_tile(tokio_stream::iter(msgs))
            .await?
            .into_inner();
        Ok(ack.accepted)
    }
}

/// The leases of a lease's tiles: `lease_id` and, for a span of several
/// tiles (`tiles` > 1), the ids after it, one per tile.
fn span_ids(lease: &pb::Lease) -> impl Iterator<Item = u64> {
    // A span is never wider than a band: the bound only keeps a confused
    // coordinator from making us heartbeat millions of ids.
    let n = lease.tiles.clamp(1, 1 << 16);
    let first = lease.lease_id;
    (0..u64::from(n)).map(move |i| first + i)
}

/// What a render of a lease's rectangle reports besides its pixels.
#[derive(Debug, Clone, Copy)]
pub struct Rendered {
    /// Rays traced.
    pub rays: u64,
    /// Time spent rendering (not loading the scene or waiting): the
    /// coordinator sizes the job's leases from it.
    pub took: Duration,
}

/// The messages of a tile upload: the header, then the pixels in chunks.
pub fn tile_messages(
    worker: u64,
    session: &[u8],
    lease: &pb::Lease,
    rect: Rect,
    rendered: Rendered,
    pixels: &[[f32; 3]],
) -> Vec<pb::TileUpload> {
    use pb::tile_upload::Part;
    let bytes = pixels_to_bytes(pixels);
    let mut msgs = vec![header_message(worker, session, lease, rect, rendered)];
    msgs.extend(bytes.chunks(CHUNK_SIZE).map(|c| pb::TileUpload {
        part: Some(Part::Pixels(c.to_vec())),
    }));
    msgs
}

/// The first message of an upload, floats or segments: the header.
pub(crate) fn header_message(
    worker: u64,
    session: &[u8],
    lease: &pb::Lease,
    rect: Rect,
    rendered: Rendered,
) -> pb::TileUpload {
    pb::TileUpload {
        part: Some(pb::tile_upload::Part::Header(pb::TileHeader {
            worker_id: worker,
            lease_id: lease.lease_id,
            job_id: lease.job_id,
            rect: Some(rect.into()),
            rays: rendered.rays,
            session: session.to_vec(),
            frame: lease.frame,
            render_micros: Some(rendered.took.as_micros().min(u128::from(u64::MAX)) as u64),
        })),
    }
}
