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
        let p = self
            .jobs
            .get_preview(pb::JobId { id, frame: None })
            .await
            .map_err(status_error)?
            .into_inner();
        let mut tmp = PartFile::new(out).await?;
        tokio::fs::write(&tmp.path, &p.png)
            .await
            .with_context(|| format!("cannot write {}", tmp.path.display()))?;
        tmp.persist(out).await?;
        Ok(p)
    }
}

/// The `--preview` file while a job is watched: rewritten at most once a
/// second while tiles arrive, and once more when the job ends.
pub(super) struct PreviewFile {
    path: Option<PathBuf>,
    last: Option<Instant>,
    tiles: Option<u64>,
    warned: bool,
}

impl PreviewFile {
    pub(super) fn new(path: Option<PathBuf>) -> Self {
        PreviewFile {
            path,
            last: None,
            tiles: None,
            warned: false,
        }
    }

    /// Rewrites the file from job `s.id`'s preview when tiles arrived and
    /// it is due (or the job has ended).
    pub(super) async fn update(&mut self, client: &mut Client, s: &pb::JobStatus) {
        let Some(path) = self.path.clone() else {
            return;
        };
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
            // The render matters more than its preview: say so once, go on.
            Err(e) if !self.warned => {
                self.warned = true;
                eprintln!("trevi-submit: cannot update the preview: {e:#}");
            }
            Err(_) => {}
        }
    }
}
