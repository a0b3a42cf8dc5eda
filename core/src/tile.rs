//! Tiles: rectangles of a camera's frame, the unit of work everywhere.
//!
//! A frame is exactly the union of its tiles; [`band_order_tiles`] lists them
//! band by band (top to bottom, left to right inside a band) so that an output
//! writer can let rows go as soon as a band is complete.

use crate::integrator::{Integrator, RayObserver, RenderOptions};
use crate::world::Scene;
use rayon::prelude::*;

/// A rectangle of pixels: columns `x..x+w`, rows `y..y+h` (row 0 at the top).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Rect {
    pub x: u32,
    pub y: u32,
    pub w: u32,
    pub h: u32,
}

impl Rect {
    pub fn new(x: u32, y: u32, w: u32, h: u32) -> Self {
        Rect { x, y, w, h }
    }

    pub fn pixel_count(&self) -> usize {
        self.w as usize * self.h as usize
    }

    /// Whether the rectangle is non-empty and lies inside a `width`×`height` frame.
    pub fn fits(&self, width: u32, height: u32) -> bool {
        self.w > 0
            && self.h > 0
            && (self.x as u64 + self.w as u64) <= width as u64
            && (self.y as u64 + self.h as u64) <= height as u64
    }
}

/// The tiles of a `width`×`height` frame, `tile`×`tile` pixels each (smaller
/// at the right and bottom edges), in band order.
pub fn band_order_tiles(width: u32, height: u32, tile: u32) -> Vec<Rect> {
    let tile = tile.max(1);
    let mut out = Vec::new();
    let mut y = 0;
    while y < height {
        let h = tile.min(height - y);
        let mut x = 0;
        while x < width {
            let w = tile.min(width - x);
            out.push(Rect { x, y, w, h });
            x += w;
        }
        y += h;
    }
    out
}

/// The rendered pixels of a tile: `rect.w * rect.h` linear RGB values, row
/// by row, and how many rays were traced for them.
#[derive(Debug, Clone, PartialEq)]
pub struct TileResult {
    pub pixels: Vec<[f32; 3]>,
    pub rays: u64,
}

/// Renders rectangle `rect` of camera `camera`'s frame on the current rayon
/// pool (rows in parallel). Each pixel depends only on the scene and its
/// coordinates, so the result is the same whatever the tiling or threads.
pub fn render_tile(scene: &Scene, camera: usize, rect: Rect) -> TileResult {
    render_tile_with(scene, camera, rect, RenderOptions::default())
}

/// [`render_tile`] with explicit sampling options.
pub fn render_tile_with(
    scene: &Scene,
    camera: usize,
    rect: Rect,
    options: RenderOptions,
) -> TileResult {
    render_tile_observed(scene, camera, rect, options, &())
}

/// [`render_tile_with`], showing every traced ray to `observer` (the rows are
/// rendered in parallel, so the observer sees them from several threads in
/// no fixed order unless the rayon pool has one thread).
pub fn render_tile_observed<O: RayObserver>(
    scene: &Scene,
    camera: usize,
    rect: Rect,
    options: RenderOptions,
    observer: &O,
) -> TileResult {
    let integrator = Integrator::observed(scene, camera, options, observer);
    let mut pixels = vec![[0.0f32; 3]; rect.pixel_count()];
    let rays = pixels
        .par_chunks_mut(rect.w.max(1) as usize)
        .enumerate()
        .map(|(row, out)| {
            let y = rect.y + row as u32;
            let mut rays = 0;
            for (i, px) in out.iter_mut().enumerate() {
                let (v, r) = integrator.pixel(rect.x + i as u32, y);
                *px = v;
                rays += r;
            }
            rays
        })
        .sum();
    TileResult { pixels, rays }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn band_order_tiles_cover_the_frame_exactly_once() {
        for &(w, h, t) in &[
            (1, 1, 64),
            (10, 7, 3),
            (64, 64, 64),
            (100, 37, 7),
            (5, 9, 1),
        ] {
            let mut seen = vec![0u8; w as usize * h as usize];
            let tiles = band_order_tiles(w, h, t);
            for r in &tiles {
                assert!(r.fits(w, h));
                for y in r.y..r.y + r.h {
                    for x in r.x..r.x + r.w {
                        seen[(y * w + x) as usize] += 1;
                    }
                }
            }
            assert!(seen.iter().all(|&c| c == 1), "{w}x{h} tile {t}");
            // Band order: rows never go back up.
            assert!(tiles.windows(2).all(|p| p[0].y <= p[1].y));
        }
    }
}
