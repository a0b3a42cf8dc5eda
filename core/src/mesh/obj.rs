//! PLACEHOLDER (being implemented).
use super::Mesh;
use crate::error::SceneError;

/// Parses a OBJ file's bytes. `file` is the bundle-relative name used in errors.
pub fn parse(_file: &str, _bytes: &[u8]) -> Result<Mesh, SceneError> {
    unimplemented!()
}
