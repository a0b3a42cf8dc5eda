//! The scenes a worker keeps between leases ([`SceneCache`]).
//!
//! Building a scene (download its bundle, parse it, build every mesh's BVH)
//! is what a lease costs before its first ray, so the worker keeps the last
//! few it built, each under a [`Key`]: its bundle's hash and, for a lease of
//! a sequence's frame (`Lease.frame`), the camera and frame it was moved
//! to, and, for a pass of a job with its own samples per pixel
//! (`Lease.samples.total` above 0), the camera and that total
//! (`Scene::set_samples`; a job without it never gets such a scene). A
//! still's scene is kept as built; a frame's is moved from frame to frame
//! with `Scene::set_frame`, which rebuilds only what a frame changes
//! (instance transforms, the top-level trees, cameras, lights).
//!
//! A lookup ([`SceneCache::take`]) finds the scene at that very key; for a
//! frame it may instead hand out a frame scene of the same bundle and the
//! same samples at another frame that no render is using, to be moved in
//! place and put back. One in
//! use (another lease of the same bundle rendering meanwhile) is left alone
//! and another copy is built. At most `cap` stills' scenes and `cap` frames'
//! scenes are kept, the least recently used of each going first, so the
//! memory is bounded whatever the number of jobs and frames.

use std::num::NonZeroUsize;
use std::sync::Arc;
use trevi_core::Scene;

/// The cache as the loops of every session share it.
pub(crate) type SharedScenes = Arc<tokio::sync::Mutex<SceneCache>>;

/// Which scene an entry holds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Key {
    /// The hash of the scene's bundle.
    pub hash: String,
    /// The camera and frame the scene was moved to (`None`: as built, for
    /// a still).
    pub frame: Option<(String, u32)>,
    /// The camera and samples per pixel `Scene::set_samples` gave it
    /// (`None`: the scene's own sampling).
    pub samples: Option<(String, u32)>,
}

impl Key {
    /// The scene of bundle `hash` as built.
    pub fn still(hash: &str) -> Key {
        Key {
            hash: hash.to_string(),
            frame: None,
            samples: None,
        }
    }

    /// The scene of bundle `hash` at frame `frame` of camera `camera`.
    pub fn frame(hash: &str, camera: &str, frame: u32) -> Key {
        Key {
            hash: hash.to_string(),
            frame: Some((camera.to_string(), frame)),
            samples: None,
        }
    }

    /// This key's scene with camera `camera` rendering `total` samples per
    /// pixel (`Scene::set_samples`); a `total` of 0 is the scene's own
    /// sampling, this very key.
    pub fn with_samples(self, camera: &str, total: u32) -> Key {
        Key {
            samples: (total > 0).then(|| (camera.to_string(), total)),
            ..self
        }
    }
}

/// What [`SceneCache::take`] found.
pub enum Found {
    /// The scene at that very key.
    Ready(Arc<Scene>),
    /// For a frame: a scene of that bundle and samples at another frame,
    /// no longer in use: move it with `Scene::set_frame` (and give it the
    /// samples again) and [`SceneCache::put`] it back.
    Reuse(Box<Scene>),
    /// Nothing to reuse: build the scene.
    Miss,
}

struct Entry {
    key: Key,
    scene: Arc<Scene>,
}

/// Built scenes, most recently used last.
pub struct SceneCache {
    /// The most entries kept of each kind (stills, frames).
    cap: NonZeroUsize,
    entries: Vec<Entry>,
}

impl SceneCache {
    /// An empty cache keeping up to `cap` stills' scenes and `cap` frames'.
    pub fn new(cap: NonZeroUsize) -> Self {
        SceneCache {
            cap,
            entries: Vec::new(),
        }
    }

    /// The scene at `key`, or (for a frame) one to move there, or
    /// [`Found::Miss`].
    pub fn take(&mut self, key: &Key) -> Found {
        if let Some(i) = self.entries.iter().position(|e| e.key == *key) {
            let e = self.entries.remove(i);
            let s = e.scene.clone();
            self.entries.push(e);
            return Found::Ready(s);
        }
        if key.frame.is_none() {
            return Found::Miss;
        }
        let free = self.entries.iter().position(|e| {
            e.key.frame.is_some()
                && e.key.hash == key.hash
                && e.key.samples == key.samples
                && Arc::strong_count(&e.scene) == 1
        });
        if let Some(i) = free {
            let e = self.entries.remove(i);
            if let Ok(scene) = Arc::try_unwrap(e.scene) {
                return Found::Reuse(Box::new(scene));
            }
        }
        Found::Miss
    }

    /// Keeps `scene` under `key`, making room by dropping the least
    /// recently used entry of the same kind (still or frame).
    pub fn put(&mut self, key: Key, scene: Arc<Scene>) {
        let same_kind = |e: &Entry| e.key.frame.is_some() == key.frame.is_some();
        if self.entries.iter().filter(|&e| same_kind(e)).count() >= self.cap.get() {
            if let Some(oldest) = self.entries.iter().position(same_kind) {
                self.entries.remove(oldest);
            }
        }
        self.entries.push(Entry { key, scene });
    }

    #[cfg(test)]
    fn len(&self) -> usize {
        self.entries.len()
    }
}

#[cfg(test)]
mod tests;
