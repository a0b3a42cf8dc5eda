//! Leases uploaded as encoded PNG segments (docs/farm.md, "Encoded
//! segments"): what is checked, how a span is taken whole or not at all,
//! stored, appended to the output and added to the preview.
//!
//! A worker that registered with this coordinator's encoder
//! ([`trevi_core::output::PNG_ENCODER`]) may upload a lease of whole
//! 16-row segments of full-width rows as the segments
//! [`trevi_core::output::encode_segment`] makes, and the preview's box sums
//! of its pixels. The coordinator never sees those pixels: it checks the
//! framing of every segment, inflates one per upload in full, stores the
//! bytes and appends them to the file.

use super::{lock, Farm, TileOutcome};
use crate::error::FarmError;
use crate::preview::Preview;
use crate::scheduler::{JobId, LeaseId, WorkerId};
use std::path::Path;
use std::time::{Duration, Instant};
use trevi_core::output::{
    adler32, adler32_combine, check_segment, segment_filtered_len, whole_segments, Format,
    PngSegment, SegmentError, FINAL_EMPTY_BLOCK, PNG_ENCODER,
};
use trevi_core::Rect;

/// A lease's result as encoded PNG segments, for [`Farm::put_segments`].
#[derive(Debug, Clone, Copy)]
pub struct SegmentUpload<'a> {
    /// The lease of the span's first tile (the others follow, one each).
    pub lease: LeaseId,
    /// The job the lease is of.
    pub job: JobId,
    /// The lease's rect: whole segments of full-width rows.
    pub rect: Rect,
    /// Rays the worker traced for it.
    pub rays: u64,
    /// As for [`super::LeaseResult::worker`]; such a worker must also have
    /// registered with the coordinator's encoder.
    pub worker: Option<WorkerId>,
    /// The rect's segments, top to bottom.
    pub segments: &'a [PngSegment],
    /// The preview's box sums over the rect (see `PreviewSums`): three a
    /// cell, for the cells [`Preview::cells`] gives.
    pub sums: &'a [f32],
}

/// What an upload for a rect must hold: [`Farm::segment_plan`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SegmentPlan {
    /// The frame's width in pixels.
    pub width: u32,
    /// The frame's height in pixels.
    pub height: u32,
    /// The index of the rect's first segment in the frame.
    pub first: u32,
    /// How many segments the rect is.
    pub count: u32,
    /// The preview's cell edge in pixels (`Lease.preview_scale`).
    pub scale: u32,
    /// The number of preview cells the rect overlaps: the upload carries
    /// `3 × cells` sums.
    pub cells: usize,
}

impl SegmentPlan {
    /// The filtered length of the rect's `i`-th segment.
    pub fn filtered_len(&self, i: u32) -> u64 {
        segment_filtered_len(self.width, self.height, self.first + i)
    }
}

/// What [`inflate_check`] found wrong with a segment's deflate bytes.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum InflateError {
    /// The bytes inflate past the segment's claimed filtered length.
    #[error("segment {index} does not inflate to {expected} bytes (it inflates to more)")]
    TooMuch {
        /// The segment's index in the frame.
        index: u32,
        /// Its claimed filtered length.
        expected: u64,
    },
    /// A row starts with a filter type PNG does not have, or (the
    /// segment's first row) one that reads the row above.
    #[error("segment {index}'s row {row} has filter type {filter}, not 0..={most}")]
    Filter {
        /// The segment's index in the frame.
        index: u32,
        /// The row, counted from the segment's first.
        row: u64,
        /// The filter type found.
        filter: u8,
        /// The largest allowed there: 1 on the first row, else 4.
        most: u8,
    },
    /// The deflate stream ends (a final block) before the segment's bytes
    /// do.
    #[error("segment {index} ends its deflate stream after {at} of its {len} bytes")]
    EndsEarly {
        /// The segment's index in the frame.
        index: u32,
        /// The byte offset where the stream ended.
        at: usize,
        /// The segment's deflate length.
        len: usize,
    },
    /// The bytes are not valid deflate, or stop short of the claimed
    /// length.
    #[error("segment {index} does not inflate to {expected} bytes ({status} after {wrote})")]
    Malformed {
        /// The segment's index in the frame.
        index: u32,
        /// Its claimed filtered length.
        expected: u64,
        /// miniz_oxide's status where inflating stopped.
        status: String,
        /// Bytes inflated before it stopped.
        wrote: u64,
    },
    /// The bytes inflate to fewer bytes than claimed.
    #[error("segment {index} inflates to {wrote} bytes, not the {expected} it claims")]
    Length {
        /// The segment's index in the frame.
        index: u32,
        /// Bytes it inflates to.
        wrote: u64,
        /// Its claimed filtered length.
        expected: u64,
    },
    /// The inflated bytes' Adler-32 is not the one uploaded with them.
    #[error(
        "segment {index}'s bytes have Adler-32 {got:#010x}, not the {claimed:#010x} it claims"
    )]
    Adler {
        /// The segment's index in the frame.
        index: u32,
        /// The Adler-32 of the inflated bytes.
        got: u32,
        /// [`PngSegment::adler32`] as uploaded.
        claimed: u32,
    },
}

