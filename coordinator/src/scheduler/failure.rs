//! Why a job failed ([`JobFailure`]), and a job's outcome ([`Outcome`]):
//! what the scheduler and the farm pass around when a job ends, by cause;
//! its sentence is what `status` shows and the database keeps (a job read
//! back after a restart has the sentence only).

/// A job's end: done (its output in place) or failed, and why.
pub type Outcome = Result<(), JobFailure>;

/// Why a job failed, by cause. The sentence (`Display`) is the job's
/// `error` as users see it.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum JobFailure {
    /// Its tiles failed or lost their workers too often
    /// (`Limits::max_tile_failures`, `max_tile_losses`), or every live
    /// worker is kept from it (`max_worker_failures`).
    #[error("{0}")]
    Tiles(String),
    /// No live worker has the memory its scene needs, past the grace
    /// (`Limits::memory_grace`).
    #[error("{0}")]
    Memory(String),
    /// Its bundle's stored copy is damaged or gone.
    #[error("{0}")]
    Bundle(String),
    /// The coordinator could not write its output or its stored tiles (a
    /// full or failing disk), or resume it after a restart.
    #[error("{0}")]
    Output(String),
    /// A frame or a pass of it failed (for a sequence or a progressive
    /// job), naming which and why.
    #[error("{0}")]
    Part(String),
    /// A job it waited for (`--after`) failed or was cancelled, naming it
    /// and why.
    #[error("{0}")]
    After(String),
}

impl JobFailure {
    /// The sentence users see (the job's `error`).
    pub fn message(&self) -> String {
        self.to_string()
    }
}
