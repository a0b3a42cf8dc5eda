//! Raw deflate of one PNG segment, and the Adler-32 arithmetic that joins
//! segments into one zlib stream.
//!
//! The compressor is the algorithm of the `fdeflate` crate 0.3.7 (image-rs,
//! MIT OR Apache-2.0), which the `png` crate uses for its fast preset: one
//! dynamic Huffman block whose code table is fixed (tuned for filtered PNG
//! rows), literals, and runs of zero bytes as matches at distance 1. It is
//! copied here rather than called because a segment must end differently:
//! `fdeflate` marks its block final and appends the zlib trailer, while a
//! segment's block is not final and ends with a sync flush (an empty stored
//! block, which ends byte-aligned) so that segments compressed apart, by
//! any machine, concatenate into one valid stream. Copying it also pins the
//! bytes to this source: no crate update can change a file.
//!
//! Every match refers to the byte just before it within the same segment,
//! so a segment needs no dictionary from the one before.

/// The zlib stream header: deflate, 32 KiB window, no dictionary, "fastest"
/// (`0x78 0x01`, what `fdeflate` writes).
pub(super) const ZLIB_HEADER: [u8; 2] = [0x78, 0x01];

/// What a sync flush ends with: an empty stored block's LEN and NLEN.
pub const SYNC_FLUSH: [u8; 4] = [0x00, 0x00, 0xff, 0xff];

/// An empty final block (fixed Huffman codes, only the end-of-block code),
/// padded to the byte: what ends the stream after the last segment.
pub const FINAL_EMPTY_BLOCK: [u8; 2] = [0x03, 0x00];

/// The start of a dynamic Huffman block with `fdeflate`'s code table: the
/// 54-byte header of `fdeflate` without its two zlib bytes, of which the last
/// byte's low 5 bits are used. The first byte's bit 0 (BFINAL) is clear here
/// (`fdeflate` has `237`: its only block is the last).
const BLOCK_HEADER: [u8; 52] = [
    236, 192, 3, 160, 36, 89, 150, 198, 241, 255, 119, 238, 141, 200, 204, 167, 114, 75, 99, 174,
    109, 219, 182, 109, 219, 182, 109, 219, 182, 109, 105, 140, 158, 150, 74, 175, 158, 50, 51, 34,
    238, 249, 118, 183, 106, 122, 166, 135, 59, 107, 213, 15,
];
const BLOCK_HEADER_LAST_BITS: u8 = 5;

/// The code lengths of the literal/length alphabet that [`BLOCK_HEADER`]
/// declares (`fdeflate`'s `HUFFMAN_LENGTHS`).
const HUFFMAN_LENGTHS: [u8; 286] = [
    2, 3, 4, 5, 5, 6, 6, 7, 7, 7, 8, 8, 8, 8, 8, 9, 9, 9, 9, 9, 9, 9, 10, 10, 10, 10, 10, 10, 10,
    10, 10, 11, 11, 11, 11, 11, 11, 11, 11, 11, 11, 11, 11, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12,
    12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12,
    12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12,
    12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12,
    12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12,
    12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12,
    12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12,
    12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 11, 11, 11, 11, 11, 11, 11,
    11, 11, 11, 10, 11, 10, 10, 10, 10, 10, 10, 10, 10, 10, 9, 9, 9, 9, 9, 8, 9, 8, 8, 8, 8, 8, 7,
    7, 7, 6, 6, 6, 5, 4, 3, 12, 12, 12, 9, 9, 11, 10, 11, 11, 10, 11, 11, 11, 11, 11, 11, 12, 11,
    12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 9,
];

/// The canonical (bit-reversed, as deflate sends them) codes of
/// [`HUFFMAN_LENGTHS`].
const HUFFMAN_CODES: [u16; 286] = canonical_codes(&HUFFMAN_LENGTHS);

/// Canonical Huffman codes for `lengths` (RFC 1951 3.2.2), each bit-reversed
/// so that it can be written least significant bit first.
const fn canonical_codes(lengths: &[u8; 286]) -> [u16; 286] {
    let mut codes = [0u16; 286];
    let mut code = 0u32;
    let mut len = 1;
    while len <= 15 {
        let mut i = 0;
        while i < lengths.len() {
            if lengths[i] == len {
                codes[i] = (code as u16).reverse_bits() >> (16 - len);
                code += 1;
            }
            i += 1;
        }
        code <<= 1;
        len += 1;
    }
    assert!(code == 1 << 16, "the code lengths are not a complete code");
    codes
}

