//! `<mesh>`: triangles from inline `<vertices>`, `<normals>` and
//! `<triangles>`, or from an OBJ or PLY file of the bundle.

use super::table::{attr, Attribute, REQUIRED};
use super::values::{parse_real, parse_uint, El, NumError};
use super::xml::{excerpt, Attr, Elem};
use super::{Load, Resolver, Result};
use crate::error::SceneErrorKind;
use crate::mesh::counts::MeshCounts;
use crate::mesh::Mesh;
use crate::scene::source::read_error_kind;
use crate::scene::MAX_MESH_ELEMENTS;
use glam::{DVec3, Vec2, Vec3};

/// The attributes of `<mesh>`.
pub(super) const MESH: &[Attribute] = &[
    attr(
        "id",
        "id",
        REQUIRED,
        "the name models use to instance the mesh",
    ),
    attr(
        "file",
        "path",
        "none (inline data)",
        "an OBJ or PLY file, relative to the scene's directory and inside it",
    ),
    attr(
        "invert",
        "boolean",
        "false",
        "reverse every triangle's winding and negate every normal",
    ),
];

impl<'a> Resolver<'a> {
    pub(super) fn mesh(&mut self, e: &'a Elem) -> Result<()> {
        let el = self.el(e);
        el.check_attrs(MESH)?;
        let (id_attr, id) = el.id("id")?;
        if let Some(&(_, pos)) = self.mesh_ids.get(&id) {
            return Err(el.attr_err(
                id_attr,
                format!(
                    "duplicate id \"{}\": already used by the <mesh> at {} (expected a unique mesh id)",
                    excerpt(&id),
                    self.src.line_col(pos)
                ),
            ).with_kind(SceneErrorKind::Reference));
        }
        let invert = el.boolean("invert")?.unwrap_or(false);
        let file = el.get("file");
        if let (Some(_), Some(c)) = (file, e.children.first()) {
            return Err(self.src.err(
                c.pos,
                format!(
                    "<{}> inside a <mesh> with file= (expected either file= or inline data, not both)",
                    c.name
                ),
            ).with_kind(SceneErrorKind::UnknownElement));
        }
        if self.load == Load::HeadersOnly {
            let counts = match file {
                Some(f) => self.mesh_file_counts(&el, f)?,
                None => {
                    self.mesh_materials.push(None);
                    inline_counts(&el, &id)?
                }
            };
            check_mesh_size(&el, &id, counts.file_vertices, counts.triangles)?;
            self.mesh_ids.insert(id, (self.sizes.meshes.len(), e.pos));
            self.sizes.meshes.push(counts);
            self.mesh_offsets.push(DVec3::ZERO);
            return Ok(());
        }
        let (mut mesh, offset) = match file {
            Some(f) => {
                let (mut mesh, materials) = self.mesh_file(&el, f)?;
                self.mesh_materials.push(materials);
                let offset = recentre(mesh.positions.iter().map(|p| p.as_dvec3()));
                if offset != DVec3::ZERO {
                    for p in &mut mesh.positions {
                        *p = (p.as_dvec3() - offset).as_vec3();
                    }
                }
                (mesh, offset)
            }
            None => {
                self.mesh_materials.push(None);
                inline_mesh(&el, &id)?
            }
        };
        check_mesh_size(
            &el,
            &id,
            mesh.positions.len() as u64,
            mesh.triangles.len() as u64,
        )?;
        if mesh.normals.is_empty() {
            mesh.compute_smooth_normals();
        }
        if invert {
            mesh.invert();
        }
        self.mesh_ids.insert(id, (self.sizes.meshes.len(), e.pos));
        self.sizes.meshes.push(MeshCounts::of(&mesh));
        self.desc.meshes.push(mesh);
        self.mesh_offsets.push(offset);
        Ok(())
    }

    /// The bundle path of the mesh file `f` names, and its bytes; whether
    /// it is an OBJ (else a PLY).
    fn read_mesh_file(&self, el: &El<'a>, f: &'a Attr) -> Result<(String, Vec<u8>, bool)> {
        let path = self.bundle_path(&Self::attr_path(el, f)?);
        let lower = path.to_ascii_lowercase();
        let is_obj = lower.ends_with(".obj");
        if !is_obj && !lower.ends_with(".ply") {
            return Err(el.expected(f, "a mesh file ending in .obj or .ply"));
        }
        let bytes = self.source.read(&path).map_err(|e| {
            el.attr_err(
                f,
                format!(
                    "cannot read mesh file \"{path}\" ({e}); expected a file of the scene bundle"
                ),
            )
            .with_kind(read_error_kind(&e))
        })?;
        Ok((path, bytes, is_obj))
    }

