//! How much memory a scene takes once built, estimated from its description
//! before [`crate::Scene::build`] runs: what a worker's `--max-memory` is
//! compared with, and what the coordinator uses to lease a job only to
//! workers that can hold it.
//!
//! The estimate is in bytes of heap and is meant as an upper bound of the
//! most the worker holds while it builds the scene and renders with it:
//!
//! ```text
//! estimate = Σ meshes  ( V·(12 + 12 + 8·uv) + T·(12 + 4 + BVH_BYTES_PER_TRIANGLE) )
//!          + max meshes T·(BUILD_BYTES_PER_TRIANGLE            (the one being built)
//!                          + PARALLEL_BUILD_BYTES_PER_TRIANGLE if T ≥ PARALLEL_BUILD_TRIANGLES)
//!          + Σ textures Σ levels w·h·12                        (the MIP chain, linear f32 RGB)
//!          + Σ models   ( MODEL_BYTES + surfaces·SURFACE_BYTES + 2·T if per-triangle surfaces )
//!          + (spheres + planes + lights + cameras)·OBJECT_BYTES
//!          + views · ( (models + spheres)·INSTANCE_BYTES + (planes + lights)·16
//!                      + emitting triangles and spheres·EMITTER_BYTES )
//!          + FIXED_BYTES
//! ```
//!
//! with V vertices and T triangles per mesh (`uv` is 1 when the mesh has
//! texture coordinates), and `views` the distinct camera positions plus one
//! (each camera position gets its own top-level view when one of its cameras
//! renders, and the world-space queries one more). The per-triangle
//! constants are the BVH's cost with a margin: a mesh's tree holds its
//! triangles copied into leaves of up to four (144 bytes a leaf, 36 a
//! triangle when full, plus 4 bytes a leaf for its first triangle) and wide
//! nodes of 256 bytes (eight children, the bottom ones not full: 3.8 to 4.6
//! bytes a triangle more than nodes of four on docs/performance.md's
//! meshes); [`BVH_BYTES_PER_TRIANGLE`] allows 56. While a mesh's trees are built,
//! their input boxes, centroids, indices, bins and binary nodes are held too
//! ([`BUILD_BYTES_PER_TRIANGLE`]), one mesh at a time, and a mesh large
//! enough for the parallel build holds its subtrees' binary nodes twice for
//! a while ([`PARALLEL_BUILD_BYTES_PER_TRIANGLE`]).
//!
//! The test `core/tests/memory_estimate.rs` builds real scenes (the
//! examples, Nefertiti, textured Spot and Bob) under a counting allocator
//! and checks that the estimate is at least the peak held during the build
//! and its first render, and at most [`ESTIMATE_FACTOR`] times that peak
//! plus [`FIXED_BYTES`]. (The built scene then keeps about a third of the
//! peak for a large mesh: the estimate is what the worker must be allowed,
//! not what stays.)
//!
//! Not counted: the bundle's bytes while they are parsed (the coordinator's
//! `--max-bundle-bytes` bounds them), and the render's own buffers (a tile's
//! pixels and per-thread stacks, bounded by the tile size and `max-depth`).

use super::SceneDesc;
use crate::mesh::counts::MeshCounts;
use crate::texture::header::TextureHeader;
use std::collections::HashSet;

/// Bytes per triangle the trees of a mesh hold once built (see the
/// module's documentation).
pub const BVH_BYTES_PER_TRIANGLE: u64 = 56;

/// Bytes per triangle held only while a mesh's trees are built: its
/// triangles' boxes (24; freed before the leaves are filled), centroids
/// (12), indices (4) and bins (1), the binary tree before it is collapsed
/// (a 64-byte node per two triangles reserved, about one per three and a
/// half used with leaves of four), the wide nodes' reservation, the
/// renumbering's maps (8) and the renumbered copies of the triangles and
/// vertices, with a margin. Measured by `core/tests/memory_estimate.rs`.
pub const BUILD_BYTES_PER_TRIANGLE: u64 = 64;

/// Meshes of at least this many triangles are built in parallel
/// (`bvh/build.rs`: subtrees of 8,192 or more on both sides).
pub const PARALLEL_BUILD_TRIANGLES: u64 = 16_384;

/// What a parallel build holds on top of [`BUILD_BYTES_PER_TRIANGLE`]: each
/// subtree built on its own reserves its binary nodes (up to 32 bytes a
/// triangle) before they are appended to the whole tree's, with a margin.
pub const PARALLEL_BUILD_BYTES_PER_TRIANGLE: u64 = 48;

/// A model's record with its transform (the [`super::Model`] and its id).
pub const MODEL_BYTES: u64 = std::mem::size_of::<super::Model>() as u64 + 64;
/// One surface of a model.
pub const SURFACE_BYTES: u64 = std::mem::size_of::<super::Surface>() as u64;
/// A sphere, plane, light or camera with its id and precomputed frame.
pub const OBJECT_BYTES: u64 = 512;
/// One model or sphere in one view: its instance record (two affine
/// transforms and a normal matrix) and its share of the top-level tree
/// (docs/performance.md measures 272 bytes per extra instance, model record
/// included).
pub const INSTANCE_BYTES: u64 = 320;
/// One emitting triangle or sphere in one view, with its running sum.
pub const EMITTER_BYTES: u64 = 96;
/// What any scene costs: the vectors' headers, the cameras' tables.
pub const FIXED_BYTES: u64 = 64 << 10;

