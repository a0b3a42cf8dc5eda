//! Where a tile result is accepted: which tiles an upload covers
//! ([`Scheduler::span_tiles`]), whether it comes under the uploader's lease
//! ([`Scheduler::check_lease`]), taking the first valid result and
//! ignoring late or duplicate ones ([`Scheduler::accept_rendered`]),
//! sharing a span's rays among its tiles ([`ray_shares`]), and re-queuing
//! the tile of an invalid one ([`Scheduler::reject_tile`]). A span that is
//! taken whole (encoded segments) goes through `whole_span.rs`.

use super::expiry::Release;
use super::jobs::same_shot;
use super::lease::{is_png, whole_segments};
use super::lease_size::{self, MAX_SPAN_TILES};
use super::types::{Accepted, JobId, LeaseId, SampleRange, SchedError};
use super::window::TileState;
use super::Scheduler;
use crate::workers::WorkerId;
use std::time::{Duration, Instant};
use trevi_core::tile::Rect;

/// A span's `rays` shared among its tiles by their pixels (`pixels`, one
/// count a tile, in order): each share rounded down, the last tile the
/// remainder, so the shares add up to `rays` exactly.
pub fn ray_shares(rays: u64, pixels: &[u64]) -> Vec<u64> {
    let whole = pixels.iter().map(|&p| u128::from(p)).sum::<u128>().max(1);
    let mut left = rays;
    pixels
        .iter()
        .enumerate()
        .map(|(k, &p)| {
            if k + 1 == pixels.len() {
                left
            } else {
                let share = ((u128::from(rays) * u128::from(p) / whole) as u64).min(left);
                left -= share;
                share
            }
        })
        .collect()
}

/// Whether a result for `rect` of `job` under `lease` may come from
/// `worker` (anyone when `None`), `holder` being who holds the lease
/// ([`Job::holder`]); the error says it is not `worker`'s.
///
/// [`Job::holder`]: super::job::Job::holder
pub(super) fn check_holder(
    holder: Option<WorkerId>,
    worker: Option<WorkerId>,
    lease: LeaseId,
    rect: Rect,
    job: JobId,
) -> Result<(), SchedError> {
    match (holder, worker) {
        (Some(h), Some(w)) if h == w => Ok(()),
        (Some(_), None) => Ok(()),
        _ => Err(SchedError::NotYourLease(
            lease,
            worker.unwrap_or_default(),
            rect,
            job,
        )),
    }
}

impl Scheduler {
    /// The index of `rect` among `job`'s tiles (band order), if it is one.
    pub fn tile_index(&self, job: JobId, rect: Rect) -> Option<u32> {
        self.jobs.get(&job)?.window.tile_index(rect)
    }

    /// The rectangle of tile `idx` of `job`.
    pub fn tile_rect(&self, job: JobId, idx: u32) -> Option<Rect> {
        let j = self.jobs.get(&job)?;
        (idx < j.window.tiles_total()).then(|| j.window.rect(idx))
    }

    /// Whether tile `idx` of `job` is done (`None`: no such job or tile).
    /// For a result that must be taken whole or not at all (encoded
    /// segments covering several tiles).
    pub fn tile_done(&self, job: JobId, idx: u32) -> Option<bool> {
        let j = self.jobs.get(&job)?;
        (idx < j.window.tiles_total()).then(|| j.window.tile_state(idx) == TileState::Done)
    }

    /// Checks that a result for `rect` of `job` comes under a lease that was
    /// given to `worker` (any worker when `None`) for that tile. A result for
    /// a tile already done, or of a job that is over, passes (and is
    /// ignored later).
    pub fn check_lease(
        &self,
        job: JobId,
        rect: Rect,
        lease: LeaseId,
        worker: Option<WorkerId>,
    ) -> Result<(), SchedError> {
        let j = self.jobs.get(&job).ok_or(SchedError::UnknownJob(job))?;
        if j.state.is_final() {
            return Ok(());
        }
        let idx = j
            .window
            .tile_index(rect)
            .ok_or(SchedError::NotATile(rect, job))?;
        if j.window.tile_state(idx) == TileState::Done {
            return Ok(());
        }
        let holder = j.holder(job, idx, lease, self.leases.get(lease));
        check_holder(holder, worker, lease, rect, job)
    }

