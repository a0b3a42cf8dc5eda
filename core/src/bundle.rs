//! Scene bundles: a scene file plus the files it references.
//!
//! The bundle is what the farm ships to workers. It is addressed by the SHA-256
//! of its canonical encoding, so a worker can cache it and a coordinator can
//! check that what arrived is what was meant. Paths inside a bundle are
//! relative, use `/`, and never climb out of the scene's directory (see
//! [`crate::scene::source`], which reads the files).
//!
//! Made from a scene file, a bundle comes with the description its parse
//! produced ([`ParsedBundle`]), so that nothing reads the scene twice.

use crate::error::{Location, SceneError};
use crate::scene::aisxml::parse_scene;
use crate::scene::source::read_error_kind;
use crate::scene::SceneDesc;
use crate::world::Scene;
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::io::{self, Read};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

pub use crate::scene::source::{
    normalize_rel_path, DirSource, FileSource, PathError, ReadLimits, DEFAULT_MAX_BUNDLE_BYTES,
};

/// Why bytes are not a scene bundle's canonical encoding.
#[derive(Debug, thiserror::Error)]
pub enum BundleError {
    /// The first 8 bytes are not `TREVIBN1`.
    #[error("not a Trevi scene bundle (bad magic)")]
    BadMagic,
    /// The bytes end inside a length, a path or a file.
    #[error("truncated scene bundle")]
    Truncated,
    /// The reader failed ([`check_encoding`] only).
    #[error("reading the bundle: {0}")]
    Read(#[source] io::Error),
    /// The scene name or a path is not UTF-8.
    #[error("bundle path is not UTF-8")]
    NotUtf8,
    /// A path's length prefix (given, in bytes) is over [`MAX_PATH_BYTES`]
    /// ([`check_encoding`] only).
    #[error("a bundle path of {0} bytes is longer than {MAX_PATH_BYTES}")]
    PathTooLong(u64),
    /// A path is absolute, climbs out with `..` or is otherwise refused by
    /// [`normalize_rel_path`].
    #[error(transparent)]
    BadPath(#[from] PathError),
    /// A path is valid but not in its normal form (`a/./b`, `a//b`, …): the
    /// encoding would not be canonical.
    #[error("bundle path \"{0}\" is not normalised")]
    NotNormalised(String),
    /// The same path appears twice.
    #[error("bundle holds \"{0}\" twice")]
    Duplicate(String),
    /// A path does not sort strictly after the one before it
    /// ([`check_encoding`] only).
    #[error("bundle path \"{path}\" is out of order (after \"{prev}\"): not a canonical encoding")]
    OutOfOrder {
        /// The path out of order.
        path: String,
        /// The path just before it.
        prev: String,
    },
    /// Bytes follow the last file.
    #[error("trailing bytes after the bundle")]
    Trailing,
    /// The scene file the header names (given) is not among the files.
    #[error("bundle lacks its scene file \"{0}\"")]
    MissingScene(String),
}

/// The files read so far and their total size.
#[derive(Default)]
struct Recorded {
    files: BTreeMap<String, Vec<u8>>,
    bytes: u64,
}

/// A [`FileSource`] over a directory that keeps what it reads (each file
/// once), so that a bundle holds exactly the bytes that were parsed, and
/// stops at `limits` for all files together.
struct Recorder<'a> {
    dir: &'a DirSource,
    limits: ReadLimits,
    read: Mutex<Recorded>,
}

impl FileSource for Recorder<'_> {
    fn read(&self, rel: &str) -> io::Result<Vec<u8>> {
        let mut r = self.read.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(data) = r.files.get(rel) {
            return Ok(data.clone());
        }
        let max = self.limits.max_bytes.saturating_sub(r.bytes);
        let data = self.dir.read_within(rel, max, self.limits.max_bytes)?;
        r.bytes += data.len() as u64;
        r.files.insert(rel.to_string(), data.clone());
        Ok(data)
    }
}

/// A scene bundle held in memory: the scene file's name and every file, keyed
/// by bundle-relative path.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Bundle {
    /// The scene file's path inside the bundle (a key of `files`).
    pub scene: String,
    /// Every file's bytes by bundle-relative path (normalised, `/`-separated),
    /// the scene file included.
    pub files: BTreeMap<String, Vec<u8>>,
}

impl FileSource for Bundle {
    fn read(&self, rel: &str) -> io::Result<Vec<u8>> {
        self.files.get(rel).cloned().ok_or_else(|| {
            io::Error::new(
                io::ErrorKind::NotFound,
                format!("{rel} is not part of the scene bundle"),
            )
        })
    }
}

