//! PNG output: 8-bit sRGB RGB, made of independent 16-row segments.
//!
//! # The segmented layout
//!
//! The image is cut into segments of [`SEGMENT_ROWS`] full-width rows (the
//! last one shorter when the height is not a multiple). Each segment is
//! encoded alone by [`encode_segment`] (or [`encode_segment_srgb`]):
//!
//! 1. **Filters**, row by row, chosen adaptively: the filter whose output
//!    has the smallest sum of absolute values (bytes read as signed), ties to
//!    the lower filter type. A segment's first row chooses only between None
//!    and Sub, which do not read the row above, so no segment depends on
//!    another's pixels.
//! 2. **Deflate** of the segment's filtered bytes alone (a fresh dictionary:
//!    [`deflate`](super::deflate)), as one non-final block ended by a sync
//!    flush, so the bytes end on a byte boundary and any segments
//!    concatenate.
//! 3. Its **Adler-32** and the **length** of the filtered bytes.
//!
//! The file ([`PngStream`]) is the signature, IHDR, an sRGB chunk
//! (perceptual), then IDAT chunks: the zlib header with segment 0, then one
//! run of chunks per segment in order (a segment over [`IDAT_MAX`] bytes is
//! split at multiples of it), then a chunk with the final empty deflate
//! block and the stream's Adler-32 combined from the segments' with
//! [`adler32_combine`]; then IEND.
//!
//! The bytes are a pure function of the pixels: nothing depends on the tile
//! size, the order in which segments complete, the thread count or the
//! machine, and the compressor is this crate's own code. So a segment
//! encoded by a worker and one encoded by the coordinator or `trevi-submit`
//! are the same bytes, and so is the file they end up in.

use super::deflate::{
    adler32, adler32_combine, deflate_segment, FINAL_EMPTY_BLOCK, SYNC_FLUSH, ZLIB_HEADER,
};
use super::srgb::Srgb8;
use crate::error::OutputError;
use crate::tile::Rect;
use std::fs::File;
use std::io::{self, BufReader, BufWriter, Write};
use std::ops::Range;
use std::path::Path;

/// Names this encoder (segment rows, filter rule, compressor). A file's
/// bytes are a pure function of its pixels only while every segment of it
/// is encoded by the same encoder, so a coordinator takes encoded segments
/// only from workers that announce this same name. Change it whenever an
/// encoded byte could change.
pub const PNG_ENCODER: &str =
    "trevi-png-segments/1 (16 rows; None/Sub first row; fdeflate fast, sync flush)";

/// Rows in a PNG segment: the unit a PNG file is made of, whoever encodes it.
pub const SEGMENT_ROWS: u32 = 16;

/// The most bytes in one IDAT chunk. Part of the file layout, so fixed.
pub const IDAT_MAX: usize = 1 << 20;

const SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', b'\r', b'\n', 0x1a, b'\n'];

/// How many segments a `height`-row image has.
pub fn segment_count(height: u32) -> u32 {
    height.div_ceil(SEGMENT_ROWS)
}

/// The rows of segment `index` of a `height`-row image.
pub fn segment_rows(height: u32, index: u32) -> Range<u32> {
    let y0 = index.saturating_mul(SEGMENT_ROWS).min(height);
    y0..(y0.saturating_add(SEGMENT_ROWS)).min(height)
}

/// The filtered bytes of segment `index` of a `width` × `height` image:
/// its rows × (1 + 3 × width).
pub fn segment_filtered_len(width: u32, height: u32, index: u32) -> u64 {
    let rows = segment_rows(height, index);
    u64::from(rows.end - rows.start) * (1 + 3 * u64::from(width))
}

/// The most deflate bytes a segment of `filtered_len` filtered bytes may
/// take: 1.5 bytes a byte and 64 more. This encoder writes every byte in
/// at most 12 bits (its longest literal code; a run of zeros costs less),
/// after a 52-byte block header and before at most 7 bytes of end code and
/// sync flush; any deflate stream could also be sent as stored blocks, at
/// 5 bytes per 65,535, well under it. A segment above it is not this
/// encoder's, and is refused before its bytes are held.
pub fn max_segment_deflate_len(filtered_len: u64) -> u64 {
    filtered_len
        .saturating_add(filtered_len / 2)
        .saturating_add(64)
}

