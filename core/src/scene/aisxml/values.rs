//! Typed access to an element's attributes and text: numbers, vectors,
//! colors, integers, booleans and enumerations, each failing with a located
//! error that says what was expected.

use super::table::Attribute;
use super::xml::{excerpt, is_xml_ws, Attr, Elem, Src, Text};
use crate::error::{SceneError, SceneErrorKind};
use glam::{DVec3, Vec3};

pub(super) type Result<T> = std::result::Result<T, SceneError>;

/// Splits text at XML whitespace, yielding `(byte index, token)`.
pub(super) fn tokens(s: &str) -> impl Iterator<Item = (usize, &str)> {
    let base = s.as_ptr() as usize;
    s.split(is_xml_ws)
        .filter(|t| !t.is_empty())
        .map(move |t| (t.as_ptr() as usize - base, t))
}

/// Why a token is not an acceptable number.
pub(super) enum NumError {
    Malformed,
    NonFinite,
}

/// Parses one real number; it must be finite and representable as an `f32`
/// (the renderer's precision), so `1e39` counts as non-finite.
pub(super) fn parse_real(tok: &str) -> std::result::Result<f64, NumError> {
    // Rust's parser also takes "inf", "NaN", "infinity": classify those as
    // non-finite rather than malformed.
    let v: f64 = tok.parse().map_err(|_| NumError::Malformed)?;
    if !v.is_finite() || v.abs() > f32::MAX as f64 {
        return Err(NumError::NonFinite);
    }
    Ok(v)
}

/// Parses a non-negative decimal integer (`+` allowed), `None` if malformed
/// or too large for a `u64`.
pub(super) fn parse_uint(tok: &str) -> Option<u64> {
    let digits = tok.strip_prefix('+').unwrap_or(tok);
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    digits.parse().ok()
}

/// An element being read, with the scene file for locating errors.
pub(super) struct El<'a> {
    pub src: &'a Src<'a>,
    pub e: &'a Elem,
}

impl<'a> El<'a> {
    pub fn new(src: &'a Src<'a>, e: &'a Elem) -> Self {
        El { src, e }
    }

    pub fn name(&self) -> &str {
        &self.e.name
    }

    /// An error at the element's `<`.
    pub fn err(&self, msg: impl Into<String>) -> SceneError {
        self.src.err(self.e.pos, msg)
    }

    /// An error at an attribute's name: `attribute "a" of <e>: {msg}`.
    pub fn attr_err(&self, a: &Attr, msg: impl std::fmt::Display) -> SceneError {
        self.src.err(
            a.pos,
            format!("attribute \"{}\" of <{}>: {msg}", a.name, self.e.name),
        )
    }

    /// `expected {expected}, found "{value}"`.
    pub fn expected(&self, a: &Attr, expected: &str) -> SceneError {
        self.attr_err(
            a,
            format!("expected {expected}, found \"{}\"", excerpt(&a.value)),
        )
        .with_kind(SceneErrorKind::BadValue)
    }

    /// Fails on the first attribute not in the element's table `allowed`.
    pub fn check_attrs(&self, allowed: &[Attribute]) -> Result<()> {
        for a in &self.e.attrs {
            if !allowed.iter().any(|t| t.name == a.name) {
                let expected = if allowed.is_empty() {
                    "no attributes".to_string()
                } else {
                    let l: Vec<String> =
                        allowed.iter().map(|t| format!("\"{}\"", t.name)).collect();
                    format!("one of {}", l.join(", "))
                };
                return Err(self
                    .src
                    .err(
                        a.pos,
                        format!(
                            "unknown attribute \"{}\" of <{}> (expected {expected})",
                            excerpt(&a.name),
                            self.e.name
                        ),
                    )
                    .with_kind(SceneErrorKind::UnknownAttribute));
            }
        }
        Ok(())
    }

