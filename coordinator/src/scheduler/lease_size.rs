//! Lease sizing: how many tiles one lease covers, from the render cost the
//! coordinator measures.
//!
//! A cheap frame in 64×64 tiles costs a worker a few milliseconds a tile, so
//! a farm of many cores would spend most of the coordinator's time on the
//! lease and upload of each tile. A worker that registers with
//! `multi_tile` is given leases of several tiles instead (a *span*): it
//! renders their union as one rectangle and uploads it once; the
//! coordinator splits it back into its tiles, which are validated, stored
//! and stitched one by one as before. Tile size never changes a pixel, so
//! neither does a span.
//!
//! A span is adjacent tiles of one band, or whole bands: one that starts at
//! the first tile of a band and takes all of it continues into the next
//! bands while every tile of each is pending (never leased, or re-queued),
//! within the sizer's share, the pixel cap, [`MAX_SPAN_TILES`] and the
//! band window. Its tiles are in band order (band by band, left to right),
//! their lease ids consecutive in that order, and its rectangle their
//! union: full-width rows. A band partly taken gives a span of the rest of
//! that band only.
//!
//! *Segment leases.* To a worker that also encodes PNG segments with the
//! coordinator's encoder (`RegisterRequest.png_encoder`), a span of whole
//! bands of a PNG frame whose rows are whole 16-row segments goes as a
//! segment lease (`Lease.png_segments`): the worker uploads encoded
//! segments, at most about 4.5 bytes a pixel (a cheap scene's 0.55) instead
//! of 12, so such a lease may hold up to [`Limits::max_segment_lease_pixels`]
//! (2²², where a second of 16 threads on the cheap scene is 3.4 Mpixel) and
//! the window counts its bands at that cost (see the `window` module).
//! With tiles whose height is not a multiple of 16, the most bands that
//! end on a segment's edge (or the frame's bottom) are taken; when none
//! do, the lease is floats, as for any other worker or format.
//!
//! The rule ([`tiles_per_lease`]): a job's cost is measured in
//! core-seconds per pixel from its completed leases (the time the worker
//! says it spent rendering the lease, times the threads it registered
//! with, over the lease's pixels), smoothed over the last few leases. The
//! render time is the worker's, not the coordinator's clock from grant to
//! result: on a saturated coordinator that is mostly the upload waiting
//! its turn, and leases would shrink as the coordinator slows, feeding its
//! load. A worker that does not say (older than `TileHeader.render_micros`)
//! is measured from grant to result, and a reported time is never taken
//! above that ([`render_time`]). A lease then gets as many
//! tiles as `threads` cores render in about [`Limits::lease_target`], at
//! least one, at most [`Limits::max_lease_pixels`] pixels
//! ([`Limits::max_segment_lease_pixels`] for a segment lease), as whole
//! bands when they fit, the rest of the band otherwise (a segment lease,
//! which can only be whole bands, takes one band when the share is
//! between half a band and one). A job submitted while an
//! unfinished job of the same bundle and camera has a measured cost (the
//! next frame of a sequence, the same scene again) starts from that cost,
//! and jobs submitted together before any was measured all start from the
//! first measurement of any of them; otherwise, until
//! it has a measurement, its leases are single tiles (they make the first
//! measurements): on a busy farm every worker asking meanwhile got one, and
//! a new frame began with hundreds of single-tile leases. A worker that does not
//! announce `multi_tile` always gets one tile per lease.
//!
//! [`Limits::lease_target`]: crate::limits::Limits::lease_target
//! [`Limits::max_lease_pixels`]: crate::limits::Limits::max_lease_pixels
//! [`Limits::max_segment_lease_pixels`]: crate::limits::Limits::max_segment_lease_pixels

use super::{JobId, WorkerId};
use std::collections::{HashMap, HashSet};
use std::time::Duration;

