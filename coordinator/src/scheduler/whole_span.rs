//! Taking a span whole: the result of a lease of several tiles that cannot
//! be cut (encoded PNG segments, docs/farm.md "Encoded segments") is
//! checked and then taken under one lock, with the job looked up once, the
//! span's leases walked in id order, its cost measured once and its worker
//! credited once, instead of tile by tile. On a big farm each upload is
//! hundreds of tiles, and this is the part of ingest that runs under the
//! farm's one lock (docs/benchmarks.md, "Stage 6").

use super::results::{check_holder, ray_shares};
use super::types::{JobId, LeaseId, SchedError};
use super::window::TileState;
use super::Scheduler;
use crate::workers::WorkerId;
use std::time::{Duration, Instant};
use trevi_core::tile::Rect;

/// What [`Scheduler::check_span`] found of a span.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SpanCheck {
    /// The indices of the span's tiles, in the order of its parts; empty
    /// when the job is over.
    pub tiles: Vec<u32>,
    /// Whether it can be taken whole: the job is not over and none of its
    /// tiles is done.
    pub open: bool,
}

impl Scheduler {
    /// [`Scheduler::check_lease`] for every tile of a span at once: `parts`
    /// are its tiles, whose leases are `lease`, `lease + 1`, …, and
    /// `worker` is who uploads it (anyone when `None`). The first tile
    /// whose lease is not `worker`'s is the error, as `check_lease` gives
    /// it; a tile already done passes, and makes the span not open.
    pub fn check_span(
        &self,
        job: JobId,
        parts: &[Rect],
        lease: LeaseId,
        worker: Option<WorkerId>,
    ) -> Result<SpanCheck, SchedError> {
        let j = self.jobs.get(&job).ok_or(SchedError::UnknownJob(job))?;
        if j.state.is_final() {
            return Ok(SpanCheck {
                tiles: Vec::new(),
                open: false,
            });
        }
        // The live leases among the span's ids, in id order. An id past
        // u64::MAX (a hostile lease id) wraps, finds none, and is refused
        // below unless a past lease has it.
        let mut held = self.leases.in_range(lease, parts.len() as u64).peekable();
        let mut tiles = Vec::with_capacity(parts.len());
        let mut open = true;
        for (i, &part) in parts.iter().enumerate() {
            let id = lease.wrapping_add(i as u64);
            let idx = j
                .window
                .tile_index(part)
                .ok_or(SchedError::NotATile(part, job))?;
            tiles.push(idx);
            while held.next_if(|&(k, _)| k < id).is_some() {}
            let live = held.next_if(|&(k, _)| k == id).map(|(_, e)| e);
            if j.window.tile_state(idx) == TileState::Done {
                open = false;
                continue;
            }
            check_holder(j.holder(job, idx, id, live), worker, id, part, job)?;
        }
        Ok(SpanCheck { tiles, open })
    }

