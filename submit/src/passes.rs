//! Progressive renders from the client's side (docs/progressive.md): the
//! flags that make a job progressive (`--samples`, `--pass`,
//! `--time-limit`, `--noise-target`) with their bounds, the
//! `SubmitJobRequest.progressive` and `ExtendJobRequest` they make, and how
//! a job's passes read in `status`, `list` and the progress display.
//!
//! Every bound is checked when the command line is read, before anything
//! is uploaded: a value clap's parser refuses names its flag, and the one
//! rule across flags (a pass no larger than the total) is checked by
//! [`check`] right after.

use std::time::Duration;
use trevi_core::passes::MAX_SAMPLES;
use trevi_proto::pb;

/// Longest `--time-limit`: 365 days. Longer is a typo, not a render.
pub const MAX_TIME_LIMIT: Duration = Duration::from_secs(365 * 86400);

/// The flags of a progressive render that `extend` takes too: how the
/// (new) passes are cut and when they stop.
#[derive(clap::Args, Debug, Clone, Default, PartialEq)]
pub struct PassFlags {
    /// Samples per pixel in each pass (at least 1, at most --samples; default:
    /// the coordinator's, from the scene's cost). On a render: makes the job
    /// progressive.
    #[arg(long, env = "TREVI_PASS", value_parser = pass_samples)]
    pub pass: Option<u32>,
    /// Start no new pass once the job has rendered this long (1s to 365d, like
    /// 90s, 10m, 2h). On a render: makes the job progressive.
    #[arg(long = "time-limit", env = "TREVI_TIME_LIMIT", value_parser = time_limit)]
    pub time_limit: Option<Duration>,
    /// Stop after the first pass whose estimated relative error of the frame
    /// is at most this: a number above 0 and below 1 (0.01: 1 %). On a
    /// render: makes the job progressive.
    #[arg(long = "noise-target", env = "TREVI_NOISE_TARGET", value_parser = noise_target)]
    pub noise_target: Option<f64>,
}

impl PassFlags {
    /// Whether any of them is given.
    pub fn any(&self) -> bool {
        self.pass.is_some() || self.time_limit.is_some() || self.noise_target.is_some()
    }

    /// The request's `Progressive` with these and `samples` (0: unset).
    fn message(&self, samples: u32) -> pb::Progressive {
        pb::Progressive {
            samples,
            pass: self.pass.unwrap_or(0),
            // At most MAX_TIME_LIMIT: fits in u64 milliseconds.
            time_limit_ms: self.time_limit.map_or(0, |d| d.as_millis() as u64),
            noise_target: self.noise_target.unwrap_or(0.0),
        }
    }
}

/// `--samples` of a render, and of `extend`: 1 to [`MAX_SAMPLES`].
pub fn samples(s: &str) -> Result<u32, String> {
    count(s, "samples per pixel")
}

/// `--pass`: 1 to [`MAX_SAMPLES`] (and no more than the total, see [`check`]).
pub fn pass_samples(s: &str) -> Result<u32, String> {
    count(s, "samples per pass")
}

fn count(s: &str, what: &str) -> Result<u32, String> {
    match s.trim().parse::<u32>() {
        Ok(n) if (1..=MAX_SAMPLES).contains(&n) => Ok(n),
        _ => Err(format!(
            "\"{s}\" is not a number of {what} from 1 to {MAX_SAMPLES}"
        )),
    }
}

/// `--time-limit`: a duration of `trevi_proto::duration` from 1 s to
/// [`MAX_TIME_LIMIT`].
pub fn time_limit(s: &str) -> Result<Duration, String> {
    let d = trevi_proto::duration::parse(s).map_err(|e| e.to_string())?;
    if d.is_zero() || d > MAX_TIME_LIMIT {
        return Err(format!("\"{s}\" is not a time limit from 1s to 365d"));
    }
    Ok(d)
}

/// `--noise-target`: a finite number above 0 and below 1.
pub fn noise_target(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(x) if x.is_finite() && x > 0.0 && x < 1.0 => Ok(x),
        _ => Err(format!(
            "\"{s}\" is not a relative error above 0 and below 1 (like 0.01 for 1 %)"
        )),
    }
}

/// The rule across flags: a pass no larger than the samples (the total of
/// a render, the samples added by `extend`).
pub fn check(samples: Option<u32>, flags: &PassFlags) -> Result<(), String> {
    match (samples, flags.pass) {
        (Some(total), Some(pass)) if pass > total => Err(format!(
            "--pass {pass} is more than --samples {total}: a pass is a share of the samples"
        )),
        _ => Ok(()),
    }
}

/// A render's `SubmitJobRequest.progressive`: set when any of the flags is
/// given (0 for each one not given), else unset (one pass of the scene's
/// samples).
pub fn progressive(samples: Option<u32>, flags: &PassFlags) -> Option<pb::Progressive> {
    if samples.is_none() && !flags.any() {
        return None;
    }
    Some(flags.message(samples.unwrap_or(0)))
}

/// `extend`'s request: `samples` more per pixel for job `id`; the new
/// passes' settings only when one is given.
pub fn extend_request(id: u64, samples: u32, flags: &PassFlags) -> pb::ExtendJobRequest {
    pb::ExtendJobRequest {
        id,
        samples,
        passes: flags.any().then(|| flags.message(0)),
    }
}

/// A relative error as a percentage with two significant digits or so.
pub fn percent(e: f64) -> String {
    let p = e * 100.0;
    if !p.is_finite() {
        "unknown".to_string()
    } else if p >= 10.0 {
        format!("{p:.0}%")
    } else if p >= 1.0 {
        format!("{p:.1}%")
    } else {
        format!("{p:.2}%")
    }
}

/// Why a job's passes stopped early, as a phrase ("stopped by the time
/// limit"); `None` when they did not.
pub fn stopped_by(p: &pb::PassesInfo) -> Option<String> {
    match p.stopped_by.as_str() {
        "" => None,
        "time limit" => Some("stopped by the time limit".into()),
        "noise target" => Some("stopped by the noise target".into()),
        other => Some(format!("stopped by {other}")),
    }
}

/// A job's passes for `status`: "pass D, S of T samples per pixel,
/// estimated error E%" (no error before a pass with two samples a pixel),
/// and why it stopped early, if it did.
pub fn describe(p: &pb::PassesInfo) -> String {
    let mut line = format!(
        "pass {}, {} of {} samples per pixel",
        p.done, p.samples_done, p.samples_total
    );
    if let Some(e) = p.error {
        line.push_str(&format!(", estimated error {}", percent(e)));
    }
    if let Some(why) = stopped_by(p) {
        line.push_str(&format!(", {why}"));
    }
    line
}

/// A job's passes in `list`: samples per pixel done and asked for.
pub fn spp(p: &pb::PassesInfo) -> String {
    format!("{}/{}", p.samples_done, p.samples_total)
}

#[cfg(test)]
mod tests;
