//! Keyframed animation (a Trevi extension, docs/aisxml-extensions.md
//! "Animation"): what `<animate>` elements say, resolved, and the scene's
//! values at a time `t` in seconds.
//!
//! Every channel is a list of keys `(tᵢ, vᵢ)` with strictly increasing
//! times. At time `t`: before the first key the first value holds, after the
//! last key the last value holds; between `tᵢ` and `tᵢ₊₁`, with
//! `u = (t − tᵢ) / (tᵢ₊₁ − tᵢ)`, vectors and numbers are `vᵢ + (vᵢ₊₁ − vᵢ)·u`
//! and rotations are the spherical interpolation (shortest arc) of the two
//! keys' unit quaternions. Everything is evaluated in f64 and rounded to the
//! renderer's f32 only where the static description is.

use super::{CameraDesc, Light, SceneDesc};
use glam::{DMat4, DQuat, DVec3, Vec3};

/// Most keys in one channel (one `<animate>`): bounds what a scene file can
/// make the parser hold per channel (32 bytes a key at most).
pub const MAX_KEYS: usize = 65_536;

/// One keyed channel with `N` numbers per key.
#[derive(Debug, Clone, PartialEq)]
pub struct Track<const N: usize> {
    /// Strictly increasing, finite; at least one.
    pub times: Vec<f64>,
    /// One value per time.
    pub values: Vec<[f64; N]>,
}

/// Where `t` falls among a track's keys.
enum At {
    /// Before the first key, after the last, or exactly on key `i`.
    Key(usize),
    /// Between keys `i` and `i + 1`, at the fraction `u ∈ (0, 1)`.
    Between(usize, f64),
}

impl<const N: usize> Track<N> {
    fn at(&self, t: f64) -> At {
        let n = self.times.len();
        // The first key whose time is > t.
        let j = self.times.partition_point(|&k| k <= t);
        if j == 0 {
            return At::Key(0);
        }
        if j == n || self.times[j - 1] == t {
            return At::Key(j - 1);
        }
        let (t0, t1) = (self.times[j - 1], self.times[j]);
        At::Between(j - 1, (t - t0) / (t1 - t0))
    }

    /// The linear interpolation of the values at `t` (held outside the keys).
    pub fn lerp(&self, t: f64) -> [f64; N] {
        match self.at(t) {
            At::Key(i) => self.values[i],
            At::Between(i, u) => {
                let (a, b) = (self.values[i], self.values[i + 1]);
                std::array::from_fn(|k| a[k] + (b[k] - a[k]) * u)
            }
        }
    }
}

impl Track<3> {
    /// The vector at `t` ([`Track::lerp`]).
    pub fn vec3(&self, t: f64) -> DVec3 {
        DVec3::from_array(self.lerp(t))
    }
}

impl Track<1> {
    /// The number at `t` ([`Track::lerp`]).
    pub fn scalar(&self, t: f64) -> f64 {
        self.lerp(t)[0]
    }
}

impl Track<4> {
    /// A rotation track (`x y z angle°`, axis normalised by the parser):
    /// the slerp of the keys' quaternions, as a matrix.
    pub fn rotation(&self, t: f64) -> DMat4 {
        let q = |i: usize| {
            let [x, y, z, deg] = self.values[i];
            DQuat::from_axis_angle(DVec3::new(x, y, z), deg.to_radians())
        };
        let r = match self.at(t) {
            At::Key(i) => q(i),
            At::Between(i, u) => q(i).slerp(q(i + 1), u).normalize(),
        };
        DMat4::from_quat(r)
    }
}

/// The keyed channels of one `<model>`. Its world transform at `t` is
/// `T(t) · R(t) · S(t) · static`, where `static` is the model's
/// [`super::Model::transform`] without animation (its `<transform>`, and the
/// parser's recentring on the right): the keyed scale is applied after the
/// static transform, then the keyed rotation (about the world's origin),
/// then the keyed translation. A channel without keys is the identity.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelAnimation {
    /// Index into [`SceneDesc::models`].
    pub model: usize,
    /// The static transform the keyed channels apply to (`static` above).
    pub base: DMat4,
    /// The keyed translation, in scene units.
    pub translate: Option<Track<3>>,
    /// `x y z angle` (axis normalised, angle in degrees).
    pub rotate: Option<Track<4>>,
    /// Per-axis factors, each > 0.
    pub scale: Option<Track<3>>,
}

