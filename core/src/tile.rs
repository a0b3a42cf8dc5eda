//! Tiles: rectangles of a camera's frame, the unit of work everywhere.
//!
//! A frame is exactly the union of its tiles; [`band_order_tiles`] lists them
//! band by band (top to bottom, left to right inside a band) so that an output
//! writer can let rows go as soon as a band is complete.

use crate::aov::{AovTile, Aovs};
use crate::integrator::{Integrator, PixelState, RayObserver, RenderOptions, MAX_AOV_CHANNELS};
use crate::world::Scene;
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};

/// A rectangle of pixels: columns `x..x+w`, rows `y..y+h` (row 0 at the top).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Rect {
    /// The first column.
    pub x: u32,
    /// The first row.
    pub y: u32,
    /// The width in pixels.
    pub w: u32,
    /// The height in pixels.
    pub h: u32,
}

impl Rect {
    /// Columns `x..x+w`, rows `y..y+h` (not checked against any frame).
    pub fn new(x: u32, y: u32, w: u32, h: u32) -> Self {
        Rect { x, y, w, h }
    }

    /// `w × h`, the number of pixels.
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
    /// The pixels, row by row.
    pub pixels: Vec<[f32; 3]>,
    /// Rays traced for them, of every kind.
    pub rays: u64,
}

/// The index of the first pixel (row by row) with a component that is not
/// finite and non-negative, if any: what no render produces (radiance is
/// linear and at least 0, and any finite value may be true, since a scene
/// may have lights that bright). The coordinator checks float uploads with
/// it, a worker its pixels before it encodes them. One branch-free pass in
/// the usual case; only a bad tile is searched for its culprit. `-0.0` is a
/// zero.
pub fn first_invalid_pixel(pixels: &[[f32; 3]]) -> Option<usize> {
    // NaN fails both comparisons, infinities the upper one.
    let valid = |c: f32| (0.0..=f32::MAX).contains(&c);
    let all_good = pixels.iter().flatten().fold(true, |ok, &c| ok & valid(c));
    if all_good {
        return None;
    }
    pixels.iter().position(|p| !p.iter().all(|&c| valid(c)))
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
    let never = AtomicBool::new(false);
    match render_rows(scene, camera, rect, options, observer, &never) {
        Ok(r) => r,
        Err(Cancelled) => unreachable!("a flag that is never set cancelled a render"),
    }
}

/// The render of a tile was stopped by its cancellation flag.
pub use crate::integrator::Cancelled;

/// [`render_tile`] that gives up soon after `cancel` turns true: the flag is
/// read before every pixel and every [`crate::integrator::CANCEL_EVERY`]
/// rays inside one (integrator/pixel.rs), so a tile stops within
/// milliseconds however expensive the tile or a single pixel of it, and
/// no pixel is left half-made. An uncancelled render returns exactly the
/// pixels of [`render_tile`].
pub fn render_tile_cancellable(
    scene: &Scene,
    camera: usize,
    rect: Rect,
    cancel: &AtomicBool,
) -> Result<TileResult, Cancelled> {
    render_rows(scene, camera, rect, RenderOptions::default(), &(), cancel)
}

fn render_rows<O: RayObserver>(
    scene: &Scene,
    camera: usize,
    rect: Rect,
    options: RenderOptions,
    observer: &O,
    cancel: &AtomicBool,
) -> Result<TileResult, Cancelled> {
    let integrator = Integrator::observed(scene, camera, options, observer).cancelled_by(cancel);
    let mut pixels = vec![[0.0f32; 3]; rect.pixel_count()];
    let rays = for_each_pixel(rect, &mut pixels, cancel, |x, y, px| {
        let (v, r) = integrator.pixel(x, y)?;
        *px = v;
        Ok(r)
    })?;
    Ok(TileResult { pixels, rays })
}

/// [`render_tile_cancellable`] with the render passes `aovs` (see
/// [`crate::aov`]): the tile's beauty, the very pixels of [`render_tile`],
/// and its passes. With no passes the passes are empty and nothing more is
/// traced.
pub fn render_tile_aovs(
    scene: &Scene,
    camera: usize,
    rect: Rect,
    aovs: Aovs,
    cancel: &AtomicBool,
) -> Result<(TileResult, AovTile), Cancelled> {
    if aovs.is_empty() {
        let beauty = render_tile_cancellable(scene, camera, rect, cancel)?;
        return Ok((
            beauty,
            AovTile {
                aovs,
                values: Vec::new(),
            },
        ));
    }
    let integrator =
        Integrator::observed(scene, camera, RenderOptions::default(), &()).cancelled_by(cancel);
    let mut items = vec![([0.0f32; 3], [0.0f32; MAX_AOV_CHANNELS]); rect.pixel_count()];
    let rays = for_each_pixel(rect, &mut items, cancel, |x, y, item| {
        let (v, a, r) = integrator.pixel_aovs(x, y, aovs)?;
        *item = (v, a);
        Ok(r)
    })?;
    let n = aovs.channels();
    let pixels = items.iter().map(|(v, _)| *v).collect();
    let values = items
        .iter()
        .flat_map(|(_, a)| a[..n].iter().copied())
        .collect();
    Ok((TileResult { pixels, rays }, AovTile { aovs, values }))
}

