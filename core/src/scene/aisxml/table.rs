//! The shape of the attribute tables each element's file keeps beside the
//! code that reads the element: every attribute's name, the form of its
//! value, its default and its meaning. A reader passes its table to
//! `El::check_attrs`, so an attribute missing from the table is refused as
//! unknown; and docs/aisxml.md (with docs/aisxml-extensions.md for Trevi's
//! extensions) is checked against the tables by a test, so the reference
//! and the parser cannot drift apart.

/// One attribute an element accepts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Attribute {
    pub name: &'static str,
    /// The form of the value the reader accepts.
    pub ty: &'static str,
    /// The value when absent, [`REQUIRED`], or what absence means.
    pub default: &'static str,
    pub meaning: &'static str,
    /// A Trevi extension of AISXML v1, documented in
    /// docs/aisxml-extensions.md rather than docs/aisxml.md.
    pub extension: bool,
}

/// The [`Attribute::default`] of a required attribute.
pub const REQUIRED: &str = "required";

/// An attribute of AISXML v1.
pub(super) const fn attr(
    name: &'static str,
    ty: &'static str,
    default: &'static str,
    meaning: &'static str,
) -> Attribute {
    Attribute {
        name,
        ty,
        default,
        meaning,
        extension: false,
    }
}

/// An attribute Trevi adds to AISXML v1.
pub(super) const fn extension(
    name: &'static str,
    ty: &'static str,
    default: &'static str,
    meaning: &'static str,
) -> Attribute {
    Attribute {
        extension: true,
        ..attr(name, ty, default, meaning)
    }
}
