//! `--denoise` (and a camera's `<render denoise="true">`): a still is
//! rendered, locally or on a farm, to a noisy multi-layer OpenEXR beside its
//! output (`NAME.noisy.exr`: the beauty with the albedo and normal passes the
//! denoiser uses), then denoised band by band into the output
//! ([`trevi_denoise::denoise_file`]: the frame is never whole in memory). A
//! sequence renders its noisy frames by the pattern beside the output's
//! (`shot_##.png` → `shot_##.noisy.exr`), then each frame is denoised the
//! same way, one after the other, once the sequence has rendered.
//!
//! Where it runs: here, on the machine that runs `trevi-submit`, after the
//! frame is stitched and downloaded. The coordinator never spends a core on
//! it (OIDN takes about 8 s per megapixel per thread, docs/denoise.md: a 4K
//! frame is a minute of one core, which a coordinator serving a farm should
//! not pay out of its request threads), the library is needed only where
//! someone asked for denoising, and a frame denoised after a farm render is
//! the one a local render denoises: the same noisy bytes through the same
//! code.
//!
//! Checked before anything renders: the build has the `denoise` feature and
//! the library starts ([`check`]); `--detach` (nothing is left to denoise
//! when the job ends) is refused. The output
//! carries the passes that were asked for; an EXR output also holds the
//! beauty before denoising as its layer `noisy` (the noisy file is then
//! removed), a PNG output keeps the noisy file beside it.

mod preview;

pub use preview::denoise_preview;

use crate::sequence::Sequence;
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;
use trevi_core::scene::animation::Frames;
use trevi_denoise::{denoise_file, Denoised, Denoiser, DEFAULT_BAND_ROWS, DEFAULT_OVERLAP};

/// The noisy frame's file beside `out`: `shot.png` → `shot.noisy.exr` (and
/// a sequence's pattern `shot_##.png` → `shot_##.noisy.exr`).
pub fn noisy_path(out: &Path) -> PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    out.with_file_name(format!("{stem}.noisy.exr"))
}

/// The render passes of a still to denoise: `asked`, and the albedo and
/// normal the denoiser takes as guides.
pub fn with_guides(asked: trevi_core::Aovs) -> trevi_core::Aovs {
    asked
        .with(trevi_core::Aov::Albedo)
        .with(trevi_core::Aov::Normal)
}

/// Refuses `--denoise` before anything renders when this build or this
/// machine cannot denoise, saying how to get a denoiser.
pub fn check(threads: u32) -> Result<()> {
    Denoiser::new(threads)
        .map(drop)
        .context("--denoise (or a camera's denoise=\"true\")")
}

/// Refuses what `--denoise` cannot do: a job left running (`--detach`).
pub fn check_detach(detach: bool) -> Result<()> {
    if detach {
        bail!(
            "--denoise cannot --detach: the frame is denoised by trevi-submit once it has it \
             (fetch it later, then run the denoise_exr example of trevi-denoise on it)"
        );
    }
    Ok(())
}

/// A camera's output to denoise once rendered: a still, or every frame of
/// a sequence (its files by pattern, one at a time: a sequence of many
/// frames costs two paths, not two a frame).
pub struct Output {
    /// The noisy frame the render writes (a sequence: its pattern).
    pub noisy: PathBuf,
    /// The denoised output (a sequence: its pattern).
    pub out: PathBuf,
    /// A sequence's frames; `None` for a still.
    pub frames: Option<Frames>,
    /// The render passes the output carries from the noisy frame (those
    /// asked for; the guides the denoiser alone wanted stay out).
    pub carry: trevi_core::Aovs,
}

impl Output {
    /// Each frame to denoise: (noisy file, denoised file).
    fn files(&self) -> impl Iterator<Item = (PathBuf, PathBuf)> + '_ {
        let frames = match self.frames {
            Some(f) => f.first..=f.last,
            // One item, the still itself.
            None => 0..=0,
        };
        frames.map(move |frame| match self.frames {
            None => (self.noisy.clone(), self.out.clone()),
            Some(frames) => {
                let file = |pattern: &Path| {
                    Sequence {
                        frames,
                        pattern: pattern.to_path_buf(),
                    }
                    .output(frame)
                };
                (file(&self.noisy), file(&self.out))
            }
        })
    }
}

