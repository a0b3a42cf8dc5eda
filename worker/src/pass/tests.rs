use super::*;
use crate::render::{render_lease, Stop};
use crate::scene_cache::Key;
use crate::scene_load::apply_key;
use crate::upload::{Payload, Pixels};
use trevi_core::tile::render_tile;

/// Soft shadows and jittered samples: every sample changes the pixels.
const SCENE: &str = r#"<scene version="1">
  <sphere id="s" center="0 0 0" radius="1"><surface diffuse="0.8 0.3 0.2"/></sphere>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1" radius="1"/>
  <camera id="c" position="0 0 5" lookat="0 0 0" up="0 1 0" fov="30">
    <render width="6" height="5" supersample="2" jitter="true" shadow-samples="1" output="o.png"/>
  </camera>
</scene>"#;

fn scene() -> Scene {
    Scene::from_bundle(&trevi_core::Bundle {
        scene: "s.xml".into(),
        files: [("s.xml".to_string(), SCENE.as_bytes().to_vec())].into(),
    })
    .unwrap()
}

fn bits(p: &[[f32; 3]]) -> Vec<[u32; 3]> {
    p.iter().map(|v| v.map(f32::to_bits)).collect()
}

fn range(start: u32, end: u32, total: u32) -> pb::SampleRange {
    pb::SampleRange { start, end, total }
}

/// `bytes` as a FetchState stream of `size`-byte chunks.
fn chunks(
    bytes: &[u8],
    size: usize,
) -> impl Stream<Item = Result<pb::StateChunk, tonic::Status>> + Unpin {
    let parts: Vec<_> = bytes
        .chunks(size)
        .map(|c| Ok(pb::StateChunk { data: c.to_vec() }))
        .collect();
    tokio_stream::iter(parts)
}

/// A lease's render (`render_lease`, what `Session::tile` runs): the
/// floats and the encoded state of a pass.
fn lease(
    scene: &Scene,
    rect: Rect,
    id: u64,
    r: pb::SampleRange,
    fetched: Option<Vec<u8>>,
) -> (Vec<[f32; 3]>, u64, Vec<u8>) {
    let pass = Pass::check(id, rect, r).unwrap();
    let never = AtomicBool::new(false);
    match render_lease(scene, 0, rect, id, Some((pass, fetched)), None, &never) {
        Ok((
            Payload {
                pixels: Pixels::Floats(px),
                state: Some(state),
            },
            rays,
            _,
        )) => (px, rays, state),
        Ok(_) => panic!("a pass gives floats and a state"),
        Err(Stop::Failed(e)) => panic!("{e}"),
        Err(Stop::Cancelled) => panic!("cancelled"),
    }
}

/// A pass rendered in two leases, 0..3 then 3..8 of a job's own 8 samples,
/// its state carried between them as the wire carries it (encoded, split
/// into chunks, read back with the bound, checked), finishes to the bytes
/// and the rays of the one-shot render of the scene given 8 samples.
#[tokio::test]
async fn two_leases_finish_to_the_one_shot_render() {
    let rect = Rect::new(1, 1, 4, 3);
    let mut pass_scene = scene();
    apply_key(&mut pass_scene, &Key::still("h").with_samples("c", 8)).unwrap();
    let (first, rays_a, state) = lease(&pass_scene, rect, 1, range(0, 3, 8), None);
    let fetched = read_state(2, rect, chunks(&state, 100)).await.unwrap();
    assert_eq!(fetched, state);
    let (last, rays_b, state) = lease(&pass_scene, rect, 2, range(3, 8, 8), Some(fetched));
    let done = TileState::decode(&state).unwrap();
    assert_eq!((done.rect(), done.next()), (rect, 8));
    let mut eight = scene();
    eight.set_samples(0, 8);
    let once = render_tile(&eight, 0, rect);
    assert_eq!(bits(&last), bits(&once.pixels));
    assert_eq!(rays_a + rays_b, once.rays);
    assert_ne!(bits(&first), bits(&last), "3 samples are not 8");
    // Not the scene's own sampling (2x2): the key's total was applied.
    assert_ne!(bits(&render_tile(&scene(), 0, rect).pixels), bits(&last));
}

/// A stream longer than a state of the lease's rect is refused, naming the
/// lease and the bound, as soon as a chunk would pass the bound: even an
/// endless one. One of exactly the bound is read.
#[tokio::test]
async fn a_state_longer_than_its_rect_s_is_refused() {
    let rect = Rect::new(0, 0, 2, 2);
    let bound = TileState::encoded_len(rect);
    assert_eq!(bound, 32 + 4 * 64);
    let exact = vec![0u8; bound];
    assert_eq!(
        read_state(7, rect, chunks(&exact, 100))
            .await
            .unwrap()
            .len(),
        bound
    );
    let long = vec![0u8; bound + 1];
    let e = read_state(7, rect, chunks(&long, 100)).await.unwrap_err();
    assert!(
        matches!(e, PassError::TooLong { lease: 7, bound: b } if b == bound),
        "{e}"
    );
    let said = e.to_string();
    assert!(
        said.contains("lease 7") && said.contains(&bound.to_string()),
        "{said}"
    );
    let endless = tokio_stream::iter(std::iter::repeat_with(|| {
        Ok(pb::StateChunk {
            data: vec![0u8; 64],
        })
    }));
    let e = read_state(7, rect, endless).await.unwrap_err();
    assert!(matches!(e, PassError::TooLong { .. }), "{e}");
}