    /// The job and rectangle of the lease (a span's first) that `worker`
    /// holds as `lease`: what the worker renders, and so the state it
    /// fetches. Refused when the lease is not out under `worker`.
    pub fn leased_span(
        &self,
        lease: LeaseId,
        worker: WorkerId,
    ) -> Result<(JobId, Rect, Option<SampleRange>), SchedError> {
        let not_yours = || SchedError::NotHeld(lease, worker);
        let run = self.leases.span(lease).ok_or_else(not_yours)?;
        if run.worker != worker {
            return Err(not_yours());
        }
        let j = self
            .jobs
            .get(&run.job)
            .ok_or(SchedError::UnknownJob(run.job))?;
        let (a, b) = (
            j.window.rect(run.first_tile),
            j.window.rect(run.first_tile + run.len - 1),
        );
        let rect = Rect::new(a.x, a.y, b.x + b.w - a.x, b.y + b.h - a.y);
        Ok((run.job, rect, j.spec.samples))
    }

    /// The tile index of `rect` in `job`, checking that it is one of its tiles.
    pub fn check_tile(&self, job: JobId, rect: Rect) -> Result<(), SchedError> {
        let j = self.jobs.get(&job).ok_or(SchedError::UnknownJob(job))?;
        if j.state.is_final() {
            return Ok(()); // Retired: the result will be ignored anyway.
        }
        j.window
            .tile_index(rect)
            .map(|_| ())
            .ok_or(SchedError::NotATile(rect, job))
    }

    /// The tiles of `job` that a result for `rect` brings, in band order:
    /// `rect` itself when it is one tile, or the tiles of a span: adjacent
    /// tiles of one band, or whole full-width bands one after the other,
    /// band by band and left to right (see [`lease_size`]), at most
    /// [`MAX_SPAN_TILES`] of them. Its pixels are at most
    /// [`Limits::max_segment_lease_pixels`] when it could be a segment lease
    /// (a PNG frame's whole bands that are whole segments,
    /// [`Lease::png_segments`]), [`Limits::max_lease_pixels`] otherwise;
    /// [`Scheduler::span_tiles_as`] applies the cap of the upload's kind
    /// once it is known. A job that is over: `rect` alone (the result will
    /// be ignored anyway).
    ///
    /// [`Lease::png_segments`]: super::Lease::png_segments
    /// [`Limits::max_lease_pixels`]: crate::limits::Limits::max_lease_pixels
    /// [`Limits::max_segment_lease_pixels`]: crate::limits::Limits::max_segment_lease_pixels
    pub fn span_tiles(&self, job: JobId, rect: Rect) -> Result<Vec<Rect>, SchedError> {
        self.span_tiles_capped(job, rect, None)
    }

    /// [`Scheduler::span_tiles`] for an upload of encoded segments
    /// (`png_segments`) or of floats: a segment upload must be whole
    /// segments of whole full-width bands of a PNG frame, at most
    /// [`Limits::max_segment_lease_pixels`]; a float upload at most
    /// [`Limits::max_lease_pixels`] (a single tile may be bigger).
    ///
    /// [`Limits::max_lease_pixels`]: crate::limits::Limits::max_lease_pixels
    /// [`Limits::max_segment_lease_pixels`]: crate::limits::Limits::max_segment_lease_pixels
    pub fn span_tiles_as(
        &self,
        job: JobId,
        rect: Rect,
        png_segments: bool,
    ) -> Result<Vec<Rect>, SchedError> {
        self.span_tiles_capped(job, rect, Some(png_segments))
    }

    fn span_tiles_capped(
        &self,
        job: JobId,
        rect: Rect,
        kind: Option<bool>,
    ) -> Result<Vec<Rect>, SchedError> {
        let j = self.jobs.get(&job).ok_or(SchedError::UnknownJob(job))?;
        if j.state.is_final() {
            return Ok(vec![rect]);
        }
        let not_a_span = || SchedError::NotATile(rect, job);
        let w = &j.window;
        let (width, height) = w.size();
        let t = j.spec.tile_size;
        let (x1, y1) = (rect.x as u64 + rect.w as u64, rect.y as u64 + rect.h as u64);
        // On the tile grid, inside the frame, ending on the grid or at the
        // frame's edge.
        if rect.w == 0
            || rect.h == 0
            || rect.x % t != 0
            || rect.y % t != 0
            || x1 > width as u64
            || y1 > height as u64
            || (x1 % t as u64 != 0 && x1 != width as u64)
            || (y1 % t as u64 != 0 && y1 != height as u64)
        {
            return Err(not_a_span());
        }
        let (x1, y1) = (x1 as u32, y1 as u32);
        let full_width = rect.x == 0 && x1 == width;
        let (band0, bands) = (rect.y / t, (y1 - rect.y).div_ceil(t));
        if bands > 1 && !full_width {
            return Err(not_a_span());
        }
        let (c0, c1) = (rect.x / t, x1.div_ceil(t));
        let count = bands as u64 * (c1 - c0) as u64;
        let segment_shaped = full_width && is_png(&j.spec) && whole_segments(rect.y, y1, height);
        let cfg = self.cfg.for_state(j.spec.samples.is_some());
        let cap = match kind {
            Some(true) if !segment_shaped => return Err(not_a_span()),
            Some(true) => cfg.max_segment_lease_pixels,
            None if segment_shaped => cfg.max_segment_lease_pixels.max(cfg.max_lease_pixels),
            // A single tile of any size is its own lease (a progressive
            // job's tiles fit its cap: checked at submission).
            _ if count == 1 => u64::MAX,
            _ => cfg.max_lease_pixels,
        };
        if count > MAX_SPAN_TILES as u64 || rect.pixel_count() as u64 > cap {
            return Err(not_a_span());
        }
        let cols = w.cols();
        let mut parts = Vec::with_capacity(count as usize);
        for band in band0..band0 + bands {
            for c in c0..c1 {
                parts.push(w.rect(band * cols + c));
            }
        }
        Ok(parts)
    }

