//! The one module of the tree with `unsafe` code: the SSE and AVX tests of
//! a wide node's eight boxes, their scalar twin, the choice between them,
//! the SSE test of a leaf's four triangles (whose scalar twin is
//! [`triangle::intersect`](crate::geometry::triangle::intersect) itself,
//! lane by lane), and the traversal stack.
//!
//! **Bit-identical paths.** The scalar test performs, lane by lane, exactly
//! the operations of the SSE and AVX tests, in the same order:
//! `(plane − o) · inv` (a subtraction then a multiplication, never fused:
//! Rust does not contract, and no path uses FMA, AVX's walk included), then
//! `maxps`/`minps`, whose semantics (`a > b ? a : b`, `a < b ? a : b`: the
//! second operand when either is NaN) `max_ps` and `min_ps` spell out. So
//! every entry distance, every mask bit, and with them the walk's visit
//! order, are the same bits on every path and every machine;
//! `core/tests/simd.rs` renders scenes through each path and compares the
//! bytes.
//!
//! **AVX at run time.** The AVX path is chosen only where the machine runs
//! AVX (detected once by `std`). Its walk runs inside `avx_region`, a
//! function compiled with AVX enabled into which the walk (its node tests,
//! and a mesh's leaf tests) is inlined; `AvxTest`, which only exists
//! where AVX was detected, is what lets it be called.
//!
//! **NaN.** A ray with a zero direction component has an infinite `inv`;
//! a box plane through the origin then gives `0 · ∞ = NaN`. Each slab value
//! enters the min/max chains as the *first* operand, whose NaN is dropped,
//! so that slab is treated as unbounded: conservative, never a missed box.

use super::{Node, Ref, WIDTH};
use crate::geometry::triangle::TriangleHit;
use std::mem::MaybeUninit;
use std::sync::atomic::{AtomicU8, Ordering};

/// The factor by which a box's exit distance is stretched before comparing
/// it with the entry, so that rounding never culls a box the ray grazes
/// (Ize, "Robust BVH Ray Traversal", 2013). The same as
/// [`ray_box`](crate::geometry::ray_box)'s.
pub(super) const SLACK: f32 = 1.000_000_4;

/// A code path of the node test.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Simd {
    /// Plain Rust, every target.
    Scalar,
    /// SSE2 (the x86_64 baseline): a node's eight boxes in two passes of four.
    Sse,
    /// AVX, detected at run time: a node's eight boxes in one pass, and the
    /// whole walk (leaf tests included) compiled for AVX (VEX encoding,
    /// the same IEEE operations; no FMA).
    Avx,
}

#[cfg(target_arch = "x86_64")]
static WITH_AVX: [Simd; 3] = [Simd::Scalar, Simd::Sse, Simd::Avx];

impl Simd {
    /// Every path this machine can run, scalar first.
    pub fn available() -> &'static [Simd] {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx") {
                &WITH_AVX
            } else {
                &WITH_AVX[..2]
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            &[Simd::Scalar]
        }
    }

    /// The best path this machine can run.
    pub fn best() -> Simd {
        *Simd::available().last().unwrap_or(&Simd::Scalar)
    }

    /// Parses a `TREVI_SIMD` value.
    pub fn parse(s: &str) -> Option<Simd> {
        match s {
            "scalar" => Some(Simd::Scalar),
            "sse" => Some(Simd::Sse),
            "avx" => Some(Simd::Avx),
            _ => None,
        }
    }

    fn code(self) -> u8 {
        match self {
            Simd::Scalar => 1,
            Simd::Sse => 2,
            Simd::Avx => 3,
        }
    }
}

/// 0: not chosen yet; otherwise [`Simd::code`].
static PATH: AtomicU8 = AtomicU8::new(0);

/// The environment variable that forces a path (`scalar`, `sse` or `avx`).
pub const SIMD_ENV: &str = "TREVI_SIMD";