/// [`length_symbol`] of every match length 0..=258 (0..=2 unused).
const LENGTH_SYMBOLS: [(u16, u8, u16); 259] = {
    let mut t = [(0u16, 0u8, 0u16); 259];
    let mut len = 3;
    while len <= 258 {
        let (sym, extra, base) = length_symbol(len as u32);
        t[len] = (sym as u16, extra, base as u16);
        len += 1;
    }
    t
};

/// The length symbol (257..=285) of match lengths 3..=258, its number of
/// extra bits and its base length.
const fn length_symbol(len: u32) -> (usize, u8, u32) {
    // (symbol, extra bits, base length) per RFC 1951 3.2.5.
    const BASE: [u32; 29] = [
        3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 15, 17, 19, 23, 27, 31, 35, 43, 51, 59, 67, 83, 99, 115,
        131, 163, 195, 227, 258,
    ];
    const EXTRA: [u8; 29] = [
        0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4, 5, 5, 5, 5, 0,
    ];
    let mut i = 28;
    while BASE[i] > len {
        i -= 1;
    }
    (257 + i, EXTRA[i], BASE[i])
}

/// A raw deflate stream being written into a byte vector, bits least
/// significant first.
struct BitWriter {
    out: Vec<u8>,
    buffer: u64,
    nbits: u8,
}

impl BitWriter {
    #[inline(always)]
    fn write_bits(&mut self, bits: u64, nbits: u8) {
        debug_assert!(nbits <= 64);
        self.buffer |= bits << self.nbits;
        self.nbits += nbits;
        if self.nbits >= 64 {
            self.out.extend_from_slice(&self.buffer.to_le_bytes());
            self.nbits -= 64;
            self.buffer = bits.checked_shr(u32::from(nbits - self.nbits)).unwrap_or(0);
        }
    }

    /// Pads with zero bits to the next byte and writes out what is buffered.
    fn align(&mut self) {
        if !self.nbits.is_multiple_of(8) {
            self.write_bits(0, 8 - self.nbits % 8);
        }
        let bytes = usize::from(self.nbits / 8);
        self.out
            .extend_from_slice(&self.buffer.to_le_bytes()[..bytes]);
        self.buffer = 0;
        self.nbits = 0;
    }

    #[inline(always)]
    fn literal(&mut self, b: u8) {
        let s = usize::from(b);
        self.write_bits(u64::from(HUFFMAN_CODES[s]), HUFFMAN_LENGTHS[s]);
    }

    /// A run of `run` (≥ 1) zero bytes: a literal zero, then matches at
    /// distance 1 (distance code 0, one bit long in this table).
    fn zero_run(&mut self, mut run: u32) {
        self.literal(0);
        run -= 1;
        while run >= 258 {
            self.write_bits(u64::from(HUFFMAN_CODES[285]), HUFFMAN_LENGTHS[285] + 1);
            run -= 258;
        }
        if run > 4 {
            let (sym, extra_bits, base) = LENGTH_SYMBOLS[run as usize];
            let sym = usize::from(sym);
            self.write_bits(u64::from(HUFFMAN_CODES[sym]), HUFFMAN_LENGTHS[sym]);
            // The extra bits, then the one-bit distance code 0.
            self.write_bits(u64::from(run - u32::from(base)), extra_bits + 1);
        } else {
            // Zero's code is all zero bits: `run` more literal zeros.
            debug_assert_eq!(HUFFMAN_CODES[0], 0);
            self.write_bits(0, run as u8 * HUFFMAN_LENGTHS[0]);
        }
    }
}

