//! Where a leased tile is rendered: its scene loaded ([`crate::scene_load`]),
//! the rectangle rendered on the render threads (and, for a segment lease,
//! checked and encoded there, [`crate::segments`]) while the lease is
//! heartbeated. A pass of a progressive job (`Lease.samples`,
//! [`crate::pass`]) fetches the state it continues (or starts a new one) and
//! renders its range on it instead. The render (or the fetch) stops when the
//! coordinator drops the lease, the worker pauses or `shutdown` turns true;
//! a render that panics becomes a failure of the tile, not of the worker.

use crate::cpu::CpuMeter;
use crate::error::SceneLoadError;
use crate::memory;
use crate::pass::{self, Pass, PassError};
use crate::scene_cache::Key;
use crate::segments;
use crate::session::{span_ids, Me, Session};
use crate::upload::{Payload, Pixels, Rendered};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::watch;
use tonic::Code;
use trevi_core::passes::TileState;
use trevi_core::{Aovs, Rect};
use trevi_proto::pb;

/// How working on one leased tile ended.
pub(crate) enum TileEnd {
    /// The result, and what its render reports (rays, time, CPU time).
    Rendered(Payload, Rendered),
    /// The coordinator no longer wants it (the job was cancelled or the
    /// lease expired): the render was stopped.
    Dropped,
    /// `shutdown` turned true: the render was stopped.
    Stopped,
    /// The worker stepped aside (see [`crate::pause`]): the render was stopped.
    Paused,
    /// The scene could not be loaded, the pass's state was refused, or the
    /// render panicked.
    Failed(String),
    /// Fetching the pass's state failed on the connection or the session
    /// ([`pass::connection_lost`]): the session ends, as after the worker's
    /// other calls.
    Lost(tonic::Status),
    /// The scene needs about this many bytes, more than `--max-memory`:
    /// declined without building it (see [`crate::memory`]).
    Declined(u64),
}

/// A render's cancellation: the flag the render polls, and the same news
/// for a fetch to wait on.
#[derive(Clone)]
struct Cancel {
    flag: Arc<AtomicBool>,
    said: Arc<watch::Sender<bool>>,
}

impl Cancel {
    fn new() -> Self {
        Cancel {
            flag: Arc::new(AtomicBool::new(false)),
            said: Arc::new(watch::channel(false).0),
        }
    }

    fn set(&self) {
        self.flag.store(true, Ordering::Relaxed);
        self.said.send_replace(true);
    }

    /// Returns once [`Cancel::set`] was called.
    async fn wait(&self) {
        let mut said = self.said.subscribe();
        // The sender lives as long as `self`: no error.
        let _ = said.wait_for(|&c| c).await;
    }
}

/// Sets a render's cancellation when dropped, so a loop aborted midway
/// (the session ends) does not leave its render running.
struct CancelOnDrop(Cancel);

impl Drop for CancelOnDrop {
    fn drop(&mut self) {
        self.0.set();
    }
}

/// Why a render on the render threads did not give a payload.
pub(crate) enum Stop {
    Cancelled,
    Failed(String),
}

/// The message of a caught panic.
fn panic_message(p: &(dyn std::any::Any + Send)) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".to_string())
}

