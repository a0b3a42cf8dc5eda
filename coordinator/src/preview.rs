//! A running frame's live preview: the frame shrunk by a whole factor so
//! that neither side exceeds [`Preview::MAX_EDGE`] pixels, filled in tile by
//! tile as results arrive.
//!
//! Each preview pixel is the mean of the frame pixels in its `scale`×`scale`
//! block (a box filter), accumulated in linear light, so tiles that split a
//! block add up to the same mean whatever order they come in. The
//! coordinator keeps only this small image per running job (at most
//! 512×512×16 bytes = 4 MiB), never the frame. Pixels no tile has reached
//! yet are transparent in the PNG.
//!
//! This is the image of one frame; which jobs keep one, for how long, and
//! when it is encoded is the farm's (`farm/job_previews.rs`).

use trevi_core::output::Srgb8;
use trevi_core::Rect;

/// The preview of one frame.
#[derive(Debug, Clone)]
pub struct Preview {
    /// The preview's width in pixels: the frame's divided by `scale`,
    /// rounded up (at most [`Preview::MAX_EDGE`]).
    pub width: u32,
    /// The preview's height in pixels, likewise.
    pub height: u32,
    /// Frame pixels per preview pixel along each axis.
    pub scale: u32,
    /// Linear RGB sums and sample counts, row-major; empty until the first
    /// tile arrives (queued jobs cost nothing).
    sum: Vec<[f32; 3]>,
    count: Vec<u32>,
    /// Tiles added so far.
    pub tiles: u64,
}

impl Preview {
    /// Largest preview edge in pixels.
    pub const MAX_EDGE: u32 = 512;

    /// The preview of a `frame_w`×`frame_h` frame (both ≥ 1).
    pub fn new(frame_w: u32, frame_h: u32) -> Preview {
        let (fw, fh) = (frame_w.max(1), frame_h.max(1));
        let scale = fw
            .div_ceil(Self::MAX_EDGE)
            .max(fh.div_ceil(Self::MAX_EDGE))
            .max(1);
        Preview {
            width: fw.div_ceil(scale),
            height: fh.div_ceil(scale),
            scale,
            sum: Vec::new(),
            count: Vec::new(),
            tiles: 0,
        }
    }

    /// Adds a tile's pixels (row-major, `rect.w × rect.h`, already checked).
    pub fn add_tile(&mut self, rect: Rect, pixels: &[[f32; 3]]) {
        if pixels.len() != rect.pixel_count() {
            return;
        }
        if self.sum.is_empty() {
            let n = self.width as usize * self.height as usize;
            self.sum = vec![[0.0; 3]; n];
            self.count = vec![0; n];
        }
        let s = self.scale as usize;
        let w = self.width as usize;
        let x0 = rect.x as usize;
        for (row, line) in pixels.chunks_exact(rect.w.max(1) as usize).enumerate() {
            let py = (rect.y as usize + row) / s;
            if py >= self.height as usize {
                break;
            }
            // The line in runs of columns that share a preview pixel (no
            // division per pixel); each preview pixel still adds its frame pixels in the same
            // order, so the sums are the same floats.
            let (sum, count) = (&mut self.sum[py * w..], &mut self.count[py * w..]);
            let mut col = 0;
            let mut px = x0 / s;
            while col < line.len() && px < w {
                let end = ((px + 1) * s - x0).min(line.len());
                let acc = &mut sum[px];
                for p in &line[col..end] {
                    for (a, v) in acc.iter_mut().zip(p) {
                        *a += v;
                    }
                }
                count[px] += (end - col) as u32;
                col = end;
                px += 1;
            }
        }
        self.tiles += 1;
    }

    /// The preview cells (`scale`-square blocks of frame pixels) `rect`
    /// overlaps, as (first column, first row, columns, rows) of cells;
    /// `rect` must fit the frame.
    pub fn cells(&self, rect: Rect) -> (u32, u32, u32, u32) {
        let s = self.scale;
        if rect.w == 0 || rect.h == 0 {
            return (rect.x / s, rect.y / s, 0, 0);
        }
        let (cx0, cy0) = (rect.x / s, rect.y / s);
        let (cx1, cy1) = ((rect.x + rect.w - 1) / s, (rect.y + rect.h - 1) / s);
        (cx0, cy0, cx1 - cx0 + 1, cy1 - cy0 + 1)
    }