/// A bundle and the description of its scene, parsed once: what
/// [`ParsedBundle::from_scene_file`] reads, or what
/// [`ParsedBundle::parse`] makes of a decoded bundle. Build the renderable
/// scene from `desc` with [`crate::Scene::build`] (no second parse).
#[derive(Debug, Clone)]
pub struct ParsedBundle {
    /// The files, exactly as the parse read them.
    pub bundle: Bundle,
    /// The scene those files describe.
    pub desc: SceneDesc,
}

impl ParsedBundle {
    /// Reads the scene file at `path` and exactly the files it references,
    /// within the default [`ReadLimits`] (see
    /// [`ParsedBundle::from_scene_file_with`]).
    pub fn from_scene_file(path: &Path) -> Result<ParsedBundle, SceneError> {
        ParsedBundle::from_scene_file_with(path, ReadLimits::default())
    }

    /// Reads the scene file at `path` and exactly the files it references:
    /// the scene is parsed (which refuses references outside its directory
    /// and reports any error with its location), and the bundle holds the
    /// bytes that parse read. Files are read through a [`DirSource`]: a
    /// link leaving the scene's directory, anything but a regular file, or
    /// more than `limits.max_bytes` in all is an error located at the
    /// element that references the file.
    pub fn from_scene_file_with(
        path: &Path,
        limits: ReadLimits,
    ) -> Result<ParsedBundle, SceneError> {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let root = path
            .parent()
            .map(Path::to_path_buf)
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or_else(|| PathBuf::from("."));
        let dir = DirSource { root };
        let recorder = Recorder {
            dir: &dir,
            limits,
            read: Mutex::new(Recorded::default()),
        };
        let desc = parse_scene(&name, &recorder)?;
        let wanted: Vec<&String> = std::iter::once(&name).chain(desc.files.iter()).collect();
        for &rel in &wanted {
            // The parser has read every file it lists; this is a fallback.
            let missing = !recorder
                .read
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .files
                .contains_key(rel);
            if missing {
                recorder.read(rel).map_err(|e| {
                    SceneError::of_kind(
                        read_error_kind(&e),
                        Location::new(rel.clone(), 1, 1),
                        format!("cannot read: {e}"),
                    )
                })?;
            }
        }
        let mut read = recorder
            .read
            .into_inner()
            .unwrap_or_else(|e| e.into_inner())
            .files;
        let files = wanted
            .into_iter()
            .map(|rel| (rel.clone(), read.remove(rel).unwrap_or_default()))
            .collect();
        Ok(ParsedBundle {
            bundle: Bundle { scene: name, files },
            desc,
        })
    }

    /// Parses the scene of a bundle held in memory (a decoded one, say),
    /// once.
    pub fn parse(bundle: Bundle) -> Result<ParsedBundle, SceneError> {
        let desc = parse_scene(&bundle.scene, &bundle)?;
        Ok(ParsedBundle { bundle, desc })
    }
}

const MAGIC: &[u8; 8] = b"TREVIBN1";

impl Bundle {
    /// The bundle of [`ParsedBundle::from_scene_file`], without its
    /// description.
    pub fn from_scene_file(path: &Path) -> Result<Bundle, SceneError> {
        ParsedBundle::from_scene_file(path).map(|p| p.bundle)
    }

    /// The bundle of [`ParsedBundle::from_scene_file_with`], without its
    /// description.
    pub fn from_scene_file_with(path: &Path, limits: ReadLimits) -> Result<Bundle, SceneError> {
        ParsedBundle::from_scene_file_with(path, limits).map(|p| p.bundle)
    }

    /// Canonical encoding: magic, then for the scene and each file in path
    /// order `len(path) path len(data) data` with little-endian u64 lengths.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::new();
        out.extend_from_slice(MAGIC);
        put(&mut out, self.scene.as_bytes());
        out.extend_from_slice(&(self.files.len() as u64).to_le_bytes());
        for (path, data) in &self.files {
            put(&mut out, path.as_bytes());
            put(&mut out, data);
        }
        out
    }

    /// Decodes [`Bundle::encode`]'s output, checking every path and length.
    pub fn decode(bytes: &[u8]) -> Result<Bundle, BundleError> {
        let mut r = Reader { bytes, pos: 0 };
        if r.take(8)? != MAGIC {
            return Err(BundleError::BadMagic);
        }
        let scene = r.string()?;
        let count = r.u64()?;
        let mut files = BTreeMap::new();
        for _ in 0..count {
            let path = r.string()?;
            check_normalised(&path)?;
            let len = r.u64()? as usize;
            let data = r.take(len)?.to_vec();
            if files.insert(path.clone(), data).is_some() {
                return Err(BundleError::Duplicate(path));
            }
        }
        if r.pos != bytes.len() {
            return Err(BundleError::Trailing);
        }
        if !files.contains_key(&scene) {
            return Err(BundleError::MissingScene(scene));
        }
        Ok(Bundle { scene, files })
    }

    /// Hex SHA-256 of the canonical encoding: the bundle's address.
    pub fn hash(&self) -> String {
        sha256_hex(&self.encode())
    }
}