/// The most tiles in one span, whatever the sizing says: a worker
/// heartbeats one lease id per tile (8 bytes each in a message of at most
/// 4 MiB), and `trevi-worker` takes no more ids than this from one lease
/// (worker/src/lib.rs, `span_ids`). Only spans of several bands of small
/// tiles come near it (2²² pixels in 8×8 tiles).
pub const MAX_SPAN_TILES: u32 = 1 << 16;

/// Weight of a new measurement in a job's smoothed cost.
pub(super) const SMOOTHING: f64 = 0.25;

/// How many tiles of `tile_pixels` pixels a lease for a worker of `threads`
/// threads gets when its job costs `cost` core-seconds per pixel (`None`:
/// not measured yet): enough for about `target` of the worker's time, at
/// least 1, and at most `max_pixels` pixels (but always at least one tile).
pub fn tiles_per_lease(
    cost: Option<f64>,
    threads: u32,
    tile_pixels: u64,
    target: Duration,
    max_pixels: u64,
) -> u32 {
    let Some(cost) = cost.filter(|c| c.is_finite() && *c > 0.0) else {
        return 1;
    };
    let tile_pixels = tile_pixels.max(1);
    let by_time = target.as_secs_f64() * f64::from(threads.max(1)) / (cost * tile_pixels as f64);
    let by_size = (max_pixels / tile_pixels).max(1);
    // `as` saturates a huge or infinite quotient; floor keeps a lease at or
    // under the target.
    let by_time = by_time.floor().max(1.0) as u64;
    by_time.min(by_size).min(u64::from(u32::MAX)) as u32
}

/// The render time a result measures: what the worker `reported`, never
/// more than the lease's time from grant to result (`granted_to_result`,
/// the coordinator's own clock, which a render cannot exceed); that time
/// itself when the worker did not say.
pub fn render_time(granted_to_result: Duration, reported: Option<Duration>) -> Duration {
    reported.map_or(granted_to_result, |r| r.min(granted_to_result))
}

/// The scheduler's lease sizing state: which workers take spans, and each
/// running job's measured cost.
#[derive(Debug, Default)]
pub struct LeaseSizer {
    multi_tile: HashSet<WorkerId>,
    /// Workers that upload encoded PNG segments.
    segments: HashSet<WorkerId>,
    /// Core-seconds per pixel, smoothed.
    cost: HashMap<JobId, f64>,
}

impl LeaseSizer {
    /// `worker` said it renders leases of several tiles.
    pub fn allow_spans(&mut self, worker: WorkerId) {
        self.multi_tile.insert(worker);
    }

    /// Whether `worker` takes leases of several tiles ([`Self::allow_spans`]).
    pub fn takes_spans(&self, worker: WorkerId) -> bool {
        self.multi_tile.contains(&worker)
    }

    /// `worker` said it encodes PNG segments with the coordinator's encoder.
    pub fn allow_segments(&mut self, worker: WorkerId) {
        self.segments.insert(worker);
    }

    /// Whether `worker` uploads PNG segments ([`Self::allow_segments`]).
    pub fn takes_segments(&self, worker: WorkerId) -> bool {
        self.segments.contains(&worker)
    }

    /// Keeps only the workers `known` says still exist.
    pub fn retain_workers(&mut self, known: impl Fn(WorkerId) -> bool) {
        self.multi_tile.retain(|&w| known(w));
        self.segments.retain(|&w| known(w));
    }

    /// A lease of `job` covering `pixels` pixels took a worker of `threads`
    /// threads `took` from grant to result.
    pub fn observe(&mut self, job: JobId, took: Duration, threads: u32, pixels: u64) {
        if pixels == 0 {
            return;
        }
        let sample = took.as_secs_f64() * f64::from(threads.max(1)) / pixels as f64;
        if !sample.is_finite() {
            return;
        }
        self.cost
            .entry(job)
            .and_modify(|c| *c += SMOOTHING * (sample - *c))
            .or_insert(sample);
    }

