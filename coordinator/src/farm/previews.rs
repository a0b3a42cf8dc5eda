//! Each job's live preview as a PNG: filling in while the job runs, and the
//! last state of the newest few ended jobs, so the monitor still shows them.

use super::{lock, Farm, State};
use crate::error::FarmError;
use crate::preview::{encode_png, Preview};
use crate::scheduler::JobId;
use std::sync::Arc;
use std::time::Instant;

/// A job's preview as a PNG file, with what it shows.
#[derive(Debug, Clone)]
pub struct PreviewImage {
    pub width: u32,
    pub height: u32,
    /// Tiles of the frame in the preview.
    pub tiles: u64,
    pub png: Arc<Vec<u8>>,
}

impl State {
    /// Keeps an ended job's last preview, so the monitor still shows it;
    /// `keep` at most (the newest).
    pub(super) fn keep_final_preview(
        &mut self,
        job: JobId,
        image: Option<PreviewImage>,
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
    pub(super) fn final_preview(&self, job: JobId) -> Option<PreviewImage> {
        let out = lock(&self.state).outputs.get(&job).cloned()?;
        let p = lock(&out).preview.clone();
        preview_image(&p).ok()
    }

    /// The job's preview: filling in while it runs, the last state once it
    /// ended (for the newest few finished jobs).
    pub fn preview(&self, job: JobId) -> Result<PreviewImage, FarmError> {
        let job = self.preview_job(job);
        let st = lock(&self.state);
        if let Some((_, image)) = st.final_previews.iter().find(|(j, _)| *j == job) {
            return Ok(image.clone());
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