impl Session {
    /// Loads the scene and renders the tile (or the pass `pass` on its
    /// fetched state) while heartbeating its lease; stops the render when
    /// the lease is dropped, the worker pauses or `shutdown` turns true.
    pub(crate) async fn tile(
        &mut self,
        me: &Me,
        lease: &pb::Lease,
        rect: Rect,
        pass: Option<Pass>,
        beat: Duration,
        shutdown: &mut watch::Receiver<bool>,
    ) -> TileEnd {
        #[cfg(feature = "test-hooks")]
        if let Some(why) = crate::test_hooks::job_fault(lease.job_id) {
            return TileEnd::Failed(why);
        }
        let cancel = Cancel::new();
        let _guard = CancelOnDrop(cancel.clone());
        let work = {
            let mut s = self.clone();
            let cancel = cancel.clone();
            let camera = lease.camera.clone();
            let key = match lease.frame {
                None => Key::still(&lease.bundle_hash),
                Some(f) => Key::frame(&lease.bundle_hash, &camera, f),
            };
            let key = match pass {
                Some(p) => key.with_samples(&camera, p.total),
                None => key,
            };
            let state_bytes = pass.map_or(0, |_| memory::pass_state_bytes(rect));
            let (me, lease_id) = (me.clone(), lease.lease_id);
            let (png, preview_scale) = (lease.png_segments, lease.preview_scale);
            let aovs = Aovs::parse(&lease.aovs);
            #[cfg(feature = "test-hooks")]
            let fault = self.fault;
            async move {
                // From here to the render's end the render threads are this
                // lease's (see `crate::cpu`): the scene's build counts too.
                let clocks = s.clocks.clone();
                let meter = CpuMeter::start(&clocks);
                let scene = s.scene(key, state_bytes).await;
                let scene = match scene {
                    Ok(s) => s,
                    Err(SceneLoadError::TooBig { needs, .. }) => return TileEnd::Declined(needs),
                    Err(e) => return TileEnd::Failed(format!("cannot load the scene: {e}")),
                };
                let Some(camera) = scene.camera_index(&camera) else {
                    return TileEnd::Failed(format!("the scene has no camera \"{camera}\""));
                };
                let aovs = match aovs {
                    Ok(a) => a,
                    Err(e) => return TileEnd::Failed(format!("the lease's render passes: {e}")),
                };
                // A pass's state: fetched (bounded) unless it starts at 0.
                let pass = match pass {
                    Some(p) if p.start > 0 => {
                        let fetched = tokio::select! {
                            r = s.fetch_state(&me, lease_id, rect) => r,
                            () = cancel.wait() => return TileEnd::Dropped,
                        };
                        match fetched {
                            Ok(bytes) => Some((p, Some(bytes))),
                            Err(PassError::Fetch { status, .. })
                                if pass::connection_lost(&status) =>
                            {
                                return TileEnd::Lost(status)
                            }
                            Err(e) => return TileEnd::Failed(e.to_string()),
                        }
                    }
                    Some(p) => Some((p, None)),
                    None => None,
                };
                let pool = s.pool.clone();
                // For a segment lease: the frame's size and the preview's
                // cell edge, to check the rect and encode it.
                let segments = png.then(|| {
                    let r = &scene.desc.cameras[camera].render;
                    (r.width, r.height, preview_scale)
                });
                let job = tokio::task::spawn_blocking(move || {
                    pool.install(|| {
                        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                            #[cfg(feature = "test-hooks")]
                            if let Some(f) = fault {
                                f.strike(rect);
                            }
                            render_lease_aovs(
                                &scene,
                                camera,
                                rect,
                                lease_id,
                                pass,
                                segments,
                                aovs,
                                &cancel.flag,
                            )
                        }))
                    })
                });
                match job.await {
                    Ok(Ok(Ok((payload, rays, took)))) => TileEnd::Rendered(
                        payload,
                        Rendered {
                            rays,
                            took,
                            cpu_micros: meter.micros(),
                        },
                    ),
                    Ok(Ok(Err(Stop::Failed(e)))) => TileEnd::Failed(e),
                    Ok(Ok(Err(Stop::Cancelled))) => TileEnd::Dropped,
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
                        cancel.set();
                    }
                }
                r = self.paused.changed(), if !pausing && watched => match r {
                    // The watcher stopped (the worker is stopping).
                    Err(_) => watched = false,
                    Ok(()) => if self.paused.borrow().is_some() {
                        pausing = true;
                        cancel.set();
                    }
                },
                r = shutdown.changed(), if !stopping => {
                    // A closed channel means the sender is gone: stop too.
                    if r.is_err() || *shutdown.borrow() {
                        stopping = true;
                        cancel.set();
                    }
                }
            }
        }
    }
}

