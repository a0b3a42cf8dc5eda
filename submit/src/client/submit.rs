//! Submitting: one job per camera, a still or a sequence of frames (a
//! still is the case without a frame range), then, unless detached,
//! following each job to its end and downloading its output. The embedded
//! farm of a local render is driven through here like any other.

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::time::Duration;
use trevi_core::output::Format;
use trevi_core::scene::animation::Frames;
use trevi_proto::pb::{self, JobState};

use super::connect::{reconnectable_error, status_error};
use super::upload::Encoded;
use super::Client;
use crate::progress::Progress;
use crate::sequence::Sequence;

/// Where a camera's output goes.
pub enum Output {
    /// A still's file.
    Still(PathBuf),
    /// A sequence: its frames and their files.
    Sequence(Sequence),
}

/// What every job of a submission asks of the farm besides its camera.
#[derive(Debug, Clone, Default)]
pub struct JobSpec {
    /// Higher runs first.
    pub priority: i32,
    /// Tile edge in pixels.
    pub tile_size: u32,
    /// Set for a progressive still (`--samples`, `--pass`, `--time-limit`,
    /// `--noise-target`; see `passes.rs`).
    pub progressive: Option<pb::Progressive>,
    /// URLs that receive each job's events (`--notify`).
    pub notify: Vec<String>,
    /// Farm jobs this one waits for (`--after`).
    pub after: Vec<u64>,
    /// The render passes (`--aovs`); `None`: each camera's own
    /// `<render aovs>`.
    pub aovs: Option<trevi_core::Aovs>,
}

/// One camera to render and where its output goes.
pub struct Target {
    pub camera: String,
    pub output: Output,
    /// The format of the file, or of every frame's (from the name's
    /// extension): the coordinator writes it.
    pub format: Format,
    /// This camera's render passes when they are not the submission's
    /// (`--denoise` adds the albedo and normal the denoiser uses).
    pub aovs: Option<trevi_core::Aovs>,
}

impl Target {
    /// A still of `camera` to `out`, or with `frames` a sequence to the
    /// files of the pattern `out`. Checks the output before anything is
    /// rendered: its extension must name a format (.png or .exr), it must
    /// not be anything but a regular file if it exists (see
    /// [`trevi_core::output::check_output`]), and it follows the scene
    /// parser's rule for `#` (none in a still's name, one run in a
    /// sequence's file name).
    pub fn new(camera: String, out: PathBuf, frames: Option<Frames>) -> Result<Target> {
        let (output, format) = match frames {
            None => {
                crate::cli::still_output(&out)?;
                let format = trevi_core::output::check_output(&out)?;
                (Output::Still(out), format)
            }
            Some(frames) => {
                let seq = Sequence::new(frames, out)?;
                let format = seq.format()?;
                (Output::Sequence(seq), format)
            }
        };
        Ok(Target {
            camera,
            output,
            format,
            aovs: None,
        })
    }

    /// The frames of a sequence; `None` for a still.
    pub fn frames(&self) -> Option<Frames> {
        match &self.output {
            Output::Still(_) => None,
            Output::Sequence(seq) => Some(seq.frames),
        }
    }

    /// The request that submits this camera of bundle `bundle_hash` as `job`.
    pub fn request(&self, bundle_hash: &str, job: &JobSpec) -> pb::SubmitJobRequest {
        pb::SubmitJobRequest {
            bundle_hash: bundle_hash.to_string(),
            camera: self.camera.clone(),
            priority: job.priority,
            tile_size: job.tile_size,
            output_format: self.format.extension().to_string(),
            frames: self.frames().map(|f| pb::FrameRange {
                first: f.first,
                last: f.last,
            }),
            progressive: job.progressive,
            notify: job.notify.clone(),
            after: job.after.clone(),
            aovs: self.aovs.or(job.aovs).map(|a| a.to_string()),
        }
    }
}

impl Client {
    /// Submits `target`'s camera of the bundle `bundle_hash` as one job: a
    /// still, or every frame of a sequence.
    pub async fn submit(
        &mut self,
        bundle_hash: &str,
        target: &Target,
        job: &JobSpec,
    ) -> Result<pb::JobStatus> {
        let request = target.request(bundle_hash, job);
        let what = if request.frames.is_some() {
            "'s sequence"
        } else {
            ""
        };
        Ok(self
            .jobs
            .submit_job(request)
            .await
            .map_err(status_error)
            .with_context(|| format!("the coordinator refused camera \"{}\"{what}", target.camera))?
            .into_inner())
    }

    /// Uploads the bundle, submits one job per target, and unless `detach`
    /// follows each (progress as `progress` says) and downloads its output:
    /// a still's image, or every frame of a sequence.
    pub async fn render(
        &mut self,
        bundle: &Encoded,
        targets: &[Target],
        job: &JobSpec,
        detach: bool,
        progress: Progress,
    ) -> Result<()> {
        let hash = self.upload(bundle).await?;
        let mut jobs = Vec::new();
        for t in targets {
            let s = self.submit(&hash, t, job).await?;
            self.submitted.push(s.id);
            let say = self.announce && progress != Progress::Quiet;
            match t.frames() {
                None if detach || say => eprintln!(
                    "job {} queued: camera {} ({}x{}, {} tiles) on {}",
                    s.id, s.camera, s.width, s.height, s.tiles_total, self.url
                ),
                Some(f) if say && !detach => eprintln!(
                    "sequence {}: camera {}, frames {}-{}",
                    s.id, t.camera, f.first, f.last
                ),
                _ => {}
            }
            if detach {
                println!("{}", s.id);
            }
            jobs.push(s.id);
        }
        if detach {
            return Ok(());
        }
        for (t, id) in targets.iter().zip(jobs) {
            match &t.output {
                Output::Still(out) => self.finish_still(id, t, out, progress).await?,
                Output::Sequence(seq) => self.finish_sequence(id, t, seq, progress).await?,
            }
        }
        Ok(())
    }

