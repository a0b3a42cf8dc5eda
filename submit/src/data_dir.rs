//! The embedded coordinator's data directory: a temporary one, removed at
//! the end, or a kept one for local renders `extend` continues later
//! (kept.rs says which renders keep theirs, and where).

use anyhow::{bail, Context, Result};
use std::fs::File;
use std::path::{Path, PathBuf};
use trevi_coordinator::dir_lock::{lock_data_dir, DirLockError};

/// The embedded coordinator's data directory.
pub enum DataDir {
    /// A `trevi-submit-*` directory in the system's temporary directory,
    /// removed when dropped. Made before the async runtime and dropped after
    /// it, so no task of the embedded farm still writes into it while it is
    /// removed.
    Temporary(tempfile::TempDir),
    /// A kept directory (`--local-dir`, see kept.rs), locked for this
    /// process while held.
    Kept {
        /// The directory.
        path: PathBuf,
        /// The coordinator's lock on it.
        _lock: File,
    },
}

impl DataDir {
    /// A new temporary directory.
    pub fn temporary() -> Result<DataDir> {
        let dir = tempfile::Builder::new()
            .prefix("trevi-submit-")
            .tempdir()
            .context("cannot create a temporary directory")?;
        Ok(DataDir::Temporary(dir))
    }

    /// The kept directory `dir`, made if missing and locked; refused when
    /// it is not a directory or another process uses it.
    pub fn kept(dir: &Path) -> Result<DataDir> {
        if dir.exists() && !dir.is_dir() {
            bail!(
                "--local-dir {}: not a directory (a local render with --samples keeps its job \
                 there for `trevi-submit extend`)",
                dir.display()
            );
        }
        let lock = lock_data_dir(dir).map_err(|e| match e {
            DirLockError::InUse { pid, .. } => anyhow::anyhow!(
                "another trevi-submit{} is rendering with the local directory {}: wait for it \
                 to end, or give this one another --local-dir (and give `extend` the same \
                 --local-dir later)",
                pid.map(|p| format!(" (PID {p})")).unwrap_or_default(),
                dir.display()
            ),
            e => anyhow::Error::new(e),
        })?;
        Ok(DataDir::Kept {
            path: dir.to_path_buf(),
            _lock: lock,
        })
    }

    /// The directory's path.
    pub fn path(&self) -> &Path {
        match self {
            DataDir::Temporary(t) => t.path(),
            DataDir::Kept { path, .. } => path,
        }
    }

    /// Whether it outlives this process.
    pub fn is_kept(&self) -> bool {
        matches!(self, DataDir::Kept { .. })
    }
}