    /// Takes a span that [`Scheduler::check_span`] found open under the
    /// same lock (`tiles`: its indices, in the order of its parts): every
    /// tile is done at once, as [`Scheduler::accept_rendered`] would do
    /// them one by one. `rays` are shared by pixels, the remainder going
    /// to the last tile; the span's result is one measurement of the job's
    /// cost (`render`, as for `accept_rendered`); its worker is credited
    /// once. Returns the tiles taken with their rays, and whether the job
    /// is now complete. A tile that is done or was never handed out (which
    /// an open check under the same lock rules out) is not taken.
    pub fn take_span(
        &mut self,
        job: JobId,
        tiles: &[u32],
        rays: u64,
        render: Option<Duration>,
        now: Instant,
    ) -> Result<(Vec<(u32, u64)>, bool), SchedError> {
        let measured_before = self.sizer.cost(job).is_some();
        let j = self.jobs.get_mut(&job).ok_or(SchedError::UnknownJob(job))?;
        if j.state.is_final() {
            self.counters.tiles_ignored += tiles.len() as u64;
            return Ok((Vec::new(), false));
        }
        let total = j.window.tiles_total();
        let pixels: Vec<u64> = tiles
            .iter()
            .map(|&t| match t < total {
                true => j.window.rect(t).pixel_count() as u64,
                false => 0,
            })
            .collect();
        let shares = ray_shares(rays, &pixels);
        let mut taken = Vec::with_capacity(tiles.len());
        // Credit goes to each run of tiles of one worker at once (a span
        // is one worker's: one run).
        let mut credit: Option<(WorkerId, u64, u64)> = None;
        for (&idx, &rays) in tiles.iter().zip(&shares) {
            if idx >= total {
                self.counters.tiles_ignored += 1;
                continue;
            }
            let worker = match j.window.tile_state(idx) {
                TileState::Leased(l) => self.leases.remove(l).map(|e| {
                    if e.span_pixels > 0 {
                        let threads = self.workers.threads(e.worker).unwrap_or(1);
                        let took = super::lease_size::render_time(
                            now.saturating_duration_since(e.granted),
                            render,
                        );
                        self.sizer.observe(job, took, threads, e.span_pixels);
                    }
                    e.worker
                }),
                TileState::Pending if !j.window.is_fresh(idx) => j
                    .past_leases
                    .values()
                    .find(|(t, _)| *t == idx)
                    .map(|&(_, w)| w),
                _ => {
                    self.counters.tiles_ignored += 1;
                    continue;
                }
            };
            j.set_done(idx);
            j.done += 1;
            j.rays = j.rays.saturating_add(rays);
            taken.push((idx, rays));
            if let Some(w) = worker {
                match &mut credit {
                    Some((cw, n, r)) if *cw == w => {
                        *n += 1;
                        *r = r.saturating_add(rays);
                    }
                    _ => {
                        if let Some((cw, n, r)) = credit.replace((w, 1, rays)) {
                            self.workers.credit_tiles(cw, n, r, now);
                        }
                    }
                }
            }
        }
        if let Some((w, n, r)) = credit {
            self.workers.credit_tiles(w, n, r, now);
        }
        let last = j.done == u64::from(total);
        let taken_rays = taken.iter().fold(0u64, |a, &(_, r)| a.saturating_add(r));
        self.counters.tiles_accepted += taken.len() as u64;
        self.counters.rays = self.counters.rays.saturating_add(taken_rays);
        if !measured_before && !taken.is_empty() {
            self.seed_unmeasured_like(job);
        }
        Ok((taken, last))
    }
}

#[cfg(test)]
mod tests {
    use super::super::{test_scheduler, test_spec, Accepted, Limits};
    use super::*;

    /// A scheduler with a 4 × 4-tile PNG frame of 10-pixel tiles (measured,
    /// cheap, so one lease is the whole frame) and a worker of 4 threads
    /// that takes spans; the worker holds that one lease.
    fn leased_frame() -> (Scheduler, JobId, WorkerId, super::super::Lease, Instant) {
        let now = Instant::now();
        let mut s = test_scheduler(Limits::default());
        let w = s.register_worker(now, None);
        s.describe_worker(w, "w", 4);
        s.allow_spans(w);
        let j = s.submit(test_spec(40, 40, 10, "o.png"), now);
        s.sizer.seed(j, 1e-12);
        let l = s.lease(w, now).unwrap().unwrap();
        assert_eq!((l.tiles, l.rect), (16, Rect::new(0, 0, 40, 40)));
        (s, j, w, l, now)
    }

