//! The worker's settings ([`WorkerConfig`]) and their defaults.
//!
//! `trevi-worker` fills them from its flags (`src/main.rs`); `trevi-submit`
//! fills them for the worker it runs in its own process (a local render).

use crate::memory::MaxMemory;
use crate::pause::PauseConfig;
use crate::priority::Priority;
use std::num::NonZeroUsize;
use std::sync::Arc;
use std::time::Duration;
use trevi_core::Scene;

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
    /// hours (nothing watched by default; see [`pause`](crate::pause)).
    pub pause: PauseConfig,
    /// The most memory one scene may take ([`memory`](crate::memory)); no limit by
    /// default here (an in-process worker renders what its user asked
    /// for), while `trevi-worker` defaults to a share of the machine's RAM
    /// ([`MaxMemory::default_for_this_machine`]).
    pub max_memory: MaxMemory,
    /// Tests only: make the render of one tile fail (see
    /// [`TestFault`](crate::TestFault); the `test-hooks` feature).
    #[cfg(feature = "test-hooks")]
    #[doc(hidden)]
    pub test_fault: Option<crate::TestFault>,
}

/// A scene built before the worker starts, and the hash of its bundle (see
/// [`WorkerConfig::preloaded`]).
#[derive(Clone)]
pub struct Preloaded {
    /// The bundle's hash (hex SHA-256), as leases name it.
    pub hash: String,
    /// The scene built from that bundle, used for every lease naming it.
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
            #[cfg(feature = "test-hooks")]
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
