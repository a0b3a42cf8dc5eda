//! `<light>`: a point or spot light.

use super::animation::{Keys, Kind};
use super::table::{attr, extension, Attribute, REQUIRED};
use super::xml::Elem;
use super::{req_vec3, Resolver, Result};
use crate::scene::animation::LightAnimation;
use crate::scene::{Light, LightKind};
use glam::{DVec3, Vec3};

/// The attributes of `<light>`.
pub(super) const LIGHT: &[Attribute] = &[
    extension("id", "id", "none", "the light's name, unique among lights"),
    attr("type", "point | spot", "point", "the kind of light"),
    attr("position", "point", REQUIRED, "where the light is"),
    attr("color", "color", "1 1 1", "the light's color"),
    attr("intensity", "real ≥ 0", "1", "the factor on its color"),
    attr(
        "radius",
        "real ≥ 0",
        "0",
        "half the side of the square its shadow rays aim at (soft shadows)",
    ),
    attr(
        "attenuation",
        "three reals ≥ 0, not all 0",
        "1 0 0",
        "c l q of E = color·intensity / (c + l·d + q·d²)",
    ),
    attr(
        "direction",
        "direction",
        "required for a spot",
        "where a spot light points",
    ),
    attr(
        "inner",
        "real in [0, 180)",
        "20",
        "a spot's full-intensity half-angle, in degrees",
    ),
    attr(
        "outer",
        "real in [0, 180)",
        "30",
        "a spot's cut-off half-angle, in degrees",
    ),
];

/// The channels of a `<light>`'s `<animate>` (docs/aisxml-extensions.md).
const LIGHT_CHANNELS: &[(&str, Kind)] =
    &[("position", Kind::Vector), ("intensity", Kind::NonNegative)];

impl<'a> Resolver<'a> {
    pub(super) fn light(&mut self, e: &'a Elem) -> Result<()> {
        let el = self.el(e);
        el.check_attrs(LIGHT)?;
        if el.get("id").is_some() {
            let (id_attr, id) = el.id("id")?;
            Self::claim(self.src, &mut self.light_ids, &el, id_attr, &id)?;
        }
        let spot = el
            .keyword("type", &[("point", false), ("spot", true)])?
            .unwrap_or(false);
        let position = req_vec3(&el, "position")?;
        let color = el.color("color")?.unwrap_or(Vec3::ONE);
        let intensity = el
            .real_in("intensity", "a number ≥ 0", |v| v >= 0.0)?
            .unwrap_or(1.0);
        let radius = el
            .real_in("radius", "a number ≥ 0", |v| v >= 0.0)?
            .unwrap_or(0.0);
        let attenuation = match el.get("attenuation") {
            None => Vec3::new(1.0, 0.0, 0.0),
            Some(a) => {
                let what = "three numbers \"c l q\", each ≥ 0 and not all 0";
                let v = el.reals(a, &[3], what)?;
                if v.iter().any(|&x| x < 0.0) || v.iter().all(|&x| x == 0.0) {
                    return Err(el.expected(a, what));
                }
                Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32)
            }
        };
        let kind = if spot {
            el.req("direction")?;
            let direction = el.direction("direction")?.unwrap_or(DVec3::NEG_Y);
            let angle = "a half-angle in degrees in [0, 180)";
            let in_range = |v: f64| (0.0..180.0).contains(&v);
            let inner = el.real_in("inner", angle, in_range)?.unwrap_or(20.0);
            let outer = el.real_in("outer", angle, in_range)?.unwrap_or(30.0);
            if inner > outer {
                return Err(match (el.get("outer"), el.get("inner")) {
                    (Some(o), _) => {
                        el.expected(o, &format!("an angle ≥ inner ({inner}) and < 180"))
                    }
                    (None, Some(i)) => {
                        el.expected(i, &format!("an angle ≤ outer ({outer}, the default)"))
                    }
                    (None, None) => el.err("inner half-angle exceeds outer"),
                });
            }
            LightKind::Spot {
                direction: direction.as_vec3().normalize_or(Vec3::NEG_Y),
                cos_inner: crate::math::cos(inner.to_radians()) as f32,
                cos_outer: crate::math::cos(outer.to_radians()) as f32,
            }
        } else {
            // Accepted and ignored on point lights, but still well-formed.
            el.vec3("direction")?;
            el.real("inner")?;
            el.real("outer")?;
            LightKind::Point
        };
        let light = Light {
            kind,
            position,
            color,
            intensity: intensity as f32,
            radius: radius as f32,
            attenuation,
        };
        let keys = self.animates(e, LIGHT_CHANNELS)?;
        if keys.is_empty() {
            self.desc.lights.push(light);
            return Ok(());
        }
        let find = |i: usize| keys.iter().find(|k| k.channel == i);
        let anim = LightAnimation {
            light: self.desc.lights.len(),
            base: light,
            position: find(0).map(Keys::track),
            intensity: find(1).map(Keys::track),
        };
        self.desc.lights.push(anim.light_at(0.0));
        self.desc.animation.lights.push(anim);
        Ok(())
    }
}