/// Renders lease `lease_id`'s `rect` of camera `camera` on the current rayon
/// pool: at once, or `pass` on its state (`Some(bytes)`: fetched, checked
/// here; `None`: a new one). Gives the payload (floats, or for a segment
/// lease, `segments` = the frame's size and the preview's cell edge, the
/// encoded segments), the rays traced and the time it took (the state's
/// decoding aside: like loading the scene, it is not the render).
#[cfg(test)]
pub(crate) fn render_lease(
    scene: &trevi_core::Scene,
    camera: usize,
    rect: Rect,
    lease_id: u64,
    pass: Option<(Pass, Option<Vec<u8>>)>,
    segments: Option<(u32, u32, u32)>,
    cancel: &AtomicBool,
) -> Result<(Payload, u64, Duration), Stop> {
    render_lease_aovs(
        scene,
        camera,
        rect,
        lease_id,
        pass,
        segments,
        Aovs::NONE,
        cancel,
    )
}

/// [`render_lease`] with the lease's render passes `aovs` (`Lease.aovs`):
/// rendered with the beauty from the same samples
/// (`trevi_core::tile::render_tile_aovs`) and uploaded after its floats.
/// The coordinator never asks for them with segments or a pass.
#[allow(clippy::too_many_arguments)]
pub(crate) fn render_lease_aovs(
    scene: &trevi_core::Scene,
    camera: usize,
    rect: Rect,
    lease_id: u64,
    pass: Option<(Pass, Option<Vec<u8>>)>,
    segments: Option<(u32, u32, u32)>,
    aovs: Aovs,
    cancel: &AtomicBool,
) -> Result<(Payload, u64, Duration), Stop> {
    if !aovs.is_empty() && (pass.is_some() || segments.is_some()) {
        return Err(Stop::Failed(format!(
            "a lease with render passes \"{aovs}\" cannot be {}",
            if pass.is_some() {
                "a progressive pass"
            } else {
                "encoded PNG segments"
            }
        )));
    }
    let failed = |e: PassError| match e {
        PassError::Cancelled => Stop::Cancelled,
        e => Stop::Failed(e.to_string()),
    };
    let pass = match pass {
        None => None,
        Some((p, None)) => Some((p, TileState::new(rect))),
        Some((p, Some(bytes))) => {
            let state = pass::accept_state(lease_id, rect, p.start, &bytes).map_err(failed)?;
            drop(bytes);
            Some((p, state))
        }
    };
    let start = std::time::Instant::now();
    // Counted as render time: the coordinator sizes leases by it.
    #[cfg(feature = "test-hooks")]
    crate::test_hooks::lease_delay();
    if !aovs.is_empty() {
        let (r, values) = trevi_core::tile::render_tile_aovs(scene, camera, rect, aovs, cancel)
            .map_err(|trevi_core::tile::Cancelled| Stop::Cancelled)?;
        let pixels = Pixels::WithAovs(r.pixels, values.values);
        return Ok((
            Payload {
                pixels,
                state: None,
            },
            r.rays,
            start.elapsed(),
        ));
    }
    let (pixels, rays, state) = match pass {
        None => {
            let r = trevi_core::tile::render_tile_cancellable(scene, camera, rect, cancel)
                .map_err(|trevi_core::tile::Cancelled| Stop::Cancelled)?;
            (r.pixels, r.rays, None)
        }
        Some((p, state)) => {
            let done =
                pass::render_pass(scene, camera, lease_id, p, state, cancel).map_err(failed)?;
            (done.pixels, done.rays, Some(done.state))
        }
    };
    // The encoding counts as the lease's render time: it is the worker's
    // time that the coordinator sizes leases from.
    let pixels = match segments {
        None => Pixels::Floats(pixels),
        Some((w, h, scale)) => Pixels::Segments(
            segments::encode_rect(rect, w, h, scale, &pixels)
                .map_err(|e| Stop::Failed(e.to_string()))?,
        ),
    };
    Ok((Payload { pixels, state }, rays, start.elapsed()))
}
