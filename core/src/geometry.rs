//! Rays, boxes, the three primitive shapes (triangles, spheres, planes) and
//! the optics of a smooth surface (`optics`: reflection, refraction).
//!
//! Everything here is plain `f32` data and free functions: the traversal hot
//! path calls them directly, with no dynamic dispatch.

pub mod optics;
pub mod plane;
pub mod sphere;
pub mod triangle;

use glam::Vec3;

/// A ray `origin + t·dir` for `t` in `(0, t_max)`. `dir` need not be unit
/// length (instance transforms scale it), so `t` is a parameter, not a distance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    /// Where the ray starts (`t = 0`), in the coordinates of whatever it is
    /// tested against (camera-relative world, or an instance's object space).
    pub origin: Vec3,
    /// The direction, any non-zero length: one unit of `t` moves this far.
    pub dir: Vec3,
}

impl Ray {
    /// The ray from `origin` along `dir`.
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        Ray { origin, dir }
    }

    /// The point at parameter `t`: `origin + t·dir`.
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }
}

/// An axis-aligned bounding box. The empty box has `min = +inf`, `max = -inf`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// The smallest coordinate on each axis.
    pub min: Vec3,
    /// The largest coordinate on each axis.
    pub max: Vec3,
}

impl Aabb {
    /// The box of nothing: the identity of [`Aabb::union`] and
    /// [`Aabb::grow`].
    pub const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };

    /// The smallest box holding every point ([`Aabb::EMPTY`] for none).
    pub fn from_points(points: &[Vec3]) -> Aabb {
        points.iter().fold(Aabb::EMPTY, |b, &p| b.grow(p))
    }

    /// The smallest box holding this one and `p`.
    pub fn grow(self, p: Vec3) -> Aabb {
        Aabb {
            min: self.min.min(p),
            max: self.max.max(p),
        }
    }

    /// The smallest box holding both boxes.
    pub fn union(self, o: Aabb) -> Aabb {
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }

    /// Whether the box holds no point: `min > max` on some axis, or a NaN
    /// bound.
    pub fn is_empty(&self) -> bool {
        !(self.min.x <= self.max.x && self.min.y <= self.max.y && self.min.z <= self.max.z)
    }

    /// The box's centre (meaningless for an empty box).
    pub fn center(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }

    /// Half the surface area (enough for SAH ratios); 0 for an empty box.
    pub fn half_area(&self) -> f32 {
        if self.is_empty() {
            return 0.0;
        }
        let d = self.max - self.min;
        d.x * d.y + d.y * d.z + d.z * d.x
    }

    /// The length of the diagonal from `min` to `max`; 0 for an empty box.
    pub fn diagonal(&self) -> f32 {
        if self.is_empty() {
            0.0
        } else {
            (self.max - self.min).length()
        }
    }
}

/// Moves a surface point off its surface along the geometric normal `n`
/// (pointing to the side the new ray leaves from), so that the new ray does
/// not hit the surface it starts on. The offset is a few ULPs of the point's
/// own coordinates, so it scales with distance from the origin instead of
/// being a fixed epsilon that is too small far away and too large up close
/// (Wächter and Binder, "A Fast and Robust Method for Avoiding
/// Self-Intersection", Ray Tracing Gems, 2019).
pub fn offset_ray_origin(p: Vec3, n: Vec3) -> Vec3 {
    const ORIGIN: f32 = 1.0 / 32.0;
    const FLOAT_SCALE: f32 = 1.0 / 65536.0;
    const INT_SCALE: f32 = 256.0;
    let mut out = [0.0f32; 3];
    for i in 0..3 {
        let of_i = (INT_SCALE * n[i]) as i32;
        let pi = p[i];
        let bits = pi.to_bits() as i32;
        let moved = f32::from_bits(bits.wrapping_add(if pi < 0.0 { -of_i } else { of_i }) as u32);
        out[i] = if pi.abs() < ORIGIN {
            pi + FLOAT_SCALE * n[i]
        } else {
            moved
        };
    }
    Vec3::from(out)
}

