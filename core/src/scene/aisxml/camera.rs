//! `<camera>`: where the eye is, where it looks, its lens; with its one
//! `<render>` child.

use super::table::{attr, Attribute, REQUIRED};
use super::xml::{excerpt, Elem};
use super::{req_vec3, Resolver, Result};
use crate::error::SceneErrorKind;
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
        for c in &e.children {
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
        self.desc.cameras.push(CameraDesc {
            id,
            position,
            direction: direction.as_vec3().normalize_or(Vec3::NEG_Z),
            up: up.as_vec3().normalize_or(Vec3::Y),
            fov: fov as f32,
            aperture: aperture as f32,
            focus: focus as f32,
            lens,
            render,
        });
        Ok(())
    }
}
