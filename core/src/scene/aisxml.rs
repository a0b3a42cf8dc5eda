//! AISXML parsing: scene file → resolved, validated [`SceneDesc`].
//!
//! The contract is docs/aisxml.md (the format as `shared/spec/aisxml.md`
//! fixes it) with Trevi's extensions in docs/aisxml-extensions.md. Parsing
//! is strict: every problem is a [`SceneError`] located at
//! `file:line:column` (the attribute's name for attribute errors, the
//! element's `<` for element errors, the offending number inside element
//! text) whose message says what was expected, and whose kind says what
//! sort of problem it is.
//!
//! Two phases: `xml.rs` turns the text into a small element tree (checking XML
//! well-formedness, rejecting DTDs and entities, and checking which element
//! may appear where); this module then reads that tree, loads meshes and
//! fills in every default. [`parse_scene_headers`] reads the same tree but
//! of mesh and texture files only their headers (see [`SceneHeaders`]):
//! what the coordinator admits a job with.
//!
//! One file per element reads it, beside its attribute table (name, type,
//! default, meaning; see [`table`]): `settings.rs`, `mesh.rs`, `model.rs`
//! with `transform.rs` and `surface.rs`, `sphere.rs`, `plane.rs`,
//! `light.rs`, `camera.rs` and its `render.rs`; `values.rs` reads typed
//! values. The root `<scene>` is read here. The tables are what an element
//! accepts (an attribute not in its table is an error) and what
//! docs/aisxml.md is checked against (see `ELEMENTS`, the one table of the
//! elements, and `doc_tests.rs`).
//!
//! Paths: `file=` and `output=` are relative to the scene file's directory
//! and must stay inside it; they are stored bundle-relative (prefixed with
//! the scene's directory, which is empty when the scene is at the bundle's
//! top, the usual case).

mod animation;
mod camera;
mod light;
mod materials;
mod mesh;
mod model;
mod outputs;
mod plane;
mod render;
mod settings;
mod sphere;
mod surface;
pub mod table;
mod texture;
mod transform;
mod values;
mod xml;

#[cfg(test)]
mod animation_tests;
#[cfg(test)]
mod bounds_tests;
#[cfg(test)]
mod defaults_tests;
#[cfg(test)]
mod doc_tests;
#[cfg(test)]
mod headers_tests;
#[cfg(test)]
mod tests;

use super::estimate::{estimate_sized, AssetSizes, MemoryEstimate};
use super::source::{normalize_rel_path, FileSource, PathError};
use super::{SceneDesc, MAX_OBJECTS};
use crate::error::{Location, SceneError, SceneErrorKind};
use crate::scene::source::read_error_kind;
use glam::DVec3;
use std::collections::{BTreeSet, HashMap};
use table::{attr, Attribute, Element, REQUIRED};
use values::{El, Result};
use xml::{excerpt, Attr, Elem, Src};

/// The attributes of the root `<scene>`.
const SCENE: &[Attribute] = &[attr("version", "\"1\"", REQUIRED, "the AISXML version")];

/// How the reader reads an element that is a child of the root.
type Reader = for<'a> fn(&mut Resolver<'a>, &'a Elem) -> Result<()>;

/// `Some(read)`, with the closure coerced to a [`Reader`].
const fn reads(read: Reader) -> Option<Reader> {
    Some(read)
}