/// Why a segment's framing is not what segment `index` of an image must
/// have ([`check_segment`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SegmentError {
    /// The index is past the image's last segment.
    #[error("segment {index} is not one of the image's {count} segments")]
    NotInImage {
        /// The segment's index.
        index: u32,
        /// The image's number of segments ([`segment_count`]).
        count: u32,
    },
    /// The segment claims a filtered length other than its rows'.
    #[error("segment {index} holds {got} filtered bytes, not {expected}")]
    FilteredLen {
        /// The segment's index.
        index: u32,
        /// [`PngSegment::filtered_len`] as given.
        got: u64,
        /// Its rows' filtered length ([`segment_filtered_len`]).
        expected: u64,
    },
    /// More deflate bytes than this encoder can make of the rows.
    #[error(
        "segment {index} has {len} deflate bytes, more than the {most} its {filtered} \
         filtered bytes can take"
    )]
    TooLong {
        /// The segment's index.
        index: u32,
        /// Its deflate bytes' length.
        len: u64,
        /// [`max_segment_deflate_len`] of its filtered length.
        most: u64,
        /// Its filtered length.
        filtered: u64,
    },
    /// The deflate bytes do not end in `00 00 FF FF`, so the next segment
    /// cannot follow them.
    #[error("segment {index} does not end in a sync flush")]
    NoSyncFlush {
        /// The segment's index.
        index: u32,
    },
}

/// Checks the framing of `segment` as segment `index` of a `width` ×
/// `height` image, what can be checked without inflating it: the index is
/// one of the image's segments, the filtered length is its rows', the
/// deflate bytes are at most [`max_segment_deflate_len`] and end in a sync
/// flush. The error says what is wrong. (Whether the bytes inflate to
/// that many filtered bytes with that Adler-32, and the pixels are right,
/// it cannot tell.)
pub fn check_segment(
    width: u32,
    height: u32,
    index: u32,
    segment: &PngSegment,
) -> Result<(), SegmentError> {
    let count = segment_count(height);
    if index >= count {
        return Err(SegmentError::NotInImage { index, count });
    }
    let expected = segment_filtered_len(width, height, index);
    if segment.filtered_len != expected {
        return Err(SegmentError::FilteredLen {
            index,
            got: segment.filtered_len,
            expected,
        });
    }
    let most = max_segment_deflate_len(expected);
    if segment.deflate.len() as u64 > most {
        return Err(SegmentError::TooLong {
            index,
            len: segment.deflate.len() as u64,
            most,
            filtered: expected,
        });
    }
    if !segment.deflate.ends_with(&SYNC_FLUSH) {
        return Err(SegmentError::NoSyncFlush { index });
    }
    Ok(())
}

/// Why a rect of a frame is not whole segments of full-width rows
/// ([`whole_segments`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SegmentRectError {
    /// The rect's rows end below the frame's bottom.
    #[error("rows {y}..+{h} are not in the {width}x{height} frame")]
    OutsideFrame {
        /// The rect's first row.
        y: u32,
        /// The rect's height in rows.
        h: u32,
        /// The frame's width in pixels.
        width: u32,
        /// The frame's height in pixels.
        height: u32,
    },
    /// The rect does not span columns `0..width`.
    #[error("columns {x}..{end} are not the frame's full width {width}")]
    NotFullWidth {
        /// The rect's first column.
        x: u32,
        /// The column after its last.
        end: u32,
        /// The frame's width in pixels.
        width: u32,
    },
    /// The rect has no rows, or starts or ends inside a segment (other
    /// than at the frame's bottom).
    #[error("rows {y}..{end} are not whole {SEGMENT_ROWS}-row segments")]
    NotWholeSegments {
        /// The rect's first row.
        y: u32,
        /// The row after its last.
        end: u32,
    },
}

