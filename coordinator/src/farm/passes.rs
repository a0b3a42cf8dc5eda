//! A progressive job's passes as the coordinator plans them (how many
//! samples each, when to stop) and what a submission asks of them: values
//! only, kept with the job's [`super::sequences::Sequence`] and run by
//! `progressive.rs`.

use crate::error::FarmError;
use crate::scheduler::{PassesInfo, SampleRange, StopReason};
use crate::store::StoredPasses;
use std::collections::HashMap;
use std::time::Duration;
use trevi_core::passes::{Noise, MAX_SAMPLES};

/// Passes a job renders at most (each costs the coordinator a pass over
/// the frame's states, and a restart a pass job row).
pub const MAX_PASSES: u32 = 4096;
/// Passes a job's samples are split into when it does not say
/// (`--pass`): a first look after an eighth of the samples; after that a
/// still's passes are sized from the scene's measured cost (see
/// [`PASS_TARGET`]).
pub const DEFAULT_PASSES: u32 = 8;
/// The render time a still's pass aims at when the job does not say
/// `--pass`: each pass after the first takes as many samples as the one
/// before rendered in this long (at most twice as many), so a cheap frame
/// finishes in a few passes and an expensive one shows a new image about
/// this often.
pub const PASS_TARGET: Duration = Duration::from_secs(10);

/// What a submission asks of a progressive job (`SubmitJobRequest.progressive`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Progressive {
    /// The job's own samples per pixel; 0: the scene's.
    pub samples: u32,
    /// Samples per pass; 0: the coordinator's ([`DEFAULT_PASSES`] passes
    /// at first, then sized towards [`PASS_TARGET`]).
    pub pass: u32,
    /// No pass starts once the job has rendered this long.
    pub time_limit: Option<Duration>,
    /// The job stops after a pass whose estimated relative error is at
    /// most this (above 0).
    pub noise_target: Option<f64>,
}

impl Progressive {
    /// Checks the request's values (before anything is queued).
    pub fn check(&self) -> Result<(), FarmError> {
        if self.samples > MAX_SAMPLES {
            return Err(FarmError::Invalid(format!(
                "{} samples per pixel are more than the {MAX_SAMPLES} a job may ask for",
                self.samples
            )));
        }
        if let Some(t) = self.noise_target {
            if !(t.is_finite() && t > 0.0) {
                return Err(FarmError::Invalid(format!(
                    "the noise target {t} is not a number above 0"
                )));
            }
        }
        Ok(())
    }
}

/// A progressive job's passes, kept with its [`super::sequences::Sequence`]
/// (whose frames are the passes' indices).
#[derive(Debug, Clone)]
pub struct Passes {
    pub(super) total: u32,
    /// `total` is the job's own (rendered as min = max adaptive sampling),
    /// so it extends.
    pub(super) own: bool,
    pub(super) pass: u32,
    pub(super) time_limit: Option<Duration>,
    pub(super) noise_target: Option<f64>,
    /// Samples per pixel of the passes done.
    pub(super) samples_done: u32,
    pub(super) error: Option<f64>,
    pub(super) stopped_by: Option<StopReason>,
    /// The noise of the tiles of the pass in progress, by tile origin
    /// (a tile taken twice counts once).
    pub(super) noise: HashMap<(u32, u32), Noise>,
    /// The pass size is the coordinator's to choose (no `--pass`).
    pub(super) auto: bool,
    /// The passes are each frame's of a sequence (`samples_done` then
    /// counts the current frame's), not a still's.
    pub(super) frames: bool,
}

impl Passes {
    /// The passes of a job of `total` samples per pixel.
    pub fn new(total: u32, own: bool, p: &Progressive) -> Passes {
        let total = total.max(1);
        let pass = if p.pass == 0 {
            total.div_ceil(DEFAULT_PASSES)
        } else {
            p.pass.min(total)
        }
        .max(total.div_ceil(MAX_PASSES))
        .max(1);
        Passes {
            total,
            own,
            pass,
            time_limit: p.time_limit,
            noise_target: p.noise_target,
            samples_done: 0,
            error: None,
            stopped_by: None,
            noise: HashMap::new(),
            auto: p.pass == 0,
            frames: false,
        }
    }

    /// After a pass of `samples` samples that rendered in `took`: the next
    /// pass's size, when the coordinator chooses it (a still without
    /// `--pass`), from what a sample cost, towards [`PASS_TARGET`].
    pub fn resize(&mut self, samples: u32, took: Duration) {
        if !self.auto || self.frames || samples == 0 {
            return;
        }
        let per_sample = took.as_secs_f64() / f64::from(samples);
        let want = if per_sample > 0.0 {
            (PASS_TARGET.as_secs_f64() / per_sample)
                .floor()
                .min(f64::from(u32::MAX)) as u32
        } else {
            u32::MAX
        };
        let floor = self.total.div_ceil(MAX_PASSES);
        self.pass = want.clamp(1, self.pass.saturating_mul(2)).max(floor);
    }

    /// The passes still to render.
    pub fn remaining(&self) -> u32 {
        (self.total - self.samples_done.min(self.total)).div_ceil(self.pass)
    }

