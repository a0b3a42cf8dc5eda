//! The output of a still requeued with a rectangle (`requeue ID --rect`):
//! [`Patch`], a [`TileSink`] that takes the tiles the rectangle touches as
//! they are rendered again, and the pixels of every other tile from the old
//! output, read back band by band of tiles ([`PngRows`]) as the new file is
//! written. The new file is written to a temporary file and renamed over
//! the old one only when complete (a failure leaves the old output); its
//! bytes are those of a render of the whole frame, as the writer's bytes
//! are a function of its 8-bit rows.
//!
//! Memory: a band of the old frame's rows (`tile × 3·width` bytes) while
//! it is handed over, and the rows the writer holds (see
//! [`FrameWriter`]): bands are read only once every band above them is
//! complete, so at most the band being completed and the one read, plus
//! the new tiles that came early (the scheduler hands them out in band
//! order).

use crate::sink::{SinkError, TileSink};
use std::path::Path;
use trevi_core::output::{segment_rows, PngRows, PngSegment};
use trevi_core::{FrameWriter, OutputError, Rect};

/// Which tiles of a frame are rendered again: those a rect touches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TileSpan {
    /// The tile edge.
    pub tile: u32,
    /// Columns `col0..col1` and rows `row0..row1` of tiles.
    pub col0: u32,
    pub col1: u32,
    pub row0: u32,
    pub row1: u32,
}

impl TileSpan {
    /// The tiles `rect` (inside the frame) touches, with tiles of `tile`.
    pub fn of(rect: Rect, tile: u32) -> TileSpan {
        let tile = tile.max(1);
        let end = |a: u32, n: u32| ((u64::from(a) + u64::from(n)).div_ceil(u64::from(tile))) as u32;
        TileSpan {
            tile,
            col0: rect.x / tile,
            col1: end(rect.x, rect.w),
            row0: rect.y / tile,
            row1: end(rect.y, rect.h),
        }
    }

    /// Whether tile `idx` of a frame `cols` tiles wide is rendered again.
    pub fn has(&self, idx: u32, cols: u32) -> bool {
        let (c, r) = (idx % cols, idx / cols);
        (self.col0..self.col1).contains(&c) && (self.row0..self.row1).contains(&r)
    }
}

/// See the module's doc.
pub struct Patch {
    writer: FrameWriter,
    old: PngRows,
    width: u32,
    height: u32,
    span: TileSpan,
    /// The next band of tiles whose old pixels are handed to the writer.
    next_band: u32,
    /// New pixels still to come, per band of tiles in `row0..row1`.
    missing: Vec<u64>,
}

impl Patch {
    /// A patch of the `width` × `height` PNG at `path` (read, and replaced
    /// when [`TileSink::finish`] succeeds) rendering again the tiles of
    /// `span`.
    pub fn open(path: &Path, width: u32, height: u32, span: TileSpan) -> Result<Patch, SinkError> {
        let old = PngRows::open(path, width, height)?;
        let writer = FrameWriter::create(path, width, height)?;
        let t = u64::from(span.tile);
        let x0 = u64::from(span.col0) * t;
        let x1 = (u64::from(span.col1) * t).min(u64::from(width));
        let missing = (span.row0..span.row1)
            .map(|r| {
                let y0 = u64::from(r) * t;
                let y1 = (y0 + t).min(u64::from(height));
                (x1 - x0) * (y1 - y0)
            })
            .collect();
        let mut patch = Patch {
            writer,
            old,
            width,
            height,
            span,
            next_band: 0,
            missing,
        };
        patch.feed()?;
        Ok(patch)
    }

    fn bands(&self) -> u32 {
        self.height.div_ceil(self.span.tile)
    }

    /// New pixels still missing in band `b`.
    fn missing(&self, b: u32) -> u64 {
        b.checked_sub(self.span.row0)
            .and_then(|i| self.missing.get(i as usize))
            .copied()
            .unwrap_or(0)
    }

    /// Counts `n` new pixels of band `b` come.
    fn came(&mut self, b: u32, n: u64) {
        if let Some(m) = b
            .checked_sub(self.span.row0)
            .and_then(|i| self.missing.get_mut(i as usize))
        {
            *m = m.saturating_sub(n);
        }
    }

    /// Hands the writer the old pixels of every band whose bands above are
    /// complete.
    fn feed(&mut self) -> Result<(), OutputError> {
        while self.next_band < self.bands()
            && (self.next_band == 0 || self.missing(self.next_band - 1) == 0)
        {
            let b = self.next_band;
            let t = self.span.tile;
            let y0 = b * t;
            let h = t.min(self.height - y0);
            let stride = 3 * self.width as usize;
            let mut band = Vec::with_capacity(stride * h as usize);
            for _ in 0..h {
                band.extend_from_slice(self.old.next_row()?);
            }
            let touched = (self.span.row0..self.span.row1).contains(&b);
            let (x0, x1) = if touched {
                let x1 = (u64::from(self.span.col1) * u64::from(t)).min(u64::from(self.width));
                (self.span.col0 * t, x1 as u32)
            } else {
                (self.width, self.width)
            };
            // The old pixels left and right of the new tiles (all of them
            // in a band the rect does not touch).
            for (a, z) in [(0, x0), (x1, self.width)] {
                if a == z {
                    continue;
                }
                let part: Vec<u8> = band
                    .chunks_exact(stride)
                    .flat_map(|row| &row[3 * a as usize..3 * z as usize])
                    .copied()
                    .collect();
                self.writer
                    .write_tile_srgb8(Rect::new(a, y0, z - a, h), &part)?;
            }
            self.next_band += 1;
        }
        Ok(())
    }
}

