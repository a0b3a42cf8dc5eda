//! Where a leased tile's scene comes from: the scene cache
//! ([`crate::scene_cache`]), or its bundle downloaded by hash, checked
//! (SHA-256, the memory estimate against `--max-memory`) and built, then
//! moved to the lease's frame for a sequence and given a pass's samples per
//! pixel (`Scene::set_samples`) for a job with its own.

use crate::error::SceneLoadError;
use crate::scene_cache::{Found, Key};
use crate::session::Session;
use std::sync::Arc;
use trevi_core::{Bundle, Scene};
use trevi_proto::pb;

impl Session {
    /// The scene at `key`: kept from an earlier lease, or a kept one moved
    /// to the key's frame, or fetched and built (see
    /// [`crate::scene_cache`]). The cache stays locked meanwhile, so a
    /// scene is built once however many loops want it. `state`: the bytes
    /// a pass's accumulation state holds besides the scene
    /// ([`crate::memory::pass_state_bytes`], 0 for other leases), counted
    /// with the scene's estimate against `--max-memory` before a build.
    pub(crate) async fn scene(
        &mut self,
        key: Key,
        state: u64,
    ) -> Result<Arc<Scene>, SceneLoadError> {
        let scenes = self.scenes.clone();
        let mut cache = scenes.lock().await;
        let scene = match cache.take(&key) {
            Found::Ready(s) => return Ok(s),
            Found::Reuse(s) => *s,
            Found::Miss => self.build(&key.hash, state).await?,
        };
        let scene = if key.frame.is_none() && key.samples.is_none() {
            scene
        } else {
            to_key(scene, &key, &self.pool).await?
        };
        let scene = Arc::new(scene);
        cache.put(key, scene.clone());
        Ok(scene)
    }

    /// Fetches bundle `hash` and builds its scene, unless its estimate and
    /// `state` bytes together pass `--max-memory`.
    async fn build(&mut self, hash: &str, state: u64) -> Result<Scene, SceneLoadError> {
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
        // On the render threads (under `Session::render`'s permit): at
        // their priority, and counted in the lease's CPU time
        // ([`crate::cpu`]), the BVH build's parallel parts included.
        let pool = self.pool.clone();
        let scene = tokio::task::spawn_blocking(move || {
            pool.install(|| -> Result<Scene, SceneLoadError> {
                let got = trevi_core::bundle::sha256_hex(&bytes);
                if got != want {
                    return Err(SceneLoadError::HashMismatch { want, got });
                }
                let bundle = Bundle::decode(&bytes)?;
                drop(bytes);
                let desc = trevi_core::ParsedBundle::parse(bundle)?.desc;
                // Checked before the build, which is what takes the memory.
                let needs = trevi_core::scene::estimate::estimate(&desc)
                    .total()
                    .saturating_add(state);
                if !limit.allows(needs) {
                    return Err(SceneLoadError::TooBig {
                        needs,
                        state,
                        limit,
                    });
                }
                Ok(Scene::build(desc))
            })
        })
        .await??;
        let memory = trevi_core::scene::memory::SceneMemory::of(&scene.desc);
        tracing::info!(
            bundle = %hash,
            mesh_bytes = memory.meshes,
            texture_bytes = memory.textures,
            set_up_us = start.elapsed().as_micros() as u64,
            "scene built"
        );
        Ok(scene)
    }
}

/// Moves `scene` to `key`'s frame and gives it `key`'s samples, on the
/// render threads `pool` (as a build is).
async fn to_key(
    mut scene: Scene,
    key: &Key,
    pool: &Arc<rayon::ThreadPool>,
) -> Result<Scene, SceneLoadError> {
    let start = std::time::Instant::now();
    let moved = key.clone();
    let pool = pool.clone();
    let scene = tokio::task::spawn_blocking(move || {
        pool.install(|| apply_key(&mut scene, &moved).map(|()| scene))
    })
    .await??;
    if let Some((_, frame)) = &key.frame {
        tracing::info!(bundle = %key.hash, frame, set_up_us = start.elapsed().as_micros() as u64,
            "scene moved to the frame");
    }
    Ok(scene)
}

/// Makes a scene as built into `key`'s: moved to its frame
/// (`Scene::set_frame`), then, for a pass with its own total, that camera
/// given `min-samples = max-samples = total` (`Scene::set_samples`, which a
/// move does not undo: it is applied after). A scene at another frame of
/// the same key's bundle and samples may be given too (a reused one).
pub(crate) fn apply_key(scene: &mut Scene, key: &Key) -> Result<(), SceneLoadError> {
    if let Some((camera, frame)) = &key.frame {
        let cam = scene.camera_index(camera).ok_or_else(|| {
            SceneLoadError::Frame(format!("the scene has no camera \"{camera}\""))
        })?;
        scene
            .set_frame(cam, *frame)
            .map_err(|e| SceneLoadError::Frame(e.to_string()))?;
    }
    if let Some((camera, total)) = &key.samples {
        let cam = scene
            .camera_index(camera)
            .ok_or_else(|| SceneLoadError::NoCamera(camera.clone()))?;
        scene.set_samples(cam, *total);
    }
    Ok(())
}
