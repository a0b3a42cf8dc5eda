//! `<settings>`: the background and the ambient light, at most once per
//! scene.

use super::table::{attr, Attribute};
use super::xml::Elem;
use super::{Resolver, Result};
use crate::error::SceneErrorKind;
use crate::scene::Settings;

/// The attributes of `<settings>`.
pub(super) const SETTINGS: &[Attribute] = &[
    attr(
        "background",
        "color",
        "0 0 0",
        "the color of rays that hit nothing",
    ),
    attr("ambient", "color", "0 0 0", "the ambient light's color"),
];

impl<'a> Resolver<'a> {
    /// Reads the scene's `<settings>`; a second one is an error.
    pub(super) fn settings(&mut self, e: &'a Elem) -> Result<()> {
        if let Some(first) = self.settings_at {
            return Err(self
                .src
                .err(
                    e.pos,
                    format!(
                        "more than one <settings> (the first is at {}; expected at most one)",
                        self.src.line_col(first)
                    ),
                )
                .with_kind(SceneErrorKind::UnknownElement));
        }
        self.settings_at = Some(e.pos);
        let el = self.el(e);
        el.check_attrs(SETTINGS)?;
        let d = Settings::default();
        self.desc.settings = Settings {
            background: el.color("background")?.unwrap_or(d.background),
            ambient: el.color("ambient")?.unwrap_or(d.ambient),
        };
        Ok(())
    }
}
