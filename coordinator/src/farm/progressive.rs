//! Progressive jobs: a still's samples rendered in passes over the whole
//! frame (docs/progressive.md).
//!
//! A progressive job is run like a sequence (`sequences.rs`), with passes
//! for frames: it has a row of its own, and each pass is an ordinary job
//! (`JobSpec::samples` set) leased, stitched and stored tile by tile like a
//! still, one pass at a time, so every tile of pass k is handed out before
//! any of pass k + 1. A lease of a pass names its sample range
//! (`Lease::samples`); the worker fetches the rect's accumulation state
//! ([`Farm::state_source`], kept on disk by `pass_states.rs`), renders the
//! range, and uploads the finished pixels and the new state, which is
//! checked ([`Farm::put_state`]) and written before the tiles are taken.
//! When a pass is done its output replaces the job's (one rename: the
//! output is a whole image after every pass) and the job either stops (its
//! total reached, its time limit passed, its noise target met) or queues
//! the next pass. A job with its own sample count (`--samples`) can be
//! extended later ([`Farm::extend`]): its states are kept until retention
//! removes the job.

use super::pass_states::{state_bytes, state_path, StateFile};
use super::{Farm, SubmitOptions};
use crate::error::{FarmError, LimitKind};
use crate::scheduler::{JobId, JobSpec, JobState, SampleRange, WorkerId};
use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Instant;
use trevi_core::passes::{Noise, TileState, MAX_SAMPLES};
use trevi_core::Rect;

pub use super::passes::{Passes, Progressive, DEFAULT_PASSES, MAX_PASSES, PASS_TARGET};

impl Farm {
    /// The directory a progressive job keeps its output and states in.
    pub(super) fn job_dir(&self, job: JobId) -> PathBuf {
        self.cfg.data_dir.join("jobs").join(job.to_string())
    }

    /// A pass job's progressive job, sample range and frame width, while
    /// the pass runs (`None` for any other job, or a pass that ended).
    fn pass_of(&self, job: JobId) -> Option<(JobId, SampleRange, u32)> {
        let st = self.state.lock();
        let info = st.sched.info(job, Instant::now())?;
        let range = info.spec.samples?;
        let parent = *st.parent_of.get(&job)?;
        Some((parent, range, info.spec.width))
    }

    /// Whether `job` is a pass of a progressive job (running or not).
    fn is_pass(&self, job: JobId) -> bool {
        let st = self.state.lock();
        st.sched
            .info(job, Instant::now())
            .is_some_and(|i| i.spec.samples.is_some())
    }

    /// Where worker `worker` reads the state its lease `lease` (a span's
    /// first) continues: the state file, the rect and the sample it is at.
    /// Refused for a lease the worker does not hold, or of a job that is
    /// not a pass, or of a first pass (which starts from nothing).
    pub fn state_source(
        &self,
        worker: WorkerId,
        lease: u64,
    ) -> Result<(StateFile, Rect, u32), FarmError> {
        let (job, rect, range) = self.state.lock().sched.leased_span(lease, worker)?;
        let Some(range) = range.filter(|r| r.start > 0) else {
            return Err(FarmError::Invalid(format!(
                "lease {lease} does not continue a state: it is not a later pass of a \
                 progressive job"
            )));
        };
        let (parent, _, width) = self.pass_of(job).ok_or(FarmError::JobOver(job))?;
        let path = state_path(&self.job_dir(parent), range.pass + 1);
        Ok((StateFile::open(&path, width, false)?, rect, range.start))
    }

