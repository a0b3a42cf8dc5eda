//! Progressive renders finish to the one-shot bytes for any split, states
//! survive their encoding, the decoder refuses hostile bytes, and the
//! noise estimate matches closed forms.

use super::*;
use crate::integrator::PixelState;
use crate::testing::scene;
use crate::tile::render_tile;
use proptest::prelude::*;
use std::sync::atomic::Ordering;

/// Whitted with every effect: depth of field (aperture), soft shadows (a
/// light with a radius), ambient occlusion, the diffuse gather, a mirror;
/// 3×3 jittered samples.
const WHITTED: &str = r#"<scene version="1"><settings ambient="0.3 0.3 0.3"/>
  <sphere id="s" center="0 0 0" radius="1">
    <surface diffuse="0.8 0.3 0.2" ambient="0.5 0.5 0.5" reflectivity="0.3"/></sphere>
  <plane id="p" point="0 -1 0" normal="0 1 0"><surface diffuse="0.5 0.5 0.5" ambient="0.2 0.2 0.2"/></plane>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1" radius="0.5"/>
  <camera id="c" position="0 0.3 5" lookat="0 0 0" up="0 1 0" fov="40" aperture="0.2" focus="5">
    <render width="4" height="3" supersample="3" jitter="true" shadow-samples="2"
            ao-samples="2" diffuse-samples="2" diffuse-depth="1" output="o.png"/>
  </camera>
</scene>"#;

/// The path tracer: a rect light over a diffuse sphere and floor, 3×3
/// jittered samples.
const PATH: &str = r#"<scene version="1">
  <light type="rect" position="-0.5 3 -0.5" edge-u="1 0 0" edge-v="0 0 1" emission="4 4 4"/>
  <sphere id="s" center="0 0 0" radius="1"><surface diffuse="0.7 0.7 0.7"/></sphere>
  <plane id="p" point="0 -1 0" normal="0 1 0"><surface diffuse="0.5 0.4 0.3"/></plane>
  <camera id="c" position="0 0.5 5" lookat="0 0 0" up="0 1 0" fov="40">
    <render width="4" height="3" supersample="3" jitter="true" integrator="path"
            max-bounces="4" output="o.png"/>
  </camera>
</scene>"#;

/// Adaptive sampling with soft shadows: the background stops at two
/// samples, the lit sphere runs on.
fn adaptive(max: u32) -> String {
    adaptive_between(3, max)
}

/// [`adaptive`] with its own min-samples.
fn adaptive_between(min: u32, max: u32) -> String {
    format!(
        r#"<scene version="1">
  <sphere id="s" center="0 0 0" radius="1"><surface diffuse="0.8 0.3 0.2"/></sphere>
  <plane id="p" point="0 -1 0" normal="0 1 0"><surface diffuse="0.5 0.5 0.5"/></plane>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1" radius="1.5"/>
  <camera id="c" position="0 0.5 5" lookat="0 0 0" up="0 1 0" fov="50">
    <render width="5" height="4" noise-threshold="0.01" min-samples="{min}" max-samples="{max}"
            shadow-samples="1" output="o.png"/>
  </camera>
</scene>"#
    )
}

/// More samples than one block of the sums: 33² = 1089.
const BLOCKS: &str = r#"<scene version="1">
  <sphere id="s" center="0 0 0" radius="1"><surface diffuse="0.8 0.3 0.2"/></sphere>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1"/>
  <camera id="c" position="0 0 5" lookat="0 0 0" up="0 1 0" fov="20">
    <render width="2" height="1" supersample="33" jitter="true" output="o.png"/>
  </camera>
</scene>"#;

fn bits(pixels: &[[f32; 3]]) -> Vec<[u32; 3]> {
    pixels.iter().map(|p| p.map(f32::to_bits)).collect()
}

fn whole(s: &Scene) -> Rect {
    let r = &s.desc.cameras[0].render;
    Rect::new(0, 0, r.width, r.height)
}