/// Deflates `data` as one non-final dynamic block followed by a sync flush:
/// a piece of a raw deflate stream that starts and ends on a byte boundary
/// and refers to nothing before it. Deterministic: the bytes depend only on
/// `data`.
pub(super) fn deflate_segment(data: &[u8]) -> Vec<u8> {
    let mut w = BitWriter {
        out: Vec::with_capacity(data.len() / 2 + 64),
        buffer: 0,
        nbits: 0,
    };
    w.out
        .extend_from_slice(&BLOCK_HEADER[..BLOCK_HEADER.len() - 1]);
    w.write_bits(
        u64::from(BLOCK_HEADER[BLOCK_HEADER.len() - 1]),
        BLOCK_HEADER_LAST_BITS,
    );

    let mut run = 0u32;
    let mut chunks = data.chunks_exact(8);
    for chunk in &mut chunks {
        let word = u64::from_le_bytes(chunk.try_into().unwrap_or([0; 8]));
        if word == 0 {
            run += 8;
            continue;
        } else if run > 0 {
            let run_extra = word.trailing_zeros() / 8;
            w.zero_run(run + run_extra);
            run = 0;
            if run_extra > 0 {
                run = word.leading_zeros() / 8;
                for &b in &chunk[run_extra as usize..8 - run as usize] {
                    w.literal(b);
                }
                continue;
            }
        }
        let run_start = word.leading_zeros() / 8;
        if run_start > 0 {
            for &b in &chunk[..8 - run_start as usize] {
                w.literal(b);
            }
            run = run_start;
            continue;
        }
        // Eight literals in two writes of four.
        for quad in chunk.chunks_exact(4) {
            let mut bits = 0u64;
            let mut n = 0u8;
            for &b in quad {
                let s = usize::from(b);
                bits |= u64::from(HUFFMAN_CODES[s]) << n;
                n += HUFFMAN_LENGTHS[s];
            }
            w.write_bits(bits, n);
        }
    }
    if run > 0 {
        w.zero_run(run);
    }
    for &b in chunks.remainder() {
        w.literal(b);
    }
    // End of block, then the sync flush: an empty stored block (BFINAL 0,
    // BTYPE 00, three zero bits), zero bits to the byte, LEN 0 and NLEN.
    w.write_bits(u64::from(HUFFMAN_CODES[256]), HUFFMAN_LENGTHS[256]);
    w.write_bits(0, 3);
    w.align();
    w.out.extend_from_slice(&SYNC_FLUSH);
    w.out
}

/// The Adler-32 modulus.
const ADLER_BASE: u64 = 65521;

/// The Adler-32 of `data`.
pub fn adler32(data: &[u8]) -> u32 {
    let mut a = simd_adler32::Adler32::new();
    a.write(data);
    a.finish()
}