impl ModelAnimation {
    /// The model's object-to-world transform at time `t` (seconds).
    pub fn transform(&self, t: f64) -> DMat4 {
        let mut m = self.base;
        if let Some(s) = &self.scale {
            m = DMat4::from_scale(s.vec3(t)) * m;
        }
        if let Some(r) = &self.rotate {
            m = r.rotation(t) * m;
        }
        if let Some(tr) = &self.translate {
            m = DMat4::from_translation(tr.vec3(t)) * m;
        }
        m
    }
}

/// The keyed channels of one `<camera>`; an unkeyed channel keeps the
/// camera's attribute.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraAnimation {
    /// Index into [`SceneDesc::cameras`].
    pub camera: usize,
    /// The camera as its attributes say (the unkeyed values).
    pub base: CameraDesc,
    /// The camera's `lookat`, when it has one (then `direction` is never keyed).
    pub lookat: Option<DVec3>,
    /// The camera has an explicit `focus` attribute.
    pub focus_given: bool,
    /// The keyed eye position.
    pub position: Option<Track<3>>,
    /// Linear, then normalised.
    pub direction: Option<Track<3>>,
    /// The keyed `lookat` point (only with `lookat`).
    pub lookat_keys: Option<Track<3>>,
    /// The keyed horizontal field of view, in degrees.
    pub fov: Option<Track<1>>,
    /// The keyed focus distance (each key > 0).
    pub focus: Option<Track<1>>,
}

/// A frame's camera that cannot be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("camera \"{camera}\" at t = {t} s: {problem}")]
pub struct FrameError {
    /// The camera's id.
    pub camera: String,
    /// The time, in seconds.
    pub t: f64,
    /// What is wrong with the camera then.
    pub problem: &'static str,
}

impl CameraAnimation {
    /// The camera at time `t` (seconds); an error when the keys give no
    /// camera there (the lookat point at the eye, a zero or up-parallel
    /// view direction, a focus distance of 0).
    pub fn camera_at(&self, t: f64) -> Result<CameraDesc, FrameError> {
        let b = &self.base;
        let err = |problem| FrameError {
            camera: b.id.clone(),
            t,
            problem,
        };
        let position = self.position.as_ref().map_or(b.position, |p| p.vec3(t));
        let (direction, distance) = match self.lookat {
            Some(l) => {
                let target = self.lookat_keys.as_ref().map_or(l, |k| k.vec3(t));
                let to = target - position;
                let d = to.length();
                if !(d as f32 > 0.0) || !d.is_finite() {
                    return Err(err("the lookat point is at the camera's position"));
                }
                (to / d, Some(d))
            }
            None => match &self.direction {
                Some(k) => {
                    let d = k.vec3(t).normalize_or_zero();
                    if d == DVec3::ZERO {
                        return Err(err("the interpolated view direction is zero"));
                    }
                    (d, None)
                }
                None => (b.direction.as_dvec3(), None),
            },
        };
        if direction.cross(b.up.as_dvec3()).length() < 1e-9 {
            return Err(err("the view direction is parallel to up"));
        }
        let focus = match (&self.focus, self.focus_given, distance) {
            (Some(k), _, _) => k.scalar(t) as f32,
            (None, false, Some(d)) => d as f32,
            _ => b.focus,
        };
        if !(focus > 0.0) {
            return Err(err("the focus distance rounds to 0"));
        }
        Ok(CameraDesc {
            position,
            direction: direction.as_vec3().normalize_or(Vec3::NEG_Z),
            fov: self.fov.as_ref().map_or(b.fov, |k| k.scalar(t) as f32),
            focus,
            ..b.clone()
        })
    }
}

/// The keyed channels of one `<light>`.
#[derive(Debug, Clone, PartialEq)]
pub struct LightAnimation {
    /// Index into [`SceneDesc::lights`].
    pub light: usize,
    /// The light as its attributes say (the unkeyed values).
    pub base: Light,
    /// The keyed position.
    pub position: Option<Track<3>>,
    /// Each key ≥ 0.
    pub intensity: Option<Track<1>>,
}

