//! Build and traversal against the reference tree (visit for visit, on
//! random, lattice, nested and degenerate scenes), against brute force, and
//! the tree's own invariants.

use super::*;
use crate::geometry::ray_box;

fn lcg(state: &mut u64) -> f32 {
    *state = state
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    ((*state >> 40) as f32) / (1u64 << 24) as f32
}

fn random_boxes(n: usize, seed: u64) -> Vec<Aabb> {
    let mut s = seed;
    (0..n)
        .map(|_| {
            let c = Vec3::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) * 10.0;
            let e = Vec3::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) * 0.3;
            Aabb {
                min: c - e,
                max: c + e,
            }
        })
        .collect()
}

/// Unit boxes on an integer lattice, some repeated: many equal entry
/// distances, shared faces, and rays along the axes.
fn lattice_boxes(n: usize) -> Vec<Aabb> {
    (0..n)
        .map(|i| {
            let c = Vec3::new((i % 7) as f32, ((i / 7) % 5) as f32, (i / 35 % 6) as f32);
            Aabb {
                min: c,
                max: c + Vec3::ONE,
            }
        })
        .collect()
}

/// Nested boxes halving in size: a chain far deeper than the stack.
fn nested_boxes(n: usize) -> Vec<Aabb> {
    (0..n)
        .map(|i| {
            let s = 0.5f32.powi(i as i32 / 2) * 100.0;
            Aabb {
                min: Vec3::ZERO,
                max: Vec3::splat(s),
            }
        })
        .collect()
}

fn ref_leaves(r: &reference::RefBvh) -> Vec<Vec<u32>> {
    let mut out = Vec::new();
    let mut stack = vec![0usize];
    while let Some(i) = stack.pop() {
        let n = r.nodes[i];
        if n.count > 0 {
            out.push(r.prims[n.first as usize..(n.first + n.count) as usize].to_vec());
        } else {
            stack.push(n.first as usize + 1);
            stack.push(n.first as usize);
        }
    }
    out
}

#[derive(Clone, Copy, Debug)]
enum Mode {
    Closest,
    Gather,
    StopAfter(usize),
}

type Trace = (Vec<(u32, u32)>, u32, bool);

fn run(
    boxes: &[Aabb],
    o: Vec3,
    d: Vec3,
    mode: Mode,
    traverse: impl FnOnce(&mut dyn FnMut(u32, f32) -> Visit) -> (f32, bool),
) -> Trace {
    let inv = d.recip();
    let mut seen = Vec::new();
    let mut f = |p: u32, tm: f32| {
        seen.push((p, tm.to_bits()));
        let b = boxes[p as usize];
        match (mode, ray_box(o, inv, b.min, b.max, tm)) {
            (Mode::Closest, Some(t)) => Visit::Hit(t),
            (Mode::StopAfter(k), Some(_)) if seen.len() > k => Visit::Stop,
            _ => Visit::Miss,
        }
    };
    let (t, h) = traverse(&mut f);
    (seen, t.to_bits(), h)
}

fn rays(seed: u64, n: usize, boxes: &[Aabb]) -> Vec<(Vec3, Vec3, f32)> {
    let mut s = seed;
    let b = boxes.iter().fold(Aabb::EMPTY, |a, &b| a.union(b));
    let ext = b.max - b.min;
    let mut out = Vec::new();
    for i in 0..n {
        let mut o =
            b.min - ext * 0.2 + Vec3::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) * ext * 1.4;
        let mut d = Vec3::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) - 0.5;
        match i % 5 {
            // Along an axis: zero direction components (inf in 1/d).
            1 => d = [Vec3::X, -Vec3::Y, Vec3::Z, Vec3::new(0.0, 1.0, -1.0)][i / 5 % 4],
            // From a lattice point, on box faces.
            2 => o = o.round(),
            3 => {
                o = o.round();
                d = d.signum() * Vec3::new(1.0, 0.0, 1.0);
            }
            _ => {}
        }
        let t_max = if i % 7 == 0 { 2.5 } else { f32::INFINITY };
        out.push((o, d, t_max));
    }
    out
}