/// The segments `rect` of a `width` × `height` frame is, as (first, count),
/// when it is whole segments: full-width rows from a multiple of
/// [`SEGMENT_ROWS`] to a multiple of it or the frame's bottom, at least one
/// row. The one rule for what a lease of encoded segments may cover.
pub fn whole_segments(rect: Rect, width: u32, height: u32) -> Result<(u32, u32), SegmentRectError> {
    let Some(end) = rect.y.checked_add(rect.h).filter(|&e| e <= height) else {
        return Err(SegmentRectError::OutsideFrame {
            y: rect.y,
            h: rect.h,
            width,
            height,
        });
    };
    if rect.x != 0 || rect.w != width {
        return Err(SegmentRectError::NotFullWidth {
            x: rect.x,
            end: rect.x.saturating_add(rect.w),
            width,
        });
    }
    if rect.h == 0
        || !rect.y.is_multiple_of(SEGMENT_ROWS)
        || (!end.is_multiple_of(SEGMENT_ROWS) && end != height)
    {
        return Err(SegmentRectError::NotWholeSegments { y: rect.y, end });
    }
    let first = rect.y / SEGMENT_ROWS;
    Ok((first, end.div_ceil(SEGMENT_ROWS) - first))
}

/// One segment, encoded: a piece of the image's zlib stream and what is
/// needed to join it to the others.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PngSegment {
    /// Raw deflate bytes: one non-final block and a sync flush.
    pub deflate: Vec<u8>,
    /// The Adler-32 of the segment's filtered bytes.
    pub adler32: u32,
    /// The length of the segment's filtered bytes: rows × (1 + 3 × width).
    pub filtered_len: u64,
}

/// Encodes a segment from linear RGB pixels, `width` × rows of them row by
/// row, converted to 8-bit sRGB as [`linear_to_srgb8`](super::linear_to_srgb8)
/// does. `pixels.len()` must be a multiple of `width` (the rows); the
/// caller cuts the image into segments ([`segment_rows`]).
pub fn encode_segment(width: u32, pixels: &[[f32; 3]]) -> PngSegment {
    let srgb = Srgb8::new();
    let bytes: Vec<u8> = pixels
        .iter()
        .flat_map(|p| p.map(|c| srgb.encode(c)))
        .collect();
    let rows: Vec<&[u8]> = bytes.chunks_exact(3 * width.max(1) as usize).collect();
    encode_segment_srgb(width, &rows)
}

/// Encodes a segment from its rows of sRGB bytes (R G B per pixel,
/// `3 × width` bytes a row).
pub fn encode_segment_srgb<R: AsRef<[u8]>>(width: u32, rows: &[R]) -> PngSegment {
    let stride = 3 * width as usize;
    let mut filtered = Vec::with_capacity(rows.len() * (stride + 1));
    let mut scratch = [vec![0u8; stride], vec![0u8; stride]];
    let mut prev: Option<&[u8]> = None;
    for row in rows {
        let row = row.as_ref();
        debug_assert_eq!(row.len(), stride);
        filter_row(row, prev, &mut scratch, &mut filtered);
        prev = Some(row);
    }
    PngSegment {
        adler32: adler32(&filtered),
        filtered_len: filtered.len() as u64,
        deflate: deflate_segment(&filtered),
    }
}

/// The heuristic's cost of a filtered row: the sum of its bytes' absolute
/// values read as signed.
fn cost(bytes: &[u8]) -> u64 {
    let mut sum = 0u64;
    for chunk in bytes.chunks(32) {
        // At most 32 × 128: no overflow in u32, and the loop vectorises.
        let part: u32 = chunk
            .iter()
            .map(|&b| u32::from((b as i8).unsigned_abs()))
            .sum();
        sum += u64::from(part);
    }
    sum
}

/// The Paeth predictor (PNG specification 9.4), with the distances written
/// without the intermediate `p` so that it compiles to selects.
#[inline(always)]
fn paeth(a: u8, b: u8, c: u8) -> u8 {
    let (a16, b16, c16) = (i16::from(a), i16::from(b), i16::from(c));
    let pa = (b16 - c16).abs();
    let pb = (a16 - c16).abs();
    let pc = (a16 + b16 - 2 * c16).abs();
    if pa <= pb && pa <= pc {
        a
    } else if pb <= pc {
        b
    } else {
        c
    }
}

/// Bytes per pixel: 8-bit RGB.
const BPP: usize = 3;

