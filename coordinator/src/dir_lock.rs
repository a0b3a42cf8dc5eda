//! One coordinator per data directory: [`lock_data_dir`] takes an exclusive
//! `flock` on `DIR/coordinator.lock`, held for as long as the process runs
//! (the kernel lets go when it exits, however it exits), and writes its PID
//! into the file so that a second coordinator's refusal names the first.
//! Two coordinators on one directory would hand out the same job ids and
//! overwrite each other's outputs.

use std::fs::File;
use std::io::{Read, Seek, Write};
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};

/// The lock file's name in the data directory.
pub const LOCK_FILE: &str = "coordinator.lock";

/// Why the data directory could not be locked.
#[derive(Debug, thiserror::Error)]
pub enum DirLockError {
    /// Another process holds the lock.
    #[error(
        "another coordinator{} is using the data directory {} (it holds {}); stop it, or \
         give this one another --data-dir",
        .pid.map(|p| format!(" (PID {p})")).unwrap_or_default(),
        .dir.display(),
        LOCK_FILE
    )]
    InUse {
        /// The data directory.
        dir: PathBuf,
        /// The holder's PID, as it wrote it in the lock file (`None` when
        /// the file holds no number).
        pid: Option<u32>,
    },
    /// Creating the directory, or opening, locking or writing the lock
    /// file failed.
    #[error("cannot lock the data directory {}: {source}", .dir.display())]
    Io {
        /// The data directory.
        dir: PathBuf,
        /// The system's error.
        source: std::io::Error,
    },
}

/// Locks `dir` (created if missing) for this process; keep the file to
/// keep the lock.
pub fn lock_data_dir(dir: &Path) -> Result<File, DirLockError> {
    let io = |source| DirLockError::Io {
        dir: dir.to_path_buf(),
        source,
    };
    std::fs::create_dir_all(dir).map_err(io)?;
    let mut file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(dir.join(LOCK_FILE))
        .map_err(io)?;
    // SAFETY: flock on a descriptor this function owns; no memory is shared.
    let r = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
    if r != 0 {
        let e = std::io::Error::last_os_error();
        if e.raw_os_error() == Some(libc::EWOULDBLOCK) {
            let mut text = String::new();
            // A short read of a small file; the PID is only a courtesy.
            let _ = (&file).take(32).read_to_string(&mut text);
            return Err(DirLockError::InUse {
                dir: dir.to_path_buf(),
                pid: text.trim().parse().ok(),
            });
        }
        return Err(io(e));
    }
    file.set_len(0).map_err(io)?;
    file.rewind().map_err(io)?;
    writeln!(file, "{}", std::process::id()).map_err(io)?;
    Ok(file)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_lock_is_refused_naming_the_holder_and_a_released_one_is_taken() {
        let dir = tempfile::tempdir().unwrap();
        let first = lock_data_dir(dir.path()).unwrap();
        // flock locks belong to the open file: a second open is refused
        // like another process would be.
        let e = lock_data_dir(dir.path()).unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains(&format!("PID {}", std::process::id())) && msg.contains("--data-dir"),
            "{msg}"
        );
        drop(first);
        lock_data_dir(dir.path()).unwrap();
    }
}
