//! `<light>`: a point or spot light, or (a Trevi extension) a rectangle
//! light `type="rect"`: an emitting parallelogram that becomes a two-triangle
//! model of the scene (so camera rays see it and it casts shadows), lit by
//! sampled shadow rays in Whitted mode and by next-event estimation in path
//! mode (docs/aisxml-extensions.md, "Rectangle lights").

use super::animation::{Keys, Kind};
use super::table::{attr, extension, Attribute, REQUIRED};
use super::values::El;
use super::xml::Elem;
use super::{req_vec3, Resolver, Result};
use crate::error::SceneErrorKind;
use crate::mesh::Mesh;
use crate::scene::animation::LightAnimation;
use crate::scene::{Light, LightKind, Model, Sided, Surface};
use glam::{DMat4, DVec3, Vec3};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Type {
    Point,
    Spot,
    Rect,
}

/// The attributes of `<light>`.
pub(super) const LIGHT: &[Attribute] = &[
    extension("id", "id", "none", "the light's name, unique among lights"),
    attr(
        "type",
        "point | spot | rect",
        "point",
        "the kind of light (rect: a Trevi extension)",
    ),
    attr(
        "position",
        "point",
        REQUIRED,
        "where the light is (a rect light's centre)",
    ),
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
    extension(
        "edge-u",
        "vector",
        "required for a rect",
        "a rect light's first edge (at most 1e9 long): its corners are position ± edge-u/2 ± edge-v/2",
    ),
    extension(
        "edge-v",
        "vector",
        "required for a rect",
        "a rect light's second edge (at most 1e9 long); the front faces edge-u × edge-v",
    ),
    extension(
        "emission",
        "color",
        "one of emission, power",
        "a rect light's radiance Le (linear RGB, each ≥ 0)",
    ),
    extension(
        "power",
        "real ≥ 0",
        "one of emission, power",
        "a rect light's power Φ: Le = color·Φ / (sides·π·area)",
    ),
    extension(
        "sided",
        "two | front",
        "two",
        "a rect light emits (and is hit) on both sides, or only its front",
    ),
];

