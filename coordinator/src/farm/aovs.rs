//! Render passes (AOVs, `trevi_core::aov`) on the farm: the set a
//! submission asks for, checked before any work ([`aovs_from`]), the set a
//! job gets ([`apply_aovs`]), and the file a PNG output's pass is written
//! to beside it ([`pass_files`], [`Farm::aov_file`]): a still's, or each
//! frame's of a PNG sequence (filed with its frame, `Farm::file_frame`).
//! Their values travel with each tile's
//! pixels (`TileUpload.aovs`), are checked there (`checks::validate_aovs`),
//! stored after the pixels in the tile's bytes (`stitch.rs`, read back by
//! `restore.rs`) and written by the job's `FrameWriter`
//! (`FrameWriter::create_with_aovs`: EXR layers, or PNG side files).

use super::Farm;
use crate::error::FarmError;
use crate::scheduler::{JobId, JobSpec};
use std::path::{Path, PathBuf};
use trevi_core::{Aov, Aovs};

/// The longest `SubmitJobRequest.aovs` (and `--aovs`) taken, in bytes:
/// the three names with separators fit many times over.
pub const MAX_AOVS_BYTES: usize = 64;

/// The render passes a submission names (`None`: unset, the camera's own),
/// checked before the scene is read: at most [`MAX_AOVS_BYTES`], every
/// name one of `albedo`, `normal`, `depth`, and none for a progressive job
/// (its passes do not carry them yet).
pub fn aovs_from(names: Option<&str>, progressive: bool) -> Result<Option<Aovs>, FarmError> {
    let Some(names) = names else {
        return Ok(None);
    };
    if names.len() > MAX_AOVS_BYTES {
        return Err(FarmError::Invalid(format!(
            "--aovs is {} bytes, more than the {MAX_AOVS_BYTES} allowed (at most the three \
             passes albedo, normal, depth)",
            names.len()
        )));
    }
    let aovs = Aovs::parse(names).map_err(|e| FarmError::Invalid(format!("--aovs: {e}")))?;
    if !aovs.is_empty() && progressive {
        return Err(FarmError::Invalid(format!(
            "--aovs \"{aovs}\": render passes are not rendered for progressive jobs yet; \
             submit without --samples/--pass"
        )));
    }
    Ok(Some(aovs))
}

/// Gives `spec` (whose passes are its camera's, from [`Farm::job_spec`],
/// and whose output name is final) the passes asked for, or its camera's
/// when unset; a progressive job renders none of its camera's (its passes
/// do not carry them). A still or a sequence takes them in either format:
/// an EXR output (every frame of an EXR sequence) holds them as layers, a
/// PNG output (every frame of a PNG sequence) gets its pass files beside
/// it (`pass_files` names them).
pub fn apply_aovs(spec: &mut JobSpec, asked: Option<Aovs>, progressive: bool) {
    spec.aovs = match asked {
        Some(a) => a,
        None if progressive => Aovs::NONE,
        None => spec.aovs,
    };
}

/// The files beside frame file `output` holding its passes `aovs`, in
/// layout order (see `trevi_core::aov::aov_path`): none for an EXR output,
/// which holds them as layers.
pub(super) fn pass_files(output: &Path, aovs: Aovs) -> Vec<PathBuf> {
    aovs.iter()
        .filter_map(|a| trevi_core::aov::aov_path(output, a))
        .collect()
}

impl Farm {
    /// The file finished job `job` wrote beside its PNG output for pass
    /// `name` (see `trevi_core::aov::aov_path`): a still's (`frame`
    /// `None`; a frame is refused, naming it), or that of frame `frame` of
    /// a sequence (`None`: its highest frame done, as `DownloadOutput`).
    /// The name and the frame are checked before any file is looked at:
    /// a frame outside the sequence's range is refused naming the range.
    /// Call off the async threads.
    pub fn aov_file(
        &self,
        job: JobId,
        name: &str,
        frame: Option<u32>,
    ) -> Result<PathBuf, FarmError> {
        let aov = Aov::from_name(name).ok_or_else(|| {
            FarmError::Invalid(format!(
                "unknown render pass \"{}\" (expected albedo, normal or depth)",
                name.chars().take(64).collect::<String>()
            ))
        })?;
        let info = self.info(job)?;
        if !info.spec.aovs.contains(aov) {
            return Err(FarmError::NoOutput(
                job,
                format!("it renders no {name} pass"),
            ));
        }
        // `frame_file` checks the frame against the range (and refuses one
        // for a still) before it stats a file.
        let output = match frame {
            Some(f) => self.frame_file(job, Some(f))?,
            None => self.output_file(job)?,
        };
        let path = trevi_core::aov::aov_path(&output, aov).ok_or_else(|| {
            FarmError::NoOutput(
                job,
                format!(
                    "its output {} holds the {name} pass as layers, not in a file of its own",
                    info.spec.output_name
                ),
            )
        })?;
        if !path.is_file() {
            let which = frame.map_or(String::new(), |f| format!(" of frame {f}"));
            return Err(FarmError::NoOutput(
                job,
                format!("the {name} pass file{which} is missing"),
            ));
        }
        Ok(path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_checked_before_the_work() {
        assert_eq!(aovs_from(None, false).unwrap(), None);
        assert_eq!(aovs_from(Some(""), true).unwrap(), Some(Aovs::NONE));
        assert_eq!(
            aovs_from(Some("depth,albedo normal"), false).unwrap(),
            Some(Aovs::ALL)
        );
        let e = aovs_from(Some("albedo,specular"), false).unwrap_err();
        assert!(e.to_string().contains("\"specular\""), "{e}");
        let long = "albedo,".repeat(10);
        let e = aovs_from(Some(&long), false).unwrap_err();
        assert!(e.to_string().contains("64"), "{e}");
        let e = aovs_from(Some("depth"), true).unwrap_err();
        assert!(e.to_string().contains("progressive"), "{e}");
    }

    #[test]
    fn a_still_keeps_its_cameras_passes_unless_asked_otherwise() {
        let mut spec = crate::scheduler::test_spec(4, 4, 4, "o.exr");
        spec.aovs = Aovs::ALL;
        let mut s = spec.clone();
        apply_aovs(&mut s, None, false);
        assert_eq!(s.aovs, Aovs::ALL);
        apply_aovs(&mut s, Some(Aovs::NONE), false);
        assert_eq!(s.aovs, Aovs::NONE);
        let mut s = spec.clone();
        apply_aovs(&mut s, None, true);
        assert_eq!(s.aovs, Aovs::NONE, "progressive: none");
    }

    #[test]
    fn a_png_frame_s_passes_sit_beside_it_and_an_exr_s_in_it() {
        let depth = Aovs::NONE.with(Aov::Depth);
        assert_eq!(
            pass_files(Path::new("jobs/7/shot_01.png"), Aovs::ALL),
            [
                "jobs/7/shot_01.albedo.png",
                "jobs/7/shot_01.normal.png",
                "jobs/7/shot_01.depth.exr"
            ]
            .map(PathBuf::from)
        );
        assert_eq!(
            pass_files(Path::new("jobs/7/shot_01.png"), depth),
            [PathBuf::from("jobs/7/shot_01.depth.exr")]
        );
        assert!(pass_files(Path::new("jobs/7/shot_01.exr"), Aovs::ALL).is_empty());
        assert!(pass_files(Path::new("jobs/7/shot_01.png"), Aovs::NONE).is_empty());
    }
}
