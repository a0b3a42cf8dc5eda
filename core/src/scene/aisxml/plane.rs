//! `<plane>`: an infinite, two-sided plane with an optional `<surface>`.

use super::table::{attr, Attribute, REQUIRED};
use super::xml::Elem;
use super::{req_vec3, Resolver, Result};
use crate::scene::Plane;
use glam::{DVec3, Vec3};

/// The attributes of `<plane>`.
pub(super) const PLANE: &[Attribute] = &[
    attr(
        "id",
        "id",
        REQUIRED,
        "the plane's name, unique among models, spheres and planes",
    ),
    attr("point", "point", REQUIRED, "a point \"x y z\" on the plane"),
    attr(
        "normal",
        "direction",
        REQUIRED,
        "the plane's normal (non-zero)",
    ),
];

impl<'a> Resolver<'a> {
    pub(super) fn plane(&mut self, e: &'a Elem) -> Result<()> {
        let el = self.el(e);
        el.check_attrs(PLANE)?;
        let (id_attr, id) = el.id("id")?;
        Self::claim(self.src, &mut self.object_ids, &el, id_attr, &id)?;
        let point = req_vec3(&el, "point")?;
        el.req("normal")?;
        let normal = el.direction("normal")?.unwrap_or(DVec3::Y);
        let surface = self.single_surface(e)?;
        self.desc.planes.push(Plane {
            id,
            point,
            normal: normal.as_vec3().normalize_or(Vec3::Y),
            surface,
        });
        Ok(())
    }
}
