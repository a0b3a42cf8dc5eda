//! The shape of the attribute tables each element's file keeps beside the
//! code that reads the element: every attribute's name, the form of its
//! value, its default and its meaning. A reader passes its table to
//! `El::check_attrs`, so an attribute missing from the table is refused as
//! unknown; and docs/aisxml.md (with docs/aisxml-extensions.md for Trevi's
//! extensions) is checked against the tables by a test, so the reference
//! and the parser cannot drift apart. [`Element`] is the shape of the
//! reader's one table of elements, which names each element with its
//! attribute table and the elements it may hold.

/// One attribute an element accepts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Attribute {
    /// The attribute's name, as written in the file.
    pub name: &'static str,
    /// The form of the value the reader accepts.
    pub ty: &'static str,
    /// The value when absent, [`REQUIRED`], or what absence means.
    pub default: &'static str,
    /// What the value means, in a phrase (the reference's last column).
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

/// One element of AISXML: its name, its attribute table (empty when it
/// takes none), the elements that may appear inside it, and whether its
/// content is text. The reader's one table of these (`ELEMENTS` in
/// `aisxml.rs`) is what the tree is checked against, what each element's
/// attributes are looked up in, and how the root's children are read.
#[derive(Debug, Clone, Copy)]
pub struct Element<R: 'static> {
    /// The element's tag name.
    pub name: &'static str,
    /// Its attribute table.
    pub attributes: &'static [Attribute],
    /// The names of the elements it may hold.
    pub children: &'static [&'static str],
    /// Its content is text (whitespace-separated numbers), not elements.
    pub text: bool,
    /// How the reader reads it where it is a child of the root (`None`:
    /// its parent's reader reads it).
    pub read: Option<R>,
}