fn sorted(mut v: Vec<u32>) -> Vec<u32> {
    v.sort_unstable();
    v
}

/// The scalar and SSE node tests give the same visits, in the same order,
/// with the same `t_max` at each (the bits of the image on every machine).
fn same_on_every_path(
    bvh: &Bvh,
    boxes: &[Aabb],
    o: Vec3,
    d: Vec3,
    t_max: f32,
    mode: Mode,
) -> Trace {
    let mut traces = Simd::available().iter().map(|&p| {
        run(boxes, o, d, mode, |f| {
            bvh.traverse_on::<_, true>(p, o, d, t_max, f)
        })
    });
    let first = traces.next().expect("the scalar path");
    for t in traces {
        assert_eq!(t, first, "paths differ: {o} {d} {t_max} {mode:?}");
    }
    first
}

/// [`same_on_every_path`] for the unordered walk
/// ([`Bvh::traverse_unordered`]).
fn same_on_every_path_unordered(
    bvh: &Bvh,
    boxes: &[Aabb],
    o: Vec3,
    d: Vec3,
    t_max: f32,
    mode: Mode,
) -> Trace {
    let mut traces = Simd::available().iter().map(|&p| {
        run(boxes, o, d, mode, |f| {
            bvh.traverse_on::<_, false>(p, o, d, t_max, f)
        })
    });
    let first = traces.next().expect("the scalar path");
    for t in traces {
        assert_eq!(t, first, "unordered paths differ: {o} {d} {t_max} {mode:?}");
    }
    first
}

#[test]
fn build_matches_the_reference_and_traversal_finds_what_it_finds() {
    let scenes = [
        (random_boxes(3000, 7), 4),
        (random_boxes(500, 8), 2),
        (lattice_boxes(400), 4),
        (lattice_boxes(300), 1),
        (nested_boxes(300), 2),
        (
            vec![
                Aabb {
                    min: Vec3::ZERO,
                    max: Vec3::ONE
                };
                50
            ],
            4,
        ),
        (random_boxes(1, 3), 4),
    ];
    for (k, (boxes, max_leaf)) in scenes.iter().enumerate() {
        let new = Bvh::build(boxes, *max_leaf);
        let old = reference::RefBvh::build(boxes, *max_leaf);
        // Collapsing keeps the binary tree's leaves, in its order.
        let leaves: Vec<Vec<u32>> = new.leaves().iter().map(|l| l.1.to_vec()).collect();
        assert_eq!(leaves, ref_leaves(&old), "scene {k}: leaves");
        assert_eq!(new.bounds(), old.bounds(), "scene {k}");
        let sah_old = old.sah_cost();
        assert!(
            (new.sah_cost() - sah_old).abs() <= 1e-4 * sah_old.max(1.0),
            "scene {k}"
        );
        for (i, &(o, d, t_max)) in rays(k as u64 + 1, 400, boxes).iter().enumerate() {
            let what = format!("scene {k}, ray {i} {o} {d}");
            // Every primitive the reference visits, each once (the wide
            // tree skips some of the binary tree's boxes, so it may visit
            // more), on every path alike.
            let (seen, ..) = same_on_every_path(&new, boxes, o, d, t_max, Mode::Gather);
            let seen = sorted(seen.iter().map(|s| s.0).collect());
            let mut unique = seen.clone();
            unique.dedup();
            assert_eq!(seen, unique, "{what}: visited twice");
            let (want, ..) = run(boxes, o, d, Mode::Gather, |f| old.traverse(o, d, t_max, f));
            for (p, _) in want {
                assert!(seen.binary_search(&p).is_ok(), "{what}: missed {p}");
            }
            // The same closest distance and the same answer to any-hit.
            let (_, t_new, h_new) = same_on_every_path(&new, boxes, o, d, t_max, Mode::Closest);
            let (_, t_old, h_old) =
                run(boxes, o, d, Mode::Closest, |f| old.traverse(o, d, t_max, f));
            assert_eq!((t_new, h_new), (t_old, h_old), "{what}: closest");
            let (_, _, h_new) = same_on_every_path(&new, boxes, o, d, t_max, Mode::StopAfter(0));
            assert_eq!(h_new, h_old, "{what}: any hit");
            // The unordered walk (shadow rays): the same answer to any-hit,
            // and the same set of primitives when it does not stop.
            let (_, _, h_un) =
                same_on_every_path_unordered(&new, boxes, o, d, t_max, Mode::StopAfter(0));
            assert_eq!(h_un, h_old, "{what}: unordered any hit");
            let (seen_un, ..) =
                same_on_every_path_unordered(&new, boxes, o, d, t_max, Mode::Gather);
            assert_eq!(
                sorted(seen_un.iter().map(|s| s.0).collect()),
                seen,
                "{what}: unordered visits"
            );
            same_on_every_path(&new, boxes, o, d, t_max, Mode::StopAfter(i % 4));
        }
    }
}