    /// A mesh file's counts (the headers-only parse), with its OBJ
    /// materials resolved as [`Resolver::mesh_file`] resolves them (their
    /// textures' headers read), but without their per-triangle table.
    fn mesh_file_counts(&mut self, el: &El<'a>, f: &'a Attr) -> Result<MeshCounts> {
        let (path, bytes, is_obj) = self.read_mesh_file(el, f)?;
        let counts = if is_obj {
            let c = crate::mesh::counts::obj(&path, &bytes)?;
            // What `obj_materials` reads of the mesh: whether it has uvs.
            let uvs = Mesh {
                uvs: if c.counts.uvs {
                    vec![glam::Vec2::ZERO]
                } else {
                    Vec::new()
                },
                ..Mesh::default()
            };
            let m = crate::mesh::obj::ObjMaterials {
                libs: c.libs,
                names: c.names,
                triangle_material: Vec::new(),
            };
            let materials = self.obj_materials(&path, &bytes, &uvs, &m)?;
            self.mesh_materials.push(materials);
            c.counts
        } else {
            self.mesh_materials.push(None);
            crate::mesh::ply::counts(&path, &bytes)?
        };
        if counts.triangles == 0 {
            return Err(el.attr_err(
                f,
                format!("mesh file \"{path}\": the mesh has no triangles (expected at least one)"),
            ));
        }
        self.files.insert(path);
        Ok(counts)
    }

    fn mesh_file(
        &mut self,
        el: &El<'a>,
        f: &'a Attr,
    ) -> Result<(Mesh, Option<super::materials::MeshMaterials>)> {
        let (path, bytes, is_obj) = self.read_mesh_file(el, f)?;
        let (mesh, materials) = if is_obj {
            let (mesh, m) = crate::mesh::obj::parse_with_materials(&path, &bytes)?;
            let materials = self.obj_materials(&path, &bytes, &mesh, &m)?;
            (mesh, materials)
        } else {
            (crate::mesh::ply::parse(&path, &bytes)?, None)
        };
        // The loaders promise these; check anyway so that nothing downstream
        // (smooth normals, the BVH) can index out of bounds.
        let bad = |what: String| el.attr_err(f, format!("mesh file \"{path}\": {what}"));
        if mesh.triangles.is_empty() {
            return Err(bad(
                "the mesh has no triangles (expected at least one)".into()
            ));
        }
        let nv = mesh.positions.len();
        if let Some((t, i)) = mesh
            .triangles
            .iter()
            .enumerate()
            .find_map(|(t, tri)| tri.iter().find(|&&i| i as usize >= nv).map(|&i| (t, i)))
        {
            return Err(bad(format!(
                "triangle {t} refers to vertex {i} but there are only {nv} vertices"
            )));
        }
        if !mesh.normals.is_empty() && mesh.normals.len() != nv {
            return Err(bad(format!(
                "{} normals for {nv} vertices (expected one normal per vertex)",
                mesh.normals.len()
            )));
        }
        if !mesh
            .positions
            .iter()
            .chain(&mesh.normals)
            .all(|p| p.is_finite())
        {
            return Err(bad(
                "non-finite coordinates (expected finite numbers)".into()
            ));
        }
        self.files.insert(path);
        Ok((mesh, materials))
    }
}

/// Fails when a mesh has more vertices or triangles than a scene may have.
fn check_mesh_size(el: &El, id: &str, vertices: u64, triangles: u64) -> Result<()> {
    for (n, what) in [(vertices, "vertices"), (triangles, "triangles")] {
        if n > MAX_MESH_ELEMENTS as u64 {
            return Err(el
                .err(format!(
                    "<mesh> \"{}\" has {n} {what} (expected at most {MAX_MESH_ELEMENTS})",
                    excerpt(id)
                ))
                .with_kind(SceneErrorKind::Limit));
        }
    }
    Ok(())
}

/// Where to put a mesh's object-space origin: the centre of its bounding box
/// when the mesh lies far from the origin compared with its size (more than
/// 8 half-extents away), else the origin itself. Vertices are stored in f32
/// relative to it, so a mesh a million units out keeps the precision it has
/// at the origin; the model's f64 transform takes the offset back (the
/// renderer composes it with the camera-relative shift in f64).
fn recentre(points: impl Iterator<Item = DVec3>) -> DVec3 {
    let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for p in points {
        lo = lo.min(p);
        hi = hi.max(p);
    }
    if !(lo.cmple(hi).all() && lo.is_finite() && hi.is_finite()) {
        return DVec3::ZERO;
    }
    let centre = (lo + hi) * 0.5;
    let half = ((hi - lo) * 0.5).max_element();
    if centre.abs().max_element() > 8.0 * half {
        centre
    } else {
        DVec3::ZERO
    }
}