    /// Adds the box sums a worker computed for `rect` (see
    /// `PreviewSums` in the proto): for every cell `rect` overlaps
    /// ([`Preview::cells`]), row-major, the sums of linear R, G, B over
    /// the rect's pixels in it; each cell's count grows by its overlap
    /// with `rect`. `tiles` is how many tiles `rect` brings. Sums of the
    /// wrong length change nothing (the caller checked them).
    pub fn add_sums(&mut self, rect: Rect, sums: &[f32], tiles: u64) {
        let (cx0, cy0, cols, rows) = self.cells(rect);
        if sums.len() != 3 * cols as usize * rows as usize
            || cx0 + cols > self.width
            || cy0 + rows > self.height
        {
            return;
        }
        if self.sum.is_empty() {
            let n = self.width as usize * self.height as usize;
            self.sum = vec![[0.0; 3]; n];
            self.count = vec![0; n];
        }
        let s = self.scale;
        let (x1, y1) = (rect.x + rect.w, rect.y + rect.h);
        let mut cell = sums.chunks_exact(3);
        for cy in cy0..cy0 + rows {
            let h = (y1.min((cy + 1) * s)) - rect.y.max(cy * s);
            for cx in cx0..cx0 + cols {
                let w = (x1.min((cx + 1) * s)) - rect.x.max(cx * s);
                let i = cy as usize * self.width as usize + cx as usize;
                if let Some(v) = cell.next() {
                    for (a, b) in self.sum[i].iter_mut().zip(v) {
                        *a += b;
                    }
                }
                self.count[i] += w * h;
            }
        }
        self.tiles += tiles;
    }

    /// 8-bit sRGB RGBA, row-major; alpha 0 where no tile has arrived yet.
    pub fn to_rgba8(&self) -> Vec<u8> {
        let n = self.width as usize * self.height as usize;
        let mut out = vec![0u8; n * 4];
        if self.sum.is_empty() {
            return out;
        }
        let srgb = Srgb8::new();
        for (i, px) in out.chunks_exact_mut(4).enumerate() {
            let k = self.count[i];
            if k == 0 {
                continue;
            }
            let inv = 1.0 / k as f32;
            for (out, s) in px.iter_mut().zip(self.sum[i]) {
                *out = srgb.encode(s * inv);
            }
            px[3] = 255;
        }
        out
    }
}

