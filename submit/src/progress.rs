//! How a job's progress is shown while it is followed: a still's tiles, a
//! progressive still's passes (the current pass's tiles, the samples per
//! pixel and the estimated error), or a sequence's frames done and its
//! current frame's share, with an ETA; as a bar at a terminal, as a line
//! every 10 % (a still), every pass (a progressive still) or every frame
//! (a sequence) otherwise, or not at all (`-q`).

use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal;
use trevi_proto::pb;

/// How progress is shown.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Progress {
    Quiet,
    /// A progress bar (stderr is a terminal).
    Bar,
    /// Plain lines every 10 %.
    Lines,
}

impl Progress {
    /// Nothing with `quiet`, else a bar when stderr is a terminal and lines
    /// when it is not.
    pub fn choose(quiet: bool) -> Progress {
        if quiet {
            Progress::Quiet
        } else if std::io::stderr().is_terminal() {
            Progress::Bar
        } else {
            Progress::Lines
        }
    }
}

/// One followed job's progress on stderr, from its statuses.
pub struct ProgressView {
    mode: Progress,
    bar: Option<ProgressBar>,
    last_pct: Option<u64>,
}

impl ProgressView {
    pub fn new(mode: Progress) -> Self {
        ProgressView {
            mode,
            bar: None,
            last_pct: None,
        }
    }

    /// Shows status `s`: a still's tiles, or a sequence's frames.
    pub fn show(&mut self, s: &pb::JobStatus) {
        // Rates and the ETA count the time rendered, not the queue wait.
        let secs = s.render_ms as f64 / 1e3;
        if let Some(f) = s.frames {
            return self.show_frames(s, f, secs);
        }
        let rate = s.rays as f64 / secs.max(1e-9) / 1e6;
        if let Some(p) = &s.passes {
            return self.show_passes(s, p, secs, rate);
        }
        let eta = eta(s, secs);
        match self.mode {
            Progress::Quiet => {}
            Progress::Bar => {
                let bar = self.bar.get_or_insert_with(|| {
                    let b = ProgressBar::new(s.tiles_total);
                    b.set_style(
                        ProgressStyle::with_template("{prefix} [{bar:40}] {pos}/{len} tiles {msg}")
                            .expect("static template")
                            .progress_chars("=> "),
                    );
                    b.set_prefix(s.camera.clone());
                    b
                });
                bar.set_position(s.tiles_done);
                bar.set_message(format!("{rate:.2} M rays/s {eta}"));
            }
            Progress::Lines => {
                let pct = s.tiles_done * 100 / s.tiles_total.max(1);
                let due = match self.last_pct {
                    None => true,
                    Some(p) => pct >= p + 10 || (pct == 100 && p != 100),
                };
                if due {
                    self.last_pct = Some(pct);
                    eprintln!(
                        "{}: {pct}% ({}/{} tiles, {rate:.2} M rays/s, {eta})",
                        s.camera, s.tiles_done, s.tiles_total
                    );
                }
            }
        }
    }

    /// A sequence: frames done, the current frame's share, an ETA from the
    /// tiles of every frame.
    fn show_frames(&mut self, s: &pb::JobStatus, f: pb::FrameRange, secs: f64) {
        let count = u64::from(f.last - f.first) + 1;
        let eta = eta(s, secs);
        let current = match s.current_frame {
            Some(c) => format!(
                ", frame {c} {}%",
                s.current_tiles_done * 100 / s.current_tiles_total.max(1)
            ),
            None => String::new(),
        };
        let line = format!(
            "{}: {}/{count} frames done{current}, {eta}",
            s.camera, s.frames_done
        );
        match self.mode {
            Progress::Quiet => {}
            Progress::Bar => {
                let bar = self.bar.get_or_insert_with(|| {
                    let b = ProgressBar::new(count);
                    b.set_style(ProgressStyle::with_template("{msg}").expect("static template"));
                    b
                });
                bar.set_message(line);
            }
            Progress::Lines => {
                let pct = u64::from(s.frames_done);
                if self.last_pct != Some(pct) {
                    self.last_pct = Some(pct);
                    eprintln!("{line}");
                }
            }
        }
    }

