//! `diffuse-texture`, `texture-wrap` and `texture-scale` on `<surface>`
//! (their rows are in `surface.rs`'s table): the image file is read from
//! the bundle and decoded once per scene, however many surfaces use it.

use super::values::El;
use super::xml::Attr;
use super::{Load, Resolver, Result};
use crate::error::SceneErrorKind;
use crate::scene::source::read_error_kind;
use crate::scene::TextureMap;
use crate::texture::jpeg_scan::JpegScanError;
use crate::texture::{header, Texture, TextureError, Wrap, MAX_SCENE_TEXELS};
use glam::Vec2;

impl<'a> Resolver<'a> {
    /// The texture of a `<surface>`, if it names one. `has_uvs`: the
    /// surface is on a mesh with texture coordinates (a texture anywhere
    /// else is an error: it would have nothing to be looked up by).
    pub(super) fn surface_texture(
        &mut self,
        el: &El<'a>,
        has_uvs: bool,
    ) -> Result<Option<TextureMap>> {
        let Some(f) = el.get("diffuse-texture") else {
            for other in ["texture-wrap", "texture-scale"] {
                if let Some(a) = el.get(other) {
                    return Err(el
                        .attr_err(a, format!("{other} without diffuse-texture (expected diffuse-texture= beside it)"))
                        .with_kind(SceneErrorKind::Missing));
                }
            }
            return Ok(None);
        };
        if !has_uvs {
            return Err(el
                .attr_err(
                    f,
                    "a texture needs texture coordinates (expected it on a <model> whose mesh has uvs: OBJ vt on every face corner, PLY u v, or inline <uvs>)",
                )
                .with_kind(SceneErrorKind::BadValue));
        }
        let wrap = el
            .keyword(
                "texture-wrap",
                &[("repeat", Wrap::Repeat), ("clamp", Wrap::Clamp)],
            )?
            .unwrap_or_default();
        let scale = match el.get("texture-scale") {
            None => Vec2::ONE,
            Some(a) => {
                let v = el.reals(a, &[2], "two numbers su sv")?;
                let s = Vec2::new(v[0] as f32, v[1] as f32);
                if !s.is_finite() {
                    return Err(el.expected(a, "two finite numbers su sv"));
                }
                s
            }
        };
        let texture = self.texture_file(el, f)?;
        Ok(Some(TextureMap {
            texture,
            wrap,
            scale,
        }))
    }

    /// Reads and decodes the image `f` names (once per scene), returning its
    /// index in `desc.textures` (and `sizes.textures`).
    pub(super) fn texture_file(&mut self, el: &El<'a>, f: &'a Attr) -> Result<u32> {
        let path = self.bundle_path(&Self::attr_path(el, f)?);
        self.load_texture(&path, |msg, kind| el.attr_err(f, msg).with_kind(kind))
    }

    /// Decodes the bundle file `path` once (a headers-only parse reads its
    /// size from its headers instead); `err` places an error (at the
    /// attribute, or at the `.mtl` line that named the file).
    pub(super) fn load_texture(
        &mut self,
        path: &str,
        err: impl Fn(String, SceneErrorKind) -> crate::error::SceneError,
    ) -> Result<u32> {
        if let Some(&i) = self.texture_ids.get(path) {
            return Ok(i);
        }
        let bytes = self.source.read(path).map_err(|e| {
            err(
                format!("cannot read texture file \"{path}\" ({e}); expected a file of the scene bundle"),
                read_error_kind(&e),
            )
        })?;
        let left = MAX_SCENE_TEXELS - self.texels;
        let located = |e: TextureError| {
            let kind = match e {
                TextureError::TooLarge { .. }
                | TextureError::OverBudget { .. }
                | TextureError::Png(_)
                | TextureError::Jpeg(JpegScanError::TooManyScans { .. }) => SceneErrorKind::Limit,
                _ => SceneErrorKind::Invalid,
            };
            err(format!("texture file \"{path}\": {e}"), kind)
        };
        let (width, height) = match self.load {
            Load::Full => {
                let texture = Texture::decode_within(&bytes, left).map_err(located)?;
                let l0 = &texture.levels[0];
                let size = (l0.width, l0.height);
                self.desc.textures.push(texture);
                size
            }
            // Every part's size from the headers, checked as the decoder
            // checks it before decoding.
            Load::HeadersOnly => header::probe(&bytes)
                .and_then(|h| h.check(left))
                .map_err(located)?,
        };
        self.texels += u64::from(width) * u64::from(height);
        let i = self.sizes.textures.len() as u32;
        self.sizes.textures.push((width, height));
        self.texture_ids.insert(path.to_string(), i);
        self.files.insert(path.to_string());
        Ok(i)
    }
}

#[cfg(test)]
mod tests {
    use crate::bundle::Bundle;
    use crate::error::SceneErrorKind;
    use crate::scene::aisxml::parse_scene;
    use crate::texture::Wrap;
    use std::collections::BTreeMap;