/// Renders `s` in the ranges between consecutive `cuts` (0 and the samples
/// per pixel added at the ends) and returns the state and the rays.
fn in_passes(s: &Scene, rect: Rect, cuts: &[u32]) -> (TileState, u64) {
    let total = samples_per_pixel(&s.desc.cameras[0].render);
    let mut cuts: Vec<u32> = cuts.iter().map(|&c| c % (total + 1)).collect();
    cuts.sort_unstable();
    let never = AtomicBool::new(false);
    let mut state = TileState::new(rect);
    let mut rays = 0;
    let mut start = 0;
    for end in cuts.into_iter().chain([total]) {
        rays += state.render(s, 0, start..end, &never).unwrap();
        start = end;
    }
    (state, rays)
}

/// The one-shot render's bytes and rays equal those of `s` rendered in the
/// passes `cuts`.
fn check_split(s: &Scene, cuts: &[u32]) -> Result<(), TestCaseError> {
    let rect = whole(s);
    let once = render_tile(s, 0, rect);
    let (state, rays) = in_passes(s, rect, cuts);
    prop_assert_eq!(bits(&state.finish()), bits(&once.pixels), "cuts {:?}", cuts);
    prop_assert_eq!(rays, once.rays);
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn any_split_of_a_whitted_render_is_the_one_shot_render(
        cuts in prop::collection::vec(0u32..10, 0..6)
    ) {
        check_split(&scene(WHITTED), &cuts)?;
    }

    #[test]
    fn any_split_of_a_path_render_is_the_one_shot_render(
        cuts in prop::collection::vec(0u32..10, 0..6)
    ) {
        check_split(&scene(PATH), &cuts)?;
    }

    #[test]
    fn any_split_of_an_adaptive_render_is_the_one_shot_render(
        cuts in prop::collection::vec(0u32..41, 0..6)
    ) {
        check_split(&scene(&adaptive(40)), &cuts)?;
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4))]

    /// Splits inside and across the sums' blocks of 1024 samples.
    #[test]
    fn any_split_across_sum_blocks_is_the_one_shot_render(
        cuts in prop::collection::vec(prop_oneof![1000u32..1090, 0u32..1090], 1..5)
    ) {
        check_split(&scene(BLOCKS), &cuts)?;
    }
}

#[test]
fn splits_at_the_block_boundary_are_the_one_shot_render() {
    let s = scene(BLOCKS);
    for cuts in [&[1023][..], &[1024], &[1025], &[1, 1023, 1024, 1025, 1088]] {
        check_split(&s, cuts).unwrap();
    }
}

/// Adaptive sampling stops some pixels early and runs others to the end,
/// so the splits above cross both kinds.
#[test]
fn the_adaptive_scene_stops_some_pixels_early_and_not_others() {
    let s = scene(&adaptive(40));
    let (state, _) = in_passes(&s, whole(&s), &[]);
    let counts: Vec<u32> = state.pixels().iter().map(PixelState::count).collect();
    assert!(counts.contains(&3), "{counts:?}");
    assert!(counts.contains(&40), "{counts:?}");
}

/// Adaptive sampling's sequence does not depend on max-samples, so a
/// finished render extended under a larger max-samples is the render made
/// with it at once.
#[test]
fn an_adaptive_render_extends_to_a_larger_max_samples() {
    let (small, large) = (scene(&adaptive(16)), scene(&adaptive(64)));
    let rect = whole(&small);
    let never = AtomicBool::new(false);
    let mut state = TileState::new(rect);
    state.render(&small, 0, 0..16, &never).unwrap();
    assert_eq!(
        bits(&state.finish()),
        bits(&render_tile(&small, 0, rect).pixels)
    );
    state.render(&large, 0, 16..64, &never).unwrap();
    assert_eq!(
        bits(&state.finish()),
        bits(&render_tile(&large, 0, rect).pixels)
    );
}

