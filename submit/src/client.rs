//! The client of a coordinator: upload a bundle, submit jobs (stills and
//! sequences alike), watch them, download their outputs; and `status`,
//! `list`, `cancel`, `pause`, `resume`, `fetch`, `extend`.
//!
//! It drives a farm's coordinator and the one embedded in `trevi-submit`
//! for a local render (see `local.rs`) alike, so both produce the same
//! bytes. The connection is here; what is done with it, one concept a
//! file, in `client/`.

use std::path::PathBuf;
use trevi_proto::pb::{self, bundles_client::BundlesClient, jobs_client::JobsClient};
use trevi_proto::AuthChannel;

mod aovs;
mod connect;
mod download;
mod jobs;
mod preview;
mod submit;
mod upload;
mod watch;

pub use submit::{JobSpec, Output, Target};
pub use upload::Encoded;

/// A connection to a coordinator.
pub struct Client {
    url: String,
    /// Say which jobs were queued where (off for the embedded farm).
    pub announce: bool,
    /// Keep the watched job's live preview in this PNG file (`--preview`).
    pub preview: Option<PathBuf>,
    /// With `--denoise`: a progressive job's preview is denoised after each
    /// pass, with this many OIDN threads (0: every core).
    pub denoise_preview: Option<u32>,
    /// The jobs submitted through this connection, in order.
    pub submitted: Vec<u64>,
    /// While a progressive still is watched: where its image goes, written
    /// again after each pass (the output is whole after every pass).
    pass_output: Option<(PathBuf, trevi_core::output::Format)>,
    jobs: JobsClient<AuthChannel>,
    bundles: BundlesClient<AuthChannel>,
}

/// One line about a job, for `status` and `list`.
pub fn describe(s: &pb::JobStatus) -> String {
    let mut line = format!(
        "{:>6}  {:<9}  {} camera {}  {}x{}  {}/{} tiles  priority {}  queued {:.1} s, \
         rendered {:.1} s  by {}",
        s.id,
        crate::control::state_word(s),
        s.scene,
        s.camera,
        s.width,
        s.height,
        s.tiles_done,
        s.tiles_total,
        s.priority,
        s.queued_ms as f64 / 1e3,
        s.render_ms as f64 / 1e3,
        if s.submitter.is_empty() {
            "-"
        } else {
            &s.submitter
        }
    );
    if let Some(f) = s.frames {
        line.push_str(&format!(
            "  frames {}-{}: {} done",
            f.first, f.last, s.frames_done
        ));
        if let Some(c) = s.current_frame {
            line.push_str(&format!(
                ", frame {c} {}/{} tiles",
                s.current_tiles_done, s.current_tiles_total
            ));
        }
    }
    if let Some(p) = &s.passes {
        line.push_str(&format!("  {}", crate::passes::describe(p)));
    }
    line.push_str(&crate::control::waiting_note(s));
    if !s.error.is_empty() {
        line.push_str(&format!("  error: {}", s.error));
    }
    line
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_progressive_job_s_status_shows_its_passes() {
        let mut s = pb::JobStatus {
            id: 4,
            error: "x".into(),
            ..Default::default()
        };
        let plain = describe(&s);
        assert!(!plain.contains("samples per pixel"), "{plain}");
        s.passes = Some(pb::PassesInfo {
            done: 3,
            samples_done: 12,
            samples_total: 64,
            error: Some(0.021),
            pass: 4,
            stopped_by: "time limit".into(),
            ..Default::default()
        });
        let line = describe(&s);
        assert!(
            line.contains(
                "  pass 3, 12 of 64 samples per pixel, estimated error 2.1%, \
                 stopped by the time limit  error: x"
            ),
            "{line}"
        );
        assert_eq!(
            line.replace(
                "  pass 3, 12 of 64 samples per pixel, estimated error 2.1%, \
                 stopped by the time limit",
                ""
            ),
            plain
        );
    }
}
