//! `<animate>`: one keyed channel of a `<model>`, `<camera>` or `<light>`
//! (a Trevi extension, docs/aisxml-extensions.md "Animation"). The keys are
//! read here; what they mean at a time `t` is `scene::animation`.

use super::table::{extension, Attribute, REQUIRED};
use super::values::{parse_real, tokens, El, NumError};
use super::xml::{excerpt, is_xml_ws, Elem};
use super::{Resolver, Result};
use crate::error::SceneErrorKind;
use crate::scene::animation::{Track, MAX_KEYS};

/// The attributes of `<animate>`.
pub(super) const ANIMATE: &[Attribute] = &[
    extension(
        "channel",
        "keyword (per parent, see below)",
        REQUIRED,
        "what the keys set: translate, rotate or scale of a model; position, direction, lookat, fov or focus of a camera; position or intensity of a light",
    ),
    extension(
        "times",
        "reals, strictly increasing (at most 65536)",
        REQUIRED,
        "the keys' times in seconds",
    ),
    extension(
        "values",
        "reals, the channel's count per key",
        REQUIRED,
        "the keys' values, key after key",
    ),
];

/// What a channel's keys hold.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Kind {
    /// Three numbers.
    Vector,
    /// Three numbers, not all zero.
    Direction,
    /// Three numbers, each > 0.
    Scale,
    /// An axis (three numbers, not all zero) and an angle in degrees.
    Rotation,
    /// One number in (0, 180).
    Fov,
    /// One number > 0.
    Positive,
    /// One number ≥ 0.
    NonNegative,
}

impl Kind {
    fn arity(self) -> usize {
        match self {
            Kind::Vector | Kind::Direction | Kind::Scale => 3,
            Kind::Rotation => 4,
            Kind::Fov | Kind::Positive | Kind::NonNegative => 1,
        }
    }

    fn what(self) -> &'static str {
        match self {
            Kind::Vector => "three numbers \"x y z\" per key",
            Kind::Direction => "a non-zero direction \"x y z\" per key",
            Kind::Scale => "three factors \"x y z\", each > 0, per key",
            Kind::Rotation => {
                "an axis and an angle in degrees \"x y z angle\" per key (axis non-zero)"
            }
            Kind::Fov => "one angle in (0, 180) per key",
            Kind::Positive => "one number > 0 per key",
            Kind::NonNegative => "one number ≥ 0 per key",
        }
    }

    /// Checks (and normalises) one key's numbers.
    fn check(self, v: &mut [f64]) -> bool {
        match self {
            Kind::Vector => true,
            Kind::Direction | Kind::Rotation => {
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                if !(l > 0.0) || !l.is_finite() {
                    return false;
                }
                if self == Kind::Rotation {
                    for x in &mut v[..3] {
                        *x /= l;
                    }
                }
                true
            }
            Kind::Scale => v.iter().all(|&x| x as f32 > 0.0),
            Kind::Fov => v[0] > 0.0 && v[0] < 180.0,
            Kind::Positive => v[0] as f32 > 0.0,
            Kind::NonNegative => v[0] >= 0.0,
        }
    }
}

/// One `<animate>` read: its channel's index in the parent's list and its keys.
pub(super) struct Keys {
    pub channel: usize,
    /// Offset of the `<animate>`'s `<`.
    pub pos: usize,
    pub times: Vec<f64>,
    /// `arity` numbers per key.
    pub values: Vec<f64>,
}

impl Keys {
    pub fn track<const N: usize>(&self) -> Track<N> {
        Track {
            times: self.times.clone(),
            values: self
                .values
                .chunks_exact(N)
                .map(|c| std::array::from_fn(|i| c[i]))
                .collect(),
        }
    }
}

