//! Patching a PNG frame this module wrote: its rows read back one by one
//! ([`PngRows`]) and written again as they are
//! ([`FrameWriter::write_tile_srgb8`]) beside tiles rendered anew. The file
//! is then the bytes a render of the whole frame gives: the writer's bytes
//! are a function of its 8-bit sRGB rows, and the rows read back are those
//! the old render's float pixels became.

use super::{Encoder, FrameWriter, OutputError};
use crate::tile::Rect;
use std::fs::File;
use std::io::BufReader;
use std::path::Path;

/// An 8-bit RGB PNG read row by row, top to bottom: only one row is held
/// (and the decoder's state), whatever the frame's size.
pub struct PngRows {
    reader: ::png::Reader<BufReader<File>>,
    path: String,
    next: u32,
    height: u32,
}

impl PngRows {
    /// Opens `path`, which must be a non-interlaced 8-bit RGB PNG of
    /// `width` × `height` pixels (what a [`FrameWriter`] writes), or an
    /// [`OutputError`] saying what it is instead.
    pub fn open(path: &Path, width: u32, height: u32) -> Result<PngRows, OutputError> {
        let p = path.display().to_string();
        let file = File::open(path).map_err(|source| OutputError::Io {
            path: p.clone(),
            source,
        })?;
        let bad = |message: String| OutputError::Encode {
            path: p.clone(),
            message,
        };
        let reader = ::png::Decoder::new(BufReader::new(file))
            .read_info()
            .map_err(|e| bad(e.to_string()))?;
        let info = reader.info();
        if info.color_type != ::png::ColorType::Rgb
            || info.bit_depth != ::png::BitDepth::Eight
            || info.interlaced
        {
            return Err(bad(format!(
                "expected a non-interlaced 8-bit RGB PNG, found {:?} {:?}{}",
                info.color_type,
                info.bit_depth,
                if info.interlaced { " interlaced" } else { "" }
            )));
        }
        if (info.width, info.height) != (width, height) {
            return Err(bad(format!(
                "the file is {}x{}, the frame {width}x{height}",
                info.width, info.height
            )));
        }
        Ok(PngRows {
            reader,
            path: p,
            next: 0,
            height,
        })
    }

    /// The index of the next row [`PngRows::next_row`] gives.
    pub fn position(&self) -> u32 {
        self.next
    }

    /// The next row: `3 × width` bytes, R G B a pixel.
    pub fn next_row(&mut self) -> Result<&[u8], OutputError> {
        let (path, next, height) = (&self.path, self.next, self.height);
        let bad = |message: String| OutputError::Encode {
            path: path.clone(),
            message,
        };
        if next >= height {
            return Err(bad(format!("row {next} is past the frame's {height} rows")));
        }
        let row = match self.reader.next_row() {
            Ok(Some(row)) => row.data(),
            Ok(None) => return Err(bad(format!("the file ends before row {next}"))),
            Err(e) => return Err(bad(format!("row {next}: {e}"))),
        };
        self.next += 1;
        Ok(row)
    }
}

