//! Tests of spans over several bands and of segment leases: which bands a
//! span takes, in which order, what `span_tiles` accepts, when a lease asks
//! for encoded PNG segments, and how a span's tiles come back.

use super::*;
use std::time::{Duration, Instant};
use trevi_core::tile::Rect;

/// A worker of `threads` threads that takes spans and encodes segments as
/// asked.
fn worker(s: &mut Scheduler, now: Instant, threads: u32, spans: bool, segments: bool) -> WorkerId {
    let w = s.register_worker(now, None);
    s.describe_worker(w, "w", threads);
    if spans {
        s.allow_spans(w);
    }
    if segments {
        s.allow_segments(w);
    }
    w
}

/// So cheap that the sizer's share is never what stops a span.
const CHEAP: f64 = 1e-12;

/// The tiles of bands `bands` of a frame `cols` tiles of `tile` pixels
/// wide (none at an edge), row-major: computed apart from the scheduler.
fn row_major(bands: std::ops::Range<u32>, cols: u32, tile: u32) -> Vec<Rect> {
    bands
        .flat_map(|b| (0..cols).map(move |c| Rect::new(c * tile, b * tile, tile, tile)))
        .collect()
}

/// A measured, cheap EXR frame of 4 × 4 tiles of 10 pixels, and two
/// workers of 4 threads: `w` takes spans, `old` does not.
fn cheap_frame_and_two_workers(now: Instant) -> (Scheduler, JobId, WorkerId, WorkerId) {
    let mut s = test_scheduler(Limits::default());
    let w = worker(&mut s, now, 4, true, false);
    let old = worker(&mut s, now, 4, false, false);
    let j = s.submit(test_spec(40, 40, 10, "o.exr"), now);
    s.sizer.seed(j, CHEAP);
    (s, j, w, old)
}

#[test]
fn a_span_continues_only_into_wholly_pending_bands_row_major_with_consecutive_ids() {
    let now = Instant::now();
    let (mut s, j, w, old) = cheap_frame_and_two_workers(now);
    // Band 0 is partly taken: the span is the rest of it, one band.
    let single = s.lease(old, now).unwrap().unwrap();
    assert_eq!((single.tiles, single.rect), (1, Rect::new(0, 0, 10, 10)));
    let rest = s.lease(w, now).unwrap().unwrap();
    assert_eq!((rest.tiles, rest.rect), (3, Rect::new(10, 0, 30, 10)));
    // Bands 1-3 are wholly pending: one span of all three.
    let span = s.lease(w, now).unwrap().unwrap();
    assert_eq!((span.tiles, span.rect), (12, Rect::new(0, 10, 40, 30)));
    assert!(!span.png_segments, "an EXR frame");
    let parts = s.span_tiles(j, span.rect).unwrap();
    assert_eq!(parts, row_major(1..4, 4, 10));
    for (i, &p) in parts.iter().enumerate() {
        let id = span.id + i as u64;
        assert_eq!(s.tile_index(j, p), Some(4 + i as u32));
        s.check_lease(j, p, id, Some(w)).unwrap();
        assert!(s.check_lease(j, p, id + 1, Some(w)).is_err(), "{p:?}");
        assert!(s.check_lease(j, p, id, Some(old)).is_err(), "{p:?}");
    }
    // Bands 1 and 3 come back; band 2 stays out.
    for i in (0..4).chain(8..12) {
        s.return_lease(w, span.id + i, None, now).unwrap();
    }
    assert_eq!(s.queue_depth().tiles, 8);
    // Band 1 is wholly pending, band 2 is not: band 1 alone. Then band 3,
    // after the gap, in a lease of its own.
    let b1 = s.lease(w, now).unwrap().unwrap();
    assert_eq!((b1.tiles, b1.rect), (4, Rect::new(0, 10, 40, 10)));
    let b3 = s.lease(w, now).unwrap().unwrap();
    assert_eq!((b3.tiles, b3.rect), (4, Rect::new(0, 30, 40, 10)));
    assert_eq!(s.lease(w, now).unwrap(), None);
    for (l, band) in [(&b1, 1), (&b3, 3)] {
        let parts = s.span_tiles(j, l.rect).unwrap();
        assert_eq!(parts, row_major(band..band + 1, 4, 10));
        for (i, &p) in parts.iter().enumerate() {
            s.check_lease(j, p, l.id + i as u64, Some(w)).unwrap();
        }
    }
    // A band re-queued in part is leased in part: a worker that takes no
    // spans takes band 1's first tile back, and the span is the rest.
    for i in 0..4 {
        s.return_lease(w, b1.id + i, None, now).unwrap();
    }
    let one = s.lease(old, now).unwrap().unwrap();
    assert_eq!(one.rect, Rect::new(0, 10, 10, 10));
    let part = s.lease(w, now).unwrap().unwrap();
    assert_eq!((part.tiles, part.rect), (3, Rect::new(10, 10, 30, 10)));
}