#[test]
fn after_taking_the_leaf_order_the_walk_reports_leaf_positions() {
    let boxes = random_boxes(2000, 21);
    let rays = rays(5, 300, &boxes);
    let modes = [Mode::Gather, Mode::Closest];
    let mut bvh = Bvh::build(&boxes, 4);
    let before: Vec<Trace> = rays
        .iter()
        .flat_map(|&(o, d, t_max)| {
            let bvh = &bvh;
            let boxes = &boxes;
            modes.map(move |m| run(boxes, o, d, m, |f| bvh.traverse(o, d, t_max, f)))
        })
        .collect();
    let order = bvh.take_leaf_order();
    let mut sorted = order.clone();
    sorted.sort_unstable();
    assert!(
        sorted.iter().copied().eq(0..boxes.len() as u32),
        "a permutation"
    );
    // Primitive k is now the old order[k]: the same visits, renamed.
    let renumbered: Vec<Aabb> = order.iter().map(|&p| boxes[p as usize]).collect();
    let mut i = 0;
    for &(o, d, t_max) in &rays {
        for m in modes {
            let (seen, t, h) = run(&renumbered, o, d, m, |f| bvh.traverse(o, d, t_max, f));
            let seen: Vec<(u32, u32)> = seen
                .iter()
                .map(|&(k, tm)| (order[k as usize], tm))
                .collect();
            assert_eq!((seen, t, h), before[i], "ray {} {m:?}", i / 2);
            i += 1;
        }
    }
}

#[test]
fn every_primitive_is_in_exactly_one_leaf_and_inside_its_boxes() {
    let boxes = random_boxes(5000, 7);
    let bvh = Bvh::build(&boxes, 4);
    let mut seen = vec![0; boxes.len()];
    for (b, prims) in bvh.leaves() {
        for &p in prims {
            seen[p as usize] += 1;
            let pb = boxes[p as usize];
            assert!(pb.min.cmpge(b.min).all() && pb.max.cmple(b.max).all());
        }
    }
    assert!(seen.iter().all(|&c| c == 1));
}

#[test]
fn traversal_finds_the_same_closest_box_as_brute_force() {
    let boxes = random_boxes(2000, 11);
    let bvh = Bvh::build(&boxes, 4);
    let mut s = 99u64;
    for _ in 0..500 {
        let o = Vec3::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) * 14.0 - 2.0;
        let d = Vec3::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) - 0.5;
        let inv = d.recip();
        let brute = boxes
            .iter()
            .filter_map(|b| ray_box(o, inv, b.min, b.max, f32::INFINITY))
            .fold(f32::INFINITY, f32::min);
        let (t, hit) = bvh.traverse(o, d, f32::INFINITY, |p, tmax| {
            let b = boxes[p as usize];
            match ray_box(o, inv, b.min, b.max, tmax) {
                Some(t) => Visit::Hit(t),
                None => Visit::Miss,
            }
        });
        assert_eq!(hit, brute.is_finite());
        if hit {
            assert_eq!(t, brute);
        }
    }
}

#[test]
fn sah_beats_a_single_leaf_and_identical_boxes_still_build() {
    let boxes = random_boxes(1000, 3);
    let bvh = Bvh::build(&boxes, 4);
    assert!(bvh.sah_cost() < 1000.0 / 10.0);
    let same = vec![
        Aabb {
            min: Vec3::ZERO,
            max: Vec3::ONE
        };
        100
    ];
    let bvh = Bvh::build(&same, 4);
    assert!(bvh.leaves().iter().all(|l| l.1.len() <= 4));
    assert_eq!(
        Bvh::build(&[], 4).traverse(Vec3::ZERO, Vec3::X, 1.0, |_, _| Visit::Stop),
        (1.0, false)
    );
}

