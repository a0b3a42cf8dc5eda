//! Area lights: the emitting surfaces of a view (triangles of models,
//! `<light type="rect">` among them, and spheres whose `<surface>` has
//! `emission` > 0), as path mode's next-event estimation and Whitted mode's
//! shadow rays (`integrator/area.rs`) sample them. Two consecutive triangles
//! forming a parallelogram are kept as one parallelogram emitter.
//!
//! One entry per emitting triangle or sphere, in the view's camera-relative
//! coordinates (built with the view, see `world.rs`), so the memory is
//! bounded by the scene's own triangle and sphere counts. An emitter is
//! chosen with probability proportional to its *weight* mean(Le)·area (the
//! mean of the radiance's three channels times the area), then a point
//! uniformly on it; so the density of a point y on emitter i, per unit area,
//! is mean(Le_i) / W with W the total weight, whatever emitter it lies on.
//! That is what [`AreaLights::pdf_area`] returns for a hit found by BSDF
//! sampling, without looking the emitter up. A sphere is sampled uniformly
//! over its whole area (from outside half the points face away and are
//! blocked by its near side: unbiased, if not the cheapest). Emitting planes
//! are infinite and are not sampled: they light only the paths that hit them.
//!
//! Power: an emitter of radiance Le and area A that emits on one side sends
//! Φ = π·A·Le into the scene (Le over the hemisphere, cosine-weighted);
//! emitting on both sides, 2π·A·Le. See docs/aisxml-extensions.md.

use crate::geometry::offset_from_surface;
use glam::Vec3;

/// The shape of one emitter.
#[derive(Debug, Clone, Copy)]
enum Shape {
    /// Vertex `a`, edges `e1 = b − a`, `e2 = c − a`; the unit front normal is
    /// normalize(e1 × e2) (the side the world-space winding faces).
    Triangle {
        a: Vec3,
        e1: Vec3,
        e2: Vec3,
    },
    Sphere {
        center: Vec3,
        radius: f32,
    },
    /// Corner `a`, edges `e1`, `e2`: the points a + s·e1 + t·e2, s, t in
    /// [0, 1]; front normal normalize(e1 × e2). Two consecutive triangles
    /// that make a parallelogram (a rect light, a quad of a mesh) are merged
    /// into one: the density per area is the same, and one 2D sample covers
    /// the whole quad, so a stratified set of samples stays stratified over
    /// it (the triangle pick would otherwise spend one dimension).
    Parallelogram {
        a: Vec3,
        e1: Vec3,
        e2: Vec3,
    },
}

/// One emitting triangle or sphere.
#[derive(Debug, Clone, Copy)]
pub struct Emitter {
    shape: Shape,
    radiance: Vec3,
    /// Emits on both sides (`sided="two"`); otherwise on the front only.
    two_sided: bool,
    /// The magnitude of its coordinates, for the offset of a shadow ray's end.
    scale: f32,
}

/// A point sampled on an emitter.
#[derive(Debug, Clone, Copy)]
pub struct LightSample {
    /// The point, moved off the emitter towards `toward` (so a shadow ray
    /// that ends there does not hit the emitter itself).
    pub y: Vec3,
    /// The unit normal of the emitter at `y` (the front side for a
    /// triangle, outward for a sphere).
    pub n: Vec3,
    /// The emitter's radiance Le, linear RGB (the same at every point).
    pub radiance: Vec3,
    /// Whether the emitter emits on both sides; otherwise only towards `n`.
    pub two_sided: bool,
    /// Density of `y` per unit area.
    pub pdf_area: f32,
}

/// The emitters of one view with their selection table.
#[derive(Debug, Default)]
pub struct AreaLights {
    emitters: Vec<Emitter>,
    /// Running sums of the weights (f64: exact enough for millions of
    /// emitters); `cdf[i]` is the sum of weights `0..=i`.
    cdf: Vec<f64>,
    total: f64,
}

/// mean(Le): the per-emitter factor of the selection weight.
#[inline]
pub fn mean(c: Vec3) -> f32 {
    (c.x + c.y + c.z) * (1.0 / 3.0)
}

impl AreaLights {
    /// An empty set; add emitters with [`AreaLights::triangle`] and
    /// [`AreaLights::sphere`].
    pub fn new() -> AreaLights {
        AreaLights::default()
    }