#[test]
fn a_span_of_bands_stays_within_the_sizers_share_and_the_pixel_cap() {
    let now = Instant::now();
    // 4 tiles of 10 a band: 400 pixels a band; at most 1000 pixels.
    let mut s = test_scheduler(Limits {
        max_lease_pixels: 1000,
        ..Limits::default()
    });
    let w = worker(&mut s, now, 1, true, false);
    let j = s.submit(test_spec(40, 100, 10, "o.png"), now);
    s.sizer.seed(j, CHEAP);
    let l = s.lease(w, now).unwrap().unwrap();
    assert_eq!((l.tiles, l.rect), (8, Rect::new(0, 0, 40, 20)), "two bands");
    // A second of one thread is 11 tiles: two whole bands (8 tiles), as
    // a band more would be 12.
    let mut s = test_scheduler(Limits::default());
    let w = worker(&mut s, now, 1, true, false);
    let j = s.submit(test_spec(40, 100, 10, "o.exr"), now);
    s.sizer.seed(j, 1.0 / 1100.0);
    let l = s.lease(w, now).unwrap().unwrap();
    assert_eq!((l.tiles, l.rect), (8, Rect::new(0, 0, 40, 20)));
    // Less than a band's worth (3.5 tiles): part of the band, as before.
    s.sizer.seed(j, 1.0 / 350.0);
    let l = s.lease(w, now).unwrap().unwrap();
    assert_eq!((l.tiles, l.rect), (3, Rect::new(0, 20, 30, 10)));
}

