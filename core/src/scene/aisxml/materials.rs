//! OBJ materials: the `.mtl` files an OBJ names become surfaces of the
//! models that instance it (unless the model has `<surface>` children of
//! its own, which then replace them all).
//!
//! Mapping (docs/aisxml-extensions.md, "OBJ materials"): `Kd` → diffuse
//! (absent: 1 with a `map_Kd`, whose image is then the colour, else 0.8),
//! `Ka` → ambient (absent: = diffuse, as in AISXML), `Ks` → specular (not
//! for nvdiffrec's `bsdf` materials, whose `Ks` packs PBR parameters),
//! `Ns` → shininess, `d`/`Tr` → opacity, `Ni` → ior, `map_Kd` →
//! diffuse-texture; `illum` 3, 5 and 8 (ray-traced reflection) make a mirror
//! with reflectivity = the largest `Ks` component, 4, 6, 7 and 9 (glass) the
//! same plus refraction by `d` and `Ni`; 0-2 and absent are plain Phong.

use std::collections::HashMap;
use std::rc::Rc;

use super::{outside_scene, Resolver, Result};
use crate::error::{Location, SceneError, SceneErrorKind};
use crate::mesh::mtl::{self, Material};
use crate::mesh::obj::{ObjMaterials, MAX_OBJ_MATERIALS, NO_MATERIAL};
use crate::mesh::Mesh;
use crate::scene::source::read_error_kind;
use crate::scene::source::resolve_reference;
use crate::scene::{Surface, TextureMap};
use crate::texture::Wrap;

/// The surfaces an OBJ's materials give its triangles: `surfaces[0]` is the
/// default (for triangles without a known material), and
/// `triangle_surface[t]` the surface of triangle `t`.
#[derive(Debug, Clone, Default)]
pub(super) struct MeshMaterials {
    pub surfaces: Vec<Surface>,
    pub triangle_surface: Vec<u16>,
}

/// A parsed `.mtl` file, read and parsed once per scene however many
/// meshes and `mtllib` statements name it: its bundle path, its bytes (to
/// locate an error in it) and its materials.
#[derive(Debug)]
pub(super) struct MtlLibrary {
    path: String,
    bytes: Vec<u8>,
    materials: Vec<Material>,
}