/// The attributes a point or spot light does not take.
const RECT_ONLY: &[&str] = &["edge-u", "edge-v", "emission", "power", "sided"];
/// The attributes a rect light does not take.
const POINT_ONLY: &[&str] = &[
    "intensity",
    "radius",
    "attenuation",
    "direction",
    "inner",
    "outer",
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
        let kind = el
            .keyword(
                "type",
                &[
                    ("point", Type::Point),
                    ("spot", Type::Spot),
                    ("rect", Type::Rect),
                ],
            )?
            .unwrap_or(Type::Point);
        let (not_taken, what) = match kind {
            Type::Rect => (POINT_ONLY, "a rect light"),
            _ => (RECT_ONLY, "a point or spot light"),
        };
        if let Some(a) =
            el.e.attrs
                .iter()
                .find(|a| not_taken.contains(&a.name.as_str()))
        {
            return Err(el
                .attr_err(a, format!("not an attribute of {what}"))
                .with_kind(SceneErrorKind::UnknownAttribute));
        }
        if kind == Type::Rect {
            return self.rect_light(e, &el);
        }
        let spot = kind == Type::Spot;
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

/// The longest edge of a rect light: its area, up to 10¹⁸, then has a
/// square (10³⁶) that fits in 32 bits, as the area lights' sampling
/// computes it.
pub const MAX_RECT_EDGE: f64 = 1e9;

impl<'a> Resolver<'a> {
    /// `<light type="rect">`: a two-triangle mesh (corners relative to the
    /// centre, the centre in the model's transform, so far-off lights keep
    /// their precision) and a model of it whose surface reflects nothing and
    /// emits Le. Its id, if any, is the light's (the model has none: models,
    /// spheres and planes keep their own namespace).
    fn rect_light(&mut self, e: &'a Elem, el: &El<'a>) -> Result<()> {
        self.room_for_an_object(el)?;
        if let Some(c) = e.children.iter().find(|c| c.name == "animate") {
            return Err(self
                .src
                .err(
                    c.pos,
                    "a rect light cannot be animated (expected no <animate> in <light type=\"rect\">)",
                )
                .with_kind(SceneErrorKind::UnknownElement));
        }
        let position = req_vec3(el, "position")?;
        el.req("edge-u")?;
        el.req("edge-v")?;
        let u = el.vec3("edge-u")?.unwrap_or(DVec3::ZERO).as_vec3();
        let v = el.vec3("edge-v")?.unwrap_or(DVec3::ZERO).as_vec3();
        for (name, x) in [("edge-u", u), ("edge-v", v)] {
            if !x.is_finite() {
                let a = el.req(name)?;
                return Err(el.expected(a, "a vector \"x y z\" whose components fit in 32 bits"));
            }
            // The emitter's area is computed in 32 bits (|u × v|, through
            // its square): past this an edge made it infinite and the
            // light vanished without an error.
            if x.as_dvec3().length() > MAX_RECT_EDGE {
                let a = el.req(name)?;
                return Err(el
                    .attr_err(
                        a,
                        format!("a rect light's edge may be at most {MAX_RECT_EDGE:e} long (its area is computed in 32 bits); this one is {:e}", x.as_dvec3().length()),
                    )
                    .with_kind(SceneErrorKind::Limit));
            }
        }
        let sided = el
            .keyword("sided", &[("two", Sided::Two), ("front", Sided::Front)])?
            .unwrap_or(Sided::Two);
        let sides = if sided == Sided::Two { 2.0 } else { 1.0 };
        // In f64: tiny edges (1e-20) would underflow the f32 cross product.
        let area = u.as_dvec3().cross(v.as_dvec3()).length();
        let emission = match (el.get("emission"), el.get("power")) {
            (Some(_), Some(p)) => {
                return Err(el
                    .attr_err(p, "give either emission (radiance) or power, not both")
                    .with_kind(SceneErrorKind::BadValue))
            }
            (None, None) => {
                return Err(el
                    .err("<light type=\"rect\"> needs \"emission\" (its radiance) or \"power\"")
                    .with_kind(SceneErrorKind::Missing))
            }
            (Some(_), None) => {
                if let Some(c) = el.get("color") {
                    return Err(el
                        .attr_err(c, "a rect light with emission takes its colour from emission (color tints power only)")
                        .with_kind(SceneErrorKind::BadValue));
                }
                el.color("emission")?.unwrap_or(Vec3::ZERO)
            }
            (None, Some(p)) => {
                let power = el
                    .real_in("power", "a number ≥ 0", |x| x >= 0.0)?
                    .unwrap_or(0.0);
                let color = el.color("color")?.unwrap_or(Vec3::ONE);
                if power > 0.0 && !(area > 0.0) {
                    return Err(el
                        .attr_err(p, "a rect light of zero area (edge-u × edge-v = 0) cannot send a power (its radiance would be infinite)")
                        .with_kind(SceneErrorKind::BadValue));
                }
                let le = if power > 0.0 {
                    power / (sides * std::f64::consts::PI * area)
                } else {
                    0.0
                };
                let le = color * le as f32;
                if !le.is_finite() {
                    return Err(el
                        .attr_err(p, format!("the radiance power / (sides·π·area) = {le} overflows 32 bits (expected a smaller power or a larger rectangle)"))
                        .with_kind(SceneErrorKind::BadValue));
                }
                le
            }
        };
        let (hu, hv) = (u * 0.5, v * 0.5);
        let mut mesh = Mesh {
            positions: vec![-hu - hv, hu - hv, hu + hv, -hu + hv],
            normals: Vec::new(),
            uvs: Vec::new(),
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        };
        mesh.compute_smooth_normals();
        self.desc.meshes.push(mesh);
        self.mesh_offsets.push(DVec3::ZERO);
        self.mesh_materials.push(None);
        self.desc.models.push(Model {
            id: String::new(),
            mesh: self.desc.meshes.len() - 1,
            transform: DMat4::from_translation(position),
            surfaces: vec![Surface {
                diffuse: Vec3::ZERO,
                ambient: Vec3::ZERO,
                specular: Vec3::ZERO,
                smooth: false,
                sided,
                emission,
                ..Surface::default()
            }],
            triangle_surface: Vec::new(),
        });
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::super::parse_scene;
    use crate::scene::{SceneDesc, Sided};
    use crate::Bundle;
    use glam::{DVec3, Vec3};
    use std::collections::BTreeMap;

    /// A scene with `light` on line 2.
    fn parse(light: &str) -> super::Result<SceneDesc> {
        let text = format!(
            "<scene version=\"1\">\n{light}\n<camera id=\"c\" position=\"0 0 5\" lookat=\"0 0 0\" fov=\"50\"><render width=\"4\" height=\"3\"/></camera>\n</scene>\n"
        );
        let mut files = BTreeMap::new();
        files.insert("scene.xml".to_string(), text.into_bytes());
        parse_scene(
            "scene.xml",
            &Bundle {
                scene: "scene.xml".into(),
                files,
            },
        )
    }

    /// Fails on line 2 where `at` first occurs in `light` (the element's
    /// `<` for "<"), with every one of `needles`.
    #[track_caller]
    fn check(light: &str, at: &str, needles: &[&str]) {
        let col = light.find(at).expect(at) as u32 + 1;
        let e = parse(light).expect_err(light);
        assert_eq!(
            (e.location.file.as_str(), e.location.line, e.location.column),
            ("scene.xml", 2, col),
            "{e}"
        );
        for n in needles {
            assert!(e.message.contains(n), "`{e}` lacks `{n}`");
        }
    }

    #[test]
    fn a_rect_light_becomes_an_emitting_two_triangle_model_centred_on_its_position() {
        let d = parse(
            r#"<light id="lamp" type="rect" position="1 2 3" edge-u="2 0 0" edge-v="0 0 0.5" emission="4 5 6" sided="front"/>"#,
        )
        .unwrap();
        assert!(d.lights.is_empty());
        assert_eq!(d.models.len(), 1);
        let m = &d.models[0];
        let mesh = &d.meshes[m.mesh];
        assert_eq!(mesh.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        let corners: Vec<DVec3> = mesh
            .positions
            .iter()
            .map(|p| m.transform.transform_point3(p.as_dvec3()))
            .collect();
        let expect = [
            DVec3::new(0.0, 2.0, 2.75),
            DVec3::new(2.0, 2.0, 2.75),
            DVec3::new(2.0, 2.0, 3.25),
            DVec3::new(0.0, 2.0, 3.25),
        ];
        for (c, e) in corners.iter().zip(expect) {
            assert!((*c - e).length() < 1e-6, "{corners:?}");
        }
        // The front (edge-u × edge-v) faces −y, as the triangles' winding.
        let [a, b, c] = [0, 1, 2].map(|i| mesh.positions[i]);
        assert!((b - a).cross(c - a).normalize().dot(Vec3::NEG_Y) > 0.999);
        let s = m.surfaces[0];
        assert_eq!(s.emission, Vec3::new(4.0, 5.0, 6.0));
        assert_eq!(
            (s.diffuse, s.specular, s.ambient),
            (Vec3::ZERO, Vec3::ZERO, Vec3::ZERO)
        );
        assert_eq!(s.sided, Sided::Front);
    }

    #[test]
    fn a_rect_light_given_its_power_gets_the_radiance_that_sends_it() {
        // Area 2 × 0.5 = 1; both sides: Le = color·Φ/(2π).
        let d = parse(
            r#"<light type="rect" position="0 0 0" edge-u="2 0 0" edge-v="0 0 0.5" power="10" color="1 0.5 0"/>"#,
        )
        .unwrap();
        let le = 10.0 / (2.0 * std::f32::consts::PI);
        let got = d.models[0].surfaces[0].emission;
        assert!(
            (got - Vec3::new(1.0, 0.5, 0.0) * le).length() < 1e-5,
            "{got}"
        );
        let front = parse(
            r#"<light type="rect" position="0 0 0" edge-u="2 0 0" edge-v="0 0 0.5" power="10" sided="front"/>"#,
        )
        .unwrap();
        let got = front.models[0].surfaces[0].emission;
        assert!((got - Vec3::splat(2.0 * le)).length() < 1e-5, "{got}");
    }

    #[test]
    fn bad_rect_lights_are_errors_at_the_attribute_that_is_wrong() {
        let r = r#"<light type="rect" position="0 0 0" edge-u="1 0 0" edge-v="0 0 1""#;
        check(
            &format!(r#"{r} emission="1 1 1" power="2"/>"#),
            "power=",
            &["attribute \"power\"", "either emission", "not both"],
        );
        check(
            &format!("{r}/>"),
            "<",
            &["needs \"emission\"", "or \"power\""],
        );
        check(
            &format!(r#"{r} color="1 0 0" emission="1 1 1"/>"#),
            "color=",
            &["attribute \"color\"", "tints power only"],
        );
        check(
            &format!(r#"{r} emission="1 1 1" attenuation="0 0 1"/>"#),
            "attenuation=",
            &[
                "attribute \"attenuation\"",
                "not an attribute of a rect light",
            ],
        );
        check(
            &format!(r#"{r} emission="1 -1 1"/>"#),
            "emission=",
            &["attribute \"emission\"", "≥ 0"],
        );
        check(
            r#"<light type="rect" position="0 0 0" edge-u="1 0 0" emission="1 1 1"/>"#,
            "<",
            &["missing its required attribute \"edge-v\""],
        );
        check(
            r#"<light type="rect" position="0 0 0" edge-u="1 0 0" edge-v="2 0 0" power="1"/>"#,
            "power=",
            &["attribute \"power\"", "zero area"],
        );
        check(
            r#"<light type="rect" position="0 0 0" edge-u="1 0 0" edge-v="0 0 1" sided="back" emission="1 1 1"/>"#,
            "sided=",
            &["attribute \"sided\"", "\"two\", \"front\""],
        );
        check(
            r#"<light position="0 0 0" edge-u="1 0 0"/>"#,
            "edge-u=",
            &[
                "attribute \"edge-u\"",
                "not an attribute of a point or spot light",
            ],
        );
        check(
            r#"<light type="rect" position="0 0 0" edge-u="1 0 0" edge-v="0 0 1" emission="1 1 1"><animate channel="position" times="0 1" values="0 0 0 1 1 1"/></light>"#,
            "<animate",
            &["cannot be animated"],
        );
        check(
            r#"<light type="area" position="0 0 0"/>"#,
            "type=",
            &["attribute \"type\"", "\"rect\""],
        );
        // A zero-area rect with a radiance is allowed (it emits nothing).
        parse(
            r#"<light type="rect" position="0 0 0" edge-u="0 0 0" edge-v="0 0 1" emission="1 1 1"/>"#,
        )
        .unwrap();
    }
}