impl TileSink for Patch {
    fn write_tile(&mut self, rect: Rect, pixels: &[[f32; 3]]) -> Result<(), SinkError> {
        self.writer.write_tile(rect, pixels)?;
        self.came(rect.y / self.span.tile, rect.pixel_count() as u64);
        Ok(self.feed()?)
    }

    fn write_segment(&mut self, index: u32, segment: &PngSegment) -> Result<(), SinkError> {
        self.writer.write_segment(index, segment)?;
        let rows = segment_rows(self.height, index);
        let t = self.span.tile;
        for y in rows {
            self.came(y / t, u64::from(self.width));
        }
        Ok(self.feed()?)
    }

    fn finish(self: Box<Self>) -> Result<(), SinkError> {
        Ok(self.writer.finish()?)
    }

    fn rows_held(&self) -> usize {
        self.writer.rows_held()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pixels(rect: Rect, seed: u32) -> Vec<[f32; 3]> {
        (rect.y..rect.y + rect.h)
            .flat_map(|y| (rect.x..rect.x + rect.w).map(move |x| (x, y)))
            .map(|(x, y)| {
                let v = ((x * 5 + y * 11 + seed) % 89) as f32 / 88.0;
                [v, (v * 2.0) % 1.0, 1.0 - v]
            })
            .collect()
    }

    fn whole(path: &Path, w: u32, h: u32, seed: u32) {
        let mut f = FrameWriter::create(path, w, h).unwrap();
        let r = Rect::new(0, 0, w, h);
        f.write_tile(r, &pixels(r, seed)).unwrap();
        f.finish().unwrap();
    }

    #[test]
    fn a_patched_frame_is_the_bytes_of_a_whole_render() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h, t) = (70, 53, 16);
        let fresh = dir.path().join("fresh.png");
        whole(&fresh, w, h, 3);
        for (rect, reverse) in [
            (Rect::new(20, 18, 5, 3), false),
            (Rect::new(0, 0, 70, 53), true),
            (Rect::new(69, 52, 1, 1), true),
            (Rect::new(3, 40, 60, 13), false),
        ] {
            let out = dir.path().join("out.png");
            // The old output: other pixels (seed 4) where the tiles come
            // again, the fresh ones elsewhere.
            let span = TileSpan::of(rect, t);
            let cols = w.div_ceil(t);
            let mut mixed = FrameWriter::create(&out, w, h).unwrap();
            let total = cols * h.div_ceil(t);
            for idx in 0..total {
                let (c, r) = (idx % cols, idx / cols);
                let tr = Rect::new(c * t, r * t, t.min(w - c * t), t.min(h - r * t));
                let seed = if span.has(idx, cols) { 4 } else { 3 };
                mixed.write_tile(tr, &pixels_of(tr, w, h, seed)).unwrap();
            }
            mixed.finish().unwrap();
            let mut patch: Box<dyn TileSink> = Box::new(Patch::open(&out, w, h, span).unwrap());
            let mut news: Vec<Rect> = (0..total)
                .filter(|&i| span.has(i, cols))
                .map(|i| {
                    let (c, r) = (i % cols, i / cols);
                    Rect::new(c * t, r * t, t.min(w - c * t), t.min(h - r * t))
                })
                .collect();
            if reverse {
                news.reverse();
            }
            for tr in news {
                assert!(std::fs::read(&out).unwrap() != std::fs::read(&fresh).unwrap());
                patch.write_tile(tr, &pixels_of(tr, w, h, 3)).unwrap();
                assert!(patch.rows_held() <= (h as usize), "{}", patch.rows_held());
            }
            patch.finish().unwrap();
            assert_eq!(
                std::fs::read(&out).unwrap(),
                std::fs::read(&fresh).unwrap(),
                "{rect:?}"
            );
        }
    }

    /// The pixels of `rect` in a whole frame of `seed`.
    fn pixels_of(rect: Rect, w: u32, h: u32, seed: u32) -> Vec<[f32; 3]> {
        let all = pixels(Rect::new(0, 0, w, h), seed);
        (rect.y..rect.y + rect.h)
            .flat_map(|y| {
                let s = (y * w + rect.x) as usize;
                all[s..s + rect.w as usize].to_vec()
            })
            .collect()
    }

    #[test]
    fn an_unfinished_patch_leaves_the_old_file() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("o.png");
        whole(&out, 32, 32, 1);
        let before = std::fs::read(&out).unwrap();
        let span = TileSpan::of(Rect::new(0, 0, 1, 1), 16);
        let patch: Box<dyn TileSink> = Box::new(Patch::open(&out, 32, 32, span).unwrap());
        assert!(patch.finish().is_err(), "a tile is missing");
        assert_eq!(std::fs::read(&out).unwrap(), before);
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1, "no temporary file left");
        assert!(Patch::open(&dir.path().join("none.png"), 32, 32, span).is_err());
    }

    #[test]
    fn the_tiles_a_rect_touches() {
        let s = TileSpan::of(Rect::new(15, 16, 2, 1), 16);
        assert_eq!((s.col0, s.col1, s.row0, s.row1), (0, 2, 1, 2));
        assert!(s.has(4, 3) && s.has(3, 3) && !s.has(5, 3) && !s.has(0, 3));
        let s = TileSpan::of(Rect::new(u32::MAX - 1, 0, 1, 1), 64);
        assert_eq!(s.col1, (u32::MAX as u64).div_ceil(64) as u32);
    }
}