impl Resolver<'_> {
    /// Loads the `.mtl` files of the OBJ `obj_path` (its bytes `obj`) and
    /// turns its materials into surfaces. `None` when it names no `.mtl`
    /// (a `usemtl` without an `mtllib` is ignored, as before).
    ///
    /// Cost: each library is read and parsed once per scene (shared
    /// through `mtl_libraries`), and each `usemtl` name is looked up by
    /// hash, so the work is linear in the files' sizes; `m` holds each
    /// name once (see [`crate::mesh::obj::parse_with_materials`]).
    pub(super) fn obj_materials(
        &mut self,
        obj_path: &str,
        obj: &[u8],
        mesh: &Mesh,
        m: &ObjMaterials,
    ) -> Result<Option<MeshMaterials>> {
        if m.libs.is_empty() || m.names.is_empty() {
            return Ok(None);
        }
        let mut libs: Vec<Rc<MtlLibrary>> = Vec::with_capacity(m.libs.len());
        for (name, at) in &m.libs {
            let loc = || Location::at_offset(obj_path, obj, *at);
            let path = self.referenced_path(obj_path, name, loc)?;
            if let Some(lib) = self.mtl_libraries.get(&path) {
                libs.push(lib.clone());
                continue;
            }
            let bytes = self.source.read(&path).map_err(|e| {
                SceneError::of_kind(
                    read_error_kind(&e),
                    loc(),
                    format!("cannot read material library \"{path}\" ({e}); expected a file of the scene bundle"),
                )
            })?;
            let materials = mtl::parse(&path, &bytes)?;
            let lib = Rc::new(MtlLibrary {
                path: path.clone(),
                bytes,
                materials,
            });
            self.mtl_libraries.insert(path.clone(), lib.clone());
            self.files.insert(path);
            libs.push(lib);
        }
        // The first definition of a name wins (libraries in mtllib order).
        let mut by_name: HashMap<&str, (usize, usize)> = HashMap::new();
        for (l, lib) in libs.iter().enumerate() {
            for (k, mat) in lib.materials.iter().enumerate() {
                by_name.entry(mat.name.as_str()).or_insert((l, k));
            }
        }
        if m.names.len() > MAX_OBJ_MATERIALS {
            // The OBJ reader refuses this where the name is; a fallback.
            return Err(SceneError::of_kind(
                SceneErrorKind::Limit,
                Location::at_offset(obj_path, obj, m.names[MAX_OBJ_MATERIALS].1),
                format!("more than {MAX_OBJ_MATERIALS} materials (usemtl names) in one mesh"),
            ));
        }
        let mut surfaces = vec![Surface::default()];
        // Per usemtl name, its surface (0: unknown name, the default).
        let mut of_name = Vec::with_capacity(m.names.len());
        for (name, _) in &m.names {
            let Some(&(l, k)) = by_name.get(name.as_str()) else {
                of_name.push(0u16);
                continue;
            };
            let lib = &libs[l];
            let mat = &lib.materials[k];
            let mut s = surface_of(mat);
            if let Some(map) = &mat.map_kd {
                let at = || Location::at_offset(&lib.path, &lib.bytes, map.at);
                if mesh.uvs.is_empty() {
                    return Err(SceneError::of_kind(
                        SceneErrorKind::BadValue,
                        at(),
                        format!("map_Kd of material \"{name}\": the mesh \"{obj_path}\" has no texture coordinates (expected vt on every face corner)"),
                    ));
                }
                let path = self.referenced_path(&lib.path, &map.file, at)?;
                let texture =
                    self.load_texture(&path, |msg, kind| SceneError::of_kind(kind, at(), msg))?;
                s.texture = Some(TextureMap {
                    texture,
                    wrap: if map.clamp { Wrap::Clamp } else { Wrap::Repeat },
                    scale: map.scale,
                });
            }
            of_name.push(surfaces.len() as u16);
            surfaces.push(s);
        }
        let triangle_surface = m
            .triangle_material
            .iter()
            .map(|&k| {
                if k == NO_MATERIAL {
                    0
                } else {
                    of_name[k as usize]
                }
            })
            .collect();
        Ok(Some(MeshMaterials {
            surfaces,
            triangle_surface,
        }))
    }

    /// The bundle path of `reference`, written in the bundle file
    /// `referrer` (an OBJ or a `.mtl`): resolved against the referrer's
    /// folder, and refused if it leaves the scene's directory (the one rule
    /// of [`resolve_reference`], as for a path an attribute names: an
    /// error at `at`).
    fn referenced_path(
        &self,
        referrer: &str,
        reference: &str,
        at: impl Fn() -> Location,
    ) -> Result<String> {
        let in_scene = if self.scene_dir.is_empty() {
            referrer
        } else {
            referrer
                .strip_prefix(self.scene_dir.as_str())
                .and_then(|r| r.strip_prefix('/'))
                .unwrap_or(referrer)
        };
        let from = in_scene.rfind('/').map_or("", |i| &in_scene[..i]);
        let rel = resolve_reference(from, reference)
            .map_err(|e| SceneError::of_kind(SceneErrorKind::Reference, at(), outside_scene(&e)))?;
        Ok(self.bundle_path(&rel))
    }
}

/// A material's surface (see the module's mapping).
fn surface_of(m: &Material) -> Surface {
    let d = Surface::default();
    // A map_Kd without Kd is the colour itself (as nvdiffrec's and most
    // exporters' files mean it), not the image times AISXML's default 0.8.
    let no_kd = if m.map_kd.is_some() {
        glam::Vec3::ONE
    } else {
        d.diffuse
    };
    let diffuse = m.kd.unwrap_or(no_kd);
    let specular = if m.bsdf {
        d.specular
    } else {
        m.ks.unwrap_or(d.specular)
            .clamp(glam::Vec3::ZERO, glam::Vec3::ONE)
    };
    let clamp01 = |x: f32| x.clamp(0.0, 1.0);
    let mirror = specular.max_element();
    let (reflectivity, opacity) = match m.illum {
        Some(3 | 5 | 8) => (mirror, 1.0),
        Some(4 | 6 | 7 | 9) => (mirror, clamp01(m.d.unwrap_or(1.0))),
        _ => (0.0, clamp01(m.d.unwrap_or(1.0))),
    };
    Surface {
        diffuse,
        ambient: m.ka.unwrap_or(diffuse),
        specular,
        shininess: m.ns.map_or(d.shininess, |n| n.max(0.0)),
        reflectivity,
        opacity,
        ior: m.ni.filter(|&n| n > 0.0).unwrap_or(d.ior),
        ..d
    }
}

#[cfg(test)]
mod tests {
    use crate::bundle::Bundle;
    use crate::error::SceneErrorKind;
    use crate::scene::aisxml::parse_scene;
    use glam::Vec3;
    use std::collections::BTreeMap;