/// Writes filter `kind` (1 Sub, 2 Up, 3 Average, 4 Paeth) of `row` into
/// `out`; `up` is the row above (only read by 2-4).
fn apply_filter(kind: u8, row: &[u8], up: &[u8], out: &mut [u8]) {
    let n = row.len();
    let head = BPP.min(n);
    // The first pixel has no left neighbour (a = c = 0).
    for i in 0..head {
        out[i] = row[i].wrapping_sub(match kind {
            1 => 0,
            2 | 4 => up[i],
            _ => up[i] >> 1,
        });
    }
    if n <= BPP {
        return;
    }
    let (cur, left) = (&row[BPP..], &row[..n - BPP]);
    let dst = &mut out[BPP..];
    match kind {
        1 => {
            for ((d, &x), &a) in dst.iter_mut().zip(cur).zip(left) {
                *d = x.wrapping_sub(a);
            }
        }
        2 => {
            for ((d, &x), &b) in out.iter_mut().zip(row).zip(up) {
                *d = x.wrapping_sub(b);
            }
        }
        3 => {
            for (((d, &x), &a), &b) in dst.iter_mut().zip(cur).zip(left).zip(&up[BPP..]) {
                *d = x.wrapping_sub(((u16::from(a) + u16::from(b)) >> 1) as u8);
            }
        }
        _ => {
            for ((((d, &x), &a), &b), &c) in dst
                .iter_mut()
                .zip(cur)
                .zip(left)
                .zip(&up[BPP..])
                .zip(&up[..n - BPP])
            {
                *d = x.wrapping_sub(paeth(a, b, c));
            }
        }
    }
}

/// Appends the filter type byte and the filtered `row` to `out`, choosing the
/// filter by [`cost`] (the first of None, Sub, Up, Average, Paeth with the
/// least); `prev` is the row above in the same segment (`None` for a
/// segment's first row: only None and Sub are tried).
fn filter_row(row: &[u8], prev: Option<&[u8]>, scratch: &mut [Vec<u8>; 2], out: &mut Vec<u8>) {
    let mut best_type = 0u8;
    let mut best_cost = cost(row);
    let [cand, best] = scratch;
    let kinds: &[u8] = if prev.is_some() { &[1, 2, 3, 4] } else { &[1] };
    for &kind in kinds {
        if best_cost == 0 {
            // Nothing can be strictly cheaper.
            break;
        }
        apply_filter(kind, row, prev.unwrap_or(&[]), cand);
        let c = cost(cand);
        if c < best_cost {
            best_cost = c;
            best_type = kind;
            std::mem::swap(cand, best);
        }
    }
    out.push(best_type);
    if best_type == 0 {
        out.extend_from_slice(row);
    } else {
        out.extend_from_slice(best);
    }
}

/// Writes a segmented PNG to `W`: [`PngStream::new`] writes the header,
/// [`PngStream::push`] each segment in order, [`PngStream::finish`] the end.
/// Holds nothing of the image.
pub struct PngStream<W: Write> {
    out: W,
    width: u32,
    height: u32,
    segments: u32,
    pushed: u32,
    adler: u32,
}