/// The estimate is at most this many times the peak a build holds, plus
/// [`FIXED_BYTES`] (checked by `core/tests/memory_estimate.rs` on real
/// scenes; it is never below the peak).
pub const ESTIMATE_FACTOR: f64 = 1.5;

/// The parts of an estimate, in bytes (see the module's documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MemoryEstimate {
    /// Vertices, triangles, the renumbering's index and the trees.
    pub meshes: u64,
    /// What building the largest mesh holds on top, for a while.
    pub build: u64,
    /// Every level of every texture.
    pub textures: u64,
    /// Models, spheres, planes, lights and cameras, and their views.
    pub objects: u64,
}

impl MemoryEstimate {
    /// The whole estimate.
    pub fn total(&self) -> u64 {
        self.meshes
            .saturating_add(self.build)
            .saturating_add(self.textures)
            .saturating_add(self.objects)
    }
}

/// The sizes the estimate needs of a scene's meshes and textures, from the
/// loaded ones ([`AssetSizes::of`]) or from their files' headers (the
/// headers-only parse, [`super::aisxml::parse_scene_headers`]), which then
/// leaves [`SceneDesc::meshes`] and [`SceneDesc::textures`] empty.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct AssetSizes {
    /// Per mesh of [`SceneDesc::meshes`], in order.
    pub meshes: Vec<MeshCounts>,
    /// Per texture of [`SceneDesc::textures`], its level-0 width and height.
    pub textures: Vec<(u32, u32)>,
    /// Per model of [`SceneDesc::models`], the length of its per-triangle
    /// surface table ([`super::Model::triangle_surface`]).
    pub triangle_surfaces: Vec<u64>,
}

impl AssetSizes {
    /// The sizes of a fully parsed scene's meshes and textures.
    pub fn of(desc: &SceneDesc) -> AssetSizes {
        AssetSizes {
            meshes: desc.meshes.iter().map(MeshCounts::of).collect(),
            textures: desc
                .textures
                .iter()
                .map(|t| t.levels.first().map_or((0, 0), |l| (l.width, l.height)))
                .collect(),
            triangle_surfaces: desc
                .models
                .iter()
                .map(|m| m.triangle_surface.len() as u64)
                .collect(),
        }
    }
}

/// Estimates the most memory building `desc` and rendering it holds (see the module's
/// documentation for the formula).
pub fn estimate(desc: &SceneDesc) -> MemoryEstimate {
    estimate_sized(desc, &AssetSizes::of(desc))
}

/// [`estimate`] with the meshes' and textures' sizes given apart from
/// `desc` (whose meshes and textures are then not read). From the sizes a
/// headers-only parse gives, the result is at least the full parse's (equal
/// unless an OBJ or PLY mesh may split vertices: see
/// [`MeshCounts::vertices`]).
pub fn estimate_sized(desc: &SceneDesc, sizes: &AssetSizes) -> MemoryEstimate {
    let mut meshes = 0u64;
    let mut largest = 0u64;
    for m in &sizes.meshes {
        let v = m.vertices;
        let t = m.triangles;
        let uv = if m.uvs { 8 } else { 0 };
        meshes = meshes
            .saturating_add(v.saturating_mul(24 + uv))
            .saturating_add(t.saturating_mul(16 + BVH_BYTES_PER_TRIANGLE));
        let per = if t >= PARALLEL_BUILD_TRIANGLES {
            BUILD_BYTES_PER_TRIANGLE + PARALLEL_BUILD_BYTES_PER_TRIANGLE
        } else {
            BUILD_BYTES_PER_TRIANGLE
        };
        largest = largest.max(t.saturating_mul(per));
    }
    let build = largest;
    let textures = sizes
        .textures
        .iter()
        .map(|&(w, h)| TextureHeader::decoded_bytes(w, h))
        .fold(0u64, u64::saturating_add);

    let mut objects = FIXED_BYTES;
    let mut emitters = 0u64;
    for (i, model) in desc.models.iter().enumerate() {
        let table = sizes.triangle_surfaces.get(i).copied().unwrap_or(0);
        objects = objects
            .saturating_add(MODEL_BYTES)
            .saturating_add(model.surfaces.len() as u64 * SURFACE_BYTES)
            .saturating_add(table.saturating_mul(2));
        let glows = |s: &super::Surface| s.emission != glam::Vec3::ZERO;
        if model.surfaces.iter().any(glows) {
            let t = sizes.meshes.get(model.mesh).map_or(0, |m| m.triangles);
            emitters = emitters.saturating_add(t);
        }
    }
    emitters += desc
        .spheres
        .iter()
        .filter(|s| s.surface.emission != glam::Vec3::ZERO)
        .count() as u64;
    let singles = desc.spheres.len() + desc.planes.len() + desc.lights.len() + desc.cameras.len();
    objects = objects.saturating_add(singles as u64 * OBJECT_BYTES);
    let eyes: HashSet<[u64; 3]> = desc
        .cameras
        .iter()
        .map(|c| c.position.to_array().map(f64::to_bits))
        .collect();
    let views = eyes.len() as u64 + 1;
    let per_view = ((desc.models.len() + desc.spheres.len()) as u64)
        .saturating_mul(INSTANCE_BYTES)
        .saturating_add(((desc.planes.len() + desc.lights.len()) as u64).saturating_mul(16))
        .saturating_add(emitters.saturating_mul(EMITTER_BYTES));
    objects = objects.saturating_add(per_view.saturating_mul(views));

    MemoryEstimate {
        meshes,
        build,
        textures,
        objects,
    }
}

