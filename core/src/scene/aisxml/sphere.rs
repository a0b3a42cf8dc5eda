//! `<sphere>`: an analytic sphere with an optional `<surface>`.

use super::table::{attr, Attribute, REQUIRED};
use super::xml::Elem;
use super::{req_vec3, Resolver, Result};
use crate::scene::Sphere;

/// The attributes of `<sphere>`.
pub(super) const SPHERE: &[Attribute] = &[
    attr(
        "id",
        "id",
        REQUIRED,
        "the sphere's name, unique among models, spheres and planes",
    ),
    attr("center", "point", REQUIRED, "the centre \"x y z\""),
    attr("radius", "real > 0", REQUIRED, "the radius"),
];

impl<'a> Resolver<'a> {
    pub(super) fn sphere(&mut self, e: &'a Elem) -> Result<()> {
        let el = self.el(e);
        el.check_attrs(SPHERE)?;
        self.room_for_an_object(&el)?;
        let (id_attr, id) = el.id("id")?;
        Self::claim(self.src, &mut self.object_ids, &el, id_attr, &id)?;
        let center = req_vec3(&el, "center")?;
        el.req("radius")?;
        let radius = el
            .real_in("radius", "a number > 0", |r| r > 0.0)?
            .unwrap_or(1.0);
        let surface = self.single_surface(e)?;
        self.desc.spheres.push(Sphere {
            id,
            center,
            radius: radius as f32,
            surface,
        });
        Ok(())
    }
}
