//! AISXML parsing. PLACEHOLDER (being implemented).
use super::SceneDesc;
use crate::bundle::FileSource;
use crate::error::SceneError;

/// Parses the scene file `scene` (bundle-relative) from `source`, loading the
/// meshes it references, and returns the resolved, validated description.
pub fn parse_scene(_scene: &str, _source: &dyn FileSource) -> Result<SceneDesc, SceneError> {
    unimplemented!()
}
