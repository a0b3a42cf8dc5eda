//! Render passes (AOVs, `trevi_core::aov`) on the farm: the set a
//! submission asks for, checked before any work ([`aovs_from`]), the set a
//! job gets ([`apply_aovs`]), and the file a PNG output's pass is written
//! to beside it ([`Farm::aov_file`]). Their values travel with each tile's
//! pixels (`TileUpload.aovs`), are checked there (`checks::validate_aovs`),
//! stored after the pixels in the tile's bytes (`stitch.rs`, read back by
//! `restore.rs`) and written by the job's `FrameWriter`
//! (`FrameWriter::create_with_aovs`: EXR layers, or PNG side files).

use super::Farm;
use crate::error::FarmError;
use crate::scheduler::{JobId, JobSpec};
use std::path::{Path, PathBuf};
use trevi_core::output::Format;
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
/// do not carry them). A sequence's frames carry them as layers of EXR
/// files; a PNG sequence with passes is refused (its frames' pass files
/// are not filed and fetched yet).
pub fn apply_aovs(
    spec: &mut JobSpec,
    asked: Option<Aovs>,
    sequence: bool,
    progressive: bool,
) -> Result<(), FarmError> {
    let aovs = match asked {
        Some(a) => a,
        None if progressive => Aovs::NONE,
        None => spec.aovs,
    };
    if sequence
        && !aovs.is_empty()
        && Format::from_path(Path::new(&spec.output_name)) != Some(Format::Exr)
    {
        return Err(FarmError::Invalid(format!(
            "render passes \"{aovs}\" of a sequence need an EXR output (its frames hold them \
             as layers); {} is not one: use -o NAME.exr or --format exr",
            spec.output_name
        )));
    }
    spec.aovs = aovs;
    Ok(())
}

impl Farm {
    /// The file finished still `job` wrote beside its PNG output for pass
    /// `name` (see `trevi_core::aov::aov_path`). Call off the async
    /// threads.
    pub fn aov_file(&self, job: JobId, name: &str) -> Result<PathBuf, FarmError> {
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
        let output = self.output_file(job)?;
        trevi_core::aov::aov_path(&output, aov).ok_or_else(|| {
            FarmError::NoOutput(
                job,
                format!(
                    "its output {} holds the {name} pass as layers, not in a file of its own",
                    info.spec.output_name
                ),
            )
        })
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
        apply_aovs(&mut s, None, false, false).unwrap();
        assert_eq!(s.aovs, Aovs::ALL);
        apply_aovs(&mut s, Some(Aovs::NONE), false, false).unwrap();
        assert_eq!(s.aovs, Aovs::NONE);
        let mut s = spec.clone();
        apply_aovs(&mut s, None, false, true).unwrap();
        assert_eq!(s.aovs, Aovs::NONE, "progressive: none");
    }

    #[test]
    fn a_sequence_carries_passes_in_exr_frames_and_refuses_them_in_png() {
        let mut spec = crate::scheduler::test_spec(4, 4, 4, "shot.exr");
        spec.aovs = Aovs::NONE.with(Aov::Depth);
        let mut s = spec.clone();
        apply_aovs(&mut s, None, true, false).unwrap();
        assert_eq!(s.aovs, spec.aovs, "the camera's passes");
        apply_aovs(&mut s, Some(Aovs::ALL), true, false).unwrap();
        assert_eq!(s.aovs, Aovs::ALL, "the passes asked for");
        let mut png = crate::scheduler::test_spec(4, 4, 4, "shot.png");
        png.aovs = Aovs::NONE.with(Aov::Depth);
        let e = apply_aovs(&mut png.clone(), None, true, false).unwrap_err();
        assert!(
            e.to_string().contains("EXR") && e.to_string().contains("shot.png"),
            "{e}"
        );
        apply_aovs(&mut png, Some(Aovs::NONE), true, false).unwrap();
        assert_eq!(png.aovs, Aovs::NONE, "none asked: a PNG sequence as before");
    }
}
