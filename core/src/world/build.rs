//! The build step: a parsed [`SceneDesc`] becomes a [`Scene`] (one BVH per
//! mesh, the meshes renumbered in leaf order), and everything that follows
//! where the models and cameras are is computed (the distinct camera
//! positions, the bounds, the cameras' sample hashes). It takes a
//! description, never a file: parsing is `scene::aisxml`'s, and
//! `Scene::from_bundle` (bundle.rs) chains the two.

use super::eye::{eye_key, world_box};
use super::Scene;
use crate::bvh::MeshBvh;
use crate::camera::Camera;
use crate::geometry::Aabb;
use crate::sampling::{hash2, hash_str};
use crate::scene::SceneDesc;
use glam::DVec3;
use std::collections::HashMap;
use std::sync::OnceLock;

impl Scene {
    /// Builds the acceleration structures of a parsed scene.
    pub fn build(mut desc: SceneDesc) -> Scene {
        // Each mesh is renumbered in its BVH's leaf order (see
        // `MeshBvh::build`): a leaf's triangles are consecutive, and its
        // vertices are copied into the leaf. Per-triangle surfaces follow.
        let (blas, orders): (Vec<MeshBvh>, Vec<Vec<u32>>) =
            desc.meshes.iter_mut().map(MeshBvh::build).unzip();
        for model in &mut desc.models {
            if !model.triangle_surface.is_empty() {
                let old = std::mem::take(&mut model.triangle_surface);
                model.triangle_surface = orders[model.mesh]
                    .iter()
                    .map(|&t| old[t as usize])
                    .collect();
            }
        }
        let has_translucency = desc
            .models
            .iter()
            .flat_map(|m| m.surfaces.iter())
            .chain(desc.spheres.iter().map(|s| &s.surface))
            .chain(desc.planes.iter().map(|p| &p.surface))
            .any(|s| s.opacity < 1.0);
        let mut scene = Scene {
            desc,
            blas,
            loaded_index: orders,
            from_eyes: Vec::new(),
            eyes: Vec::new(),
            camera_eye: Vec::new(),
            from_origin: OnceLock::new(),
            bounds: Aabb::EMPTY,
            has_translucency,
            cameras: Vec::new(),
            camera_hashes: Vec::new(),
        };
        scene.place(None);
        scene
    }

    /// Computes everything that follows where the models, cameras and
    /// lights are (all but the meshes and their BVHs): the distinct camera
    /// positions and their (not yet built) views, the bounds, the cameras'
    /// frames and sample hashes. `frame` is the sequence's frame number,
    /// which enters every camera's hash (`None` for a still: the hash of a
    /// scene without frames is what it always was).
    pub(super) fn place(&mut self, frame: Option<u32>) {
        let desc = &self.desc;
        let mut eyes: Vec<DVec3> = Vec::new();
        let mut index_of_eye: HashMap<[u64; 3], usize> = HashMap::new();
        let mut camera_eye = Vec::with_capacity(desc.cameras.len());
        for c in &desc.cameras {
            let i = *index_of_eye.entry(eye_key(c.position)).or_insert_with(|| {
                eyes.push(c.position);
                eyes.len() - 1
            });
            camera_eye.push(i);
        }
        self.from_eyes = eyes.iter().map(|_| OnceLock::new()).collect();
        self.from_origin = OnceLock::new();
        let mut bounds = Aabb::EMPTY;
        for model in &desc.models {
            let b = world_box(self.blas[model.mesh].bounds(), &model.transform);
            bounds = bounds.union(b);
        }
        for s in &desc.spheres {
            let r = DVec3::splat(s.radius as f64);
            bounds = bounds.union(Aabb {
                min: (s.center - r).as_vec3(),
                max: (s.center + r).as_vec3(),
            });
        }
        self.bounds = bounds;
        self.eyes = eyes;
        self.camera_eye = camera_eye;
        self.cameras = desc.cameras.iter().map(Camera::new).collect();
        self.camera_hashes = desc
            .cameras
            .iter()
            .map(|c| match frame {
                None => hash_str(&c.id),
                Some(f) => hash2(hash_str(&c.id), u64::from(f)),
            })
            .collect();
    }
}
