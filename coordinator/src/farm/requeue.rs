//! Requeueing part of a job ([`Farm::requeue`], `trevi-submit requeue ID
//! [--frames A-B] [--rect X,Y,W,H]`): it is rendered again under its id and
//! its output rewritten in place, the bytes of a fresh render (determinism
//! makes this safe).
//!
//! - An ended still (done, failed or cancelled), whole: queued again with
//!   none of its tiles (a failed still's kept tiles are dropped); its output
//!   is written to a temporary file renamed over the old one when complete,
//!   so a failure leaves the old output.
//! - With a rect: only the tiles the rect touches are queued; the others'
//!   pixels come from the old output, read back band by band as the new
//!   file is written ([`super::patch`]). The output must be a PNG (an EXR
//!   with a rect is refused) and must exist.
//! - A running still is refused (cancel it, or wait for its end); so is a
//!   progressive job (`extend` adds samples to it). Sequences: see
//!   `requeue/frames.rs`.
//!
//! A coordinator restarted while a requeued still renders resumes it as
//! any job: from the tiles stored since the requeue, rendering the others
//! (those a rect did not touch too), so the file is the same bytes.

mod frames;

use super::patch::{Patch, TileSpan};
use super::{Farm, Output};
use crate::error::FarmError;
use crate::preview::Preview;
use crate::scheduler::{JobId, JobInfo, JobSpec, JobState, Restored, FRAME_IDS};
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Instant;
use trevi_core::output::{Format, PngRows};
use trevi_core::texture::srgb_to_linear;
use trevi_core::Rect;

/// Checks that `rect` is inside a `width` × `height` frame and not empty.
pub fn check_rect(rect: Rect, width: u32, height: u32) -> Result<(), FarmError> {
    let Rect { x, y, w, h } = rect;
    if w == 0 || h == 0 {
        return Err(FarmError::Invalid(format!(
            "--rect {x},{y},{w},{h} is empty: its width and height must be at least 1"
        )));
    }
    if u64::from(x) + u64::from(w) > u64::from(width)
        || u64::from(y) + u64::from(h) > u64::from(height)
    {
        return Err(FarmError::Invalid(format!(
            "--rect {x},{y},{w},{h} is not inside the {width}x{height} frame"
        )));
    }
    Ok(())
}

/// The live preview of a still requeued with a rect: the old output's
/// pixels of the tiles kept (back to linear light), read band by band of
/// tiles; the tiles rendered again are added as they come.
fn kept_preview(path: &Path, spec: &JobSpec, span: TileSpan) -> Result<Preview, FarmError> {
    let (w, h, t) = (spec.width, spec.height, span.tile);
    let mut preview = Preview::new(w, h);
    let mut rows = PngRows::open(path, w, h)
        .map_err(|e| FarmError::Conflict(format!("the old output cannot be read: {e}")))?;
    let linear: Vec<f32> = (0..=255u8)
        .map(|v| srgb_to_linear(f64::from(v) / 255.0) as f32)
        .collect();
    let cols = w.div_ceil(t);
    let mut band: Vec<Vec<[f32; 3]>> = Vec::new();
    for r in 0..h.div_ceil(t) {
        let y0 = r * t;
        band.clear();
        for _ in y0..(y0 + t).min(h) {
            let row = rows
                .next_row()
                .map_err(|e| FarmError::Conflict(format!("the old output cannot be read: {e}")))?;
            band.push(
                row.chunks_exact(3)
                    .map(|p| {
                        [
                            linear[p[0] as usize],
                            linear[p[1] as usize],
                            linear[p[2] as usize],
                        ]
                    })
                    .collect(),
            );
        }
        for c in (0..cols).filter(|&c| !span.has(r * cols + c, cols)) {
            let x0 = c * t;
            let rect = Rect::new(x0, y0, t.min(w - x0), band.len() as u32);
            let px: Vec<[f32; 3]> = band
                .iter()
                .flat_map(|line| &line[x0 as usize..(x0 + rect.w) as usize])
                .copied()
                .collect();
            preview.add_tile(rect, &px);
        }
    }
    Ok(preview)
}

