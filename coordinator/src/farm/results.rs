//! Taking a worker's tile results: each checked (its pixels, its lease, its
//! rectangle) and recorded with the scheduler, a span cut into its tiles,
//! then handed to `stitch.rs` to be stored and written. A result as
//! encoded PNG segments comes in through `segments.rs` instead.

use super::checks::{validate_aovs, validate_pixels};
use super::outputs::Output;
use super::Farm;
use crate::error::FarmError;
use crate::scheduler::{ray_shares, Accepted, JobId, LeaseId, WorkerId};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use trevi_core::{Aovs, Rect};

/// What became of a valid tile result.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TileOutcome {
    /// The first valid result for the tile: it is stored and in the output.
    Accepted,
    /// Late or duplicate: another result won, or the job is over.
    Ignored,
}

/// A result for one leased tile, for [`Farm::put_tile`].
#[derive(Debug, Clone, Copy)]
pub struct LeaseResult<'a> {
    /// The lease the tile was rendered under.
    pub lease: LeaseId,
    /// The tile's job.
    pub job: JobId,
    /// The tile's pixels in the frame (the lease's rectangle).
    pub rect: Rect,
    /// Rays the worker traced for it.
    pub rays: u64,
    /// Linear RGB radiance, row by row, `rect.w × rect.h` of them; each must be
    /// finite and non-negative.
    pub pixels: &'a [[f32; 3]],
    /// When given, `lease` must be this worker's lease on that tile: a
    /// result under someone else's lease, or a made-up one, is refused and
    /// changes nothing.
    pub worker: Option<WorkerId>,
}

/// A running job's output, shared by the uploads writing to it.
pub(super) type SharedOutput = Arc<Mutex<Output>>;

/// A tile result the scheduler took, on its way to the store and the output.
pub(super) struct Admitted<P> {
    pub(super) idx: u32,
    pub(super) rect: Rect,
    pub(super) rays: u64,
    pub(super) pixels: P,
    /// The tile's render pass values (empty for a job without passes).
    pub(super) aovs: Vec<f32>,
    pub(super) out: SharedOutput,
}

impl Farm {
    /// Checks that `rect` is one of `job`'s tiles or a span of them (before
    /// reading a result), within the cap of the upload's kind: encoded
    /// segments or floats; returns the tiles, left to right (see
    /// [`Scheduler::span_tiles_as`](crate::scheduler::Scheduler::span_tiles_as)).
    pub fn span_tiles_as(
        &self,
        job: JobId,
        rect: Rect,
        png_segments: bool,
    ) -> Result<Vec<Rect>, FarmError> {
        Ok(self
            .state
            .lock()
            .sched
            .span_tiles_as(job, rect, png_segments)?)
    }

    /// Takes the result of a lease of several tiles: `r.rect` is their
    /// union, `parts` its tiles in row-major order (band by band, left to
    /// right: [`Farm::span_tiles_as`]), whose leases are `r.lease`,
    /// `r.lease + 1`, …. Each tile is checked and
    /// taken as [`Farm::put_tile`] takes one, with its own pixels and its
    /// share of the rays (by pixels); the new ones are then stored in one
    /// transaction and written. Accepted when every tile is; the first
    /// error otherwise, after every tile was tried.
    pub fn put_span(&self, r: LeaseResult, parts: &[Rect]) -> Result<TileOutcome, FarmError> {
        self.put_span_rendered(r, parts, None)
    }

    /// [`Farm::put_span`] with the time the worker said it spent rendering
    /// the lease (`None`: it did not say), which measures the job's cost
    /// for lease sizing (see [`Scheduler::accept_rendered`](crate::scheduler::Scheduler::accept_rendered)).
    pub fn put_span_rendered(
        &self,
        r: LeaseResult,
        parts: &[Rect],
        render: Option<Duration>,
    ) -> Result<TileOutcome, FarmError> {
        self.put_span_aovs(r, &[], parts, render)
    }

