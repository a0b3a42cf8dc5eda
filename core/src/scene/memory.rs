//! What a built scene holds for its geometry and textures, for the worker's
//! "scene built" log line: the meshes' arrays and the textures' MIP chains.
//! A textured scene's memory is these two (plus the BVHs and the per-camera
//! worlds, which do not depend on textures); a scene without textures has
//! `textures == 0`, and its meshes have uvs only if their files give them.

use glam::{Vec2, Vec3};

use super::SceneDesc;

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::texture::tests::png_rgb8;

    /// A scene's reported memory is its meshes' arrays plus each texture's MIP
    /// chain once (however many surfaces use it), counted here from the sizes
    /// alone; the same scene without the texture reports none.
    #[test]
    fn scene_memory_is_the_meshes_plus_each_texture_s_mip_chain_once() {
        use crate::bundle::Bundle;
        use crate::scene::aisxml::parse_scene;
        use std::collections::BTreeMap;

        let scene = |surface: &str| {
            format!(
                r#"<scene version="1">
      <mesh id="quad"><vertices>0 0 0  1 0 0  1 1 0  0 1 0</vertices>
        <uvs>0 0  1 0  1 1  0 1</uvs><triangles>0 1 2  0 2 3</triangles></mesh>
      <mesh id="tri"><vertices>0 0 1  1 0 1  0 1 1</vertices><triangles>0 1 2</triangles></mesh>
      <model id="a" mesh="quad">{surface}</model>
      <model id="b" mesh="quad">{surface}</model>
      <model id="c" mesh="tri"/>
      <camera id="c" position="0 0 5" lookat="0 0 0" fov="50"><render width="4" height="3"/></camera>
    </scene>"#
            )
        };
        let parse = |text: String| {
            let mut files = BTreeMap::new();
            files.insert("s.xml".to_string(), text.into_bytes());
            files.insert("t.png".to_string(), png_rgb8(6, 4, &[128; 6 * 4 * 3]));
            let bundle = Bundle {
                scene: "s.xml".into(),
                files,
            };
            SceneMemory::of(&parse_scene("s.xml", &bundle).unwrap())
        };
        // quad: 4 positions, 4 normals (made), 4 uvs, 2 triangles; tri: 3, 3, 0, 1.
        let meshes = (4 * 12 + 4 * 12 + 4 * 8 + 2 * 12) + (3 * 12 + 3 * 12 + 12);
        // 6 x 4, then 3 x 2, then 1 x 1 (the odd column folded in): 12 bytes a texel.
        let chain = (6 * 4 + 3 * 2 + 1) * 12;
        let textured = parse(scene(r#"<surface diffuse-texture="t.png"/>"#));
        assert_eq!(
            textured,
            SceneMemory {
                meshes,
                textures: chain
            }
        );
        let plain = parse(scene(r#"<surface diffuse="1 1 1"/>"#));
        assert_eq!(
            plain,
            SceneMemory {
                meshes,
                textures: 0
            }
        );
    }
}
