//! A pass of a progressive job: a lease with `samples` (`Lease.samples`,
//! docs/progressive.md) renders sample indices `start..end` of every pixel
//! of its rect, continuing an accumulation state
//! ([`trevi_core::passes::TileState`]), and uploads the finished pixels and
//! then the new state (`crate::upload::state_messages`).
//!
//! - [`Pass::check`]: the lease's range, checked before anything is
//!   loaded: `start < end`, `total` (when above 0, the job's own samples
//!   per pixel, `Scene::set_samples`) at most [`MAX_SAMPLES`] and at least
//!   `end`, the rect at most [`MAX_STATE_PIXELS`] pixels.
//! - The state: a new one when `start` is 0; otherwise fetched
//!   (`FetchState`) with [`read_state`], which holds at most
//!   `TileState::encoded_len(rect)` bytes (a longer stream is refused with
//!   the lease and the bound named, before its excess is kept), and checked
//!   with [`accept_state`]: it decodes, and its rect and `next` are the
//!   lease's rect and `start`. Any failure fails the lease, which goes back
//!   with the error; a fetch that fails on the connection ([`connection_lost`])
//!   ends the session like the worker's other calls.
//! - [`render_pass`]: the range rendered on the state (on a copy: a
//!   cancelled pass leaves nothing behind, and nothing is uploaded), the
//!   pixels finished, the state encoded.
//!
//! Memory: a state is 64 bytes a pixel, held at most twice at once (the
//! fetched bytes and the decoded state; the state and the copy a pass
//! renders on; the state and its encoding; the encoding and its upload
//! chunks): [`crate::memory::pass_state_bytes`], counted against
//! `--max-memory` with the scene.

use crate::session::{Me, Session};
use std::sync::atomic::AtomicBool;
use tokio_stream::{Stream, StreamExt};
use trevi_core::passes::{self, TileState, MAX_SAMPLES, MAX_STATE_PIXELS};
use trevi_core::{Rect, Scene};
use trevi_proto::pb;

/// A lease's sample range, checked ([`Pass::check`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Pass {
    /// The first sample index rendered: the state's `next`.
    pub(crate) start: u32,
    /// The sample index after the last one rendered.
    pub(crate) end: u32,
    /// The job's own samples per pixel (`Scene::set_samples`); 0: the
    /// scene's own.
    pub(crate) total: u32,
}

/// Why a pass lease cannot be rendered: the lease goes back with this as
/// its error (except [`PassError::Cancelled`], which gives it back
/// unrendered, and a [`PassError::Fetch`] that [`connection_lost`] says is
/// the connection's, which ends the session).
#[derive(Debug, thiserror::Error)]
pub enum PassError {
    #[error("lease {lease}: the samples {start}..{end} are an empty or reversed range")]
    Range { lease: u64, start: u32, end: u32 },
    #[error(
        "lease {lease}: a total of {total} samples per pixel is more than the {MAX_SAMPLES} \
         a job may ask for"
    )]
    Total { lease: u64, total: u32 },
    #[error(
        "lease {lease}: the samples {start}..{end} go past the job's {total} samples per pixel"
    )]
    PastTotal {
        lease: u64,
        start: u32,
        end: u32,
        total: u32,
    },
    #[error(
        "lease {lease}: its rect of {pixels} pixels is more than the {MAX_STATE_PIXELS} an \
         accumulation state may hold"
    )]
    TooManyPixels { lease: u64, pixels: u64 },
    /// `FetchState` answered with an error, or its stream broke off.
    #[error("lease {lease}: cannot fetch its accumulation state: {}: {}", .status.code(), .status.message())]
    Fetch { lease: u64, status: tonic::Status },
    #[error(
        "lease {lease}: the accumulation state sent is longer than the {bound} bytes of a \
         state of its rect"
    )]
    TooLong { lease: u64, bound: usize },
    #[error("lease {lease}: the accumulation state sent is not one: {source}")]
    Decode {
        lease: u64,
        source: passes::StateError,
    },
    #[error(
        "lease {lease}: the accumulation state sent is of the rect {}x{} at ({}, {}), \
         not the lease's {}x{} at ({}, {})",
        .got.w, .got.h, .got.x, .got.y, .want.w, .want.h, .want.x, .want.y
    )]
    OtherRect { lease: u64, want: Rect, got: Rect },
    #[error(
        "lease {lease}: the accumulation state sent has the samples 0..{next}, but the pass \
         starts at {start}"
    )]
    OtherNext { lease: u64, start: u32, next: u32 },
    /// The range does not fit the scene's sampling (`start` not the state's
    /// `next`, or `end` past the camera's samples per pixel).
    #[error("lease {lease}: {source}")]
    Render {
        lease: u64,
        source: passes::PassError,
    },
    /// The lease was dropped, the worker paused or is stopping: the state
    /// is unchanged and nothing is uploaded.
    #[error("the pass was cancelled")]
    Cancelled,
}

