//! Downloading a finished job's output: a still's image or a sequence's
//! frames (each with the pass files beside a PNG, `aovs.rs`), each through
//! a hidden part file renamed into place when complete; and `fetch`, which
//! finds out where they go from the job.

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use trevi_core::output::Format;
use trevi_core::scene::animation::Frames;
use trevi_proto::pb::{self, JobState};

use super::connect::status_error;
use super::Client;
use crate::sequence::Sequence;

impl Client {
    /// Downloads a finished job's image, or frame `frame` of a sequence,
    /// which must be a `format` file, to `out` (through a temporary file
    /// beside it, renamed into place when complete; removed on failure, or
    /// when this future is dropped).
    pub async fn download(
        &mut self,
        id: u64,
        frame: Option<u32>,
        out: &Path,
        format: Format,
    ) -> Result<u64> {
        use tokio::io::AsyncWriteExt;
        let mut stream = self
            .jobs
            .download_output(pb::JobId { id, frame })
            .await
            .map_err(status_error)?
            .into_inner();
        let mut tmp = PartFile::new(out).await?;
        let mut file = tokio::fs::File::create(&tmp.path)
            .await
            .with_context(|| format!("cannot write {}", tmp.path.display()))?;
        let mut size = None;
        let mut got = 0u64;
        while let Some(c) = stream.message().await.map_err(status_error)? {
            if size.is_none() {
                size = Some(c.size);
                // A coordinator that ignores `output_format` (older than
                // it) sends the scene's format: never store those bytes
                // under a name that promises another.
                let is = Format::sniff(&c.data);
                if is != Some(format) {
                    bail!(
                        "job {id}'s output is {}, not the {} file {} must be; \
                         submit again with -o FILE.{}, or to a newer coordinator",
                        is.map_or("not an image", |f| f.extension()),
                        format.extension(),
                        out.display(),
                        is.map_or("png", |f| f.extension()),
                    );
                }
            }
            got += c.data.len() as u64;
            file.write_all(&c.data).await?;
        }
        file.sync_all().await?;
        drop(file);
        if size != Some(got) {
            bail!("the download of job {id} stopped at {got} of {size:?} bytes");
        }
        tmp.persist(out).await?;
        Ok(got)
    }

    /// `trevi-submit fetch`: downloads finished job `id`'s image to `out`,
    /// by default the job's output file name in the current directory.
    /// Returns where it went and the job's status.
    pub async fn fetch(&mut self, id: u64, out: Option<&Path>) -> Result<(PathBuf, pb::JobStatus)> {
        let s = self.status(id).await?;
        if s.frames.is_some() {
            return self.fetch_frames(s, out).await;
        }
        match s.state() {
            JobState::Done => {}
            JobState::Failed => bail!("job {id} failed, it has no image: {}", s.error),
            JobState::Cancelled => bail!("job {id} was cancelled, it has no image"),
            other => bail!(
                "job {id} is {} ({}/{} tiles): fetch it once it is done \
                 (trevi-submit status {id})",
                other.label(),
                s.tiles_done,
                s.tiles_total
            ),
        }
        // Only the name: the coordinator does not choose the directory.
        let name = Path::new(&s.output_name)
            .file_name()
            .map(PathBuf::from)
            .with_context(|| format!("job {id} names no output file ({:?})", s.output_name))?;
        let format = Format::from_path(&name)
            .with_context(|| format!("job {id}'s output {} is not .png or .exr", name.display()))?;
        let out = out.map_or(name, Path::to_path_buf);
        let want = trevi_core::output::check_output(&out)?;
        if want != format {
            bail!(
                "job {id}'s image is a {} file ({}): -o must end in .{}",
                format.extension(),
                s.output_name,
                format.extension()
            );
        }
        self.download(id, None, &out, format).await?;
        // A PNG's render passes, beside it.
        self.download_aovs(&s, None, &out).await?;
        Ok((out, s))
    }