impl<'a> Resolver<'a> {
    /// Reads the `<animate>` children of `parent`, whose channels are
    /// `channels` (name and kind): at most one `<animate>` per channel.
    pub(super) fn animates(
        &self,
        parent: &'a Elem,
        channels: &[(&str, Kind)],
    ) -> Result<Vec<Keys>> {
        let mut out: Vec<Keys> = Vec::new();
        for c in parent.children.iter().filter(|c| c.name == "animate") {
            let el = self.el(c);
            let keys = animate(&el, channels)?;
            if let Some(first) = out.iter().find(|k| k.channel == keys.channel) {
                return Err(el
                    .err(format!(
                        "a second <animate channel=\"{}\"> in this <{}> (the first is at {}; expected one per channel)",
                        channels[keys.channel].0,
                        parent.name,
                        self.src.line_col(first.pos)
                    ))
                    .with_kind(SceneErrorKind::UnknownElement));
            }
            out.push(keys);
        }
        Ok(out)
    }
}

fn animate(el: &El, channels: &[(&str, Kind)]) -> Result<Keys> {
    el.check_attrs(ANIMATE)?;
    let ca = el.req("channel")?;
    let ta = el.req("times")?;
    let va = el.req("values")?;
    let name = ca.value.trim_matches(is_xml_ws);
    let Some(channel) = channels.iter().position(|(n, _)| *n == name) else {
        let l: Vec<String> = channels.iter().map(|(k, _)| format!("\"{k}\"")).collect();
        return Err(el.expected(ca, &format!("one of {}", l.join(", "))));
    };
    let kind = channels[channel].1;

    let count = tokens(&ta.value).count();
    if count > MAX_KEYS {
        return Err(el
            .attr_err(
                ta,
                format!("{count} keys (expected at most {MAX_KEYS} per channel)"),
            )
            .with_kind(SceneErrorKind::Limit));
    }
    if count == 0 {
        return Err(el.expected(ta, "at least one time in seconds"));
    }
    let times = numbers(el, ta, "times in seconds")?;
    for (i, w) in times.windows(2).enumerate() {
        if w[1] <= w[0] {
            let how = if w[1] == w[0] {
                "repeats"
            } else {
                "comes before"
            };
            return Err(el.expected(
                ta,
                &format!(
                    "strictly increasing times (key {} at t = {} {how} key {} at t = {})",
                    i + 1,
                    w[1],
                    i,
                    w[0]
                ),
            ));
        }
    }

    let arity = kind.arity();
    let n = tokens(&va.value).count();
    if n != arity * count {
        return Err(el
            .attr_err(
                va,
                format!(
                    "expected {} for {count} key{} ({} numbers), found {n} number{}",
                    kind.what(),
                    if count == 1 { "" } else { "s" },
                    arity * count,
                    if n == 1 { "" } else { "s" }
                ),
            )
            .with_kind(SceneErrorKind::BadValue));
    }
    let mut values = numbers(el, va, kind.what())?;
    for (i, key) in values.chunks_exact_mut(arity).enumerate() {
        if !kind.check(key) {
            let shown: Vec<String> = key.iter().map(f64::to_string).collect();
            return Err(el.expected(
                va,
                &format!(
                    "{} (key {i} is \"{}\")",
                    kind.what(),
                    excerpt(&shown.join(" "))
                ),
            ));
        }
    }
    Ok(Keys {
        channel,
        pos: el.e.pos,
        times,
        values,
    })
}

/// Every number of an attribute (already counted, so bounded).
fn numbers(el: &El, a: &super::xml::Attr, what: &str) -> Result<Vec<f64>> {
    tokens(&a.value)
        .map(|(_, tok)| match parse_real(tok) {
            Ok(v) => Ok(v),
            Err(e) => Err(el
                .attr_err(
                    a,
                    format!(
                        "expected {what}, found \"{}\" ({})",
                        excerpt(tok),
                        match e {
                            NumError::Malformed => "not a number",
                            NumError::NonFinite => "not a finite number",
                        }
                    ),
                )
                .with_kind(SceneErrorKind::BadValue)),
        })
        .collect()
}