/// Moves surface point `p` off its surface along the unit geometric normal
/// `n` (pointing to the side the new ray leaves from) by 2⁻¹⁶·m, where m is
/// the larger of `scale` and p's largest coordinate. `scale` is the
/// magnitude of the numbers p was computed from (the triangle's vertices
/// and the instance's translation, a sphere's centre plus radius, a plane's
/// point), which bounds p's rounding error at a few ULPs of m. This is the
/// renderer's offset; it differs from [`offset_ray_origin`] (Wächter and
/// Binder) in one way that matters at the extremes: near the origin W&B add
/// a fixed 2⁻¹⁶, which is 15% of a scene 10⁻⁴ units across and too little
/// for a point near 0 computed from big coordinates, while this offset
/// scales with the numbers involved. 2⁻¹⁶ is about 128 ULPs of m: safely
/// above the error of p (a few ULPs), and far below anything an image can
/// show (a pixel of a 1000-pixel-wide 60° view at distance D is 10⁻³·D
/// across, the offset at most 1.5·10⁻⁵·D).
#[inline]
pub fn offset_from_surface(p: Vec3, n: Vec3, scale: f32) -> Vec3 {
    let m = scale.max(p.abs().max_element()).max(f32::MIN_POSITIVE);
    p + n * (m * (1.0 / 65536.0))
}

/// The ray–box slab test: the entry distance if the ray meets `b` within
/// `(0, t_max)`. `inv_dir` is `1/dir` per component (±inf for zero components;
/// `min`/`max` then discard the NaN of `0·inf`).
#[inline(always)]
pub fn ray_box(origin: Vec3, inv_dir: Vec3, b_min: Vec3, b_max: Vec3, t_max: f32) -> Option<f32> {
    let t0 = (b_min - origin) * inv_dir;
    let t1 = (b_max - origin) * inv_dir;
    let tmin = t0.min(t1);
    let tmax = t0.max(t1);
    let enter = tmin.x.max(tmin.y).max(tmin.z).max(0.0);
    let exit = tmax.x.min(tmax.y).min(tmax.z).min(t_max);
    // The 1.0000004 factor keeps rays grazing a box face from being culled by
    // rounding (Ize, "Robust BVH Ray Traversal", 2013).
    if enter <= exit * 1.000_000_4 {
        Some(enter)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offset_leaves_the_surface_on_the_normal_side_at_every_scale() {
        for &s in &[1e-4f32, 0.01, 1.0, 1e3, 1e6] {
            let p = Vec3::new(s, -s, 0.5 * s);
            let n = Vec3::new(0.0, 1.0, 0.0);
            let q = offset_ray_origin(p, n);
            assert!(q.y > p.y, "scale {s}");
            assert_eq!(q.x, p.x);
            let q = offset_ray_origin(p, -n);
            assert!(q.y < p.y, "scale {s}");
        }
    }

    #[test]
    fn scaled_offset_leaves_the_surface_at_every_scale_and_stays_relative() {
        for &s in &[1e-30f32, 1e-4, 1.0, 1e6, 1e30] {
            for &(p, scale) in &[(Vec3::new(s, -s, 0.5 * s), s), (Vec3::ZERO, s)] {
                let n = Vec3::new(0.0, 0.6, 0.8);
                let q = offset_from_surface(p, n, scale);
                let d = (q - p).dot(n);
                assert!(d > 0.0, "scale {s}");
                assert!(d <= 3e-5 * s, "scale {s}: offset {d}");
                let q = offset_from_surface(p, -n, scale);
                assert!((q - p).dot(n) < 0.0, "scale {s}");
            }
        }
    }

    #[test]
    fn ray_box_hits_and_misses() {
        let (lo, hi) = (Vec3::splat(-1.0), Vec3::splat(1.0));
        let o = Vec3::new(0.0, 0.0, -5.0);
        let d = Vec3::new(0.0, 0.0, 1.0);
        assert_eq!(ray_box(o, d.recip(), lo, hi, f32::INFINITY), Some(4.0));
        assert_eq!(ray_box(o, d.recip(), lo, hi, 3.0), None);
        let d2 = Vec3::new(0.0, 1.0, 0.0);
        assert_eq!(ray_box(o, d2.recip(), lo, hi, f32::INFINITY), None);
        // Origin inside: enters at 0.
        assert_eq!(ray_box(Vec3::ZERO, d.recip(), lo, hi, 10.0), Some(0.0));
        // Zero direction components (inv_dir = inf) inside the slab still hit.
        let o3 = Vec3::new(-5.0, 0.5, 0.25);
        let d3 = Vec3::new(1.0, 0.0, 0.0);
        assert_eq!(ray_box(o3, d3.recip(), lo, hi, f32::INFINITY), Some(4.0));
    }
}