#[test]
fn large_builds_take_the_parallel_path_and_still_match() {
    // Above the parallel thresholds: parallel binning and subtrees.
    let boxes = random_boxes(150_000, 5);
    let new = Bvh::build(&boxes, 4);
    let old = reference::RefBvh::build(&boxes, 4);
    let leaves: Vec<Vec<u32>> = new.leaves().iter().map(|l| l.1.to_vec()).collect();
    assert_eq!(leaves, ref_leaves(&old));
}

// ------------------------------------------------------------ triangle leaves

use crate::geometry::triangle::{self, ShearedRay, TriangleHit};
use crate::mesh::Mesh;

/// Leaves priced in blocks of four: the same tree as the reference's, and
/// most leaves full (the point of pricing by blocks; with per-triangle
/// pricing, the same scene has far fewer full leaves).
#[test]
fn block_sah_matches_the_reference_and_fills_the_leaves() {
    for (k, boxes) in [
        random_boxes(3000, 11),
        lattice_boxes(400),
        random_boxes(7, 12),
    ]
    .iter()
    .enumerate()
    {
        let new = Bvh::build_blocks(boxes, 4, 4);
        let old = reference::RefBvh::build_blocks(boxes, 4, 4);
        let leaves: Vec<Vec<u32>> = new.leaves().iter().map(|l| l.1.to_vec()).collect();
        assert_eq!(leaves, ref_leaves(&old), "scene {k}: leaves");
        let sah_old = old.sah_cost();
        assert!((new.sah_cost() - sah_old).abs() <= 1e-4 * sah_old.max(1.0));
        assert!(leaves.iter().all(|l| (1..=4).contains(&l.len())));
        if boxes.len() >= 400 {
            let full = |t: &Bvh| t.leaves().iter().filter(|l| l.1.len() == 4).count();
            let per_prim = Bvh::build(boxes, 4);
            let (f_new, n_new) = (full(&new), new.leaves().len());
            assert!(
                2 * f_new > n_new,
                "scene {k}: {f_new} of {n_new} leaves full"
            );
            assert!(f_new > 2 * full(&per_prim), "scene {k}");
        }
    }
}

/// Triangles for the pack tests: random ones, ones sharing edges and
/// vertices with rays through them (edge functions exactly zero), slivers,
/// degenerate and huge ones.
fn pack_triangles(seed: u64, n: usize) -> Vec<[Vec3; 3]> {
    let mut s = seed;
    let mut r3 = |k: f32| Vec3::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) * k;
    let mut out = Vec::new();
    while out.len() < n {
        let a = r3(4.0).round() * 0.5;
        let b = a + r3(2.0).round() - Vec3::ONE;
        let c = a + r3(2.0) - Vec3::ONE;
        out.push([a, b, c]);
        out.push([a, c, b + Vec3::X]);
        out.push([a, a, b]);
        out.push([a * 1e20, b * 1e20, c * 1e20]);
        out.push([a, b, a + (b - a) * 0.5 + Vec3::splat(1e-7)]);
    }
    out.truncate(n);
    out
}

/// The leaf copies of `tris` as `MeshBvh` lays them out, followed by
/// `tail` floats (the next leaf's, or the padding).
fn leaf_floats(tris: &[[Vec3; 3]], tail: f32) -> Vec<f32> {
    let n = tris.len();
    let mut p = vec![tail; 9 * n + leaves::PAD];
    for (lane, t) in tris.iter().enumerate() {
        for v in 0..3 {
            for a in 0..3 {
                p[(3 * v + a) * n + lane] = t[v][a];
            }
        }
    }
    p
}

fn same_hit(a: Option<TriangleHit>, b: Option<TriangleHit>) -> bool {
    let bits =
        |h: Option<TriangleHit>| h.map(|h| (h.t.to_bits(), h.bary.map(f32::to_bits), h.front));
    bits(a) == bits(b)
}

