//! What the farm checks before it takes something in: a tile result's
//! pixels, a frame's cost against the per-job window, and the output file
//! name a job writes.

use super::Farm;
use crate::error::{FarmError, LimitKind};
use crate::scheduler::{band_bytes, encoder_bytes, JobSpec};
use std::path::Path;
use trevi_core::{Aovs, Rect};

/// Checks a result's pixels against its rectangle: right count, every
/// component finite and not negative. The renderer only ever produces linear
/// radiance ≥ 0; there is no upper bound short of `f32::MAX`, because a scene
/// may legitimately have lights and colors that large (AISXML allows any
/// finite value ≥ 0), so anything finite and ≥ 0 could be a true result.
pub fn validate_pixels(rect: Rect, pixels: &[[f32; 3]]) -> Result<(), FarmError> {
    if pixels.len() != rect.pixel_count() {
        return Err(FarmError::BadTile(format!(
            "{}x{} tile at ({}, {}) needs {} pixels, got {}",
            rect.w,
            rect.h,
            rect.x,
            rect.y,
            rect.pixel_count(),
            pixels.len()
        )));
    }
    let Some(i) = trevi_core::tile::first_invalid_pixel(pixels) else {
        return Ok(());
    };
    let (x, y) = (rect.x + (i as u32 % rect.w), rect.y + (i as u32 / rect.w));
    let p = pixels[i];
    Err(FarmError::BadTile(if p.iter().all(|c| c.is_finite()) {
        format!("pixel ({x}, {y}) is negative: {p:?} (radiance is never below 0)")
    } else {
        format!("pixel ({x}, {y}) is not finite: {p:?}")
    }))
}

/// Checks a tile's render pass values: exactly `rect`'s pixels × the
/// job's `aovs` channels (none for a job without passes; `None`: a result
/// whose values could not be cut into its tiles, of the wrong size too).
/// Any value is taken (a miss's depth is +∞, and a pass is not radiance).
pub fn validate_aovs(rect: Rect, aovs: Aovs, values: Option<&[f32]>) -> Result<(), FarmError> {
    let want = rect.pixel_count().saturating_mul(aovs.channels());
    match values {
        Some(v) if v.len() == want => Ok(()),
        got => Err(FarmError::BadTile(format!(
            "{}x{} tile at ({}, {}) with render passes \"{aovs}\" needs {want} pass values \
             ({} a pixel), got {}",
            rect.w,
            rect.h,
            rect.x,
            rect.y,
            aovs.channels(),
            match got {
                Some(v) => v.len().to_string(),
                None => "a number that is not a whole number of pixels".to_string(),
            }
        ))),
    }
}

impl Farm {
    /// Refuses a frame whose one band of tiles, with its bookkeeping and the
    /// encoder's rows, does not fit in the per-job window: everything the
    /// coordinator holds for a job grows with the width, the band height
    /// and the tile count in a band, and only the band count is bounded by
    /// the window otherwise. Also refuses more tiles than a job can number.
    pub(super) fn check_memory(&self, spec: &JobSpec) -> Result<(), FarmError> {
        let tile = if spec.tile_size == 0 {
            self.cfg.default_tile
        } else {
            spec.tile_size
        }
        .max(1);
        let tiles =
            (spec.width as u64).div_ceil(tile as u64) * (spec.height as u64).div_ceil(tile as u64);
        if tiles > u32::MAX as u64 {
            return Err(FarmError::limit(
                LimitKind::JobTiles,
                tiles,
                u32::MAX as u64,
                format!(
                    "a {}x{} frame in {tile}-pixel tiles is {tiles} tiles, more than a job may \
                 have ({}); use larger tiles",
                    spec.width,
                    spec.height,
                    u32::MAX
                ),
            ));
        }
        let need = band_bytes(&JobSpec {
            frame: None,
            tile_size: tile,
            ..spec.clone()
        }) + encoder_bytes(spec);
        let window = self.cfg.limits.window_bytes;
        if need > window {
            let mib = |b: u64| b.div_ceil(1 << 20);
            return Err(FarmError::limit(
                LimitKind::Window,
                need,
                window,
                format!(
                    "a {}x{} frame in {tile}-pixel tiles needs {} MiB for one band of tiles, more \
                 than the coordinator's per-job window of {} MiB (--window-mib); use a \
                 narrower frame or smaller tiles, or raise --window-mib",
                    spec.width,
                    spec.height,
                    mib(need),
                    mib(window)
                ),
            ));
        }
        Ok(())
    }
}

/// The output file name `name` (as [`Farm::job_spec`] made it) with the
/// extension of `format` (`png` or `exr`, any case; empty keeps `name`): a
/// submitter's `-o` decides the format, not the scene's `output`.
pub fn output_name_as(name: &str, format: &str) -> Result<String, FarmError> {
    if format.is_empty() {
        return Ok(name.to_string());
    }
    let f = trevi_core::output::Format::from_extension(format).ok_or_else(|| {
        FarmError::refused_scene(format!(
            "output format \"{format}\" is not supported (png or exr)"
        ))
    })?;
    Ok(Path::new(name)
        .with_extension(f.extension())
        .to_string_lossy()
        .into_owned())
}

/// The file name of a camera's `output`, checked to be PNG or EXR.
pub(super) fn output_name(output: &str) -> Result<String, FarmError> {
    let name = Path::new(output)
        .file_name()
        .and_then(|n| n.to_str())
        .ok_or_else(|| FarmError::refused_scene(format!("output \"{output}\" names no file")))?;
    let ext = Path::new(name)
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    match ext.as_deref() {
        Some("png") | Some("exr") => Ok(name.to_string()),
        _ => Err(FarmError::refused_scene(format!(
            "output \"{output}\" must end in .png or .exr"
        ))),
    }
}
