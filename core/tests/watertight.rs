//! Closed meshes never leak: over a million rays aimed exactly at vertices
//! and at points on edges — where two or more triangles meet and a
//! non-watertight test lets rays slip through — from inside and from outside.

// Independent closed forms and test geometry, computed with std on purpose (clippy.toml).
#![allow(clippy::disallowed_methods)]

use glam::{DMat4, Vec3};
use rayon::prelude::*;
use trevi_core::mesh::Mesh;
use trevi_core::scene::{Model, SceneDesc, Surface};
use trevi_core::Scene;

fn icosphere(levels: u32) -> Mesh {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut pos: Vec<Vec3> = [
        (-1.0, t, 0.0),
        (1.0, t, 0.0),
        (-1.0, -t, 0.0),
        (1.0, -t, 0.0),
        (0.0, -1.0, t),
        (0.0, 1.0, t),
        (0.0, -1.0, -t),
        (0.0, 1.0, -t),
        (t, 0.0, -1.0),
        (t, 0.0, 1.0),
        (-t, 0.0, -1.0),
        (-t, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| Vec3::new(x, y, z).normalize())
    .collect();
    let mut tris: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..levels {
        let mut mid = std::collections::HashMap::new();
        let mut next = Vec::new();
        for [a, b, c] in tris {
            let mut m = |i: u32, j: u32| -> u32 {
                *mid.entry((i.min(j), i.max(j))).or_insert_with(|| {
                    pos.push(((pos[i as usize] + pos[j as usize]) * 0.5).normalize());
                    pos.len() as u32 - 1
                })
            };
            let (ab, bc, ca) = (m(a, b), m(b, c), m(c, a));
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        tris = next;
    }
    finish(pos, tris)
}

fn torus(u: u32, v: u32) -> Mesh {
    let (big, small) = (1.0f32, 0.4f32);
    let mut pos = Vec::new();
    for i in 0..u {
        let a = std::f32::consts::TAU * i as f32 / u as f32;
        for j in 0..v {
            let b = std::f32::consts::TAU * j as f32 / v as f32;
            pos.push(Vec3::new(
                (big + small * b.cos()) * a.cos(),
                small * b.sin(),
                (big + small * b.cos()) * a.sin(),
            ));
        }
    }
    let mut tris = Vec::new();
    for i in 0..u {
        for j in 0..v {
            let idx = |i: u32, j: u32| (i % u) * v + (j % v);
            let (a, b, c, d) = (idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1));
            tris.push([a, d, c]);
            tris.push([a, c, b]);
        }
    }
    finish(pos, tris)
}

/// A cube of side 2 whose faces are n×n grids of quads sharing their edges.
fn grid_cube(n: u32) -> Mesh {
    let mut pos = Vec::new();
    let mut tris = Vec::new();
    let mut index = std::collections::HashMap::new();
    let mut vert = |p: Vec3, pos: &mut Vec<Vec3>| -> u32 {
        let key = (p * 1000.0).round().as_ivec3().to_array();
        *index.entry(key).or_insert_with(|| {
            pos.push(p);
            pos.len() as u32 - 1
        })
    };
    for axis in 0..3 {
        for side in [-1.0f32, 1.0] {
            let (a1, a2) = ((axis + 1) % 3, (axis + 2) % 3);
            for i in 0..n {
                for j in 0..n {
                    let corner = |di: u32, dj: u32| {
                        let mut p = Vec3::ZERO;
                        p[axis] = side;
                        p[a1] = -1.0 + 2.0 * (i + di) as f32 / n as f32;
                        p[a2] = -1.0 + 2.0 * (j + dj) as f32 / n as f32;
                        p
                    };
                    let q = [corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)];
                    let mut q: Vec<u32> = q.iter().map(|&p| vert(p, &mut pos)).collect();
                    // a1 × a2 = +axis: wind the −axis side the other way so
                    // every face points outwards.
                    if side < 0.0 {
                        q.reverse();
                    }
                    tris.push([q[0], q[1], q[2]]);
                    tris.push([q[0], q[2], q[3]]);
                }
            }
        }
    }
    finish(pos, tris)
}

fn finish(positions: Vec<Vec3>, triangles: Vec<[u32; 3]>) -> Mesh {
    let mut m = Mesh {
        positions,
        normals: vec![],
        uvs: vec![],
        triangles,
    };
    m.compute_smooth_normals();
    m
}

fn scene_of(mesh: Mesh, transform: DMat4) -> Scene {
    Scene::build(SceneDesc {
        meshes: vec![mesh],
        models: vec![Model {
            id: "m".into(),
            mesh: 0,
            transform,
            surfaces: vec![Surface::default()],
            triangle_surface: vec![],
        }],
        ..SceneDesc::default()
    })
}

/// A point on the surface and the normals of the faces that meet there.
struct Target {
    p: Vec3,
    normals: Vec<Vec3>,
}

