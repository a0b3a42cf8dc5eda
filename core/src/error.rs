//! Typed errors of the core library.
//!
//! Scene errors always carry a [`Location`] so that a user sees
//! `scene.xml:12:5: expected three numbers in "position"` and can fix the file.

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

/// An error in a scene bundle: the scene file itself or a file it references.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{location}: {message}")]
pub struct SceneError {
    pub location: Location,
    pub message: String,
}

impl SceneError {
    pub fn new(location: Location, message: impl Into<String>) -> Self {
        SceneError {
            location,
            message: message.into(),
        }
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
    #[error("the frame is incomplete: {missing} rows were never written")]
    Incomplete { missing: u32 },
    /// The output path names something a rename would replace but must not:
    /// a directory, a device (`/dev/full`), a FIFO, a socket.
    #[error("{path} exists and is {what}, not a regular file: refusing to replace it")]
    NotARegularFile { path: String, what: &'static str },
}
