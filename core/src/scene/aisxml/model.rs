//! `<model>`: an instance of a mesh with its transform and surfaces.

use super::animation::{Keys, Kind};
use super::surface::surface;
use super::table::{attr, Attribute, REQUIRED};
use super::values::{parse_uint, tokens, El};
use super::xml::{excerpt, is_xml_ws, Elem};
use super::{Load, Resolver, Result};
use crate::error::SceneErrorKind;
use crate::scene::animation::ModelAnimation;
use crate::scene::{Model, Surface};
use glam::{DMat4, DVec3};

/// The attributes of `<model>`.
pub(super) const MODEL: &[Attribute] = &[
    attr(
        "id",
        "id",
        REQUIRED,
        "the model's name, unique among models, spheres and planes",
    ),
    attr(
        "mesh",
        "id",
        REQUIRED,
        "the id of the `<mesh>` it instances",
    ),
];

/// The channels of a `<model>`'s `<animate>` (docs/aisxml-extensions.md).
const MODEL_CHANNELS: &[(&str, Kind)] = &[
    ("translate", Kind::Vector),
    ("rotate", Kind::Rotation),
    ("scale", Kind::Scale),
];

impl<'a> Resolver<'a> {
    pub(super) fn model(&mut self, e: &'a Elem) -> Result<()> {
        let el = self.el(e);
        el.check_attrs(MODEL)?;
        self.room_for_an_object(&el)?;
        let (id_attr, id) = el.id("id")?;
        Self::claim(self.src, &mut self.object_ids, &el, id_attr, &id)?;
        let mesh_attr = el.req("mesh")?;
        let mesh_id = mesh_attr.value.trim_matches(is_xml_ws);
        let Some(&(mesh, _)) = self.mesh_ids.get(mesh_id) else {
            return Err(el
                .attr_err(
                    mesh_attr,
                    format!(
                        "no <mesh> has the id \"{}\" (expected the id of a <mesh> in this scene)",
                        excerpt(mesh_id)
                    ),
                )
                .with_kind(SceneErrorKind::Reference));
        };
        // From the counts, which both parses have (see `mesh.rs`).
        let counts = self.sizes.meshes.get(mesh).copied().unwrap_or_default();
        let tri_count = usize::try_from(counts.triangles).unwrap_or(usize::MAX);
        let has_uvs = counts.uvs;

        let mut transform: Option<DMat4> = None;
        let mut default: Option<(Surface, usize)> = None;
        let mut named: Vec<(Surface, &'a Elem)> = Vec::new();
        for c in &e.children {
            match c.name.as_str() {
                "transform" => {
                    if transform.is_some() {
                        return Err(self
                            .src
                            .err(
                                c.pos,
                                "second <transform> in a <model> (expected at most one)",
                            )
                            .with_kind(SceneErrorKind::UnknownElement));
                    }
                    transform = Some(self.transform(c)?);
                }
                "animate" => {}
                _ => {
                    let cl = self.el(c);
                    let mut surface = surface(&cl, true)?;
                    surface.texture = self.surface_texture(&cl, has_uvs)?;
                    if cl.get("triangles").is_some() {
                        named.push((surface, c));
                    } else if let Some((_, first)) = default {
                        return Err(cl.err(format!(
                            "more than one default <surface> (one without triangles=) in this <model>; the first is at {} (expected at most one)",
                            self.src.line_col(first)
                        )).with_kind(SceneErrorKind::UnknownElement));
                    } else {
                        default = Some((surface, c.pos));
                    }
                }
            }
        }
        let mut surfaces = vec![default.map_or_else(Surface::default, |(s, _)| s)];
        let mut triangle_surface: Vec<u16> = Vec::new();
        // The length of the model's per-triangle table in a full parse.
        let mut table = 0u64;
        // No <surface> of its own: the OBJ's materials, if it has any.
        if default.is_none() && named.is_empty() {
            if let Some(Some(m)) = self.mesh_materials.get(mesh) {
                surfaces = m.surfaces.clone();
                triangle_surface = m.triangle_surface.clone();
                // A headers-only parse has no table of the OBJ's materials;
                // a full parse's has one entry a triangle.
                table = counts.triangles;
            }
        }
        if !named.is_empty() {
            triangle_surface = vec![0; tri_count];
            let mut owners: Vec<usize> = Vec::new();
            for (surf, c) in named {
                let cl = self.el(c);
                let Ok(k) = u16::try_from(surfaces.len()) else {
                    return Err(cl
                        .err(format!(
                            "too many <surface> elements in one <model> (expected at most {})",
                            u16::MAX
                        ))
                        .with_kind(SceneErrorKind::Limit));
                };
                owners.push(c.pos);
                self.assign_triangles(&cl, k, &mut triangle_surface, &owners)?;
                surfaces.push(surf);
            }
        }
        table = table.max(triangle_surface.len() as u64);
        self.sizes.triangle_surfaces.push(table);
        if self.load == Load::HeadersOnly {
            // Checked; the estimate needs only its length.
            triangle_surface = Vec::new();
        }
        let base = match self.mesh_offsets.get(mesh) {
            Some(&o) if o != DVec3::ZERO => {
                transform.unwrap_or(DMat4::IDENTITY) * DMat4::from_translation(o)
            }
            _ => transform.unwrap_or(DMat4::IDENTITY),
        };
        let keys = self.animates(e, MODEL_CHANNELS)?;
        let mut transform = base;
        if !keys.is_empty() {
            let find = |i: usize| keys.iter().find(|k| k.channel == i);
            let anim = ModelAnimation {
                model: self.desc.models.len(),
                base,
                translate: find(0).map(Keys::track),
                rotate: find(1).map(Keys::track),
                scale: find(2).map(Keys::track),
            };
            transform = anim.transform(0.0);
            self.desc.animation.models.push(anim);
        }
        self.desc.models.push(Model {
            id,
            mesh,
            transform,
            surfaces,
            triangle_surface,
        });
        Ok(())
    }

    /// Marks the triangles named by `<surface triangles>` as belonging to
    /// surface `k`. `owners[j]` is the position of the surface numbered `j+1`.
    fn assign_triangles(
        &self,
        cl: &El<'a>,
        k: u16,
        table: &mut [u16],
        owners: &[usize],
    ) -> Result<()> {
        let Some(a) = cl.get("triangles") else {
            return Ok(());
        };
        let expected = "triangle indices and inclusive ranges like \"0-9 12 40-41\"";
        let count = table.len();
        let mut any = false;
        for (_, tok) in tokens(&a.value) {
            any = true;
            let (lo, hi) = match tok.split_once('-') {
                Some((l, h)) => (parse_uint(l), parse_uint(h)),
                None => (parse_uint(tok), parse_uint(tok)),
            };
            let (Some(lo), Some(hi)) = (lo, hi) else {
                return Err(cl
                    .attr_err(
                        a,
                        format!("expected {expected}, found \"{}\"", excerpt(tok)),
                    )
                    .with_kind(SceneErrorKind::BadValue));
            };
            if lo > hi {
                return Err(cl
                    .attr_err(
                        a,
                        format!(
                        "expected {expected}, found the reversed range \"{}\" (write it low-high)",
                        excerpt(tok)
                    ),
                    )
                    .with_kind(SceneErrorKind::BadValue));
            }
            if hi >= count as u64 {
                return Err(cl.attr_err(
                    a,
                    format!(
                        "triangle {hi} is beyond the mesh's {count} triangles (expected indices 0-{})",
                        count.saturating_sub(1)
                    ),
                ).with_kind(SceneErrorKind::BadValue));
            }
            let (lo, hi) = (lo as usize, hi as usize);
            for (t, slot) in (lo..).zip(&mut table[lo..=hi]) {
                let prev = *slot;
                if prev != 0 {
                    let at = owners
                        .get(usize::from(prev) - 1)
                        .map_or_else(String::new, |&p| self.src.line_col(p));
                    return Err(cl.attr_err(
                        a,
                        format!(
                            "triangle {t} is named twice (already by the <surface> at {at}); expected each triangle in at most one <surface triangles>"
                        ),
                    ));
                }
                *slot = k;
            }
        }
        if !any {
            return Err(cl.expected(a, expected));
        }
        Ok(())
    }
}