    /// Adds the triangle `a b c` (view coordinates) emitting `radiance`.
    /// When the emitter added last is the triangle `a p b` of the same
    /// radiance and sides and the quad `a p b c` is a parallelogram, the two
    /// become one parallelogram emitter.
    pub fn triangle(&mut self, [a, b, c]: [Vec3; 3], radiance: Vec3, two_sided: bool) {
        if let Some(q) = self.parallelogram_with_last([a, b, c], radiance, two_sided) {
            let last = self.emitters.len() - 1;
            self.emitters.pop();
            self.cdf.pop();
            self.total = if last == 0 { 0.0 } else { self.cdf[last - 1] };
            let scale = q.scale;
            let Shape::Parallelogram { e1, e2, .. } = q.shape else {
                unreachable!("parallelogram_with_last returns parallelograms")
            };
            let area = f64::from(e1.cross(e2).length());
            self.push(Emitter { scale, ..q }, area);
            return;
        }
        let (e1, e2) = (b - a, c - a);
        let area = 0.5 * f64::from(e1.cross(e2).length());
        let scale = a.abs().max(b.abs()).max(c.abs()).max_element();
        self.push(
            Emitter {
                shape: Shape::Triangle { a, e1, e2 },
                radiance,
                two_sided,
                scale,
            },
            area,
        );
    }

    /// Adds a sphere emitting `radiance`.
    pub fn sphere(&mut self, center: Vec3, radius: f32, radiance: Vec3, two_sided: bool) {
        let area = 4.0 * std::f64::consts::PI * f64::from(radius) * f64::from(radius);
        let scale = center.abs().max_element() + radius;
        self.push(
            Emitter {
                shape: Shape::Sphere { center, radius },
                radiance,
                two_sided,
                scale,
            },
            area,
        );
    }

    /// The parallelogram the last emitter (a triangle `a p b`) makes with
    /// the triangle `a b c` (its quad `a p b c`), if it does: same first
    /// vertex, its third vertex is this one's second, c − a = b − p (within
    /// rounding), same radiance and sides.
    fn parallelogram_with_last(
        &self,
        [a, b, c]: [Vec3; 3],
        radiance: Vec3,
        two_sided: bool,
    ) -> Option<Emitter> {
        let last = self.emitters.last()?;
        let Shape::Triangle {
            a: a0,
            e1: p_a,
            e2: b_a,
        } = last.shape
        else {
            return None;
        };
        if a0 != a || last.radiance != radiance || last.two_sided != two_sided {
            return None;
        }
        // The quad a, p, b, c: a parallelogram when c − a = b − p. Vertices
        // come from one transform in f32, so "equal" is within rounding.
        let (e1, e2) = (p_a, c - a);
        let size = e1.abs().max_element().max(e2.abs().max_element());
        let shared = (b - a - b_a).abs().max_element();
        let gap = (e2 - (b_a - p_a)).abs().max_element();
        if !(shared <= 1e-5 * size) || !(gap <= 1e-5 * size) {
            return None;
        }
        Some(Emitter {
            shape: Shape::Parallelogram { a, e1, e2 },
            radiance,
            two_sided,
            scale: last.scale.max(c.abs().max_element()),
        })
    }

    fn push(&mut self, e: Emitter, area: f64) {
        let w = f64::from(mean(e.radiance)) * area;
        // A degenerate (zero-area) or non-finite emitter is never chosen:
        // it cannot be hit either.
        if !(w > 0.0) || !w.is_finite() {
            return;
        }
        self.total += w;
        self.cdf.push(self.total);
        self.emitters.push(e);
    }

    /// Whether the view has no emitter to sample (then nothing is).
    pub fn is_empty(&self) -> bool {
        self.emitters.is_empty()
    }

    /// The number of emitters (a merged parallelogram counts once).
    pub fn len(&self) -> usize {
        self.emitters.len()
    }

    /// The density per unit area of a point sampled on an emitter of
    /// radiance `radiance` (the same for every point of every emitter of
    /// that radiance; 0 when nothing is sampled).
    #[inline]
    pub fn pdf_area(&self, radiance: Vec3) -> f32 {
        if self.total > 0.0 {
            (f64::from(mean(radiance)) / self.total) as f32
        } else {
            0.0
        }
    }