#[test]
fn span_tiles_takes_whole_bands_and_refuses_near_misses() {
    let now = Instant::now();
    let mut s = test_scheduler(Limits {
        max_lease_pixels: 1200,
        max_segment_lease_pixels: 4096,
        ..Limits::default()
    });
    // 4 × 4 tiles of 10, the last band 5 rows high.
    let exr = s.submit(test_spec(40, 35, 10, "o.exr"), now);
    let ok = |s: &Scheduler, r: Rect| s.span_tiles(exr, r);
    assert_eq!(
        ok(&s, Rect::new(0, 0, 40, 30)).unwrap(),
        row_major(0..3, 4, 10)
    );
    let last = ok(&s, Rect::new(0, 20, 40, 15)).unwrap();
    let mut want = row_major(2..3, 4, 10);
    want.extend((0..4).map(|c| Rect::new(10 * c, 30, 10, 5)));
    assert_eq!(last, want, "down to the frame's bottom");
    assert_eq!(
        ok(&s, Rect::new(10, 10, 20, 10)).unwrap(),
        vec![Rect::new(10, 10, 10, 10), Rect::new(20, 10, 10, 10)],
        "part of one band, as before"
    );
    assert_eq!(ok(&s, Rect::new(30, 30, 10, 5)).unwrap().len(), 1);
    for bad in [
        Rect::new(0, 0, 40, 25),  // a band short of its end
        Rect::new(0, 5, 40, 20),  // off the grid
        Rect::new(0, 0, 30, 20),  // several bands, not full width
        Rect::new(10, 0, 30, 20), // several bands, not from the left
        Rect::new(0, 10, 40, 30), // past the bottom
        Rect::new(0, 0, 45, 10),  // past the right edge
        Rect::new(0, 0, 40, 40),  // past the bottom, and over the cap
        Rect::new(0, 0, 0, 10),
        Rect::new(0, 0, 40, 0),
        Rect::new(u32::MAX - 9, 0, 20, 10),
    ] {
        assert!(ok(&s, bad).is_err(), "{bad:?}");
    }
    // Over the float cap: 1200 pixels pass, 1600 do not.
    let exr2 = s.submit(test_spec(40, 80, 10, "o.exr"), now);
    assert!(s.span_tiles(exr2, Rect::new(0, 0, 40, 30)).is_ok());
    assert!(s.span_tiles(exr2, Rect::new(0, 0, 40, 40)).is_err());
    // A PNG frame's whole segments go up to the segment cap.
    let png = s.submit(test_spec(64, 80, 16, "o.png"), now);
    let whole = Rect::new(0, 0, 64, 64);
    assert_eq!(s.span_tiles(png, whole).unwrap().len(), 16);
    assert_eq!(s.span_tiles_as(png, whole, true).unwrap().len(), 16);
    assert!(
        s.span_tiles_as(png, whole, false).is_err(),
        "floats: the float cap"
    );
    assert!(s.span_tiles_as(png, Rect::new(0, 0, 64, 80), true).is_err());
    // The same rectangle of an EXR frame is floats: the float cap.
    let exr3 = s.submit(test_spec(64, 80, 16, "o.exr"), now);
    assert!(s.span_tiles(exr3, whole).is_err());
    assert!(s.span_tiles_as(exr3, whole, true).is_err());
    // Segments must be whole: with 24-row tiles, one band is not.
    let t24 = s.submit(test_spec(48, 80, 24, "o.png"), now);
    assert!(s.span_tiles_as(t24, Rect::new(0, 0, 48, 24), true).is_err());
    assert!(s.span_tiles_as(t24, Rect::new(0, 0, 48, 24), false).is_ok());
    assert_eq!(
        s.span_tiles_as(t24, Rect::new(0, 0, 48, 48), true)
            .unwrap()
            .len(),
        4
    );
    assert!(s
        .span_tiles_as(t24, Rect::new(0, 24, 48, 48), true)
        .is_err());
    assert!(
        s.span_tiles_as(t24, Rect::new(0, 72, 48, 8), true).is_err(),
        "72 is not a segment's first row"
    );
    assert!(
        s.span_tiles_as(t24, Rect::new(0, 0, 24, 48), true).is_err(),
        "not full width"
    );
    // Never more tiles than a worker heartbeats: 2^16 pass, more do not.
    let mut s = test_scheduler(Limits {
        max_lease_pixels: 1 << 30,
        ..Limits::default()
    });
    let tiny = s.submit(test_spec(1024, 1024, 2, "o.exr"), now);
    assert_eq!(
        s.span_tiles(tiny, Rect::new(0, 0, 1024, 256))
            .unwrap()
            .len(),
        1 << 16
    );
    assert!(s.span_tiles(tiny, Rect::new(0, 0, 1024, 258)).is_err());
}

/// Submits `spec`, measured as very cheap when `measured`, leases it to
/// `who` and cancels it: the lease `who` got.
fn first_lease(s: &mut Scheduler, who: WorkerId, spec: JobSpec, measured: bool) -> Lease {
    let now = Instant::now();
    let j = s.submit(spec, now);
    if measured {
        s.sizer.seed(j, CHEAP);
    }
    let l = s.lease(who, now).unwrap().unwrap();
    assert_eq!(l.job, j);
    s.cancel(j, now).unwrap();
    l
}

