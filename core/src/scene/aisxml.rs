//! AISXML parsing: scene file → resolved, validated [`SceneDesc`].
//!
//! The contract is `shared/spec/aisxml.md`. Parsing is strict: every problem
//! is a [`SceneError`] located at `file:line:column` (the attribute's name for
//! attribute errors, the element's `<` for element errors, the offending
//! number inside element text) whose message says what was expected.
//!
//! Two phases: [`xml`] turns the text into a small element tree (checking XML
//! well-formedness, rejecting DTDs and entities, and checking which element
//! may appear where); this module then reads that tree, loads meshes and
//! fills in every default.
//!
//! Paths: `file=` and `output=` are relative to the scene file's directory
//! and must stay inside it; they are stored bundle-relative (prefixed with
//! the scene's directory, which is empty when the scene is at the bundle's
//! top, the usual case).

mod values;
mod xml;

#[cfg(test)]
mod tests;

use super::{
    Adaptive, AoDistance, CameraDesc, Lens, Light, LightKind, Model, Plane, RenderSettings,
    SceneDesc, Settings, Sided, Sphere, Surface, MAX_ADAPTIVE_SAMPLES, MAX_DEPTH, MAX_IMAGE_SIDE,
    MAX_MESH_ELEMENTS, MAX_OBJECTS, MAX_RAY_SAMPLES, MAX_SUPERSAMPLE,
};
use crate::bundle::{normalize_rel_path, FileSource};
use crate::error::{Location, SceneError};
use crate::mesh::Mesh;
use glam::{DMat4, DVec3, Vec3};
use std::collections::{BTreeSet, HashMap};
use values::{parse_uint, tokens, El, Result};
use xml::{excerpt, is_xml_ws, Attr, Elem, Src};

/// Parses the scene file `scene` (bundle-relative) from `source`, loading the
/// meshes it references, and returns the resolved, validated description.
pub fn parse_scene(scene: &str, source: &dyn FileSource) -> Result<SceneDesc> {
    let bytes = source.read(scene).map_err(|e| {
        SceneError::new(
            Location::new(scene, 1, 1),
            format!("cannot read the scene file: {e}"),
        )
    })?;
    let text = std::str::from_utf8(&bytes).map_err(|e| {
        SceneError::new(
            Location::at_offset(scene, &bytes, e.valid_up_to()),
            "the scene file is not valid UTF-8 (expected UTF-8 text)",
        )
    })?;
    parse_scene_str(scene, text, source)
}

/// Like [`parse_scene`], with the scene file's text already in hand. `scene`
/// is its bundle-relative name (used in errors and to resolve `file=`).
pub fn parse_scene_str(scene: &str, text: &str, source: &dyn FileSource) -> Result<SceneDesc> {
    let src = Src { file: scene, text };
    let root = xml::parse_document(&src)?;
    let scene_dir = match scene.rfind('/') {
        Some(i) => scene[..i].to_string(),
        None => String::new(),
    };
    let mut r = Resolver {
        src: &src,
        source,
        scene_dir,
        desc: SceneDesc::default(),
        files: BTreeSet::new(),
        mesh_ids: HashMap::new(),
        mesh_offsets: Vec::new(),
        object_ids: HashMap::new(),
        light_ids: HashMap::new(),
        camera_ids: HashMap::new(),
        outputs: HashMap::new(),
    };
    r.scene(&root)?;
    let mut desc = r.desc;
    desc.files = r.files.into_iter().collect();
    Ok(desc)
}

/// Where an id was first defined: element name and offset of its `<`.
type Claim = (String, usize);

