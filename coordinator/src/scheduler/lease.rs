//! Where a lease is granted: [`Scheduler::lease`] takes the jobs in queue
//! order (priority, then submission), skips those the worker is kept from
//! or cannot hold, and plans what the lease covers from the job's next
//! pending tile ([`span_plan`]): one tile, adjacent tiles of one band, or
//! whole full-width bands as floats or as encoded PNG segments.

use super::expiry::earliest;
use super::lease_size::{self, MAX_SPAN_TILES};
use super::lease_table::NewSpan;
use super::types::{JobSpec, JobState, Lease, SchedError};
use super::window::BandWindow;
use super::Scheduler;
use crate::limits::Limits;
use crate::workers::WorkerId;
use std::path::Path;
use std::time::Instant;
use trevi_core::output::{Format, SEGMENT_ROWS};
use trevi_core::tile::Rect;

/// How a lease that starts at a job's pending tile is made up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SpanPlan {
    /// That many whole full-width bands from the tile's (the first tile of
    /// its band), as encoded PNG segments or as floats.
    Bands { bands: u32, segments: bool },
    /// Up to `want` adjacent tiles of the tile's band, from it on, as floats.
    InBand { want: u32 },
}

/// Whether `spec`'s output is a PNG (its name's extension).
pub(super) fn is_png(spec: &JobSpec) -> bool {
    Format::from_path(Path::new(&spec.output_name)) == Some(Format::Png)
}

/// Whether rows `y0..y1` of a `height`-row frame are whole PNG segments:
/// they start on a multiple of [`SEGMENT_ROWS`] and end on one or at the
/// frame's bottom.
pub(super) fn whole_segments(y0: u32, y1: u32, height: u32) -> bool {
    y0 % SEGMENT_ROWS == 0 && (y1 % SEGMENT_ROWS == 0 || y1 == height)
}

/// What a lease starting at pending tile `first` covers (`None`: nothing
/// may go out from there now). `want(cap)` is how many tiles the sizer
/// gives the worker under a cap of `cap` pixels (1 for a worker that takes
/// no spans). From the first tile of a band that is wholly pending, whole
/// bands go out: as encoded segments when `may_encode` (the worker encodes,
/// the output is PNG) and the rows are whole segments, under
/// `max_segment_lease_pixels` and the window at the segment cost; as
/// floats otherwise, under `max_lease_pixels` and the window at the float
/// cost. Failing that (the band is partly taken, or more than the worker's
/// share), adjacent tiles of one band as floats, as before bands were
/// leased whole.
fn span_plan(
    window: &BandWindow,
    spec: &JobSpec,
    first: u32,
    may_encode: bool,
    want: impl Fn(u64) -> u32,
    cfg: &Limits,
) -> Option<SpanPlan> {
    let cols = window.cols();
    let band = first / cols;
    let (width, height) = window.size();
    let tile = spec.tile_size.max(1);
    // Counted as a full band: the last band, shorter, is then under its cap.
    let band_pixels = (width as u64 * tile.min(height) as u64).max(1);
    // The whole bands within what the sizer wants; with `at_least_one` (a
    // segment lease, which can only be whole bands), one band when it
    // wants half a band or more.
    let most_bands = |cap: u64, at_least_one: bool| -> u32 {
        let want = want(cap);
        let by_time = match want / cols {
            0 if at_least_one && want.saturating_mul(2) >= cols => 1,
            n => n,
        };
        let by_pixels = u32::try_from(cap / band_pixels).unwrap_or(u32::MAX);
        by_time.min(by_pixels).min(MAX_SPAN_TILES / cols)
    };
    if first % cols == 0 {
        if may_encode {
            let n = window.whole_bands(band, most_bands(cfg.max_segment_lease_pixels, true), true);
            let y0 = band * tile;
            let whole = (1..=n)
                .rev()
                .find(|&k| whole_segments(y0, (band + k).saturating_mul(tile).min(height), height));
            if let Some(bands) = whole {
                return Some(SpanPlan::Bands {
                    bands,
                    segments: true,
                });
            }
        }
        let n = window.whole_bands(band, most_bands(cfg.max_lease_pixels, false), false);
        if n > 0 {
            return Some(SpanPlan::Bands {
                bands: n,
                segments: false,
            });
        }
    }
    window.band_fits(band, false).then(|| SpanPlan::InBand {
        want: want(cfg.max_lease_pixels).clamp(1, MAX_SPAN_TILES),
    })
}

