//! The pinhole / thin-lens camera exactly as the spec defines it.
//!
//! Frame: w = −d, u = normalize(up × w), v = w × u (the report's u = w × U
//! would mirror the image). View plane: a = u, b = v·height/width,
//! s = 0.5/tan(fov/2), c = −a/2 − b/2 − s·w. Row 0 is the top of the image.
//!
//! Rays come out relative to the camera: the renderer shifts the world so
//! the camera sits at the origin (in f64, before anything is rounded to
//! f32), so primary rays start at 0 (or on the lens around it) and `eye`
//! holds where that is in the world (see docs/numerics.md).

use crate::geometry::Ray;
use crate::sampling::concentric_disk;
use crate::scene::{CameraDesc, Lens};
use glam::{DVec3, Vec3};

/// A scene camera ready to shoot primary rays: its orthonormal frame and
/// view plane, computed once from its [`CameraDesc`].
#[derive(Debug, Clone, Copy)]
pub struct Camera {
    /// The camera's position in the world, in f64: the origin of the
    /// camera-relative coordinates its rays are expressed in.
    pub eye: DVec3,
    /// The pinhole in those coordinates: always zero.
    pub position: Vec3,
    /// The viewing direction, normalised.
    pub d: Vec3,
    /// The image's rightward axis: `up × w`, normalised.
    pub u: Vec3,
    /// The image's upward axis: `w × u` (unit, orthogonal to `d`).
    pub v: Vec3,
    /// `−d`: the frame's third axis, pointing back out of the image.
    pub w: Vec3,
    c: Vec3,
    /// a/width and b/height: one pixel's step along each (the divisions of
    /// the view-plane point, taken once per camera instead of per ray).
    a_px: Vec3,
    b_px: Vec3,
    height: f32,
    aperture: f32,
    focus: f32,
    lens: Lens,
}

impl Camera {
    /// The camera of a description (its direction and up need not be
    /// normalised; the parser has checked that they are not parallel).
    pub fn new(desc: &CameraDesc) -> Camera {
        let d = desc.direction.normalize();
        let w = -d;
        let u = desc.up.cross(w).normalize();
        let v = w.cross(u);
        let width = desc.render.width as f32;
        let height = desc.render.height as f32;
        let s = 0.5 / crate::math::tanf(desc.fov.to_radians() * 0.5);
        let a = u;
        let b = v * (height / width);
        let c = -0.5 * a - 0.5 * b - s * w;
        Camera {
            eye: desc.position,
            position: Vec3::ZERO,
            d,
            u,
            v,
            w,
            c,
            a_px: a / width,
            b_px: b / height,
            height,
            aperture: desc.aperture,
            focus: desc.focus,
            lens: desc.lens,
        }
    }

    /// Whether the camera is a thin lens (aperture over 0), so that rays
    /// start at points on the lens and need their lens samples.
    pub fn has_lens(&self) -> bool {
        self.aperture > 0.0
    }

    /// The pinhole direction through offset `(sx, sy) ∈ [0,1)²` of pixel
    /// (column `i`, row `r`), normalised.
    #[inline]
    pub fn direction(&self, i: u32, r: u32, sx: f32, sy: f32) -> Vec3 {
        (self.c + self.a_px * (i as f32 + sx) + self.b_px * (self.height - r as f32 - sy))
            .normalize()
    }

    /// The primary ray; `lens_u ∈ [0,1)²` picks the point on the lens (unused
    /// for a pinhole camera).
    #[inline]
    pub fn ray(&self, i: u32, r: u32, sx: f32, sy: f32, lens_u: [f32; 2]) -> Ray {
        let dir = self.direction(i, r, sx, sy);
        if self.aperture <= 0.0 {
            return Ray::new(self.position, dir);
        }
        let (x, y) = match self.lens {
            Lens::Square => (
                (lens_u[0] - 0.5) * self.aperture,
                (lens_u[1] - 0.5) * self.aperture,
            ),
            Lens::Disk => {
                let [x, y] = concentric_disk(lens_u);
                (x * 0.5 * self.aperture, y * 0.5 * self.aperture)
            }
        };
        // Aim at where the pinhole ray meets the focal plane (perpendicular
        // to d at distance `focus`).
        let focal_point = self.position + dir * (self.focus / dir.dot(self.d));
        let origin = self.position + self.u * x + self.v * y;
        Ray::new(origin, (focal_point - origin).normalize())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{AoDistance, IntegratorKind, RenderSettings, DEFAULT_MAX_BOUNCES};

    pub(crate) fn desc(fov: f32, w: u32, h: u32) -> CameraDesc {
        CameraDesc {
            id: "c".into(),
            position: DVec3::ZERO,
            direction: -Vec3::Z,
            up: Vec3::Y,
            fov,
            aperture: 0.0,
            focus: 1.0,
            lens: Lens::Square,
            render: RenderSettings {
                width: w,
                height: h,
                supersample: 1,
                jitter: false,
                max_depth: 5,
                shadow_samples: 1,
                ao_samples: 0,
                ao_distance: AoDistance::Auto,
                diffuse_samples: 0,
                diffuse_depth: 1,
                seed: 0,
                output: "c.png".into(),
                adaptive: None,
                integrator: IntegratorKind::Whitted,
                max_bounces: DEFAULT_MAX_BOUNCES,
                aovs: crate::aov::Aovs::NONE,
                denoise: false,
                frames: None,
                fps: 24.0,
            },
        }
    }

    #[test]
    fn looking_down_minus_z_puts_plus_x_right_and_plus_y_up() {
        let cam = Camera::new(&desc(60.0, 100, 50));
        assert!((cam.u - Vec3::X).length() < 1e-6);
        assert!((cam.v - Vec3::Y).length() < 1e-6);
        // Top-left pixel looks up and left; bottom-right looks down and right.
        let tl = cam.direction(0, 0, 0.5, 0.5);
        assert!(tl.x < 0.0 && tl.y > 0.0 && tl.z < 0.0);
        let br = cam.direction(99, 49, 0.5, 0.5);
        assert!(br.x > 0.0 && br.y < 0.0);
    }

    #[test]
    fn horizontal_field_of_view_spans_the_image_width() {
        let fov = 70.0f32;
        let cam = Camera::new(&desc(fov, 200, 100));
        // The left edge of pixel 0 and the right edge of the last pixel.
        let l = cam.direction(0, 50, 0.0, 0.0);
        let r = cam.direction(199, 50, 1.0, 0.0);
        let angle = l.angle_between(r).to_degrees();
        assert!((angle - fov).abs() < 1e-3, "{angle}");
    }

    #[test]
    fn lens_rays_converge_on_the_focal_plane() {
        let mut d = desc(40.0, 64, 64);
        d.aperture = 0.5;
        d.focus = 7.0;
        for lens in [Lens::Square, Lens::Disk] {
            d.lens = lens;
            let cam = Camera::new(&d);
            let pin = cam.ray(10, 20, 0.5, 0.5, [0.5, 0.5]);
            let p_focus = pin.origin + pin.dir * (7.0 / pin.dir.dot(-Vec3::Z));
            for lu in [[0.0, 0.0], [0.9, 0.1], [0.3, 0.7]] {
                let r = cam.ray(10, 20, 0.5, 0.5, lu);
                assert!(r.origin.z.abs() < 1e-6);
                let t = (p_focus.z - r.origin.z) / r.dir.z;
                assert!((r.origin + r.dir * t - p_focus).length() < 1e-4);
            }
        }
    }
}