#[test]
fn png_segments_only_when_every_condition_holds() {
    let now = Instant::now();
    let mut s = test_scheduler(Limits::default());
    let enc = worker(&mut s, now, 16, true, true);
    let floats = worker(&mut s, now, 16, true, false);
    let no_spans = worker(&mut s, now, 16, false, true);
    let l = first_lease(&mut s, enc, test_spec(64, 64, 16, "o.png"), true);
    assert!(l.png_segments);
    assert_eq!((l.tiles, l.rect), (16, Rect::new(0, 0, 64, 64)));
    // Down to the bottom, 8 rows short of a segment; any case of "png".
    let l = first_lease(&mut s, enc, test_spec(64, 40, 16, "frame.PNG"), true);
    assert!(l.png_segments);
    assert_eq!(l.rect, Rect::new(0, 0, 64, 40));
    // EXR: the same bands, as floats.
    let l = first_lease(&mut s, enc, test_spec(64, 64, 16, "o.exr"), true);
    assert!(!l.png_segments);
    assert_eq!(l.rect, Rect::new(0, 0, 64, 64));
    // A worker without the encoder, or without spans.
    let l = first_lease(&mut s, floats, test_spec(64, 64, 16, "o.png"), true);
    assert!(!l.png_segments);
    assert_eq!(l.rect, Rect::new(0, 0, 64, 64));
    let l = first_lease(&mut s, no_spans, test_spec(64, 64, 16, "o.png"), true);
    assert!(!l.png_segments);
    assert_eq!(l.tiles, 1);
    // Not measured yet: one tile, as floats, also when the frame is two
    // tiles wide (one tile is half a band).
    let l = first_lease(&mut s, enc, test_spec(64, 64, 16, "o.png"), false);
    assert!(!l.png_segments);
    assert_eq!(l.rect, Rect::new(0, 0, 16, 16));
    let l = first_lease(&mut s, enc, test_spec(24, 20, 16, "o.png"), false);
    assert!(!l.png_segments);
    assert_eq!(l.rect, Rect::new(0, 0, 16, 16));
    // A partial band: the rest of it, as floats; then whole bands.
    let j = s.submit(test_spec(64, 64, 16, "o.png"), now);
    s.sizer.seed(j, CHEAP);
    assert_eq!(s.lease(no_spans, now).unwrap().unwrap().tiles, 1);
    let part = s.lease(enc, now).unwrap().unwrap();
    assert!(!part.png_segments);
    assert_eq!(part.rect, Rect::new(16, 0, 48, 16));
    let bands = s.lease(enc, now).unwrap().unwrap();
    assert!(bands.png_segments);
    assert_eq!(bands.rect, Rect::new(0, 16, 64, 48));
    s.cancel(j, now).unwrap();

    // 24-row tiles, 48 × 80: bands end at rows 24, 48, 72 and 80. With
    // room for one band a lease, the band is not whole segments: floats.
    let band = 48 * 24;
    let mut s = test_scheduler(Limits {
        max_lease_pixels: band,
        max_segment_lease_pixels: band,
        ..Limits::default()
    });
    let enc = worker(&mut s, now, 16, true, true);
    let l = first_lease(&mut s, enc, test_spec(48, 80, 24, "o.png"), true);
    assert!(!l.png_segments);
    assert_eq!(l.rect, Rect::new(0, 0, 48, 24));
    // Room for two or three bands: two, rows 0-48, whole segments (three
    // would end at row 72, in a segment).
    for bands in [2, 3] {
        s.cfg.max_segment_lease_pixels = bands * band;
        let l = first_lease(&mut s, enc, test_spec(48, 80, 24, "o.png"), true);
        assert!(l.png_segments, "{bands}");
        assert_eq!(l.rect, Rect::new(0, 0, 48, 48));
    }
    // Four: the whole frame, to its bottom.
    s.cfg.max_segment_lease_pixels = 4 * band;
    let l = first_lease(&mut s, enc, test_spec(48, 80, 24, "o.png"), true);
    assert!(l.png_segments);
    assert_eq!(l.rect, Rect::new(0, 0, 48, 80));
    // Each lease's rectangle is one `span_tiles_as` takes as the kind of
    // upload the lease asks for. Three bands a lease: rows 0-48 and 48-80
    // (to the bottom), both segments.
    s.cfg.max_segment_lease_pixels = 3 * band;
    let j = s.submit(test_spec(48, 80, 24, "o.png"), now);
    s.sizer.seed(j, CHEAP);
    let a = s.lease(enc, now).unwrap().unwrap();
    let b = s.lease(enc, now).unwrap().unwrap();
    assert_eq!(
        (a.rect, b.rect),
        (Rect::new(0, 0, 48, 48), Rect::new(0, 48, 48, 32))
    );
    assert!(a.png_segments && b.png_segments);
    for l in [&a, &b] {
        assert_eq!(s.span_tiles_as(j, l.rect, true).unwrap().len(), 4);
        assert!(
            s.span_tiles_as(j, l.rect, false).is_err(),
            "over the float cap"
        );
    }
    s.cancel(j, now).unwrap();
    // One band a lease: every band as floats (rows 0, 24, 48 and 72 start
    // them; only 0 and 48 start a segment, and no band is whole segments).
    s.cfg.max_segment_lease_pixels = band;
    let j = s.submit(test_spec(48, 80, 24, "o.png"), now);
    s.sizer.seed(j, CHEAP);
    for y in [0, 24, 48, 72] {
        let l = s.lease(enc, now).unwrap().unwrap();
        assert_eq!(l.rect, Rect::new(0, y, 48, 24.min(80 - y)));
        assert!(!l.png_segments, "{y}");
        assert_eq!(s.span_tiles_as(j, l.rect, false).unwrap().len(), 2);
        assert!(s.span_tiles_as(j, l.rect, true).is_err());
    }
}