/// The path every traversal of this process takes: the one forced by
/// [`force`], else by `TREVI_SIMD` (read once), else [`Simd::best`]. An
/// unknown value, or a path this machine cannot run, falls back to the best
/// one with a warning on stderr (the image is the same on every path).
#[inline]
pub fn current() -> Simd {
    match PATH.load(Ordering::Relaxed) {
        1 => Simd::Scalar,
        2 => Simd::Sse,
        3 => Simd::Avx,
        _ => init_from_env(),
    }
}

#[cold]
fn init_from_env() -> Simd {
    let chosen = match std::env::var(SIMD_ENV) {
        Ok(v) => match Simd::parse(&v) {
            Some(s) if Simd::available().contains(&s) => s,
            _ => {
                eprintln!(
                    "trevi: {SIMD_ENV}={v:?} is not one of {:?} on this machine; using {:?}",
                    Simd::available(),
                    Simd::best()
                );
                Simd::best()
            }
        },
        Err(_) => Simd::best(),
    };
    // A racing `force` wins; otherwise this choice sticks.
    let _ = PATH.compare_exchange(0, chosen.code(), Ordering::Relaxed, Ordering::Relaxed);
    current()
}

/// Forces the path for the rest of the process (tests and the bench);
/// false, and no change, if this machine cannot run it.
pub fn force(s: Simd) -> bool {
    if Simd::available().contains(&s) {
        PATH.store(s.code(), Ordering::Relaxed);
        true
    } else {
        false
    }
}

/// A ray as the node test needs it: origin, `1/dir`, and per axis which of
/// a node's two planes the ray meets first (index into [`Node::b`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct NodeRay {
    pub o: [f32; 3],
    pub inv: [f32; 3],
    pub near: [usize; 3],
    pub far: [usize; 3],
}

impl NodeRay {
    pub fn new(o: glam::Vec3, dir: glam::Vec3) -> NodeRay {
        let inv = dir.recip().to_array();
        let mut near = [0; 3];
        let mut far = [0; 3];
        for a in 0..3 {
            // Negative (−0 included: its inverse is −∞): the max plane first.
            let neg = usize::from(inv[a] < 0.0);
            near[a] = 2 * a + neg;
            far[a] = 2 * a + 1 - neg;
        }
        NodeRay {
            o: o.to_array(),
            inv,
            near,
            far,
        }
    }
}