impl Farm {
    /// Renders part of job `id` again (see the module's doc): frames
    /// `first..=last` of a sequence, and/or the tiles `rect` touches.
    pub fn requeue(
        &self,
        id: JobId,
        frames: Option<(u32, u32)>,
        rect: Option<Rect>,
    ) -> Result<JobInfo, FarmError> {
        let seq = {
            let st = self.state.lock();
            if let Some(seq) = st.parent_of.get(&id) {
                return Err(FarmError::Conflict(format!(
                    "job {id} is a part of job {seq}: requeue job {seq} (with --frames)"
                )));
            }
            match st.seqs.get(&id) {
                Some(s) if s.passes.is_some() => {
                    return Err(FarmError::Conflict(format!(
                        "job {id} is a progressive job: it cannot be requeued (extend adds \
                         samples to it; submit it again to render it anew)"
                    )))
                }
                Some(_) => true,
                None if id >= FRAME_IDS => {
                    return Err(FarmError::Conflict(format!(
                        "job {id} is a part of a sequence: requeue the sequence (with --frames)"
                    )))
                }
                None => {
                    st.info(id, Instant::now())
                        .ok_or(FarmError::UnknownJob(id))?;
                    false
                }
            }
        };
        if seq {
            return self.requeue_frames(id, frames, rect);
        }
        if frames.is_some() {
            return Err(FarmError::Invalid(format!(
                "--frames takes a sequence; job {id} is a still (requeue it without --frames)"
            )));
        }
        self.requeue_still(id, rect)
    }

    /// Requeues ended still `id`, whole or the tiles `rect` touches.
    fn requeue_still(&self, id: JobId, rect: Option<Rect>) -> Result<JobInfo, FarmError> {
        let info = {
            let st = self.state.lock();
            let info = st
                .info(id, Instant::now())
                .ok_or(FarmError::UnknownJob(id))?;
            if !info.state.is_final() || st.unrecorded.contains_key(&id) {
                return Err(FarmError::Conflict(format!(
                    "job {id} is {}: a still is requeued once it has ended (cancel it, or \
                     wait for its end)",
                    info.state.name()
                )));
            }
            info
        };
        let spec = &info.spec;
        let path = self.output_path(id, &spec.output_name);
        let tile = spec.tile_size.max(1);
        let cols = spec.width.div_ceil(tile);
        let total = u64::from(cols) * u64::from(spec.height.div_ceil(tile));
        // With a rect: the old output opened for reading before anything
        // changes, and the tiles it does not touch (kept as done).
        let patch = match rect {
            None => None,
            Some(r) => {
                check_rect(r, spec.width, spec.height)?;
                if Format::from_path(Path::new(&spec.output_name)) != Some(Format::Png) {
                    return Err(FarmError::Invalid(format!(
                        "--rect patches a PNG output; job {id} writes {} (requeue the whole \
                         frame: leave out --rect)",
                        spec.output_name
                    )));
                }
                if !spec.aovs.is_empty() {
                    return Err(FarmError::Invalid(format!(
                        "--rect patches the beauty; job {id} also writes the render passes \
                         {} (requeue the whole frame: leave out --rect)",
                        spec.aovs
                    )));
                }
                if !path.is_file() {
                    return Err(FarmError::Conflict(format!(
                        "job {id} ({}) has no output file to patch with --rect; requeue \
                         the whole frame: leave out --rect",
                        info.state.name()
                    )));
                }
                let span = TileSpan::of(r, tile);
                let patch = Patch::open(&path, spec.width, spec.height, span).map_err(|e| {
                    FarmError::Conflict(format!(
                        "the output of job {id} cannot be patched: {e}; requeue the whole \
                         frame: leave out --rect"
                    ))
                })?;
                let keep: Vec<u32> = (0..u32::try_from(total).unwrap_or(u32::MAX))
                    .filter(|&i| !span.has(i, cols))
                    .collect();
                let preview = kept_preview(&path, spec, span)?;
                Some((patch, keep, preview))
            }
        };
        let who = spec.submitter.clone();
        let mut st = self.state.lock();
        Self::check_submitter(&st, &who, self.cfg.limits.max_jobs_per_submitter)?;
        let now = Instant::now();
        // Checked again: another requeue or retry may have been quicker.
        if st.info(id, now).is_none_or(|i| !i.state.is_final()) {
            return Err(FarmError::Conflict(format!("job {id} is requeued already")));
        }
        if let Some(store) = &self.store {
            store.requeue_job(id)?;
        }
        let kept = patch.as_ref().map_or(0, |p| p.1.len());
        let (out, done_tiles) = match patch {
            Some((patch, keep, preview)) => (
                Output::restored(
                    Box::new(patch),
                    keep.len() as u64,
                    total,
                    preview,
                    trevi_core::Aovs::NONE, // Refused above for a job with passes.
                ),
                keep,
            ),
            None => (Output::deferred(path, spec, total), Vec::new()),
        };
        st.sched.restore(
            Restored {
                id,
                spec: spec.clone(),
                state: JobState::Queued,
                submitted: now,
                elapsed: None,
                render: None,
                error: None,
                finish_order: 0,
                tiles_done: 0,
                rays: 0,
                done_tiles,
            },
            now,
        );
        st.outputs.insert(id, Arc::new(Mutex::new(out)));
        st.submitters.insert(id, who);
        self.events.restored(id);
        st.publish(id);
        drop(st);
        tracing::info!(job = id, tiles_kept = kept, ?rect, "job requeued");
        self.work.notify_waiters();
        self.info(id)
    }
}