    /// [`Farm::put_span_rendered`] with the lease's render pass values
    /// (`trevi_core::AovTile` layout over `r.rect`; empty for a job without
    /// passes): each tile's must be its pixels × the job's pass channels,
    /// or the tile is refused like one of bad pixels.
    pub fn put_span_aovs(
        &self,
        r: LeaseResult,
        aovs: &[f32],
        parts: &[Rect],
        render: Option<Duration>,
    ) -> Result<TileOutcome, FarmError> {
        if let [only] = parts {
            return self.put_one(LeaseResult { rect: *only, ..r }, Some(aovs), render);
        }
        // Values a pixel, when the span's values are a whole number of
        // its pixels' (otherwise every part is refused for its size).
        let count = r.rect.pixel_count();
        let per_pixel = (count > 0 && aovs.len() % count == 0).then(|| aovs.len() / count);
        let pixels: Vec<u64> = parts.iter().map(|p| p.pixel_count() as u64).collect();
        let shares = ray_shares(r.rays, &pixels);
        let mut outcome = Ok(TileOutcome::Accepted);
        let mut admitted = Vec::with_capacity(parts.len());
        for (i, &part) in parts.iter().enumerate() {
            let mut pixels = Vec::with_capacity(part.pixel_count());
            // A result of the wrong size stays wrong: every part is refused.
            // A span may cover several full-width bands (its tiles in
            // row-major order): each part is cut at its x and y offset.
            if r.pixels.len() == r.rect.pixel_count() {
                let w = r.rect.w as usize;
                let dx = (part.x - r.rect.x) as usize;
                let dy = (part.y - r.rect.y) as usize;
                for row in r.pixels.chunks_exact(w).skip(dy).take(part.h as usize) {
                    pixels.extend_from_slice(&row[dx..dx + part.w as usize]);
                }
            }
            let part_aovs = per_pixel.map(|n| {
                let mut v = Vec::with_capacity(part.pixel_count() * n);
                let w = r.rect.w as usize * n;
                let dx = (part.x - r.rect.x) as usize * n;
                let dy = (part.y - r.rect.y) as usize;
                if n > 0 {
                    for row in aovs.chunks_exact(w).skip(dy).take(part.h as usize) {
                        v.extend_from_slice(&row[dx..dx + part.w as usize * n]);
                    }
                }
                v
            });
            let one = self.admit(
                LeaseResult {
                    lease: r.lease.wrapping_add(i as u64),
                    rect: part,
                    rays: shares[i],
                    pixels: &pixels,
                    ..r
                },
                part_aovs.as_deref(),
                render,
            );
            let one = match one {
                Ok(Some((idx, out))) => {
                    admitted.push(Admitted {
                        idx,
                        rect: part,
                        rays: shares[i],
                        pixels,
                        aovs: part_aovs.unwrap_or_default(),
                        out,
                    });
                    Ok(TileOutcome::Accepted)
                }
                Ok(None) => Ok(TileOutcome::Ignored),
                Err(e) => Err(e),
            };
            outcome = match (outcome, one) {
                (Err(e), _) | (Ok(_), Err(e)) => Err(e),
                (Ok(TileOutcome::Accepted), Ok(o)) => Ok(o),
                (Ok(o), Ok(_)) => Ok(o),
            };
        }
        // The span's new tiles are stored in one transaction, then written.
        let written = self.store_and_write(r.job, &admitted);
        match (outcome, written) {
            (Err(e), _) | (Ok(_), Err(e)) => Err(e),
            (Ok(_), Ok(false)) => Ok(TileOutcome::Ignored), // Cancelled meanwhile.
            (Ok(o), Ok(true)) => Ok(o),
        }
    }

    /// Takes a tile result: validates it, and writes it if it is the first
    /// valid one for its tile. An invalid result re-queues the tile.
    pub fn put_tile(&self, r: LeaseResult) -> Result<TileOutcome, FarmError> {
        self.put_one(r, Some(&[]), None)
    }