impl Pass {
    /// Lease `lease`'s range `r` over `rect`, or why it is not one this
    /// worker renders.
    pub(crate) fn check(lease: u64, rect: Rect, r: pb::SampleRange) -> Result<Pass, PassError> {
        let (start, end, total) = (r.start, r.end, r.total);
        if end <= start {
            return Err(PassError::Range { lease, start, end });
        }
        if total > MAX_SAMPLES {
            return Err(PassError::Total { lease, total });
        }
        if total > 0 && end > total {
            return Err(PassError::PastTotal {
                lease,
                start,
                end,
                total,
            });
        }
        let pixels = u64::from(rect.w) * u64::from(rect.h);
        if pixels > MAX_STATE_PIXELS {
            return Err(PassError::TooManyPixels { lease, pixels });
        }
        Ok(Pass { start, end, total })
    }
}

/// Whether a failed `FetchState` is the connection's or the session's (a
/// transport error, the coordinator unreachable, the session refused)
/// rather than the coordinator's answer about this lease: then the worker
/// connects and registers again, as after its other calls, and the lease
/// runs out on the coordinator; otherwise the lease fails.
pub(crate) fn connection_lost(s: &tonic::Status) -> bool {
    use tonic::Code;
    // A status made from a transport or HTTP/2 error carries it as its
    // source; one the coordinator sent has none.
    matches!(
        s.code(),
        Code::Unavailable | Code::Unauthenticated | Code::PermissionDenied
    ) || std::error::Error::source(s).is_some()
}

/// Reads lease `lease`'s accumulation state from `chunks` (a `FetchState`
/// stream), holding at most `TileState::encoded_len(rect)` bytes: a
/// stream longer than that is refused as soon as a chunk would pass the
/// bound, before that chunk is kept. `rect` must have passed
/// [`Pass::check`].
pub(crate) async fn read_state<S>(
    lease: u64,
    rect: Rect,
    mut chunks: S,
) -> Result<Vec<u8>, PassError>
where
    S: Stream<Item = Result<pb::StateChunk, tonic::Status>> + Unpin,
{
    let bound = TileState::encoded_len(rect);
    let mut bytes = Vec::new();
    while let Some(chunk) = chunks.next().await {
        let chunk = chunk.map_err(|status| PassError::Fetch { lease, status })?;
        if chunk.data.len() > bound - bytes.len() {
            return Err(PassError::TooLong { lease, bound });
        }
        if bytes.is_empty() {
            // The whole state at once: its length is the bound, unless the
            // coordinator sends a wrong one, which decoding then refuses.
            bytes.reserve_exact(bound);
        }
        bytes.extend_from_slice(&chunk.data);
    }
    Ok(bytes)
}

impl Session {
    /// Fetches lease `lease`'s accumulation state (`FetchState`) with
    /// [`read_state`]: at most the encoded length of a state of `rect`.
    pub(crate) async fn fetch_state(
        &mut self,
        me: &Me,
        lease: u64,
        rect: Rect,
    ) -> Result<Vec<u8>, PassError> {
        let chunks = self
            .workers
            .fetch_state(pb::StateRequest {
                worker_id: me.id,
                session: me.session.clone(),
                lease_id: lease,
            })
            .await
            .map_err(|status| PassError::Fetch { lease, status })?
            .into_inner();
        read_state(lease, rect, chunks).await
    }
}

/// The state in `bytes` if it is lease `lease`'s to continue: it decodes
/// (every check of `TileState::decode`), its rect is `rect` and its
/// `next` is the pass's `start`.
pub(crate) fn accept_state(
    lease: u64,
    rect: Rect,
    start: u32,
    bytes: &[u8],
) -> Result<TileState, PassError> {
    let state = TileState::decode(bytes).map_err(|source| PassError::Decode { lease, source })?;
    if state.rect() != rect {
        return Err(PassError::OtherRect {
            lease,
            want: rect,
            got: state.rect(),
        });
    }
    if state.next() != start {
        return Err(PassError::OtherNext {
            lease,
            start,
            next: state.next(),
        });
    }
    Ok(state)
}

/// What a pass leaves: the finished pixels (row by row), the rays traced,
/// and the new state's encoding (`next` = the pass's `end`).
pub(crate) struct Passed {
    pub(crate) pixels: Vec<[f32; 3]>,
    pub(crate) rays: u64,
    pub(crate) state: Vec<u8>,
}

/// Renders `pass` of lease `lease` on `state` (of camera `camera` of
/// `scene`, the scene already given the pass's total), on the current
/// rayon pool; soon after `cancel` turns true it gives up with
/// [`PassError::Cancelled`].
pub(crate) fn render_pass(
    scene: &Scene,
    camera: usize,
    lease: u64,
    pass: Pass,
    mut state: TileState,
    cancel: &AtomicBool,
) -> Result<Passed, PassError> {
    let rays = state
        .render(scene, camera, pass.start..pass.end, cancel)
        .map_err(|e| match e {
            passes::PassError::Cancelled(_) => PassError::Cancelled,
            source => PassError::Render { lease, source },
        })?;
    let pixels = state.finish();
    let encoded = state.encode();
    Ok(Passed {
        pixels,
        rays,
        state: encoded,
    })
}

#[cfg(test)]
mod fetch_tests;
#[cfg(test)]
mod tests;
