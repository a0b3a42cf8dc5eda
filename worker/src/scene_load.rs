//! Where a leased tile's scene comes from: the scene cache
//! ([`crate::scene_cache`]), or its bundle downloaded by hash, checked
//! (SHA-256, the memory estimate against `--max-memory`) and built, then
//! moved to the lease's frame for a sequence.

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
    /// scene is built once however many loops want it.
    pub(crate) async fn scene(&mut self, key: Key) -> Result<Arc<Scene>, SceneLoadError> {
        let scenes = self.scenes.clone();
        let mut cache = scenes.lock().await;
        let scene = match cache.take(&key) {
            Found::Ready(s) => return Ok(s),
            Found::Reuse(s) => *s,
            Found::Miss => self.build(&key.hash).await?,
        };
        let scene = match &key.frame {
            None => scene,
            Some((camera, frame)) => to_frame(scene, &key.hash, camera, *frame).await?,
        };
        let scene = Arc::new(scene);
        cache.put(key, scene.clone());
        Ok(scene)
    }

    /// Fetches bundle `hash` and builds its scene.
    async fn build(&mut self, hash: &str) -> Result<Scene, SceneLoadError> {
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
        let scene = tokio::task::spawn_blocking(move || -> Result<Scene, SceneLoadError> {
            let got = trevi_core::bundle::sha256_hex(&bytes);
            if got != want {
                return Err(SceneLoadError::HashMismatch { want, got });
            }
            let bundle = Bundle::decode(&bytes)?;
            drop(bytes);
            let desc = trevi_core::ParsedBundle::parse(bundle)?.desc;
            // Checked before the build, which is what takes the memory.
            let needs = trevi_core::scene::estimate::estimate(&desc).total();
            if !limit.allows(needs) {
                return Err(SceneLoadError::TooBig { needs, limit });
            }
            Ok(Scene::build(desc))
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

/// Moves `scene` (of bundle `hash`) to frame `frame` of `camera`.
async fn to_frame(
    mut scene: Scene,
    hash: &str,
    camera: &str,
    frame: u32,
) -> Result<Scene, SceneLoadError> {
    let cam = scene
        .camera_index(camera)
        .ok_or_else(|| SceneLoadError::Frame(format!("the scene has no camera \"{camera}\"")))?;
    let start = std::time::Instant::now();
    let scene = tokio::task::spawn_blocking(move || {
        scene
            .set_frame(cam, frame)
            .map(|()| scene)
            .map_err(|e| SceneLoadError::Frame(e.to_string()))
    })
    .await??;
    tracing::info!(bundle = %hash, frame, set_up_us = start.elapsed().as_micros() as u64,
        "scene moved to the frame");
    Ok(scene)
}