impl<W: Write> PngStream<W> {
    /// Writes the signature, IHDR (8-bit RGB) and the sRGB chunk of a
    /// `width` × `height` image (each 1 ..= 2³¹−1).
    pub fn new(mut out: W, width: u32, height: u32) -> io::Result<Self> {
        let limit = 1..=i32::MAX as u32;
        if !limit.contains(&width) || !limit.contains(&height) {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("a PNG cannot be {width}x{height}"),
            ));
        }
        out.write_all(&SIGNATURE)?;
        let mut ihdr = [0u8; 13];
        ihdr[..4].copy_from_slice(&width.to_be_bytes());
        ihdr[4..8].copy_from_slice(&height.to_be_bytes());
        // Bit depth 8, colour type 2 (RGB), deflate, adaptive filters, no
        // interlace.
        ihdr[8..].copy_from_slice(&[8, 2, 0, 0, 0]);
        write_chunk(&mut out, b"IHDR", &[&ihdr])?;
        write_chunk(&mut out, b"sRGB", &[&[0]])?;
        Ok(PngStream {
            out,
            width,
            height,
            segments: segment_count(height),
            pushed: 0,
            adler: 1,
        })
    }

    /// Appends the next segment (they come in order, top to bottom). A
    /// segment too many, one whose filtered length is not its rows' or whose
    /// bytes do not end in a sync flush is refused (`InvalidInput`) and
    /// nothing is written: the framing a segment made elsewhere must have.
    pub fn push(&mut self, segment: &PngSegment) -> io::Result<()> {
        if let Err(e) = check_segment(self.width, self.height, self.pushed, segment) {
            return Err(io::Error::new(io::ErrorKind::InvalidInput, e));
        }
        // The chunks cut `header ‖ deflate` every IDAT_MAX bytes.
        let header: &[u8] = if self.pushed == 0 { &ZLIB_HEADER } else { &[] };
        let body = &segment.deflate[..];
        let (h, total) = (header.len(), header.len() + body.len());
        let mut pos = 0;
        while pos < total {
            let end = (pos + IDAT_MAX).min(total);
            let parts = [
                &header[pos.min(h)..end.min(h)],
                &body[pos.max(h) - h..end.max(h) - h],
            ];
            write_chunk(&mut self.out, b"IDAT", &parts)?;
            pos = end;
        }
        self.adler = adler32_combine(self.adler, segment.adler32, segment.filtered_len);
        self.pushed += 1;
        Ok(())
    }

    /// Ends the zlib stream and the file, and returns the writer (not
    /// flushed). Fails if segments are missing.
    pub fn finish(mut self) -> io::Result<W> {
        if self.pushed != self.segments {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("{} of {} segments written", self.pushed, self.segments),
            ));
        }
        let adler = self.adler.to_be_bytes();
        write_chunk(&mut self.out, b"IDAT", &[&FINAL_EMPTY_BLOCK, &adler])?;
        write_chunk(&mut self.out, b"IEND", &[])?;
        Ok(self.out)
    }
}

/// Writes one chunk whose data is the concatenation of `parts`.
fn write_chunk<W: Write>(out: &mut W, kind: &[u8; 4], parts: &[&[u8]]) -> io::Result<()> {
    let len: usize = parts.iter().map(|p| p.len()).sum();
    let len = u32::try_from(len)
        .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "PNG chunk too long"))?;
    out.write_all(&len.to_be_bytes())?;
    out.write_all(kind)?;
    let mut crc = crc32fast::Hasher::new();
    crc.update(kind);
    for p in parts {
        out.write_all(p)?;
        crc.update(p);
    }
    out.write_all(&crc.finalize().to_be_bytes())
}

/// The file's bytes from all its segments in order: what the frame writer
/// writes when fed the same segments. Holds the whole file.
pub fn png_from_segments(width: u32, height: u32, segments: &[PngSegment]) -> io::Result<Vec<u8>> {
    let mut stream = PngStream::new(Vec::new(), width, height)?;
    for s in segments {
        stream.push(s)?;
    }
    stream.finish()
}

/// The PNG file of one frame being written: segments in, bytes out to the
/// file through a buffer.
pub(super) struct PngSink {
    stream: PngStream<BufWriter<File>>,
    path: String,
}

impl PngSink {
    /// Writes the PNG header to `file`; segments follow with
    /// [`PngSink::write_segment`].
    pub(super) fn new(
        file: File,
        width: u32,
        height: u32,
        path: &str,
    ) -> Result<Self, OutputError> {
        let stream = PngStream::new(BufWriter::with_capacity(IDAT_MAX, file), width, height)
            .map_err(|e| io_error(path, e))?;
        Ok(PngSink {
            stream,
            path: path.to_string(),
        })
    }

    /// Encodes and writes the next segment from its rows of sRGB bytes.
    pub(super) fn write_rows(&mut self, width: u32, rows: &[Vec<u8>]) -> Result<(), OutputError> {
        let segment = encode_segment_srgb(width, rows);
        self.write_segment(&segment)
    }

    /// Writes the next segment, already encoded.
    pub(super) fn write_segment(&mut self, segment: &PngSegment) -> Result<(), OutputError> {
        self.stream
            .push(segment)
            .map_err(|e| io_error(&self.path, e))
    }

    /// Ends the image and flushes it to the file. The caller fsyncs.
    pub(super) fn finish(self) -> Result<(), OutputError> {
        let PngSink { stream, path } = self;
        stream
            .finish()
            .and_then(|mut w| w.flush())
            .map_err(|e| io_error(&path, e))
    }
}

fn io_error(path: &str, source: io::Error) -> OutputError {
    OutputError::Io {
        path: path.to_string(),
        source,
    }
}