/// min-samples = max-samples = N is a plain N-sample render of any N that
/// extends: 16 continued to 64 is the 64-sample render, and not the same
/// as the adaptive one (pixels do not stop early).
#[test]
fn a_fixed_count_sequence_extends_to_any_count() {
    let (small, large) = (
        scene(&adaptive_between(16, 16)),
        scene(&adaptive_between(64, 64)),
    );
    let rect = whole(&small);
    let never = AtomicBool::new(false);
    let mut state = TileState::new(rect);
    state.render(&small, 0, 0..16, &never).unwrap();
    assert!(state.pixels().iter().all(|p| p.count() == 16));
    state.render(&large, 0, 16..64, &never).unwrap();
    assert!(state.pixels().iter().all(|p| p.count() == 64));
    let once = render_tile(&large, 0, rect).pixels;
    assert_eq!(bits(&state.finish()), bits(&once));
    assert_ne!(
        bits(&once),
        bits(&render_tile(&scene(&adaptive(64)), 0, rect).pixels)
    );
}

/// A state encoded, decoded and continued is the state continued in
/// memory, byte for byte, for a tile inside the frame.
#[test]
fn a_decoded_state_continues_as_the_state_in_memory() {
    for xml in [WHITTED, PATH, &adaptive(40)] {
        let s = scene(xml);
        let rect = Rect::new(1, 1, 3, 2);
        let never = AtomicBool::new(false);
        let total = samples_per_pixel(&s.desc.cameras[0].render);
        let mut memory = TileState::new(rect);
        memory.render(&s, 0, 0..4, &never).unwrap();
        let bytes = memory.encode();
        assert_eq!(bytes.len(), TileState::encoded_len(rect));
        let mut decoded = TileState::decode(&bytes).unwrap();
        assert_eq!(decoded, memory);
        memory.render(&s, 0, 4..total, &never).unwrap();
        decoded.render(&s, 0, 4..total, &never).unwrap();
        assert_eq!(decoded.encode(), memory.encode());
        assert_eq!(
            bits(&decoded.finish()),
            bits(&render_tile(&s, 0, rect).pixels)
        );
    }
}

#[test]
fn ranges_that_do_not_continue_the_state_are_refused() {
    let s = scene(WHITTED);
    let never = AtomicBool::new(false);
    let mut state = TileState::new(whole(&s));
    state.render(&s, 0, 0..3, &never).unwrap();
    let before = state.clone();
    assert_eq!(
        state.render(&s, 0, 2..5, &never),
        Err(PassError::NotNext {
            start: 2,
            end: 5,
            next: 3
        })
    );
    assert_eq!(
        state.render(&s, 0, 4..5, &never),
        Err(PassError::NotNext {
            start: 4,
            end: 5,
            next: 3
        })
    );
    assert_eq!(
        state.render(&s, 0, 3..10, &never),
        Err(PassError::PastEnd {
            start: 3,
            end: 10,
            samples: 9
        })
    );
    assert_eq!(state.render(&s, 0, 3..3, &never), Ok(0));
    assert_eq!(state, before);
}

#[test]
fn a_cancelled_pass_leaves_the_state_as_it_was() {
    let s = scene(WHITTED);
    let never = AtomicBool::new(false);
    let mut state = TileState::new(whole(&s));
    state.render(&s, 0, 0..3, &never).unwrap();
    let before = state.clone();
    let flag = AtomicBool::new(true);
    assert_eq!(
        state.render(&s, 0, 3..9, &flag),
        Err(PassError::Cancelled(Cancelled))
    );
    assert_eq!(state, before);
    flag.store(false, Ordering::Relaxed);
    state.render(&s, 0, 3..9, &flag).unwrap();
    assert_eq!(
        bits(&state.finish()),
        bits(&render_tile(&s, 0, whole(&s)).pixels)
    );
}

/// The encoding of a small real state (2×2 pixels, 5 samples), to mutate.
fn sample_bytes() -> Vec<u8> {
    static BYTES: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    BYTES
        .get_or_init(|| {
            let s = scene(WHITTED);
            let mut state = TileState::new(Rect::new(0, 0, 2, 2));
            state.render(&s, 0, 0..5, &AtomicBool::new(false)).unwrap();
            state.encode()
        })
        .clone()
}

