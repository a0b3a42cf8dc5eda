use super::*;
use crate::segments::encode_rect;

/// Pixels varying across and down the rect, so its segments differ.
fn pixels(rect: Rect) -> Vec<[f32; 3]> {
    let mut out = Vec::with_capacity(rect.pixel_count());
    for y in rect.y..rect.y + rect.h {
        for x in rect.x..rect.x + rect.w {
            out.push([x as f32 / 8.0, y as f32 / 64.0, 0.5]);
        }
    }
    out
}

#[test]
fn the_upload_is_header_segments_preview() {
    let rect = Rect::new(0, 16, 8, 40);
    let enc = encode_rect(rect, 8, 56, 4, &pixels(rect)).unwrap();
    let lease = pb::Lease {
        lease_id: 9,
        job_id: 3,
        png_segments: true,
        preview_scale: 4,
        ..Default::default()
    };
    let rendered = Rendered {
        rays: 5,
        took: std::time::Duration::from_micros(77),
        cpu_micros: Some(1234),
    };
    let msgs = segment_messages(1, b"s", &lease, rect, rendered, enc.clone());
    use pb::tile_upload::Part;
    assert_eq!(msgs.len(), 2 + 3);
    let Some(Part::Header(h)) = &msgs[0].part else {
        panic!()
    };
    assert_eq!((h.lease_id, h.job_id, h.render_micros), (9, 3, Some(77)));
    assert_eq!(h.cpu_micros, Some(1234));
    assert_eq!(h.rect, Some(rect.into()));
    for (m, s) in msgs[1..4].iter().zip(&enc.segments) {
        assert_eq!(m.part, Some(Part::Segment(s.clone())));
    }
    assert_eq!(
        msgs[4].part,
        Some(Part::Preview(pb::PreviewSums { sums: enc.preview }))
    );
}

#[test]
fn a_float_upload_is_header_then_chunks_of_pixels() {
    let rect = Rect::new(16, 0, 16, 16);
    let px = pixels(rect);
    let lease = pb::Lease {
        lease_id: 4,
        job_id: 2,
        frame: Some(7),
        ..Default::default()
    };
    let rendered = Rendered {
        rays: 9,
        took: Duration::from_micros(5),
        cpu_micros: None,
    };
    let msgs = tile_messages(1, b"s", &lease, rect, rendered, &px);
    use pb::tile_upload::Part;
    let Some(Part::Header(h)) = &msgs[0].part else {
        panic!("the header comes first")
    };
    assert_eq!((h.worker_id, h.lease_id, h.job_id), (1, 4, 2));
    assert_eq!((h.rays, h.frame, h.render_micros), (9, Some(7), Some(5)));
    assert_eq!(h.session, b"s");
    let mut bytes = Vec::new();
    for m in &msgs[1..] {
        let Some(Part::Pixels(c)) = &m.part else {
            panic!("pixels follow the header")
        };
        assert!(c.len() <= CHUNK_SIZE);
        bytes.extend_from_slice(c);
    }
    assert_eq!(bytes, pixels_to_bytes(&px));
}

/// The parts after the pixels: `state` chunks, at most CHUNK_SIZE each,
/// whose concatenation is returned.
fn state_after(msgs: &[pb::TileUpload]) -> Vec<u8> {
    use pb::tile_upload::Part;
    let mut bytes = Vec::new();
    for m in msgs {
        let Some(Part::State(c)) = &m.part else {
            panic!("only state chunks after the pixels: {:?}", m.part)
        };
        assert!(!c.is_empty() && c.len() <= CHUNK_SIZE);
        bytes.extend_from_slice(c);
    }
    bytes
}

/// A pass's upload: the header, the pixels (floats or segments and the
/// preview), then the new state in chunks that decode to it; a state of
/// more than one chunk is split at CHUNK_SIZE.
#[test]
fn a_pass_uploads_its_state_after_the_pixels() {
    use pb::tile_upload::Part;
    use trevi_core::passes::TileState;
    // 130 rows of 128 pixels: a state of just over 1 MiB, two chunks.
    let rect = Rect::new(0, 0, 128, 130);
    let state = TileState::new(rect);
    let encoded = state.encode();
    assert!(encoded.len() > CHUNK_SIZE && encoded.len() <= 2 * CHUNK_SIZE);
    let px = pixels(rect);
    let lease = pb::Lease {
        lease_id: 4,
        job_id: 2,
        samples: Some(pb::SampleRange {
            start: 0,
            end: 3,
            total: 8,
        }),
        ..Default::default()
    };
    let rendered = Rendered {
        rays: 9,
        took: Duration::from_micros(5),
        cpu_micros: None,
    };
    let payload = Payload {
        pixels: Pixels::Floats(px.clone()),
        state: Some(encoded.clone()),
    };
    let msgs = upload_messages(1, b"s", &lease, rect, rendered, payload);
    assert!(matches!(msgs[0].part, Some(Part::Header(_))));
    let floats = tile_messages(1, b"s", &lease, rect, rendered, &px);
    assert_eq!(
        msgs[..floats.len()],
        floats[..],
        "the pixels as without a state"
    );
    assert_eq!(msgs.len(), floats.len() + 2);
    let sent = state_after(&msgs[floats.len()..]);
    assert_eq!(TileState::decode(&sent).unwrap(), state);

    // Segments: header, segments, preview, then the state (one chunk).
    let rect = Rect::new(0, 16, 8, 40);
    let enc = encode_rect(rect, 8, 56, 4, &pixels(rect)).unwrap();
    let state = TileState::new(rect);
    let lease = pb::Lease {
        png_segments: true,
        preview_scale: 4,
        ..lease
    };
    let payload = Payload {
        pixels: Pixels::Segments(enc.clone()),
        state: Some(state.encode()),
    };
    let msgs = upload_messages(1, b"s", &lease, rect, rendered, payload);
    let segs = segment_messages(1, b"s", &lease, rect, rendered, enc);
    assert!(matches!(segs.last().unwrap().part, Some(Part::Preview(_))));
    assert_eq!(msgs[..segs.len()], segs[..]);
    assert_eq!(msgs.len(), segs.len() + 1);
    assert_eq!(
        TileState::decode(&state_after(&msgs[segs.len()..])).unwrap(),
        state
    );

    // No pass, no state.
    let payload = Payload {
        pixels: Pixels::Floats(pixels(rect)),
        state: None,
    };
    let msgs = upload_messages(1, b"s", &lease, rect, rendered, payload);
    assert!(!msgs.iter().any(|m| matches!(m.part, Some(Part::State(_)))));
}