/// Why an upload of encoded segments is refused ([`check_upload`], and the
/// uploading worker's encoder); [`FarmError::BadTile`] says it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum UploadError {
    /// More or fewer segments than the rect is.
    #[error("{got} segments uploaded, but rows {y}..{end} are {count} segments")]
    SegmentCount {
        /// Segments uploaded.
        got: usize,
        /// The rect's first row.
        y: u32,
        /// The row after its last.
        end: u32,
        /// Segments the rect is ([`SegmentPlan::count`]).
        count: u32,
    },
    /// A segment's framing is wrong ([`check_segment`]).
    #[error(transparent)]
    Framing(#[from] SegmentError),
    /// More or fewer preview sums than three a cell the rect overlaps.
    #[error(
        "{got} preview sums uploaded, but the rect overlaps {cells} preview cells of {scale} \
         pixels: {} sums",
        3 * .cells
    )]
    SumCount {
        /// Sums uploaded.
        got: usize,
        /// Preview cells the rect overlaps ([`SegmentPlan::cells`]).
        cells: usize,
        /// The preview's cell edge in pixels.
        scale: u32,
    },
    /// A preview sum is negative, infinite or NaN.
    #[error("preview sum {k} (cell {}) is {value}: sums are finite and not negative", .k / 3)]
    BadSum {
        /// The sum's index in the upload (cell `k / 3`, channel `k % 3`).
        k: usize,
        /// Its value.
        value: f32,
    },
    /// The segment inflated in full ([`sampled_segment`]) is not what its
    /// framing claims.
    #[error(transparent)]
    Inflate(#[from] InflateError),
    /// The uploading worker did not register with [`PNG_ENCODER`], so its
    /// segments may not be this coordinator's encoding.
    #[error(
        "worker {worker} did not register with this coordinator's PNG encoder \"{PNG_ENCODER}\""
    )]
    Unregistered {
        /// The worker.
        worker: WorkerId,
    },
}

/// Which of an upload's `count` segments is inflated in full: one per
/// upload, picked by mixing the lease id (SplitMix64's finaliser), so that
/// which one is not always the first, yet the same upload always gets the
/// same check.
pub fn sampled_segment(lease: LeaseId, count: u32) -> u32 {
    let mut z = lease.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z % u64::from(count.max(1))) as u32
}

