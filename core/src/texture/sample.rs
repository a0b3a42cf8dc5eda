//! Texture lookups: bilinear within a level, linear between the two levels
//! around a fractional level of detail.

use super::{Level, Texture};
use glam::{Vec2, Vec3};

/// What happens outside `[0, 1]`: the image repeats, or its edge texels
/// extend.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Wrap {
    /// Coordinates wrap around: the image tiles the plane (the default).
    #[default]
    Repeat,
    /// Coordinates clamp to `[0, 1]`: the edge texels extend.
    Clamp,
}

impl Wrap {
    #[inline]
    fn index(self, i: i64, n: u32) -> u32 {
        match self {
            Wrap::Repeat => i.rem_euclid(i64::from(n)) as u32,
            Wrap::Clamp => i.clamp(0, i64::from(n) - 1) as u32,
        }
    }
}

impl Texture {
    /// The filtered colour at `uv` and level of detail `lod` (0 = the image;
    /// `k` = level `k`, whose texels are 2^k image texels wide): level
    /// `⌊lod⌋` and the next blended by the fraction, each bilinear. `lod` is
    /// clamped to the chain; NaN counts as 0.
    pub fn sample(&self, uv: Vec2, lod: f32, wrap: Wrap) -> Vec3 {
        let top = (self.levels.len() - 1) as f32;
        let lod = if lod > 0.0 { lod.min(top) } else { 0.0 };
        let l0 = lod as usize; // floor, lod ≥ 0
        let f = lod - l0 as f32;
        let c0 = bilinear(&self.levels[l0], uv, wrap);
        if f > 0.0 {
            let c1 = bilinear(&self.levels[l0 + 1], uv, wrap);
            c0 + (c1 - c0) * f
        } else {
            c0
        }
    }
}

/// Bilinear interpolation between the four texel centres around `uv`.
#[inline]
pub(super) fn bilinear(l: &Level, uv: Vec2, wrap: Wrap) -> Vec3 {
    let finite = |x: f32| if x.is_finite() { x } else { 0.0 };
    let x = finite(uv.x * l.width as f32 - 0.5);
    let y = finite((1.0 - uv.y) * l.height as f32 - 0.5);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (i0, j0) = (x0 as i64, y0 as i64);
    let (ia, ib) = (wrap.index(i0, l.width), wrap.index(i0 + 1, l.width));
    let (ja, jb) = (wrap.index(j0, l.height), wrap.index(j0 + 1, l.height));
    let top = l.at(ia, ja) + (l.at(ib, ja) - l.at(ia, ja)) * fx;
    let bottom = l.at(ia, jb) + (l.at(ib, jb) - l.at(ia, jb)) * fx;
    top + (bottom - top) * fy
}
