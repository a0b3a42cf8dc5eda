//! A job's live preview (a PNG): saved once (`status --preview`), or kept
//! up to date in the `--preview` file while the job is watched.

use anyhow::{Context, Result};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use trevi_proto::pb;

use super::connect::status_error;
use super::download::PartFile;
use super::Client;

impl Client {
    /// Writes job `id`'s live preview (a PNG) to `out`, through a temporary
    /// file renamed into place so a viewer never sees half an image.
    pub async fn save_preview(&mut self, id: u64, out: &Path) -> Result<pb::Preview> {
        let p = self.preview(id).await?;
        write_in_place(out, &p.png).await?;
        Ok(p)
    }

    /// Writes job `id`'s live preview to `out` denoised with `threads` OIDN
    /// threads (on a blocking thread: a preview is at most 512 pixels a
    /// side), through a part file renamed into place.
    pub async fn save_denoised_preview(&mut self, id: u64, out: &Path, threads: u32) -> Result<()> {
        let p = self.preview(id).await?;
        let png =
            tokio::task::spawn_blocking(move || crate::denoise::denoise_preview(&p.png, threads))
                .await
                .context("the preview's denoise thread")??;
        write_in_place(out, &png).await
    }

    async fn preview(&mut self, id: u64) -> Result<pb::Preview> {
        Ok(self
            .jobs
            .get_preview(pb::JobId { id, frame: None })
            .await
            .map_err(status_error)?
            .into_inner())
    }
}

/// Writes `bytes` to `out` through a part file renamed into place.
async fn write_in_place(out: &Path, bytes: &[u8]) -> Result<()> {
    let mut tmp = PartFile::new(out).await?;
    tokio::fs::write(&tmp.path, bytes)
        .await
        .with_context(|| format!("cannot write {}", tmp.path.display()))?;
    tmp.persist(out).await
}

/// The `--preview` file while a job is watched: rewritten at most once a
/// second while tiles arrive, and once more when the job ends. With
/// `--denoise`, a progressive job's preview is rewritten after each pass
/// instead, denoised (crate::denoise::denoise_preview).
pub(super) struct PreviewFile {
    path: Option<PathBuf>,
    last: Option<Instant>,
    tiles: Option<u64>,
    warned: bool,
    /// OIDN threads for a progressive job's denoised preview (`None`: the
    /// preview as the farm draws it).
    denoise: Option<u32>,
    /// Passes whose denoised preview is in the file.
    passes_shown: u32,
    /// No denoised preview before then (see [`DENOISE_SHARE`]).
    next_denoise: Option<Instant>,
}

/// A denoised preview takes at most one part in this many of the time a
/// progressive job is watched (after one that took `d`, the next pass's
/// waits `d × (DENOISE_SHARE - 1)`): passes that end sooner are skipped,
/// the last is always shown. Measured in docs/denoise.md: a 512×384
/// preview takes about 0.8 s of one core, 2.6 times a pass of one sample a
/// pixel of that frame, so denoising every pass would have cost more than
/// the render.
const DENOISE_SHARE: u32 = 10;

impl PreviewFile {
    pub(super) fn new(path: Option<PathBuf>, denoise: Option<u32>) -> Self {
        PreviewFile {
            path,
            last: None,
            tiles: None,
            warned: false,
            denoise,
            passes_shown: 0,
            next_denoise: None,
        }
    }

    /// Rewrites the file from job `s.id`'s preview when tiles arrived and
    /// it is due (or the job has ended); a progressive job's, denoised, when
    /// a pass has ended.
    pub(super) async fn update(&mut self, client: &mut Client, s: &pb::JobStatus) {
        let Some(path) = self.path.clone() else {
            return;
        };
        if let (Some(threads), Some(passes)) = (self.denoise, &s.passes) {
            let due = self.next_denoise.is_none_or(|t| Instant::now() >= t);
            if passes.done > self.passes_shown && (due || s.state().is_final()) {
                self.passes_shown = passes.done;
                let started = Instant::now();
                let saved = client.save_denoised_preview(s.id, &path, threads).await;
                self.next_denoise = Some(Instant::now() + started.elapsed() * (DENOISE_SHARE - 1));
                self.warn_once(saved.err());
            }
            return;
        }
        let due = self
            .last
            .is_none_or(|t| t.elapsed() >= Duration::from_secs(1));
        let changed = self.tiles != Some(s.tiles_done);
        if !(changed && (due || s.state().is_final())) {
            return;
        }
        self.last = Some(Instant::now());
        match client.save_preview(s.id, &path).await {
            Ok(_) => self.tiles = Some(s.tiles_done),
            Err(e) => self.warn_once(Some(e)),
        }
    }

    /// The render matters more than its preview: says so once, goes on.
    fn warn_once(&mut self, e: Option<anyhow::Error>) {
        if let Some(e) = e {
            if !self.warned {
                self.warned = true;
                eprintln!("trevi-submit: cannot update the preview: {e:#}");
            }
        }
    }
}
