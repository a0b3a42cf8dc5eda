//! `<surface>`: the Phong material with reflection and refraction, of a
//! model (where `triangles=` names the triangles it covers), a sphere or a
//! plane.

use super::table::{attr, extension, Attribute};
use super::values::El;
use super::xml::Elem;
use super::{Resolver, Result};
use crate::error::SceneErrorKind;
use crate::scene::{Sided, Surface};

/// The attributes of `<surface>`; the last, `triangles`, only on a model's
/// surfaces.
pub(super) const SURFACE: &[Attribute] = &[
    attr("diffuse", "color", "0.8 0.8 0.8", "kd, the diffuse color"),
    attr("ambient", "color", "= diffuse", "ka, the ambient color"),
    attr("specular", "color", "0 0 0", "ks, the specular color"),
    attr("shininess", "real ≥ 0", "32", "the Phong exponent n"),
    attr(
        "reflectivity",
        "real in [0, 1]",
        "0",
        "r, the share of mirror reflection",
    ),
    attr(
        "opacity",
        "real in [0, 1]",
        "1",
        "α; below 1 the rest is refracted",
    ),
    attr("ior", "real > 0", "1.5", "the index of refraction"),
    attr(
        "smooth",
        "boolean",
        "true",
        "interpolate vertex normals (false: the geometric normal)",
    ),
    attr(
        "sided",
        "two | front",
        "two",
        "hit from both sides, or only from the side its winding faces",
    ),
    extension(
        "diffuse-texture",
        "path",
        "none",
        "a PNG, JPEG or OpenEXR image multiplying diffuse (and ambient) at each hit, by the mesh's texture coordinates",
    ),
    extension(
        "texture-wrap",
        "repeat | clamp",
        "repeat",
        "outside [0, 1] the image repeats, or its edge texels extend",
    ),
    extension(
        "texture-scale",
        "2 reals",
        "1 1",
        "su sv: texture coordinates are multiplied by these before the lookup",
    ),
    extension(
        "emission",
        "color",
        "0 0 0",
        "emitted radiance, on the sides the surface can be hit from (an area light)",
    ),
    attr(
        "triangles",
        "indices and ranges",
        "none (the model's default surface)",
        "the triangles of the model this surface covers, like \"0-9 12 40-41\"",
    ),
];

impl<'a> Resolver<'a> {
    /// The optional single `<surface>` of a sphere or plane.
    pub(super) fn single_surface(&mut self, e: &'a Elem) -> Result<Surface> {
        let mut out: Option<(Surface, usize)> = None;
        for c in &e.children {
            if let Some((_, first)) = out {
                return Err(self
                    .src
                    .err(
                        c.pos,
                        format!(
                            "second <surface> in a <{}> (the first is at {}; expected at most one)",
                            e.name,
                            self.src.line_col(first)
                        ),
                    )
                    .with_kind(SceneErrorKind::UnknownElement));
            }
            let cl = self.el(c);
            let mut s = surface(&cl, false)?;
            s.texture = self.surface_texture(&cl, false)?;
            out = Some((s, c.pos));
        }
        Ok(out.map_or_else(Surface::default, |(s, _)| s))
    }
}

/// A `<surface>`; `triangles=` is only allowed on a model's surfaces (the
/// caller reads it).
pub(super) fn surface(el: &El, allow_triangles: bool) -> Result<Surface> {
    // `triangles`, the table's last entry, only on a model's surfaces.
    if allow_triangles {
        el.check_attrs(SURFACE)?;
    } else {
        el.check_attrs(&SURFACE[..SURFACE.len() - 1])?;
    }
    let d = Surface::default();
    let diffuse = el.color("diffuse")?.unwrap_or(d.diffuse);
    let unit = "a number in [0, 1]";
    let in_unit = |v: f64| (0.0..=1.0).contains(&v);
    Ok(Surface {
        diffuse,
        ambient: el.color("ambient")?.unwrap_or(diffuse),
        specular: el.color("specular")?.unwrap_or(d.specular),
        shininess: el
            .real_in("shininess", "a number ≥ 0", |v| v >= 0.0)?
            .map_or(d.shininess, |v| v as f32),
        reflectivity: el
            .real_in("reflectivity", unit, in_unit)?
            .map_or(d.reflectivity, |v| v as f32),
        opacity: el
            .real_in("opacity", unit, in_unit)?
            .map_or(d.opacity, |v| v as f32),
        ior: el
            .real_in("ior", "a number > 0", |v| v > 0.0)?
            .map_or(d.ior, |v| v as f32),
        smooth: el.boolean("smooth")?.unwrap_or(d.smooth),
        sided: el
            .keyword("sided", &[("two", Sided::Two), ("front", Sided::Front)])?
            .unwrap_or(d.sided),
        // Read by the resolver, which loads the file.
        texture: None,
        emission: el.color("emission")?.unwrap_or(d.emission),
    })
}
