//! Typed errors of the core library.
//!
//! Scene errors always carry a [`Location`] so that a user sees
//! `scene.xml:12:5: expected three numbers in "position"` and can fix the file,
//! and a [`SceneErrorKind`] so that a program can tell kinds of problem apart
//! without reading the message.

use std::fmt;

/// Where in which file an error was found. `line` and `column` are 1-based;
/// `column` counts characters (not bytes) from the start of the line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    /// The file's bundle-relative path (the scene file's name for the scene).
    pub file: String,
    /// The line, from 1.
    pub line: u32,
    /// The column in characters, from 1.
    pub column: u32,
}

impl Location {
    /// Line `line`, column `column` (both 1-based) of `file`.
    pub fn new(file: impl Into<String>, line: u32, column: u32) -> Self {
        Location {
            file: file.into(),
            line,
            column,
        }
    }

    /// The location of byte offset `pos` in `text`.
    pub fn at_offset(file: &str, text: &[u8], pos: usize) -> Self {
        let pos = pos.min(text.len());
        let before = &text[..pos];
        let line = before.iter().filter(|&&b| b == b'\n').count() as u32 + 1;
        let line_start = before
            .iter()
            .rposition(|&b| b == b'\n')
            .map_or(0, |i| i + 1);
        let column = String::from_utf8_lossy(&before[line_start..])
            .chars()
            .count() as u32
            + 1;
        Location::new(file, line, column)
    }
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}:{}", self.file, self.line, self.column)
    }
}

/// What kind of problem a [`SceneError`] is, for a caller that reacts to
/// the kind (the message says the rest).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SceneErrorKind {
    /// Not well-formed: malformed XML, text that is not UTF-8, a DTD or an
    /// entity.
    Syntax,
    /// An element AISXML does not allow there, or one too many of it.
    UnknownElement,
    /// An attribute the element does not have.
    UnknownAttribute,
    /// A required attribute or child element is missing.
    Missing,
    /// A value of the wrong form or out of its range.
    BadValue,
    /// An id that is used twice or names nothing, or a file reference that
    /// leaves the scene's directory.
    Reference,
    /// A referenced file (or the scene file) is not there.
    MissingFile,
    /// More than a limit allows (objects, mesh elements, bundle bytes).
    Limit,
    /// A file could not be read for another reason.
    Io,
    /// Any other inconsistency in what the file says, such as a mesh file's
    /// content (the mesh loaders report this kind).
    Invalid,
}

/// An error in a scene bundle: the scene file itself or a file it
/// references. Displayed as `file:line:column: message`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{location}: {message}")]
pub struct SceneError {
    /// Where the problem is: the element, attribute or line at fault.
    pub location: Location,
    /// What kind of problem it is.
    pub kind: SceneErrorKind,
    /// What is wrong, for people, without the location.
    pub message: String,
}

impl SceneError {
    /// An error of kind [`SceneErrorKind::Invalid`].
    pub fn new(location: Location, message: impl Into<String>) -> Self {
        SceneError::of_kind(SceneErrorKind::Invalid, location, message)
    }

    /// An error of kind `kind` at `location`.
    pub fn of_kind(kind: SceneErrorKind, location: Location, message: impl Into<String>) -> Self {
        SceneError {
            location,
            kind,
            message: message.into(),
        }
    }

    /// The same error, of kind `kind`.
    pub fn with_kind(mut self, kind: SceneErrorKind) -> Self {
        self.kind = kind;
        self
    }
}

/// Errors while writing an output image.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// Creating, writing, syncing or renaming a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The output path (the final one, also for its temporary file).
        path: String,
        /// The system's error.
        #[source]
        source: std::io::Error,
    },
    /// The output path's extension is not `.png` or `.exr`, or the path has
    /// no file name.
    #[error("{path}: unsupported output extension (expected .png or .exr)")]
    UnsupportedFormat {
        /// The output path.
        path: String,
    },
    /// The encoder refused the frame (a size PNG and EXR cannot store, an
    /// encoder error), or an earlier write failed and the writer is done.
    #[error("{path}: {message}")]
    Encode {
        /// The output path.
        path: String,
        /// What went wrong.
        message: String,
    },
    /// A tile outside the frame, empty, or overlapping pixels already
    /// written. Nothing was written.
    #[error("tile {x},{y} {w}x{h} does not fit the {width}x{height} frame or was written twice")]
    BadTile {
        /// The tile's first column.
        x: u32,
        /// The tile's first row.
        y: u32,
        /// The tile's width in pixels.
        w: u32,
        /// The tile's height in pixels.
        h: u32,
        /// The frame's width in pixels.
        width: u32,
        /// The frame's height in pixels.
        height: u32,
    },
    /// A tile given with more or fewer pixels than its rectangle has.
    /// Nothing was written.
    #[error("tile {x},{y} {w}x{h} needs {expected} pixels but {got} were given")]
    TilePixelCount {
        /// The tile's first column.
        x: u32,
        /// The tile's first row.
        y: u32,
        /// The tile's width in pixels.
        w: u32,
        /// The tile's height in pixels.
        h: u32,
        /// `w * h`.
        expected: usize,
        /// The number of pixels given.
        got: usize,
    },
    /// An encoded PNG segment the writer cannot take: its framing is
    /// wrong (see `trevi_core::output::check_segment`), or the frame is
    /// not a PNG. Nothing was written.
    #[error("PNG segment {index}: {message}")]
    BadSegment {
        /// The segment's index (its band of rows) in the frame.
        index: u32,
        /// What is wrong with it.
        message: String,
    },
    /// The frame was finished with rows missing; the output path was left
    /// as it was.
    #[error("the frame is incomplete: {missing} rows were never written")]
    Incomplete {
        /// How many rows are not complete.
        missing: u32,
    },
    /// The output path names something a rename would replace but must not:
    /// a directory, a device (`/dev/full`), a FIFO, a socket.
    #[error("{path} exists and is {what}, not a regular file: refusing to replace it")]
    NotARegularFile {
        /// The output path.
        path: String,
        /// What is there ("a directory", "a FIFO", …).
        what: &'static str,
    },
    /// A tile's render passes are not the frame's (other passes, or a
    /// value count that is not the tile's pixels × the passes' channels).
    /// Nothing was written.
    #[error("tile {x},{y}: render passes \"{got}\" with {values} values, but the frame writes \"{expected}\" ({channels} values a pixel)")]
    AovMismatch {
        /// The tile's first column.
        x: u32,
        /// The tile's first row.
        y: u32,
        /// The frame's passes.
        expected: crate::aov::Aovs,
        /// Values a pixel of the frame's passes has.
        channels: usize,
        /// The tile's passes.
        got: crate::aov::Aovs,
        /// How many values the tile had.
        values: usize,
    },
    /// A denoised frame's tile without its noisy beauty (or with a pixel
    /// count not the tile's), or a noisy beauty for a frame that keeps
    /// none (see `FrameWriter::create_denoised`). Nothing was written.
    #[error("tile {x},{y}: {what}")]
    NoisyMismatch {
        /// The tile's first column.
        x: u32,
        /// The tile's first row.
        y: u32,
        /// What is wrong.
        what: &'static str,
    },
}