impl FrameWriter {
    /// Adds a tile of a plain PNG frame given as 8-bit sRGB bytes (R G B a
    /// pixel, row by row: `3 × rect.w × rect.h` of them), as
    /// [`PngRows`] reads a frame back. Refused as [`FrameWriter::write_tile`]
    /// refuses a tile, and for an EXR frame or one with render passes
    /// ([`OutputError::Encode`]); a refused tile changes nothing.
    pub fn write_tile_srgb8(&mut self, rect: Rect, bytes: &[u8]) -> Result<(), OutputError> {
        let plain = matches!(self.encoder, Encoder::Png { signed: false, .. });
        if !plain || !self.aovs.is_empty() {
            return Err(OutputError::Encode {
                path: self.path.display().to_string(),
                message: "only a plain PNG frame takes sRGB bytes".to_string(),
            });
        }
        if !bytes.len().is_multiple_of(3) {
            return Err(OutputError::TilePixelCount {
                x: rect.x,
                y: rect.y,
                w: rect.w,
                h: rect.h,
                expected: rect.pixel_count(),
                got: bytes.len() / 3,
            });
        }
        self.check_rect(rect, bytes.len() / 3)?;
        let (x0, x1) = (rect.x, rect.x + rect.w);
        if let Encoder::Png { rows, .. } = &mut self.encoder {
            for (y, line) in (rect.y..).zip(bytes.chunks_exact(3 * rect.w as usize)) {
                let row = rows.claim(y, x0, x1);
                row[3 * x0 as usize..3 * x1 as usize].copy_from_slice(line);
            }
        }
        self.flush_complete_rows().inspect_err(|e| {
            self.failure = Some(e.to_string());
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Test pixels, different for every pixel and seed.
    fn pixels(rect: Rect, seed: u32) -> Vec<[f32; 3]> {
        (rect.y..rect.y + rect.h)
            .flat_map(|y| (rect.x..rect.x + rect.w).map(move |x| (x, y)))
            .map(|(x, y)| {
                let v = ((x * 7 + y * 13 + seed * 31) % 97) as f32 / 96.0;
                [v, 1.0 - v, (v * 3.0) % 1.0]
            })
            .collect()
    }

    fn render(path: &Path, w: u32, h: u32, seed: u32) {
        let mut f = FrameWriter::create(path, w, h).unwrap();
        let r = Rect::new(0, 0, w, h);
        f.write_tile(r, &pixels(r, seed)).unwrap();
        f.finish().unwrap();
    }

    #[test]
    fn a_frame_read_back_row_by_row_writes_the_same_bytes() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a.png"), dir.path().join("b.png"));
        let (w, h) = (37, 41);
        render(&a, w, h, 1);
        let mut rows = PngRows::open(&a, w, h).unwrap();
        let mut out = FrameWriter::create(&b, w, h).unwrap();
        // A patch: the middle rows come anew, as floats, before the rest.
        let mid = Rect::new(5, 17, 20, 9);
        let old = (0..h)
            .map(|_| rows.next_row().unwrap().to_vec())
            .collect::<Vec<_>>();
        assert_eq!(rows.position(), h);
        assert!(rows.next_row().is_err(), "no row past the frame");
        let full = pixels(Rect::new(0, 0, w, h), 1);
        let mid_px: Vec<[f32; 3]> = (mid.y..mid.y + mid.h)
            .flat_map(|y| {
                let s = (y * w + mid.x) as usize;
                full[s..s + mid.w as usize].to_vec()
            })
            .collect();
        out.write_tile(mid, &mid_px).unwrap();
        for (y, row) in old.iter().enumerate() {
            let y = y as u32;
            if (mid.y..mid.y + mid.h).contains(&y) {
                out.write_tile_srgb8(Rect::new(0, y, mid.x, 1), &row[..3 * mid.x as usize])
                    .unwrap();
                let x1 = mid.x + mid.w;
                out.write_tile_srgb8(Rect::new(x1, y, w - x1, 1), &row[3 * x1 as usize..])
                    .unwrap();
            } else {
                out.write_tile_srgb8(Rect::new(0, y, w, 1), row).unwrap();
            }
        }
        out.finish().unwrap();
        assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    }

    #[test]
    fn bad_bytes_and_files_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("a.png");
        render(&a, 8, 8, 2);
        assert!(PngRows::open(&a, 8, 9).is_err(), "another size");
        assert!(PngRows::open(&dir.path().join("none.png"), 8, 8).is_err());
        std::fs::write(dir.path().join("junk.png"), b"not a png").unwrap();
        assert!(PngRows::open(&dir.path().join("junk.png"), 8, 8).is_err());
        let mut out = FrameWriter::create(&dir.path().join("b.png"), 8, 8).unwrap();
        assert!(out
            .write_tile_srgb8(Rect::new(0, 0, 2, 2), &[0; 11])
            .is_err());
        assert!(out
            .write_tile_srgb8(Rect::new(7, 0, 2, 1), &[0; 6])
            .is_err());
        out.write_tile_srgb8(Rect::new(0, 0, 2, 1), &[0; 6])
            .unwrap();
        assert!(
            out.write_tile_srgb8(Rect::new(1, 0, 2, 1), &[0; 6])
                .is_err(),
            "overlap"
        );
        let mut exr = FrameWriter::create(&dir.path().join("c.exr"), 8, 8).unwrap();
        assert!(exr
            .write_tile_srgb8(Rect::new(0, 0, 1, 1), &[0; 3])
            .is_err());
    }
}
