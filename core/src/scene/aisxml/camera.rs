//! `<camera>`: where the eye is, where it looks, its lens; with its one
//! `<render>` child.

use super::animation::{Keys, Kind};
use super::table::{attr, Attribute, REQUIRED};
use super::xml::{excerpt, Elem};
use super::{req_vec3, Resolver, Result};
use crate::error::SceneErrorKind;
use crate::scene::animation::CameraAnimation;
use crate::scene::{CameraDesc, Lens};
use glam::{DVec3, Vec3};

/// The attributes of `<camera>`.
pub(super) const CAMERA: &[Attribute] = &[
    attr(
        "id",
        "id",
        REQUIRED,
        "the camera's name, unique among cameras",
    ),
    attr("position", "point", REQUIRED, "the eye"),
    attr(
        "direction",
        "direction",
        "required unless lookat",
        "the view direction (exactly one of direction and lookat)",
    ),
    attr(
        "lookat",
        "point",
        "required unless direction",
        "a point the camera looks at (exactly one of direction and lookat)",
    ),
    attr(
        "up",
        "direction",
        "0 1 0",
        "the image's up, not parallel to the view direction",
    ),
    attr(
        "fov",
        "real in (0, 180)",
        REQUIRED,
        "the horizontal field of view in degrees",
    ),
    attr(
        "aperture",
        "real ≥ 0",
        "0",
        "the lens' size; > 0 gives depth of field",
    ),
    attr(
        "focus",
        "real > 0",
        "|lookat − position|",
        "the distance of the focal plane (required with direction and aperture > 0)",
    ),
    attr("lens", "square | disk", "square", "the lens' shape"),
];

/// The channels of a `<camera>`'s `<animate>` (docs/aisxml-extensions.md).
const CAMERA_CHANNELS: &[(&str, Kind)] = &[
    ("position", Kind::Vector),
    ("direction", Kind::Direction),
    ("lookat", Kind::Vector),
    ("fov", Kind::Fov),
    ("focus", Kind::Positive),
];