struct Resolver<'a> {
    src: &'a Src<'a>,
    source: &'a dyn FileSource,
    scene_dir: String,
    desc: SceneDesc,
    files: BTreeSet<String>,
    /// Mesh id → (index in `desc.meshes`, offset of its `<mesh>`).
    mesh_ids: HashMap<String, (usize, usize)>,
    /// Per mesh, where its object-space origin was moved to (see [`recentre`]).
    mesh_offsets: Vec<DVec3>,
    /// Models, spheres and planes share one namespace.
    object_ids: HashMap<String, Claim>,
    light_ids: HashMap<String, Claim>,
    camera_ids: HashMap<String, Claim>,
    /// Output path → offset of the `<render>` that writes it.
    outputs: HashMap<String, usize>,
}

const SURFACE_ATTRS: &[&str] = &[
    "diffuse",
    "ambient",
    "specular",
    "shininess",
    "reflectivity",
    "opacity",
    "ior",
    "smooth",
    "sided",
];

impl<'a> Resolver<'a> {
    fn el(&self, e: &'a Elem) -> El<'a> {
        El::new(self.src, e)
    }

    /// Prefixes a normalised scene-relative path with the scene's directory.
    fn bundle_path(&self, rel: &str) -> String {
        if self.scene_dir.is_empty() {
            rel.to_string()
        } else {
            format!("{}/{rel}", self.scene_dir)
        }
    }

    /// Records `id` in a namespace, failing if it is already there.
    fn claim(
        src: &Src,
        ids: &mut HashMap<String, Claim>,
        el: &El,
        a: &Attr,
        id: &str,
    ) -> Result<()> {
        if let Some((kind, pos)) = ids.get(id) {
            return Err(el.attr_err(
                a,
                format!(
                    "duplicate id \"{}\": already used by the <{kind}> at {} (expected a unique id)",
                    excerpt(id),
                    src.line_col(*pos)
                ),
            ));
        }
        ids.insert(id.to_string(), (el.name().to_string(), el.e.pos));
        Ok(())
    }

    /// Fails when the scene already has [`MAX_OBJECTS`] models and spheres.
    fn room_for_an_object(&self, el: &El) -> Result<()> {
        if self.desc.models.len() + self.desc.spheres.len() >= MAX_OBJECTS {
            return Err(el.err(format!(
                "too many models and spheres (expected at most {MAX_OBJECTS} together)"
            )));
        }
        Ok(())
    }

    fn scene(&mut self, root: &'a Elem) -> Result<()> {
        let el = self.el(root);
        let Some(v) = el.get("version") else {
            return Err(el.err(
                "expected the root element <scene version=\"1\">: attribute \"version\" is missing",
            ));
        };
        if v.value != "1" {
            return Err(el.expected(v, "\"1\" (AISXML version 1)"));
        }
        el.check_attrs(&["version"])?;

        // Meshes first, so that models may refer to meshes defined later.
        for c in root.children.iter().filter(|c| c.name == "mesh") {
            self.mesh(c)?;
        }
        let mut settings_at: Option<usize> = None;
        for c in &root.children {
            match c.name.as_str() {
                "settings" => {
                    if let Some(first) = settings_at {
                        return Err(self.src.err(
                            c.pos,
                            format!(
                                "more than one <settings> (the first is at {}; expected at most one)",
                                self.src.line_col(first)
                            ),
                        ));
                    }
                    settings_at = Some(c.pos);
                    self.settings(c)?;
                }
                "mesh" => {}
                "model" => self.model(c)?,
                "sphere" => self.sphere(c)?,
                "plane" => self.plane(c)?,
                "light" => self.light(c)?,
                "camera" => self.camera(c)?,
                // xml::parse_document admits no other children of <scene>.
                other => {
                    return Err(self.src.err(c.pos, format!("unknown element <{other}>")));
                }
            }
        }
        if self.desc.cameras.is_empty() {
            return Err(el.err("the scene has no <camera> (expected at least one)"));
        }
        Ok(())
    }

    fn settings(&mut self, e: &'a Elem) -> Result<()> {
        let el = self.el(e);
        el.check_attrs(&["background", "ambient"])?;
        let d = Settings::default();
        self.desc.settings = Settings {
            background: el.color("background")?.unwrap_or(d.background),
            ambient: el.color("ambient")?.unwrap_or(d.ambient),
        };
        Ok(())
    }

    // ---------------------------------------------------------------- meshes

    fn mesh(&mut self, e: &'a Elem) -> Result<()> {
        let el = self.el(e);
        el.check_attrs(&["id", "file", "invert"])?;
        let (id_attr, id) = el.id("id")?;
        if let Some(&(_, pos)) = self.mesh_ids.get(&id) {
            return Err(el.attr_err(
                id_attr,
                format!(
                    "duplicate id \"{}\": already used by the <mesh> at {} (expected a unique mesh id)",
                    excerpt(&id),
                    self.src.line_col(pos)
                ),
            ));
        }
        let invert = el.boolean("invert")?.unwrap_or(false);
        let (mut mesh, offset) = match el.get("file") {
            Some(f) => {
                if let Some(c) = e.children.first() {
                    return Err(self.src.err(
                        c.pos,
                        format!(
                            "<{}> inside a <mesh> with file= (expected either file= or inline data, not both)",
                            c.name
                        ),
                    ));
                }
                let mut mesh = self.mesh_file(&el, f)?;
                let offset = recentre(mesh.positions.iter().map(|p| p.as_dvec3()));
                if offset != DVec3::ZERO {
                    for p in &mut mesh.positions {
                        *p = (p.as_dvec3() - offset).as_vec3();
                    }
                }
                (mesh, offset)
            }
            None => inline_mesh(&el, &id)?,
        };
        for (n, what) in [
            (mesh.positions.len(), "vertices"),
            (mesh.triangles.len(), "triangles"),
        ] {
            if n > MAX_MESH_ELEMENTS {
                return Err(el.err(format!(
                    "<mesh> \"{}\" has {n} {what} (expected at most {MAX_MESH_ELEMENTS})",
                    excerpt(&id)
                )));
            }
        }
        if mesh.normals.is_empty() {
            mesh.compute_smooth_normals();
        }
        if invert {
            mesh.invert();
        }
        self.mesh_ids.insert(id, (self.desc.meshes.len(), e.pos));
        self.desc.meshes.push(mesh);
        self.mesh_offsets.push(offset);
        Ok(())
    }

    fn mesh_file(&mut self, el: &El<'a>, f: &'a Attr) -> Result<Mesh> {
        let rel = normalize_rel_path(&f.value).map_err(|m| {
            el.attr_err(
                f,
                format!("{m} (expected a relative path inside the scene's directory)"),
            )
        })?;
        let path = self.bundle_path(&rel);
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
        })?;
        let mesh = if is_obj {
            crate::mesh::obj::parse(&path, &bytes)?
        } else {
            crate::mesh::ply::parse(&path, &bytes)?
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
        Ok(mesh)
    }