/// An inline mesh: `<vertices>`, optional `<normals>` and `<uvs>` (two
/// numbers, u v, per vertex), `<triangles>`; and
/// the offset its vertices were stored relative to (see [`recentre`]).
/// An inline mesh's `<vertices>`, `<normals>`, `<triangles>` and `<uvs>`
/// (the first and third required), each at most once and without
/// attributes.
#[allow(clippy::type_complexity)]
fn inline_parts<'e>(
    el: &El<'e>,
    id: &str,
) -> Result<(&'e Elem, Option<&'e Elem>, &'e Elem, Option<&'e Elem>)> {
    let mut parts: [Option<&Elem>; 4] = [None, None, None, None];
    for c in &el.e.children {
        let slot = match c.name.as_str() {
            "vertices" => 0,
            "normals" => 1,
            "uvs" => 3,
            _ => 2,
        };
        if let Some(first) = parts[slot] {
            return Err(el
                .src
                .err(
                    c.pos,
                    format!(
                        "second <{}> in <mesh> \"{}\" (the first is at {}; expected at most one)",
                        c.name,
                        excerpt(id),
                        el.src.line_col(first.pos)
                    ),
                )
                .with_kind(SceneErrorKind::UnknownElement));
        }
        parts[slot] = Some(c);
    }
    for c in parts.iter().flatten() {
        El::new(el.src, c).check_attrs(&[])?;
    }
    let [Some(ve), ne, Some(te), ue] = parts else {
        return Err(el
            .err(format!(
                "<mesh> \"{}\" has no {} (expected file= or inline <vertices> and <triangles>)",
                excerpt(id),
                if parts[0].is_none() {
                    "<vertices>"
                } else {
                    "<triangles>"
                }
            ))
            .with_kind(SceneErrorKind::Missing));
    };
    Ok((ve, ne, te, ue))
}

fn inline_mesh(el: &El, id: &str) -> Result<(Mesh, DVec3)> {
    let (ve, ne, te, ue) = inline_parts(el, id)?;
    let vel = El::new(el.src, ve);
    let v = vel.text_reals()?;
    if !v.len().is_multiple_of(3) {
        return Err(vel.err(format!(
            "<vertices> of mesh \"{}\": expected 3 numbers per vertex (a multiple of 3), found {}",
            excerpt(id),
            v.len()
        )));
    }
    let to_vecs = |v: &[f64], o: DVec3| -> Vec<Vec3> {
        v.chunks_exact(3)
            .map(|c| (DVec3::new(c[0], c[1], c[2]) - o).as_vec3())
            .collect()
    };
    let offset = recentre(v.chunks_exact(3).map(|c| DVec3::new(c[0], c[1], c[2])));
    let positions = to_vecs(&v, offset);
    let normals = match ne {
        None => Vec::new(),
        Some(ne) => {
            let nel = El::new(el.src, ne);
            let n = nel.text_reals()?;
            if n.len() != v.len() {
                return Err(nel.err(format!(
                    "<normals> of mesh \"{}\": expected one normal per vertex ({} numbers for {} vertices), found {} numbers",
                    excerpt(id),
                    v.len(),
                    positions.len(),
                    n.len()
                )));
            }
            to_vecs(&n, DVec3::ZERO)
        }
    };
    let uvs = match ue {
        None => Vec::new(),
        Some(ue) => {
            let uel = El::new(el.src, ue);
            let t = uel.text_reals()?;
            if t.len() != 2 * positions.len() {
                return Err(uel.err(format!(
                    "<uvs> of mesh \"{}\": expected one u v pair per vertex ({} numbers for {} vertices), found {} numbers",
                    excerpt(id),
                    2 * positions.len(),
                    positions.len(),
                    t.len()
                )));
            }
            t.chunks_exact(2)
                .map(|c| Vec2::new(c[0] as f32, c[1] as f32))
                .collect()
        }
    };
    let tel = El::new(el.src, te);
    let nv = positions.len();
    let mut idx: Vec<u32> = Vec::new();
    for (pos, tok) in tel.text_tokens() {
        let Some(i) = parse_uint(tok).and_then(|i| u32::try_from(i).ok()) else {
            return Err(el.src.err(
                pos,
                format!(
                    "<triangles>: expected a vertex index (an integer ≥ 0), found \"{}\"",
                    excerpt(tok)
                ),
            ));
        };
        if i as usize >= nv {
            return Err(el.src.err(
                pos,
                format!(
                    "<triangles> of mesh \"{}\": vertex index {i} is out of range (expected an index below the vertex count, {nv})",
                    excerpt(id)
                ),
            ));
        }
        idx.push(i);
    }
    if idx.is_empty() {
        return Err(tel.err(format!(
            "<triangles> of mesh \"{}\" is empty (expected at least one triangle)",
            excerpt(id)
        )));
    }
    if !idx.len().is_multiple_of(3) {
        return Err(tel.err(format!(
            "<triangles> of mesh \"{}\": expected 3 indices per triangle (a multiple of 3), found {}",
            excerpt(id),
            idx.len()
        )));
    }
    Ok((
        Mesh {
            positions,
            normals,
            uvs,
            triangles: idx.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        },
        offset,
    ))
}