/// `maxps`: `a > b ? a : b`.
#[inline(always)]
fn max_ps(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// `minps`: `a < b ? a : b`.
#[inline(always)]
fn min_ps(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

/// Entry distance of lane `i` of boxes `b` (laid out as [`Node::b`]) and
/// whether the ray enters it within `(0, t_max)`: the scalar path.
#[inline(always)]
pub(super) fn lane(b: &[[f32; WIDTH]; 6], r: &NodeRay, t_max: f32, i: usize) -> (f32, bool) {
    let n = |a: usize| (b[r.near[a]][i] - r.o[a]) * r.inv[a];
    let f = |a: usize| (b[r.far[a]][i] - r.o[a]) * r.inv[a];
    let enter = max_ps(n(0), max_ps(n(1), max_ps(n(2), 0.0)));
    let exit = min_ps(f(0), min_ps(f(1), min_ps(f(2), t_max)));
    (enter, enter <= exit * SLACK)
}

/// A node test: the entry distances of a node's [`WIDTH`] lanes and the
/// mask of boxes entered. One zero-sized type per path, so that the walk is
/// monomorphised for each (no dispatch per node).
pub(super) trait NodeTest: Copy {
    fn test(self, node: &Node, r: &NodeRay, t_max: f32) -> ([f32; WIDTH], u32);

    /// Runs `f` (a walk) compiled for this path's instruction set.
    #[inline(always)]
    fn region<R>(self, f: impl FnOnce() -> R) -> R {
        f()
    }
}

/// The scalar path: [`lane`] for each lane.
#[derive(Clone, Copy)]
pub(super) struct ScalarTest;

impl NodeTest for ScalarTest {
    #[inline(always)]
    fn test(self, node: &Node, r: &NodeRay, t_max: f32) -> ([f32; WIDTH], u32) {
        let mut enter = [0.0; WIDTH];
        let mut mask = 0;
        for (i, e) in enter.iter_mut().enumerate() {
            let (t, hit) = lane(&node.b, r, t_max, i);
            *e = t;
            mask |= u32::from(hit) << i;
        }
        (enter, mask)
    }
}

/// The SSE path: [`ScalarTest`]'s operations four lanes at a time.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
pub(super) struct SseTest;

#[cfg(target_arch = "x86_64")]
impl NodeTest for SseTest {
    #[inline(always)]
    fn test(self, node: &Node, r: &NodeRay, t_max: f32) -> ([f32; WIDTH], u32) {
        use std::arch::x86_64::*;
        let mut e = [0.0f32; WIDTH];
        let mut mask = 0;
        for k in (0..WIDTH).step_by(4) {
            // SAFETY: the only obligations are that SSE/SSE2 exist, which
            // the x86_64 baseline guarantees (this is compiled for x86_64
            // only), and that each unaligned load reads 16 valid bytes and
            // the store writes 16: each pointer is `&x[k..k + 4]` of an
            // `[f32; WIDTH]` (`node.b[plane]`, `e`), bounds-checked by the
            // slicing (`k + 4 ≤ WIDTH` as WIDTH is a multiple of 4). The
            // indices `r.near[a]`, `r.far[a]` are below 6 by construction
            // (`NodeRay::new`) and are bounds-checked anyway.
            unsafe {
                let slab = |a: usize, plane: usize| {
                    _mm_mul_ps(
                        _mm_sub_ps(
                            _mm_loadu_ps(node.b[plane][k..k + 4].as_ptr()),
                            _mm_set1_ps(r.o[a]),
                        ),
                        _mm_set1_ps(r.inv[a]),
                    )
                };
                let enter = _mm_max_ps(
                    slab(0, r.near[0]),
                    _mm_max_ps(
                        slab(1, r.near[1]),
                        _mm_max_ps(slab(2, r.near[2]), _mm_setzero_ps()),
                    ),
                );
                let exit = _mm_min_ps(
                    slab(0, r.far[0]),
                    _mm_min_ps(
                        slab(1, r.far[1]),
                        _mm_min_ps(slab(2, r.far[2]), _mm_set1_ps(t_max)),
                    ),
                );
                let m = _mm_movemask_ps(_mm_cmple_ps(enter, _mm_mul_ps(exit, _mm_set1_ps(SLACK))));
                mask |= (m as u32) << k;
                _mm_storeu_ps(e[k..k + 4].as_mut_ptr(), enter);
            }
        }
        (e, mask)
    }
}

/// The AVX path: [`ScalarTest`]'s operations eight lanes at a time. Only
/// [`AvxTest::new`] makes one, and only where AVX runs: holding one is the
/// proof that its `unsafe` calls may use AVX.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
pub(super) struct AvxTest(());

#[cfg(target_arch = "x86_64")]
impl AvxTest {
    /// The AVX test, if this machine runs AVX.
    #[inline(always)]
    pub fn new() -> Option<AvxTest> {
        std::arch::is_x86_feature_detected!("avx").then_some(AvxTest(()))
    }
}

/// [`ScalarTest`]'s operations on eight lanes in AVX registers.
///
/// # Safety
///
/// The machine runs AVX. Not a `#[target_feature]` function, which could
/// not be `#[inline(always)]`: inlined into [`avx_region`]'s walk, its
/// intrinsics are inlined there, where AVX is enabled.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn test_avx(node: &Node, r: &NodeRay, t_max: f32) -> ([f32; WIDTH], u32) {
    use std::arch::x86_64::*;
    const { assert!(WIDTH.is_multiple_of(8)) };
    let mut e = [0.0f32; WIDTH];
    let mut mask = 0;
    for k in (0..WIDTH).step_by(8) {
        // SAFETY: AVX runs (this function's precondition). Each unaligned
        // load reads 32 valid bytes and the store writes 32: each pointer is
        // `&x[k..k + 8]` of an `[f32; WIDTH]` (`node.b[plane]`, `e`),
        // bounds-checked by the slicing. The indices `r.near[a]`,
        // `r.far[a]` are below 6 by construction (`NodeRay::new`) and are
        // bounds-checked anyway.
        unsafe {
            let slab = |a: usize, plane: usize| {
                _mm256_mul_ps(
                    _mm256_sub_ps(
                        _mm256_loadu_ps(node.b[plane][k..k + 8].as_ptr()),
                        _mm256_set1_ps(r.o[a]),
                    ),
                    _mm256_set1_ps(r.inv[a]),
                )
            };
            let enter = _mm256_max_ps(
                slab(0, r.near[0]),
                _mm256_max_ps(
                    slab(1, r.near[1]),
                    _mm256_max_ps(slab(2, r.near[2]), _mm256_setzero_ps()),
                ),
            );
            let exit = _mm256_min_ps(
                slab(0, r.far[0]),
                _mm256_min_ps(
                    slab(1, r.far[1]),
                    _mm256_min_ps(slab(2, r.far[2]), _mm256_set1_ps(t_max)),
                ),
            );
            // `_CMP_LE_OS`: `cmpleps`'s predicate (false when either side
            // is NaN).
            let m = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OS>(
                enter,
                _mm256_mul_ps(exit, _mm256_set1_ps(SLACK)),
            ));
            mask |= (m as u32) << k;
            _mm256_storeu_ps(e[k..k + 8].as_mut_ptr(), enter);
        }
    }
    (e, mask)
}