    // ------------------------------------------------------ models, surfaces

    fn model(&mut self, e: &'a Elem) -> Result<()> {
        let el = self.el(e);
        el.check_attrs(&["id", "mesh"])?;
        self.room_for_an_object(&el)?;
        let (id_attr, id) = el.id("id")?;
        Self::claim(self.src, &mut self.object_ids, &el, id_attr, &id)?;
        let mesh_attr = el.req("mesh")?;
        let mesh_id = mesh_attr.value.trim_matches(is_xml_ws);
        let Some(&(mesh, _)) = self.mesh_ids.get(mesh_id) else {
            return Err(el.attr_err(
                mesh_attr,
                format!(
                    "no <mesh> has the id \"{}\" (expected the id of a <mesh> in this scene)",
                    excerpt(mesh_id)
                ),
            ));
        };
        let tri_count = self.desc.meshes.get(mesh).map_or(0, |m| m.triangles.len());

        let mut transform: Option<DMat4> = None;
        let mut default: Option<(Surface, usize)> = None;
        let mut named: Vec<(Surface, &'a Elem)> = Vec::new();
        for c in &e.children {
            match c.name.as_str() {
                "transform" => {
                    if transform.is_some() {
                        return Err(self.src.err(
                            c.pos,
                            "second <transform> in a <model> (expected at most one)",
                        ));
                    }
                    transform = Some(self.transform(c)?);
                }
                _ => {
                    let cl = self.el(c);
                    let surface = surface(&cl, true)?;
                    if cl.get("triangles").is_some() {
                        named.push((surface, c));
                    } else if let Some((_, first)) = default {
                        return Err(cl.err(format!(
                            "more than one default <surface> (one without triangles=) in this <model>; the first is at {} (expected at most one)",
                            self.src.line_col(first)
                        )));
                    } else {
                        default = Some((surface, c.pos));
                    }
                }
            }
        }
        let mut surfaces = vec![default.map_or_else(Surface::default, |(s, _)| s)];
        let mut triangle_surface: Vec<u16> = Vec::new();
        if !named.is_empty() {
            triangle_surface = vec![0; tri_count];
            let mut owners: Vec<usize> = Vec::new();
            for (surf, c) in named {
                let cl = self.el(c);
                let Ok(k) = u16::try_from(surfaces.len()) else {
                    return Err(cl.err(format!(
                        "too many <surface> elements in one <model> (expected at most {})",
                        u16::MAX
                    )));
                };
                owners.push(c.pos);
                self.assign_triangles(&cl, k, &mut triangle_surface, &owners)?;
                surfaces.push(surf);
            }
        }
        self.desc.models.push(Model {
            id,
            mesh,
            transform: match self.mesh_offsets.get(mesh) {
                Some(&o) if o != DVec3::ZERO => {
                    transform.unwrap_or(DMat4::IDENTITY) * DMat4::from_translation(o)
                }
                _ => transform.unwrap_or(DMat4::IDENTITY),
            },
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
                return Err(cl.attr_err(
                    a,
                    format!("expected {expected}, found \"{}\"", excerpt(tok)),
                ));
            };
            if lo > hi {
                return Err(cl.attr_err(
                    a,
                    format!(
                        "expected {expected}, found the reversed range \"{}\" (write it low-high)",
                        excerpt(tok)
                    ),
                ));
            }
            if hi >= count as u64 {
                return Err(cl.attr_err(
                    a,
                    format!(
                        "triangle {hi} is beyond the mesh's {count} triangles (expected indices 0-{})",
                        count.saturating_sub(1)
                    ),
                ));
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

    fn transform(&self, e: &'a Elem) -> Result<DMat4> {
        let el = self.el(e);
        el.check_attrs(&[])?;
        let mut m = DMat4::IDENTITY;
        for c in &e.children {
            let cl = self.el(c);
            let step = match c.name.as_str() {
                "translate" => {
                    cl.check_attrs(&["v"])?;
                    let a = cl.req("v")?;
                    let v = cl.reals(a, &[3], "three numbers \"x y z\"")?;
                    DMat4::from_translation(DVec3::new(v[0], v[1], v[2]))
                }
                "rotate" => {
                    cl.check_attrs(&["axis", "angle"])?;
                    cl.req("axis")?;
                    let a = cl.req("angle")?;
                    let axis = cl.direction("axis")?.unwrap_or(DVec3::Y);
                    let angle = cl.reals(a, &[1], "an angle in degrees")?[0];
                    DMat4::from_axis_angle(axis, angle.to_radians())
                }
                "scale" => {
                    cl.check_attrs(&["v"])?;
                    let a = cl.req("v")?;
                    let v = cl.reals(a, &[1, 3], "one number or three numbers \"x y z\"")?;
                    match v[..] {
                        [s] => DMat4::from_scale(DVec3::splat(s)),
                        [x, y, z] => DMat4::from_scale(DVec3::new(x, y, z)),
                        _ => DMat4::IDENTITY,
                    }
                }
                _ => {
                    cl.check_attrs(&["m"])?;
                    let a = cl.req("m")?;
                    let v = cl.reals(a, &[16], "16 numbers (a 4×4 matrix, row by row)")?;
                    if v[12..16] != [0.0, 0.0, 0.0, 1.0] {
                        return Err(cl.attr_err(
                            a,
                            format!(
                                "expected the last row \"0 0 0 1\", found \"{} {} {} {}\"",
                                v[12], v[13], v[14], v[15]
                            ),
                        ));
                    }
                    let mut cols = [0.0; 16];
                    cols.copy_from_slice(&v);
                    DMat4::from_cols_array(&cols).transpose()
                }
            };
            if singular(&step) {
                return Err(cl.err(format!(
                    "singular <{}> (expected an invertible transform)",
                    c.name
                )));
            }
            // Document order: the first child is applied first.
            m = step * m;
        }
        if singular(&m) {
            return Err(el.err(
                "the <transform> is singular or out of range as a whole (expected an invertible transform)",
            ));
        }
        Ok(m)
    }

    // ---------------------------------------------------- spheres and planes

    /// The optional single `<surface>` of a sphere or plane.
    fn single_surface(&self, e: &'a Elem) -> Result<Surface> {
        let mut out: Option<(Surface, usize)> = None;
        for c in &e.children {
            if let Some((_, first)) = out {
                return Err(self.src.err(
                    c.pos,
                    format!(
                        "second <surface> in a <{}> (the first is at {}; expected at most one)",
                        e.name,
                        self.src.line_col(first)
                    ),
                ));
            }
            out = Some((surface(&self.el(c), false)?, c.pos));
        }
        Ok(out.map_or_else(Surface::default, |(s, _)| s))
    }

    fn sphere(&mut self, e: &'a Elem) -> Result<()> {
        let el = self.el(e);
        el.check_attrs(&["id", "center", "radius"])?;
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

    fn plane(&mut self, e: &'a Elem) -> Result<()> {
        let el = self.el(e);
        el.check_attrs(&["id", "point", "normal"])?;
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

    // ------------------------------------------------------------- lights

    fn light(&mut self, e: &'a Elem) -> Result<()> {
        let el = self.el(e);
        el.check_attrs(&[
            "id",
            "type",
            "position",
            "color",
            "intensity",
            "radius",
            "attenuation",
            "direction",
            "inner",
            "outer",
        ])?;
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
                cos_inner: inner.to_radians().cos() as f32,
                cos_outer: outer.to_radians().cos() as f32,
            }
        } else {
            // Accepted and ignored on point lights, but still well-formed.
            el.vec3("direction")?;
            el.real("inner")?;
            el.real("outer")?;
            LightKind::Point
        };
        self.desc.lights.push(Light {
            kind,
            position,
            color,
            intensity: intensity as f32,
            radius: radius as f32,
            attenuation,
        });
        Ok(())
    }

    // ------------------------------------------------------------ cameras

    fn camera(&mut self, e: &'a Elem) -> Result<()> {
        let el = self.el(e);
        el.check_attrs(&[
            "id",
            "position",
            "direction",
            "lookat",
            "up",
            "fov",
            "aperture",
            "focus",
            "lens",
        ])?;
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
                ))
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
            ));
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
                ))
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
                ));
            }
            render = Some(c);
        }
        let Some(render) = render else {
            return Err(el.err(format!(
                "<camera> \"{}\" has no <render> child (expected exactly one)",
                excerpt(&id)
            )));
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

    fn render(
        &mut self,
        e: &'a Elem,
        camera: &El<'a>,
        camera_id_attr: &'a Attr,
        camera_id: &str,
    ) -> Result<RenderSettings> {
        let el = self.el(e);
        el.check_attrs(&[
            "width",
            "height",
            "supersample",
            "jitter",
            "max-depth",
            "shadow-samples",
            "ao-samples",
            "ao-distance",
            "diffuse-samples",
            "diffuse-depth",
            "seed",
            "output",
            "noise-threshold",
            "min-samples",
            "max-samples",
        ])?;
        el.req("width")?;
        el.req("height")?;
        // Every count has a maximum (see the constants and the limits table
        // of docs/aisxml-extensions.md): past it, arithmetic on it would
        // overflow or lose precision, or memory would grow without bound.
        let width = el.u32_in("width", 1, MAX_IMAGE_SIDE)?.unwrap_or(1);
        let height = el.u32_in("height", 1, MAX_IMAGE_SIDE)?.unwrap_or(1);
        let supersample = el.u32_in("supersample", 1, MAX_SUPERSAMPLE)?.unwrap_or(1);
        let jitter = el.boolean("jitter")?.unwrap_or(false);
        let max_depth = el.u32_in("max-depth", 0, MAX_DEPTH)?.unwrap_or(5);
        let shadow_samples = el
            .u32_in("shadow-samples", 1, MAX_RAY_SAMPLES)?
            .unwrap_or(1);
        let ao_samples = el.u32_in("ao-samples", 0, MAX_RAY_SAMPLES)?.unwrap_or(0);
        let ao_distance = match el.get("ao-distance") {
            Some(a) if a.value.trim_matches(is_xml_ws) == "auto" => AoDistance::Auto,
            Some(_) => AoDistance::Fixed(
                el.real_in("ao-distance", "a number > 0 or \"auto\"", |v| v > 0.0)?
                    .unwrap_or(1.0) as f32,
            ),
            None => AoDistance::Auto,
        };
        let diffuse_samples = el
            .u32_in("diffuse-samples", 0, MAX_RAY_SAMPLES)?
            .unwrap_or(0);
        let diffuse_depth = el.u32_in("diffuse-depth", 1, MAX_DEPTH)?.unwrap_or(1);
        let seed = el.uint("seed", 0, u64::MAX)?.unwrap_or(0);

        let output_attr = el.get("output");
        let output = match output_attr {
            Some(a) => {
                let rel = normalize_rel_path(&a.value).map_err(|m| {
                    el.attr_err(
                        a,
                        format!("{m} (expected a relative path inside the scene's directory)"),
                    )
                })?;
                if !has_image_extension(&rel) {
                    return Err(el.expected(a, "a file name ending in .png or .exr"));
                }
                rel
            }
            None => {
                let default = format!("{camera_id}.png");
                match normalize_rel_path(&default) {
                    Ok(rel) if has_image_extension(&rel) => rel,
                    _ => {
                        return Err(camera.attr_err(
                            camera_id_attr,
                            format!(
                                "the default output \"{}\" is not a usable file name (expected an id that makes one, or an explicit output= on <render>)",
                                excerpt(&default)
                            ),
                        ))
                    }
                }
            }
        };
        let output = self.bundle_path(&output);
        if let Some(&first) = self.outputs.get(&output) {
            let msg = format!(
                "output \"{}\" is already written by the <render> at {} (expected a distinct output per camera)",
                excerpt(&output),
                self.src.line_col(first)
            );
            return Err(match output_attr {
                Some(a) => el.attr_err(a, msg),
                None => el.err(msg),
            });
        }
        self.outputs.insert(output.clone(), e.pos);

        let threshold = el.real_in("noise-threshold", "a number > 0", |v| v > 0.0)?;
        let min_samples = el.u32_in("min-samples", 1, MAX_ADAPTIVE_SAMPLES)?;
        let max_samples = el.u32_in("max-samples", 1, MAX_ADAPTIVE_SAMPLES)?;
        let adaptive = match threshold {
            None => {
                if let Some(a) = el.get("min-samples").or_else(|| el.get("max-samples")) {
                    return Err(el.attr_err(
                        a,
                        "only allowed together with \"noise-threshold\" (expected noise-threshold= to enable adaptive sampling)",
                    ));
                }
                None
            }
            Some(t) => {
                let min_samples = min_samples.unwrap_or(4);
                let max_samples = max_samples.unwrap_or(256);
                if max_samples < min_samples {
                    let a = el
                        .get("max-samples")
                        .or_else(|| el.get("min-samples"))
                        .ok_or_else(|| el.err("max-samples < min-samples"))?;
                    return Err(el.expected(
                        a,
                        &format!(
                            "max-samples ≥ min-samples ({min_samples} ≤ {max_samples} is violated)"
                        ),
                    ));
                }
                Some(Adaptive {
                    threshold: t as f32,
                    min_samples,
                    max_samples,
                })
            }
        };
        Ok(RenderSettings {
            width,
            height,
            supersample,
            jitter,
            max_depth,
            shadow_samples,
            ao_samples,
            ao_distance,
            diffuse_samples,
            diffuse_depth,
            seed,
            output,
            adaptive,
        })
    }
}

