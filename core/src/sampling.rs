//! Deterministic per-pixel sampling.
//!
//! The spec requires every random number for a pixel to be a pure function
//! of (seed, camera id, pixel column, pixel row, sample index, dimension).
//! Here a *stream* names a dimension pair (lens, one light's shadow rays at
//! one node of the ray tree, the hemisphere at one gather level, …) and an
//! *index* counts samples within the pixel. A stream is a 2D Sobol sequence
//! (0,2)-sequence with hash-based Owen scrambling (Burley, "Practical
//! Hash-based Owen Scrambling", JCGT 2020), scrambled differently per pixel
//! and stream: any power-of-two prefix of a pixel's samples is stratified in
//! both dimensions, and neighbouring pixels and streams are decorrelated.
//! [`SamplerKind::Independent`] gives plain white noise with the same
//! interface, kept for measuring what the low-discrepancy sequence buys.

use glam::Vec3;

/// Which point set a pixel's streams draw from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SamplerKind {
    /// Owen-scrambled Sobol (the default).
    #[default]
    Sobol,
    /// Independent uniform random numbers.
    Independent,
}

/// 64-bit finaliser (splitmix64): a bijective hash with good avalanche.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Combines a hash with another value.
#[inline]
pub fn hash2(a: u64, b: u64) -> u64 {
    mix64(a ^ mix64(b.wrapping_add(0x9e37_79b9_7f4a_7c15)))
}

/// FNV-1a of a string, then mixed: stable across platforms and runs.
pub fn hash_str(s: &str) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in s.bytes() {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    mix64(h)
}

/// The seed of one pixel of one camera.
pub fn pixel_seed(seed: u64, camera_hash: u64, x: u32, y: u32) -> u64 {
    hash2(hash2(seed, camera_hash), ((y as u64) << 32) | x as u64)
}

/// The sampler of one pixel.
#[derive(Debug, Clone, Copy)]
pub struct PixelSampler {
    /// The pixel's seed ([`pixel_seed`]): every stream is scrambled by it.
    pub seed: u64,
    /// Which point set the streams draw from.
    pub kind: SamplerKind,
}

impl PixelSampler {
    /// Point `index` of stream `stream`, in `[0,1)²`.
    #[inline]
    pub fn get2(&self, stream: u64, index: u32) -> [f32; 2] {
        self.stream(stream).get2(index)
    }

    /// Stream `stream` of this pixel, its hash taken once: a loop drawing
    /// many points of one stream (ambient occlusion, the diffuse gather,
    /// soft shadows) pays for it once instead of once a point. The same
    /// points as [`PixelSampler::get2`] and [`PixelSampler::get2_wide`].
    #[inline]
    pub fn stream(&self, stream: u64) -> Stream {
        let s = hash2(self.seed, stream);
        let s1 = (s >> 32) as u32;
        Stream {
            sampler: *self,
            stream,
            s,
            seed_x: hash32(s1, 0x68bc_21eb),
            seed_y: hash32(s1, 0x02e5_be93),
        }
    }
}

/// One stream of a pixel's sampler (see [`PixelSampler::stream`]).
#[derive(Debug, Clone, Copy)]
pub struct Stream {
    sampler: PixelSampler,
    stream: u64,
    /// `hash2(seed, stream)`: the index's scramble (low half), and the
    /// seed of the two dimensions' scrambles (high half), already hashed
    /// into `seed_x` and `seed_y`.
    s: u64,
    seed_x: u32,
    seed_y: u32,
}

impl Stream {
    /// Point `index` of the stream, in `[0,1)²`.
    #[inline]
    pub fn get2(&self, index: u32) -> [f32; 2] {
        let s = self.s;
        match self.sampler.kind {
            SamplerKind::Sobol => {
                let i = nested_uniform_scramble(index, s as u32);
                let x = nested_uniform_scramble(sobol_dim0(i), self.seed_x);
                let y = nested_uniform_scramble(sobol_dim1(i), self.seed_y);
                [to_unit(x), to_unit(y)]
            }
            SamplerKind::Independent => {
                let h = hash2(s, index as u64);
                [to_unit(h as u32), to_unit((h >> 32) as u32)]
            }
        }
    }
}