/// An inline mesh's counts (the headers-only parse), checked as
/// [`inline_mesh`] checks it (every number and index, every count) but
/// without keeping a number.
fn inline_counts(el: &El, id: &str) -> Result<MeshCounts> {
    let (ve, ne, te, ue) = inline_parts(el, id)?;
    let vel = El::new(el.src, ve);
    let v = count_reals(&vel)?;
    if !v.is_multiple_of(3) {
        return Err(vel.err(format!(
            "<vertices> of mesh \"{}\": expected 3 numbers per vertex (a multiple of 3), found {v}",
            excerpt(id)
        )));
    }
    let nv = v / 3;
    if let Some(ne) = ne {
        let nel = El::new(el.src, ne);
        let n = count_reals(&nel)?;
        if n != v {
            return Err(nel.err(format!(
                "<normals> of mesh \"{}\": expected one normal per vertex ({v} numbers for {nv} vertices), found {n} numbers",
                excerpt(id)
            )));
        }
    }
    if let Some(ue) = ue {
        let uel = El::new(el.src, ue);
        let t = count_reals(&uel)?;
        if t != 2 * nv {
            return Err(uel.err(format!(
                "<uvs> of mesh \"{}\": expected one u v pair per vertex ({} numbers for {nv} vertices), found {t} numbers",
                excerpt(id),
                2 * nv
            )));
        }
    }
    let tel = El::new(el.src, te);
    let mut idx = 0usize;
    for (pos, tok) in tel.text_tokens() {
        let Some(i) = parse_uint(tok).and_then(|i| u32::try_from(i).ok()) else {
            return Err(el.src.err(
                pos,
                format!(
                    "<triangles>: expected a vertex index (an integer ≥ 0), found \"{}\"",
                    excerpt(tok)
                ),
            ));
        };
        if i as usize >= nv {
            return Err(el.src.err(
                pos,
                format!(
                    "<triangles> of mesh \"{}\": vertex index {i} is out of range (expected an index below the vertex count, {nv})",
                    excerpt(id)
                ),
            ));
        }
        idx += 1;
    }
    if idx == 0 {
        return Err(tel.err(format!(
            "<triangles> of mesh \"{}\" is empty (expected at least one triangle)",
            excerpt(id)
        )));
    }
    if !idx.is_multiple_of(3) {
        return Err(tel.err(format!(
            "<triangles> of mesh \"{}\": expected 3 indices per triangle (a multiple of 3), found {idx}",
            excerpt(id)
        )));
    }
    Ok(MeshCounts {
        vertices: nv as u64,
        file_vertices: nv as u64,
        triangles: (idx / 3) as u64,
        uvs: ue.is_some(),
    })
}

/// How many numbers an element's text holds, each checked as
/// [`El::text_reals`] checks it.
fn count_reals(el: &El) -> Result<usize> {
    let mut n = 0;
    for (pos, tok) in el.text_tokens() {
        if let Err(e) = parse_real(tok) {
            let what = match e {
                NumError::Malformed => "a number",
                NumError::NonFinite => "a finite number",
            };
            return Err(el
                .src
                .err(
                    pos,
                    format!(
                        "<{}>: expected {what}, found \"{}\"",
                        el.e.name,
                        excerpt(tok)
                    ),
                )
                .with_kind(SceneErrorKind::BadValue));
        }
        n += 1;
    }
    Ok(n)
}
