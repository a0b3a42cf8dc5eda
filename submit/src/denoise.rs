//! `--denoise` (and a camera's `<render denoise="true">`): a still is
//! rendered, locally or on a farm, to a noisy multi-layer OpenEXR beside its
//! output (`NAME.noisy.exr`: the beauty with the albedo and normal passes the
//! denoiser uses), then denoised band by band into the output
//! ([`trevi_denoise::denoise_file`]: the frame is never whole in memory).
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
//! when the job ends) and sequences (not yet) are refused. The output
//! carries the passes that were asked for; an EXR output also holds the
//! beauty before denoising as its layer `noisy` (the noisy file is then
//! removed), a PNG output keeps the noisy file beside it.

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::time::Instant;
use trevi_denoise::{denoise_file, Denoised, Denoiser, DEFAULT_BAND_ROWS, DEFAULT_OVERLAP};

/// The noisy frame's file beside `out`: `shot.png` → `shot.noisy.exr`.
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

/// Refuses what `--denoise` cannot do: a job left running (`--detach`), a
/// sequence.
pub fn check_targets(detach: bool, sequence: Option<&str>) -> Result<()> {
    if detach {
        bail!(
            "--denoise cannot --detach: the frame is denoised by trevi-submit once it has it \
             (fetch it later, then run the denoise_exr example of trevi-denoise on it)"
        );
    }
    if let Some(camera) = sequence {
        bail!(
            "camera \"{camera}\" renders a sequence: --denoise (denoise=\"true\") takes stills \
             for now"
        );
    }
    Ok(())
}

/// A still to denoise once rendered.
pub struct Still {
    /// The noisy frame the render writes.
    pub noisy: PathBuf,
    /// The denoised output.
    pub out: PathBuf,
    /// The render passes the output carries from the noisy frame (those
    /// asked for; the guides the denoiser alone wanted stay out).
    pub carry: trevi_core::Aovs,
}

/// Denoises every still, one after the other, on a thread of its own (OIDN's
/// device stays on the thread that made it), with `threads` OIDN threads
/// (0: every core). Says what it did unless `quiet`.
pub fn run(stills: Vec<Still>, threads: u32, quiet: bool) -> Result<()> {
    for s in stills {
        let started = Instant::now();
        let d = denoise_one(&s, threads)?;
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
/// SIGTERM stops waiting for it, removes the denoised output's temporary
/// file (the writer's `.NAME.trevi-tmp-PID-N`, see trevi_core::output) and
/// is the error; the noisy frames stay. The process exits right after, with
/// the thread.
pub async fn run_interruptible(
    stills: Vec<Still>,
    threads: u32,
    quiet: bool,
    signals: &mut crate::local::Signals,
) -> Result<()> {
    let outs: Vec<PathBuf> = stills.iter().map(|s| s.out.clone()).collect();
    let (tx, rx) = tokio::sync::oneshot::channel();
    std::thread::Builder::new()
        .name("denoise".into())
        .spawn(move || {
            let _ = tx.send(run(stills, threads, quiet));
        })
        .context("starting the denoise thread")?;
    tokio::select! {
        r = rx => r.context("the denoise thread ended without a word")?,
        sig = signals.next() => {
            for out in &outs {
                remove_temporary(out);
            }
            Err(anyhow::Error::new(sig))
        }
    }
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

fn denoise_one(s: &Still, threads: u32) -> Result<Denoised> {
    let denoiser = Denoiser::new(threads).context("starting the denoiser")?;
    denoise_file(
        &denoiser,
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
    fn detach_and_sequences_are_refused_by_name() {
        let e = check_targets(true, None).unwrap_err().to_string();
        assert!(e.contains("--detach"), "{e}");
        let e = check_targets(false, Some("cam")).unwrap_err().to_string();
        assert!(e.contains("\"cam\"") && e.contains("stills"), "{e}");
        assert!(check_targets(false, None).is_ok());
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