/// Overwrites `bytes[at..]` with `v`.
fn put(mut bytes: Vec<u8>, at: usize, v: &[u8]) -> Vec<u8> {
    bytes[at..at + v.len()].copy_from_slice(v);
    bytes
}

#[test]
fn hostile_headers_are_refused_before_anything_is_allocated() {
    let good = sample_bytes();
    assert!(TileState::decode(&good).is_ok());
    let cases: Vec<(Vec<u8>, StateError)> = vec![
        (vec![], StateError::Short { len: 0 }),
        (good[..31].to_vec(), StateError::Short { len: 31 }),
        (put(good.clone(), 0, b"TVPX"), StateError::Magic),
        (
            put(good.clone(), 4, &2u16.to_le_bytes()),
            StateError::Version(2),
        ),
        (put(good.clone(), 6, &[1, 0]), StateError::Reserved),
        (put(good.clone(), 28, &[0, 0, 0, 1]), StateError::Reserved),
        (
            put(good.clone(), 16, &0u32.to_le_bytes()),
            StateError::Rect {
                x: 0,
                y: 0,
                w: 0,
                h: 2,
            },
        ),
        (
            put(good.clone(), 8, &u32::MAX.to_le_bytes()),
            StateError::Rect {
                x: u32::MAX,
                y: 0,
                w: 2,
                h: 2,
            },
        ),
        // 2³² × 2³² pixels announced in a 32-byte header.
        (
            put(
                put(good[..32].to_vec(), 16, &u32::MAX.to_le_bytes()),
                20,
                &u32::MAX.to_le_bytes(),
            ),
            StateError::TooLarge {
                pixels: u64::from(u32::MAX) * u64::from(u32::MAX),
            },
        ),
        (
            put(
                put(good[..32].to_vec(), 16, &65536u32.to_le_bytes()),
                20,
                &65u32.to_le_bytes(),
            ),
            StateError::TooLarge { pixels: 65536 * 65 },
        ),
        (
            put(good[..32].to_vec(), 20, &1000u32.to_le_bytes()),
            StateError::Length {
                expected: 32 + 64 * 2000,
                got: 32,
            },
        ),
        (
            good[..good.len() - 1].to_vec(),
            StateError::Length {
                expected: 32 + 64 * 4,
                got: 32 + 64 * 4 - 1,
            },
        ),
        (
            [&good[..], &[0]].concat(),
            StateError::Length {
                expected: 32 + 64 * 4,
                got: 32 + 64 * 4 + 1,
            },
        ),
    ];
    for (bytes, want) in cases {
        assert_eq!(TileState::decode(&bytes), Err(want));
    }
}

#[test]
fn pixels_no_render_could_leave_are_refused() {
    let good = sample_bytes();
    let pixel = |i: usize| HEADER_BYTES + PIXEL_BYTES * i;
    let refused = |bytes: Vec<u8>, index: usize| {
        assert!(
            matches!(TileState::decode(&bytes), Err(StateError::Pixel { index: i, .. }) if i == index),
            "{:?}",
            TileState::decode(&bytes)
        );
    };
    // More samples than the state has rendered (next is 5).
    refused(put(good.clone(), pixel(1) + 12, &6u32.to_le_bytes()), 1);
    // NaN in each sum.
    refused(put(good.clone(), pixel(2) + 4, &f32::NAN.to_le_bytes()), 2);
    refused(put(good.clone(), pixel(2) + 24, &f64::NAN.to_le_bytes()), 2);
    refused(put(good.clone(), pixel(3) + 56, &f64::NAN.to_le_bytes()), 3);
    // A negative sum of squares.
    refused(
        put(good.clone(), pixel(0) + 40, &(-1.0f64).to_le_bytes()),
        0,
    );
    // Sums without a sample.
    refused(put(good.clone(), pixel(3) + 12, &0u32.to_le_bytes()), 3);
    // An open block at a block boundary: a state whose next is a block.
    let mut boundary = put(good.clone(), 24, &SUM_BLOCK_BYTES);
    boundary = put(boundary, pixel(1) + 12, &SUM_BLOCK_BYTES);
    refused(boundary, 1);
}

