//! The Trevi gRPC contract (`trevi.v1`).
//!
//! The protos live in `proto/trevi/v1/`; `build.rs` compiles them with protox
//! (no `protoc` needed) into the [`pb`] module. Conversions between the prost
//! messages and `trevi-core`'s domain types live here, so `trevi-core` never
//! sees prost, and so does the pixel wire format ([`pixels_to_bytes`],
//! [`pixels_from_bytes`]).
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

use trevi_core::Rect;

pub mod connect;
pub mod duration;
pub mod requeue;
pub mod signal;
pub use connect::{endpoint, ClientTls, EndpointError};

/// Generated prost messages and tonic clients and servers.
pub mod pb {
    // This is tonic-prost-build's output, regenerated on every build: it
    // cannot carry docs of ours (prost copies the .proto comments where
    // there are some, the tonic glue has none) nor meet our clippy rules.
    // The contract is documented in proto/proto/trevi/v1/farm.proto.
    #![allow(clippy::all, missing_docs)]
    tonic::include_proto!("trevi.v1");

    /// The encoded `FileDescriptorSet`, for gRPC server reflection.
    pub const FILE_DESCRIPTOR_SET: &[u8] =
        include_bytes!(concat!(env!("OUT_DIR"), "/trevi_descriptor.bin"));
}

/// Size of the chunks bundles, tiles and images travel in.
pub const CHUNK_SIZE: usize = 1 << 20;

/// Largest gRPC message either side accepts (a chunk plus framing).
pub const MAX_MESSAGE_SIZE: usize = 4 << 20;

/// Client side of the farm's tokens: adds `authorization: Bearer TOKEN` to
/// every call (nothing when there is no token).
#[derive(Clone, Default)]
pub struct Bearer(Option<tonic::metadata::MetadataValue<tonic::metadata::Ascii>>);

impl Bearer {
    /// `None`: no header. A token must be printable ASCII without spaces.
    pub fn new(token: Option<&str>) -> Result<Bearer, TokenError> {
        match token {
            None => Ok(Bearer(None)),
            Some(t) if t.is_empty() || t.chars().any(|c| !c.is_ascii_graphic()) => {
                Err(TokenError::NotPrintable)
            }
            Some(t) => Ok(Bearer(Some(format!("Bearer {t}").parse()?))),
        }
    }
}