/// A state that decodes but is not the one the lease continues (another
/// rect, a smaller one within the bound, another `next`) or does not
/// decode is refused, naming the lease.
#[test]
fn a_state_for_another_rect_or_next_is_refused() {
    let rect = Rect::new(2, 0, 3, 2);
    let mut s = scene();
    s.set_samples(0, 8);
    let mut state = TileState::new(rect);
    state.render(&s, 0, 0..3, &AtomicBool::new(false)).unwrap();
    let bytes = state.encode();
    assert_eq!(accept_state(4, rect, 3, &bytes).unwrap(), state);
    for other in [
        Rect::new(1, 0, 3, 2),
        Rect::new(2, 0, 2, 3),
        Rect::new(2, 0, 3, 3),
    ] {
        let e = accept_state(4, other, 3, &bytes).unwrap_err();
        assert!(
            matches!(e, PassError::OtherRect { lease: 4, want, got } if want == other && got == rect),
            "{e}"
        );
    }
    let smaller = TileState::new(Rect::new(2, 0, 1, 1)).encode();
    assert!(smaller.len() < TileState::encoded_len(rect));
    let e = accept_state(4, rect, 0, &smaller).unwrap_err();
    assert!(matches!(e, PassError::OtherRect { .. }), "{e}");
    for start in [0, 2, 4] {
        let e = accept_state(4, rect, start, &bytes).unwrap_err();
        assert!(
            matches!(
                e,
                PassError::OtherNext {
                    lease: 4,
                    next: 3,
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().contains("lease 4"), "{e}");
    }
    let e = accept_state(4, rect, 3, &bytes[..bytes.len() - 1]).unwrap_err();
    assert!(matches!(e, PassError::Decode { lease: 4, .. }), "{e}");
    let e = accept_state(4, rect, 3, b"not a state").unwrap_err();
    assert!(matches!(e, PassError::Decode { .. }), "{e}");
}

/// A refused state fails the lease through the worker's render, never a
/// panic, and leaves nothing to upload.
#[test]
fn the_render_of_a_refused_state_fails_the_lease() {
    let rect = Rect::new(0, 0, 2, 2);
    let s = scene();
    let pass = Pass::check(5, rect, range(3, 4, 0)).unwrap();
    let wrong = TileState::new(rect).encode();
    let never = AtomicBool::new(false);
    match render_lease(&s, 0, rect, 5, Some((pass, Some(wrong))), None, &never) {
        Err(Stop::Failed(e)) => assert!(e.contains("lease 5") && e.contains("0..0"), "{e}"),
        _ => panic!("a state at 0 does not continue at 3"),
    }
    // Past the scene's own 2x2 samples.
    let pass = Pass::check(5, rect, range(0, 5, 0)).unwrap();
    match render_lease(&s, 0, rect, 5, Some((pass, None)), None, &never) {
        Err(Stop::Failed(e)) => assert!(e.contains("lease 5") && e.contains("past"), "{e}"),
        _ => panic!("5 samples of 4"),
    }
    // Cancelled: no payload.
    let pass = Pass::check(5, rect, range(0, 4, 0)).unwrap();
    let stop = AtomicBool::new(true);
    assert!(matches!(
        render_lease(&s, 0, rect, 5, Some((pass, None)), None, &stop),
        Err(Stop::Cancelled)
    ));
}

#[test]
fn a_lease_s_range_is_checked_before_the_work() {
    let rect = Rect::new(0, 0, 64, 64);
    assert_eq!(
        Pass::check(1, rect, range(3, 8, 8)).unwrap(),
        Pass {
            start: 3,
            end: 8,
            total: 8
        }
    );
    assert!(
        Pass::check(1, rect, range(0, 9, 0)).is_ok(),
        "the scene's own: checked later"
    );
    let e = |r| Pass::check(1, rect, r).unwrap_err();
    assert!(matches!(e(range(3, 3, 8)), PassError::Range { .. }));
    assert!(matches!(e(range(4, 3, 8)), PassError::Range { .. }));
    assert!(matches!(e(range(0, 9, 8)), PassError::PastTotal { .. }));
    assert!(matches!(
        e(range(0, 1, MAX_SAMPLES + 1)),
        PassError::Total { .. }
    ));
    assert!(Pass::check(1, rect, range(0, 1, MAX_SAMPLES)).is_ok());
    let band = Rect::new(0, 0, 1 << 16, 64);
    assert!(Pass::check(1, band, range(0, 1, 0)).is_ok());
    let past = Rect::new(0, 0, 1 << 16, 65);
    assert!(matches!(
        Pass::check(1, past, range(0, 1, 0)).unwrap_err(),
        PassError::TooManyPixels { lease: 1, .. }
    ));
    let huge = Rect::new(0, 0, u32::MAX, u32::MAX);
    assert!(Pass::check(1, huge, range(0, 1, 0)).is_err());
}

/// A fetch that fails on the connection or the session ends the session;
/// the coordinator's answer about the lease fails the lease.
#[test]
fn transport_failures_are_the_connection_s() {
    use tonic::Status;
    assert!(connection_lost(&Status::unavailable("gone")));
    assert!(connection_lost(&Status::permission_denied("old session")));
    let io = std::io::Error::new(std::io::ErrorKind::ConnectionReset, "reset");
    assert!(connection_lost(&Status::from_error(Box::new(io))));
    assert!(!connection_lost(&Status::not_found("no state for lease 3")));
    assert!(!connection_lost(&Status::unimplemented("FetchState")));
    assert!(!connection_lost(&Status::invalid_argument("not a pass")));
}
