//! Where a rendered tile is uploaded: the `SubmitTile` stream of a lease's
//! result, as floats ([`tile_messages`]) or, for a lease with
//! `png_segments`, as the encoded segments and preview sums
//! ([`segment_messages`], encoded by [`crate::segments`]). Both start with
//! the same header ([`header_message`]). A pass of a progressive job
//! (`Lease.samples`, [`crate::pass`]) then sends its new accumulation state
//! in chunks ([`state_messages`]).

use crate::segments::EncodedRect;
use crate::session::{Me, Session};
use std::time::Duration;
use trevi_core::Rect;
use trevi_proto::pb;
use trevi_proto::{pixels_to_bytes, CHUNK_SIZE};

/// What a rendered lease uploads.
pub(crate) struct Payload {
    pub(crate) pixels: Pixels,
    /// For a pass (`Lease.samples`): the new accumulation state, encoded.
    pub(crate) state: Option<Vec<u8>>,
}

/// A rendered lease's pixels, as the lease asks for them.
pub(crate) enum Pixels {
    /// The pixels, as floats.
    Floats(Vec<[f32; 3]>),
    /// For a lease with `png_segments`: the rect's encoded segments and
    /// preview sums (see [`crate::segments`]).
    Segments(EncodedRect),
    /// For a lease with `aovs`: the pixels as floats, then the render pass
    /// values (`trevi_core::AovTile` layout), uploaded after them.
    WithAovs(Vec<[f32; 3]>, Vec<f32>),
}

/// What a render of a lease's rectangle reports besides its pixels.
#[derive(Debug, Clone, Copy)]
pub struct Rendered {
    /// Rays traced.
    pub rays: u64,
    /// Time spent rendering (not loading the scene or waiting): the
    /// coordinator sizes the job's leases from it.
    pub took: Duration,
    /// CPU time the render threads spent on the lease, scene build
    /// included, in microseconds (`None`: not measured; see
    /// `cpu.rs`).
    pub cpu_micros: Option<u64>,
}

impl Session {
    /// Uploads a lease's result; whether the coordinator accepted it.
    pub(crate) async fn send(
        &mut self,
        me: &Me,
        lease: &pb::Lease,
        rect: Rect,
        rendered: Rendered,
        payload: Payload,
    ) -> Result<bool, tonic::Status> {
        let msgs = upload_messages(me.id, &me.session, lease, rect, rendered, payload);
        let ack = self
            .workers
            .submit_tile(tokio_stream::iter(msgs))
            .await?
            .into_inner();
        Ok(ack.accepted)
    }
}

/// The messages of a lease's upload: the header, the pixels (floats, or
/// segments and preview sums), then for a pass the state in chunks.
pub(crate) fn upload_messages(
    worker: u64,
    session: &[u8],
    lease: &pb::Lease,
    rect: Rect,
    rendered: Rendered,
    payload: Payload,
) -> Vec<pb::TileUpload> {
    let mut msgs = match payload.pixels {
        Pixels::Floats(pixels) => tile_messages(worker, session, lease, rect, rendered, &pixels),
        Pixels::Segments(encoded) => {
            segment_messages(worker, session, lease, rect, rendered, encoded)
        }
        Pixels::WithAovs(pixels, aovs) => {
            let mut msgs = tile_messages(worker, session, lease, rect, rendered, &pixels);
            msgs.extend(aov_messages(&aovs));
            msgs
        }
    };
    if let Some(state) = payload.state {
        msgs.extend(state_messages(state));
    }
    msgs
}

/// An encoded accumulation state as the `state` parts of an upload, in
/// chunks of at most `CHUNK_SIZE` bytes (one chunk is the state itself,
/// not a copy).
pub fn state_messages(state: Vec<u8>) -> Vec<pb::TileUpload> {
    use pb::tile_upload::Part;
    if state.len() <= CHUNK_SIZE {
        return vec![pb::TileUpload {
            part: Some(Part::State(state)),
        }];
    }
    state
        .chunks(CHUNK_SIZE)
        .map(|c| pb::TileUpload {
            part: Some(Part::State(c.to_vec())),
        })
        .collect()
}

/// The messages of a tile upload: the header, then the pixels in chunks.
pub fn tile_messages(
    worker: u64,
    session: &[u8],
    lease: &pb::Lease,
    rect: Rect,
    rendered: Rendered,
    pixels: &[[f32; 3]],
) -> Vec<pb::TileUpload> {
    use pb::tile_upload::Part;
    let bytes = pixels_to_bytes(pixels);
    let mut msgs = vec![header_message(worker, session, lease, rect, rendered)];
    msgs.extend(bytes.chunks(CHUNK_SIZE).map(|c| pb::TileUpload {
        part: Some(Part::Pixels(c.to_vec())),
    }));
    msgs
}

/// Render pass values as the `aovs` parts of an upload (little-endian
/// f32), in chunks of at most `CHUNK_SIZE` bytes.
pub fn aov_messages(values: &[f32]) -> Vec<pb::TileUpload> {
    use pb::tile_upload::Part;
    trevi_proto::floats_to_bytes(values)
        .chunks(CHUNK_SIZE)
        .map(|c| pb::TileUpload {
            part: Some(Part::Aovs(c.to_vec())),
        })
        .collect()
}

/// The first message of an upload, floats or segments: the header.
pub(crate) fn header_message(
    worker: u64,
    session: &[u8],
    lease: &pb::Lease,
    rect: Rect,
    rendered: Rendered,
) -> pb::TileUpload {
    pb::TileUpload {
        part: Some(pb::tile_upload::Part::Header(pb::TileHeader {
            worker_id: worker,
            lease_id: lease.lease_id,
            job_id: lease.job_id,
            rect: Some(rect.into()),
            rays: rendered.rays,
            session: session.to_vec(),
            frame: lease.frame,
            render_micros: Some(rendered.took.as_micros().min(u128::from(u64::MAX)) as u64),
            cpu_micros: rendered.cpu_micros,
        })),
    }
}

/// The messages of a segment upload: the header (as for floats), the
/// segments in order, one message each, then the preview sums.
pub fn segment_messages(
    worker: u64,
    session: &[u8],
    lease: &pb::Lease,
    rect: Rect,
    rendered: Rendered,
    encoded: EncodedRect,
) -> Vec<pb::TileUpload> {
    use pb::tile_upload::Part;
    let mut msgs = Vec::with_capacity(encoded.segments.len() + 2);
    msgs.push(header_message(worker, session, lease, rect, rendered));
    msgs.extend(encoded.segments.into_iter().map(|s| pb::TileUpload {
        part: Some(Part::Segment(s)),
    }));
    msgs.push(pb::TileUpload {
        part: Some(Part::Preview(pb::PreviewSums {
            sums: encoded.preview,
        })),
    });
    msgs
}

#[cfg(test)]
mod tests;