/// A required `x y z` attribute.
fn req_vec3(el: &El, name: &str) -> Result<DVec3> {
    el.req(name)?;
    Ok(el.vec3(name)?.unwrap_or(DVec3::ZERO))
}

fn has_image_extension(path: &str) -> bool {
    let lower = path.to_ascii_lowercase();
    lower.ends_with(".png") || lower.ends_with(".exr")
}

/// Singular, or not representable: determinant zero or not finite, tiny
/// relative to the product of the column lengths, or entries beyond `f32`.
fn singular(m: &DMat4) -> bool {
    let det = m.determinant();
    let scale =
        m.x_axis.truncate().length() * m.y_axis.truncate().length() * m.z_axis.truncate().length();
    let in_range = m
        .to_cols_array()
        .iter()
        .all(|v| v.is_finite() && v.abs() <= f64::from(f32::MAX));
    !in_range || !det.is_finite() || !scale.is_finite() || det == 0.0 || det.abs() <= 1e-12 * scale
}

/// A `<surface>`; `triangles=` is only allowed on a model's surfaces (the
/// caller reads it).
fn surface(el: &El, allow_triangles: bool) -> Result<Surface> {
    if allow_triangles {
        let mut allowed = SURFACE_ATTRS.to_vec();
        allowed.push("triangles");
        el.check_attrs(&allowed)?;
    } else {
        el.check_attrs(SURFACE_ATTRS)?;
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
    })
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

