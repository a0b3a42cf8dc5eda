//! Where a scene's files come from: the [`FileSource`] the parser reads
//! through, the directory source with its safety checks and size limits,
//! and the normalisation of a `file="..."` reference into a path relative
//! to the scene's directory.
//!
//! Paths handed to a [`FileSource`] are relative, use `/`, and never climb
//! out of the scene's directory ([`normalize_rel_path`] makes them so).

use crate::error::SceneErrorKind;
use std::io::{self, Read};
use std::path::{Component, Path, PathBuf};

/// Anything that can hand out the bytes of a bundle-relative file.
pub trait FileSource: Sync {
    /// `rel` is a normalised bundle-relative path (see [`normalize_rel_path`]).
    fn read(&self, rel: &str) -> io::Result<Vec<u8>>;
}

/// The default of [`ReadLimits::max_bytes`]: 256 MiB, the coordinator's
/// default limit on an uploaded bundle, so that a bundle this side reads
/// is one the farm accepts.
pub const DEFAULT_MAX_BUNDLE_BYTES: u64 = 256 << 20;

/// Bounds on reading a scene bundle from disk.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReadLimits {
    /// Bytes of the scene file and every file it references, together.
    /// Enforced while reading: a larger file (or `/dev/zero`) is cut off at
    /// the limit plus one byte and refused.
    pub max_bytes: u64,
}

impl Default for ReadLimits {
    fn default() -> Self {
        ReadLimits {
            max_bytes: DEFAULT_MAX_BUNDLE_BYTES,
        }
    }
}

/// The error inside the [`io::Error`] of a read that would pass its size
/// limit, so that the caller can tell it from other read errors (see
/// [`read_error_kind`]).
#[derive(Debug, thiserror::Error)]
#[error("\"{rel}\" takes the scene bundle past its limit of {limit} bytes (the scene and every file it references together)")]
pub struct OverLimit {
    /// The bundle-relative path of the file that passed the limit.
    pub rel: String,
    /// The limit passed, in bytes (for all the files together, or for the
    /// one file).
    pub limit: u64,
}

/// Files read from a directory on disk, and only from inside it.
///
/// Every read resolves the path (symbolic links included) and refuses it
/// unless it ends at a regular file inside the directory: a link to
/// `/etc/passwd` or `~/.ssh` would otherwise be uploaded with the scene and
/// handed to anyone who can download the bundle. A FIFO, a device or a
/// directory is refused from its metadata before it is opened, so that a
/// FIFO cannot hang the reader and `/dev/zero` cannot fill memory; and a
/// read stops one byte past its limit whatever the metadata said (a file
/// may grow while it is read). As a [`FileSource`] each file may have up to
/// [`DEFAULT_MAX_BUNDLE_BYTES`]; [`crate::Bundle::from_scene_file_with`]
/// bounds the bundle as a whole.
pub struct DirSource {
    /// The scene's directory: bundle-relative paths are relative to it, and
    /// no read leaves it.
    pub root: PathBuf,
}

impl DirSource {
    /// Reads `rel` (bundle-relative) if it is a regular file inside the
    /// directory of at most `max` bytes; `limit` is the limit to name in the
    /// error when it is larger (`max` is what is left of it).
    pub(crate) fn read_within(&self, rel: &str, max: u64, limit: u64) -> io::Result<Vec<u8>> {
        let root = std::fs::canonicalize(&self.root)?;
        let real = std::fs::canonicalize(self.root.join(rel))?;
        if !real.starts_with(&root) {
            return Err(refused(format!(
                "\"{rel}\" resolves to {}, outside the scene's directory {} \
                 (a symbolic link may only point inside it)",
                real.display(),
                root.display()
            )));
        }
        // `real` has no links left, so this is the file itself.
        let meta = std::fs::metadata(&real)?;
        if !meta.is_file() {
            return Err(refused(format!(
                "\"{rel}\" is {} (expected a regular file)",
                kind_of(meta.file_type())
            )));
        }
        let file = std::fs::File::open(&real)?;
        // The same check on what was opened (the path may have changed since).
        let opened = file.metadata()?;
        if !opened.is_file() {
            return Err(refused(format!(
                "\"{rel}\" is {} (expected a regular file)",
                kind_of(opened.file_type())
            )));
        }
        let mut data = Vec::with_capacity(opened.len().min(max) as usize);
        file.take(max.saturating_add(1)).read_to_end(&mut data)?;
        if data.len() as u64 > max {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                OverLimit {
                    rel: rel.to_string(),
                    limit,
                },
            ));
        }
        Ok(data)
    }
}

fn refused(msg: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, msg)
}

/// What kind of non-regular file `t` is, for an error message.
fn kind_of(t: std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO";
        }
        if t.is_char_device() || t.is_block_device() {
            return "a device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    if t.is_dir() {
        "a directory"
    } else {
        "not a regular file"
    }
}

impl FileSource for DirSource {
    fn read(&self, rel: &str) -> io::Result<Vec<u8>> {
        self.read_within(rel, DEFAULT_MAX_BUNDLE_BYTES, DEFAULT_MAX_BUNDLE_BYTES)
    }
}

/// Why a file reference is not a usable bundle-relative path.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PathError {
    /// The reference is `""`.
    #[error("empty file reference")]
    Empty,
    /// The reference (given) starts at a root, a `/`, a `\` or a drive
    /// prefix.
    #[error("file \"{0}\" is absolute; references must be relative to the scene's directory")]
    Absolute(String),
    /// The reference (given) has more `..` than the folders above it, up to
    /// the scene's directory.
    #[error("file \"{0}\" climbs out of the scene's directory")]
    ClimbsOut(String),
    /// The reference (given) normalises to nothing, like `.` or `a/..`.
    #[error("file \"{0}\" names no file")]
    NamesNoFile(String),
}