#[test]
fn expiry_heartbeats_and_returns_of_a_multi_band_span_cover_every_tile() {
    let t0 = Instant::now();
    let mut s = test_scheduler(Limits::default());
    let w = worker(&mut s, t0, 4, true, true);
    let j = s.submit(test_spec(64, 64, 16, "o.png"), t0);
    s.sizer.seed(j, CHEAP);
    let span = s.lease(w, t0).unwrap().unwrap();
    assert!(span.png_segments);
    assert_eq!(span.tiles, 16);
    let ids: Vec<LeaseId> = (0..16).map(|i| span.id + i).collect();
    // Heartbeats renew every tile's lease.
    let t1 = t0 + Duration::from_secs(4);
    assert_eq!(s.heartbeat(w, &ids, t1).unwrap(), Vec::<LeaseId>::new());
    assert_eq!(s.expire(t0 + Duration::from_secs(6)), 0);
    assert_eq!(s.queue_depth().tiles, 0);
    // Silence: every tile's lease runs out and every tile is re-queued.
    let t2 = t0 + Duration::from_secs(10);
    assert_eq!(s.expire(t2), 16);
    assert_eq!(s.queue_depth().tiles, 16);
    assert_eq!(s.heartbeat(w, &ids, t2).unwrap(), ids);
    // The same span goes out again, whole, under new ids.
    let w2 = worker(&mut s, t2, 4, true, true);
    let again = s.lease(w2, t2).unwrap().unwrap();
    assert_eq!((again.rect, again.tiles), (span.rect, 16));
    assert!(again.png_segments);
    assert!(again.id >= span.id + 16);
    // Its render fails (a NaN): every tile comes back, each counted once.
    for i in 0..16 {
        s.return_lease(w2, again.id + i, Some("NaN in pixel (3, 4)"), t2)
            .unwrap();
    }
    assert_eq!(s.queue_depth().tiles, 16);
    assert_eq!(s.counters().tiles_requeued, 32);
    assert!(s.take_failed().is_empty(), "two failures a tile, of five");
    let w3 = worker(&mut s, t2, 4, true, true);
    let third = s.lease(w3, t2).unwrap().unwrap();
    assert_eq!((third.rect, third.tiles), (span.rect, 16));
    // Its result: every tile done, the job complete.
    let parts = s.span_tiles_as(j, third.rect, true).unwrap();
    let mut last = false;
    for &p in &parts {
        match s.accept_tile(j, p, 1, t2).unwrap() {
            Accepted::New { last: l } => last = l,
            Accepted::Ignored => panic!("{p:?} ignored"),
        }
    }
    assert!(last);
}