/// Runs `f` in a function compiled for AVX, so that the walk `f` inlines
/// (node and leaf tests) uses it.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
#[inline]
fn avx_region<R>(f: impl FnOnce() -> R) -> R {
    f()
}

#[cfg(target_arch = "x86_64")]
impl NodeTest for AvxTest {
    #[inline(always)]
    fn test(self, node: &Node, r: &NodeRay, t_max: f32) -> ([f32; WIDTH], u32) {
        // SAFETY: `self` exists only where AVX runs (`AvxTest::new`).
        unsafe { test_avx(node, r, t_max) }
    }

    #[inline(always)]
    fn region<R>(self, f: impl FnOnce() -> R) -> R {
        // SAFETY: `self` exists only where AVX runs (`AvxTest::new`).
        unsafe { avx_region(f) }
    }
}

/// The four lanes of a leaf's triangle test ([`triangles_sse`]).
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
pub(super) struct Tri4 {
    pub t: [f32; 4],
    pub u: [f32; 4],
    pub v: [f32; 4],
    pub w: [f32; 4],
    pub inv: [f32; 4],
    /// Lanes whose determinant is positive (the front side).
    pub front: u32,
    /// Lanes hit within `(0, t_max)` (edge lanes excluded).
    pub hit: u32,
    /// Lanes where an edge function came out exactly zero: the scalar test
    /// decides them (it redoes the edge functions in f64).
    pub edge: u32,
}

#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
impl Tri4 {
    /// The hit of lane `i` of [`Tri4::hit`], as `triangle::intersect`
    /// makes it from the same numbers.
    #[inline(always)]
    pub fn hit_of(&self, i: usize) -> TriangleHit {
        let inv = self.inv[i];
        TriangleHit {
            t: self.t[i],
            bary: [self.u[i] * inv, self.v[i] * inv, self.w[i] * inv],
            front: self.front & (1 << i) != 0,
        }
    }
}

