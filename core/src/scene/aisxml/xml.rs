//! Phase 1 of AISXML parsing: XML text → a small element tree that remembers
//! the byte offset of every element, attribute and character of text.
//!
//! quick-xml does the tokenising; this module adds what quick-xml leaves to
//! its callers and the spec demands: attribute syntax (with positions),
//! entity handling (only the five predefined entities and character
//! references, never a DTD), a single root, no stray text, and the AISXML
//! element structure (which element may appear inside which), checked as the
//! tree is built so that nesting depth is bounded by the schema.

use super::table::Element;
use crate::error::{Location, SceneError, SceneErrorKind};
use quick_xml::events::Event;
use quick_xml::Reader;
use std::collections::HashMap;

/// The scene file being parsed: its name (for error locations) and its text.
pub(super) struct Src<'a> {
    pub file: &'a str,
    pub text: &'a str,
}

impl Src<'_> {
    /// An error at byte offset `pos` of the scene file.
    pub fn err(&self, pos: usize, message: impl Into<String>) -> SceneError {
        SceneError::new(
            Location::at_offset(self.file, self.text.as_bytes(), pos),
            message,
        )
    }

    /// `line:column` of byte offset `pos`, for messages that refer to an
    /// earlier place in the same file.
    pub fn line_col(&self, pos: usize) -> String {
        let l = Location::at_offset(self.file, self.text.as_bytes(), pos);
        format!("{}:{}", l.line, l.column)
    }
}

/// An attribute with its (entity-expanded, whitespace-normalised) value.
#[derive(Debug)]
pub(super) struct Attr {
    pub name: String,
    /// Byte offset of the attribute's name.
    pub pos: usize,
    pub value: String,
}

/// Character data with a map back to byte offsets in the scene file.
#[derive(Debug, Default)]
pub(super) struct Text {
    pub s: String,
    /// `(index in s, offset in the file)`: from each anchor on, bytes of `s`
    /// were copied verbatim from the file until the next anchor.
    anchors: Vec<(usize, usize)>,
}

impl Text {
    /// The file offset of byte `idx` of the text.
    pub fn file_pos(&self, idx: usize) -> usize {
        let i = self.anchors.partition_point(|&(at, _)| at <= idx);
        match i.checked_sub(1).and_then(|i| self.anchors.get(i)) {
            Some(&(at, pos)) => pos + (idx - at),
            None => 0,
        }
    }

    /// Appends a CDATA section's content (taken literally).
    fn push_literal(&mut self, raw: &str, pos: usize) {
        self.anchors.push((self.s.len(), pos));
        self.s.push_str(raw);
    }

    /// Appends escaped character data, expanding references.
    fn push_escaped(&mut self, src: &Src, raw: &str, pos: usize) -> Result<(), SceneError> {
        self.anchors.push((self.s.len(), pos));
        let mut rest = raw;
        let mut at = pos;
        while let Some(amp) = rest.find('&') {
            self.s.push_str(&rest[..amp]);
            let (c, len) = reference(src, &rest[amp..], at + amp)?;
            self.anchors.push((self.s.len(), at + amp));
            self.s.push(c);
            rest = &rest[amp + len..];
            at += amp + len;
            self.anchors.push((self.s.len(), at));
        }
        self.s.push_str(rest);
        Ok(())
    }
}

/// An element of the tree.
#[derive(Debug)]
pub(super) struct Elem {
    pub name: String,
    /// Byte offset of the element's `<`.
    pub pos: usize,
    pub attrs: Vec<Attr>,
    pub children: Vec<Elem>,
    /// Character data; only kept for elements that take text.
    pub text: Text,
}