/// An inline mesh: `<vertices>`, optional `<normals>`, `<triangles>`; and
/// the offset its vertices were stored relative to (see [`recentre`]).
fn inline_mesh(el: &El, id: &str) -> Result<(Mesh, DVec3)> {
    let mut parts: [Option<&Elem>; 3] = [None, None, None];
    for c in &el.e.children {
        let slot = match c.name.as_str() {
            "vertices" => 0,
            "normals" => 1,
            _ => 2,
        };
        if let Some(first) = parts[slot] {
            return Err(el.src.err(
                c.pos,
                format!(
                    "second <{}> in <mesh> \"{}\" (the first is at {}; expected at most one)",
                    c.name,
                    excerpt(id),
                    el.src.line_col(first.pos)
                ),
            ));
        }
        parts[slot] = Some(c);
    }
    for c in parts.iter().flatten() {
        El::new(el.src, c).check_attrs(&[])?;
    }
    let [Some(ve), ne, Some(te)] = parts else {
        return Err(el.err(format!(
            "<mesh> \"{}\" has no {} (expected file= or inline <vertices> and <triangles>)",
            excerpt(id),
            if parts[0].is_none() {
                "<vertices>"
            } else {
                "<triangles>"
            }
        )));
    };
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
            triangles: idx.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        },
        offset,
    ))
}