impl PixelSampler {
    /// Point `index` of stream `stream` for a 64-bit index: [`get2`]
    /// itself below 2³², and beyond, point `index mod 2³²` of a stream
    /// named after `(stream, index / 2³²)`. A pixel may draw more than 2³²
    /// points from one stream (`supersample²` × `shadow-samples` can pass
    /// it); a 32-bit index wrapped round and drew the same points again.
    ///
    /// [`get2`]: PixelSampler::get2
    #[inline]
    pub fn get2_wide(&self, stream: u64, index: u64) -> [f32; 2] {
        self.stream(stream).get2_wide(index)
    }
}

impl Stream {
    /// [`PixelSampler::get2_wide`] of this stream.
    #[inline]
    pub fn get2_wide(&self, index: u64) -> [f32; 2] {
        match u32::try_from(index) {
            Ok(i) => self.get2(i),
            Err(_) => self
                .sampler
                .get2(hash2(self.stream, index >> 32), index as u32),
        }
    }
}

#[inline]
fn hash32(a: u32, b: u32) -> u32 {
    (mix64(((a as u64) << 32) | b as u64) >> 16) as u32
}

/// Maps 32 random bits to `[0, 1)` exactly (24 bits of mantissa).
#[inline]
fn to_unit(x: u32) -> f32 {
    (x >> 8) as f32 * (1.0 / 16_777_216.0)
}

#[inline]
fn sobol_dim0(i: u32) -> u32 {
    i.reverse_bits()
}

/// Second Sobol dimension: the Pascal matrix over GF(2), whose column for
/// bit `j` of the index is `v_j` (`v_0 = 2³¹`, `v_{j+1} = v_j ^ (v_j >> 1)`),
/// so the result is the XOR of the columns of the index's set bits. The index
/// arrives scrambled (32 random bits), where a loop over the bits mispredicts
/// about every other one; the XOR is taken a byte at a time from
/// [`SOBOL1_BYTES`] instead, with the same result.
#[inline]
fn sobol_dim1(i: u32) -> u32 {
    let t = &SOBOL1_BYTES;
    t[0][(i & 0xff) as usize]
        ^ t[1][((i >> 8) & 0xff) as usize]
        ^ t[2][((i >> 16) & 0xff) as usize]
        ^ t[3][(i >> 24) as usize]
}

/// `SOBOL1_BYTES[k][b]`: the XOR of the Pascal-matrix columns `8k..8k+8`
/// selected by the bits of `b` (4 KiB, built at compile time).
static SOBOL1_BYTES: [[u32; 256]; 4] = sobol1_bytes();

const fn sobol1_bytes() -> [[u32; 256]; 4] {
    let mut columns = [0u32; 32];
    let mut v: u32 = 1 << 31;
    let mut j = 0;
    while j < 32 {
        columns[j] = v;
        v ^= v >> 1;
        j += 1;
    }
    let mut t = [[0u32; 256]; 4];
    let mut k = 0;
    while k < 4 {
        let mut b = 0;
        while b < 256 {
            let mut x = 0;
            let mut bit = 0;
            while bit < 8 {
                if b & (1 << bit) != 0 {
                    x ^= columns[8 * k + bit];
                }
                bit += 1;
            }
            t[k][b] = x;
            b += 1;
        }
        k += 1;
    }
    t
}

#[inline]
fn laine_karras_permutation(mut x: u32, seed: u32) -> u32 {
    x = x.wrapping_add(seed);
    x ^= x.wrapping_mul(0x6c50_b47c);
    x ^= x.wrapping_mul(0xb82f_1e52);
    x ^= x.wrapping_mul(0xc7af_e638);
    x ^= x.wrapping_mul(0x8d22_f6e6);
    x
}

/// Owen scrambling: each bit is flipped depending only on the bits above it.
#[inline]
fn nested_uniform_scramble(x: u32, seed: u32) -> u32 {
    laine_karras_permutation(x.reverse_bits(), seed).reverse_bits()
}