    const OBJ: &str = "mtllib m/lib.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n\
                       f 1/1 2/2 3/3\nusemtl glass\nf 1/1 3/3 2/2\nusemtl unknown\nf 1/1 2/2 3/3\n\
                       usemtl tex\nf 1/1 2/2 3/3\n";
    const MTL: &str = "newmtl glass\nKd 0.1 0.2 0.3\nKs 0.5\nillum 4\nd 0.25\nNi 1.4\n\
                       newmtl tex\nbsdf pbr\nKs 0 0.25 0\nmap_Kd -clamp on t.png\n";

    fn parse(model: &str, files: &[(&str, &[u8])]) -> super::Result<crate::scene::SceneDesc> {
        let text = format!(
            "<scene version=\"1\"><mesh id=\"o\" file=\"o.obj\"/>{model}\
             <camera id=\"c\" position=\"0 0 5\" lookat=\"0 0 0\" fov=\"50\"><render width=\"4\" height=\"3\"/></camera></scene>"
        );
        let mut map = BTreeMap::new();
        map.insert("s.xml".to_string(), text.into_bytes());
        for (n, b) in files {
            map.insert(n.to_string(), b.to_vec());
        }
        parse_scene(
            "s.xml",
            &Bundle {
                scene: "s.xml".into(),
                files: map,
            },
        )
    }

    #[test]
    fn materials_become_surfaces_unless_the_model_has_its_own() {
        let png = crate::texture::tests::png_rgb8(1, 1, &[255, 0, 0]);
        let files: [(&str, &[u8]); 3] = [
            ("o.obj", OBJ.as_bytes()),
            ("m/lib.mtl", MTL.as_bytes()),
            ("m/t.png", &png),
        ];
        let d = parse(r#"<model id="a" mesh="o"/>"#, &files).unwrap();
        let m = &d.models[0];
        // Default, glass, tex; the unknown name and the first triangle use 0.
        assert_eq!(m.triangle_surface, vec![0, 1, 0, 2]);
        let glass = &m.surfaces[1];
        assert_eq!(glass.diffuse, Vec3::new(0.1, 0.2, 0.3));
        assert_eq!(glass.ambient, glass.diffuse);
        assert_eq!(
            (glass.reflectivity, glass.opacity, glass.ior),
            (0.5, 0.25, 1.4)
        );
        let tex = &m.surfaces[2];
        assert_eq!(tex.specular, Vec3::ZERO, "bsdf pbr: Ks is not a colour");
        assert_eq!(
            tex.diffuse,
            Vec3::ONE,
            "map_Kd without Kd: the image is the colour"
        );
        assert_eq!(tex.ambient, Vec3::ONE);
        assert_eq!(
            m.surfaces[0].diffuse,
            Vec3::splat(0.8),
            "no material: the default"
        );
        let t = tex.texture.unwrap();
        assert_eq!(t.wrap, crate::texture::Wrap::Clamp);
        assert_eq!(d.textures.len(), 1);
        assert!(d.files.contains(&"m/lib.mtl".to_string()));
        assert!(d.files.contains(&"m/t.png".to_string()));
        // A <surface> of the model replaces them all.
        let d = parse(
            r#"<model id="a" mesh="o"><surface diffuse="1 0 0"/></model>"#,
            &files,
        )
        .unwrap();
        assert_eq!(d.models[0].surfaces.len(), 1);
        assert!(d.models[0].triangle_surface.is_empty());
    }

    #[test]
    fn a_missing_library_or_texture_is_located_where_it_is_named() {
        let e = parse(r#"<model id="a" mesh="o"/>"#, &[("o.obj", OBJ.as_bytes())]).unwrap_err();
        assert_eq!(e.kind, SceneErrorKind::MissingFile, "{e}");
        assert_eq!(
            (e.location.file.as_str(), e.location.line, e.location.column),
            ("o.obj", 1, 8),
            "{e}"
        );
        let e = parse(
            r#"<model id="a" mesh="o"/>"#,
            &[("o.obj", OBJ.as_bytes()), ("m/lib.mtl", MTL.as_bytes())],
        )
        .unwrap_err();
        assert_eq!(e.kind, SceneErrorKind::MissingFile, "{e}");
        assert_eq!(
            (e.location.file.as_str(), e.location.line, e.location.column),
            ("m/lib.mtl", 10, 18),
            "{e}"
        );
        assert!(e.message.contains("m/t.png"), "{e}");
    }
}
