//! The output file formats, chosen by a path's extension, and the checks
//! made on an output path before anything renders.

use crate::error::OutputError;
use std::fs;
use std::path::Path;

/// The output file formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// 8-bit sRGB RGB PNG.
    Png,
    /// 32-bit float linear RGB OpenEXR.
    Exr,
}

impl Format {
    /// The format chosen by `path`'s extension (case-insensitive), if any.
    pub fn from_path(path: &Path) -> Option<Format> {
        Format::from_extension(path.extension()?.to_str()?)
    }

    /// The format named by `ext` (`png` or `exr`, any case), if any.
    pub fn from_extension(ext: &str) -> Option<Format> {
        if ext.eq_ignore_ascii_case("png") {
            Some(Format::Png)
        } else if ext.eq_ignore_ascii_case("exr") {
            Some(Format::Exr)
        } else {
            None
        }
    }

    /// The format whose signature `bytes` start with, if any: what a file
    /// really holds, whatever its name says.
    pub fn sniff(bytes: &[u8]) -> Option<Format> {
        const PNG: &[u8] = b"\x89PNG\r\n\x1a\n";
        const EXR: &[u8] = &[0x76, 0x2f, 0x31, 0x01];
        if bytes.starts_with(PNG) {
            Some(Format::Png)
        } else if bytes.starts_with(EXR) {
            Some(Format::Exr)
        } else {
            None
        }
    }

    /// The file name extension, lower case: `png` or `exr`.
    pub fn extension(self) -> &'static str {
        match self {
            Format::Png => "png",
            Format::Exr => "exr",
        }
    }
}

/// Checks, before anything is rendered, that a frame can be written to
/// `path`: its extension names a [`Format`] ([`OutputError::UnsupportedFormat`]
/// if not) and [`check_target`] accepts it. Returns the format.
pub fn check_output(path: &Path) -> Result<Format, OutputError> {
    let format = Format::from_path(path).ok_or_else(|| OutputError::UnsupportedFormat {
        path: path.display().to_string(),
    })?;
    check_target(path)?;
    Ok(format)
}

/// Checks that a finished file may be renamed onto `path`: nothing is
/// there, or a regular file (symbolic links followed) that it replaces.
/// Anything else, a directory, a device such as `/dev/full`, a FIFO or a
/// socket, is [`OutputError::NotARegularFile`]: a rename would replace the
/// node itself. Every writer that renames a finished file into place calls
/// this first.
pub fn check_target(path: &Path) -> Result<(), OutputError> {
    let meta = match fs::metadata(path) {
        Ok(m) => m,
        // Nothing there (or a dangling link, which the rename replaces).
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(source) => {
            return Err(OutputError::Io {
                path: path.display().to_string(),
                source,
            })
        }
    };
    let kind = meta.file_type();
    if kind.is_file() {
        return Ok(());
    }
    let what = if kind.is_dir() {
        "a directory"
    } else {
        special_kind(&kind)
    };
    Err(OutputError::NotARegularFile {
        path: path.display().to_string(),
        what,
    })
}

#[cfg(unix)]
fn special_kind(kind: &fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if kind.is_char_device() {
        "a character device"
    } else if kind.is_block_device() {
        "a block device"
    } else if kind.is_fifo() {
        "a FIFO"
    } else if kind.is_socket() {
        "a socket"
    } else {
        "not a regular file"
    }
}

#[cfg(not(unix))]
fn special_kind(_kind: &fs::FileType) -> &'static str {
    "a special file"
}