/// The SSE test of four triangles gives, lane by lane, the bits of the
/// scalar watertight test (or hands the lane to it, when an edge function
/// is exactly zero), for rays from lattice points and along axes, through
/// shared edges and vertices, and every bound.
#[cfg(target_arch = "x86_64")]
#[test]
fn sse_triangle_lanes_are_the_scalar_tests_bits() {
    let tris = pack_triangles(5, 400);
    let mut s = 99u64;
    let mut edge_lanes = 0;
    let mut hits = 0;
    // Leaves of 1, 2, 3, 4, 1, … triangles, followed by zeros, NaNs or huge
    // numbers in the lanes past their count.
    let mut start = 0;
    for i in 0usize.. {
        if start >= tris.len() {
            break;
        }
        let quad = &tris[start..(start + 1 + i % 4).min(tris.len())];
        start += quad.len();
        let floats = leaf_floats(quad, [0.0, f32::NAN, 1e30][i % 3]);
        let leaf = leaves::Leaf {
            p: &floats,
            n: quad.len(),
        };
        for j in 0..40 {
            let mut o = Vec3::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) * 6.0 - 1.0;
            let target = match j % 4 {
                // A vertex, an edge's midpoint: edge functions of zero.
                0 => quad[j / 4 % quad.len()][0],
                1 => (quad[0][0] + quad[0][1]) * 0.5,
                _ => Vec3::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) * 2.0,
            };
            if j % 7 == 0 {
                o = o.round();
            }
            let mut d = target - o;
            if j % 9 == 0 {
                d = Vec3::new(0.0, -1.0, 0.0);
                o = quad[0][0] + Vec3::Y;
            }
            let r = ShearedRay::new(o, d);
            for t_max in [f32::INFINITY, 1.0, 0.5, 1e-3] {
                let l = simd::triangles_sse(leaf.p, leaf.n, &r, t_max);
                for lane in 0..leaf.n {
                    let want = triangle::intersect(
                        &r,
                        leaf.vertex(0, lane),
                        leaf.vertex(1, lane),
                        leaf.vertex(2, lane),
                        t_max,
                    );
                    if l.edge & (1 << lane) != 0 {
                        edge_lanes += 1;
                        assert_eq!(l.hit & (1 << lane), 0);
                        continue;
                    }
                    let got = (l.hit & (1 << lane) != 0).then(|| l.hit_of(lane));
                    hits += usize::from(got.is_some());
                    assert!(
                        same_hit(got, want),
                        "pack {i}, ray {j}, lane {lane}, t_max {t_max}: {got:?} vs {want:?}"
                    );
                }
            }
        }
    }
    assert!(
        edge_lanes > 0 && hits > 100,
        "{edge_lanes} edge lanes, {hits} hits"
    );
}

/// A random triangle mesh, as loaded.
fn soup(seed: u64, n: usize) -> Mesh {
    let mut s = seed;
    let mut m = Mesh::default();
    for i in 0..n {
        let c = Vec3::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) * 10.0;
        for _ in 0..3 {
            m.positions
                .push(c + Vec3::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) - 0.5);
        }
        let k = 3 * i as u32;
        m.triangles.push([k, k + 1, k + 2]);
    }
    // Coincident copies of some triangles (ties at equal `t`) and a shared edge.
    for i in 0..n as u32 / 10 {
        m.triangles.push(m.triangles[(7 * i) as usize % n]);
        let [a, b, _] = m.triangles[(3 * i) as usize % n];
        m.triangles.push([b, a, (a + 5) % (3 * n as u32)]);
    }
    m
}