/// Inflates segment `index` of a `width`-wide frame in full (miniz_oxide,
/// an inflater independent of the encoder) and checks what its framing
/// only claims: the deflate bytes are one stream piece that ends exactly
/// where they do (no final block inside), inflating to exactly
/// `filtered_len` bytes whose Adler-32 is the one given, made of rows
/// that each start with a filter type 0..=4 (the segment's first row 0 or
/// 1: None or Sub, which do not read the row above). What it still cannot
/// tell is whether the pixels are the right ones.
///
/// The bytes are inflated through a ring of `INFLATE_RING` bytes and
/// checked as they come, not into one buffer the segment's size: a wide
/// frame's segment inflates to hundreds of kilobytes, which zeroing and
/// faulting in cost as much as inflating did (docs/benchmarks.md,
/// "Stage 7").
pub fn inflate_check(width: u32, index: u32, seg: &PngSegment) -> Result<(), InflateError> {
    use miniz_oxide::inflate::core::{decompress, inflate_flags, DecompressorOxide};
    use miniz_oxide::inflate::TINFLStatus;
    let expected = seg.filtered_len;
    let stride = 1 + 3 * u64::from(width);
    let mut ring = vec![0u8; INFLATE_RING];
    let mut d = DecompressorOxide::new();
    // What has come out so far: its length, its Adler-32, and where the
    // next row's filter byte is.
    let (mut wrote, mut adler, mut row_start) = (0u64, 1u32, 0u64);
    let mut at = 0usize;
    // The segment's bytes, then the empty final block that ends the stream
    // for this check (the output file ends it once, after the last segment).
    let pieces = [&seg.deflate[..], &FINAL_EMPTY_BLOCK[..]];
    for (p, piece) in pieces.into_iter().enumerate() {
        let last = p + 1 == pieces.len();
        let flags = if last {
            0
        } else {
            inflate_flags::TINFL_FLAG_HAS_MORE_INPUT
        };
        let mut input = piece;
        loop {
            let (status, read, out) = decompress(&mut d, input, &mut ring, at, flags);
            input = &input[read..];
            let chunk = &ring[at..at + out];
            if wrote + out as u64 > expected {
                return Err(InflateError::TooMuch { index, expected });
            }
            while row_start < wrote + out as u64 {
                let row = row_start / stride;
                let most = if row == 0 { 1 } else { 4 };
                let filter = chunk[(row_start - wrote) as usize];
                if filter > most {
                    return Err(InflateError::Filter {
                        index,
                        row,
                        filter,
                        most,
                    });
                }
                row_start += stride;
            }
            adler = adler32_combine(adler, adler32(chunk), out as u64);
            wrote += out as u64;
            at = (at + out) & (INFLATE_RING - 1);
            match status {
                TINFLStatus::HasMoreOutput => continue,
                TINFLStatus::NeedsMoreInput if !last && input.is_empty() => break,
                TINFLStatus::Done if last && input.is_empty() => break,
                TINFLStatus::Done if !last => {
                    return Err(InflateError::EndsEarly {
                        index,
                        at: seg.deflate.len() - input.len(),
                        len: seg.deflate.len(),
                    })
                }
                status => {
                    return Err(InflateError::Malformed {
                        index,
                        expected,
                        status: format!("{status:?}"),
                        wrote,
                    })
                }
            }
        }
    }
    if wrote != expected {
        return Err(InflateError::Length {
            index,
            wrote,
            expected,
        });
    }
    if adler != seg.adler32 {
        return Err(InflateError::Adler {
            index,
            got: adler,
            claimed: seg.adler32,
        });
    }
    Ok(())
}

/// The ring [`inflate_check`] inflates through: a power of two (which
/// miniz_oxide's wrapping output needs) of at least deflate's 32 KiB
/// window, small enough to stay in a core's L2 cache.
const INFLATE_RING: usize = 1 << 16;

/// Checks an upload against its plan: the segments' count and framing
/// (every one), one of them inflated in full ([`sampled_segment`],
/// [`inflate_check`]), and the preview sums' count and values (finite,
/// not negative). The error says what is wrong.
pub fn check_upload(plan: &SegmentPlan, up: &SegmentUpload) -> Result<(), UploadError> {
    if up.segments.len() != plan.count as usize {
        return Err(UploadError::SegmentCount {
            got: up.segments.len(),
            y: up.rect.y,
            end: up.rect.y + up.rect.h,
            count: plan.count,
        });
    }
    for (i, seg) in (plan.first..).zip(up.segments) {
        check_segment(plan.width, plan.height, i, seg)?;
    }
    if up.sums.len() != 3 * plan.cells {
        return Err(UploadError::SumCount {
            got: up.sums.len(),
            cells: plan.cells,
            scale: plan.scale,
        });
    }
    if let Some(k) = up.sums.iter().position(|v| !(0.0..=f32::MAX).contains(v)) {
        return Err(UploadError::BadSum {
            k,
            value: up.sums[k],
        });
    }
    let i = sampled_segment(up.lease, plan.count);
    Ok(inflate_check(
        plan.width,
        plan.first + i,
        &up.segments[i as usize],
    )?)
}