impl LightAnimation {
    /// The light at time `t` (seconds).
    pub fn light_at(&self, t: f64) -> Light {
        let b = &self.base;
        Light {
            position: self.position.as_ref().map_or(b.position, |p| p.vec3(t)),
            intensity: self
                .intensity
                .as_ref()
                .map_or(b.intensity, |k| k.scalar(t) as f32),
            ..b.clone()
        }
    }
}

/// Every keyed channel of a scene.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Animation {
    /// The animated models, in document order.
    pub models: Vec<ModelAnimation>,
    /// The animated cameras, in document order.
    pub cameras: Vec<CameraAnimation>,
    /// The animated lights, in document order.
    pub lights: Vec<LightAnimation>,
}

impl Animation {
    /// Whether nothing in the scene is keyed (the scene is the same at
    /// every time).
    pub fn is_empty(&self) -> bool {
        self.models.is_empty() && self.cameras.is_empty() && self.lights.is_empty()
    }

    /// Sets every animated model, camera and light of `desc` to its value
    /// at time `t` (seconds). On an error `desc` may be partly updated.
    pub fn apply(&self, desc: &mut SceneDesc, t: f64) -> Result<(), FrameError> {
        for m in &self.models {
            desc.models[m.model].transform = m.transform(t);
        }
        for l in &self.lights {
            desc.lights[l.light] = l.light_at(t);
        }
        for c in &self.cameras {
            desc.cameras[c.camera] = c.camera_at(t)?;
        }
        Ok(())
    }
}

/// The range of frames `<render frames="first-last" fps>` renders.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frames {
    /// The first frame rendered.
    pub first: u32,
    /// The last frame rendered (included; `first..=last`, at most
    /// [`MAX_FRAME`]).
    pub last: u32,
}

/// Largest frame number: frame numbers fit in 7 digits, and a range's count
/// in a `u32`.
pub const MAX_FRAME: u32 = 9_999_999;

/// The default `fps`.
pub const DEFAULT_FPS: f64 = 24.0;

/// The time of frame `frame` at `fps` frames per second: `frame / fps`
/// seconds (frame 0 is at t = 0).
pub fn frame_time(frame: u32, fps: f64) -> f64 {
    f64::from(frame) / fps
}

/// The runs of `#` in output path `path` (`/`-separated, like `output=`
/// and `-o`), if it is a valid output: 0 for a still's file name, 1 for a
/// sequence's pattern. `None` when a `#` is in a directory or the file name
/// has more than one run: one rule for the scene parser and trevi-submit.
pub fn frame_runs(path: &str) -> Option<usize> {
    let name = path.rsplit('/').next().unwrap_or(path);
    let runs = name
        .as_bytes()
        .split(|&b| b != b'#')
        .filter(|r| !r.is_empty())
        .count();
    let in_dir = path[..path.len() - name.len()].contains('#');
    (!in_dir && runs <= 1).then_some(runs)
}

/// An output path split at its first run of `#`: what comes before it, the
/// run's length and what comes after it; a still's name (no `#`) is all
/// prefix, with a run of 0.
pub fn split_pattern(pattern: &str) -> (&str, usize, &str) {
    match pattern.find('#') {
        None => (pattern, 0, ""),
        Some(i) => {
            let n = pattern[i..].bytes().take_while(|&b| b == b'#').count();
            (&pattern[..i], n, &pattern[i + n..])
        }
    }
}

