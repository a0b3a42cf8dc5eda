//! Where a leased tile is rendered: its scene loaded ([`crate::scene_load`]),
//! the rectangle rendered on the render threads (and, for a segment lease,
//! checked and encoded there, [`crate::segments`]) while the lease is
//! heartbeated. The render stops within a pixel when the coordinator drops
//! the lease, the worker pauses or `shutdown` turns true; a render that
//! panics becomes a failure of the tile, not of the worker.

use crate::error::SceneLoadError;
use crate::scene_cache::Key;
use crate::segments;
use crate::session::{span_ids, Me, Session};
use crate::upload::Payload;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::watch;
use tonic::Code;
use trevi_core::Rect;
use trevi_proto::pb;

/// How working on one leased tile ended.
pub(crate) enum TileEnd {
    /// The result, the rays traced, and how long the render itself took
    /// (told to the coordinator, which sizes leases from it).
    Rendered(Payload, u64, Duration),
    /// The coordinator no longer wants it (the job was cancelled or the
    /// lease expired): the render was stopped.
    Dropped,
    /// `shutdown` turned true: the render was stopped.
    Stopped,
    /// The worker stepped aside (see [`crate::pause`]): the render was stopped.
    Paused,
    /// The scene could not be loaded, or the render panicked.
    Failed(String),
    /// The scene needs about this many bytes, more than `--max-memory`:
    /// declined without building it (see [`crate::memory`]).
    Declined(u64),
}

/// Sets a render's cancellation flag when dropped, so a loop aborted midway
/// (the session ends) does not leave its render running.
struct CancelOnDrop(Arc<AtomicBool>);

impl Drop for CancelOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

/// The message of a caught panic.
fn panic_message(p: &(dyn std::any::Any + Send)) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".to_string())
}

impl Session {
    /// Loads the scene and renders the tile while heartbeating its lease;
    /// stops the render when the lease is dropped, the worker pauses or
    /// `shutdown` turns true.
    pub(crate) async fn tile(
        &mut self,
        me: &Me,
        lease: &pb::Lease,
        rect: Rect,
        beat: Duration,
        shutdown: &mut watch::Receiver<bool>,
    ) -> TileEnd {
        let cancel = Arc::new(AtomicBool::new(false));
        let _guard = CancelOnDrop(cancel.clone());
        let work = {
            let mut s = self.clone();
            let cancel = cancel.clone();
            let camera = lease.camera.clone();
            let key = match lease.frame {
                None => Key::still(&lease.bundle_hash),
                Some(f) => Key::frame(&lease.bundle_hash, &camera, f),
            };
            #[cfg(feature = "test-hooks")]
            let fault = self.fault;
            async move {
                let scene = s.scene(key).await;
                let scene = match scene {
                    Ok(s) => s,
                    Err(SceneLoadError::TooBig { needs, .. }) => return TileEnd::Declined(needs),
                    Err(e) => return TileEnd::Failed(format!("cannot load the scene: {e}")),
                };
                let Some(camera) = scene.camera_index(&camera) else {
                    return TileEnd::Failed(format!("the scene has no camera \"{camera}\""));
                };
                let pool = s.pool.clone();
                // For a segment lease: the frame's size and the preview's
                // cell edge, to check the rect and encode it.
                let segments = lease.png_segments.then(|| {
                    let r = &scene.desc.cameras[camera].render;
                    (r.width, r.height, lease.preview_scale)
                });
                let job = tokio::task::spawn_blocking(move || {
                    pool.install(|| {
                        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                            #[cfg(feature = "test-hooks")]
                            if let Some(f) = fault {
                                f.strike(rect);
                            }
                            let start = std::time::Instant::now();
                            let r = trevi_core::tile::render_tile_cancellable(
                                &scene, camera, rect, &cancel,
                            )?;
                            // The encoding counts as the lease's render time:
                            // it is the worker's time that the coordinator
                            // sizes leases from.
                            let payload = match segments {
                                None => Ok(Payload::Floats(r.pixels)),
                                Some((w, h, scale)) => {
                                    segments::encode_rect(rect, w, h, scale, &r.pixels)
                                        .map(Payload::Segments)
                                }
                            };
                            Ok((payload, r.rays, start.elapsed()))
                        }))
                    })
                });
                match job.await {
                    Ok(Ok(Ok((Ok(payload), rays, took)))) => TileEnd::Rendered(payload, rays, took),
                    Ok(Ok(Ok((Err(e), ..)))) => TileEnd::Failed(e.to_string()),
                    Ok(Ok(Err(trevi_core::tile::Cancelled))) => TileEnd::Dropped,
                    Ok(Err(panic)) => TileEnd::Failed(format!(
                        "the render panicked: {}",
                        panic_message(panic.as_ref())
                    )),
                    Err(e) => TileEnd::Failed(format!("the render task failed: {e}")),
                }
            }
        };
        tokio::pin!(work);
        let (mut dropped, mut stopping, mut pausing) = (false, false, false);
        let mut watched = true;
        let mut tick = tokio::time::interval(beat);
        tick.tick().await;
        loop {
            tokio::select! {
                end = &mut work => {
                    return match end {
                        _ if stopping => TileEnd::Stopped,
                        TileEnd::Dropped if pausing => TileEnd::Paused,
                        TileEnd::Rendered(..) if dropped => TileEnd::Dropped,
                        end => end,
                    };
                }
                _ = tick.tick(), if !dropped && !stopping => {
                    let hb = self.workers.heartbeat(pb::HeartbeatRequest {
                        worker_id: me.id,
                        lease_ids: span_ids(lease).collect(),
                        session: me.session.clone(),
                        paused: String::new(),
                    }).await;
                    dropped = match hb {
                        Ok(r) => !r.into_inner().dropped.is_empty(),
                        Err(s) if matches!(s.code(), Code::Unauthenticated | Code::PermissionDenied) => true,
                        Err(s) => {
                            tracing::warn!("heartbeat failed: {}", s.message());
                            false
                        }
                    };
                    if dropped {
                        cancel.store(true, Ordering::Relaxed);
                    }
                }
                r = self.paused.changed(), if !pausing && watched => match r {
                    // The watcher stopped (the worker is stopping).
                    Err(_) => watched = false,
                    Ok(()) => if self.paused.borrow().is_some() {
                        pausing = true;
                        cancel.store(true, Ordering::Relaxed);
                    }
                },
                r = shutdown.changed(), if !stopping => {
                    // A closed channel means the sender is gone: stop too.
                    if r.is_err() || *shutdown.borrow() {
                        stopping = true;
                        cancel.store(true, Ordering::Relaxed);
                    }
                }
            }
        }
    }
}