    /// A progressive still: the current pass's tiles on the bar, the samples
    /// per pixel and the error beside it; a line at each pass completed.
    fn show_passes(&mut self, s: &pb::JobStatus, p: &pb::PassesInfo, secs: f64, rate: f64) {
        let eta = passes_eta(s, p, secs);
        let mut said = pass_text(s, p);
        match self.mode {
            Progress::Quiet => {}
            Progress::Bar => {
                let bar = self.bar.get_or_insert_with(|| {
                    let b = ProgressBar::new(s.tiles_total);
                    b.set_style(
                        ProgressStyle::with_template("{prefix} [{bar:30}] {pos}/{len} tiles {msg}")
                            .expect("static template")
                            .progress_chars("=> "),
                    );
                    b.set_prefix(s.camera.clone());
                    b
                });
                // Each pass counts its own tiles.
                bar.set_length(s.tiles_total);
                bar.set_position(s.tiles_done);
                bar.set_message(format!("{said}, {rate:.2} M rays/s {eta}"));
            }
            Progress::Lines => {
                let done = u64::from(p.done);
                if self.last_pct != Some(done) {
                    self.last_pct = Some(done);
                    said.push_str(&format!(", {rate:.2} M rays/s, {eta}"));
                    eprintln!("{}: {said}", s.camera);
                }
            }
        }
    }

    /// Clears the bar, if any: the job has ended or is no longer followed.
    pub fn done(&mut self) {
        if let Some(b) = self.bar.take() {
            b.finish_and_clear();
        }
    }
}

/// The time left, from the share of the tiles done in `secs`.
fn eta(s: &pb::JobStatus, secs: f64) -> String {
    if s.tiles_done > 0 && s.tiles_done < s.tiles_total {
        let left = secs * (s.tiles_total - s.tiles_done) as f64 / s.tiles_done as f64;
        format!("ETA {left:.0} s")
    } else {
        "ETA -".to_string()
    }
}

/// A progressive still's passes for the progress display: the pass
/// rendering now (or the last one, once it ended), the samples per pixel
/// in the output and asked for, the estimated error, why it stopped early.
fn pass_text(s: &pb::JobStatus, p: &pb::PassesInfo) -> String {
    let running = !s.state().is_final() && p.samples_done < p.samples_total;
    let mut t = if running {
        format!(
            "pass {}, {}/{} spp done",
            p.done + 1,
            p.samples_done,
            p.samples_total
        )
    } else {
        format!(
            "pass {}, {}/{} spp",
            p.done, p.samples_done, p.samples_total
        )
    };
    if let Some(e) = p.error {
        t.push_str(&format!(", error {}", crate::passes::percent(e)));
    }
    if let Some(why) = crate::passes::stopped_by(p) {
        t.push_str(&format!(", {why}"));
    }
    t
}

/// The time left of a progressive still: the samples left at the pace of
/// those rendered in `secs` (the current pass's share counted by its
/// tiles), no later than the end of the pass that runs when the time
/// limit comes. A noise target may stop it sooner.
fn passes_eta(s: &pb::JobStatus, p: &pb::PassesInfo, secs: f64) -> String {
    let total = f64::from(p.samples_total);
    let this_pass = f64::from(p.pass.min(p.samples_total.saturating_sub(p.samples_done)));
    let share = s.tiles_done as f64 / s.tiles_total.max(1) as f64;
    let rendered = f64::from(p.samples_done) + this_pass * share;
    if rendered <= 0.0 || rendered >= total || s.state().is_final() {
        return "ETA -".to_string();
    }
    let per_sample = secs / rendered;
    let mut left = per_sample * (total - rendered);
    if p.time_limit_ms > 0 {
        let to_limit = (p.time_limit_ms as f64 / 1e3 - secs).max(0.0);
        let pass_left = per_sample * this_pass * (1.0 - share);
        left = left.min(to_limit.max(pass_left));
    }
    format!("ETA {left:.0} s")
}

#[cfg(test)]
mod tests;