    /// An emitter chosen by `u_pick` ∈ [0,1) in proportion to its weight,
    /// and a point on it uniform in area by `u`; the point is moved off the
    /// surface towards `toward` by the renderer's ray offset. `None` when
    /// there are no emitters.
    pub fn sample(&self, u_pick: f32, u: [f32; 2], toward: Vec3) -> Option<LightSample> {
        let last = self.emitters.len().checked_sub(1)?;
        let target = f64::from(u_pick) * self.total;
        // The first emitter whose running sum passes the target.
        let i = self.cdf.partition_point(|&c| c <= target).min(last);
        let e = &self.emitters[i];
        let (y, n) = match e.shape {
            Shape::Triangle { a, e1, e2 } => {
                let su = u[0].sqrt();
                let (b1, b2) = (su * (1.0 - u[1]), su * u[1]);
                let n = e1.cross(e2).normalize_or_zero();
                (a + e1 * b1 + e2 * b2, n)
            }
            Shape::Parallelogram { a, e1, e2 } => {
                (a + e1 * u[0] + e2 * u[1], e1.cross(e2).normalize_or_zero())
            }
            Shape::Sphere { center, radius } => {
                let z = 1.0 - 2.0 * u[0];
                let r = (1.0 - z * z).max(0.0).sqrt();
                // φ = 2π·u[1].
                let (sin_phi, cos_phi) = crate::math::sin_cos_turns(u[1]);
                let n = Vec3::new(r * cos_phi, r * sin_phi, z);
                (center + n * radius, n)
            }
        };
        if n == Vec3::ZERO {
            return None;
        }
        let side = if (toward - y).dot(n) >= 0.0 { n } else { -n };
        Some(LightSample {
            y: offset_from_surface(y, side, e.scale),
            n,
            radiance: e.radiance,
            two_sided: e.two_sided,
            pdf_area: self.pdf_area(e.radiance),
        })
    }

