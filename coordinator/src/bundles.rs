//! Scene bundles on disk, addressed by the hex SHA-256 of their encoding.

use crate::error::FarmError;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use trevi_core::Bundle;

/// A directory of bundles named by hash.
pub struct BundleStore {
    dir: PathBuf,
}

static TEMP: AtomicU64 = AtomicU64::new(0);

/// Whether `hash` looks like a hex SHA-256 (and so is a safe file name).
pub fn is_hash(hash: &str) -> bool {
    hash.len() == 64 && hash.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f'))
}

impl BundleStore {
    pub fn open(dir: &Path) -> Result<Self, FarmError> {
        std::fs::create_dir_all(dir)
            .map_err(|e| FarmError::Io(format!("cannot create {}: {e}", dir.display())))?;
        Ok(BundleStore {
            dir: dir.to_path_buf(),
        })
    }

    fn path(&self, hash: &str) -> Result<PathBuf, FarmError> {
        if !is_hash(hash) {
            return Err(FarmError::UnknownBundle(hash.to_string()));
        }
        Ok(self.dir.join(hash))
    }

    /// Checks and stores an uploaded bundle encoding; returns its hash.
    pub fn put(&self, bytes: &[u8]) -> Result<String, FarmError> {
        self.put_limited(bytes, usize::MAX)
    }

    /// [`BundleStore::put`] refusing bundles of more than `max_files` files.
    pub fn put_limited(&self, bytes: &[u8], max_files: usize) -> Result<String, FarmError> {
        let bundle = Bundle::decode(bytes).map_err(FarmError::BadBundle)?;
        if bundle.files.len() > max_files {
            return Err(FarmError::Limit(format!(
                "the bundle holds {} files, more than the coordinator's limit of {max_files} \
                 (--max-bundle-files)",
                bundle.files.len()
            )));
        }
        let hash = trevi_core::bundle::sha256_hex(bytes);
        debug_assert_eq!(hash, bundle.hash());
        let path = self.path(&hash)?;
        if !path.exists() {
            let tmp = self.dir.join(format!(
                ".upload-{}-{}",
                std::process::id(),
                TEMP.fetch_add(1, Ordering::Relaxed)
            ));
            let io = |e: std::io::Error| FarmError::Io(format!("storing bundle {hash}: {e}"));
            std::fs::write(&tmp, bytes).map_err(io)?;
            std::fs::rename(&tmp, &path).map_err(io)?;
        }
        Ok(hash)
    }

    /// The encoded bundle with this hash, checked against it (a file
    /// damaged on disk is an error, never served or rendered).
    pub fn get_bytes(&self, hash: &str) -> Result<Vec<u8>, FarmError> {
        let bytes = std::fs::read(self.path(hash)?)
            .map_err(|_| FarmError::UnknownBundle(hash.to_string()))?;
        let got = trevi_core::bundle::sha256_hex(&bytes);
        if got != hash {
            return Err(FarmError::BadBundle(format!(
                "the stored bundle {hash} is damaged (its content hashes to {got})"
            )));
        }
        Ok(bytes)
    }

    pub fn get(&self, hash: &str) -> Result<Bundle, FarmError> {
        Bundle::decode(&self.get_bytes(hash)?).map_err(FarmError::BadBundle)
    }
}
