//! What a built scene holds for its geometry and textures, for the worker's
//! "scene built" log line: the meshes' arrays and the textures' MIP chains.
//! A textured scene's memory is these two (plus the BVHs and the per-camera
//! worlds, which do not depend on textures); a scene without textures has
//! `textures == 0`, and its meshes have uvs only if their files give them.

use glam::{Vec2, Vec3};

use crate::scene::SceneDesc;

/// Bytes a parsed scene holds in its meshes and textures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SceneMemory {
    /// Every mesh's positions, normals, texture coordinates and triangles
    /// (once per mesh, however many models instance it).
    pub meshes: u64,
    /// Every texture's texels, at every level of its MIP chain (once per
    /// file, however many surfaces use it).
    pub textures: u64,
}

impl SceneMemory {
    /// The memory of `desc`'s meshes and textures.
    pub fn of(desc: &SceneDesc) -> SceneMemory {
        let bytes = |n: usize, size: usize| (n * size) as u64;
        SceneMemory {
            meshes: desc
                .meshes
                .iter()
                .map(|m| {
                    bytes(m.positions.len(), size_of::<Vec3>())
                        + bytes(m.normals.len(), size_of::<Vec3>())
                        + bytes(m.uvs.len(), size_of::<Vec2>())
                        + bytes(m.triangles.len(), size_of::<[u32; 3]>())
                })
                .sum(),
            textures: desc.textures.iter().map(|t| t.memory_bytes()).sum(),
        }
    }
}