/// The bytes a span's upload is stored as (and replayed from after a
/// restart), little-endian: `TSG1`, the rect (x, y, w, h), the preview's
/// scale, the segment count and for each its index, Adler-32, filtered
/// length, deflate length and deflate bytes, then the sum count and the
/// sums.
pub(super) fn encode_stored<'u>(
    plan: &SegmentPlan,
    rect: Rect,
    up: &SegmentUpload<'u>,
) -> StoredPieces<'u> {
    let mut head = Vec::with_capacity(28);
    head.extend_from_slice(b"TSG1");
    for v in [rect.x, rect.y, rect.w, rect.h, plan.scale, plan.count] {
        head.extend_from_slice(&v.to_le_bytes());
    }
    let heads = (plan.first..)
        .zip(up.segments)
        .map(|(i, s)| {
            let mut h = [0u8; 20];
            h[0..4].copy_from_slice(&i.to_le_bytes());
            h[4..8].copy_from_slice(&s.adler32.to_le_bytes());
            h[8..16].copy_from_slice(&s.filtered_len.to_le_bytes());
            h[16..20].copy_from_slice(&(s.deflate.len() as u32).to_le_bytes());
            h
        })
        .collect();
    let mut tail = Vec::with_capacity(4 + 4 * up.sums.len());
    tail.extend_from_slice(&(up.sums.len() as u32).to_le_bytes());
    for v in up.sums {
        tail.extend_from_slice(&v.to_le_bytes());
    }
    StoredPieces {
        head,
        heads,
        segments: up.segments,
        tail,
    }
}

/// What [`encode_stored`] makes: the stored record in pieces that borrow
/// the upload's deflate bytes, so that a span is written to the store
/// without first being copied into one buffer (that copy, into freshly
/// mapped pages at every upload, was a sixth of the coordinator's time with
/// 1,000 workers: docs/benchmarks.md, "Stage 4").
pub(super) struct StoredPieces<'u> {
    head: Vec<u8>,
    heads: Vec<[u8; 20]>,
    segments: &'u [PngSegment],
    tail: Vec<u8>,
}

impl StoredPieces<'_> {
    /// The record's bytes in order.
    pub fn pieces(&self) -> Vec<&[u8]> {
        let mut v = Vec::with_capacity(2 + 2 * self.heads.len());
        v.push(&self.head[..]);
        for (h, s) in self.heads.iter().zip(self.segments) {
            v.push(&h[..]);
            v.push(&s.deflate[..]);
        }
        v.push(&self.tail[..]);
        v
    }
}

/// A stored span, decoded.
pub(super) struct StoredSpan {
    pub rect: Rect,
    pub scale: u32,
    pub segments: Vec<(u32, PngSegment)>,
    pub sums: Vec<f32>,
}

/// Reads what [`encode_stored`] wrote; anything malformed (which the
/// CRC-32 the store checks makes unlikely) is [`FarmError::Damaged`].
/// Every length is checked against what is left before it is allocated.
pub(super) fn decode_stored(bytes: &[u8]) -> Result<StoredSpan, FarmError> {
    let damaged = |what: &str| FarmError::Damaged(format!("a stored span of segments: {what}"));
    let mut rest = bytes;
    let mut take = |n: usize| -> Result<&[u8], FarmError> {
        if rest.len() < n {
            return Err(damaged("it ends early"));
        }
        let (a, b) = rest.split_at(n);
        rest = b;
        Ok(a)
    };
    if take(4)? != b"TSG1" {
        return Err(damaged("not the format this coordinator writes"));
    }
    let mut u32s = [0u32; 6];
    for v in &mut u32s {
        *v = u32::from_le_bytes(take(4)?.try_into().expect("4 bytes"));
    }
    let [x, y, w, h, scale, count] = u32s;
    let mut segments = Vec::new();
    for _ in 0..count {
        let head = take(20)?;
        let index = u32::from_le_bytes(head[0..4].try_into().expect("4 bytes"));
        let adler = u32::from_le_bytes(head[4..8].try_into().expect("4 bytes"));
        let filtered_len = u64::from_le_bytes(head[8..16].try_into().expect("8 bytes"));
        let len = u32::from_le_bytes(head[16..20].try_into().expect("4 bytes"));
        let deflate = take(len as usize)?.to_vec();
        segments.push((
            index,
            PngSegment {
                deflate,
                adler32: adler,
                filtered_len,
            },
        ));
    }
    let n = u32::from_le_bytes(take(4)?.try_into().expect("4 bytes")) as usize;
    let raw = take(n.checked_mul(4).ok_or_else(|| damaged("too many sums"))?)?;
    let sums = raw
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
        .collect();
    if !rest.is_empty() {
        return Err(damaged("bytes after its end"));
    }
    Ok(StoredSpan {
        rect: Rect::new(x, y, w, h),
        scale,
        segments,
        sums,
    })
}

