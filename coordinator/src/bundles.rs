//! Scene bundles on disk, addressed by the hex SHA-256 of their encoding.
//!
//! - An upload streams into a temporary file `.upload-*` in the bundles
//!   directory, hashed as it is written ([`Upload`]); it is checked from the
//!   file ([`trevi_core::bundle::check_encoding`], memory: one path and a
//!   read buffer) and then renamed to its hash. A failed or abandoned upload
//!   removes its temporary file; temporary files left by a crash are swept
//!   when the store opens.
//! - Uploading a hash already stored replaces the stored copy with the new
//!   one (verified by its hash while it was written), so a copy damaged on
//!   disk is repaired by uploading the right bytes again.
//! - Reading a bundle checks its hash, so a damaged copy is an error, never
//!   served or rendered ([`BundleStore::open_verified`]).
//! - Garbage collection ([`BundleStore::collect`]): a bundle is removed when
//!   no job the coordinator knows of uses it (queued, running, or ended and
//!   not yet pruned) and it was last uploaded or used longer ago than a grace
//!   period, so a bundle uploaded for a job about to be submitted is kept.

use crate::error::FarmError;
use sha2::{Digest, Sha256};
use std::collections::HashSet;
use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::{Duration, SystemTime};
use trevi_core::Bundle;

/// A directory of bundles named by hash.
pub struct BundleStore {
    dir: PathBuf,
    /// Held while a bundle file is put in place, marked as used, or checked
    /// and removed by [`BundleStore::collect`], so the collector never
    /// removes a copy that was just uploaded or used.
    files: Mutex<()>,
}

static TEMP: AtomicU64 = AtomicU64::new(0);

/// The prefix of the temporary file of an upload in progress.
const TEMP_PREFIX: &str = ".upload-";

/// Whether `hash` looks like a hex SHA-256 (and so is a safe file name).
pub fn is_hash(hash: &str) -> bool {
    hash.len() == 64 && hash.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f'))
}

/// An upload being written to its temporary file. Dropped without
/// [`BundleStore::finish_upload`] (an error, a stalled or vanished client),
/// it removes the file.
pub struct Upload {
    path: PathBuf,
    file: std::fs::File,
    hasher: Sha256,
    size: u64,
}

impl Upload {
    /// Appends `data` to the file and the hash.
    pub fn write(&mut self, data: &[u8]) -> Result<(), FarmError> {
        self.file
            .write_all(data)
            .map_err(|e| FarmError::io("storing an uploaded bundle", e))?;
        self.hasher.update(data);
        self.size += data.len() as u64;
        Ok(())
    }

    /// Bytes written so far.
    pub fn size(&self) -> u64 {
        self.size
    }
}

impl Drop for Upload {
    fn drop(&mut self) {
        // After a successful finish the path no longer exists.
        let _ = std::fs::remove_file(&self.path);
    }
}

/// A stored copy whose content hashes to `got` instead of `hash` is damaged.
fn check_hash(hash: &str, got: &str) -> Result<(), FarmError> {
    if got == hash {
        return Ok(());
    }
    Err(FarmError::BadBundle(format!(
        "the stored bundle {hash} is damaged (its content hashes to {got}); upload it again to \
         repair it"
    )))
}