/// Denoises every output's frames, one after the other, on a thread of its
/// own (OIDN's device stays on the thread that made it), with `threads` OIDN
/// threads (0: every core). `current` names the output being written (for
/// [`run_interruptible`]). Says what it did unless `quiet`.
fn run(
    outputs: Vec<Output>,
    threads: u32,
    quiet: bool,
    current: &Mutex<Option<PathBuf>>,
) -> Result<()> {
    let denoiser = Denoiser::new(threads).context("starting the denoiser")?;
    for (noisy, out, carry) in outputs
        .iter()
        .flat_map(|o| o.files().map(move |(n, d)| (n, d, o.carry)))
    {
        let s = Still { noisy, out, carry };
        *current.lock().unwrap_or_else(|e| e.into_inner()) = Some(s.out.clone());
        let started = Instant::now();
        let d = denoise_one(&denoiser, &s)?;
        // An EXR output holds the noisy beauty (its layer `noisy`) and the
        // passes asked for: the noisy file has nothing more to give.
        let layer =
            trevi_core::output::Format::from_path(&s.out) == Some(trevi_core::output::Format::Exr);
        if layer {
            std::fs::remove_file(&s.noisy)
                .with_context(|| format!("removing {}", s.noisy.display()))?;
        }
        if !quiet {
            eprintln!(
                "denoised {} ({}x{}{}) in {:.1} s; {}",
                s.out.display(),
                d.width,
                d.height,
                match (d.albedo, d.normal) {
                    (true, true) => ", with albedo and normals",
                    (true, false) => ", with albedo",
                    _ => "",
                },
                started.elapsed().as_secs_f64(),
                if layer {
                    "the noisy beauty is its layer \"noisy\"".to_string()
                } else {
                    format!("the noisy frame is {}", s.noisy.display())
                }
            );
        }
    }
    Ok(())
}

/// [`run`] on a thread of its own while `signals` are watched: SIGINT or
/// SIGTERM stops waiting for it, removes the temporary file of the output
/// being denoised (the writer's `.NAME.trevi-tmp-PID-N`, see
/// trevi_core::output) and is the error; the noisy frames, and the frames
/// already denoised, stay. The process exits right after, with the thread.
pub async fn run_interruptible(
    outputs: Vec<Output>,
    threads: u32,
    quiet: bool,
    signals: &mut crate::local::Signals,
) -> Result<()> {
    let current = Arc::new(Mutex::new(None::<PathBuf>));
    let (tx, rx) = tokio::sync::oneshot::channel();
    let writing = Arc::clone(&current);
    std::thread::Builder::new()
        .name("denoise".into())
        .spawn(move || {
            let _ = tx.send(run(outputs, threads, quiet, &writing));
        })
        .context("starting the denoise thread")?;
    tokio::select! {
        r = rx => r.context("the denoise thread ended without a word")?,
        sig = signals.next() => {
            if let Some(out) = current.lock().unwrap_or_else(|e| e.into_inner()).as_ref() {
                remove_temporary(out);
            }
            Err(anyhow::Error::new(sig))
        }
    }
}

/// One frame to denoise.
struct Still {
    noisy: PathBuf,
    out: PathBuf,
    carry: trevi_core::Aovs,
}

/// Removes this process's temporary files of the output `out`.
fn remove_temporary(out: &Path) {
    let (Some(dir), Some(name)) = (out.parent(), out.file_name()) else {
        return;
    };
    let dir = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    let prefix = format!(
        ".{}.trevi-tmp-{}-",
        name.to_string_lossy(),
        std::process::id()
    );
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            if e.file_name().to_string_lossy().starts_with(&prefix) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
}

fn denoise_one(denoiser: &Denoiser, s: &Still) -> Result<Denoised> {
    denoise_file(
        denoiser,
        &s.noisy,
        &s.out,
        DEFAULT_BAND_ROWS,
        DEFAULT_OVERLAP,
        s.carry,
    )
    .with_context(|| format!("denoising {} into {}", s.noisy.display(), s.out.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_noisy_frame_sits_beside_the_output() {
        assert_eq!(
            noisy_path(Path::new("out/shot.png")),
            Path::new("out/shot.noisy.exr")
        );
        assert_eq!(noisy_path(Path::new("a.b.exr")), Path::new("a.b.noisy.exr"));
    }

    #[test]
    fn a_still_to_denoise_renders_the_guides_and_what_was_asked() {
        use trevi_core::{Aov, Aovs};
        let g = with_guides(Aovs::NONE);
        assert_eq!(g.iter().collect::<Vec<_>>(), [Aov::Albedo, Aov::Normal]);
        assert_eq!(with_guides(Aovs::NONE.with(Aov::Depth)), Aovs::ALL);
    }

    #[test]
    fn detach_is_refused_by_name() {
        let e = check_detach(true).unwrap_err().to_string();
        assert!(e.contains("--detach"), "{e}");
        assert!(check_detach(false).is_ok());
    }

    #[test]
    fn a_sequence_denoises_each_frame_from_its_noisy_frame() {
        let out = PathBuf::from("f/shot_##.png");
        let o = Output {
            noisy: noisy_path(&out),
            out,
            frames: Some(Frames { first: 9, last: 11 }),
            carry: trevi_core::Aovs::NONE,
        };
        let files: Vec<_> = o.files().collect();
        let want = [9, 10, 11].map(|n| {
            (
                PathBuf::from(format!("f/shot_{n:02}.noisy.exr")),
                PathBuf::from(format!("f/shot_{n:02}.png")),
            )
        });
        assert_eq!(files, want);
        let still = Output { frames: None, ..o };
        assert_eq!(
            still.files().collect::<Vec<_>>(),
            [(still.noisy.clone(), still.out.clone())]
        );
    }

    #[cfg(not(feature = "denoise"))]
    #[test]
    fn a_build_without_the_feature_says_how_to_get_one() {
        let e = format!("{:#}", check(1).unwrap_err());
        assert!(
            e.contains("--denoise") && e.contains("`denoise` cargo feature"),
            "{e}"
        );
    }
}