    /// Checks a worker's new state for the span `parts` (union `rect`) of
    /// pass job `job` and writes it, counting each tile's noise. A result
    /// of any other job must come without one. Call before the tiles are
    /// taken: a refusal re-queues them like invalid pixels.
    pub fn put_state(
        &self,
        job: JobId,
        rect: Rect,
        parts: &[Rect],
        state: Option<&[u8]>,
    ) -> Result<(), FarmError> {
        let pass = self.pass_of(job);
        if pass.is_none() && state.is_some() && self.is_pass(job) {
            // A pass that ended: the result is late, and ignored further on.
            return Ok(());
        }
        let (state, (parent, range, width)) = match (state, pass) {
            (None, None) => return Ok(()),
            (Some(_), None) => {
                return Err(FarmError::BadTile(format!(
                    "job {job} is not a pass of a progressive job: its results carry no state"
                )))
            }
            (None, Some(_)) => {
                return Err(FarmError::BadTile(format!(
                    "job {job} is a pass of a progressive job: its results carry the \
                     accumulation state"
                )))
            }
            (Some(s), Some(p)) => (s, p),
        };
        let decoded = TileState::decode(state)
            .map_err(|e| FarmError::BadTile(format!("the accumulation state: {e}")))?;
        if decoded.rect() != rect || decoded.next() != range.end {
            return Err(FarmError::BadTile(format!(
                "the accumulation state is of {:?} at sample {}, the lease is {rect:?} up to \
                 sample {}",
                decoded.rect(),
                decoded.next(),
                range.end
            )));
        }
        let mut noise = Vec::with_capacity(parts.len());
        for p in parts {
            let mut n = Noise::default();
            for y in p.y..p.y + p.h {
                let at = ((y - rect.y) * rect.w + (p.x - rect.x)) as usize;
                n += Noise::of_pixels(&decoded.pixels()[at..at + p.w as usize]);
            }
            noise.push(((p.x, p.y), n));
        }
        let path = state_path(&self.job_dir(parent), range.pass);
        StateFile::open(&path, width, true)?.write(rect, state)?;
        let mut st = self.state.lock();
        if let Some(passes) = st.seqs.get_mut(&parent).and_then(|s| s.passes.as_mut()) {
            passes.noise.extend(noise);
        }
        Ok(())
    }

    /// The noise of pass job `job`'s frame once its tiles are all taken:
    /// the tiles counted as they came, and any not counted (taken before a
    /// restart) read back from the state file.
    pub(super) fn pass_noise(&self, job: JobId) -> Option<Noise> {
        let (parent, range, width) = self.pass_of(job)?;
        let (counted, tiles) = {
            let st = self.state.lock();
            let counted = st.seqs.get(&parent)?.passes.as_ref()?.noise.clone();
            let mut tiles = Vec::new();
            let mut i = 0;
            while let Some(r) = st.sched.tile_rect(job, i) {
                tiles.push(r);
                i += 1;
            }
            (counted, tiles)
        };
        let path = state_path(&self.job_dir(parent), range.pass);
        // The pass's states reach the disk before its end is recorded: a
        // restart after it reads them.
        let file = StateFile::open(&path, width, false).ok()?;
        if let Err(e) = file.sync() {
            tracing::error!(job, error = %e, "cannot sync the pass's states");
        }
        let mut total = Noise::default();
        for t in tiles {
            match counted.get(&(t.x, t.y)) {
                Some(n) => total += *n,
                None => total += file.noise(t, range.end).ok()?,
            }
        }
        Some(total)
    }