    /// The sample range of pass `index`, the next one.
    pub fn range(&self, index: u32) -> SampleRange {
        SampleRange {
            pass: index,
            start: self.samples_done,
            end: (self.samples_done + self.pass).min(self.total),
            total: if self.own { self.total } else { 0 },
        }
    }

    /// Why no further pass should start now, after a pass ended, having
    /// rendered for `rendered`.
    pub fn stop(&self, rendered: Duration) -> Option<StopReason> {
        if self.samples_done == 0 || self.samples_done >= self.total {
            return None;
        }
        if let (Some(t), Some(e)) = (self.noise_target, self.error) {
            if e <= t {
                return Some(StopReason::NoiseTarget);
            }
        }
        match self.time_limit {
            Some(l) if rendered >= l => Some(StopReason::TimeLimit),
            _ => None,
        }
    }

    /// What `status` shows, with `done` passes done.
    pub fn info(&self, done: u32) -> PassesInfo {
        PassesInfo {
            done,
            samples_done: self.samples_done,
            samples_total: self.total,
            pass: self.pass,
            error: self.error.filter(|e| e.is_finite()),
            time_limit: self.time_limit,
            noise_target: self.noise_target,
            stopped_by: self.stopped_by,
        }
    }

    /// As stored.
    pub fn stored(&self) -> StoredPasses {
        StoredPasses {
            total: self.total,
            own: self.own,
            pass: self.pass,
            time_limit_ms: self.time_limit.map_or(0, |d| d.as_millis() as u64),
            noise_target: self.noise_target.unwrap_or(0.0),
            samples_done: self.samples_done,
            error: self.error,
            stopped_by: self.stopped_by,
            frames: self.frames,
            auto: self.auto,
        }
    }

    /// From the database.
    pub fn from_stored(p: &StoredPasses) -> Passes {
        Passes {
            total: p.total.max(1),
            own: p.own,
            pass: p.pass.max(1),
            time_limit: (p.time_limit_ms > 0).then(|| Duration::from_millis(p.time_limit_ms)),
            noise_target: (p.noise_target > 0.0).then_some(p.noise_target),
            samples_done: p.samples_done,
            error: p.error,
            stopped_by: p.stopped_by,
            noise: HashMap::new(),
            frames: p.frames,
            auto: p.auto,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn passes(total: u32, pass: u32) -> Passes {
        Passes::new(
            total,
            true,
            &Progressive {
                pass,
                ..Progressive::default()
            },
        )
    }

    #[test]
    fn ranges_cover_the_total_in_order() {
        let mut p = passes(20, 8);
        let mut got = Vec::new();
        for i in 0..p.remaining() {
            let r = p.range(i);
            got.push((r.start, r.end));
            p.samples_done = r.end;
        }
        assert_eq!(got, [(0, 8), (8, 16), (16, 20)]);
        assert_eq!(passes(64, 0).pass, 8, "eight passes by default");
        assert_eq!(passes(3, 0).pass, 1);
        assert_eq!(passes(1 << 20, 1).pass, 256, "at most MAX_PASSES passes");
        assert_eq!(passes(5, 9).pass, 5);
    }

    #[test]
    fn stops_at_the_noise_target_or_the_time_limit_not_before_a_pass() {
        let mut p = Passes::new(
            64,
            true,
            &Progressive {
                pass: 8,
                time_limit: Some(Duration::from_secs(10)),
                noise_target: Some(0.05),
                ..Progressive::default()
            },
        );
        assert_eq!(p.stop(Duration::from_secs(99)), None, "no pass yet");
        p.samples_done = 8;
        p.error = Some(0.2);
        assert_eq!(p.stop(Duration::from_secs(9)), None);
        assert_eq!(p.stop(Duration::from_secs(10)), Some(StopReason::TimeLimit));
        p.error = Some(0.05);
        assert_eq!(p.stop(Duration::ZERO), Some(StopReason::NoiseTarget));
        p.samples_done = 64;
        assert_eq!(p.stop(Duration::from_secs(99)), None, "done anyway");
    }

    #[test]
    fn without_pass_the_coordinator_sizes_passes_from_their_cost() {
        let mut p = passes(64, 0);
        assert_eq!((p.pass, p.auto), (8, true));
        // A sample took 10 s: one sample a pass.
        p.resize(8, Duration::from_secs(80));
        assert_eq!(p.pass, 1);
        // A sample took 0.1 s: 100 wanted, at most twice the last pass.
        p.resize(1, Duration::from_millis(100));
        assert_eq!(p.pass, 2);
        p.resize(2, Duration::ZERO);
        assert_eq!(p.pass, 4);
        // --pass given: kept.
        let mut fixed = passes(64, 4);
        fixed.resize(4, Duration::from_secs(400));
        assert_eq!(fixed.pass, 4);
    }

    #[test]
    fn stored_passes_come_back() {
        let mut p = passes(48, 16);
        p.samples_done = 16;
        p.error = Some(0.125);
        p.stopped_by = Some(StopReason::NoiseTarget);
        let back = Passes::from_stored(&p.stored());
        assert_eq!(back.stored(), p.stored());
    }
}