/// An element without attributes, read by its parent, holding `children`.
const fn holding(name: &'static str, children: &'static [&'static str]) -> Element<Reader> {
    Element {
        name,
        attributes: &[],
        children,
        text: false,
        read: None,
    }
}

/// An element read by its parent, with `attributes` and no children.
const fn leaf(name: &'static str, attributes: &'static [Attribute]) -> Element<Reader> {
    Element {
        attributes,
        ..holding(name, &[])
    }
}

/// An element whose content is text (numbers), without attributes.
const fn text(name: &'static str) -> Element<Reader> {
    Element {
        text: true,
        ..holding(name, &[])
    }
}

/// Every AISXML element, the root first: the one place an element is
/// named. The tree is checked against its children (`xml.rs`), the root's
/// children are read by its readers, and docs/aisxml.md is checked against
/// its attribute tables (`doc_tests.rs`).
const ELEMENTS: &[Element<Reader>] = &[
    Element {
        name: "scene",
        attributes: SCENE,
        children: &[
            "settings", "mesh", "model", "sphere", "plane", "light", "camera",
        ],
        text: false,
        read: None,
    },
    Element {
        name: "settings",
        attributes: settings::SETTINGS,
        children: &[],
        text: false,
        read: reads(|r, e| r.settings(e)),
    },
    Element {
        name: "mesh",
        attributes: mesh::MESH,
        children: &["vertices", "normals", "uvs", "triangles"],
        text: false,
        read: reads(|r, e| r.mesh(e)),
    },
    text("vertices"),
    text("normals"),
    text("uvs"),
    text("triangles"),
    Element {
        name: "model",
        attributes: model::MODEL,
        children: &["transform", "surface", "animate"],
        text: false,
        read: reads(|r, e| r.model(e)),
    },
    holding("transform", &["translate", "rotate", "scale", "matrix"]),
    leaf("surface", surface::SURFACE),
    leaf("translate", transform::TRANSLATE),
    leaf("rotate", transform::ROTATE),
    leaf("scale", transform::SCALE),
    leaf("matrix", transform::MATRIX),
    Element {
        name: "sphere",
        attributes: sphere::SPHERE,
        children: &["surface"],
        text: false,
        read: reads(|r, e| r.sphere(e)),
    },
    Element {
        name: "plane",
        attributes: plane::PLANE,
        children: &["surface"],
        text: false,
        read: reads(|r, e| r.plane(e)),
    },
    Element {
        name: "light",
        attributes: light::LIGHT,
        children: &["animate"],
        text: false,
        read: reads(|r, e| r.light(e)),
    },
    Element {
        name: "camera",
        attributes: camera::CAMERA,
        children: &["render", "animate"],
        text: false,
        read: reads(|r, e| r.camera(e)),
    },
    leaf("render", render::RENDER),
    leaf("animate", animation::ANIMATE),
];

/// The element that reads meshes: they are read before the root's other
/// children, so that models may refer to meshes defined later.
const MESH_ELEMENT: &str = "mesh";

/// Parses the scene file `scene` (bundle-relative) from `source`, loading the
/// meshes it references, and returns the resolved, validated description.
pub fn parse_scene(scene: &str, source: &dyn FileSource) -> Result<SceneDesc> {
    let bytes = read_scene(scene, source)?;
    parse_scene_str(scene, scene_text(scene, &bytes)?, source)
}

/// Like [`parse_scene`], with the scene file's text already in hand. `scene`
/// is its bundle-relative name (used in errors and to resolve `file=`).
pub fn parse_scene_str(scene: &str, text: &str, source: &dyn FileSource) -> Result<SceneDesc> {
    parse_with(scene, text, source, Load::Full).map(|r| r.0)
}

/// A scene read by [`parse_scene_headers`]: its description with every
/// camera, light, object and surface resolved, but no mesh or texture
/// loaded ([`SceneDesc::meshes`] and [`SceneDesc::textures`] are empty,
/// models keep no per-triangle surface table, and no mesh is recentred), so
/// it cannot be built; and the sizes of its meshes and textures, read from
/// their files' headers.
#[derive(Debug, Clone)]
pub struct SceneHeaders {
    /// The description, without meshes and textures.
    pub desc: SceneDesc,
    /// The sizes of its meshes and textures, from their files' headers.
    pub sizes: AssetSizes,
}

impl SceneHeaders {
    /// The scene's memory estimate: at least what the full parse's gives
    /// (see [`estimate_sized`]).
    pub fn estimate(&self) -> MemoryEstimate {
        estimate_sized(&self.desc, &self.sizes)
    }
}

/// [`parse_scene`] for admitting a job: the scene file is read and checked
/// as fully as by [`parse_scene`], but of mesh and texture files only what
/// their headers say is read (image sizes of every part, mesh counts; see
/// `mesh/counts.rs` and `texture/header.rs`), never a pixel, and no mesh is
/// built. A texture's size is checked against the same bounds as when it
/// is decoded; what is wrong inside a mesh's or image's data is found by
/// the full parse (the worker's).
pub fn parse_scene_headers(scene: &str, source: &dyn FileSource) -> Result<SceneHeaders> {
    let bytes = read_scene(scene, source)?;
    let (desc, sizes) = parse_with(scene, scene_text(scene, &bytes)?, source, Load::HeadersOnly)?;
    Ok(SceneHeaders { desc, sizes })
}

fn read_scene(scene: &str, source: &dyn FileSource) -> Result<Vec<u8>> {
    source.read(scene).map_err(|e| {
        SceneError::of_kind(
            read_error_kind(&e),
            Location::new(scene, 1, 1),
            format!("cannot read the scene file: {e}"),
        )
    })
}

fn scene_text<'b>(scene: &str, bytes: &'b [u8]) -> Result<&'b str> {
    std::str::from_utf8(bytes).map_err(|e| {
        SceneError::of_kind(
            SceneErrorKind::Syntax,
            Location::at_offset(scene, bytes, e.valid_up_to()),
            "the scene file is not valid UTF-8 (expected UTF-8 text)",
        )
    })
}

/// What a parse loads of the mesh and texture files a scene names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Load {
    /// Meshes loaded and textures decoded: a scene to build.
    Full,
    /// Counts and image sizes from the files' headers only.
    HeadersOnly,
}