    /// Queues a progressive job: `spec`'s camera rendered in passes, as
    /// `p` asks. It counts as one job of its submitter.
    pub fn submit_progressive<'a>(
        &self,
        spec: JobSpec,
        p: Progressive,
        opts: impl Into<SubmitOptions<'a>>,
    ) -> Result<crate::scheduler::JobInfo, FarmError> {
        p.check()?;
        let (total, own) = self.job_samples(&spec, &p);
        self.check_progressive(&spec, total)?;
        let passes = Passes::new(total, own, &p);
        self.submit_runs(spec, super::sequences::Runs::Passes(passes), opts.into())
    }

    /// Queues a sequence in passes: frames `first..=last` of `spec`'s
    /// camera, each rendered in passes as `p` asks (its samples and pass
    /// size; a sequence takes no time limit or noise target), one frame
    /// after the other.
    pub fn submit_progressive_sequence<'a>(
        &self,
        spec: JobSpec,
        first: u32,
        last: u32,
        p: Progressive,
        opts: impl Into<SubmitOptions<'a>>,
    ) -> Result<crate::scheduler::JobInfo, FarmError> {
        p.check()?;
        if p.time_limit.is_some() || p.noise_target.is_some() {
            return Err(FarmError::Invalid(
                "a sequence in passes takes --samples and --pass only: a time limit or a \
                 noise target would stop it in the middle of a frame"
                    .into(),
            ));
        }
        let (total, own) = self.job_samples(&spec, &p);
        self.check_progressive(&spec, total)?;
        let mut passes = Passes::new(total, own, &p);
        passes.frames = true;
        self.submit_frames(spec, first, last, Some(passes), opts.into())
    }

    /// A job's samples per pixel and whether they are its own (`p.samples`)
    /// or its scene's.
    fn job_samples(&self, spec: &JobSpec, p: &Progressive) -> (u32, bool) {
        match p.samples {
            0 => (
                self.summaries
                    .get(&spec.bundle_hash)
                    .and_then(|s| {
                        s.cameras
                            .iter()
                            .find(|c| c.id == spec.camera)
                            .map(|c| c.samples_per_pixel)
                    })
                    .unwrap_or(1),
                false,
            ),
            n => (n, true),
        }
    }

    /// The bounds a progressive job of `total` samples per pixel must fit:
    /// the frame's samples, its tiles' states, its states on disk.
    fn check_progressive(&self, spec: &JobSpec, total: u32) -> Result<(), FarmError> {
        let limits = &self.cfg.limits;
        let samples = u64::from(spec.width) * u64::from(spec.height) * u64::from(total);
        if samples > limits.max_image_samples {
            return Err(FarmError::limit(
                LimitKind::ImageSamples,
                samples,
                limits.max_image_samples,
                format!(
                    "{}x{} at {total} samples per pixel is {samples} samples, more than the \
                     coordinator's limit of {} (--max-image-samples)",
                    spec.width, spec.height, limits.max_image_samples
                ),
            ));
        }
        let tile = u64::from(spec.tile_size.max(1)).pow(2);
        if tile > limits.max_state_lease_pixels {
            return Err(FarmError::limit(
                LimitKind::StateLeasePixels,
                tile,
                limits.max_state_lease_pixels,
                format!(
                    "a progressive job's tiles carry their state (64 bytes a pixel): tiles of \
                     {tile} pixels are more than the {} a lease of one may hold; use a smaller \
                     --tile-size",
                    limits.max_state_lease_pixels
                ),
            ));
        }
        let bytes = state_bytes(spec.width, spec.height);
        if bytes > limits.max_job_state_bytes {
            return Err(FarmError::limit(
                LimitKind::JobStateBytes,
                bytes,
                limits.max_job_state_bytes,
                format!(
                    "a progressive job keeps 128 bytes a pixel of accumulation state on the \
                     coordinator's disk: {}x{} is {bytes} bytes, more than the {} a job may keep",
                    spec.width, spec.height, limits.max_job_state_bytes
                ),
            ));
        }
        Ok(())
    }

    /// Adds `samples` samples per pixel to finished progressive job `job`
    /// with its own sample count, and runs it again from its states, with
    /// `p`'s pass size and stop conditions (its own when not given).
    pub fn extend(
        &self,
        job: JobId,
        samples: u32,
        p: Progressive,
    ) -> Result<crate::scheduler::JobInfo, FarmError> {
        p.check()?;
        if samples == 0 {
            return Err(FarmError::Invalid("extend by at least 1 sample".into()));
        }
        let (spec, passes, done, state) = {
            let st = self.state.lock();
            let Some(s) = st.seqs.get(&job) else {
                return Err(if st.info(job, Instant::now()).is_some() {
                    FarmError::Invalid(format!(
                        "job {job} was not rendered in passes: only a job submitted with \
                         --samples can be extended"
                    ))
                } else {
                    FarmError::UnknownJob(job)
                });
            };
            let Some(passes) = s.passes.clone().filter(|p| !p.frames) else {
                return Err(FarmError::Invalid(format!(
                    "job {job} is a sequence: only a still rendered in passes can be extended"
                )));
            };
            (s.spec.clone(), passes, s.done, s.state)
        };
        if state != JobState::Done {
            return Err(FarmError::Invalid(format!(
                "job {job} is {}: only a finished job can be extended",
                state.name()
            )));
        }
        if !passes.own {
            return Err(FarmError::Invalid(format!(
                "job {job} renders the scene's own samples, whose sequence does not extend: \
                 submit with --samples N to extend it later"
            )));
        }
        let total = u64::from(passes.samples_done) + u64::from(samples);
        if total > u64::from(MAX_SAMPLES) {
            return Err(FarmError::Invalid(format!(
                "{total} samples per pixel are more than the {MAX_SAMPLES} a job may have"
            )));
        }
        let total = total as u32;
        self.check_progressive(&spec, total)?;
        let dir = self.job_dir(job);
        if done > 0 && !state_path(&dir, done - 1).is_file() {
            return Err(FarmError::Invalid(format!(
                "job {job}'s accumulation state is gone (removed by retention): it cannot be \
                 extended"
            )));
        }
        let mut next = Passes {
            total,
            noise: HashMap::new(),
            stopped_by: None,
            ..passes
        };
        if p.pass > 0 {
            next.pass = p.pass.min(total - next.samples_done).max(1);
            next.auto = false;
        }
        next.time_limit = p.time_limit.or(next.time_limit);
        next.noise_target = p.noise_target.or(next.noise_target);
        if next.remaining() + done > MAX_PASSES {
            next.pass = (total - next.samples_done).div_ceil(MAX_PASSES - done.min(MAX_PASSES - 1));
        }
        self.reopen_runs(job, next)?;
        self.info(job)
    }
}