impl Farm {
    /// What an upload of encoded segments for `rect` of `job` must hold
    /// (checked before any of it is read): `rect` is whole 16-row segments
    /// of full-width rows of a PNG frame; otherwise
    /// [`FarmError::BadTile`] saying why.
    pub fn segment_plan(&self, job: JobId, rect: Rect) -> Result<SegmentPlan, FarmError> {
        let spec = self
            .state
            .lock()
            .sched
            .info(job, Instant::now())
            .ok_or(FarmError::UnknownJob(job))?
            .spec;
        if Format::from_path(Path::new(&spec.output_name)) != Some(Format::Png) {
            return Err(FarmError::BadTile(format!(
                "job {job} writes {}, not a PNG: it takes no encoded segments",
                spec.output_name
            )));
        }
        let (width, height) = (spec.width, spec.height);
        let (first, count) = whole_segments(rect, width, height).map_err(|e| {
            FarmError::BadTile(format!("an upload of encoded segments for job {job}: {e}"))
        })?;
        let preview = Preview::new(width, height);
        let (_, _, cols, rows) = preview.cells(rect);
        Ok(SegmentPlan {
            width,
            height,
            first,
            count,
            scale: preview.scale,
            cells: cols as usize * rows as usize,
        })
    }

    /// The preview cell edge a lease of `job` asks its sums for
    /// (`Lease.preview_scale`); 0 for an unknown job.
    pub fn preview_scale(&self, job: JobId) -> u32 {
        self.state
            .lock()
            .sched
            .info(job, Instant::now())
            .map_or(0, |i| Preview::new(i.spec.width, i.spec.height).scale)
    }

    /// Takes a lease's result as encoded segments: `up.rect` is the span's
    /// rect, `parts` its tiles in row-major order (the scheduler's `span_tiles`),
    /// whose leases are `up.lease`, `up.lease + 1`, ….
    ///
    /// An invalid upload ([`check_upload`], or a worker that did not
    /// register with this coordinator's encoder) re-queues every tile of
    /// the span as an invalid float result does, and is the error. A valid
    /// one is taken whole or not at all: if any of its tiles is already
    /// done (another result won it) or the job is over, nothing is taken
    /// ([`TileOutcome::Ignored`]) and the span's other tiles this worker
    /// still holds are given back to the queue. That is safe because the
    /// segments cannot be cut: rows someone else already gave cannot be
    /// given again, and the tiles not done are re-rendered (as floats or
    /// segments, the same pixels either way). Otherwise every tile is
    /// marked done, the upload stored ([`crate::store::Store::put_segment_span`])
    /// before this returns, then its segments are appended to the output
    /// ([`trevi_core::FrameWriter::write_segment`]), its sums added to the
    /// preview, and `trevi_png_segments_total` counts them.
    pub fn put_segments(
        &self,
        up: SegmentUpload,
        parts: &[Rect],
        render: Option<Duration>,
    ) -> Result<TileOutcome, FarmError> {
        let job = up.job;
        let plan = match self.segment_plan(job, up.rect) {
            Ok(p) => p,
            Err(FarmError::BadTile(m)) => {
                return Err(self.reject_segments(up.lease, job, parts, up.worker, m))
            }
            Err(e) => return Err(e),
        };
        // The parts must tile the rect (the gRPC path has them from
        // `span_tiles`; a caller of this API might not).
        let inside = parts.iter().all(|p| {
            p.x >= up.rect.x
                && p.y >= up.rect.y
                && p.x + p.w <= up.rect.x + up.rect.w
                && p.y + p.h <= up.rect.y + up.rect.h
        });
        let area: usize = parts.iter().map(|p| p.pixel_count()).sum();
        if parts.is_empty() || !inside || area != up.rect.pixel_count() {
            return Err(FarmError::BadTile(format!(
                "the tiles given do not make up {:?}",
                up.rect
            )));
        }
        let valid = check_upload(&plan, &up);
        let now = Instant::now();
        let mut st = self.state.lock();
        // Every lease checked, and the tiles found, in one pass.
        let span = st.sched.check_span(job, parts, up.lease, up.worker)?;
        let valid = valid.and_then(|()| match up.worker {
            Some(worker) if !st.segment_workers.contains(&worker) => {
                Err(UploadError::Unregistered { worker })
            }
            _ => Ok(()),
        });
        if let Err(e) = valid {
            drop(st);
            return Err(self.reject_segments(up.lease, job, parts, up.worker, e.to_string()));
        }
        let out = st.outputs.get(&job).cloned();
        let (Some(out), true) = (out, span.open) else {
            // Not taken: give back what this worker still holds of it.
            if let Some(w) = up.worker {
                for (i, &t) in span.tiles.iter().enumerate() {
                    if st.sched.tile_done(job, t) == Some(false) {
                        let id = up.lease.wrapping_add(i as u64);
                        let _ = st.sched.return_lease(w, id, None, now);
                    }
                }
            }
            drop(st);
            self.work.notify_waiters();
            return Ok(TileOutcome::Ignored);
        };
        // Checked open under this same lock: every tile is new.
        let (stored, _) = st.sched.take_span(job, &span.tiles, up.rays, render, now)?;
        // Not in a status until stored, below.
        st.taking(job, stored.len() as u64, self.store.is_some());
        st.publish(job);
        drop(st);
        self.work.notify_waiters();

        if let Some(store) = &self.store {
            let record = encode_stored(&plan, up.rect, &up);
            let put = store.put_segment_span(job, &stored, &record.pieces());
            self.state.lock().stored(job, stored.len() as u64);
            if let Err(e) = put {
                lock(&out).sink = None;
                self.end_job(
                    job,
                    Err(crate::scheduler::JobFailure::Output(format!(
                        "storing the segments of tile {}: {e}",
                        stored[0].0
                    ))),
                );
                return Err(e);
            }
        }
        let taken = self.write_segments(
            job,
            &out,
            up.rect,
            plan.first,
            up.segments.iter(),
            up.sums,
            parts.len() as u64,
        )?;
        Ok(if taken {
            TileOutcome::Accepted
        } else {
            TileOutcome::Ignored // Cancelled meanwhile.
        })
    }