fn lock(m: &Mutex<()>) -> std::sync::MutexGuard<'_, ()> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl BundleStore {
    /// Opens (creating) the directory and removes the temporary files of
    /// uploads a previous run left behind.
    pub fn open(dir: &Path) -> Result<Self, FarmError> {
        std::fs::create_dir_all(dir)
            .map_err(|e| FarmError::io(format!("cannot create {}", dir.display()), e))?;
        let store = BundleStore {
            dir: dir.to_path_buf(),
            files: Mutex::new(()),
        };
        let swept = store.sweep_temp_files();
        if swept > 0 {
            tracing::info!(
                files = swept,
                "removed unfinished uploads of an earlier run"
            );
        }
        Ok(store)
    }

    /// Removes every `.upload-*` file (none of this process's uploads is
    /// running yet when called from [`BundleStore::open`]).
    fn sweep_temp_files(&self) -> usize {
        let Ok(entries) = std::fs::read_dir(&self.dir) else {
            return 0;
        };
        entries
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().starts_with(TEMP_PREFIX))
            .filter(|e| std::fs::remove_file(e.path()).is_ok())
            .count()
    }

    fn path(&self, hash: &str) -> Result<PathBuf, FarmError> {
        if !is_hash(hash) {
            return Err(FarmError::UnknownBundle(hash.to_string()));
        }
        Ok(self.dir.join(hash))
    }

    /// Starts an upload: a new temporary file in the bundles directory.
    pub fn begin_upload(&self) -> Result<Upload, FarmError> {
        let path = self.dir.join(format!(
            "{TEMP_PREFIX}{}-{}",
            std::process::id(),
            TEMP.fetch_add(1, Ordering::Relaxed)
        ));
        let file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&path)
            .map_err(|e| FarmError::io(format!("cannot create {}", path.display()), e))?;
        Ok(Upload {
            path,
            file,
            hasher: Sha256::new(),
            size: 0,
        })
    }

    /// Checks a complete upload from its file (at most `max_files` files)
    /// and stores it under its hash, replacing any copy already there (which
    /// repairs a damaged one). Returns the hash.
    pub fn finish_upload(&self, mut up: Upload, max_files: usize) -> Result<String, FarmError> {
        let io = |e: std::io::Error| FarmError::io("storing an uploaded bundle", e);
        up.file.sync_all().map_err(io)?;
        let read = std::fs::File::open(&up.path).map_err(io)?;
        let files = trevi_core::bundle::check_encoding(read)
            .map_err(|e| FarmError::BadBundle(e.to_string()))?;
        if files > max_files as u64 {
            return Err(FarmError::limit(
                crate::error::LimitKind::BundleFiles,
                files,
                max_files as u64,
                format!(
                    "the bundle holds {files} files, more than the coordinator's limit of \
                 {max_files} (--max-bundle-files)"
                ),
            ));
        }
        let hash = hex::encode(std::mem::take(&mut up.hasher).finalize());
        let path = self.path(&hash)?;
        let _files = lock(&self.files);
        std::fs::rename(&up.path, &path).map_err(io)?;
        Ok(hash)
    }

    /// Opens the stored file of `hash` and marks the bundle as used (see
    /// [`BundleStore::collect`]); a missing file is
    /// [`FarmError::UnknownBundle`], any other error [`FarmError::Io`].
    fn open_used(&self, hash: &str) -> Result<std::fs::File, FarmError> {
        let path = self.path(hash)?;
        let _files = lock(&self.files);
        // Only a missing file is "no bundle": any other error (too many
        // open files, permissions, a failing disk) says what it is and
        // fails no job (see `crate::grpc`).
        let file = std::fs::File::open(&path).map_err(|e| match e.kind() {
            std::io::ErrorKind::NotFound => FarmError::UnknownBundle(hash.to_string()),
            _ => FarmError::io(format!("opening the stored bundle {hash}"), e),
        })?;
        // Only the collector reads this time; failing to set it is harmless.
        let _ = file.set_modified(SystemTime::now());
        Ok(file)
    }

    /// The stored bundle file with this hash, open at its start, after
    /// checking its content against the hash (reading it once, a piece at a
    /// time), and its size. A damaged copy is [`FarmError::BadBundle`]
    /// saying so.
    pub fn open_verified(&self, hash: &str) -> Result<(std::fs::File, u64), FarmError> {
        let mut file = self.open_used(hash)?;
        let io = |e: std::io::Error| FarmError::io(format!("reading the stored bundle {hash}"), e);
        let mut hasher = Sha256::new();
        let mut buf = vec![0u8; 1 << 20];
        let mut size = 0u64;
        loop {
            let n = file.read(&mut buf).map_err(io)?;
            if n == 0 {
                break;
            }
            hasher.update(&buf[..n]);
            size += n as u64;
        }
        check_hash(hash, &hex::encode(hasher.finalize()))?;
        file.rewind().map_err(io)?;
        Ok((file, size))
    }

    /// The encoded bundle with this hash, checked against it (a file
    /// damaged on disk is an error, never served or rendered).
    pub fn get_bytes(&self, hash: &str) -> Result<Vec<u8>, FarmError> {
        let mut bytes = Vec::new();
        self.open_used(hash)?
            .read_to_end(&mut bytes)
            .map_err(|e| FarmError::io(format!("reading the stored bundle {hash}"), e))?;
        check_hash(hash, &trevi_core::bundle::sha256_hex(&bytes))?;
        Ok(bytes)
    }

    /// The decoded bundle (held in memory whole: at most the coordinator's
    /// bundle size limit, once per call).
    pub fn get(&self, hash: &str) -> Result<Bundle, FarmError> {
        Bundle::decode(&self.get_bytes(hash)?).map_err(|e| FarmError::BadBundle(e.to_string()))
    }

    /// Removes the bundles whose hash is not in `keep` and that were last
    /// uploaded or used more than `grace` ago. Returns how many went.
    pub fn collect(&self, keep: &HashSet<String>, grace: Duration) -> usize {
        let Ok(entries) = std::fs::read_dir(&self.dir) else {
            return 0;
        };
        let now = SystemTime::now();
        let mut removed = 0;
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if !is_hash(&name) || keep.contains(&name) {
                continue;
            }
            let _files = lock(&self.files);
            let old = e
                .metadata()
                .and_then(|m| m.modified())
                .ok()
                .and_then(|t| now.duration_since(t).ok())
                .is_some_and(|age| age > grace);
            if old && std::fs::remove_file(e.path()).is_ok() {
                tracing::info!(bundle = %name, "removed a bundle no job uses");
                removed += 1;
            }
        }
        removed
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    fn bundle(text: &str) -> Vec<u8> {
        let mut files = BTreeMap::new();
        files.insert("s.xml".to_string(), text.as_bytes().to_vec());
        Bundle {
            scene: "s.xml".into(),
            files,
        }
        .encode()
    }

    /// Stores a bundle encoding held in memory as an upload would; returns
    /// its hash.
    fn put(store: &BundleStore, bytes: &[u8]) -> Result<String, FarmError> {
        let mut up = store.begin_upload()?;
        up.write(bytes)?;
        store.finish_upload(up, usize::MAX)
    }

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn a_failed_or_abandoned_upload_leaves_no_file_and_a_restart_sweeps_old_ones() {
        let tmp = tempfile::tempdir().unwrap();
        let store = BundleStore::open(tmp.path()).unwrap();
        // Refused on validation.
        let mut up = store.begin_upload().unwrap();
        up.write(b"not a bundle").unwrap();
        assert!(matches!(
            store.finish_upload(up, 10),
            Err(FarmError::BadBundle(_))
        ));
        // Over the file limit.
        let mut up = store.begin_upload().unwrap();
        up.write(&bundle("<scene/>")).unwrap();
        assert!(matches!(
            store.finish_upload(up, 0),
            Err(FarmError::Limit(_))
        ));
        // Abandoned half way.
        let mut up = store.begin_upload().unwrap();
        up.write(&bundle("<scene/>")[..10]).unwrap();
        drop(up);
        assert_eq!(names(tmp.path()), Vec::<String>::new());
        // A crash's leftovers go when the store opens again.
        std::fs::write(tmp.path().join(".upload-1-2"), b"half").unwrap();
        let hash = put(&store, &bundle("<scene/>")).unwrap();
        drop(store);
        let _store = BundleStore::open(tmp.path()).unwrap();
        assert_eq!(names(tmp.path()), vec![hash]);
    }

    #[test]
    fn uploading_again_repairs_a_damaged_copy() {
        let tmp = tempfile::tempdir().unwrap();
        let store = BundleStore::open(tmp.path()).unwrap();
        let bytes = bundle("<scene/>");
        let hash = put(&store, &bytes).unwrap();
        assert_eq!(store.get_bytes(&hash).unwrap(), bytes);
        let mut bad = bytes.clone();
        *bad.last_mut().unwrap() ^= 1;
        std::fs::write(tmp.path().join(&hash), &bad).unwrap();
        let e = store.open_verified(&hash).unwrap_err();
        assert!(e.to_string().contains("damaged"), "{e}");
        assert_eq!(put(&store, &bytes).unwrap(), hash);
        assert_eq!(store.get_bytes(&hash).unwrap(), bytes);
    }

    #[test]
    fn collection_keeps_bundles_in_use_or_young() {
        let tmp = tempfile::tempdir().unwrap();
        let store = BundleStore::open(tmp.path()).unwrap();
        let used = put(&store, &bundle("<scene>a</scene>")).unwrap();
        let unused = put(&store, &bundle("<scene>b</scene>")).unwrap();
        let keep: HashSet<String> = [used.clone()].into();
        // Young: kept even though no job uses it.
        assert_eq!(store.collect(&keep, Duration::from_secs(3600)), 0);
        // Older than the grace period and unused: removed.
        let old = SystemTime::now() - Duration::from_secs(7200);
        for h in [&used, &unused] {
            let f = std::fs::File::options()
                .write(true)
                .open(tmp.path().join(h))
                .unwrap();
            f.set_modified(old).unwrap();
        }
        assert_eq!(store.collect(&keep, Duration::from_secs(3600)), 1);
        assert_eq!(names(tmp.path()), vec![used.clone()]);
        // Using a bundle makes it young again.
        let f = std::fs::File::options()
            .write(true)
            .open(tmp.path().join(&used))
            .unwrap();
        f.set_modified(old).unwrap();
        store.open_verified(&used).unwrap();
        assert_eq!(store.collect(&HashSet::new(), Duration::from_secs(3600)), 0);
    }
}