/// An output pattern's name for one frame: its one run of `#` replaced by
/// the frame number, zero-padded to the run's length (longer numbers are
/// written in full).
pub fn frame_output(pattern: &str, frame: u32) -> String {
    match split_pattern(pattern) {
        (_, 0, _) => pattern.to_string(),
        (prefix, n, suffix) => format!("{prefix}{frame:0n$}{suffix}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rot(keys: &[(f64, f64)]) -> Track<4> {
        Track {
            times: keys.iter().map(|k| k.0).collect(),
            values: keys.iter().map(|k| [0.0, 1.0, 0.0, k.1]).collect(),
        }
    }

    fn close(a: DMat4, b: DMat4) -> bool {
        a.abs_diff_eq(b, 1e-12)
    }

    #[test]
    fn quarter_turns_interpolate_along_the_arc() {
        let r = rot(&[(0.0, 0.0), (1.0, 90.0), (2.0, 180.0)]);
        let y = |deg: f64| DMat4::from_rotation_y(deg.to_radians());
        assert!(close(r.rotation(0.5), y(45.0)));
        assert!(close(r.rotation(1.0), y(90.0)));
        assert!(close(r.rotation(1.5), y(135.0)));
        assert!(close(r.rotation(0.25), y(22.5)));
        // A quarter turn takes the +X axis to −Z; halfway it is on the diagonal.
        let h = r.rotation(0.5).transform_vector3(DVec3::X);
        let s = std::f64::consts::FRAC_1_SQRT_2;
        assert!(h.abs_diff_eq(DVec3::new(s, 0.0, -s), 1e-12));
    }

    #[test]
    fn rotation_ends_hold() {
        let r = rot(&[(1.0, 30.0), (2.0, 60.0)]);
        let y = |deg: f64| DMat4::from_rotation_y(deg.to_radians());
        assert!(close(r.rotation(-5.0), y(30.0)));
        assert!(close(r.rotation(1.0), y(30.0)));
        assert!(close(r.rotation(2.0), y(60.0)));
        assert!(close(r.rotation(1e9), y(60.0)));
    }

    #[test]
    fn scale_midpoints_and_held_ends() {
        let s = Track {
            times: vec![0.0, 2.0],
            values: vec![[1.0, 2.0, 4.0], [3.0, 2.0, 8.0]],
        };
        assert_eq!(s.lerp(1.0), [2.0, 2.0, 6.0]);
        assert_eq!(s.lerp(0.5), [1.5, 2.0, 5.0]);
        assert_eq!(s.lerp(-1.0), [1.0, 2.0, 4.0]);
        assert_eq!(s.lerp(2.0), [3.0, 2.0, 8.0]);
        assert_eq!(s.lerp(7.0), [3.0, 2.0, 8.0]);
    }

    #[test]
    fn a_single_key_holds_everywhere() {
        let s = Track {
            times: vec![3.0],
            values: vec![[5.0]],
        };
        for t in [-1.0, 0.0, 3.0, 10.0] {
            assert_eq!(s.scalar(t), 5.0);
        }
    }

    #[test]
    fn keyed_transform_composes_after_the_static_one() {
        // static: scale 2; keyed: rotate a quarter turn about y, then move +x.
        let m = ModelAnimation {
            model: 0,
            base: DMat4::from_scale(DVec3::splat(2.0)),
            translate: Some(Track {
                times: vec![0.0, 1.0],
                values: vec![[0.0; 3], [10.0, 0.0, 0.0]],
            }),
            rotate: Some(rot(&[(0.0, 0.0), (1.0, 90.0)])),
            scale: Some(Track {
                times: vec![0.0, 1.0],
                values: vec![[1.0; 3], [3.0; 3]],
            }),
        };
        // At t = 1: (1,0,0) → static ×2 → (2,0,0) → keyed ×3 → (6,0,0)
        // → quarter turn about y → (0,0,−6) → +10 x → (10,0,−6).
        let p = m.transform(1.0).transform_point3(DVec3::X);
        assert!(p.abs_diff_eq(DVec3::new(10.0, 0.0, -6.0), 1e-12), "{p}");
        // At t = 0.5: ×2, ×2, 45°, +5 x.
        let p = m.transform(0.5).transform_point3(DVec3::X);
        let s = 4.0 * std::f64::consts::FRAC_1_SQRT_2;
        assert!(p.abs_diff_eq(DVec3::new(5.0 + s, 0.0, -s), 1e-12), "{p}");
    }

    #[test]
    fn frame_times_and_outputs() {
        assert_eq!(frame_time(0, 24.0), 0.0);
        assert_eq!(frame_time(1, 24.0), 1.0 / 24.0);
        assert_eq!(frame_time(48, 24.0), 2.0);
        assert_eq!(frame_output("shot.####.png", 7), "shot.0007.png");
        assert_eq!(frame_output("shot.##.png", 12345), "shot.12345.png");
        assert_eq!(frame_output("a/f#.exr", 3), "a/f3.exr");
        assert_eq!(frame_output("still.png", 3), "still.png");
    }
}