/// Reads a whole 8-bit RGB PNG into memory: `(width, height, pixels)`, row by
/// row. Any other PNG kind is an [`OutputError::Encode`] error.
///
/// For tests and tools only: it holds the entire image, which the farm's
/// writers never do.
pub fn read_png_rgb8(path: &Path) -> Result<(u32, u32, Vec<[u8; 3]>), OutputError> {
    let p = path.display().to_string();
    let decode_err = |e: ::png::DecodingError| match e {
        ::png::DecodingError::IoError(source) => OutputError::Io {
            path: p.clone(),
            source,
        },
        other => OutputError::Encode {
            path: p.clone(),
            message: other.to_string(),
        },
    };
    let file = File::open(path).map_err(|source| OutputError::Io {
        path: p.clone(),
        source,
    })?;
    let decoder =
        ::png::Decoder::new_with_limits(BufReader::new(file), ::png::Limits { bytes: usize::MAX });
    let mut reader = decoder.read_info().map_err(decode_err)?;
    let info = reader.info();
    let (width, height) = (info.width, info.height);
    if info.color_type != ::png::ColorType::Rgb || info.bit_depth != ::png::BitDepth::Eight {
        return Err(OutputError::Encode {
            path: p.clone(),
            message: format!(
                "expected an 8-bit RGB PNG, found {:?} {:?}",
                info.color_type, info.bit_depth
            ),
        });
    }
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| OutputError::Encode {
            path: p.clone(),
            message: format!("a {width}x{height} image does not fit in memory"),
        })?;
    let mut buf = vec![0; size];
    let frame = reader.next_frame(&mut buf).map_err(decode_err)?;
    let pixels = buf[..frame.buffer_size()]
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    Ok((width, height, pixels))
}

/// Decodes a whole 8-bit PNG held in memory, RGB like the frames this
/// module writes or RGBA like the coordinator's previews: `(width, height,
/// samples)`, the samples row by row as stored (3 or 4 a pixel).
///
/// For tests and tools only, like [`read_png_rgb8`].
pub fn decode_png(bytes: &[u8]) -> Result<(u32, u32, Vec<u8>), OutputError> {
    let what = || "a PNG in memory".to_string();
    let decode_err = |e: ::png::DecodingError| OutputError::Encode {
        path: what(),
        message: e.to_string(),
    };
    let mut reader = ::png::Decoder::new(io::Cursor::new(bytes))
        .read_info()
        .map_err(decode_err)?;
    let info = reader.info();
    if info.bit_depth != ::png::BitDepth::Eight {
        return Err(OutputError::Encode {
            path: what(),
            message: format!("expected an 8-bit PNG, found {:?}", info.bit_depth),
        });
    }
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| OutputError::Encode {
            path: what(),
            message: "the image does not fit in memory".into(),
        })?;
    let mut buf = vec![0; size];
    let frame = reader.next_frame(&mut buf).map_err(decode_err)?;
    buf.truncate(frame.buffer_size());
    Ok((frame.width, frame.height, buf))
}

#[cfg(test)]
mod tests {
    use super::super::{linear_to_srgb8, FrameWriter};
    use super::*;
    use crate::tile::{band_order_tiles, Rect};

    /// Deterministic test pixels in [-0.2, 1.3) with runs of flat colour, so
    /// that every filter wins somewhere.
    fn pixels(width: u32, height: u32, seed: u64) -> Vec<[f32; 3]> {
        let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        (0..height)
            .flat_map(|y| (0..width).map(move |x| (x, y)))
            .map(|(x, y)| {
                let smooth = (x + 2 * y) as f32 / (width + 2 * height) as f32;
                match (x / 5 + y / 3) % 4 {
                    0 => [0.25, 0.25, 0.25],
                    1 => [smooth, 0.5 * smooth, 1.0 - smooth],
                    _ => [
                        next() * 1.5 - 0.2,
                        next() * 1.5 - 0.2,
                        smooth + 0.1 * next(),
                    ],
                }
            })
            .collect()
    }

    /// Segments encoded one by one from the linear pixels.
    fn segments(width: u32, height: u32, px: &[[f32; 3]]) -> Vec<PngSegment> {
        (0..segment_count(height))
            .map(|i| {
                let r = segment_rows(height, i);
                let w = width as usize;
                encode_segment(width, &px[r.start as usize * w..r.end as usize * w])
            })
            .collect()
    }