    /// Starts `job` from `cost` (that of a job like it), as if measured.
    pub fn seed(&mut self, job: JobId, cost: f64) {
        if cost.is_finite() && cost > 0.0 {
            self.cost.insert(job, cost);
        }
    }

    /// The job's smoothed cost in core-seconds per pixel, if measured.
    pub fn cost(&self, job: JobId) -> Option<f64> {
        self.cost.get(&job).copied()
    }

    /// Forgets a job that ended.
    pub fn forget_job(&mut self, job: JobId) {
        self.cost.remove(&job);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scheduler::test_spec;

    const S: Duration = Duration::from_secs(1);

    /// A scheduler with room for any test frame and a worker of `threads`
    /// threads named `name` that takes spans.
    fn scheduler_with_span_worker(
        now: std::time::Instant,
        name: &str,
        threads: u32,
    ) -> (crate::scheduler::Scheduler, WorkerId) {
        let mut s = crate::scheduler::test_scheduler(crate::limits::Limits::default());
        let w = s.register_worker(now, None);
        s.describe_worker(w, name, threads);
        s.allow_spans(w);
        (s, w)
    }

    #[test]
    fn an_unmeasured_job_gets_one_tile() {
        assert_eq!(tiles_per_lease(None, 16, 4096, S, 1 << 20), 1);
        assert_eq!(tiles_per_lease(Some(0.0), 16, 4096, S, 1 << 20), 1);
        assert_eq!(tiles_per_lease(Some(f64::NAN), 16, 4096, S, 1 << 20), 1);
    }

    #[test]
    fn a_lease_holds_about_the_target_of_the_workers_time() {
        // 0.01 core-seconds per 64×64 tile, 16 threads: 1600 tiles a second,
        // capped by the size limit (2^20 / 4096 = 256 tiles).
        let cost = 0.01 / 4096.0;
        assert_eq!(tiles_per_lease(Some(cost), 16, 4096, S, 1 << 20), 256);
        // Without the cap: exactly 1600 (floor of 1600 ± rounding).
        let n = tiles_per_lease(Some(cost), 16, 4096, S, u64::MAX);
        assert!((1599..=1600).contains(&n), "{n}");
        // One thread, 0.1 s a tile: 10 tiles a second.
        let n = tiles_per_lease(Some(0.1 / 4096.0), 1, 4096, S, u64::MAX);
        assert!((9..=10).contains(&n), "{n}");
        // Half the target, half the tiles.
        let n = tiles_per_lease(Some(0.1 / 4096.0), 1, 4096, S / 2, u64::MAX);
        assert!((4..=5).contains(&n), "{n}");
    }

    #[test]
    fn an_expensive_tile_is_still_leased_alone() {
        // 3 core-seconds a tile on 2 threads: 1.5 s > target.
        assert_eq!(tiles_per_lease(Some(3.0 / 4096.0), 2, 4096, S, 1 << 20), 1);
        // A tile bigger than the size limit: one tile, never zero.
        assert_eq!(tiles_per_lease(Some(1e-9), 64, 1 << 21, S, 1 << 20), 1);
    }

    #[test]
    fn zero_threads_count_as_one() {
        assert_eq!(
            tiles_per_lease(Some(0.1 / 4096.0), 0, 4096, S, u64::MAX),
            tiles_per_lease(Some(0.1 / 4096.0), 1, 4096, S, u64::MAX)
        );
    }

    #[test]
    fn the_cost_is_smoothed_over_leases() {
        let mut s = LeaseSizer::default();
        assert_eq!(s.cost(1), None);
        // 1 s on 4 threads for 1000 pixels: 0.004 core-seconds a pixel.
        s.observe(1, Duration::from_secs(1), 4, 1000);
        assert_eq!(s.cost(1), Some(0.004));
        // A second lease twice as costly moves it a quarter of the way.
        s.observe(1, Duration::from_secs(2), 4, 1000);
        let c = s.cost(1).unwrap();
        assert!((c - 0.005).abs() < 1e-12, "{c}");
        s.observe(1, Duration::from_secs(1), 4, 0);
        assert_eq!(s.cost(1), Some(c));
        s.forget_job(1);
        assert_eq!(s.cost(1), None);
    }

    #[test]
    fn a_measured_job_leases_spans_of_one_band_each_tile_under_its_own_lease() {
        use crate::scheduler::Accepted;
        use std::time::Instant;
        use trevi_core::tile::Rect;
        let now = Instant::now();
        let (mut s, w) = scheduler_with_span_worker(now, "new", 4);
        let old = s.register_worker(now, None);
        s.describe_worker(old, "old", 4);
        // 10 tiles of 10×10 a band, two bands.
        let job = s.submit(test_spec(100, 20, 10, "o.png"), now);
        // Not measured yet: one tile.
        let first = s.lease(w, now).unwrap().unwrap();
        assert_eq!((first.tiles, first.rect), (1, Rect::new(0, 0, 10, 10)));
        // Its result 1 ms later: 4 threads × 1 ms / 100 pixels. A second of
        // 4 threads is 1000 such tiles: the span takes the band's other 9.
        let t = now + Duration::from_millis(1);
        assert_eq!(
            s.accept_tile(job, first.rect, 1, t).unwrap(),
            Accepted::New { last: false }
        );
        let c = s.measured_cost(job).unwrap();
        assert!((c - 4e-5).abs() < 1e-12, "{c}");
        let span = s.lease(w, t).unwrap().unwrap();
        assert_eq!((span.tiles, span.rect), (9, Rect::new(10, 0, 90, 10)));
        // A worker that did not announce spans: one tile, of the next band.
        let single = s.lease(old, t).unwrap().unwrap();
        assert_eq!((single.tiles, single.rect), (1, Rect::new(0, 10, 10, 10)));
        // The span splits back into its tiles, each under its own lease.
        let parts = s.span_tiles(job, span.rect).unwrap();
        let want: Vec<Rect> = (1..10).map(|i| Rect::new(10 * i, 0, 10, 10)).collect();
        assert_eq!(parts, want);
        for (i, &p) in parts.iter().enumerate() {
            let lease = span.id + i as u64;
            s.check_lease(job, p, lease, Some(w)).unwrap();
            assert!(s.check_lease(job, p, lease, Some(old)).is_err());
            assert_eq!(
                s.accept_tile(job, p, 1, t).unwrap(),
                Accepted::New { last: false }
            );
        }
        // Rectangles that are not spans of whole tiles of one band.
        for bad in [
            Rect::new(10, 10, 25, 10),
            Rect::new(5, 10, 20, 10),
            Rect::new(10, 0, 20, 20),
            Rect::new(90, 10, 20, 10),
        ] {
            assert!(s.span_tiles(job, bad).is_err(), "{bad:?}");
        }
    }

    /// A span's result measures the job once, however many tiles it has:
    /// the cost moves a quarter of the way to it, as for one tile.
    #[test]
    fn a_span_s_result_is_one_measurement_of_the_cost() {
        use std::time::Instant;
        let now = Instant::now();
        let (mut s, w) = scheduler_with_span_worker(now, "w", 4);
        // 10 tiles of 10×10 a band, ten bands.
        let job = s.submit(test_spec(100, 100, 10, "o.exr"), now);
        // The first tile: 4 threads × 1 ms / 100 pixels = 4e-5.
        let first = s.lease(w, now).unwrap().unwrap();
        let t = now + Duration::from_millis(1);
        s.accept_tile(job, first.rect, 1, t).unwrap();
        let c0 = s.measured_cost(job).unwrap();
        assert!((c0 - 4e-5).abs() < 1e-12, "{c0}");
        // A span whose result takes twice as long a pixel.
        let span = s.lease(w, t).unwrap().unwrap();
        assert!(span.tiles > 1, "{span:?}");
        let px = span.rect.pixel_count() as f64;
        let took = Duration::from_secs_f64(2.0 * c0 * px / 4.0);
        let t2 = t + took;
        for p in s.span_tiles(job, span.rect).unwrap() {
            s.accept_tile(job, p, 1, t2).unwrap();
        }
        let c = s.measured_cost(job).unwrap();
        let want = c0 + SMOOTHING * (2.0 * c0 - c0);
        assert!((c - want).abs() < 1e-9 * want, "{c} vs {want}");
    }

    #[test]
    fn the_render_time_is_the_workers_within_the_lease() {
        let ms = Duration::from_millis;
        // An older worker: grant to result.
        assert_eq!(render_time(ms(900), None), ms(900));
        // A worker that says: its time, not the queueing around it.
        assert_eq!(render_time(ms(900), Some(ms(40))), ms(40));
        // A render cannot take longer than its lease was out.
        assert_eq!(render_time(ms(900), Some(ms(5000))), ms(900));
        assert_eq!(render_time(ms(0), Some(ms(1))), ms(0));
    }

    /// A saturated coordinator: results arrive long after the render ended.
    /// With the worker's render time, the measured cost and the leases stay
    /// what the render costs; without it (an older worker) they follow the
    /// queueing.
    #[test]
    fn a_slow_coordinator_does_not_shrink_leases_of_workers_that_report() {
        use std::time::Instant;
        let run = |report: bool| {
            let now = Instant::now();
            let (mut s, w) = scheduler_with_span_worker(now, "w", 16);
            // 64 tiles of 64×64 a band.
            let job = s.submit(test_spec(4096, 4096, 64, "o.png"), now);
            // Every lease renders in 2 ms a tile on 16 threads (0.032
            // core-seconds a tile; a second of 16 threads is 500 tiles, a
            // band has 64), and its result waits 50 ms a tile in the
            // coordinator's queue before it is taken.
            let mut t = now;
            let mut sizes = Vec::new();
            for _ in 0..12 {
                let l = s.lease(w, t).unwrap().unwrap();
                sizes.push(l.tiles);
                let render = Duration::from_millis(2) * l.tiles;
                t += render + Duration::from_millis(50) * l.tiles;
                for p in s.span_tiles(job, l.rect).unwrap() {
                    s.accept_rendered(job, p, 1, report.then_some(render), t)
                        .unwrap();
                }
            }
            (s.measured_cost(job).unwrap(), sizes)
        };
        let (cost, sizes) = run(true);
        let want = 0.002 * 16.0 / 4096.0;
        assert!((cost - want).abs() < want * 1e-9, "{cost} vs {want}");
        // After the first (measuring) tile, the rest of its band, then
        // whole bands: 500 tiles' worth, capped at 2^20 pixels (256 tiles,
        // four bands).
        assert_eq!(sizes[..3], [1, 63, 256]);
        assert!(sizes[2..].iter().all(|&n| n == 256), "{sizes:?}");
        // Grant to result: the queueing counts as render (52 ms a tile,
        // 26 times the cost), and a lease is what 16 threads render in a
        // second at that cost: 16 / (0.052 × 16) = 19.2 tiles.
        let (cost, sizes) = run(false);
        assert!((cost - 26.0 * want).abs() < want * 1e-6, "{cost} vs {want}");
        assert_eq!(sizes[..2], [1, 19]);
        assert!(sizes[1..].iter().all(|&n| n <= 19), "{sizes:?}");
    }

    /// A job of the same bundle and camera as a measured one starts from
    /// its cost: its first lease is already a span. Another camera, or
    /// another bundle, starts unmeasured.
    #[test]
    fn a_job_like_a_measured_one_starts_from_its_cost() {
        use std::time::Instant;
        use trevi_core::tile::Rect;
        let now = Instant::now();
        let (mut s, w) = scheduler_with_span_worker(now, "w", 4);
        let first = s.submit(spec("h", "c"), now);
        let l = s.lease(w, now).unwrap().unwrap();
        assert_eq!((l.job, l.tiles), (first, 1));
        let t = now + Duration::from_millis(1);
        s.accept_rendered(first, l.rect, 1, Some(Duration::from_millis(1)), t)
            .unwrap();
        let cost = s.measured_cost(first).unwrap();
        let other_camera = s.submit(spec("h", "d"), t);
        let other_bundle = s.submit(spec("g", "c"), t);
        let like = s.submit(spec("h", "c"), t);
        assert_eq!(s.measured_cost(like), Some(cost));
        assert_eq!(s.measured_cost(other_camera), None);
        assert_eq!(s.measured_cost(other_bundle), None);
        // The first job's first band, then the new one's: a span at once.
        let span = s.lease(w, t).unwrap().unwrap();
        assert_eq!((span.job, span.tiles), (first, 9));
        s.cancel(first, t).unwrap();
        s.cancel(other_camera, t).unwrap();
        s.cancel(other_bundle, t).unwrap();
        // Its first lease: both its bands (1000 tiles' worth), whole.
        let l = s.lease(w, t).unwrap().unwrap();
        assert_eq!((l.job, l.tiles), (like, 20));
        assert_eq!(l.rect, Rect::new(0, 0, 100, 20));
    }

    /// A 100×20 frame in tiles of 10 of bundle `hash`, camera `camera`.
    fn spec(hash: &str, camera: &str) -> crate::scheduler::JobSpec {
        crate::scheduler::JobSpec {
            bundle_hash: hash.into(),
            camera: camera.into(),
            ..test_spec(100, 20, 10, "o.png")
        }
    }

    /// Jobs of one shot submitted together, none measured (a sequence's
    /// first frames): the first measurement of any of them is every
    /// unmeasured sibling's first estimate, so their first leases are
    /// spans; another camera's job stays unmeasured, and a sibling already
    /// measured keeps its own cost.
    #[test]
    fn the_first_measurement_of_a_shot_sizes_its_unmeasured_siblings() {
        use std::time::Instant;
        let now = Instant::now();
        let (mut s, w) = scheduler_with_span_worker(now, "w", 4);
        let a = s.submit(spec("h", "c"), now);
        let b = s.submit(spec("h", "c"), now);
        let other_camera = s.submit(spec("h", "d"), now);
        let measured = s.submit(spec("h", "c"), now);
        s.sizer.seed(measured, 0.5);
        assert_eq!(s.measured_cost(b), None);
        let l = s.lease(w, now).unwrap().unwrap();
        assert_eq!((l.job, l.tiles), (a, 1));
        let t = now + Duration::from_millis(1);
        s.accept_rendered(a, l.rect, 1, Some(Duration::from_millis(1)), t)
            .unwrap();
        let cost = s.measured_cost(a).unwrap();
        assert_eq!(s.measured_cost(b), Some(cost));
        assert_eq!(s.measured_cost(other_camera), None);
        assert_eq!(s.measured_cost(measured), Some(0.5));
        // A second measurement of `a` moves only `a`'s cost.
        let l = s.lease(w, t).unwrap().unwrap();
        assert_eq!(l.job, a);
        let tile = trevi_core::tile::Rect::new(l.rect.x, l.rect.y, 10, 10);
        s.accept_rendered(a, tile, 1, Some(Duration::from_millis(900)), t + S)
            .unwrap();
        assert_ne!(s.measured_cost(a), Some(cost));
        assert_eq!(s.measured_cost(b), Some(cost));
        s.cancel(a, t).unwrap();
        let l = s.lease(w, t).unwrap().unwrap();
        assert_eq!(l.job, b);
        assert!(l.tiles > 1, "{l:?}");
    }

    #[test]
    fn only_announced_workers_take_spans() {
        let mut s = LeaseSizer::default();
        s.allow_spans(7);
        assert!(s.takes_spans(7));
        assert!(!s.takes_spans(8));
        s.retain_workers(|w| w != 7);
        assert!(!s.takes_spans(7));
    }
}