/// RGBA pixels (`width × height × 4` bytes) as a PNG file's bytes.
pub fn encode_png(width: u32, height: u32, rgba: &[u8]) -> Result<Vec<u8>, png::EncodingError> {
    let mut bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut bytes, width, height);
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        let mut w = enc.write_header()?;
        w.write_image_data(rgba)?;
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use trevi_core::output::linear_to_srgb8;

    fn tile(rect: Rect, f: impl Fn(u32, u32) -> [f32; 3]) -> Vec<[f32; 3]> {
        let mut v = Vec::new();
        for y in rect.y..rect.y + rect.h {
            for x in rect.x..rect.x + rect.w {
                v.push(f(x, y));
            }
        }
        v
    }

    /// The sums a worker would send for `rect`, computed pixel by pixel.
    fn sums_of(p: &Preview, rect: Rect, f: impl Fn(u32, u32) -> [f32; 3]) -> Vec<f32> {
        let (cx0, cy0, cols, rows) = p.cells(rect);
        let mut out = vec![0.0f32; 3 * (cols * rows) as usize];
        for y in rect.y..rect.y + rect.h {
            for x in rect.x..rect.x + rect.w {
                let i = ((y / p.scale - cy0) * cols + (x / p.scale - cx0)) as usize;
                for (o, v) in out[3 * i..3 * i + 3].iter_mut().zip(f(x, y)) {
                    *o += v;
                }
            }
        }
        out
    }

    #[test]
    fn sums_give_the_preview_tiles_give() {
        // 1100 wide: scale 3, so full-width bands of 16 rows cut cells.
        let (w, h) = (1100, 40);
        let f = |x: u32, y: u32| [(x % 7) as f32 * 0.25, (y % 5) as f32 * 0.5, 1.0];
        let mut by_tiles = Preview::new(w, h);
        let mut by_sums = Preview::new(w, h);
        assert_eq!(by_sums.scale, 3);
        for (y, rh) in [(0, 16), (16, 16), (32, 8)] {
            let r = Rect::new(0, y, w, rh);
            by_tiles.add_tile(r, &tile(r, f));
            by_sums.add_sums(r, &sums_of(&by_sums, r, f), 2);
        }
        assert_eq!(by_sums.count, by_tiles.count);
        assert_eq!(by_sums.tiles, 6);
        for (a, b) in by_sums.sum.iter().zip(&by_tiles.sum) {
            for (x, y) in a.iter().zip(b) {
                assert!((x - y).abs() <= 1e-4 * y.abs().max(1.0), "{a:?} {b:?}");
            }
        }
        assert_eq!(by_sums.to_rgba8(), by_tiles.to_rgba8());
        // Sums of the wrong length change nothing.
        let mut p = Preview::new(w, h);
        p.add_sums(Rect::new(0, 0, w, 16), &[1.0; 6], 1);
        assert!(p.sum.is_empty() && p.tiles == 0);
    }

    #[test]
    fn size_is_bounded_by_512_on_both_sides() {
        for (w, h, pw, ph, s) in [
            (512, 300, 512, 300, 1),
            (513, 10, 257, 5, 2),
            (3000, 2000, 500, 334, 6),
            (16384, 16384, 512, 512, 32),
            (1, 10000, 1, 500, 20),
            (1, 1, 1, 1, 1),
        ] {
            let p = Preview::new(w, h);
            assert_eq!((p.width, p.height, p.scale), (pw, ph, s), "{w}x{h}");
            assert!(p.width <= 512 && p.height <= 512);
            // Every frame pixel lands in the preview.
            assert!((w - 1) / p.scale < p.width && (h - 1) / p.scale < p.height);
        }
    }

    #[test]
    fn each_pixel_is_the_mean_of_its_block_whatever_the_tiling() {
        // A 1030×7 frame: scale 3, and 5-pixel tiles split the 3×3 blocks.
        let (w, h) = (1030u32, 7u32);
        let f = |x: u32, y: u32| [x as f32 / w as f32, y as f32 / h as f32, 0.25];
        let mut p = Preview::new(w, h);
        assert_eq!(p.scale, 3);
        let t = 5;
        for ty in (0..h).step_by(t as usize).rev() {
            for tx in (0..w).step_by(t as usize) {
                let r = Rect::new(tx, ty, t.min(w - tx), t.min(h - ty));
                p.add_tile(r, &tile(r, f));
            }
        }
        let rgba = p.to_rgba8();
        // The mean of each block computed directly from the function.
        for py in 0..p.height {
            for px in 0..p.width {
                let (mut sum, mut n) = ([0f64; 3], 0);
                for y in py * 3..((py + 1) * 3).min(h) {
                    for x in px * 3..((px + 1) * 3).min(w) {
                        let v = f(x, y);
                        for c in 0..3 {
                            sum[c] += v[c] as f64;
                        }
                        n += 1;
                    }
                }
                let i = ((py * p.width + px) * 4) as usize;
                for c in 0..3 {
                    let want = linear_to_srgb8((sum[c] / n as f64) as f32);
                    let got = rgba[i + c];
                    assert!(got.abs_diff(want) <= 1, "({px},{py}) c{c}: {got} vs {want}");
                }
                assert_eq!(rgba[i + 3], 255);
            }
        }
    }

    /// The sums are the very floats of the plain per-pixel loop (each
    /// preview pixel adds its frame pixels in the same order).
    #[test]
    fn runs_of_columns_add_the_same_floats_as_pixel_by_pixel() {
        let (w, h) = (1030u32, 29u32);
        let f = |x: u32, y: u32| {
            let v = (x.wrapping_mul(2654435761) ^ y.wrapping_mul(40503)) % 1000;
            [v as f32 / 997.0, (x + y) as f32 / 3.0, 1.0 / (1 + x) as f32]
        };
        let mut p = Preview::new(w, h);
        let n = (p.width * p.height) as usize;
        let (mut sum, mut count) = (vec![[0f32; 3]; n], vec![0u32; n]);
        for (tw, th) in [(5, 7), (64, 3), (1, 1), (333, 29)] {
            for ty in (0..h).step_by(th as usize) {
                for tx in (0..w).step_by(tw as usize) {
                    let r = Rect::new(tx, ty, tw.min(w - tx), th.min(h - ty));
                    let px = tile(r, f);
                    p.add_tile(r, &px);
                    for (i, v) in px.iter().enumerate() {
                        let (x, y) = (r.x + i as u32 % r.w, r.y + i as u32 / r.w);
                        let k = ((y / p.scale) * p.width + x / p.scale) as usize;
                        for c in 0..3 {
                            sum[k][c] += v[c];
                        }
                        count[k] += 1;
                    }
                }
            }
        }
        assert_eq!(p.count, count);
        let bits = |s: &[[f32; 3]]| s.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&p.sum), bits(&sum));
    }

    #[test]
    fn pixels_not_reached_yet_are_transparent() {
        let mut p = Preview::new(128, 128);
        assert!(p.to_rgba8().iter().all(|&b| b == 0));
        let r = Rect::new(0, 0, 64, 64);
        p.add_tile(r, &vec![[1.0, 1.0, 1.0]; 64 * 64]);
        let rgba = p.to_rgba8();
        let at = |x: usize, y: usize| &rgba[(y * 128 + x) * 4..(y * 128 + x) * 4 + 4];
        assert_eq!(at(10, 10), &[255, 255, 255, 255]);
        assert_eq!(at(100, 10), &[0, 0, 0, 0]);
        assert_eq!(p.tiles, 1);
    }

    #[test]
    fn png_decodes_to_the_same_pixels() {
        let mut p = Preview::new(40, 30);
        let r = Rect::new(0, 0, 40, 15);
        p.add_tile(r, &tile(r, |x, _| [x as f32 / 40.0, 0.5, 0.0]));
        let png_bytes = encode_png(p.width, p.height, &p.to_rgba8()).unwrap();
        let dec = png::Decoder::new(std::io::Cursor::new(png_bytes));
        let mut reader = dec.read_info().unwrap();
        let mut buf = vec![
            0;
            reader
                .output_buffer_size()
                .expect("the image fits in memory")
        ];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (40, 30));
        assert_eq!(info.color_type, png::ColorType::Rgba);
        assert_eq!(&buf[..info.buffer_size()], &p.to_rgba8()[..]);
    }
}