    /// A segment's filtered bytes, by an independent inflater (the segment
    /// is not final: a final empty block ends it).
    fn inflate(seg: &PngSegment) -> Vec<u8> {
        let stream = [&seg.deflate[..], &super::super::deflate::FINAL_EMPTY_BLOCK].concat();
        miniz_oxide::inflate::decompress_to_vec(&stream).expect("raw deflate")
    }

    const SIZES: [(u32, u32); 8] = [
        (1, 1),
        (1, 40),
        (40, 1),
        (61, 29),
        (7, 33),
        (5, 16),
        (3, 17),
        (130, 48),
    ];

    #[test]
    fn decodes_to_the_srgb8_of_the_pixels() {
        for (i, &(w, h)) in SIZES.iter().enumerate() {
            let px = pixels(w, h, i as u64);
            let file = png_from_segments(w, h, &segments(w, h, &px)).unwrap();
            let (dw, dh, back) = decode_png(&file).unwrap();
            assert_eq!((dw, dh), (w, h));
            let expected: Vec<u8> = px.iter().flat_map(|p| p.map(linear_to_srgb8)).collect();
            assert_eq!(back, expected, "{w}x{h}");
            // And through the image crate, a second decoder's front end.
            let img = image::load_from_memory_with_format(&file, image::ImageFormat::Png)
                .unwrap()
                .into_rgb8();
            assert_eq!(img.into_raw(), expected, "{w}x{h} (image)");
        }
    }

    #[test]
    fn the_writer_makes_the_concatenated_segments_from_tiles_in_any_order() {
        let dir = tempfile::tempdir().unwrap();
        for (i, &(w, h)) in SIZES.iter().enumerate() {
            let px = pixels(w, h, 100 + i as u64);
            let expected = png_from_segments(w, h, &segments(w, h, &px)).unwrap();
            for (t, tile) in [1, 7, 16, 64].into_iter().enumerate() {
                let mut tiles = band_order_tiles(w, h, tile);
                if t % 2 == 1 {
                    tiles.reverse();
                }
                let path = dir.path().join(format!("f{i}-{tile}.png"));
                let mut writer = FrameWriter::create(&path, w, h).unwrap();
                for r in tiles {
                    let cut: Vec<[f32; 3]> = (r.y..r.y + r.h)
                        .flat_map(|y| {
                            let s = (y * w + r.x) as usize;
                            px[s..s + r.w as usize].to_vec()
                        })
                        .collect();
                    writer.write_tile(r, &cut).unwrap();
                }
                writer.finish().unwrap();
                assert!(
                    std::fs::read(&path).unwrap() == expected,
                    "{w}x{h}, {tile}-pixel tiles"
                );
            }
        }
        // A segment is the same bytes however its pixels were cut up.
        let (w, h) = (61, 29);
        let px = pixels(w, h, 7);
        let whole = Rect::new(0, 0, w, 16);
        let a = encode_segment(w, &px[..whole.pixel_count()]);
        let srgb: Vec<Vec<u8>> = px[..whole.pixel_count()]
            .chunks(w as usize)
            .map(|l| l.iter().flat_map(|p| p.map(linear_to_srgb8)).collect())
            .collect();
        assert_eq!(a, encode_segment_srgb(w, &srgb));
    }

    #[test]
    fn a_segment_is_its_filtered_rows_and_their_first_row_reads_nothing_above() {
        let (w, h) = (61, 29);
        let px = pixels(w, h, 11);
        let mut seen = [false; 5];
        for (i, seg) in segments(w, h, &px).iter().enumerate() {
            let rows = segment_rows(h, i as u32);
            let raw = inflate(seg);
            let stride = 1 + 3 * w as usize;
            assert_eq!(raw.len() as u64, seg.filtered_len);
            assert_eq!(raw.len(), rows.len() * stride);
            assert_eq!(adler32(&raw), seg.adler32);
            assert!(raw[0] <= 1, "segment {i} starts with filter {}", raw[0]);
            for r in raw.chunks(stride) {
                seen[r[0] as usize] = true;
            }
            // Ends with the sync flush, byte-aligned.
            assert!(seg.deflate.ends_with(&[0, 0, 0xff, 0xff]));
        }
        // Rows below a segment's first do use the filters that read above.
        assert!(seen[2] || seen[3] || seen[4], "filters used: {seen:?}");
    }