    /// `fetch` of a sequence: every frame done, named by the sequence's
    /// pattern (`shot.####.png`), into `out`: a pattern with a run of `#`,
    /// or a directory (default: the current one). Returns the pattern.
    pub(super) async fn fetch_frames(
        &mut self,
        s: pb::JobStatus,
        out: Option<&Path>,
    ) -> Result<(PathBuf, pb::JobStatus)> {
        let id = s.id;
        let f = s.frames.expect("a sequence");
        if s.state() != JobState::Done && s.frames_done == 0 {
            bail!(
                "sequence {id} is {} with no frame done yet (trevi-submit status {id})",
                s.state().label()
            );
        }
        let name = Path::new(&s.output_name)
            .file_name()
            .map(PathBuf::from)
            .with_context(|| format!("job {id} names no output pattern ({:?})", s.output_name))?;
        let pattern = match out {
            Some(o) if o.to_string_lossy().contains('#') => o.to_path_buf(),
            // A name like x.png is one file, not a directory to make.
            Some(o) if (o.extension().is_some() || o.exists()) && !o.is_dir() => {
                bail!(
                    "sequence {id} has {} frames: -o {} names one file; give a pattern \
                     with a run of # (like shot.####.png) or a directory",
                    f.last - f.first + 1,
                    o.display()
                )
            }
            Some(dir) => dir.join(&name),
            None => name,
        };
        // Only where the frames done can be: one request per frame done,
        // plus at most one per frame in progress (or cancelled by the end
        // of a sequence that failed), never one per frame of the range.
        let last = done_frames_end(&s, &f);
        let seq = Sequence::new(
            Frames {
                first: f.first,
                last,
            },
            pattern.clone(),
        )?;
        let format = seq.format()?;
        let mut got = 0;
        for frame in f.first..=last {
            if got >= s.frames_done {
                break;
            }
            let out = seq.output(frame);
            match self.download(id, Some(frame), &out, format).await {
                Ok(_) => got += 1,
                // A sequence that did not finish has frames without output.
                Err(_) if s.state() != JobState::Done => continue,
                Err(e) => return Err(e.context(format!("frame {frame}"))),
            }
            // A PNG frame's render passes, beside it (filed with the frame
            // on the coordinator: a frame there has them).
            self.download_aovs(&s, Some(frame), &out)
                .await
                .with_context(|| format!("frame {frame}"))?;
        }
        if got == 0 {
            bail!("sequence {id}: no frame could be fetched");
        }
        Ok((pattern, s))
    }
}

/// Where a file bound for `out` is written until it is complete: a hidden
/// name beside it (the directory is created), so a rename moves it into
/// place and nobody ever sees half a file under `out`. Removed when dropped
/// unless [`PartFile::persist`] moved it into place: after an error, and
/// when the future writing it is dropped (a signal, a cancelled render).
pub(super) struct PartFile {
    pub(super) path: PathBuf,
    armed: bool,
}

impl PartFile {
    pub(super) async fn new(out: &Path) -> Result<PartFile> {
        let dir = out
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        tokio::fs::create_dir_all(dir)
            .await
            .with_context(|| format!("cannot create {}", dir.display()))?;
        let name = out.file_name().and_then(|n| n.to_str()).unwrap_or("out");
        Ok(PartFile {
            path: dir.join(format!(".{name}.{}.part", std::process::id())),
            armed: true,
        })
    }

    /// Renames the finished file onto `out`, unless `out` exists and is not
    /// a regular file (a rename would replace a device or a directory).
    pub(super) async fn persist(&mut self, out: &Path) -> Result<()> {
        trevi_core::output::check_target(out)?;
        tokio::fs::rename(&self.path, out)
            .await
            .with_context(|| format!("cannot move the file to {}", out.display()))?;
        self.armed = false;
        Ok(())
    }
}

impl Drop for PartFile {
    fn drop(&mut self) {
        if self.armed {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

/// The last frame of sequence `s` (frames `f`) that may be done. Frames
/// are started in order and a failed frame ends its sequence: the frames
/// done are among the first `frames_done + frames_in_progress` of the
/// range, or, once it failed or was cancelled, `frames_done` plus the
/// frames that were in progress then (at most the coordinator's maximum
/// of frames in progress).
fn done_frames_end(s: &pb::JobStatus, f: &pb::FrameRange) -> u32 {
    if s.state() == JobState::Done {
        return f.last;
    }
    let slack = if matches!(s.state(), JobState::Failed | JobState::Cancelled) {
        trevi_coordinator::limits::MAX_FRAMES_IN_PROGRESS as u32
    } else {
        s.frames_in_progress
    };
    let past = u64::from(f.first) + u64::from(s.frames_done) + u64::from(slack);
    past.saturating_sub(1)
        .clamp(u64::from(f.first), u64::from(f.last)) as u32
}