/// A token that cannot travel in an `authorization` header.
#[derive(Debug, thiserror::Error)]
pub enum TokenError {
    /// The token is empty, or has a space, a control or a non-ASCII
    /// character.
    #[error("a token must be printable ASCII without spaces")]
    NotPrintable,
    /// tonic refused `Bearer TOKEN` as a header value.
    #[error("bad token: {0}")]
    Header(#[from] tonic::metadata::errors::InvalidMetadataValue),
}

impl tonic::service::Interceptor for Bearer {
    fn call(&mut self, mut req: tonic::Request<()>) -> Result<tonic::Request<()>, tonic::Status> {
        if let Some(v) = &self.0 {
            req.metadata_mut().insert("authorization", v.clone());
        }
        Ok(req)
    }
}

/// A channel whose calls carry the token.
pub type AuthChannel =
    tonic::service::interceptor::InterceptedService<tonic::transport::Channel, Bearer>;

/// A message from the wire that does not make sense.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum WireError {
    /// A message field that must be set is not (its name).
    #[error("missing field {0}")]
    Missing(&'static str),
    /// Pixel bytes whose length (given) is not a multiple of 12.
    #[error("pixel data of {0} bytes is not a whole number of RGB f32 triples")]
    RaggedPixels(usize),
}

impl From<Rect> for pb::Rect {
    fn from(r: Rect) -> Self {
        pb::Rect {
            x: r.x,
            y: r.y,
            w: r.w,
            h: r.h,
        }
    }
}

impl From<pb::Rect> for Rect {
    fn from(r: pb::Rect) -> Self {
        Rect::new(r.x, r.y, r.w, r.h)
    }
}

/// The rectangle of an optional message field.
pub fn rect_from(r: Option<pb::Rect>) -> Result<Rect, WireError> {
    r.map(Rect::from).ok_or(WireError::Missing("rect"))
}

/// Linear RGB pixels as little-endian f32 triples.
pub fn pixels_to_bytes(pixels: &[[f32; 3]]) -> Vec<u8> {
    pixels_as_bytes(pixels).into_owned()
}

/// [`pixels_to_bytes`] without the copy where the pixels already are those
/// bytes (little-endian machines, all a farm runs on).
pub fn pixels_as_bytes(pixels: &[[f32; 3]]) -> std::borrow::Cow<'_, [u8]> {
    if cfg!(target_endian = "little") {
        return std::borrow::Cow::Borrowed(bytemuck::cast_slice(pixels));
    }
    let mut out = Vec::with_capacity(pixels.len() * 12);
    for p in pixels {
        for c in p {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    std::borrow::Cow::Owned(out)
}

/// Floats (a tile's render pass values) as little-endian f32.
pub fn floats_to_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// The inverse of [`floats_to_bytes`]: `None` for a length that is not a
/// whole number of floats.
pub fn floats_from_bytes(bytes: &[u8]) -> Option<Vec<f32>> {
    (bytes.len() % 4 == 0).then(|| {
        bytes
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    })
}

/// The inverse of [`pixels_to_bytes`].
pub fn pixels_from_bytes(bytes: &[u8]) -> Result<Vec<[f32; 3]>, WireError> {
    if bytes.len() % 12 != 0 {
        return Err(WireError::RaggedPixels(bytes.len()));
    }
    if cfg!(target_endian = "little") {
        // The bytes are the pixels: one copy (the buffer may be unaligned).
        return Ok(bytemuck::pod_collect_to_vec(bytes));
    }
    Ok(bytes
        .chunks_exact(12)
        .map(|c| {
            let f = |i: usize| f32::from_le_bytes([c[i], c[i + 1], c[i + 2], c[i + 3]]);
            [f(0), f(4), f(8)]
        })
        .collect())
}

impl pb::JobState {
    /// Whether the job will not change any more.
    pub fn is_final(self) -> bool {
        matches!(
            self,
            pb::JobState::Done | pb::JobState::Failed | pb::JobState::Cancelled
        )
    }

    /// Lower-case name for people. The coordinator's `JobState::name` is
    /// this label, and its database keeps these words: they never change.
    pub fn label(self) -> &'static str {
        match self {
            pb::JobState::Unspecified => "unknown",
            pb::JobState::Queued => "queued",
            pb::JobState::Running => "running",
            pb::JobState::Done => "done",
            pb::JobState::Failed => "failed",
            pb::JobState::Cancelled => "cancelled",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_token_with_spaces_or_nothing_in_it_is_refused() {
        for bad in ["", "two words", "tab\there", "caf\u{e9}"] {
            let e = Bearer::new(Some(bad)).err();
            assert!(
                matches!(e, Some(TokenError::NotPrintable)),
                "{bad:?}: {e:?}"
            );
        }
        assert!(Bearer::new(Some("s3cret-token_1")).is_ok());
        assert!(Bearer::new(None).is_ok());
    }

    #[test]
    fn pixels_round_trip_bit_exactly() {
        let px = vec![[0.0, -1.5, f32::MAX], [f32::NAN, 1e-30, 3.25]];
        let bytes = pixels_to_bytes(&px);
        assert_eq!(&*pixels_as_bytes(&px), &bytes[..]);
        // The wire format: little-endian f32 R, G, B, pixel after pixel.
        let expected: Vec<u8> = px
            .iter()
            .flatten()
            .flat_map(|c| c.to_bits().to_le_bytes())
            .collect();
        assert_eq!(bytes, expected);
        // Read back, also from an unaligned buffer (protobuf gives no alignment).
        let mut shifted = vec![0u8];
        shifted.extend_from_slice(&bytes);
        let bits = |p: &[[f32; 3]]| p.iter().flatten().map(|c| c.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&pixels_from_bytes(&bytes).unwrap()), bits(&px));
        assert_eq!(bits(&pixels_from_bytes(&shifted[1..]).unwrap()), bits(&px));
        assert_eq!(
            pixels_from_bytes(&[0u8; 13]),
            Err(WireError::RaggedPixels(13))
        );
    }

    #[test]
    fn rects_round_trip() {
        let r = Rect::new(1, 2, 3, 4);
        assert_eq!(Rect::from(pb::Rect::from(r)), r);
        assert_eq!(rect_from(None), Err(WireError::Missing("rect")));
    }

    #[test]
    fn descriptor_set_is_embedded() {
        let text = String::from_utf8_lossy(pb::FILE_DESCRIPTOR_SET);
        assert!(text.contains("trevi.v1") && text.contains("SubmitTile"));
    }
}