    pub fn get(&self, name: &str) -> Option<&'a Attr> {
        self.e.attrs.iter().find(|a| a.name == name)
    }

    /// A required attribute; missing is an error at the element.
    pub fn req(&self, name: &str) -> Result<&'a Attr> {
        self.get(name).ok_or_else(|| {
            self.err(format!(
                "<{}> is missing its required attribute \"{name}\"",
                self.e.name
            ))
            .with_kind(SceneErrorKind::Missing)
        })
    }

    /// A non-empty identifier.
    pub fn id(&self, name: &str) -> Result<(&'a Attr, String)> {
        let a = self.req(name)?;
        let v = a.value.trim_matches(is_xml_ws);
        if v.is_empty() {
            return Err(self.expected(a, "a non-empty id"));
        }
        Ok((a, v.to_string()))
    }

    /// Parses `count` numbers from an attribute; `what` describes them.
    pub fn reals(&self, a: &Attr, counts: &[usize], what: &str) -> Result<Vec<f64>> {
        let mut out = Vec::new();
        for (_, tok) in tokens(&a.value) {
            match parse_real(tok) {
                Ok(v) => out.push(v),
                Err(NumError::Malformed) => {
                    return Err(self
                        .attr_err(
                            a,
                            format!(
                                "expected {what}, found \"{}\" (\"{}\" is not a number)",
                                excerpt(&a.value),
                                excerpt(tok)
                            ),
                        )
                        .with_kind(SceneErrorKind::BadValue))
                }
                Err(NumError::NonFinite) => {
                    return Err(self
                        .attr_err(
                            a,
                            format!(
                        "expected {what} (finite), found \"{}\" (\"{}\" is not a finite number)",
                        excerpt(&a.value),
                        excerpt(tok)
                    ),
                        )
                        .with_kind(SceneErrorKind::BadValue))
                }
            }
            if out.len() > counts.iter().copied().max().unwrap_or(0) {
                break;
            }
        }
        if !counts.contains(&out.len()) {
            let n = tokens(&a.value).count();
            return Err(self
                .attr_err(
                    a,
                    format!(
                        "expected {what}, found {n} number{} in \"{}\"",
                        if n == 1 { "" } else { "s" },
                        excerpt(&a.value)
                    ),
                )
                .with_kind(SceneErrorKind::BadValue));
        }
        Ok(out)
    }

    /// A single number satisfying `ok`; `expected` describes the range, e.g.
    /// "a number in (0, 180)".
    pub fn real_in(
        &self,
        name: &str,
        expected: &str,
        ok: impl Fn(f64) -> bool,
    ) -> Result<Option<f64>> {
        let Some(a) = self.get(name) else {
            return Ok(None);
        };
        // Checked at the precision it is stored in (1e-50 > 0, but not as f32).
        let v = f64::from(self.reals(a, &[1], expected)?[0] as f32);
        if !ok(v) {
            return Err(self.expected(a, expected));
        }
        Ok(Some(v))
    }

    /// Any single finite number.
    pub fn real(&self, name: &str) -> Result<Option<f64>> {
        self.real_in(name, "a number", |_| true)
    }

    /// A vector `x y z`.
    pub fn vec3(&self, name: &str) -> Result<Option<DVec3>> {
        let Some(a) = self.get(name) else {
            return Ok(None);
        };
        let v = self.reals(a, &[3], "three numbers \"x y z\"")?;
        Ok(Some(DVec3::new(v[0], v[1], v[2])))
    }

    /// A non-zero vector, normalised.
    pub fn direction(&self, name: &str) -> Result<Option<DVec3>> {
        let Some(a) = self.get(name) else {
            return Ok(None);
        };
        let v = self.vec3(name)?.unwrap_or(DVec3::ZERO);
        let n = v.normalize_or_zero();
        if n == DVec3::ZERO || !n.is_finite() {
            return Err(self.expected(a, "a non-zero direction \"x y z\""));
        }
        Ok(Some(n))
    }

    /// A color `r g b` with every component ≥ 0.
    pub fn color(&self, name: &str) -> Result<Option<Vec3>> {
        let Some(a) = self.get(name) else {
            return Ok(None);
        };
        let what = "a color \"r g b\" (three numbers ≥ 0)";
        let v = self.reals(a, &[3], what)?;
        if v.iter().any(|&c| c < 0.0) {
            return Err(self.expected(a, what));
        }
        Ok(Some(Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32)))
    }

    /// An integer in `[min, max]`.
    pub fn uint(&self, name: &str, min: u64, max: u64) -> Result<Option<u64>> {
        let Some(a) = self.get(name) else {
            return Ok(None);
        };
        let expected = if max == u64::MAX {
            format!("an integer ≥ {min}")
        } else {
            format!("an integer in [{min}, {max}]")
        };
        let mut toks = tokens(&a.value);
        let v = match (toks.next(), toks.next()) {
            (Some((_, t)), None) => parse_uint(t),
            _ => None,
        };
        match v {
            Some(v) if v >= min && v <= max => Ok(Some(v)),
            _ => Err(self.expected(a, &expected)),
        }
    }

    /// `u32` integer in `[min, max]`.
    pub fn u32_in(&self, name: &str, min: u32, max: u32) -> Result<Option<u32>> {
        Ok(self
            .uint(name, u64::from(min), u64::from(max))?
            .map(|v| v as u32))
    }

    /// `true` / `false` (also `1` / `0`).
    pub fn boolean(&self, name: &str) -> Result<Option<bool>> {
        let Some(a) = self.get(name) else {
            return Ok(None);
        };
        match a.value.trim_matches(is_xml_ws) {
            "true" | "1" => Ok(Some(true)),
            "false" | "0" => Ok(Some(false)),
            _ => Err(self.expected(a, "\"true\" or \"false\"")),
        }
    }

    /// One of a fixed set of keywords.
    pub fn keyword<T: Copy>(&self, name: &str, options: &[(&str, T)]) -> Result<Option<T>> {
        let Some(a) = self.get(name) else {
            return Ok(None);
        };
        let v = a.value.trim_matches(is_xml_ws);
        match options.iter().find(|(k, _)| *k == v) {
            Some(&(_, t)) => Ok(Some(t)),
            None => {
                let l: Vec<String> = options.iter().map(|(k, _)| format!("\"{k}\"")).collect();
                Err(self.expected(a, &format!("one of {}", l.join(", "))))
            }
        }
    }

    /// The element's text as `(file offset, token)` pairs.
    pub fn text_tokens(&self) -> impl Iterator<Item = (usize, &'a str)> + 'a {
        let t: &'a Text = &self.e.text;
        tokens(&t.s).map(move |(i, tok)| (t.file_pos(i), tok))
    }

    /// The element's text as real numbers.
    pub fn text_reals(&self) -> Result<Vec<f64>> {
        let mut out = Vec::new();
        for (pos, tok) in self.text_tokens() {
            match parse_real(tok) {
                Ok(v) => out.push(v),
                Err(NumError::Malformed) => {
                    return Err(self
                        .src
                        .err(
                            pos,
                            format!(
                                "<{}>: expected a number, found \"{}\"",
                                self.e.name,
                                excerpt(tok)
                            ),
                        )
                        .with_kind(SceneErrorKind::BadValue))
                }
                Err(NumError::NonFinite) => {
                    return Err(self
                        .src
                        .err(
                            pos,
                            format!(
                                "<{}>: expected a finite number, found \"{}\"",
                                self.e.name,
                                excerpt(tok)
                            ),
                        )
                        .with_kind(SceneErrorKind::BadValue))
                }
            }
        }
        Ok(out)
    }
}
