//! What one session with the coordinator shares between its loops
//! ([`Session`]: the clients, the render threads, the pause and the scene
//! cache), who the coordinator registered us as ([`Me`]), and how a session
//! ends ([`End`]).
//!
//! A session begins at each registration (`run.rs`); its loops are in
//! their own files: leasing tiles (`lease.rs`), rendering one
//! (`render.rs`), loading its scene (`scene_load.rs`), sending it
//! (`upload.rs`) and reporting a pause (`machine.rs`).

use crate::cpu::RenderClocks;
use crate::memory::MaxMemory;
use crate::pause::Pause;
use crate::scene_cache::SharedScenes;
use std::sync::Arc;
use tokio::sync::watch;
use trevi_proto::pb::{self, bundles_client::BundlesClient, workers_client::WorkersClient};
use trevi_proto::AuthChannel;

/// The handles a session's loops share (each loop has its own clone).
#[derive(Clone)]
pub(crate) struct Session {
    pub(crate) workers: WorkersClient<AuthChannel>,
    pub(crate) bundles: BundlesClient<AuthChannel>,
    pub(crate) pool: Arc<rayon::ThreadPool>,
    pub(crate) threads: usize,
    /// The render threads' CPU clocks (see [`crate::cpu`]).
    pub(crate) clocks: RenderClocks,
    /// One permit: the tile that has the render threads. A loop takes it
    /// before leasing and gives it up once its tile is rendered, so the
    /// others send their results meanwhile but never hold a lease they are
    /// not working on.
    pub(crate) render: Arc<tokio::sync::Semaphore>,
    /// Why the worker steps aside now (none: it works); see
    /// [`pause`](crate::pause).
    pub(crate) paused: watch::Receiver<Option<Pause>>,
    /// The most memory one scene may take; see [`memory`](crate::memory).
    pub(crate) max_memory: MaxMemory,
    /// The built scenes, shared by every session of the worker.
    pub(crate) scenes: SharedScenes,
    /// Tests only: the tile whose render fails.
    #[cfg(feature = "test-hooks")]
    pub(crate) fault: Option<crate::TestFault>,
}

/// Who the coordinator registered us as.
#[derive(Clone)]
pub(crate) struct Me {
    pub(crate) id: u64,
    pub(crate) session: Vec<u8>,
}

/// Why a session with the coordinator ended.
pub(crate) enum End {
    Shutdown,
    /// Connection lost or coordinator restarted: connect and register again.
    Reconnect(String),
}

/// The session ends on a failed call `what`: reconnect, saying why.
pub(crate) fn reconnect(what: &str, s: tonic::Status) -> End {
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

/// The leases of a lease's tiles: `lease_id` and, for a span of several
/// tiles (`tiles` > 1), the ids after it, one per tile.
pub(crate) fn span_ids(lease: &pb::Lease) -> impl Iterator<Item = u64> {
    // A span is never wider than a band: the bound only keeps a confused
    // coordinator from making us heartbeat millions of ids.
    let n = lease.tiles.clamp(1, 1 << 16);
    let first = lease.lease_id;
    (0..u64::from(n)).map(move |i| first + i)
}