/// The Adler-32 of the concatenation `A ‖ B` from `adler_a` = Adler-32(A),
/// `adler_b` = Adler-32(B) and `len_b` = B's length: zlib's
/// `adler32_combine`, in constant time. The Adler-32 of nothing is 1.
pub fn adler32_combine(adler_a: u32, adler_b: u32, len_b: u64) -> u32 {
    let rem = len_b % ADLER_BASE;
    let a1 = u64::from(adler_a & 0xffff);
    let a2 = u64::from(adler_a >> 16);
    let b1 = u64::from(adler_b & 0xffff);
    let b2 = u64::from(adler_b >> 16);
    // sum1 = a1 + b1 - 1, sum2 = a2 + b2 + rem·(a1 - 1), all mod BASE
    // (B's running sum2 counted each of its bytes once per byte after it; A's
    // sum1 adds `len_b` more times, and the initial 1 of B's sum1 is
    // dropped).
    let sum1 = (a1 + b1 + ADLER_BASE - 1) % ADLER_BASE;
    let sum2 = (a2 + b2 + rem * a1 % ADLER_BASE + ADLER_BASE - rem) % ADLER_BASE;
    (sum1 | (sum2 << 16)) as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Adler-32 straight from its definition (RFC 1950 8.2).
    fn adler32_by_definition(data: &[u8]) -> u32 {
        let (mut a, mut b) = (1u64, 0u64);
        for &x in data {
            a = (a + u64::from(x)) % ADLER_BASE;
            b = (b + a) % ADLER_BASE;
        }
        (a | (b << 16)) as u32
    }

    fn bytes(n: usize, seed: u32) -> Vec<u8> {
        let mut s = seed.wrapping_mul(2654435761).wrapping_add(1);
        (0..n)
            .map(|i| {
                s ^= s << 13;
                s ^= s >> 17;
                s ^= s << 5;
                // Plenty of zeros and small values, like filtered rows.
                if i % 7 < 3 {
                    0
                } else {
                    (s % 5) as u8 * if s & 64 != 0 { 1 } else { 51 }
                }
            })
            .collect()
    }

    #[test]
    fn adler32_matches_its_definition() {
        for (n, seed) in [(0, 1), (1, 2), (5551, 3), (5552, 4), (70_000, 5)] {
            let d = bytes(n, seed);
            assert_eq!(adler32(&d), adler32_by_definition(&d), "{n} bytes");
        }
        // All 0xff bytes: the sums reach the modulus fastest.
        let ff = vec![0xff; 100_000];
        assert_eq!(adler32(&ff), adler32_by_definition(&ff));
    }

    #[test]
    fn adler32_combine_equals_the_adler32_of_the_concatenation() {
        let data = bytes(200_000, 9);
        let ff = vec![0xffu8; 140_000];
        for d in [&data[..], &ff[..]] {
            for split in [0, 1, 7, 5552, 65521, 65522, 131_042, d.len() - 1, d.len()] {
                let (a, b) = d.split_at(split);
                assert_eq!(
                    adler32_combine(adler32(a), adler32(b), b.len() as u64),
                    adler32_by_definition(d),
                    "split at {split}"
                );
            }
        }
        // Many pieces folded left, as the writer does.
        let mut acc = 1;
        for piece in data.chunks(3001) {
            acc = adler32_combine(acc, adler32(piece), piece.len() as u64);
        }
        assert_eq!(acc, adler32_by_definition(&data));
    }

    #[test]
    fn length_symbols_follow_rfc_1951() {
        assert_eq!(length_symbol(3), (257, 0, 3));
        assert_eq!(length_symbol(10), (264, 0, 10));
        assert_eq!(length_symbol(11), (265, 1, 11));
        assert_eq!(length_symbol(12), (265, 1, 11));
        assert_eq!(length_symbol(257), (284, 5, 227));
        assert_eq!(length_symbol(258), (285, 0, 258));
        for len in 3..=258u32 {
            let (sym, extra, base) = LENGTH_SYMBOLS[len as usize];
            assert_eq!(
                (usize::from(sym), extra, u32::from(base)),
                length_symbol(len)
            );
            assert!(len - u32::from(base) < 1 << extra || (len == 258 && extra == 0));
        }
    }

    /// A zlib stream of the given segments, as the PNG writer makes it.
    fn zlib_of(segments: &[&[u8]]) -> Vec<u8> {
        let mut z = ZLIB_HEADER.to_vec();
        let mut adler = 1;
        for s in segments {
            z.extend(deflate_segment(s));
            adler = adler32_combine(adler, adler32(s), s.len() as u64);
        }
        z.extend_from_slice(&FINAL_EMPTY_BLOCK);
        z.extend_from_slice(&adler.to_be_bytes());
        z
    }

    #[test]
    fn segments_inflate_back_to_their_data_apart_and_joined() {
        let pieces: Vec<Vec<u8>> = [
            (0, 1),
            (1, 2),
            (7, 3),
            (8, 4),
            (300, 5),
            (1000, 0),
            (70_000, 6),
        ]
        .iter()
        .map(|&(n, s)| if s == 0 { vec![0; n] } else { bytes(n, s) })
        .collect();
        let mut all = Vec::new();
        for p in &pieces {
            // Each alone, checked by an independent inflater.
            let z = zlib_of(&[p]);
            let back = miniz_oxide::inflate::decompress_to_vec_zlib(&z).expect("valid zlib");
            assert_eq!(&back, p);
            all.extend_from_slice(p);
        }
        let refs: Vec<&[u8]> = pieces.iter().map(Vec::as_slice).collect();
        let z = zlib_of(&refs);
        let back = miniz_oxide::inflate::decompress_to_vec_zlib(&z).expect("valid zlib");
        assert_eq!(back, all);
    }

    #[test]
    fn every_byte_value_and_long_zero_runs_survive() {
        let mut d: Vec<u8> = (0..=255).collect();
        d.extend(std::iter::repeat_n(0, 258 * 3 + 5));
        d.extend((0..=255).rev());
        for run in [1, 2, 3, 4, 5, 6, 257, 258, 259, 260, 263, 516, 517] {
            d.push(9);
            d.extend(std::iter::repeat_n(0, run));
        }
        let z = zlib_of(&[&d]);
        assert_eq!(
            miniz_oxide::inflate::decompress_to_vec_zlib(&z).expect("valid zlib"),
            d
        );
    }
}