    /// Records a valid result for `rect` of `job`.
    pub fn accept_tile(
        &mut self,
        job: JobId,
        rect: Rect,
        rays: u64,
        now: Instant,
    ) -> Result<Accepted, SchedError> {
        self.accept_rendered(job, rect, rays, None, now)
    }

    /// [`Scheduler::accept_tile`] for a result whose worker said how long
    /// it spent rendering its lease (`render`; `None`: an older worker that
    /// does not say). The job's measured cost comes from that time rather
    /// than from grant to result, which on a busy coordinator is mostly
    /// queueing (see [`lease_size::render_time`]).
    pub fn accept_rendered(
        &mut self,
        job: JobId,
        rect: Rect,
        rays: u64,
        render: Option<Duration>,
        now: Instant,
    ) -> Result<Accepted, SchedError> {
        let measured_before = self.sizer.cost(job).is_some();
        let j = self.jobs.get_mut(&job).ok_or(SchedError::UnknownJob(job))?;
        if j.state.is_final() {
            self.counters.tiles_ignored += 1;
            return Ok(Accepted::Ignored);
        }
        let idx = j
            .window
            .tile_index(rect)
            .ok_or(SchedError::NotATile(rect, job))?;
        let worker = match j.window.tile_state(idx) {
            TileState::Done => None,
            // Never handed out: not a result of this coordinator's leases.
            TileState::Pending if j.window.is_fresh(idx) => None,
            TileState::Leased(l) => Some(self.leases.remove(l).map(|e| {
                let threads = self.workers.threads(e.worker).unwrap_or(1);
                let took =
                    lease_size::render_time(now.saturating_duration_since(e.granted), render);
                self.sizer.observe(job, took, threads, e.span_pixels);
                e.worker
            })),
            // A late result under a lease that ran out.
            TileState::Pending => Some(
                j.past_leases
                    .values()
                    .find(|(t, _)| *t == idx)
                    .map(|&(_, w)| w),
            ),
        };
        let Some(worker) = worker else {
            self.counters.tiles_ignored += 1;
            return Ok(Accepted::Ignored);
        };
        j.set_done(idx);
        j.done += 1;
        // Ray counts come from workers: a huge one saturates, never wraps.
        j.rays = j.rays.saturating_add(rays);
        let last = j.done == j.window.tiles_total() as u64;
        self.counters.tiles_accepted += 1;
        self.counters.rays = self.counters.rays.saturating_add(rays);
        if let Some(w) = worker {
            self.workers.credit(w, rays, now);
        }
        if !measured_before {
            self.seed_unmeasured_like(job);
        }
        Ok(Accepted::New { last })
    }

    /// `job` has just been measured for the first time: its unfinished
    /// siblings (the same scene and camera) not measured yet start from its
    /// cost. Frames submitted together (a sequence's first frames, a batch)
    /// would otherwise each begin with single-tile leases until each has
    /// its own measurement; on a big farm that is thousands of them.
    pub(super) fn seed_unmeasured_like(&mut self, job: JobId) {
        let (Some(cost), Some(j)) = (self.sizer.cost(job), self.jobs.get(&job)) else {
            return;
        };
        for &(_, other) in &self.queue {
            let like = self
                .jobs
                .get(&other)
                .is_some_and(|o| same_shot(&o.spec, &j.spec));
            if like && self.sizer.cost(other).is_none() {
                self.sizer.seed(other, cost);
            }
        }
    }

    /// An invalid result arrived under `lease`: put the tile back at once
    /// (unless someone else holds it or it is done).
    pub fn reject_tile(&mut self, lease: LeaseId, cause: &str) {
        self.counters.tiles_rejected += 1;
        self.release(lease, cause, Release::Failed);
    }
}
