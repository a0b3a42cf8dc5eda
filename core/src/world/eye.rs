//! The world relative to an eye (a camera position): instance transforms
//! composed with the shift by −eye in f64 before rounding to f32, sphere
//! centres, plane points, light positions and area lights likewise, and the
//! top-level tree over them. Built when a camera first renders (cameras at
//! one position share it).

use super::{Instance, WorldFromEye};
use crate::bvh::{Bvh, MeshBvh};
use crate::geometry::Aabb;
use crate::lights::area::AreaLights;
use crate::scene::{SceneDesc, Sided};
use glam::{Affine3A, DMat4, DVec3, Mat3, Vec3};

/// The world seen from `eye`: instance transforms composed with the shift
/// by −eye in f64 before rounding, and every position likewise.
pub(super) fn build_world_from_eye(desc: &SceneDesc, blas: &[MeshBvh], eye: DVec3) -> WorldFromEye {
    let shift = DMat4::from_translation(-eye);
    let instances: Vec<Instance> = desc
        .models
        .iter()
        .enumerate()
        .map(|(i, model)| {
            let m = shift * model.transform;
            let lin = model.transform.inverse().transpose().as_mat4();
            let l = Mat3::from_mat4(m.as_mat4());
            let lin_norm = (0..3)
                .map(|r| l.row(r).abs().element_sum())
                .fold(0.0f32, f32::max);
            Instance {
                mesh: model.mesh as u32,
                model: i as u32,
                to_world: Affine3A::from_mat4(m.as_mat4()),
                to_object: Affine3A::from_mat4(m.inverse().as_mat4()),
                normal_matrix: Mat3::from_mat4(lin),
                lin_norm,
                trans_mag: m.w_axis.truncate().abs().max_element() as f32,
                mirrored: model.transform.determinant() < 0.0,
                any_front_only: model.surfaces.iter().any(|s| s.sided == Sided::Front),
            }
        })
        .collect();
    let mut boxes: Vec<Aabb> = desc
        .models
        .iter()
        .map(|model| world_box(blas[model.mesh].bounds(), &(shift * model.transform)))
        .collect();
    let sphere_centers: Vec<Vec3> = desc
        .spheres
        .iter()
        .map(|s| (s.center - eye).as_vec3())
        .collect();
    boxes.extend(desc.spheres.iter().zip(&sphere_centers).map(|(s, &c)| {
        let r = Vec3::splat(s.radius);
        pad(Aabb {
            min: c - r,
            max: c + r,
        })
    }));
    let tlas = Bvh::build(&boxes, 2);
    let bounds = boxes.iter().fold(Aabb::EMPTY, |a, &b| a.union(b));
    let plane_points = desc
        .planes
        .iter()
        .map(|pl| {
            let n = pl.normal.as_dvec3();
            let n = n / n.length();
            (n * (pl.point - eye).dot(n)).as_vec3()
        })
        .collect();
    let light_positions = desc
        .lights
        .iter()
        .map(|l| (l.position - eye).as_vec3())
        .collect();
    let area_lights = build_area_lights(desc, &instances, &sphere_centers);
    WorldFromEye {
        eye,
        instances,
        tlas,
        sphere_centers,
        plane_points,
        light_positions,
        area_lights,
        bounds,
    }
}

/// Every triangle and sphere whose surface emits, in the view's coordinates.
fn build_area_lights(
    desc: &SceneDesc,
    instances: &[Instance],
    sphere_centers: &[Vec3],
) -> AreaLights {
    let mut lights = AreaLights::new();
    for inst in instances {
        let model = &desc.models[inst.model as usize];
        if model.surfaces.iter().all(|s| s.emission == Vec3::ZERO) {
            continue;
        }
        let mesh = &desc.meshes[inst.mesh as usize];
        for (t, tri) in mesh.triangles.iter().enumerate() {
            let s = if model.triangle_surface.is_empty() {
                0
            } else {
                model.triangle_surface[t] as usize
            };
            let surf = &model.surfaces[s];
            if surf.emission != Vec3::ZERO {
                let v = tri.map(|i| inst.to_world.transform_point3(mesh.positions[i as usize]));
                lights.triangle(v, surf.emission, surf.sided == Sided::Two);
            }
        }
    }
    for (s, &c) in desc.spheres.iter().zip(sphere_centers) {
        if s.surface.emission != Vec3::ZERO {
            lights.sphere(
                c,
                s.radius,
                s.surface.emission,
                s.surface.sided == Sided::Two,
            );
        }
    }
    lights
}