/// The watertight test of
/// [`triangle::intersect`](crate::geometry::triangle::intersect) on four triangles at once:
/// the `n` lanes of a leaf's copies `p` (laid out as `leaves.rs` describes:
/// `p[(3·v + axis)·n + lane]`; lanes past `n` are computed on whatever
/// floats follow and must be masked off), every lane against `t_max`. It
/// takes the slice, not `leaves::Leaf`, so that this module does not
/// depend on the one that calls it. Each
/// lane performs that function's f32 operations in its order (the origin
/// subtracted, the shear `x − s·z`, the edge functions `c·b − c·b`, the
/// determinant `(u + v) + w`, `t_scaled = (u·az + v·bz) + w·cz`, the early
/// out `t_scaled` against `(t_max·det)·(1 + 2⁻²⁰)` on the determinant's
/// side, `t = t_scaled · (1/det)`, then `0 < t < t_max`), with IEEE
/// `subps`/`mulps`/`addps`/`divps`, never fused, so a lane that is not
/// [`Tri4::edge`] is hit exactly when the scalar test hits it, with the same
/// bits. NaN compares false in both, lane by lane alike.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(super) fn triangles_sse(
    p: &[f32],
    n: usize,
    r: &crate::geometry::triangle::ShearedRay,
    t_max: f32,
) -> Tri4 {
    use crate::geometry::triangle::T_MARGIN;
    use std::arch::x86_64::*;
    // The loads below read `p[(3·v + k)·n ..][..4]` for `v, k < 3`: at most
    // up to `p[8·n + 3]`, which is below `9·n + 3` for `n ≥ 1`.
    assert!(n >= 1 && p.len() >= 9 * n + 3);
    // SAFETY: the obligations are that SSE/SSE2 exist, which the x86_64
    // baseline guarantees (this is compiled for x86_64 only), and that each
    // unaligned load reads 16 valid bytes and each store writes 16. Loads:
    // `k < 3` is checked by indexing `o[k]` before the load and `v < 3` at
    // every call, so the offset `(3·v + k)·n` is at most `8·n` and the four
    // floats from it end at `8·n + 3 < 9·n + 3 ≤ p.len()` (asserted above).
    // Stores: into the `[f32; 4]`s of `out`.
    unsafe {
        let o = r.origin.to_array();
        let ld = |v: usize, k: usize| {
            let ok = _mm_set1_ps(o[k]);
            _mm_sub_ps(_mm_loadu_ps(p.as_ptr().add((3 * v + k) * n)), ok)
        };
        let (sx, sy, sz) = (_mm_set1_ps(r.sx), _mm_set1_ps(r.sy), _mm_set1_ps(r.sz));
        let (kx, ky, kz) = (r.kx, r.ky, r.kz);
        let (a_z, b_z, c_z) = (ld(0, kz), ld(1, kz), ld(2, kz));
        let ax = _mm_sub_ps(ld(0, kx), _mm_mul_ps(sx, a_z));
        let ay = _mm_sub_ps(ld(0, ky), _mm_mul_ps(sy, a_z));
        let bx = _mm_sub_ps(ld(1, kx), _mm_mul_ps(sx, b_z));
        let by = _mm_sub_ps(ld(1, ky), _mm_mul_ps(sy, b_z));
        let cx = _mm_sub_ps(ld(2, kx), _mm_mul_ps(sx, c_z));
        let cy = _mm_sub_ps(ld(2, ky), _mm_mul_ps(sy, c_z));
        let u = _mm_sub_ps(_mm_mul_ps(cx, by), _mm_mul_ps(cy, bx));
        let v = _mm_sub_ps(_mm_mul_ps(ax, cy), _mm_mul_ps(ay, cx));
        let w = _mm_sub_ps(_mm_mul_ps(bx, ay), _mm_mul_ps(by, ax));
        let zero = _mm_setzero_ps();
        let edge = _mm_or_ps(
            _mm_or_ps(_mm_cmpeq_ps(u, zero), _mm_cmpeq_ps(v, zero)),
            _mm_cmpeq_ps(w, zero),
        );
        let neg = _mm_or_ps(
            _mm_or_ps(_mm_cmplt_ps(u, zero), _mm_cmplt_ps(v, zero)),
            _mm_cmplt_ps(w, zero),
        );
        let pos = _mm_or_ps(
            _mm_or_ps(_mm_cmpgt_ps(u, zero), _mm_cmpgt_ps(v, zero)),
            _mm_cmpgt_ps(w, zero),
        );
        let outside = _mm_and_ps(neg, pos);
        let det = _mm_add_ps(_mm_add_ps(u, v), w);
        // `det != 0 && det.is_finite()`: |det| < ∞ is false for NaN and ±∞.
        let abs = _mm_andnot_ps(_mm_set1_ps(-0.0), det);
        let det_ok = _mm_and_ps(
            _mm_cmpneq_ps(det, zero),
            _mm_cmplt_ps(abs, _mm_set1_ps(f32::INFINITY)),
        );
        let az = _mm_mul_ps(sz, a_z);
        let bz = _mm_mul_ps(sz, b_z);
        let cz = _mm_mul_ps(sz, c_z);
        let ts = _mm_add_ps(
            _mm_add_ps(_mm_mul_ps(u, az), _mm_mul_ps(v, bz)),
            _mm_mul_ps(w, cz),
        );
        let bound = _mm_mul_ps(_mm_mul_ps(_mm_set1_ps(t_max), det), _mm_set1_ps(T_MARGIN));
        let front = _mm_cmpgt_ps(det, zero);
        let early_pos = _mm_or_ps(_mm_cmple_ps(ts, zero), _mm_cmpgt_ps(ts, bound));
        let early_neg = _mm_or_ps(_mm_cmpge_ps(ts, zero), _mm_cmplt_ps(ts, bound));
        let early = _mm_or_ps(
            _mm_and_ps(front, early_pos),
            _mm_andnot_ps(front, early_neg),
        );
        let inv = _mm_div_ps(_mm_set1_ps(1.0), det);
        let t = _mm_mul_ps(ts, inv);
        let t_ok = _mm_and_ps(_mm_cmpgt_ps(t, zero), _mm_cmplt_ps(t, _mm_set1_ps(t_max)));
        let hit = _mm_andnot_ps(
            _mm_or_ps(_mm_or_ps(edge, outside), early),
            _mm_and_ps(det_ok, t_ok),
        );
        let mut out = Tri4 {
            t: [0.0; 4],
            u: [0.0; 4],
            v: [0.0; 4],
            w: [0.0; 4],
            inv: [0.0; 4],
            front: _mm_movemask_ps(front) as u32,
            hit: _mm_movemask_ps(hit) as u32,
            edge: _mm_movemask_ps(edge) as u32,
        };
        _mm_storeu_ps(out.t.as_mut_ptr(), t);
        _mm_storeu_ps(out.u.as_mut_ptr(), u);
        _mm_storeu_ps(out.v.as_mut_ptr(), v);
        _mm_storeu_ps(out.w.as_mut_ptr(), w);
        _mm_storeu_ps(out.inv.as_mut_ptr(), inv);
        out
    }
}

