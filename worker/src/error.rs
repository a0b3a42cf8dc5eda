//! Why the worker stops ([`WorkerError`]) and why a leased tile's scene
//! cannot be loaded ([`SceneLoadError`]).

use crate::memory::MaxMemory;
use trevi_core::scene::estimate::human_bytes;

/// Why [`run`](fn@crate::run) could not start or had to give up.
#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    /// The coordinator's address (or its TLS settings) cannot make an
    /// endpoint.
    #[error(transparent)]
    Endpoint(#[from] trevi_proto::EndpointError),
    /// The coordinator's TLS certificate is not trusted or not for its name:
    /// retrying cannot help. `why` is the transport error's chain of causes
    /// on one line, without tonic's repetitions (see
    /// [`trevi_proto::connect::error_chain`]).
    #[error("cannot connect to {coordinator}: {why}")]
    Certificate {
        /// The coordinator's address, as given.
        coordinator: String,
        /// What was wrong with its certificate.
        why: String,
    },
    /// The render thread pool could not be made.
    #[error("cannot start {threads} render threads")]
    Pool {
        /// How many threads were asked for.
        threads: usize,
        /// Why rayon could not start them.
        source: rayon::ThreadPoolBuildError,
    },
    /// The worker's token cannot travel in an `authorization` header.
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
    HashMismatch {
        /// The hash the lease named (hex SHA-256).
        want: String,
        /// The hash of the bytes received (hex SHA-256).
        got: String,
    },
    /// The bytes are not a bundle encoding.
    #[error(transparent)]
    Bundle(#[from] trevi_core::bundle::BundleError),
    /// The bundle's scene does not parse or build.
    #[error(transparent)]
    Scene(#[from] trevi_core::SceneError),
    /// The blocking task that builds the scene panicked or was cancelled.
    #[error(transparent)]
    Task(#[from] tokio::task::JoinError),
    /// The scene's estimate (with a pass's accumulation state, `state`
    /// bytes of `needs`, see [`crate::memory::pass_state_bytes`]) exceeds
    /// the worker's `--max-memory`: not built.
    #[error("the scene needs about {} of memory{}, more than --max-memory {}",
        human_bytes(*.needs), with_state(*.state), human_bytes(.limit.0))]
    TooBig {
        /// The estimate in bytes, the pass's state included.
        needs: u64,
        /// The part of `needs` that is a pass's accumulation state (0
        /// outside progressive jobs).
        state: u64,
        /// The worker's `--max-memory`.
        limit: MaxMemory,
    },
    /// The scene cannot be moved to the lease's frame.
    #[error("cannot move the scene to the frame: {0}")]
    Frame(String),
    /// The lease's pass names a camera the scene does not have.
    #[error("the scene has no camera \"{0}\" to give the pass's samples")]
    NoCamera(String),
}

/// The part of [`SceneLoadError::TooBig`]'s message for a pass's state.
fn with_state(state: u64) -> String {
    if state == 0 {
        String::new()
    } else {
        format!(
            " (the pass's accumulation state's {} included)",
            human_bytes(state)
        )
    }
}