/// `bytes` for people: "3.1 GiB", "512 MiB", "900 KiB", "12 B" (binary
/// units, one decimal below 10).
pub fn human_bytes(bytes: u64) -> String {
    const UNITS: [&str; 5] = ["KiB", "MiB", "GiB", "TiB", "PiB"];
    if bytes < 1024 {
        return format!("{bytes} B");
    }
    let mut v = bytes as f64 / 1024.0;
    let mut unit = 0;
    while v >= 1024.0 && unit + 1 < UNITS.len() {
        v /= 1024.0;
        unit += 1;
    }
    if v < 10.0 {
        format!("{v:.1} {}", UNITS[unit])
    } else {
        format!("{v:.0} {}", UNITS[unit])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::Mesh;
    use crate::scene::{Model, Surface};
    use glam::{DMat4, Vec3};

    fn mesh(v: usize, t: usize) -> Mesh {
        Mesh {
            positions: vec![Vec3::ZERO; v],
            normals: vec![Vec3::Y; v],
            uvs: Vec::new(),
            triangles: vec![[0, 1, 2]; t],
        }
    }

    fn model(mesh: usize) -> Model {
        Model {
            id: "m".into(),
            mesh,
            transform: DMat4::IDENTITY,
            surfaces: vec![Surface::default()],
            triangle_surface: Vec::new(),
        }
    }

    #[test]
    fn the_formula_term_by_term() {
        let desc = SceneDesc {
            meshes: vec![mesh(100, 200), mesh(10, 1000)],
            models: vec![model(0), model(1), model(1)],
            ..SceneDesc::default()
        };
        let e = estimate(&desc);
        assert_eq!(
            e.meshes,
            100 * 24
                + 200 * (16 + BVH_BYTES_PER_TRIANGLE)
                + 10 * 24
                + 1000 * (16 + BVH_BYTES_PER_TRIANGLE)
        );
        // The largest mesh is the one whose build holds the most.
        assert_eq!(e.build, 1000 * BUILD_BYTES_PER_TRIANGLE);
        assert_eq!(e.textures, 0);
        // No camera: one view (the world's).
        assert_eq!(
            e.objects,
            FIXED_BYTES + 3 * (MODEL_BYTES + SURFACE_BYTES) + 3 * INSTANCE_BYTES
        );
        assert_eq!(e.total(), e.meshes + e.build + e.textures + e.objects);
    }

    #[test]
    fn instances_cost_per_instance_not_per_triangle() {
        let one = SceneDesc {
            meshes: vec![mesh(50_000, 100_000)],
            models: vec![model(0)],
            ..SceneDesc::default()
        };
        let mut many = one.clone();
        many.models = vec![model(0); 1000];
        let extra = estimate(&many).total() - estimate(&one).total();
        assert_eq!(extra, 999 * (MODEL_BYTES + SURFACE_BYTES + INSTANCE_BYTES));
        assert!(extra < 100_000 * BVH_BYTES_PER_TRIANGLE);
    }

    #[test]
    fn textures_count_their_whole_mip_chain() {
        let t = crate::texture::Texture::from_texels(64, 32, vec![Vec3::ONE; 64 * 32]);
        let desc = SceneDesc {
            textures: vec![t],
            ..SceneDesc::default()
        };
        // 64x32, 32x16, ..., 2x1, 1x1: the sum of a geometric series.
        let texels: u64 = (0..7)
            .map(|k| (64u64 >> k).max(1) * (32u64 >> k).max(1))
            .sum();
        assert_eq!(estimate(&desc).textures, texels * 12);
    }

    #[test]
    fn sizes_read_as_people_write_them() {
        assert_eq!(human_bytes(12), "12 B");
        assert_eq!(human_bytes(2 << 30), "2.0 GiB");
        assert_eq!(human_bytes(3_328_599_654), "3.1 GiB");
        assert_eq!(human_bytes(512 << 20), "512 MiB");
        assert_eq!(human_bytes(1536), "1.5 KiB");
    }
}