    const QUAD: &str = r#"<mesh id="q"><vertices>0 0 0 1 0 0 0 1 0</vertices><uvs>0 0 1 0 0 1</uvs><triangles>0 1 2</triangles></mesh>"#;
    const BARE: &str =
        r#"<mesh id="b"><vertices>0 0 0 1 0 0 0 1 0</vertices><triangles>0 1 2</triangles></mesh>"#;
    const CAM: &str = r#"<camera id="c" position="0 0 5" lookat="0 0 0" fov="50"><render width="4" height="3"/></camera>"#;

    fn png(w: u32, h: u32) -> Vec<u8> {
        crate::texture::tests::png_rgb8(w, h, &vec![128; (w * h * 3) as usize])
    }

    /// Parses a scene with `body` on line 2, and files `t.png` (2 × 1) and
    /// `u.png` (1 × 1).
    fn parse(body: &str) -> super::Result<crate::scene::SceneDesc> {
        let text = format!("<scene version=\"1\">\n{QUAD}{BARE}{body}\n{CAM}\n</scene>\n");
        let mut files = BTreeMap::new();
        files.insert("s.xml".to_string(), text.into_bytes());
        files.insert("t.png".to_string(), png(2, 1));
        files.insert("u.png".to_string(), png(1, 1));
        files.insert(
            "bad.png".to_string(),
            b"\x89PNG\r\n\x1a\nnot really".to_vec(),
        );
        parse_scene(
            "s.xml",
            &Bundle {
                scene: "s.xml".into(),
                files,
            },
        )
    }

    #[test]
    fn a_file_used_twice_is_decoded_once_and_listed_in_the_bundle() {
        let d = parse(
            r#"<model id="m" mesh="q"><surface diffuse-texture="t.png" texture-wrap="clamp" texture-scale="2 0.5"/>
               <surface triangles="0" diffuse-texture="./t.png"/></model>
               <model id="n" mesh="q"><surface diffuse-texture="u.png"/></model>"#,
        )
        .unwrap();
        assert_eq!(d.textures.len(), 2);
        assert_eq!(d.textures[0].levels[0].width, 2);
        let m = &d.models[0].surfaces;
        let t = m[0].texture.unwrap();
        assert_eq!(
            (t.texture, t.wrap, t.scale),
            (0, Wrap::Clamp, glam::Vec2::new(2.0, 0.5))
        );
        let t = m[1].texture.unwrap();
        assert_eq!(
            (t.texture, t.wrap, t.scale),
            (0, Wrap::Repeat, glam::Vec2::ONE)
        );
        assert_eq!(d.models[1].surfaces[0].texture.unwrap().texture, 1);
        assert!(d.files.contains(&"t.png".to_string()) && d.files.contains(&"u.png".to_string()));
        // No texture, no textures.
        let d = parse(r#"<model id="m" mesh="q"/>"#).unwrap();
        assert!(d.textures.is_empty() && d.models[0].surfaces[0].texture.is_none());
    }

    #[track_caller]
    fn fails(body: &str, column: u32, kind: SceneErrorKind, needle: &str) {
        let e = parse(body).unwrap_err();
        assert_eq!(
            (e.location.file.as_str(), e.location.line, e.location.column),
            ("s.xml", 2, column),
            "{e}"
        );
        assert_eq!(e.kind, kind, "{e}");
        assert!(e.message.contains(needle), "`{e}` lacks `{needle}`");
    }

    #[test]
    fn texture_errors_are_located_at_the_attribute() {
        let at = (QUAD.len() + BARE.len()) as u32;
        let m = r#"<model id="m" mesh="q"><surface "#;
        // Column of the attribute after `prefix` inside the surface tag.
        let col = |prefix: &str| at + (m.len() + 1 + prefix.len()) as u32;
        fails(
            &format!(r#"{m}diffuse-texture="none.png"/></model>"#),
            col(""),
            SceneErrorKind::MissingFile,
            "cannot read texture file \"none.png\"",
        );
        fails(
            &format!(r#"{m}diffuse-texture="bad.png"/></model>"#),
            col(""),
            SceneErrorKind::Invalid,
            "texture file \"bad.png\": cannot decode",
        );
        fails(
            &format!(r#"{m}diffuse-texture="../t.png"/></model>"#),
            col(""),
            SceneErrorKind::Reference,
            "inside the scene's directory",
        );
        fails(
            &format!(r#"{m}texture-wrap="clamp"/></model>"#),
            col(""),
            SceneErrorKind::Missing,
            "texture-wrap without diffuse-texture",
        );
        fails(
            &format!(r#"{m}diffuse-texture="t.png" texture-wrap="mirror"/></model>"#),
            col(r#"diffuse-texture="t.png" "#),
            SceneErrorKind::BadValue,
            "texture-wrap",
        );
        fails(
            &format!(r#"{m}diffuse-texture="t.png" texture-scale="1"/></model>"#),
            col(r#"diffuse-texture="t.png" "#),
            SceneErrorKind::BadValue,
            "su sv",
        );
        fails(
            r#"<model id="m" mesh="b"><surface diffuse-texture="t.png"/></model>"#,
            at + 33,
            SceneErrorKind::BadValue,
            "a texture needs texture coordinates",
        );
        fails(
            r#"<sphere id="s" center="0 0 0" radius="1"><surface diffuse-texture="t.png"/></sphere>"#,
            at + 51,
            SceneErrorKind::BadValue,
            "a texture needs texture coordinates",
        );
    }
}