/// Vertices, edge midpoints and points at 1/3 and 0.1 along every edge, in
/// world space, each with the normals of the faces that meet there.
fn targets(mesh: &Mesh, transform: DMat4) -> Vec<Target> {
    let m = transform.as_mat4();
    let face_n: Vec<Vec3> = mesh
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| m.transform_point3(mesh.positions[i as usize]));
            (b - a).cross(c - a).normalize()
        })
        .collect();
    let mut at_vertex = vec![Vec::new(); mesh.positions.len()];
    let mut at_edge: std::collections::BTreeMap<(u32, u32), Vec<Vec3>> = Default::default();
    for (f, t) in mesh.triangles.iter().enumerate() {
        for k in 0..3 {
            at_vertex[t[k] as usize].push(face_n[f]);
            let (a, b) = (t[k], t[(k + 1) % 3]);
            at_edge
                .entry((a.min(b), a.max(b)))
                .or_default()
                .push(face_n[f]);
        }
    }
    let mut out: Vec<Target> = mesh
        .positions
        .iter()
        .zip(at_vertex)
        .map(|(&p, normals)| Target {
            p: m.transform_point3(p),
            normals,
        })
        .collect();
    for ((a, b), normals) in at_edge {
        assert_eq!(normals.len(), 2, "test mesh is not closed");
        let (a, b) = (mesh.positions[a as usize], mesh.positions[b as usize]);
        for f in [0.5f32, 1.0 / 3.0, 0.1] {
            out.push(Target {
                p: m.transform_point3(a + (b - a) * f),
                normals: normals.clone(),
            });
        }
    }
    out
}

fn lcg(s: &mut u64) -> f32 {
    *s = s
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (*s >> 40) as f32 / (1u64 << 24) as f32
}

/// Fires rays from `origins` at every target. From inside, every ray must hit
/// something (it has to leave the closed solid), and one that crosses the
/// surface at its target (every face there turned away from it) must hit no
/// later than the target. From outside, a ray that enters the solid at its
/// target (every face there turned towards it) must hit no later than the
/// target; rays that only graze the surface at the target (the silhouette)
/// may touch or not, and are not counted. Returns the number of rays checked.
fn check(name: &str, scene: &Scene, targets: &[Target], origins: &[Vec3], inside: bool) -> usize {
    let results: Vec<(usize, Vec<String>)> = origins
        .par_iter()
        .map(|&o| {
            let mut n = 0;
            let mut leaks = Vec::new();
            for t in targets {
                let d = t.p - o;
                let dn = d.normalize();
                let crossing = if inside {
                    t.normals.iter().all(|n| n.dot(dn) > 1e-3)
                } else {
                    t.normals.iter().all(|n| n.dot(dn) < -1e-3)
                };
                if inside {
                    n += 1;
                    if scene.intersect(o, d, f32::INFINITY).is_none() {
                        leaks.push(format!("{name}: ray from {o} towards {} escaped", t.p));
                    }
                }
                if crossing {
                    n += 1;
                    if scene.intersect(o, d, 1.0 + 1e-3).is_none() {
                        leaks.push(format!("{name}: ray from {o} through {} leaked", t.p));
                    }
                }
            }
            (n, leaks)
        })
        .collect();
    let leaks: Vec<&String> = results.iter().flat_map(|r| &r.1).collect();
    assert!(leaks.is_empty(), "{} leaks, e.g. {}", leaks.len(), leaks[0]);
    results.iter().map(|r| r.0).sum()
}

#[test]
fn a_million_rays_at_vertices_and_edges_never_leak() {
    let mut total = 0;
    let mut s = 17u64;
    let random_dir =
        |s: &mut u64| Vec3::new(lcg(s) - 0.5, lcg(s) - 0.5, lcg(s) - 0.5).normalize_or(Vec3::X);
    let rotated = DMat4::from_rotation_y(0.7) * DMat4::from_rotation_x(0.3);
    for level in 0..=3 {
        let mesh = icosphere(level);
        for transform in [
            DMat4::IDENTITY,
            rotated * DMat4::from_scale(glam::DVec3::splat(3.0)),
        ] {
            let tg = targets(&mesh, transform);
            let scale = if transform == DMat4::IDENTITY {
                1.0
            } else {
                3.0
            };
            let scene = scene_of(mesh.clone(), transform);
            // Inside: the centre and random interior points.
            let mut inside = vec![Vec3::ZERO];
            inside.extend((0..7).map(|_| random_dir(&mut s) * (0.5 * lcg(&mut s) * scale)));
            total += check(
                &format!("icosphere {level} inside"),
                &scene,
                &tg,
                &inside,
                true,
            );
            // Outside: points on a sphere of radius 4 (rays to the far side of
            // the mesh are blocked earlier, which still counts as a hit).
            let outside: Vec<Vec3> = (0..24).map(|_| random_dir(&mut s) * 4.0 * scale).collect();
            total += check(
                &format!("icosphere {level} outside"),
                &scene,
                &tg,
                &outside,
                false,
            );
        }
    }
    let tor = torus(48, 24);
    let tg = targets(&tor, DMat4::IDENTITY);
    let scene = scene_of(tor, DMat4::IDENTITY);
    // Inside the tube: points on its core circle.
    let inside: Vec<Vec3> = (0..8)
        .map(|k| {
            let a = k as f32 * 0.77;
            Vec3::new(a.cos(), 0.0, a.sin())
        })
        .collect();
    total += check("torus inside", &scene, &tg, &inside, true);
    let cube = grid_cube(12);
    let tg = targets(&cube, DMat4::IDENTITY);
    let scene = scene_of(cube, DMat4::IDENTITY);
    let inside: Vec<Vec3> = (0..40)
        .map(|_| random_dir(&mut s) * 0.8 * lcg(&mut s))
        .collect();
    total += check("grid cube inside", &scene, &tg, &inside, true);
    let outside: Vec<Vec3> = (0..40).map(|_| random_dir(&mut s) * 6.0).collect();
    total += check("grid cube outside", &scene, &tg, &outside, false);
    assert!(total >= 1_000_000, "only {total} rays");
}