/// Normalises a `file="..."` reference into a bundle-relative path, or says
/// why it is not allowed (absolute, or climbing out of the scene directory).
/// A reference written in the scene file: [`resolve_reference`] from the
/// scene's directory.
pub fn normalize_rel_path(reference: &str) -> Result<String, PathError> {
    resolve_reference("", reference)
}

/// The one rule for a file named inside another file of a scene (the scene
/// file, an OBJ's `mtllib`, a `.mtl`'s `map_Kd`): `reference` is relative
/// to the folder `from` of the file that names it (itself relative to the
/// scene's directory, normalised, `""` for the scene's directory), and the
/// result, normalised, must stay inside the scene's directory. So
/// `models/x.obj` may name `../textures/x.png` (which is
/// `textures/x.png`), and nothing may name `../x.png` from the scene's
/// directory. Absolute references are refused whatever `from` is.
/// `trevi-submit` collects a bundle by parsing its scene, so what it sends
/// follows this rule too.
pub fn resolve_reference(from: &str, reference: &str) -> Result<String, PathError> {
    if reference.is_empty() {
        return Err(PathError::Empty);
    }
    let path = Path::new(reference);
    if path.is_absolute() || reference.starts_with('/') || reference.starts_with('\\') {
        return Err(PathError::Absolute(reference.to_string()));
    }
    if path
        .components()
        .any(|c| matches!(c, Component::RootDir | Component::Prefix(_)))
    {
        return Err(PathError::Absolute(reference.to_string()));
    }
    let joined = if from.is_empty() {
        reference.to_string()
    } else {
        format!("{from}/{reference}")
    };
    normalize_joined(&joined).map_err(|e| match e {
        PathError::ClimbsOut(_) => PathError::ClimbsOut(reference.to_string()),
        PathError::NamesNoFile(_) => PathError::NamesNoFile(reference.to_string()),
        other => other,
    })
}

/// [`resolve_reference`]'s normalisation of the joined path.
fn normalize_joined(reference: &str) -> Result<String, PathError> {
    if reference.is_empty() {
        return Err(PathError::Empty);
    }
    let path = Path::new(reference);
    if path.is_absolute() || reference.starts_with('/') || reference.starts_with('\\') {
        return Err(PathError::Absolute(reference.to_string()));
    }
    let mut parts: Vec<String> = Vec::new();
    for c in path.components() {
        match c {
            Component::Normal(s) => parts.push(s.to_string_lossy().into_owned()),
            Component::CurDir => {}
            Component::ParentDir => {
                if parts.pop().is_none() {
                    return Err(PathError::ClimbsOut(reference.to_string()));
                }
            }
            Component::RootDir | Component::Prefix(_) => {
                return Err(PathError::Absolute(reference.to_string()))
            }
        }
    }
    if parts.is_empty() {
        return Err(PathError::NamesNoFile(reference.to_string()));
    }
    Ok(parts.join("/"))
}

/// The kind of a failed file read: [`SceneErrorKind::MissingFile`] when the
/// file is not there, [`SceneErrorKind::Limit`] when reading it would pass a
/// size limit (see [`ReadLimits`]), else
/// [`SceneErrorKind::Io`].
pub fn read_error_kind(e: &std::io::Error) -> SceneErrorKind {
    if e.kind() == std::io::ErrorKind::NotFound {
        SceneErrorKind::MissingFile
    } else if e.get_ref().is_some_and(|inner| inner.is::<OverLimit>()) {
        SceneErrorKind::Limit
    } else {
        SceneErrorKind::Io
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_outside_the_scene_directory_are_refused() {
        assert_eq!(normalize_rel_path("a/./b/../c.obj").unwrap(), "a/c.obj");
        assert!(matches!(
            normalize_rel_path("../x.obj"),
            Err(PathError::ClimbsOut(_))
        ));
        assert!(matches!(
            normalize_rel_path("a/../../x.obj"),
            Err(PathError::ClimbsOut(_))
        ));
        assert!(matches!(
            normalize_rel_path("/etc/passwd"),
            Err(PathError::Absolute(_))
        ));
        assert_eq!(normalize_rel_path(""), Err(PathError::Empty));
        assert!(matches!(
            normalize_rel_path("a/.."),
            Err(PathError::NamesNoFile(_))
        ));
    }

    /// Regression: `models/x.obj` naming `../textures/x.png` stays inside
    /// the scene's directory and was refused as climbing out.
    #[test]
    fn references_resolve_from_the_folder_of_the_file_that_names_them() {
        assert_eq!(
            resolve_reference("models", "../textures/x.png").unwrap(),
            "textures/x.png"
        );
        assert_eq!(resolve_reference("a/b", "../../x.mtl").unwrap(), "x.mtl");
        assert_eq!(resolve_reference("a", "./t/x.png").unwrap(), "a/t/x.png");
        assert_eq!(
            resolve_reference("models", "../../x.png"),
            Err(PathError::ClimbsOut("../../x.png".into()))
        );
        assert_eq!(
            resolve_reference("models", "/etc/passwd"),
            Err(PathError::Absolute("/etc/passwd".into()))
        );
        assert_eq!(
            resolve_reference("models", ".."),
            Err(PathError::NamesNoFile("..".into()))
        );
        assert_eq!(resolve_reference("models", ""), Err(PathError::Empty));
    }
}