fn parse_with(
    scene: &str,
    text: &str,
    source: &dyn FileSource,
    load: Load,
) -> Result<(SceneDesc, AssetSizes)> {
    let src = Src { file: scene, text };
    let root = xml::parse_document(&src, ELEMENTS)?;
    let scene_dir = match scene.rfind('/') {
        Some(i) => scene[..i].to_string(),
        None => String::new(),
    };
    let mut r = Resolver {
        src: &src,
        source,
        load,
        scene_dir,
        desc: SceneDesc::default(),
        sizes: AssetSizes::default(),
        files: BTreeSet::new(),
        mesh_ids: HashMap::new(),
        mesh_offsets: Vec::new(),
        mesh_materials: Vec::new(),
        object_ids: HashMap::new(),
        light_ids: HashMap::new(),
        camera_ids: HashMap::new(),
        settings_at: None,
        outputs: outputs::Outputs::default(),
        texture_ids: HashMap::new(),
        texels: 0,
        mtl_libraries: HashMap::new(),
    };
    r.scene(&root)?;
    let mut desc = r.desc;
    desc.files = r.files.into_iter().collect();
    Ok((desc, r.sizes))
}

/// Where an id was first defined: element name and offset of its `<`.
type Claim = (String, usize);

struct Resolver<'a> {
    src: &'a Src<'a>,
    source: &'a dyn FileSource,
    load: Load,
    scene_dir: String,
    desc: SceneDesc,
    /// The meshes' counts, textures' sizes and models' per-triangle table
    /// lengths, in both modes (what models read of their mesh, and what
    /// the estimate of a headers-only parse is made from).
    sizes: AssetSizes,
    files: BTreeSet<String>,
    /// Mesh id → (index in `desc.meshes` and `sizes.meshes`, offset of its
    /// `<mesh>`).
    mesh_ids: HashMap<String, (usize, usize)>,
    /// Per mesh, where its object-space origin was moved to (see
    /// [`mesh::recentre`]).
    mesh_offsets: Vec<DVec3>,
    /// Per mesh, the surfaces its OBJ materials give (see `materials.rs`).
    mesh_materials: Vec<Option<materials::MeshMaterials>>,
    /// Models, spheres and planes share one namespace.
    object_ids: HashMap<String, Claim>,
    light_ids: HashMap<String, Claim>,
    camera_ids: HashMap<String, Claim>,
    /// The offset of the `<settings>` read, if one was.
    settings_at: Option<usize>,
    /// Every camera's output, with the offset of its `<render>`.
    outputs: outputs::Outputs,
    /// Texture file (bundle path) → index in `desc.textures`.
    texture_ids: HashMap<String, u32>,
    /// Texels (level 0) of the textures decoded so far.
    texels: u64,
    /// `.mtl` files (bundle path) parsed so far (see `materials.rs`).
    mtl_libraries: HashMap<String, std::rc::Rc<materials::MtlLibrary>>,
}

impl<'a> Resolver<'a> {
    fn el(&self, e: &'a Elem) -> El<'a> {
        El::new(self.src, e)
    }

    /// The path attribute `a` names (`file=`, `diffuse-texture=`,
    /// `output=`), normalised and relative to the scene's directory, which
    /// it must stay inside; otherwise an error at the attribute.
    fn attr_path(el: &El, a: &Attr) -> Result<String> {
        normalize_rel_path(&a.value).map_err(|e| {
            el.attr_err(a, outside_scene(&e))
                .with_kind(SceneErrorKind::Reference)
        })
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
            )
            .with_kind(SceneErrorKind::Reference));
        }
        ids.insert(id.to_string(), (el.name().to_string(), el.e.pos));
        Ok(())
    }

    /// Fails when the scene already has [`MAX_OBJECTS`] models and spheres.
    fn room_for_an_object(&self, el: &El) -> Result<()> {
        if self.desc.models.len() + self.desc.spheres.len() >= MAX_OBJECTS {
            return Err(el
                .err(format!(
                    "too many models and spheres (expected at most {MAX_OBJECTS} together)"
                ))
                .with_kind(SceneErrorKind::Limit));
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
        el.check_attrs(SCENE)?;

        // Meshes first, so that models may refer to meshes defined later.
        let (meshes, others): (Vec<&'a Elem>, Vec<&'a Elem>) =
            root.children.iter().partition(|c| c.name == MESH_ELEMENT);
        for c in meshes.into_iter().chain(others) {
            let read = ELEMENTS
                .iter()
                .find(|e| e.name == c.name)
                .and_then(|e| e.read);
            let Some(read) = read else {
                // xml::parse_document admits no other children of <scene>.
                return Err(self
                    .src
                    .err(c.pos, format!("unknown element <{}>", c.name))
                    .with_kind(SceneErrorKind::UnknownElement));
            };
            read(self, c)?;
        }
        if self.desc.cameras.is_empty() {
            return Err(el
                .err("the scene has no <camera> (expected at least one)")
                .with_kind(SceneErrorKind::Missing));
        }
        Ok(())
    }
}

/// What a path a scene names is told when it is absolute, empty or leaves
/// the scene's directory.
fn outside_scene(e: &PathError) -> String {
    format!("{e} (expected a relative path inside the scene's directory)")
}

/// A required `x y z` attribute.
fn req_vec3(el: &El, name: &str) -> Result<DVec3> {
    el.req(name)?;
    Ok(el.vec3(name)?.unwrap_or(DVec3::ZERO))
}