    /// The total power Φ of the emitters (π·A·mean(Le) per emitting side),
    /// in the units of radiance × area.
    pub fn power(&self) -> f64 {
        self.emitters
            .iter()
            .zip(&self.cdf)
            .enumerate()
            .map(|(i, (e, &c))| {
                let w = c - if i == 0 { 0.0 } else { self.cdf[i - 1] };
                let sides = if e.two_sided { 2.0 } else { 1.0 };
                std::f64::consts::PI * sides * w
            })
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn emitters_are_chosen_in_proportion_to_weight_and_points_cover_them_uniformly() {
        let mut l = AreaLights::new();
        // Two unit right triangles (area 1/2), the second three times as bright.
        l.triangle([Vec3::ZERO, Vec3::X, Vec3::Y], Vec3::ONE, false);
        l.triangle(
            [
                Vec3::Z * 5.0,
                Vec3::Z * 5.0 + Vec3::X,
                Vec3::Z * 5.0 + Vec3::Y,
            ],
            Vec3::splat(3.0),
            false,
        );
        // A zero-area triangle is dropped.
        l.triangle([Vec3::ZERO, Vec3::X, Vec3::X * 2.0], Vec3::ONE, false);
        assert_eq!(l.len(), 2);
        let n = 4096;
        let mut second = 0;
        let mut mean_x = 0.0;
        for i in 0..n {
            let u = ((i as f32 + 0.5) / n as f32, ((i * 7) % n) as f32 / n as f32);
            let s = l
                .sample(u.0, [u.1, (i % 64) as f32 / 64.0], Vec3::Z * 100.0)
                .unwrap();
            if s.y.z > 1.0 {
                second += 1;
            } else {
                mean_x += s.y.x;
                assert!(s.y.x >= 0.0 && s.y.y >= 0.0 && s.y.x + s.y.y <= 1.0 + 1e-4);
            }
        }
        assert_eq!(second, 3 * n / 4);
        // The centroid of the triangle is at x = 1/3.
        assert!((mean_x / (n / 4) as f32 - 1.0 / 3.0).abs() < 0.02);
        // pdf per area: mean(Le)/W with W = 0.5·1 + 0.5·3.
        assert!((l.pdf_area(Vec3::splat(3.0)) - 1.5).abs() < 1e-6);
        assert!((l.power() - std::f64::consts::PI * 2.0).abs() < 1e-9);
        assert!(AreaLights::new()
            .sample(0.5, [0.5, 0.5], Vec3::ZERO)
            .is_none());
    }

    /// The two triangles of a quad (a rect light's mesh) become one
    /// parallelogram emitter whose points cover the whole quad uniformly
    /// with one 2D sample; a trapezoid stays two triangles.
    #[test]
    fn the_triangles_of_a_parallelogram_merge_into_one_emitter() {
        let (p0, p1, p2, p3) = (
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(2.0, 1.0, 0.0),
            Vec3::new(2.5, 1.0, 1.0),
            Vec3::new(0.5, 1.0, 1.0),
        );
        let mut l = AreaLights::new();
        l.triangle([p0, p1, p2], Vec3::ONE, false);
        l.triangle([p0, p2, p3], Vec3::ONE, false);
        assert_eq!(l.len(), 1);
        // Area 2 (base 2, height 1), one side: Φ = π·2·1.
        assert!((l.power() - std::f64::consts::TAU).abs() < 1e-6);
        let n = 64;
        let mut mean = Vec3::ZERO;
        for i in 0..n {
            for j in 0..n {
                let u = [(i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32];
                let s = l.sample(0.5, u, Vec3::new(1.0, -5.0, 0.5)).unwrap();
                assert!((s.n - Vec3::NEG_Y).length() < 1e-6, "{}", s.n);
                mean += s.y;
            }
        }
        // The centroid of the parallelogram.
        let c = (p0 + p1 + p2 + p3) / 4.0;
        assert!(((mean / (n * n) as f32) - c).length() < 1e-3);
        let mut t = AreaLights::new();
        t.triangle([p0, p1, p2], Vec3::ONE, false);
        t.triangle([p0, p2, p3 + Vec3::X * 0.3], Vec3::ONE, false);
        assert_eq!(t.len(), 2);
        // Different radiance: not merged either.
        let mut r = AreaLights::new();
        r.triangle([p0, p1, p2], Vec3::ONE, false);
        r.triangle([p0, p2, p3], Vec3::splat(2.0), false);
        assert_eq!(r.len(), 2);
    }

    /// Φ = ∮ E dA over a sphere enclosing a rectangle light, E at each point
    /// of the sphere computed by quadrature over the rectangle
    /// (Le·cos θ_y·cos θ_x/d² per patch): π·A·Le for a one-sided light,
    /// twice that for a two-sided one, as [`AreaLights::power`] says.
    #[test]
    // An independent quadrature (std's sin and cos): it feeds no pixel.
    #[allow(clippy::disallowed_methods)]
    fn a_rect_lights_power_is_the_integral_of_its_irradiance_over_a_sphere() {
        let (w, d, le) = (1.0f64, 0.5f64, 3.0f64);
        let r = 2.0f64;
        for two_sided in [false, true] {
            let mut l = AreaLights::new();
            let (hw, hd) = (w as f32 / 2.0, d as f32 / 2.0);
            let c = [
                Vec3::new(-hw, 0.0, -hd),
                Vec3::new(hw, 0.0, -hd),
                Vec3::new(hw, 0.0, hd),
                Vec3::new(-hw, 0.0, hd),
            ];
            l.triangle([c[0], c[1], c[2]], Vec3::splat(le as f32), two_sided);
            l.triangle([c[0], c[2], c[3]], Vec3::splat(le as f32), two_sided);
            // (1,0,0) × (1,0,1): the front faces −y.
            let (nx, nz, ns, nphi) = (16, 8, 400, 100);
            let mut phi_sum = 0.0;
            for i in 0..ns {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / ns as f64;
                let s = (1.0 - z * z).sqrt();
                for j in 0..nphi {
                    let a = std::f64::consts::TAU * (j as f64 + 0.5) / nphi as f64;
                    // Sphere point with its outward normal; the light's
                    // normal is y, so put the sphere's pole on y.
                    let n_x = glam::DVec3::new(s * a.cos(), z, s * a.sin());
                    let x = n_x * r;
                    let mut e = 0.0;
                    for p in 0..nx {
                        for q in 0..nz {
                            let y = glam::DVec3::new(
                                (p as f64 + 0.5) / nx as f64 * w - w / 2.0,
                                0.0,
                                (q as f64 + 0.5) / nz as f64 * d - d / 2.0,
                            );
                            let to = x - y;
                            let dist2 = to.length_squared();
                            let l = to / dist2.sqrt();
                            let cos_y = -l.y;
                            let emits = if two_sided {
                                cos_y.abs()
                            } else {
                                cos_y.max(0.0)
                            };
                            e += le * emits * l.dot(n_x) / dist2;
                        }
                    }
                    phi_sum += e * (w * d) / (nx * nz) as f64;
                }
            }
            let got = phi_sum * 4.0 * std::f64::consts::PI * r * r / (ns * nphi) as f64;
            let sides = if two_sided { 2.0 } else { 1.0 };
            let expect = std::f64::consts::PI * w * d * le * sides;
            assert!((got - expect).abs() < 2e-3 * expect, "{got} vs {expect}");
            assert!((l.power() - expect).abs() < 1e-5 * expect, "{}", l.power());
        }
    }
}