    #[test]
    fn filters_minimise_the_sum_of_absolute_values() {
        // Against a brute force over the five filters, applied by the
        // definitions of the PNG specification.
        let (w, h) = (23, 16);
        let px = pixels(w, h, 5);
        let seg = &segments(w, h, &px)[0];
        let raw = inflate(seg);
        let rows: Vec<Vec<u8>> = px
            .chunks(w as usize)
            .map(|l| l.iter().flat_map(|p| p.map(linear_to_srgb8)).collect())
            .collect();
        for (y, row) in rows.iter().enumerate() {
            let up = if y > 0 { Some(&rows[y - 1]) } else { None };
            let costs: Vec<u64> = (0..if up.is_some() { 5 } else { 2 })
                .map(|kind| {
                    (0..row.len())
                        .map(|i| {
                            let a = if i >= 3 { row[i - 3] as i32 } else { 0 };
                            let b = up.map_or(0, |u| u[i] as i32);
                            let c = if i >= 3 {
                                up.map_or(0, |u| u[i - 3] as i32)
                            } else {
                                0
                            };
                            let pred = match kind {
                                0 => 0,
                                1 => a,
                                2 => b,
                                3 => (a + b) / 2,
                                _ => {
                                    let p = a + b - c;
                                    let (pa, pb, pc) =
                                        ((p - a).abs(), (p - b).abs(), (p - c).abs());
                                    if pa <= pb && pa <= pc {
                                        a
                                    } else if pb <= pc {
                                        b
                                    } else {
                                        c
                                    }
                                }
                            };
                            ((row[i] as i32 - pred) as u8 as i8).unsigned_abs() as u64
                        })
                        .sum()
                })
                .collect();
            let best = costs
                .iter()
                .enumerate()
                .min_by_key(|&(k, c)| (*c, k))
                .unwrap()
                .0;
            assert_eq!(
                raw[y * (1 + 3 * w as usize)] as usize,
                best,
                "row {y}: {costs:?}"
            );
        }
    }

    #[test]
    fn a_segment_longer_than_a_chunk_is_split_and_still_decodes() {
        // Noise compresses to more than a byte a byte: 16 rows of 25,000
        // pixels are over a megabyte.
        let (w, h) = (25_000, 17);
        let mut s = 0x1234_5678_u32;
        let px: Vec<[f32; 3]> = (0..w * h)
            .map(|_| {
                let mut c = || {
                    s ^= s << 13;
                    s ^= s >> 17;
                    s ^= s << 5;
                    (s >> 8) as f32 / (1u32 << 24) as f32
                };
                [c(), c(), c()]
            })
            .collect();
        let segs = segments(w, h, &px);
        assert!(segs[0].deflate.len() > IDAT_MAX);
        let file = png_from_segments(w, h, &segs).unwrap();
        let idats = file.windows(4).filter(|k| k == b"IDAT").count();
        assert!(idats >= 4, "{idats} IDAT chunks");
        let (_, _, back) = decode_png(&file).unwrap();
        let expected: Vec<u8> = px.iter().flat_map(|p| p.map(linear_to_srgb8)).collect();
        assert!(back == expected);
    }

    #[test]
    fn a_wrong_number_of_segments_is_an_error_not_a_file() {
        let px = pixels(4, 20, 1);
        let segs = segments(4, 20, &px);
        assert!(png_from_segments(4, 20, &segs[..1]).is_err());
        let mut three = segs.clone();
        three.push(segs[1].clone());
        assert!(png_from_segments(4, 20, &three).is_err());
        // Framing: the last segment's length, and the sync flush.
        let mut short = segs.clone();
        short[1].filtered_len -= 1;
        assert!(png_from_segments(4, 20, &short).is_err());
        let mut cut = segs.clone();
        cut[0].deflate.pop();
        assert!(png_from_segments(4, 20, &cut).is_err());
        assert!(png_from_segments(4, 20, &segs).is_ok());
        assert!(PngStream::new(Vec::new(), 0, 5).is_err());
        assert!(PngStream::new(Vec::new(), 5, 1 << 31).is_err());
    }
}