    /// [`Farm::put_tile`] with the tile's render pass values and the
    /// worker's render time, if it said.
    fn put_one(
        &self,
        r: LeaseResult,
        aovs: Option<&[f32]>,
        render: Option<Duration>,
    ) -> Result<TileOutcome, FarmError> {
        let Some((idx, out)) = self.admit(r, aovs, render)? else {
            return Ok(TileOutcome::Ignored);
        };
        let one = Admitted {
            idx,
            rect: r.rect,
            rays: r.rays,
            pixels: r.pixels,
            aovs: aovs.unwrap_or_default().to_vec(),
            out,
        };
        Ok(
            match self.store_and_write(r.job, std::slice::from_ref(&one))? {
                true => TileOutcome::Accepted,
                false => TileOutcome::Ignored, // Cancelled meanwhile.
            },
        )
    }

    /// Validates a result and records it with the scheduler: the tile's
    /// index and the job's output when it is the first valid result for
    /// its tile (`None`: late, duplicate, or the job is over). An invalid
    /// result re-queues the tile and is the error.
    fn admit(
        &self,
        r: LeaseResult,
        aovs: Option<&[f32]>,
        render: Option<Duration>,
    ) -> Result<Option<(u32, SharedOutput)>, FarmError> {
        let LeaseResult {
            lease,
            job,
            rect,
            rays,
            pixels,
            worker,
        } = r;
        let valid = validate_pixels(rect, pixels);
        let mut st = self.state.lock();
        st.sched.check_lease(job, rect, lease, worker)?;
        let job_aovs = st.sched.spec_of(job).map_or(Aovs::NONE, |s| s.aovs);
        let valid = valid
            .and_then(|()| validate_aovs(rect, job_aovs, aovs))
            .and_then(|()| Ok(st.sched.check_tile(job, rect)?));
        if let Err(e) = valid {
            st.sched.reject_tile(lease, &format!("invalid result: {e}"));
            let failed = st.sched.take_failed();
            drop(st);
            tracing::warn!(job, lease, error = %e, "tile rejected and re-queued");
            self.work.notify_waiters();
            self.fail_jobs(failed);
            self.log_faults();
            return Err(e);
        }
        match st
            .sched
            .accept_rendered(job, rect, rays, render, Instant::now())?
        {
            Accepted::Ignored => return Ok(None),
            Accepted::New { .. } => {}
        }
        let idx = st
            .sched
            .tile_index(job, rect)
            .expect("accepted tiles are tiles");
        let Some(out) = st.outputs.get(&job).cloned() else {
            st.publish(job);
            return Ok(None);
        };
        // Not in a status until stored (`store_and_write`).
        st.taking(job, 1, self.store.is_some());
        st.publish(job);
        drop(st);
        self.work.notify_waiters();
        Ok(Some((idx, out)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::farm::{FarmConfig, SubmitOptions, WorkerOptions};

    /// A tile the scheduler took but the database does not hold yet is not
    /// in the job's status: a status never shows more tiles than a restart
    /// finds (the store write happens outside the farm's lock, between
    /// `admit` and `store_and_write`; CI once read 45 tiles done before a
    /// kill and 30 after the restart).
    #[test]
    fn a_status_counts_a_tile_only_once_it_is_stored() {
        let dir = tempfile::tempdir().unwrap();
        let f = Farm::new(FarmConfig {
            durable: true,
            ..FarmConfig::new(dir.path())
        })
        .unwrap();
        let spec = crate::scheduler::test_spec(32, 16, 16, "o.png");
        let job = f.submit(spec, SubmitOptions::default()).unwrap().id;
        let w = f.register_worker(WorkerOptions::default()).unwrap().id;
        let l = f.lease(w).unwrap().unwrap();
        let pixels = vec![[0.5f32; 3]; l.rect.pixel_count()];
        let r = LeaseResult {
            lease: l.id,
            job,
            rect: l.rect,
            rays: 1,
            pixels: &pixels,
            worker: None,
        };
        let (idx, out) = f
            .admit(r, Some(&[]), None)
            .unwrap()
            .expect("a first result");
        assert_eq!(f.info(job).unwrap().tiles_done, 0, "taken, not stored");
        let one = Admitted {
            idx,
            rect: l.rect,
            rays: 1,
            pixels: &pixels[..],
            aovs: Vec::new(),
            out,
        };
        assert!(f.store_and_write(job, std::slice::from_ref(&one)).unwrap());
        assert_eq!(f.info(job).unwrap().tiles_done, 1, "stored");
    }
}