/// A 16-thread worker on the cheap scene of docs/benchmarks.md (4,734 ns
/// a pixel on one core): a segment lease is about a second of its time,
/// 3.4 Mpixel, where a float lease stops at `max_lease_pixels`.
#[test]
fn a_segment_lease_is_about_a_second_of_a_16_thread_worker_on_the_cheap_scene() {
    let now = Instant::now();
    let cost = 4_734e-9;
    let mut s = test_scheduler(Limits::default());
    let enc = worker(&mut s, now, 16, true, true);
    let floats = worker(&mut s, now, 16, true, false);
    // 1920 wide in 64-pixel tiles: 30 tiles and 122,880 pixels a band.
    let j = s.submit(test_spec(1920, 4096, 64, "o.png"), now);
    s.sizer.seed(j, cost);
    let l = s.lease(enc, now).unwrap().unwrap();
    assert!(l.png_segments);
    let pixels = l.rect.pixel_count() as f64;
    let seconds = pixels * cost / 16.0;
    // 16 / (4,734 ns × 4,096) = 825 tiles' worth: 27 whole bands.
    assert_eq!((l.tiles, l.rect), (27 * 30, Rect::new(0, 0, 1920, 27 * 64)));
    assert!((0.9..=1.0).contains(&seconds), "{seconds} s");
    assert!(pixels > 3.3e6, "{pixels}");
    let f = s.lease(floats, now).unwrap().unwrap();
    assert!(!f.png_segments);
    // 2^20 pixels: 8 bands (983,040 pixels), a third of a second.
    assert_eq!(f.rect, Rect::new(0, 27 * 64, 1920, 8 * 64));
}

/// A segment lease can only be whole bands: from half a band of the
/// worker's share it takes at least one (0.65 of a band gets the band, as
/// segments), above one band the whole bands within the share (1.65 gets
/// one). Under half a band the share stays as it is (floats, part of the
/// band), and a float lease takes the whole bands within its share or the
/// share itself. (An expensive scene's second of 16 threads is about one
/// band of an 8192-pixel-wide frame: without this its leases were never
/// segments.)
#[test]
fn a_segment_lease_takes_a_whole_band_from_half_a_band_of_share() {
    let now = Instant::now();
    let mut s = test_scheduler(Limits::default());
    let enc = worker(&mut s, now, 1, true, true);
    let floats = worker(&mut s, now, 1, true, false);
    let target = Limits::default().lease_target.as_secs_f64();
    // 160 × 64 in tiles of 16: bands of 10 tiles of 256 pixels.
    for (share, who, tiles, segments) in [
        (4.5, enc, 4, false),
        (6.5, enc, 10, true),
        (16.5, enc, 10, true),
        (25.5, enc, 20, true),
        (6.5, floats, 6, false),
        (16.5, floats, 10, false),
    ] {
        let j = s.submit(test_spec(160, 64, 16, "o.png"), now);
        // One thread renders `share` tiles in the lease target.
        s.sizer.seed(j, target / (share * 256.0));
        let l = s.lease(who, now).unwrap().unwrap();
        assert_eq!(
            (l.job, l.tiles, l.png_segments),
            (j, tiles, segments),
            "a share of {share} tiles"
        );
        let rows = if tiles >= 10 { 16 * tiles / 10 } else { 16 };
        assert_eq!(l.rect.h, rows, "a share of {share} tiles");
        s.cancel(j, now).unwrap();
    }
}

/// What the monitor and `/metrics` see of a worker's leases: as few rects
/// as cover exactly its leased tiles (a span of whole bands is one), and
/// exactly those, when some of a span's tiles came back.
#[test]
fn a_worker_s_leases_show_as_the_rects_they_cover_exactly() {
    let now = Instant::now();
    let (mut s, j, w, old) = cheap_frame_and_two_workers(now);
    let single = s.lease(old, now).unwrap().unwrap();
    let rest = s.lease(w, now).unwrap().unwrap();
    let span = s.lease(w, now).unwrap().unwrap();
    assert_eq!((rest.tiles, span.tiles), (3, 12));
    let held = |s: &Scheduler, who| {
        s.workers(now)
            .into_iter()
            .find(|i| i.id == who)
            .unwrap()
            .leases
    };
    assert_eq!(held(&s, old), vec![(j, single.rect)]);
    assert_eq!(
        held(&s, w),
        vec![(j, rest.rect), (j, Rect::new(0, 10, 40, 30))]
    );
    // Band 2 and the second tile of band 1 come back.
    for i in [1, 4, 5, 6, 7] {
        s.return_lease(w, span.id + i, None, now).unwrap();
    }
    assert_eq!(
        held(&s, w),
        vec![
            (j, rest.rect),
            (j, Rect::new(0, 10, 10, 10)),
            (j, Rect::new(20, 10, 20, 10)),
            (j, Rect::new(0, 30, 40, 10)),
        ]
    );
    // The queue counts the five tiles back as waiting.
    assert_eq!(s.queue_depth().tiles, 5);
}