/// An orthonormal basis `(t, b)` completing unit `n` (Duff et al., "Building
/// an Orthonormal Basis, Revisited", JCGT 2017).
#[inline]
pub fn basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1.0f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// A cosine-distributed direction about unit `n` (density cos θ / π).
#[inline]
pub fn cosine_hemisphere(n: Vec3, u: [f32; 2]) -> Vec3 {
    let r = u[0].sqrt();
    // φ = 2π·u[1]: sine and cosine by polynomial, without libm.
    let (sin_phi, cos_phi) = crate::math::sin_cos_turns(u[1]);
    let (t, b) = basis(n);
    let z = (1.0 - u[0]).max(0.0).sqrt();
    // Unit without normalising: t, b, n are orthonormal and
    // r²·(cos² + sin²) + z² = u + (1 − u) = 1, up to a few roundings
    // (|d| within 10⁻⁶ of 1, `tests`).
    t * (r * cos_phi) + b * (r * sin_phi) + n * z
}

/// Maps the unit square onto the disk of radius 1 keeping strata compact
/// (Shirley and Chiu's concentric map).
#[inline]
pub fn concentric_disk(u: [f32; 2]) -> [f32; 2] {
    let a = 2.0 * u[0] - 1.0;
    let b = 2.0 * u[1] - 1.0;
    if a == 0.0 && b == 0.0 {
        return [0.0, 0.0];
    }
    let (r, phi) = if a.abs() > b.abs() {
        (a, std::f32::consts::FRAC_PI_4 * (b / a))
    } else {
        (
            b,
            std::f32::consts::FRAC_PI_2 - std::f32::consts::FRAC_PI_4 * (a / b),
        )
    };
    [r * crate::math::cosf(phi), r * crate::math::sinf(phi)]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Pascal-matrix generator as usually written, bit by bit.
    fn sobol_dim1_bitwise(mut i: u32) -> u32 {
        let mut v: u32 = 1 << 31;
        let mut x = 0;
        while i != 0 {
            if i & 1 != 0 {
                x ^= v;
            }
            i >>= 1;
            v ^= v >> 1;
        }
        x
    }

    #[test]
    fn the_byte_table_sobol_dimension_equals_the_bitwise_generator() {
        // Every index below 2^16, then scrambled-looking ones across all 32 bits.
        for i in 0..1u32 << 16 {
            assert_eq!(sobol_dim1(i), sobol_dim1_bitwise(i), "index {i}");
        }
        for k in 0..200_000u64 {
            let i = mix64(k) as u32;
            assert_eq!(sobol_dim1(i), sobol_dim1_bitwise(i), "index {i:#x}");
        }
        // Known values: the first points of the second dimension are 0, 1/2, 3/4, 1/4.
        let unit = |i| sobol_dim1(i) as f64 / 4294967296.0;
        assert_eq!([unit(0), unit(1), unit(2), unit(3)], [0.0, 0.5, 0.75, 0.25]);
    }

    #[test]
    fn sobol_prefixes_are_stratified_in_both_dimensions() {
        let s = PixelSampler {
            seed: 12345,
            kind: SamplerKind::Sobol,
        };
        for &n in &[4u32, 16, 64, 256] {
            let mut cols = vec![0; n as usize];
            let mut rows = vec![0; n as usize];
            for i in 0..n {
                let [x, y] = s.get2(7, i);
                cols[(x * n as f32) as usize] += 1;
                rows[(y * n as f32) as usize] += 1;
            }
            assert!(cols.iter().all(|&c| c == 1), "n={n} x strata {cols:?}");
            assert!(rows.iter().all(|&c| c == 1), "n={n} y strata");
        }
    }

    #[test]
    fn samples_are_pure_functions_of_their_coordinates_and_differ_between_pixels() {
        let a = PixelSampler {
            seed: pixel_seed(0, hash_str("main"), 3, 4),
            kind: SamplerKind::Sobol,
        };
        let b = PixelSampler {
            seed: pixel_seed(0, hash_str("main"), 4, 4),
            kind: SamplerKind::Sobol,
        };
        assert_eq!(a.get2(1, 5), a.get2(1, 5));
        assert_ne!(a.get2(1, 5), b.get2(1, 5));
        assert_ne!(a.get2(1, 5), a.get2(2, 5));
        let c = PixelSampler {
            seed: pixel_seed(0, hash_str("other"), 3, 4),
            kind: SamplerKind::Sobol,
        };
        assert_ne!(a.get2(1, 5), c.get2(1, 5));
    }

    /// A stream taken once draws the points `get2` drew with every hash
    /// taken per point, as first written (the reference below), for both
    /// kinds and across the 2³² boundary of the wide index.
    #[test]
    fn a_stream_taken_once_draws_the_same_points_as_get2_as_first_written() {
        let reference = |p: &PixelSampler, stream: u64, index: u32| {
            let s = hash2(p.seed, stream);
            match p.kind {
                SamplerKind::Sobol => {
                    let (s0, s1) = (s as u32, (s >> 32) as u32);
                    let i = nested_uniform_scramble(index, s0);
                    let x = nested_uniform_scramble(sobol_dim0(i), hash32(s1, 0x68bc_21eb));
                    let y = nested_uniform_scramble(sobol_dim1(i), hash32(s1, 0x02e5_be93));
                    [to_unit(x), to_unit(y)]
                }
                SamplerKind::Independent => {
                    let h = hash2(s, index as u64);
                    [to_unit(h as u32), to_unit((h >> 32) as u32)]
                }
            }
        };
        for kind in [SamplerKind::Sobol, SamplerKind::Independent] {
            for seed in [0u64, 7, 0xdead_beef_1234_5678] {
                let p = PixelSampler { seed, kind };
                for stream in [1u64, 2, mix64(99)] {
                    let st = p.stream(stream);
                    for i in (0..300u32).chain([u32::MAX - 1, u32::MAX]) {
                        let want = reference(&p, stream, i).map(f32::to_bits);
                        assert_eq!(st.get2(i).map(f32::to_bits), want);
                        assert_eq!(p.get2(stream, i).map(f32::to_bits), want);
                        assert_eq!(st.get2_wide(u64::from(i)).map(f32::to_bits), want);
                    }
                    let wide = (3u64 << 32) + 5;
                    assert_eq!(
                        st.get2_wide(wide).map(f32::to_bits),
                        reference(&p, hash2(stream, 3), 5).map(f32::to_bits)
                    );
                }
            }
        }
    }

    #[test]
    fn wide_indices_continue_the_stream_instead_of_wrapping() {
        let s = PixelSampler {
            seed: 99,
            kind: SamplerKind::Sobol,
        };
        for i in [0u32, 1, 77, u32::MAX] {
            assert_eq!(s.get2_wide(5, i as u64), s.get2(5, i));
        }
        // Past 2^32 the points are new, not index mod 2^32 again.
        for i in [0u64, 1, 77] {
            assert_ne!(s.get2_wide(5, (1 << 32) + i), s.get2(5, i as u32));
            assert_ne!(s.get2_wide(5, (2 << 32) + i), s.get2_wide(5, (1 << 32) + i));
        }
    }

    #[test]
    fn cosine_hemisphere_has_the_right_mean_cosine() {
        // E[cos θ] under density cos θ/π is 2/3.
        let s = PixelSampler {
            seed: 1,
            kind: SamplerKind::Sobol,
        };
        let n = Vec3::new(0.3, -0.5, 0.8).normalize();
        let m = 4096;
        let mean: f32 = (0..m)
            .map(|i| cosine_hemisphere(n, s.get2(0, i)).dot(n))
            .sum::<f32>()
            / m as f32;
        assert!((mean - 2.0 / 3.0).abs() < 1e-3, "{mean}");
        for i in 0..m {
            let d = cosine_hemisphere(n, s.get2(3, i));
            assert!(d.dot(n) >= 0.0);
            assert!((d.length() - 1.0).abs() < 1e-6, "{d}");
        }
    }

    #[test]
    fn basis_is_orthonormal_even_near_minus_z() {
        for n in [
            Vec3::Z,
            -Vec3::Z,
            Vec3::X,
            Vec3::new(0.0, 1e-7, -1.0).normalize(),
        ] {
            let (t, b) = basis(n);
            assert!(t.dot(b).abs() < 1e-5 && t.dot(n).abs() < 1e-5 && b.dot(n).abs() < 1e-5);
            assert!((t.length() - 1.0).abs() < 1e-5 && (b.length() - 1.0).abs() < 1e-5);
        }
    }

    #[test]
    fn concentric_disk_stays_in_the_unit_disk() {
        for i in 0..=10 {
            for j in 0..=10 {
                let [x, y] = concentric_disk([i as f32 / 10.0, j as f32 / 10.0]);
                assert!(x * x + y * y <= 1.0 + 1e-6);
            }
        }
    }
}
