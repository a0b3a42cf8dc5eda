//! Each job's live preview as a PNG: filling in while the job runs, and the
//! last state of the newest few ended jobs, so the monitor still shows them.
//! Which jobs have one and when it is encoded is decided here; the scaled
//! image itself, filled in tile by tile, is [`crate::preview::Preview`].

use super::{lock, Farm, State};
use crate::error::FarmError;
use crate::preview::{encode_png, Preview};
use crate::scheduler::JobId;
use std::sync::{Arc, OnceLock};
use std::time::Instant;

/// A job's preview as a PNG file, with what it shows.
#[derive(Debug, Clone)]
pub struct PreviewImage {
    /// The preview's size in pixels: the frame shrunk by a whole factor to
    /// at most [`Preview::MAX_EDGE`] a side.
    pub width: u32,
    /// See `width`.
    pub height: u32,
    /// Tiles of the frame in the preview.
    pub tiles: u64,
    /// The encoded PNG file (8-bit RGBA).
    pub png: Arc<Vec<u8>>,
}

/// An ended job's last preview: its 8-bit RGBA pixels, encoded as a PNG
/// the first time someone asks for it. Encoding every ending frame's
/// preview at once (512×512 RGBA at the `png` crate's default level) was a
/// sixth of the coordinator's CPU time at a few frames a second
/// (docs/benchmarks.md, "The farm at scale"), for images the monitor
/// mostly never fetches. Holds `width × height × 4` bytes (1 MiB at most)
/// plus the PNG once made; [`crate::Limits::kept_previews`] are kept.
pub(super) struct FinalPreview {
    width: u32,
    height: u32,
    tiles: u64,
    rgba: Vec<u8>,
    png: OnceLock<Result<Arc<Vec<u8>>, String>>,
}

impl FinalPreview {
    fn of(p: &Preview) -> FinalPreview {
        FinalPreview {
            width: p.width,
            height: p.height,
            tiles: p.tiles,
            rgba: p.to_rgba8(),
            png: OnceLock::new(),
        }
    }

    /// The PNG, the same bytes as [`preview_image`] of the preview it was
    /// made from.
    fn image(&self) -> Result<PreviewImage, FarmError> {
        let png = self
            .png
            .get_or_init(|| {
                encode_png(self.width, self.height, &self.rgba)
                    .map(Arc::new)
                    .map_err(|e| e.to_string())
            })
            .clone()
            .map_err(|e| FarmError::io("encoding the preview", e))?;
        Ok(PreviewImage {
            width: self.width,
            height: self.height,
            tiles: self.tiles,
            png,
        })
    }
}

impl State {
    /// Keeps an ended job's last preview, so the monitor still shows it;
    /// `keep` at most (the newest).
    pub(super) fn keep_final_preview(
        &mut self,
        job: JobId,
        image: Option<Arc<FinalPreview>>,
        keep: usize,
    ) {
        let Some(image) = image else {
            return;
        };
        self.final_previews.push_back((job, image));
        while self.final_previews.len() > keep {
            self.final_previews.pop_front();
        }
    }
}

impl Farm {
    /// The job's preview as it stands, to keep once the job is over (made
    /// before the job is marked over, so whoever sees it over finds it).
    pub(super) fn final_preview(&self, job: JobId) -> Option<Arc<FinalPreview>> {
        let out = self.state.lock().outputs.get(&job).cloned()?;
        let image = FinalPreview::of(&lock(&out).preview);
        Some(Arc::new(image))
    }

    /// The job's preview: filling in while it runs, the last state once it
    /// ended (for the newest few finished jobs).
    pub fn preview(&self, job: JobId) -> Result<PreviewImage, FarmError> {
        let job = self.preview_job(job);
        let st = self.state.lock();
        if let Some((_, image)) = st.final_previews.iter().find(|(j, _)| *j == job) {
            let image = image.clone();
            drop(st);
            return image.image();
        }
        let info = st
            .sched
            .info(job, Instant::now())
            .ok_or(FarmError::UnknownJob(job))?;
        let out = st.outputs.get(&job).cloned();
        drop(st);
        let encoding = |e| FarmError::io("encoding the preview", e);
        match out {
            Some(out) => {
                let p = lock(&out).preview.clone();
                preview_image(&p).map_err(encoding)
            }
            None if !info.state.is_final() => {
                preview_image(&Preview::new(info.spec.width, info.spec.height)).map_err(encoding)
            }
            None => Err(FarmError::NoOutput(
                job,
                "its preview is no longer kept".to_string(),
            )),
        }
    }
}

fn preview_image(p: &Preview) -> Result<PreviewImage, png::EncodingError> {
    Ok(PreviewImage {
        width: p.width,
        height: p.height,
        tiles: p.tiles,
        png: Arc::new(encode_png(p.width, p.height, &p.to_rgba8())?),
    })
}
