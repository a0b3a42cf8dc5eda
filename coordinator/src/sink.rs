//! Where a job's accepted tiles go: [`TileSink`], normally the job's
//! [`FrameWriter`] stitching its output file; tests and benchmarks plug in
//! their own.

use trevi_core::output::PngSegment;
use trevi_core::{AovTile, FrameWriter, OutputError, Rect};

/// Why a [`TileSink`] could not take a tile or complete its output.
#[derive(Debug, thiserror::Error)]
pub enum SinkError {
    /// The output file's writer failed (encoding, or the file system).
    #[error(transparent)]
    Output(#[from] OutputError),
    /// Another sink's I/O failed.
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

/// Takes a job's tiles as they are accepted.
pub trait TileSink: Send {
    /// Takes an accepted tile's pixels: `rect.w × rect.h` linear RGB values,
    /// row by row, checked already.
    fn write_tile(&mut self, rect: Rect, pixels: &[[f32; 3]]) -> Result<(), SinkError>;
    /// [`TileSink::write_tile`] with the tile's render passes (checked
    /// already: the job's passes, their channels a pixel). A sink that
    /// takes no passes refuses a tile that has some.
    fn write_tile_aovs(
        &mut self,
        rect: Rect,
        pixels: &[[f32; 3]],
        aovs: &AovTile,
    ) -> Result<(), SinkError> {
        if !aovs.aovs.is_empty() {
            return Err(SinkError::Io(std::io::Error::new(
                std::io::ErrorKind::Unsupported,
                "this output takes no render passes",
            )));
        }
        self.write_tile(rect, pixels)
    }
    /// Takes segment `index` of a PNG frame, already encoded (see
    /// [`FrameWriter::write_segment`]). A sink that cannot refuses it.
    fn write_segment(&mut self, index: u32, segment: &PngSegment) -> Result<(), SinkError> {
        let _ = segment;
        Err(SinkError::Io(std::io::Error::new(
            std::io::ErrorKind::Unsupported,
            format!("this output takes no encoded PNG segments (segment {index})"),
        )))
    }
    /// Completes the output (for a file: moves it into place).
    fn finish(self: Box<Self>) -> Result<(), SinkError>;
    /// Rows buffered right now.
    fn rows_held(&self) -> usize;
}

impl TileSink for FrameWriter {
    fn write_tile(&mut self, rect: Rect, pixels: &[[f32; 3]]) -> Result<(), SinkError> {
        Ok(FrameWriter::write_tile(self, rect, pixels)?)
    }
    fn write_tile_aovs(
        &mut self,
        rect: Rect,
        pixels: &[[f32; 3]],
        aovs: &AovTile,
    ) -> Result<(), SinkError> {
        Ok(FrameWriter::write_tile_aovs(self, rect, pixels, aovs)?)
    }
    fn write_segment(&mut self, index: u32, segment: &PngSegment) -> Result<(), SinkError> {
        Ok(FrameWriter::write_segment(self, index, segment)?)
    }
    fn finish(self: Box<Self>) -> Result<(), SinkError> {
        Ok(FrameWriter::finish(*self)?)
    }
    fn rows_held(&self) -> usize {
        FrameWriter::rows_held(self)
    }
}
