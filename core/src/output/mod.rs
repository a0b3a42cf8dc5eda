//! Output images written band by band as tiles complete.
//!
//! PLACEHOLDER API (being implemented): see the module owner's task.

use crate::error::OutputError;
use crate::tile::Rect;
use std::path::Path;

/// Writes one camera's frame to a PNG (8-bit sRGB) or EXR (32-bit float
/// linear) file, chosen by extension. Tiles may arrive in any order; rows are
/// encoded and written as soon as they are complete, so only the rows of
/// incomplete bands are ever held. The file appears under its final name only
/// when [`FrameWriter::finish`] succeeds; dropping an unfinished writer removes
/// the temporary file.
pub struct FrameWriter {
    _private: (),
}

impl FrameWriter {
    pub fn create(_path: &Path, _width: u32, _height: u32) -> Result<Self, OutputError> {
        unimplemented!()
    }

    /// `pixels` holds `rect.w * rect.h` linear RGB values, row by row.
    pub fn write_tile(&mut self, _rect: Rect, _pixels: &[[f32; 3]]) -> Result<(), OutputError> {
        unimplemented!()
    }

    pub fn finish(self) -> Result<(), OutputError> {
        unimplemented!()
    }
}
