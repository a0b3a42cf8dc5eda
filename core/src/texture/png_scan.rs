//! A PNG's chunks read before decoding, to bound what inflating it costs.
//!
//! The decoder inflates the whole of a PNG's image data, also what comes
//! after the last row (it reads it to discard it), and deflate expands up to
//! about 1032 times: a 16 × 16 PNG of 65 KB inflated 64 MiB, and a file of
//! the bundle's size could make a worker inflate hundreds of GB. Its IHDR
//! says how many bytes the image is once inflated (`raw`), and no encoder
//! needs much more compressed data than that (stored blocks add 5 bytes per
//! 64 KiB; fixed Huffman codes at most 1/8): so a file whose `IDAT` chunks
//! together hold more than [`max_idat_bytes`] of `raw` is refused, for the
//! cost of walking its chunk headers (one pass, no allocation).

/// The most compressed image data a PNG of `raw` inflated bytes may carry:
/// `raw + raw/8 + 4 KiB`.
pub fn max_idat_bytes(raw: u64) -> u64 {
    raw + raw / 8 + 4096
}

/// Why [`check`] refused a PNG.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PngScanError {
    /// The IDAT chunks hold more than [`max_idat_bytes`] of the image's
    /// inflated size.
    #[error("the PNG's image data (IDAT) is {idat} bytes, more than the {max} its {width} x {height} image can need compressed: inflating it would cost up to a thousand times that")]
    TooMuchData {
        /// The IDAT chunks' data, in bytes, all together.
        idat: u64,
        /// [`max_idat_bytes`] of the image's inflated size.
        max: u64,
        /// The image's width in pixels, from its IHDR.
        width: u32,
        /// Its height in pixels, from its IHDR.
        height: u32,
    },
}

/// The inflated size of a PNG image with this IHDR: per row a filter byte
/// and its pixels' bits rounded up to bytes (plus, interlaced, a filter
/// byte and a partial byte per row of each of the seven passes).
fn raw_bytes(width: u32, height: u32, depth: u8, colour: u8, interlaced: bool) -> u64 {
    let channels: u64 = match colour {
        2 => 3,
        4 => 2,
        6 => 4,
        _ => 1, // grey, palette
    };
    let bits = u64::from(width) * channels * u64::from(depth.max(1));
    let rows = u64::from(height);
    let raw = rows * (1 + bits.div_ceil(8));
    if interlaced {
        raw + 2 * 7 * rows
    } else {
        raw
    }
}

/// Walks the chunks of `b` (a PNG whose IHDR comes first) up to IEND or the
/// end of the bytes and refuses it if its `IDAT` chunks hold more than the
/// image can need. Malformed chunk structure is left to the decoder.
pub fn check(b: &[u8]) -> Result<(), PngScanError> {
    if b.len() < 33 || &b[12..16] != b"IHDR" {
        return Ok(());
    }
    let be = |i: usize| u32::from_be_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
    let (width, height) = (be(16), be(20));
    let raw = raw_bytes(width, height, b[24], b[25], b[28] != 0);
    let max = max_idat_bytes(raw);
    let mut idat = 0u64;
    let mut i = 8usize;
    while i + 8 <= b.len() {
        let len = u64::from(be(i));
        let kind = &b[i + 4..i + 8];
        if kind == b"IEND" {
            break;
        }
        if kind == b"IDAT" {
            idat += len;
            if idat > max {
                return Err(PngScanError::TooMuchData {
                    idat,
                    max,
                    width,
                    height,
                });
            }
        }
        // Length, type, data, CRC.
        let next = (i as u64).saturating_add(12).saturating_add(len);
        if next > b.len() as u64 {
            break;
        }
        i = next as usize;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_raw_size_counts_filter_bytes_and_packed_bits() {
        assert_eq!(raw_bytes(16, 16, 8, 0, false), 16 * 17);
        assert_eq!(raw_bytes(3, 2, 1, 3, false), 2 * 2);
        assert_eq!(raw_bytes(2, 2, 16, 6, false), 2 * 17);
        assert_eq!(raw_bytes(2, 2, 16, 6, true), 2 * 17 + 28);
    }
}