    /// Taken whole, a span ends where taking its tiles one by one
    /// (`check_lease`, `accept_rendered`, with the same ray shares) ends:
    /// the same tiles, rays, counters, worker credit and measured cost.
    #[test]
    fn taking_a_span_whole_ends_as_taking_its_tiles_one_by_one() {
        let (mut a, j, w, l, now) = leased_frame();
        let (mut b, ..) = leased_frame();
        let parts = a.span_tiles(j, l.rect).unwrap();
        let later = now + Duration::from_millis(800);
        let render = Some(Duration::from_millis(500));
        let rays = 1_000_003;

        let check = a.check_span(j, &parts, l.id, Some(w)).unwrap();
        assert!(check.open);
        assert_eq!(check.tiles, (0..16).collect::<Vec<u32>>());
        let (taken, last) = a.take_span(j, &check.tiles, rays, render, later).unwrap();
        assert!(last);

        // One by one, each tile's share computed apart: 100 pixels of 1,600.
        let mut left = rays;
        for (i, &p) in parts.iter().enumerate() {
            b.check_lease(j, p, l.id + i as u64, Some(w)).unwrap();
            let r = if i == 15 { left } else { rays * 100 / 1600 };
            left -= r;
            assert_eq!(taken[i], (i as u32, r));
            let got = b.accept_rendered(j, p, r, render, later).unwrap();
            assert_eq!(got, Accepted::New { last: i == 15 });
        }
        let (ia, ib) = (a.info(j, later).unwrap(), b.info(j, later).unwrap());
        assert_eq!((ia.tiles_done, ia.rays), (16, rays));
        assert_eq!((ib.tiles_done, ib.rays), (16, rays));
        let (ca, cb) = (a.counters(), b.counters());
        assert_eq!((ca.tiles_accepted, ca.rays), (cb.tiles_accepted, cb.rays));
        assert_eq!(a.measured_cost(j), b.measured_cost(j));
        // 0.5 s × 4 threads over 1,600 pixels, smoothed into 1e-12.
        let sample = 0.5 * 4.0 / 1600.0;
        let want = 1e-12 + super::super::lease_size::SMOOTHING * (sample - 1e-12);
        assert!((a.measured_cost(j).unwrap() - want).abs() < 1e-15);
        let (wa, wb) = (&a.workers(later)[0], &b.workers(later)[0]);
        assert_eq!((wa.tiles_done, wa.rays), (16, rays));
        assert_eq!((wb.tiles_done, wb.rays), (16, rays));
        assert!(a.leases.len() == 0 && b.leases.len() == 0);
    }

    #[test]
    fn a_span_with_a_tile_done_is_not_open_and_a_wrong_lease_is_refused() {
        let (mut s, j, w, l, now) = leased_frame();
        let parts = s.span_tiles(j, l.rect).unwrap();
        let other = s.register_worker(now, None);
        // Not this worker's, or shifted by one id: refused as check_lease
        // refuses, naming the first tile's lease.
        for (lease, who) in [(l.id, Some(other)), (l.id + 1, Some(w))] {
            match s.check_span(j, &parts, lease, who) {
                Err(SchedError::NotYourLease(id, _, rect, job)) => {
                    assert_eq!((id, rect, job), (lease, parts[0], j));
                }
                e => panic!("{e:?}"),
            }
        }
        // A hostile lease id near u64::MAX wraps and finds nothing.
        assert!(s.check_span(j, &parts, u64::MAX - 3, Some(w)).is_err());
        // Anyone's (`None`) passes.
        assert!(s.check_span(j, &parts, l.id, None).unwrap().open);
        // Tile 5 done under its own lease: the span passes the check but
        // is not open, and taking it anyway takes only the 15 others.
        s.accept_rendered(j, parts[5], 7, None, now).unwrap();
        let check = s.check_span(j, &parts, l.id, Some(w)).unwrap();
        assert!(!check.open);
        let (taken, last) = s.take_span(j, &check.tiles, 15, None, now).unwrap();
        assert_eq!(taken.len(), 15);
        assert!(!taken.iter().any(|&(t, _)| t == 5));
        assert!(last);
        assert_eq!(s.counters().tiles_ignored, 1);
        // A part that is not a tile.
        let bad = [Rect::new(5, 0, 10, 10)];
        let (s2, j2, w2, l2, _) = leased_frame();
        assert!(matches!(
            s2.check_span(j2, &bad, l2.id, Some(w2)),
            Err(SchedError::NotATile(..))
        ));
    }

    #[test]
    fn a_span_of_a_job_that_is_over_is_not_open_and_takes_nothing() {
        let (mut s, j, w, l, now) = leased_frame();
        let parts = s.span_tiles(j, l.rect).unwrap();
        s.cancel(j, now).unwrap();
        let check = s.check_span(j, &parts, l.id, Some(w)).unwrap();
        assert_eq!(
            check,
            SpanCheck {
                tiles: vec![],
                open: false
            }
        );
        let idx: Vec<u32> = (0..16).collect();
        let (taken, last) = s.take_span(j, &idx, 5, None, now).unwrap();
        assert!(taken.is_empty() && !last);
        assert_eq!(s.counters().tiles_accepted, 0);
    }
}