impl<'a> Resolver<'a> {
    pub(super) fn camera(&mut self, e: &'a Elem) -> Result<()> {
        let el = self.el(e);
        el.check_attrs(CAMERA)?;
        let (id_attr, id) = el.id("id")?;
        Self::claim(self.src, &mut self.camera_ids, &el, id_attr, &id)?;
        let position = req_vec3(&el, "position")?;
        let (dir_attr, direction, look_distance) = match (el.get("direction"), el.get("lookat")) {
            (Some(d), Some(l)) => {
                let later = if d.pos > l.pos { d } else { l };
                return Err(el.attr_err(
                    later,
                    "expected exactly one of \"direction\" and \"lookat\", found both",
                ));
            }
            (None, None) => {
                return Err(el.err(
                    "<camera> needs exactly one of the attributes \"direction\" and \"lookat\" (found neither)",
                ).with_kind(SceneErrorKind::Missing))
            }
            (Some(d), None) => (d, el.direction("direction")?.unwrap_or(DVec3::NEG_Z), None),
            (None, Some(l)) => {
                let target = el.vec3("lookat")?.unwrap_or(DVec3::ZERO);
                let to = target - position;
                let dist = to.length();
                let dir = to.normalize_or_zero();
                if dist as f32 <= 0.0 || dir == DVec3::ZERO || !dist.is_finite() {
                    return Err(el.expected(
                        l,
                        "a point different from the camera's position",
                    ));
                }
                (l, dir, Some(dist))
            }
        };
        let up = el.direction("up")?.unwrap_or(DVec3::Y);
        if direction.cross(up).length() < 1e-9 {
            let at = el.get("up").unwrap_or(dir_attr);
            return Err(el.attr_err(
                at,
                "the view direction is parallel to up (expected a direction not parallel to up)",
            ).with_kind(SceneErrorKind::BadValue));
        }
        el.req("fov")?;
        let fov = el
            .real_in("fov", "a number in (0, 180)", |v| v > 0.0 && v < 180.0)?
            .unwrap_or(50.0);
        let aperture = el
            .real_in("aperture", "a number ≥ 0", |v| v >= 0.0)?
            .unwrap_or(0.0);
        let lens = el
            .keyword("lens", &[("square", Lens::Square), ("disk", Lens::Disk)])?
            .unwrap_or(Lens::Square);
        let focus = el.real_in("focus", "a number > 0", |v| v > 0.0)?;
        let focus = match (focus, look_distance) {
            (Some(f), _) => f,
            (None, Some(d)) => d,
            (None, None) if aperture > 0.0 => {
                return Err(el.err(
                    "<camera> with \"direction\" and aperture > 0 is missing its required attribute \"focus\"",
                ).with_kind(SceneErrorKind::Missing))
            }
            (None, None) => 1.0,
        };

        let mut render: Option<&'a Elem> = None;
        for c in e.children.iter().filter(|c| c.name == "render") {
            if let Some(first) = render {
                return Err(self.src.err(
                    c.pos,
                    format!(
                        "second <render> in <camera> \"{}\" (the first is at {}; expected exactly one)",
                        excerpt(&id),
                        self.src.line_col(first.pos)
                    ),
                ).with_kind(SceneErrorKind::UnknownElement));
            }
            render = Some(c);
        }
        let Some(render) = render else {
            return Err(el
                .err(format!(
                    "<camera> \"{}\" has no <render> child (expected exactly one)",
                    excerpt(&id)
                ))
                .with_kind(SceneErrorKind::Missing));
        };
        let render = self.render(render, &el, id_attr, &id)?;
        let camera = CameraDesc {
            id,
            position,
            direction: direction.as_vec3().normalize_or(Vec3::NEG_Z),
            up: up.as_vec3().normalize_or(Vec3::Y),
            fov: fov as f32,
            aperture: aperture as f32,
            focus: focus as f32,
            lens,
            render,
        };
        let keys = self.animates(e, CAMERA_CHANNELS)?;
        if keys.is_empty() {
            self.desc.cameras.push(camera);
            return Ok(());
        }
        let lookat = match look_distance {
            Some(_) => el.vec3("lookat")?,
            None => None,
        };
        let find = |i: usize| keys.iter().find(|k| k.channel == i);
        let wrong = match lookat {
            Some(_) => find(1).map(|k| (k, "direction", "lookat")),
            None => find(2).map(|k| (k, "lookat", "direction")),
        };
        if let Some((k, keyed, has)) = wrong {
            return Err(self.src.err(
                k.pos,
                format!("<animate channel=\"{keyed}\"> on a <camera> with {has}= (expected the channel of the attribute the camera has, \"{has}\")"),
            ).with_kind(SceneErrorKind::BadValue));
        }
        let anim = CameraAnimation {
            camera: self.desc.cameras.len(),
            base: camera,
            lookat,
            focus_given: el.get("focus").is_some(),
            position: find(0).map(Keys::track),
            direction: find(1).map(Keys::track),
            lookat_keys: find(2).map(Keys::track),
            fov: find(3).map(Keys::track),
            focus: find(4).map(Keys::track),
        };
        // Every key's time must give a camera (the times between are checked
        // when a frame is made).
        let mut at_zero = None;
        for k in &keys {
            for &t in k.times.iter().chain([0.0].iter()) {
                match anim.camera_at(t) {
                    Ok(c) if t == 0.0 => at_zero = Some(c),
                    Ok(_) => {}
                    Err(problem) => {
                        return Err(self
                            .src
                            .err(
                                k.pos,
                                format!("{problem} (expected keys that make a camera)"),
                            )
                            .with_kind(SceneErrorKind::BadValue))
                    }
                }
            }
        }
        self.desc
            .cameras
            .push(at_zero.unwrap_or_else(|| anim.base.clone()));
        self.desc.animation.cameras.push(anim);
        Ok(())
    }
}