/// Continues every pixel of `rect` of camera `camera`'s frame from its
/// state in `states` (row by row, `rect.pixel_count()` of them) up to
/// sample index `end` (see [`Integrator::pixel_samples`]), on the current
/// rayon pool; returns the rays traced. Gives up soon after `cancel` turns
/// true, and then some states have moved on and others not: the caller
/// keeps a copy (as `passes::TileState::render` does). With every state new
/// and `end` the samples per pixel, [`finish_tile`] of the states is
/// [`render_tile`]'s pixels, byte for byte, and so is any split into
/// consecutive ranges of sample indices.
///
/// # Panics
/// If `states` is not `rect.pixel_count()` long (a caller's error, never
/// input's).
pub fn render_tile_samples(
    scene: &Scene,
    camera: usize,
    rect: Rect,
    end: u32,
    states: &mut [PixelState],
    cancel: &AtomicBool,
) -> Result<u64, Cancelled> {
    assert_eq!(states.len(), rect.pixel_count(), "one state a pixel");
    let integrator =
        Integrator::observed(scene, camera, RenderOptions::default(), &()).cancelled_by(cancel);
    for_each_pixel(rect, states, cancel, |x, y, state| {
        integrator.pixel_samples(x, y, end, state)
    })
}

/// The pixels of accumulated states (see [`PixelState::finish`]).
pub fn finish_tile(states: &[PixelState]) -> Vec<[f32; 3]> {
    states.iter().map(PixelState::finish).collect()
}

/// Runs `pixel(x, y, item)` on every pixel of `rect` with its item of
/// `items` (row by row), rows in parallel; the sum of the rays it returns.
/// Stops at the first cancelled pixel of each row, and is [`Cancelled`]
/// once the flag is set.
fn for_each_pixel<T: Send>(
    rect: Rect,
    items: &mut [T],
    cancel: &AtomicBool,
    pixel: impl Fn(u32, u32, &mut T) -> Result<u64, Cancelled> + Sync,
) -> Result<u64, Cancelled> {
    let rays = items
        .par_chunks_mut(rect.w.max(1) as usize)
        .enumerate()
        .map(|(row, out)| {
            let y = rect.y + row as u32;
            let mut rays = 0;
            for (i, item) in out.iter_mut().enumerate() {
                if cancel.load(Ordering::Relaxed) {
                    break;
                }
                let Ok(r) = pixel(rect.x + i as u32, y, item) else {
                    break;
                };
                rays += r;
            }
            rays
        })
        .sum();
    if cancel.load(Ordering::Relaxed) {
        return Err(Cancelled);
    }
    Ok(rays)
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

    fn scene() -> Scene {
        let xml = r#"<scene version="1">
  <sphere id="s" center="0 0 0" radius="1"> <surface diffuse="0.8 0.3 0.2"/> </sphere>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1"/>
  <camera id="c" position="0 0 5" lookat="0 0 0" up="0 1 0" fov="50">
    <render width="8" height="6" output="o.png"/>
  </camera>
</scene>"#;
        let bundle = crate::Bundle {
            scene: "s.xml".into(),
            files: [("s.xml".to_string(), xml.as_bytes().to_vec())].into(),
        };
        Scene::from_bundle(&bundle).unwrap()
    }

    #[test]
    fn a_cancellable_render_matches_render_tile_unless_cancelled() {
        let scene = scene();
        let rect = Rect::new(0, 0, 8, 6);
        let flag = AtomicBool::new(false);
        let r = render_tile_cancellable(&scene, 0, rect, &flag).unwrap();
        assert_eq!(r, render_tile(&scene, 0, rect));
        flag.store(true, Ordering::Relaxed);
        assert_eq!(
            render_tile_cancellable(&scene, 0, rect, &flag),
            Err(Cancelled)
        );
    }

    #[test]
    fn the_first_invalid_pixel_is_the_first_not_finite_or_negative() {
        let ok = [[0.0, -0.0, 1.0], [f32::MAX, 0.5, 2.0]];
        assert_eq!(first_invalid_pixel(&ok), None);
        assert_eq!(first_invalid_pixel(&[]), None);
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -1e-30] {
            for channel in 0..3 {
                let mut px = vec![[0.25f32; 3]; 5];
                px[3][channel] = bad;
                px[4] = [bad; 3];
                assert_eq!(
                    first_invalid_pixel(&px),
                    Some(3),
                    "{bad} in channel {channel}"
                );
            }
        }
    }
}