    /// Follows still `id` to its end and downloads its image to `out`.
    pub async fn finish_still(
        &mut self,
        id: u64,
        t: &Target,
        out: &Path,
        progress: Progress,
    ) -> Result<()> {
        // A progressive still's image is downloaded after each pass too.
        self.pass_output = Some((out.to_path_buf(), t.format));
        let s = self.watch(id, progress).await;
        self.pass_output = None;
        let s = s?;
        match s.state() {
            JobState::Done => {}
            JobState::Cancelled => bail!("job {id} (camera {}) was cancelled", t.camera),
            other => bail!(
                "job {id} (camera {}) {}: {}",
                t.camera,
                other.label(),
                s.error
            ),
        }
        self.download_again(id, None, out, t.format).await?;
        let passes = self.download_aovs(&s, None, out).await?;
        if progress != Progress::Quiet {
            for p in &passes {
                eprintln!("{}: render pass -> {}", s.camera, p.display());
            }
            let secs = s.render_ms as f64 / 1e3;
            let waited = if s.queued_ms >= 100 {
                format!(", after {:.1} s in the queue", s.queued_ms as f64 / 1e3)
            } else {
                String::new()
            };
            // A progressive still: the samples it reached, its error, and
            // why it stopped early if it did.
            let passes = s.passes.as_ref().map_or(String::new(), |p| {
                format!("; {}", crate::passes::describe(p))
            });
            eprintln!(
                "{}: {}x{} -> {} in {:.2} s, {:.1} M rays ({:.2} M rays/s){waited}{passes}",
                s.camera,
                s.width,
                s.height,
                out.display(),
                secs,
                s.rays as f64 / 1e6,
                s.rays as f64 / 1e6 / secs.max(1e-9)
            );
        }
        Ok(())
    }

    /// Follows sequence `id` to its end (frames done, the current frame, an
    /// ETA) and downloads every frame to `seq`'s files (a PNG frame's pass
    /// files beside it); of a sequence that did not finish, the frames it
    /// finished.
    async fn finish_sequence(
        &mut self,
        id: u64,
        t: &Target,
        seq: &Sequence,
        progress: Progress,
    ) -> Result<()> {
        let end = self.watch(id, progress).await?;
        if end.state() != JobState::Done {
            // The frames it finished are kept.
            if end.frames_done > 0 {
                match self.fetch_frames(end.clone(), Some(&seq.pattern)).await {
                    Ok(_) if progress != Progress::Quiet => eprintln!(
                        "sequence {id}: kept the {} frames it finished ({})",
                        end.frames_done,
                        seq.pattern.display()
                    ),
                    Ok(_) => {}
                    Err(e) => eprintln!("sequence {id}: its finished frames: {e:#}"),
                }
            }
            bail!("sequence {id} {}: {}", end.state().label(), end.error);
        }
        for f in seq.frames.first..=seq.frames.last {
            let out = seq.output(f);
            self.download_again(id, Some(f), &out, t.format)
                .await
                .with_context(|| format!("frame {f}"))?;
            let passes = self
                .download_aovs(&end, Some(f), &out)
                .await
                .with_context(|| format!("frame {f}"))?;
            if progress != Progress::Quiet {
                eprintln!("{}: frame {f} -> {}", t.camera, out.display());
                for p in &passes {
                    eprintln!("{}: frame {f} render pass -> {}", t.camera, p.display());
                }
            }
        }
        Ok(())
    }

    /// Downloads the frames every sequence of `targets` has finished so far
    /// (a local render interrupted: the frames done are kept, as a
    /// sequence that failed keeps them); says so unless `progress` is quiet.
    pub async fn keep_finished_frames(&mut self, targets: &[Target], progress: Progress) {
        let Ok(jobs) = self.list(None).await else {
            return;
        };
        for s in jobs {
            let Some(seq) = targets.iter().find_map(|t| match &t.output {
                Output::Sequence(seq) if t.camera == s.camera && s.frames.is_some() => Some(seq),
                _ => None,
            }) else {
                continue;
            };
            if s.frames_done == 0 {
                continue;
            }
            let (id, done) = (s.id, s.frames_done);
            match self.fetch_frames(s, Some(&seq.pattern)).await {
                Ok(_) if progress != Progress::Quiet => eprintln!(
                    "sequence {id}: kept the {done} frames it finished ({})",
                    seq.pattern.display()
                ),
                Ok(_) => {}
                Err(e) => eprintln!("sequence {id}: its finished frames: {e:#}"),
            }
        }
    }

    /// [`Client::download`] of a job that has ended, asked again while the
    /// coordinator is away: it may restart between the end and the
    /// download.
    async fn download_again(
        &mut self,
        id: u64,
        frame: Option<u32>,
        out: &Path,
        format: Format,
    ) -> Result<u64> {
        let mut tries = 0;
        loop {
            match self.download(id, frame, out, format).await {
                Ok(n) => return Ok(n),
                Err(e) if reconnectable_error(&e) && tries < 19 => {
                    tries += 1;
                    tokio::time::sleep(Duration::from_millis(250 * tries)).await;
                }
                Err(e) => return Err(e),
            }
        }
    }
}

#[cfg(test)]
mod tests;