    /// Refuses an upload of encoded segments for the span `parts` of `job`
    /// (leases `lease`, `lease + 1`, …) because of `why`: when the leases
    /// are `worker`'s, every tile is re-queued as for an invalid float
    /// result (counting against it). Returns the error for the worker:
    /// [`FarmError::BadTile`] with `why`, or the lease check's refusal.
    pub fn reject_segments(
        &self,
        lease: LeaseId,
        job: JobId,
        parts: &[Rect],
        worker: Option<WorkerId>,
        why: String,
    ) -> FarmError {
        let mut st = self.state.lock();
        if let Err(e) = st.sched.check_span(job, parts, lease, worker) {
            return e.into();
        }
        let e = FarmError::BadTile(why);
        for i in 0..parts.len() as u64 {
            st.sched
                .reject_tile(lease.wrapping_add(i), &format!("invalid result: {e}"));
        }
        let failed = st.sched.take_failed();
        drop(st);
        tracing::warn!(job, lease, error = %e, "segments rejected; tiles re-queued");
        self.work.notify_waiters();
        self.fail_jobs(failed);
        self.log_faults();
        e
    }

    /// Appends a span's segments (from index `first`) to the job's output,
    /// adds its sums to the preview and counts its `tiles`; finishes the
    /// output with its last tile. False when the output is gone (the job
    /// was cancelled meanwhile).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn write_segments<'s>(
        &self,
        job: JobId,
        out: &std::sync::Mutex<super::Output>,
        rect: Rect,
        first: u32,
        segments: impl Iterator<Item = &'s PngSegment>,
        sums: &[f32],
        tiles: u64,
    ) -> Result<bool, FarmError> {
        let mut n = 0;
        let taken = self.write_output(job, out, tiles, |sink, preview| {
            for (i, seg) in (first..).zip(segments) {
                sink.write_segment(i, seg)?;
                n += 1;
            }
            preview.add_sums(rect, sums, tiles);
            Ok(())
        })?;
        if taken {
            self.metrics.add_png_segments(n);
        }
        Ok(taken)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use trevi_core::output::encode_segment;

    fn seg(width: u32, rows: u32, seed: u32) -> PngSegment {
        let px: Vec<[f32; 3]> = (0..width * rows)
            .map(|i| {
                let v = ((i * 7 + seed) % 23) as f32 / 23.0;
                [v, 1.0 - v, 0.5]
            })
            .collect();
        encode_segment(width, &px)
    }

    #[test]
    fn a_segment_inflates_to_what_it_claims() {
        let s = seg(9, 16, 1);
        inflate_check(9, 0, &s).unwrap();
        // A wrong Adler-32.
        let mut bad = s.clone();
        bad.adler32 ^= 1;
        let e = inflate_check(9, 0, &bad).unwrap_err();
        assert!(matches!(e, InflateError::Adler { index: 0, .. }), "{e}");
        assert!(e.to_string().contains("Adler-32"));
        // A wrong length, either way.
        let mut bad = s.clone();
        bad.filtered_len -= 1;
        assert_eq!(
            inflate_check(9, 0, &bad),
            Err(InflateError::TooMuch {
                index: 0,
                expected: 447
            })
        );
        let mut bad = s.clone();
        bad.filtered_len += 1;
        let e = inflate_check(9, 0, &bad).unwrap_err();
        assert_eq!(
            e,
            InflateError::Length {
                index: 0,
                wrote: 448,
                expected: 449
            }
        );
        assert!(e.to_string().contains("inflates to 448 bytes, not the 449"));
        // Garbage in place of the deflate bytes, framed right.
        let mut bad = s.clone();
        bad.deflate = [&[0xffu8; 40][..], &trevi_core::output::SYNC_FLUSH].concat();
        assert!(inflate_check(9, 0, &bad).is_err());
        // A final block inside: the stream would end there.
        let mut bad = s.clone();
        bad.deflate = [
            &s.deflate[..],
            &FINAL_EMPTY_BLOCK[..],
            &trevi_core::output::SYNC_FLUSH,
        ]
        .concat();
        let e = inflate_check(9, 0, &bad).unwrap_err();
        assert!(matches!(e, InflateError::EndsEarly { index: 0, .. }), "{e}");
        assert!(e.to_string().contains("ends its deflate stream"));
    }

    #[test]
    fn a_bad_filter_type_is_found() {
        // Rows of raw bytes with filter types of our choosing, deflated by
        // a stored block (any valid deflate is accepted).
        let stride = 1 + 3 * 2;
        for (types, ok) in [
            ([0u8, 4], true),
            ([1, 2], true),
            ([2, 0], false),
            ([0, 5], false),
        ] {
            let mut raw = Vec::new();
            for t in types {
                raw.push(t);
                raw.extend_from_slice(&[9; 6]);
            }
            assert_eq!(raw.len(), 2 * stride);
            let mut deflate = vec![0u8, raw.len() as u8, 0, !(raw.len() as u8), 0xff];
            deflate.extend_from_slice(&raw);
            // The sync flush: an empty stored block's header byte, LEN, NLEN.
            deflate.push(0);
            deflate.extend_from_slice(&trevi_core::output::SYNC_FLUSH);
            let s = PngSegment {
                adler32: adler32(&raw),
                filtered_len: raw.len() as u64,
                deflate,
            };
            assert_eq!(inflate_check(2, 3, &s).is_ok(), ok, "{types:?}");
        }
    }

    /// `raw` as stored (uncompressed) deflate blocks, ended by a sync flush
    /// as a segment is: any valid deflate is accepted.
    fn stored_blocks(raw: &[u8]) -> Vec<u8> {
        let mut deflate = Vec::new();
        for block in raw.chunks(usize::from(u16::MAX)) {
            let n = block.len() as u16;
            deflate.push(0);
            deflate.extend_from_slice(&n.to_le_bytes());
            deflate.extend_from_slice(&(!n).to_le_bytes());
            deflate.extend_from_slice(block);
        }
        deflate.push(0);
        deflate.extend_from_slice(&trevi_core::output::SYNC_FLUSH);
        deflate
    }

    #[test]
    fn a_wide_segment_is_checked_all_the_way_through_the_ring() {
        // An 8192-wide segment inflates to six times the ring: what is
        // wrong far into it must still be found.
        let width = 8192u32;
        let stride = 1 + 3 * width as usize;
        let raw: Vec<u8> = (0..16 * stride)
            .map(|i| match (i / stride, i % stride) {
                (0, 0) => 1,
                (row, 0) => (row % 5) as u8,
                (row, k) => (row * 31 + k * 7) as u8,
            })
            .collect();
        assert!(raw.len() > 5 * INFLATE_RING);
        let good = |raw: &[u8]| PngSegment {
            adler32: adler32(raw),
            filtered_len: raw.len() as u64,
            deflate: stored_blocks(raw),
        };
        inflate_check(width, 0, &good(&raw)).unwrap();
        // The encoder's own wide segment passes too.
        let px: Vec<[f32; 3]> = (0..width * 16)
            .map(|i| [(i % 251) as f32 / 251.0, 0.25, (i % 7) as f32 / 7.0])
            .collect();
        inflate_check(width, 0, &encode_segment(width, &px)).unwrap();
        // A filter type out of range, before and after the ring wraps.
        for row in [0usize, 3, 9, 15] {
            let mut bad = raw.clone();
            bad[row * stride] = if row == 0 { 2 } else { 5 };
            let err = inflate_check(width, 0, &good(&bad))
                .unwrap_err()
                .to_string();
            assert!(err.contains(&format!("row {row} has filter type")), "{err}");
        }
        // One byte changed deep in, under the original's Adler-32.
        let mut bad = good(&raw);
        let mut changed = raw.clone();
        changed[10 * stride + 5] ^= 0x40;
        bad.deflate = stored_blocks(&changed);
        let err = inflate_check(width, 0, &bad).unwrap_err().to_string();
        assert!(err.contains("Adler-32"), "{err}");
        // A row short or a byte long, the length claimed unchanged.
        for len in [raw.len() - stride, raw.len() + 1] {
            let mut bad = good(&raw);
            let mut other = raw.clone();
            other.resize(len, 0);
            bad.deflate = stored_blocks(&other);
            assert!(inflate_check(width, 0, &bad).is_err(), "{len}");
        }
    }

    /// The cost of the full check of one segment against encoding it, on
    /// a 1920-wide segment of a smooth image with a little noise and of
    /// pure noise (the worst case). Prints figures; run by hand:
    /// `cargo test -p trevi-coordinator --lib inflate_check_cost -- --ignored --nocapture`.
    #[test]
    #[ignore = "a measurement that prints the inflate check's cost (docs/farm.md, \
                Encoded segments) and asserts nothing; run it as said above"]
    fn inflate_check_cost() {
        let width = 1920u32;
        let mut state = 1u64;
        let mut rnd = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        for (name, noise) in [("smooth", 0.02f32), ("noise", 1.0)] {
            let px: Vec<[f32; 3]> = (0..width * 16)
                .map(|i| {
                    let (x, y) = ((i % width) as f32, (i / width) as f32);
                    let base = [x / 1920.0, y / 16.0, 0.5];
                    base.map(|c| (c * (1.0 - noise) + noise * rnd()).max(0.0))
                })
                .collect();
            let reps = 200;
            let t = std::time::Instant::now();
            let mut seg = encode_segment(width, &px);
            for _ in 1..reps {
                seg = encode_segment(width, &px);
            }
            let enc = t.elapsed().as_secs_f64() / f64::from(reps);
            let t = std::time::Instant::now();
            for _ in 0..reps {
                inflate_check(width, 0, &seg).unwrap();
            }
            let chk = t.elapsed().as_secs_f64() / f64::from(reps);
            let n = f64::from(width * 16);
            println!(
                "{name}: {} deflate bytes ({:.2} a pixel); encode {:.2} ns/pixel, \
                 inflate check {:.2} ns/pixel ({:.0} us a segment)",
                seg.deflate.len(),
                seg.deflate.len() as f64 / n,
                enc * 1e9 / n,
                chk * 1e9 / n,
                chk * 1e6
            );
        }
    }

    #[test]
    fn the_sampled_segment_is_in_range_and_varies() {
        let picks: std::collections::BTreeSet<u32> =
            (0..64).map(|l| sampled_segment(l, 4)).collect();
        assert_eq!(picks.into_iter().collect::<Vec<_>>(), [0, 1, 2, 3]);
        assert_eq!(sampled_segment(5, 1), 0);
        assert_eq!(sampled_segment(5, 0), 0);
    }

    #[test]
    fn stored_spans_read_back_and_damage_is_typed() {
        let segs = [seg(5, 16, 1), seg(5, 4, 2)];
        let plan = SegmentPlan {
            width: 5,
            height: 36,
            first: 1,
            count: 2,
            scale: 1,
            cells: 2,
        };
        let rect = Rect::new(0, 16, 5, 20);
        let up = SegmentUpload {
            lease: 1,
            job: 1,
            rect,
            rays: 0,
            worker: None,
            segments: &segs,
            sums: &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
        };
        let b = encode_stored(&plan, rect, &up).pieces().concat();
        let s = decode_stored(&b).unwrap();
        assert_eq!((s.rect, s.scale), (rect, 1));
        assert_eq!(s.segments, vec![(1, segs[0].clone()), (2, segs[1].clone())]);
        assert_eq!(s.sums, up.sums);
        for cut in [0, 3, 10, b.len() - 1] {
            assert!(matches!(
                decode_stored(&b[..cut]),
                Err(FarmError::Damaged(_))
            ));
        }
        let mut long = b.clone();
        long.push(0);
        assert!(matches!(decode_stored(&long), Err(FarmError::Damaged(_))));
    }
}