/// The elements that may appear inside `parent` (`""`: the document,
/// whose one element is the table's first, the root).
fn allowed_children<R>(elements: &'static [Element<R>], parent: &str) -> &'static [&'static str] {
    if parent.is_empty() {
        return elements
            .first()
            .map_or(&[], |root| std::slice::from_ref(&root.name));
    }
    elements
        .iter()
        .find(|e| e.name == parent)
        .map_or(&[], |e| e.children)
}

/// Whether element `name`'s content is text (whitespace-separated numbers).
fn takes_text<R>(elements: &[Element<R>], name: &str) -> bool {
    elements.iter().any(|e| e.name == name && e.text)
}

/// XML whitespace (the only characters that separate numbers).
pub(super) fn is_xml_ws(c: char) -> bool {
    matches!(c, ' ' | '\t' | '\n' | '\r')
}

fn is_xml_ws_byte(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\n' | b'\r')
}

/// Shortens a quoted value for an error message.
pub(super) fn excerpt(s: &str) -> String {
    const MAX: usize = 40;
    if s.chars().count() <= MAX {
        s.to_string()
    } else {
        let mut t: String = s.chars().take(MAX).collect();
        t.push('…');
        t
    }
}

/// Decodes the reference at the start of `s` (which starts with `&`) at file
/// offset `pos`: returns the character and the reference's length in bytes.
fn reference(src: &Src, s: &str, pos: usize) -> Result<(char, usize), SceneError> {
    let end = s.bytes().take(64).position(|b| b == b';').filter(|&e| {
        s[1..e].bytes().all(|b| {
            b == b'#'
                || b == b'_'
                || b == b'-'
                || b == b'.'
                || b.is_ascii_alphanumeric()
                || b >= 0x80
        })
    });
    let Some(end) = end else {
        return Err(src.err(
            pos,
            "malformed XML: a bare \"&\" must be written \"&amp;\" (expected an entity reference like \"&amp;\" ending in \";\")",
        ));
    };
    let name = &s[1..end];
    let c = match name {
        "lt" => Some('<'),
        "gt" => Some('>'),
        "amp" => Some('&'),
        "apos" => Some('\''),
        "quot" => Some('"'),
        _ => {
            if let Some(num) = name.strip_prefix('#') {
                let code = if let Some(hex) = num.strip_prefix('x') {
                    u32::from_str_radix(hex, 16)
                        .ok()
                        .filter(|_| !hex.starts_with('+'))
                } else {
                    num.parse::<u32>().ok().filter(|_| !num.starts_with('+'))
                };
                match code.and_then(char::from_u32) {
                    Some(c) if c != '\0' => Some(c),
                    _ => {
                        return Err(src.err(
                            pos,
                            format!(
                                "malformed XML: \"&{name};\" is not a valid character reference (expected \"&#N;\" or \"&#xH;\" naming a character)"
                            ),
                        ))
                    }
                }
            } else {
                None
            }
        }
    };
    match c {
        Some(c) => Ok((c, end + 1)),
        None => Err(src.err(
            pos,
            format!(
                "entity reference \"&{}\" is not allowed: AISXML has no DTD; expected one of &lt; &gt; &amp; &apos; &quot; or a character reference",
                excerpt(&format!("{name};"))
            ),
        )),
    }
}

/// Expands references in an attribute value and normalises literal
/// whitespace characters to spaces, as XML does. `pos` is the file offset of
/// the value's first byte.
fn attr_value(src: &Src, raw: &str, pos: usize) -> Result<String, SceneError> {
    let mut out = String::with_capacity(raw.len());
    let mut rest = raw;
    let mut at = pos;
    loop {
        let Some(i) = rest.find(['&', '<', '\t', '\n', '\r']) else {
            out.push_str(rest);
            return Ok(out);
        };
        out.push_str(&rest[..i]);
        let b = rest.as_bytes()[i];
        let len =
            match b {
                b'&' => {
                    let (c, len) = reference(src, &rest[i..], at + i)?;
                    out.push(c);
                    len
                }
                b'<' => return Err(src.err(
                    at + i,
                    "malformed XML: \"<\" is not allowed in an attribute value (expected \"&lt;\")",
                )),
                _ => {
                    out.push(' ');
                    1
                }
            };
        rest = &rest[i + len..];
        at += i + len;
    }
}

/// Splits a start tag's content (between `<` and `>` or `/>`) into the name
/// and attributes. `pos` is the offset of the `<`.
fn start_tag(src: &Src, content: &[u8], pos: usize) -> Result<(String, Vec<Attr>), SceneError> {
    let content = std::str::from_utf8(content)
        .map_err(|_| src.err(pos, "malformed XML: the tag is not valid UTF-8"))?;
    let name_end = content
        .bytes()
        .position(is_xml_ws_byte)
        .unwrap_or(content.len());
    let name = &content[..name_end];
    if name.is_empty() {
        return Err(src.err(pos, "malformed XML: expected an element name after \"<\""));
    }
    let base = pos + 1;
    let b = content.as_bytes();
    let mut i = name_end;
    let mut attrs: Vec<Attr> = Vec::new();
    // Attribute name → index in `attrs`, so that a duplicate is found in
    // constant time: scanning the earlier attributes for each made a tag
    // with many attributes quadratic (AISXML elements have at most ten
    // legal ones, but the duplicate check runs before that check does).
    let mut seen: HashMap<&str, usize> = HashMap::new();
    loop {
        let ws_start = i;
        while i < b.len() && is_xml_ws_byte(b[i]) {
            i += 1;
        }
        if i == b.len() {
            break;
        }
        if i == ws_start {
            return Err(src.err(
                base + i,
                "malformed XML: expected whitespace between attributes",
            ));
        }
        let name_start = i;
        while i < b.len()
            && !is_xml_ws_byte(b[i])
            && !matches!(b[i], b'=' | b'"' | b'\'' | b'<' | b'>' | b'/')
        {
            i += 1;
        }
        let attr_name = &content[name_start..i];
        if attr_name.is_empty() {
            let found: String = content[i..].chars().take(1).collect();
            return Err(src.err(
                base + i,
                format!(
                    "malformed XML: expected an attribute name or the end of the tag, found \"{found}\""
                ),
            ));
        }
        while i < b.len() && is_xml_ws_byte(b[i]) {
            i += 1;
        }
        if b.get(i) != Some(&b'=') {
            return Err(src.err(
                base + name_start,
                format!(
                    "malformed XML: attribute \"{}\" has no value (expected {}=\"...\")",
                    excerpt(attr_name),
                    excerpt(attr_name)
                ),
            ));
        }
        i += 1;
        while i < b.len() && is_xml_ws_byte(b[i]) {
            i += 1;
        }
        let quote = match b.get(i) {
            Some(&q) if q == b'"' || q == b'\'' => q,
            _ => {
                return Err(src.err(
                    base + i,
                    format!(
                        "malformed XML: expected a quoted value for attribute \"{}\"",
                        excerpt(attr_name)
                    ),
                ))
            }
        };
        i += 1;
        let value_start = i;
        let Some(len) = b[i..].iter().position(|&c| c == quote) else {
            return Err(src.err(
                base + value_start - 1,
                format!(
                    "malformed XML: the value of attribute \"{}\" is not closed (expected a closing {})",
                    excerpt(attr_name),
                    quote as char
                ),
            ));
        };
        let raw = &content[value_start..value_start + len];
        i = value_start + len + 1;
        if let Some(prev) = seen.get(attr_name).map(|&i| &attrs[i]) {
            return Err(src.err(
                base + name_start,
                format!(
                    "malformed XML: attribute \"{}\" is given twice (first at {}); expected each attribute at most once",
                    excerpt(attr_name),
                    src.line_col(prev.pos)
                ),
            ));
        }
        let value = attr_value(src, raw, base + value_start)?;
        seen.insert(attr_name, attrs.len());
        attrs.push(Attr {
            name: attr_name.to_string(),
            pos: base + name_start,
            value,
        });
    }
    Ok((name.to_string(), attrs))
}

/// Checks that text which is not content of a text element is only
/// whitespace (after expanding references).
fn only_whitespace(
    src: &Src,
    raw: &str,
    pos: usize,
    literal: bool,
    parent: &str,
) -> Result<(), SceneError> {
    let mut t = Text::default();
    if literal {
        t.push_literal(raw, pos);
    } else {
        t.push_escaped(src, raw, pos)?;
    }
    if let Some(i) = t.s.find(|c: char| !is_xml_ws(c)) {
        let msg = if parent.is_empty() {
            "unexpected text outside the root element (expected only whitespace and comments)"
                .to_string()
        } else {
            format!("unexpected text inside <{parent}> (expected only whitespace, comments and elements)")
        };
        return Err(src.err(t.file_pos(i), msg));
    }
    Ok(())
}

fn quick_xml_message(e: &quick_xml::Error) -> String {
    format!("malformed XML: {e}")
}

/// Parses the document into its root element, checking XML well-formedness
/// and the AISXML element structure (`elements`: which element may appear
/// inside which, and which take text).
pub(super) fn parse_document<R>(
    src: &Src,
    elements: &'static [Element<R>],
) -> Result<Elem, SceneError> {
    // Every error here is a syntax error unless it says otherwise.
    parse_tree(src, elements).map_err(|e| match e.kind {
        SceneErrorKind::Invalid => e.with_kind(SceneErrorKind::Syntax),
        _ => e,
    })
}

fn parse_tree<R>(src: &Src, elements: &'static [Element<R>]) -> Result<Elem, SceneError> {
    let mut reader = Reader::from_str(src.text);
    {
        let c = reader.config_mut();
        c.check_comments = true;
        c.check_end_names = true;
        c.expand_empty_elements = false;
        c.trim_text(false);
    }
    let mut stack: Vec<Elem> = Vec::new();
    let mut root: Option<Elem> = None;
    let mut first_event = true;
    loop {
        let start = usize::try_from(reader.buffer_position()).unwrap_or(usize::MAX);
        let event = match reader.read_event() {
            Ok(ev) => ev,
            Err(e) => {
                let at = usize::try_from(reader.error_position()).unwrap_or(usize::MAX);
                return Err(src.err(at, quick_xml_message(&e)));
            }
        };
        let was_first = first_event;
        first_event = false;
        match event {
            Event::Start(ref e) | Event::Empty(ref e) => {
                let empty = matches!(event, Event::Empty(_));
                let (name, attrs) = start_tag(src, e, start)?;
                let parent = stack.last().map_or("", |p| p.name.as_str());
                if stack.is_empty() && root.is_some() {
                    return Err(src.err(
                        start,
                        format!(
                            "unexpected element <{}> after the root element (expected a single <scene> root)",
                            excerpt(&name)
                        ),
                    )
                    .with_kind(SceneErrorKind::UnknownElement));
                }
                let allowed = allowed_children(elements, parent);
                if !allowed.contains(&name.as_str()) {
                    let msg = if parent.is_empty() {
                        format!(
                            "expected the root element <scene version=\"1\">, found <{}>",
                            excerpt(&name)
                        )
                    } else if allowed.is_empty() {
                        format!(
                            "unknown element <{}> inside <{parent}> (expected no child elements there)",
                            excerpt(&name)
                        )
                    } else {
                        let list: Vec<String> = allowed.iter().map(|a| format!("<{a}>")).collect();
                        format!(
                            "unknown element <{}> inside <{parent}> (expected one of {})",
                            excerpt(&name),
                            list.join(", ")
                        )
                    };
                    return Err(src
                        .err(start, msg)
                        .with_kind(SceneErrorKind::UnknownElement));
                }
                let elem = Elem {
                    name,
                    pos: start,
                    attrs,
                    children: Vec::new(),
                    text: Text::default(),
                };
                if empty {
                    match stack.last_mut() {
                        Some(p) => p.children.push(elem),
                        None => root = Some(elem),
                    }
                } else {
                    stack.push(elem);
                }
            }
            Event::End(_) => {
                // quick-xml has checked that the name matches the open element.
                let Some(elem) = stack.pop() else {
                    return Err(src.err(start, "malformed XML: unexpected closing tag"));
                };
                match stack.last_mut() {
                    Some(p) => p.children.push(elem),
                    None => root = Some(elem),
                }
            }
            Event::Text(ref t) => {
                let raw = std::str::from_utf8(t)
                    .map_err(|_| src.err(start, "malformed XML: text is not valid UTF-8"))?;
                match stack.last_mut() {
                    Some(p) if takes_text(elements, &p.name) => {
                        p.text.push_escaped(src, raw, start)?
                    }
                    p => {
                        only_whitespace(src, raw, start, false, p.map_or("", |p| p.name.as_str()))?
                    }
                }
            }
            Event::CData(ref t) => {
                let raw = std::str::from_utf8(t)
                    .map_err(|_| src.err(start, "malformed XML: text is not valid UTF-8"))?;
                let content_pos = start + "<![CDATA[".len();
                if stack.is_empty() {
                    return Err(src.err(
                        start,
                        "malformed XML: a CDATA section outside the root element (expected only comments and whitespace there)",
                    ));
                }
                match stack.last_mut() {
                    Some(p) if takes_text(elements, &p.name) => {
                        p.text.push_literal(raw, content_pos)
                    }
                    p => only_whitespace(
                        src,
                        raw,
                        content_pos,
                        true,
                        p.map_or("", |p| p.name.as_str()),
                    )?,
                }
            }
            Event::Comment(_) | Event::PI(_) => {}
            Event::Decl(ref d) => {
                let at_start =
                    was_first && (start == 0 || src.text.get(..start) == Some("\u{feff}"));
                if !at_start {
                    return Err(src.err(
                        start,
                        "malformed XML: the XML declaration <?xml ...?> is only allowed at the very start of the file",
                    ));
                }
                if let Err(e) = d.version() {
                    return Err(src.err(start, quick_xml_message(&e)));
                }
                match d.encoding() {
                    None => {}
                    Some(Ok(enc)) if enc.eq_ignore_ascii_case(b"utf-8") => {}
                    Some(_) => {
                        return Err(src.err(
                            start,
                            "the XML declaration names an encoding other than UTF-8 (AISXML files are UTF-8)",
                        ))
                    }
                }
            }
            Event::DocType(_) => {
                return Err(src.err(
                    start,
                    "DTDs (<!DOCTYPE ...>) and entity declarations are not allowed in AISXML (expected no DTD)",
                ));
            }
            Event::Eof => break,
        }
    }
    if let Some(open) = stack.last() {
        return Err(src.err(
            open.pos,
            format!(
                "malformed XML: element <{}> is not closed (expected </{}> before the end of the file)",
                open.name, open.name
            ),
        ));
    }
    root.ok_or_else(|| {
        src.err(
            src.text.len(),
            "the file has no root element (expected <scene version=\"1\">)",
        )
    })
}