/// Fails unless `path` is a normalised bundle-relative path.
fn check_normalised(path: &str) -> Result<(), BundleError> {
    if normalize_rel_path(path)? != path {
        return Err(BundleError::NotNormalised(path.to_string()));
    }
    Ok(())
}

/// Longest path (or scene name) [`check_encoding`] accepts, in bytes.
pub const MAX_PATH_BYTES: u64 = 4096;

/// Checks an encoding read from `r` by [`Bundle::decode`]'s rules, without
/// holding the files' contents: memory stays at one path and the reader's
/// buffer, whatever the bundle's size. Stricter than `decode` in two ways:
/// paths must come in [`Bundle::encode`]'s order (strictly ascending, so no
/// path twice) and be at most [`MAX_PATH_BYTES`] long. Returns the number of
/// files.
pub fn check_encoding(r: impl io::Read) -> Result<u64, BundleError> {
    let mut r = io::BufReader::with_capacity(1 << 16, r);
    let mut magic = [0u8; 8];
    read_exact(&mut r, &mut magic)?;
    if &magic != MAGIC {
        return Err(BundleError::BadMagic);
    }
    let scene = read_path(&mut r)?;
    let count = read_u64(&mut r)?;
    let mut seen_scene = false;
    let mut last: Option<String> = None;
    for _ in 0..count {
        let path = read_path(&mut r)?;
        check_normalised(&path)?;
        if let Some(prev) = last.take() {
            if prev >= path {
                return Err(BundleError::OutOfOrder { path, prev });
            }
        }
        seen_scene |= path == scene;
        let len = read_u64(&mut r)?;
        let skipped =
            io::copy(&mut (&mut r).take(len), &mut io::sink()).map_err(BundleError::Read)?;
        if skipped != len {
            return Err(BundleError::Truncated);
        }
        last = Some(path);
    }
    let mut one = [0u8; 1];
    if r.read(&mut one).map_err(BundleError::Read)? != 0 {
        return Err(BundleError::Trailing);
    }
    if !seen_scene {
        return Err(BundleError::MissingScene(scene));
    }
    Ok(count)
}

fn read_exact(r: &mut impl io::Read, buf: &mut [u8]) -> Result<(), BundleError> {
    r.read_exact(buf).map_err(|e| match e.kind() {
        io::ErrorKind::UnexpectedEof => BundleError::Truncated,
        _ => BundleError::Read(e),
    })
}

fn read_u64(r: &mut impl io::Read) -> Result<u64, BundleError> {
    let mut b = [0u8; 8];
    read_exact(r, &mut b)?;
    Ok(u64::from_le_bytes(b))
}

fn read_path(r: &mut impl io::Read) -> Result<String, BundleError> {
    let n = read_u64(r)?;
    if n > MAX_PATH_BYTES {
        return Err(BundleError::PathTooLong(n));
    }
    let mut b = vec![0u8; n as usize];
    read_exact(r, &mut b)?;
    String::from_utf8(b).map_err(|_| BundleError::NotUtf8)
}

/// Hex SHA-256 of some bytes.
pub fn sha256_hex(bytes: &[u8]) -> String {
    hex::encode(Sha256::digest(bytes))
}

fn put(out: &mut Vec<u8>, data: &[u8]) {
    out.extend_from_slice(&(data.len() as u64).to_le_bytes());
    out.extend_from_slice(data);
}

struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], BundleError> {
        let end = self
            .pos
            .checked_add(n)
            .filter(|&e| e <= self.bytes.len())
            .ok_or(BundleError::Truncated)?;
        let s = &self.bytes[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    fn u64(&mut self) -> Result<u64, BundleError> {
        let b = self.take(8)?;
        Ok(u64::from_le_bytes(
            b.try_into().map_err(|_| BundleError::Truncated)?,
        ))
    }
    fn string(&mut self) -> Result<String, BundleError> {
        let n = self.u64()? as usize;
        String::from_utf8(self.take(n)?.to_vec()).map_err(|_| BundleError::NotUtf8)
    }
}

/// Parsing and building in one call, for tests, tools and the fuzzers. The
/// farm parses once and keeps the description ([`ParsedBundle`], then
/// [`Scene::build`]); the build step itself never sees a file.
impl Scene {
    /// Parses and builds the scene in `bundle`.
    pub fn from_bundle(bundle: &Bundle) -> Result<Scene, SceneError> {
        Scene::from_source(&bundle.scene, bundle)
    }

    /// Parses and builds scene file `scene` read through `source`.
    pub fn from_source(scene: &str, source: &dyn FileSource) -> Result<Scene, SceneError> {
        Ok(Scene::build(parse_scene(scene, source)?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const OBJ: &[u8] = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";

    /// A scene directory whose scene.xml references `mesh` (line 2, where
    /// the `file` attribute starts at column 16).
    fn scene_dir(mesh: &str) -> tempfile::TempDir {
        let dir = tempfile::tempdir().unwrap();
        let xml = format!(
            "<scene version=\"1\">\n  <mesh id=\"m\" file=\"{mesh}\"/>\n  \
             <camera id=\"c\" position=\"0 0 5\" lookat=\"0 0 0\" fov=\"40\">\
             <render width=\"4\" height=\"4\"/></camera>\n</scene>\n"
        );
        std::fs::write(dir.path().join("scene.xml"), xml).unwrap();
        dir
    }

    /// Reads the bundle, expecting an error at the mesh's `file` attribute.
    fn refused_at_the_mesh(dir: &Path, limits: ReadLimits, what: &str) -> String {
        match Bundle::from_scene_file_with(&dir.join("scene.xml"), limits) {
            Ok(b) => panic!("read {:?}", b.files.keys().collect::<Vec<_>>()),
            Err(e) => {
                let msg = e.to_string();
                assert_eq!(
                    (e.location.file.as_str(), e.location.line, e.location.column),
                    ("scene.xml", 2, 16),
                    "{msg}"
                );
                assert!(msg.contains("attribute \"file\" of <mesh>"), "{msg}");
                assert!(msg.contains(what), "{msg}");
                msg
            }
        }
    }

    #[cfg(unix)]
    #[test]
    fn symlinks_leaving_the_scene_directory_are_refused_at_the_referencing_element() {
        let outside = tempfile::tempdir().unwrap();
        let secret = outside.path().join("secret.obj");
        std::fs::write(&secret, OBJ).unwrap();
        let dir = scene_dir("m.obj");
        std::os::unix::fs::symlink(&secret, dir.path().join("m.obj")).unwrap();
        refused_at_the_mesh(
            dir.path(),
            ReadLimits::default(),
            "outside the scene's directory",
        );
        // A link to /dev/zero is outside too (and was read until memory ran out).
        let dir = scene_dir("z.obj");
        std::os::unix::fs::symlink("/dev/zero", dir.path().join("z.obj")).unwrap();
        refused_at_the_mesh(
            dir.path(),
            ReadLimits::default(),
            "outside the scene's directory",
        );
        // A link that stays inside is followed, and the bundle holds the bytes.
        let dir = scene_dir("m.obj");
        std::fs::create_dir(dir.path().join("meshes")).unwrap();
        std::fs::write(dir.path().join("meshes/real.obj"), OBJ).unwrap();
        std::os::unix::fs::symlink("meshes/real.obj", dir.path().join("m.obj")).unwrap();
        let b = Bundle::from_scene_file(&dir.path().join("scene.xml")).unwrap();
        assert_eq!(b.files["m.obj"], OBJ);
        assert_eq!(b.files.len(), 2);
    }

    #[cfg(unix)]
    #[test]
    fn a_fifo_or_a_directory_is_refused_without_hanging() {
        let dir = scene_dir("f.obj");
        let fifo = dir.path().join("f.obj");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        if made.is_ok_and(|s| s.success()) {
            let (tx, rx) = std::sync::mpsc::channel();
            let path = dir.path().to_path_buf();
            std::thread::spawn(move || {
                let r = Bundle::from_scene_file(&path.join("scene.xml"));
                let _ = tx.send(r.map(|_| ()).map_err(|e| e.to_string()));
            });
            // Before the fix the read blocked forever waiting for a writer.
            match rx.recv_timeout(std::time::Duration::from_secs(10)) {
                Ok(Err(msg)) => {
                    assert!(msg.contains("is a FIFO (expected a regular file)"), "{msg}")
                }
                other => panic!("expected a refusal, got {other:?}"),
            }
        } else {
            eprintln!("mkfifo unavailable: FIFO case skipped");
        }
        let dir = scene_dir("d.obj");
        std::fs::create_dir(dir.path().join("d.obj")).unwrap();
        refused_at_the_mesh(dir.path(), ReadLimits::default(), "is a directory");
    }

    #[test]
    fn the_size_limit_is_enforced_while_reading() {
        let dir = scene_dir("m.obj");
        std::fs::write(dir.path().join("m.obj"), OBJ).unwrap();
        let scene_len = std::fs::metadata(dir.path().join("scene.xml"))
            .unwrap()
            .len();
        let total = scene_len + OBJ.len() as u64;
        // Exactly the scene and the mesh fit; one byte less does not.
        let b = Bundle::from_scene_file_with(
            &dir.path().join("scene.xml"),
            ReadLimits { max_bytes: total },
        )
        .unwrap();
        assert_eq!(b.files["m.obj"], OBJ);
        refused_at_the_mesh(
            dir.path(),
            ReadLimits {
                max_bytes: total - 1,
            },
            &format!("past its limit of {} bytes", total - 1),
        );
        // The scene file alone over the limit: an error at the scene file.
        let e = Bundle::from_scene_file_with(
            &dir.path().join("scene.xml"),
            ReadLimits { max_bytes: 10 },
        )
        .unwrap_err();
        assert_eq!((e.location.line, e.location.column), (1, 1));
        assert!(e.message.contains("past its limit of 10 bytes"), "{e}");
        assert_eq!(e.kind, crate::SceneErrorKind::Limit);
    }

    #[test]
    fn encoding_round_trips_and_hash_tracks_content() {
        let mut files = BTreeMap::new();
        files.insert("s.xml".to_string(), b"<scene/>".to_vec());
        files.insert("m/a.obj".to_string(), b"v 0 0 0".to_vec());
        let b = Bundle {
            scene: "s.xml".into(),
            files,
        };
        let enc = b.encode();
        assert_eq!(Bundle::decode(&enc).unwrap(), b);
        let mut c = b.clone();
        c.files.insert("m/a.obj".into(), b"v 0 0 1".to_vec());
        assert_ne!(b.hash(), c.hash());
        assert!(Bundle::decode(&enc[..enc.len() - 1]).is_err());
    }

    #[test]
    fn check_encoding_agrees_with_decode_without_holding_the_files() {
        let mut files = BTreeMap::new();
        files.insert("s.xml".to_string(), b"<scene/>".to_vec());
        files.insert("m/a.obj".to_string(), vec![7u8; 100_000]);
        let b = Bundle {
            scene: "s.xml".into(),
            files,
        };
        let enc = b.encode();
        assert_eq!(check_encoding(&enc[..]).unwrap(), 2);
        // Every truncation and a trailing byte: both refuse.
        for cut in [1, 9, 20, 50, enc.len() / 2, enc.len() - 1] {
            assert!(Bundle::decode(&enc[..cut]).is_err());
            let e = check_encoding(&enc[..cut]).unwrap_err();
            assert!(matches!(e, BundleError::Truncated), "cut at {cut}: {e}");
            assert_eq!(e.to_string(), "truncated scene bundle");
        }
        let mut long = enc.clone();
        long.push(0);
        assert!(Bundle::decode(&long).is_err());
        assert!(check_encoding(&long[..])
            .unwrap_err()
            .to_string()
            .contains("trailing"));
        // A path outside the bundle, a missing scene, bad magic.
        let mut sneaky = b.clone();
        sneaky.files.insert("../x".into(), vec![]);
        assert!(check_encoding(&sneaky.encode()[..]).is_err());
        let mut lost = b.clone();
        lost.scene = "other.xml".into();
        assert!(check_encoding(&lost.encode()[..])
            .unwrap_err()
            .to_string()
            .contains("lacks its scene"));
        assert!(check_encoding(&b"TREVIBN2"[..])
            .unwrap_err()
            .to_string()
            .contains("magic"));
        // A path length that would allocate gigabytes is refused first.
        let mut huge = MAGIC.to_vec();
        huge.extend_from_slice(&(1u64 << 40).to_le_bytes());
        assert!(check_encoding(&huge[..])
            .unwrap_err()
            .to_string()
            .contains("longer"));
        // Out of order (decode takes it; the canonical check does not).
        let mut swapped = MAGIC.to_vec();
        put(&mut swapped, b"s.xml");
        swapped.extend_from_slice(&2u64.to_le_bytes());
        for (p, d) in [("s.xml", &b"<scene/>"[..]), ("m/a.obj", &b"v"[..])] {
            put(&mut swapped, p.as_bytes());
            put(&mut swapped, d);
        }
        assert!(Bundle::decode(&swapped).is_ok());
        assert!(check_encoding(&swapped[..])
            .unwrap_err()
            .to_string()
            .contains("order"));
    }
}
