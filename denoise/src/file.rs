//! A noisy frame on disk to a denoised output file: the step the farm runs
//! after a frame is stitched.

use crate::{denoise_frame, BandPlan, DenoiseError, Denoiser, ExrSource, Source};
use std::path::Path;
use trevi_core::{Aovs, FrameWriter, Rect};

/// What a denoise of a file did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Denoised {
    /// Frame width in pixels.
    pub width: u32,
    /// Frame height in pixels.
    pub height: u32,
    /// The exposure given to every band.
    pub exposure: f32,
    /// Whether albedo and normals were used.
    pub albedo: bool,
    /// Whether normals were used (only with albedo).
    pub normal: bool,
}

/// Denoises the multi-layer EXR at `noisy` (see [`ExrSource`]) into
/// `output`, a PNG or EXR chosen by its extension, band by band as `plan`
/// cuts it (`plan.height` is replaced by the file's). The output carries
/// the render passes `carry` from the noisy file (which must hold them:
/// refused before anything is written otherwise), as channels of an EXR or
/// files beside a PNG, and an EXR output also the beauty before denoising
/// (its layer `noisy`, [`trevi_core::output::NOISY_CHANNELS`]). The output
/// appears under its name only when complete (the writer's part file is
/// renamed).
pub fn denoise_file(
    denoiser: &Denoiser,
    noisy: &Path,
    output: &Path,
    band_rows: u32,
    overlap: u32,
    carry: Aovs,
) -> Result<Denoised, DenoiseError> {
    let mut source = ExrSource::open(noisy)?;
    // A second reader of the same file for what the output carries: the
    // first is the denoiser's while the bands are written.
    let layers = ExrSource::open(noisy)?;
    let (width, height) = (source.width(), source.height());
    let plan = BandPlan::new(height, band_rows, overlap)?;
    layers.check_holds(carry)?;
    let mut writer = FrameWriter::create_denoised(output, width, height, carry)?;
    let exposure = denoise_frame(denoiser, &mut source, plan, &mut |rows, px| {
        let rect = Rect {
            x: 0,
            y: rows.start,
            w: width,
            h: rows.end - rows.start,
        };
        let (noisy, passes) = layers.read_layers(rows, carry)?;
        writer
            .write_tile_denoised(rect, px, &passes, &noisy)
            .map_err(DenoiseError::from)
    })?;
    writer.finish()?;
    Ok(Denoised {
        width,
        height,
        exposure,
        albedo: source.has_albedo(),
        normal: source.has_albedo() && source.has_normal(),
    })
}