const SUM_BLOCK_BYTES: [u8; 4] = crate::integrator::SUM_BLOCK.to_le_bytes();

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Mutated states decode to an error or to a state whose encoding is
    /// the input, and whose pixels and noise can be computed.
    #[test]
    fn mutated_states_never_panic(edits in prop::collection::vec(crate::testing::edit(&[0, 1, 0x40, 0x7f, 0xff]), 1..8)) {
        let bytes = crate::testing::apply_edits(sample_bytes(), &edits);
        if let Ok(state) = TileState::decode(&bytes) {
            prop_assert_eq!(state.encode(), bytes);
            let _ = state.finish();
            let _ = state.noise().relative_error();
        }
    }
}

/// One pixel whose samples alternate a and b (per channel) n times: mean
/// (a + b)/2, sample variance n/(n − 1)·(b − a)²/4, so the variance of the
/// mean is (b − a)²/(4(n − 1)) and the relative error
/// |b − a| / ((a + b)·√(n − 1)).
#[test]
fn the_noise_of_alternating_samples_is_its_closed_form() {
    fn closed(a: f64, b: f64, n: f64) -> f64 {
        (b - a).abs() / ((a + b) * (n - 1.0).sqrt())
    }
    for adaptive in [false, true] {
        for n in [2usize, 64, 3000] {
            let samples: Vec<[f32; 3]> = (0..n)
                .map(|i| {
                    if i % 2 == 0 {
                        [1.0, 2.0, 0.5]
                    } else {
                        [3.0, 6.0, 1.5]
                    }
                })
                .collect();
            let p = PixelState::of_samples(&samples, adaptive);
            let e = Noise::of_pixels(&[p]).relative_error();
            // Every channel is a multiple of (1, 3), so E is channel 0's.
            let want = closed(1.0, 3.0, n as f64);
            assert!((e - want).abs() <= 1e-6 * want, "n {n}: {e} vs {want}");
        }
    }
    // Two pixels: the summed variances over the summed squared means.
    let a = PixelState::of_samples(&[[1.0; 3], [3.0; 3]], false);
    let b = PixelState::of_samples(&[[4.0; 3]; 4], false);
    let e = (Noise::of_pixels(&[a]) + Noise::of_pixels(&[b])).relative_error();
    // a: var of the mean 1 a channel, mean 2; b: 0 and 4.
    let want = (3.0f64 / (3.0 * 4.0 + 3.0 * 16.0)).sqrt();
    assert!((e - want).abs() <= 1e-12, "{e} vs {want}");
    assert_eq!(Noise::of_pixels(&[a, b]).relative_error(), e);
}

#[test]
fn the_noise_of_too_few_samples_is_unknown_and_of_black_is_zero() {
    let one = PixelState::of_samples(&[[1.0; 3]], false);
    let black = PixelState::of_samples(&[[0.0; 3]; 4], false);
    assert_eq!(Noise::of_pixels(&[black]).relative_error(), 0.0);
    assert_eq!(
        Noise::of_pixels(&[black, one]).relative_error(),
        f64::INFINITY
    );
    assert_eq!(Noise::of_pixels(&[PixelState::default()]).unknown, 1);
}

/// On a real render the estimate falls about as 1/√n: from 16 to 64
/// samples of the sequence (every prefix spread over the whole pixel) it
/// about halves. Not on the grid: its first 16 of 64 samples are the top
/// two rows of strata of every pixel (docs/progressive.md).
#[test]
fn the_noise_of_a_render_falls_with_its_samples() {
    let s = scene(&adaptive_between(64, 64));
    let never = AtomicBool::new(false);
    let mut state = TileState::new(whole(&s));
    state.render(&s, 0, 0..16, &never).unwrap();
    let e16 = state.noise().relative_error();
    state.render(&s, 0, 16..64, &never).unwrap();
    let e64 = state.noise().relative_error();
    assert!(e16.is_finite() && e16 > 0.0, "{e16}");
    let ratio = e16 / e64;
    assert!((1.5..3.0).contains(&ratio), "{e16} / {e64} = {ratio}");
}
