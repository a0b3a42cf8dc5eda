//! `<settings>`: the background and the ambient light, at most once per
//! scene.

use super::table::{attr, Attribute};
use super::xml::Elem;
use super::{Resolver, Result};
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
    pub(super) fn settings(&mut self, e: &'a Elem) -> Result<()> {
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