impl Scheduler {
    /// The next tile for `worker`, if any job has one it may hand out now.
    pub fn lease(&mut self, worker: WorkerId, now: Instant) -> Result<Option<Lease>, SchedError> {
        self.touch(worker, now)?;
        // Asking for work: no longer paused.
        self.workers.set_paused(worker, None);
        // Expired tiles first; the rest of `expire` is the reaper's.
        self.expire_leases(now);
        let max_fail = self.cfg.max_worker_failures.max(1);
        let limit = self.workers.memory_limit(worker);
        // Its name claims a block read back after a restart (`blocks.rs`).
        let name = self.workers.name_of(worker).map(str::to_string);
        let mut too_small = false;
        for &(_, id) in &self.queue {
            let job = self.jobs.get_mut(&id).expect("queued jobs exist");
            if job.blocks(worker, name.as_deref(), max_fail) {
                continue;
            }
            let spans = self.sizer.takes_spans(worker);
            // Whether this lease may ask for encoded PNG segments: then the
            // window lets it run further ahead (see [`window`]).
            // Never for a job with render passes: they travel as floats.
            let may_encode = spans
                && self.sizer.takes_segments(worker)
                && is_png(&job.spec)
                && job.spec.aovs.is_empty();
            if !self.memory.fits(id, limit) {
                too_small |= job.window.next_tile(may_encode).is_some();
                continue;
            }
            let Some(first) = job.window.next_tile(may_encode) else {
                continue;
            };
            // A job not measured yet gets single tiles (they measure it),
            // so never a segment lease: rounded up to a whole band, a
            // frame one or two tiles wide would go whole.
            let measured = self.sizer.cost(id).is_some();
            let caps = self.cfg.for_state(job.spec.samples.is_some());
            let plan = span_plan(
                &job.window,
                &job.spec,
                first,
                may_encode && measured,
                |cap| {
                    if !spans {
                        return 1;
                    }
                    let t = job.spec.tile_size as u64;
                    lease_size::tiles_per_lease(
                        self.sizer.cost(id),
                        self.workers.threads(worker).unwrap_or(1),
                        t * t,
                        self.cfg.lease_target,
                        cap,
                    )
                },
                &caps,
            );
            let Some(plan) = plan else {
                // Only a segment lease could go this far ahead, and none
                // fits here.
                continue;
            };
            let (span, rect, segments) = match plan {
                SpanPlan::Bands { bands, segments } => {
                    let cols = job.window.cols();
                    let (width, height) = job.window.size();
                    let y = job.window.rect(first).y;
                    let bottom = job.window.rect(first + bands * cols - 1);
                    let rect = Rect::new(0, y, width, (bottom.y + bottom.h).min(height) - y);
                    let span: Vec<u32> = (first..first + bands * cols).collect();
                    for (i, &tile) in span.iter().enumerate() {
                        job.window
                            .set_leased(tile, self.next_lease + i as u64, segments);
                    }
                    (span, rect, segments)
                }
                SpanPlan::InBand { want } => {
                    // The next tiles while they follow `first` in its band.
                    let mut span = vec![first];
                    let mut rect = job.window.rect(first);
                    job.window.set_leased(first, self.next_lease, false);
                    while (span.len() as u32) < want {
                        let Some(next) = job.window.next_tile(false) else {
                            break;
                        };
                        let r = job.window.rect(next);
                        if next != span[span.len() - 1] + 1
                            || r.y != rect.y
                            || r.x != rect.x + rect.w
                        {
                            break;
                        }
                        span.push(next);
                        rect.w += r.w;
                        job.window
                            .set_leased(next, self.next_lease + span.len() as u64 - 1, false);
                    }
                    (span, rect, false)
                }
            };
            let lease_id = self.next_lease;
            self.next_lease += span.len() as u64;
            self.counters.leases_granted += span.len() as u64;
            if job.state == JobState::Queued {
                job.state = JobState::Running;
            }
            job.started.get_or_insert(now);
            let deadline = now + self.cfg.lease_ttl;
            self.earliest_deadline = Some(earliest(self.earliest_deadline, deadline));
            // A span's tiles are consecutive: the table derives each
            // one's lease from the first's.
            debug_assert!(span.windows(2).all(|t| t[1] == t[0] + 1));
            self.leases.insert_span(NewSpan {
                first: lease_id,
                job: id,
                first_tile: span[0],
                count: span.len() as u32,
                worker,
                deadline,
                granted: now,
                span_pixels: rect.pixel_count() as u64,
            });
            return Ok(Some(Lease {
                id: lease_id,
                job: id,
                bundle_hash: job.spec.bundle_hash.clone(),
                camera: job.spec.camera.clone(),
                rect,
                tiles: span.len() as u32,
                memory_estimate: self.memory.estimate(id),
                frame: job.spec.frame,
                png_segments: segments,
                samples: job.spec.samples,
                aovs: job.spec.aovs,
            }));
        }
        if too_small {
            // Work is waiting that this worker cannot hold.
            self.workers.set_paused(worker, Some("memory"));
        }
        Ok(None)
    }
}