/// A camera position as a hash key: positions equal as numbers (0 and −0
/// included) give the same key.
pub(super) fn eye_key(p: DVec3) -> [u64; 3] {
    (p + DVec3::ZERO).to_array().map(f64::to_bits)
}

/// Grows a box by a few ULPs of its coordinates, so that rounding its
/// corners (or the primitive inside) to f32 cannot leave a sliver outside.
fn pad(b: Aabb) -> Aabb {
    if b.is_empty() {
        return b;
    }
    let e = b.min.abs().max(b.max.abs()) * 4.0 * f32::EPSILON;
    Aabb {
        min: b.min - e,
        max: b.max + e,
    }
}

/// The box around object-space box `b` under `m`, computed in f64 and
/// rounded outwards to f32.
pub(super) fn world_box(b: Aabb, m: &DMat4) -> Aabb {
    if b.is_empty() {
        return b;
    }
    let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for i in 0..8 {
        let c = DVec3::new(
            if i & 1 == 0 { b.min.x } else { b.max.x } as f64,
            if i & 2 == 0 { b.min.y } else { b.max.y } as f64,
            if i & 4 == 0 { b.min.z } else { b.max.z } as f64,
        );
        let p = m.transform_point3(c);
        lo = lo.min(p);
        hi = hi.max(p);
    }
    pad(Aabb {
        min: lo.as_vec3(),
        max: hi.as_vec3(),
    })
}

#[cfg(test)]
mod tests {
    use crate::world::HitKind;
    use crate::{Bundle, Scene};
    use glam::Vec3;
    use std::collections::BTreeMap;

    /// Building every camera's view up front would cost cameras × objects
    /// (work quadratic in the size of the scene file): a view is built when
    /// a camera first renders, and cameras at one position share it.
    #[test]
    fn camera_views_are_built_for_the_cameras_rendered_only() {
        let n = 300;
        let mut xml = String::from("<scene version=\"1\">\n");
        for i in 0..n {
            xml.push_str(&format!(
                "<sphere id=\"s{i}\" center=\"{i} 0 -10\" radius=\"0.4\"/>\n\
                 <camera id=\"c{i}\" position=\"{i} 0 0\" direction=\"0 0 -1\" fov=\"10\">\
                 <render width=\"1\" height=\"1\"/></camera>\n"
            ));
        }
        // Two cameras at one position share a view.
        xml.push_str(
            "<camera id=\"twin\" position=\"7 0 0\" direction=\"0 0 -1\" fov=\"10\">\
             <render width=\"1\" height=\"1\"/></camera>\n</scene>\n",
        );
        let mut files = BTreeMap::new();
        files.insert("s.xml".to_string(), xml.into_bytes());
        let bundle = Bundle {
            scene: "s.xml".into(),
            files,
        };
        let scene = Scene::from_bundle(&bundle).unwrap();
        assert_eq!(scene.built_views(), 0);
        let hit = |c: usize| {
            let v = scene.view(c);
            v.intersect(Vec3::ZERO, -Vec3::Z, f32::INFINITY)
                .map(|h| h.kind)
        };
        assert_eq!(hit(7), Some(HitKind::Sphere(7)));
        assert_eq!(scene.built_views(), 1);
        assert_eq!(hit(n), Some(HitKind::Sphere(7)));
        assert_eq!(scene.built_views(), 1);
        assert_eq!(hit(250), Some(HitKind::Sphere(250)));
        assert_eq!(scene.built_views(), 2);
    }
}
