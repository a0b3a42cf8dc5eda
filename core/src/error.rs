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
    pub file: String,
    pub line: u32,
    pub column: u32,
}

impl Location {
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
    pub location: Location,
    pub kind: SceneErrorKind,
    pub message: String,
}

impl SceneError {
    /// An error of kind [`SceneErrorKind::Invalid`].
    pub fn new(location: Location, message: impl Into<String>) -> Self {
        SceneError::of_kind(SceneErrorKind::Invalid, location, message)
    }

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
    #[error("{path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: unsupported output extension (expected .png or .exr)")]
    UnsupportedFormat { path: String },
    #[error("{path}: {message}")]
    Encode { path: String, message: String },
    #[error("tile {x},{y} {w}x{h} does not fit the {width}x{height} frame or was written twice")]
    BadTile {
        x: u32,
        y: u32,
        w: u32,
        h: u32,
        width: u32,
        height: u32,
    },
    #[error("tile {x},{y} {w}x{h} needs {expected} pixels but {got} were given")]
    TilePixelCount {
        x: u32,
        y: u32,
        w: u32,
        h: u32,
        expected: usize,
        got: usize,
    },
    /// An encoded PNG segment the writer cannot take: its framing is
    /// wrong (see `trevi_core::output::check_segment`), or the frame is
    /// not a PNG. Nothing was written.
    #[error("PNG segment {index}: {message}")]
    BadSegment { index: u32, message: String },
    #[error("the frame is incomplete: {missing} rows were never written")]
    Incomplete { missing: u32 },
    /// The output path names something a rename would replace but must not:
    /// a directory, a device (`/dev/full`), a FIFO, a socket.
    #[error("{path} exists and is {what}, not a regular file: refusing to replace it")]
    NotARegularFile { path: String, what: &'static str },
}