/// The mesh tree finds, on every path, the same hits in the same order as
/// the scalar path, and its closest hit is brute force's (the smallest `t`,
/// then the smallest triangle as loaded); the any-hit walk agrees on
/// whether anything is hit.
#[test]
fn mesh_leaves_find_brute_forces_closest_hit_on_every_path() {
    let loaded = soup(3, 600);
    let mut mesh = loaded.clone();
    let (bvh, order) = MeshBvh::build(&mut mesh);
    // Leaves of one to four cover every triangle once, most of them full.
    let mut ranges = bvh.tree.leaf_ranges();
    ranges.sort_unstable();
    let mut next = 0;
    for &(first, n) in &ranges {
        assert_eq!(first, next);
        assert!((1..=4).contains(&n));
        next += n;
    }
    assert_eq!(next as usize, mesh.triangles.len());
    let full = ranges.iter().filter(|r| r.1 == 4).count();
    assert!(
        2 * full > ranges.len(),
        "{full} of {} leaves full",
        ranges.len()
    );
    let tri = |m: &Mesh, t: usize| m.triangles[t].map(|i| m.positions[i as usize]);
    let boxes: Vec<Aabb> = (0..loaded.triangles.len())
        .map(|t| Aabb::from_points(&tri(&loaded, t)))
        .collect();
    for (i, (o, d, t_max)) in rays(17, 500, &boxes).into_iter().enumerate() {
        let r = ShearedRay::new(o, d);
        // Brute force over the mesh as loaded.
        let mut want: Option<(f32, u32)> = None;
        for t in 0..loaded.triangles.len() {
            let [a, b, c] = tri(&loaded, t);
            if let Some(h) = triangle::intersect(&r, a, b, c, t_max) {
                if want.is_none_or(|(wt, _)| h.t < wt) {
                    want = Some((h.t, t as u32));
                }
            }
        }
        let mut traces = Vec::new();
        for &path in Simd::available() {
            let mut seen = Vec::new();
            let mut best: Option<(f32, u32)> = None;
            let (_, hit) = bvh.traverse_on::<_, true>(path, o, d, t_max, |t, h| {
                seen.push((t, h.t.to_bits(), h.bary.map(f32::to_bits), h.front));
                let key = (h.t, order[t as usize]);
                if best.is_none_or(|b| key.0 < b.0 || (key.0 == b.0 && key.1 < b.1)) {
                    best = Some(key);
                }
                let bt = best.unwrap().0;
                Visit::Hit(f32::from_bits(bt.to_bits() + 1))
            });
            assert_eq!(hit, best.is_some());
            assert_eq!(
                best.map(|(t, k)| (t.to_bits(), k)),
                want.map(|(t, k)| (t.to_bits(), k)),
                "ray {i} on {path:?}"
            );
            let (_, any) = bvh.traverse_on::<_, false>(path, o, d, t_max, |_, _| Visit::Stop);
            assert_eq!(any, want.is_some(), "ray {i} on {path:?}: any hit");
            traces.push(seen);
        }
        assert!(
            traces.windows(2).all(|w| w[0] == w[1]),
            "ray {i}: paths differ"
        );
    }
}

/// Rays no camera should make but a broken transform or a NaN in a scene
/// could: NaN, infinite and zero directions and origins, and NaN, zero and
/// negative `t_max`.
fn degenerate_rays(inside: Vec3) -> Vec<(Vec3, Vec3, f32)> {
    let (nan, inf) = (f32::NAN, f32::INFINITY);
    let dirs = [
        Vec3::ZERO,
        Vec3::new(nan, 0.5, 0.5),
        Vec3::splat(nan),
        Vec3::new(inf, 0.0, 0.0),
        Vec3::new(-inf, inf, 1.0),
        Vec3::splat(inf),
        Vec3::new(0.0, 0.0, -0.0),
        Vec3::new(1e-45, 0.0, 0.0),
        Vec3::new(0.3, -0.4, 0.5),
    ];
    let origins = [
        inside,
        Vec3::new(-20.0, 5.0, 5.0),
        Vec3::new(nan, 5.0, 5.0),
        Vec3::splat(nan),
        Vec3::new(inf, 5.0, 5.0),
        Vec3::new(-inf, 5.0, 5.0),
        Vec3::splat(-inf),
        Vec3::new(3e38, -3e38, 3e38),
    ];
    let mut out = Vec::new();
    for o in origins {
        for d in dirs {
            for t_max in [inf, 10.0, 0.0, -1.0, nan] {
                out.push((o, d, t_max));
            }
        }
    }
    out
}