/// Depth of the traversal stack. A node pushes at most `WIDTH − 1`
/// children, so a tree of depth `d` needs at most `(WIDTH − 1)·d` slots; a walk that would need more
/// goes on recursively from the child it cannot push (tests use a shallow
/// stack so that this is exercised).
pub(super) const STACK: usize = if cfg!(test) { 5 } else { 96 };

/// The traversal stack of (child, its entry distance), left uninitialised:
/// zeroing it on every walk of every tree (twice per ray) was measurable.
pub(super) struct Stack {
    slots: [MaybeUninit<(Ref, f32)>; STACK],
    len: usize,
}

impl Stack {
    #[inline(always)]
    pub fn new() -> Stack {
        Stack {
            slots: [const { MaybeUninit::uninit() }; STACK],
            len: 0,
        }
    }

    /// Pushes, or returns false when full.
    #[inline(always)]
    pub fn push(&mut self, v: (Ref, f32)) -> bool {
        if self.len < STACK {
            // SAFETY: `len < STACK`, so the slot is in range.
            unsafe { *self.slots.get_unchecked_mut(self.len) = MaybeUninit::new(v) };
            self.len += 1;
            true
        } else {
            false
        }
    }

    #[inline(always)]
    pub fn pop(&mut self) -> Option<(Ref, f32)> {
        if self.len == 0 {
            return None;
        }
        self.len -= 1;
        // SAFETY: `len < STACK` (it was at most STACK and was decremented),
        // and every slot below the old `len` was written by `push` (slots
        // are only ever written at `len`, which then grows past them).
        Some(unsafe { self.slots.get_unchecked(self.len).assume_init() })
    }
}
