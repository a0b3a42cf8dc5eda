//! A lease's pixels as encoded PNG segments (`Lease.png_segments`).
//!
//! When the coordinator asks for segments, the lease's `rect` is full-width
//! rows from a multiple of [`SEGMENT_ROWS`] to a multiple of it or the
//! frame's bottom. The worker then does what the coordinator did with the
//! floats: it checks them ([`check_pixels`]: finite, not negative; a bad
//! pixel fails the lease), encodes each 16-row segment of the rect with
//! [`encode_segment`] (the same encoder as the coordinator's and
//! `trevi-submit`'s `FrameWriter`, so the file's bytes do not depend on who
//! encoded which segment), and sums the pixels for the monitor's preview
//! ([`preview_sums`]). [`encode_rect`] does all three;
//! `crate::upload::segment_messages` makes the upload.
//!
//! Memory: the rect's floats (held already), one segment's sRGB and
//! filtered bytes per render thread while it is encoded, the encoded
//! segments (smaller than the floats), and the preview sums (12 bytes a
//! cell).

use rayon::prelude::*;
use trevi_core::output::{encode_segment, whole_segments, SEGMENT_ROWS};
use trevi_core::Rect;
use trevi_proto::pb;

/// A pixel whose value is not finite and non-negative: the render is wrong,
/// and the lease is given back with this as its error.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("pixel ({x}, {y}) is ({}, {}, {}): not finite and non-negative", .value[0], .value[1], .value[2])]
pub struct BadPixel {
    /// Frame coordinates: the column.
    pub x: u32,
    /// Frame coordinates: the row.
    pub y: u32,
    /// The pixel's linear R, G, B as rendered.
    pub value: [f32; 3],
}

/// Why a lease's pixels cannot be uploaded as segments.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SegmentError {
    /// A pixel is not finite and non-negative (the first, row by row).
    #[error(transparent)]
    BadPixel(#[from] BadPixel),
    /// The coordinator broke the contract: the rect is not whole segments
    /// of full-width rows.
    #[error(
        "a segment lease's rect {}x{} at ({}, {}) is not full-width rows of a {width}x{height} frame \
         from a multiple of {SEGMENT_ROWS} to a multiple of it or the bottom",
        .rect.w, .rect.h, .rect.x, .rect.y
    )]
    NotSegments {
        /// The lease's rect.
        rect: Rect,
        /// The frame's width in pixels.
        width: u32,
        /// The frame's height in pixels.
        height: u32,
    },
    /// The coordinator sent a segment lease without a preview cell size.
    #[error("a segment lease with preview_scale 0")]
    NoPreviewScale,
    /// The render gave a different number of pixels than the rect holds.
    #[error("{got} pixels for a rect of {want}")]
    PixelCount {
        /// Pixels the render gave.
        got: usize,
        /// Pixels in the rect.
        want: usize,
    },
}

/// A lease's upload on the segment path: its segments in order, and its
/// preview sums.
#[derive(Debug, Clone, PartialEq)]
pub struct EncodedRect {
    /// The rect's rows as PNG segments of [`SEGMENT_ROWS`] rows (the last
    /// may be shorter at the frame's bottom), top to bottom.
    pub segments: Vec<pb::EncodedSegment>,
    /// Three floats a preview cell (see [`preview_sums`]).
    pub preview: Vec<f32>,
}

/// The first pixel of `rect` (row by row) that is not finite and
/// non-negative in every channel, as an error.
pub fn check_pixels(rect: Rect, pixels: &[[f32; 3]]) -> Result<(), BadPixel> {
    match trevi_core::tile::first_invalid_pixel(pixels) {
        None => Ok(()),
        Some(i) => {
            let w = rect.w.max(1) as usize;
            Err(BadPixel {
                x: rect.x + (i % w) as u32,
                y: rect.y + (i / w) as u32,
                value: pixels[i],
            })
        }
    }
}

/// The preview's box sums of `rect`'s pixels (row by row), as the proto's
/// `PreviewSums` says: the frame is cut into `scale`-pixel square cells from
/// (0, 0); for every cell the rect overlaps, row-major, the sums of the
/// linear R, G, B values of the rect's pixels in that cell. Summed in f64,
/// rounded to f32 once. `scale` must be at least 1 and `pixels` hold the
/// rect's pixels.
pub fn preview_sums(rect: Rect, scale: u32, pixels: &[[f32; 3]]) -> Vec<f32> {
    debug_assert!(scale >= 1);
    debug_assert_eq!(pixels.len(), rect.pixel_count());
    if rect.w == 0 || rect.h == 0 {
        return Vec::new();
    }
    let s = scale.max(1);
    let (c0, c1) = (rect.x / s, (rect.x + rect.w - 1) / s);
    let (r0, r1) = (rect.y / s, (rect.y + rect.h - 1) / s);
    let cols = (c1 - c0 + 1) as usize;
    let mut out = Vec::with_capacity(3 * cols * (r1 - r0 + 1) as usize);
    // One cell row at a time.
    let mut row = vec![[0f64; 3]; cols];
    let w = rect.w as usize;
    for cr in r0..=r1 {
        let y0 = (cr * s).max(rect.y);
        let y1 = (cr.saturating_add(1).saturating_mul(s)).min(rect.y + rect.h);
        row.fill([0.0; 3]);
        for y in y0..y1 {
            let line = &pixels[(y - rect.y) as usize * w..][..w];
            for (i, p) in line.iter().enumerate() {
                let cell = &mut row[((rect.x + i as u32) / s - c0) as usize];
                for (acc, &c) in cell.iter_mut().zip(p) {
                    *acc += f64::from(c);
                }
            }
        }
        out.extend(row.iter().flat_map(|c| c.map(|v| v as f32)));
    }
    out
}

/// Checks `pixels` (the lease's `rect` of a `width`×`height` frame, row by
/// row), encodes the rect's segments, in parallel on the current rayon
/// pool, and sums its preview cells of `scale` pixels.
pub fn encode_rect(
    rect: Rect,
    width: u32,
    height: u32,
    scale: u32,
    pixels: &[[f32; 3]],
) -> Result<EncodedRect, SegmentError> {
    // Full-width rows from a multiple of SEGMENT_ROWS to a multiple of it
    // or the frame's bottom: core's one rule for whole segments.
    if width == 0 || whole_segments(rect, width, height).is_err() {
        return Err(SegmentError::NotSegments {
            rect,
            width,
            height,
        });
    }
    if scale == 0 {
        return Err(SegmentError::NoPreviewScale);
    }
    if pixels.len() != rect.pixel_count() {
        return Err(SegmentError::PixelCount {
            got: pixels.len(),
            want: rect.pixel_count(),
        });
    }
    check_pixels(rect, pixels)?;
    let first = rect.y / SEGMENT_ROWS;
    let per_segment = SEGMENT_ROWS as usize * rect.w as usize;
    let segments = pixels
        .par_chunks(per_segment)
        .enumerate()
        .map(|(i, px)| {
            let s = encode_segment(rect.w, px);
            pb::EncodedSegment {
                index: first + i as u32,
                deflate: s.deflate,
                adler32: s.adler32,
                filtered_len: s.filtered_len,
            }
        })
        .collect();
    Ok(EncodedRect {
        segments,
        preview: preview_sums(rect, scale, pixels),
    })
}

#[cfg(test)]
mod tests;