/// Degenerate rays neither panic nor loop: the tree visits each primitive
/// at most once per ray, and answers what the reference tree answers (box
/// tests; a NaN `t_max` enters nothing) or what brute force finds (the
/// mesh, where a ray with a NaN or a zero direction hits nothing).
#[test]
fn nan_infinite_and_zero_rays_end_and_agree_with_the_reference_and_brute_force() {
    let boxes = random_boxes(700, 31);
    let new = Bvh::build(&boxes, 4);
    let old = reference::RefBvh::build(&boxes, 4);
    for (i, &(o, d, t_max)) in degenerate_rays(Vec3::splat(5.0)).iter().enumerate() {
        let what = format!("ray {i}: {o} {d} {t_max}");
        for mode in [Mode::Closest, Mode::Gather, Mode::StopAfter(0)] {
            let guard = |seen: &Vec<(u32, u32)>| {
                assert!(seen.len() <= boxes.len(), "{what}: {} visits", seen.len())
            };
            let (seen, t_new, h_new) = same_on_every_path(&new, &boxes, o, d, t_max, mode);
            guard(&seen);
            let (seen_un, _, h_un) = same_on_every_path_unordered(&new, &boxes, o, d, t_max, mode);
            guard(&seen_un);
            let (_, t_old, h_old) = run(&boxes, o, d, mode, |f| old.traverse(o, d, t_max, f));
            if t_max.is_nan() {
                // No interval at all: the tree enters nothing (the
                // reference's box test, whose min and max drop a NaN,
                // would take it as no bound).
                assert!(
                    !h_new && !h_un && seen.is_empty(),
                    "{what}: a NaN t_max hit"
                );
                continue;
            }
            if matches!(mode, Mode::Closest) {
                assert_eq!((t_new, h_new), (t_old, h_old), "{what}: closest");
            }
            if matches!(mode, Mode::StopAfter(0)) {
                assert_eq!(h_new, h_old, "{what}: any hit");
                assert_eq!(h_un, h_old, "{what}: unordered any hit");
            }
        }
    }

    let loaded = soup(5, 300);
    let mut mesh = loaded.clone();
    let (bvh, order) = MeshBvh::build(&mut mesh);
    let tri = |m: &Mesh, t: usize| m.triangles[t].map(|i| m.positions[i as usize]);
    for (i, (o, d, t_max)) in degenerate_rays(Vec3::splat(5.0)).into_iter().enumerate() {
        let what = format!("mesh ray {i}: {o} {d} {t_max}");
        let r = ShearedRay::new(o, d);
        let mut want: Option<(f32, u32)> = None;
        for t in 0..loaded.triangles.len() {
            let [a, b, c] = tri(&loaded, t);
            if let Some(h) = triangle::intersect(&r, a, b, c, t_max) {
                if want.is_none_or(|(wt, _)| h.t < wt) {
                    want = Some((h.t, t as u32));
                }
            }
        }
        if o.is_nan() || d.is_nan() || t_max.is_nan() || d == Vec3::ZERO {
            assert_eq!(want, None, "{what}: brute force hits");
        }
        for &path in Simd::available() {
            let mut visits = 0;
            let mut best: Option<(f32, u32)> = None;
            let (_, hit) = bvh.traverse_on::<_, true>(path, o, d, t_max, |t, h| {
                visits += 1;
                assert!(visits <= mesh.triangles.len(), "{what}: {visits} visits");
                let key = (h.t, order[t as usize]);
                if best.is_none_or(|b| key.0 < b.0 || (key.0 == b.0 && key.1 < b.1)) {
                    best = Some(key);
                }
                Visit::Hit(f32::from_bits(best.unwrap().0.to_bits() + 1))
            });
            assert_eq!(hit, best.is_some(), "{what}");
            assert_eq!(
                best.map(|(t, k)| (t.to_bits(), k)),
                want.map(|(t, k)| (t.to_bits(), k)),
                "{what} on {path:?}"
            );
            let (_, any) = bvh.traverse_on::<_, false>(path, o, d, t_max, |_, _| Visit::Stop);
            assert_eq!(any, want.is_some(), "{what} on {path:?}: any hit");
        }
    }
}
