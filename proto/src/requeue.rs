//! What a requeue asks for, as users type it (`trevi-submit requeue ID
//! --frames A-B --rect X,Y,W,H`) and as the monitor sends it (`POST
//! /api/jobs/{id}/requeue` with `{"frames":"A-B","rect":[x,y,w,h]}`). One
//! grammar for the client and the coordinator, with only `std` and
//! `thiserror` (the fuzz target `requeue` compiles this file alone).
//!
//! Bounds, checked before anything else is read: a `--frames` or `--rect`
//! text of at most [`MAX_ARG_CHARS`] characters, a body of at most
//! [`MAX_BODY_BYTES`] bytes. Numbers are `u32`s; whether the frames are the
//! job's and the rect is inside its frame the coordinator checks.

/// Longest `--frames` or `--rect` text read.
pub const MAX_ARG_CHARS: usize = 64;

/// Largest `POST /api/jobs/{id}/requeue` body read.
pub const MAX_BODY_BYTES: usize = 1024;

/// What is wrong with a requeue's frames, rect or body.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BadRequeue {
    /// Longer than its bound.
    #[error("{what} is longer than {max} {unit}")]
    TooLong {
        /// What was too long.
        what: &'static str,
        /// Its bound.
        max: usize,
        /// "characters" or "bytes".
        unit: &'static str,
    },
    /// Not frames `A-B` (or one frame `A`), `A` ≤ `B`.
    #[error("frames \"{0}\": expected A-B (or one frame A), whole numbers, A <= B")]
    Frames(String),
    /// Not a rect `X,Y,W,H`.
    #[error("rect \"{0}\": expected X,Y,W,H, four whole numbers")]
    Rect(String),
    /// A body that is not the JSON object this takes.
    #[error("body: {0}")]
    Body(String),
}

/// A requeue: frames `first..=last` of a sequence and/or a rect
/// `[x, y, w, h]` of the frame; neither is the whole job.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Requeue {
    /// Frames, both included.
    pub frames: Option<(u32, u32)>,
    /// The rect's `x, y, w, h`.
    pub rect: Option<[u32; 4]>,
}

fn number(s: &str) -> Option<u32> {
    let s = s.trim();
    if s.is_empty() || !s.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    s.parse().ok()
}

fn check_len(s: &str, what: &'static str) -> Result<(), BadRequeue> {
    if s.chars().count() > MAX_ARG_CHARS {
        return Err(BadRequeue::TooLong {
            what,
            max: MAX_ARG_CHARS,
            unit: "characters",
        });
    }
    Ok(())
}

/// Reads frames `A-B` or one frame `A`.
pub fn parse_frames(s: &str) -> Result<(u32, u32), BadRequeue> {
    check_len(s, "--frames")?;
    let bad = || BadRequeue::Frames(s.trim().to_string());
    let (a, b) = match s.split_once('-') {
        Some((a, b)) => (number(a).ok_or_else(bad)?, number(b).ok_or_else(bad)?),
        None => {
            let a = number(s).ok_or_else(bad)?;
            (a, a)
        }
    };
    if a > b {
        return Err(bad());
    }
    Ok((a, b))
}

/// Reads a rect `X,Y,W,H`.
pub fn parse_rect(s: &str) -> Result<[u32; 4], BadRequeue> {
    check_len(s, "--rect")?;
    let bad = || BadRequeue::Rect(s.trim().to_string());
    let mut out = [0u32; 4];
    let mut parts = s.split(',');
    for v in &mut out {
        *v = parts.next().and_then(number).ok_or_else(bad)?;
    }
    if parts.next().is_some() {
        return Err(bad());
    }
    Ok(out)
}

/// A tiny reader of the one JSON object a body is.
struct Json<'a> {
    s: &'a [u8],
    at: usize,
}

impl Json<'_> {
    fn space(&mut self) {
        while self.s.get(self.at).is_some_and(|b| b.is_ascii_whitespace()) {
            self.at += 1;
        }
    }

    fn peek(&mut self) -> Option<u8> {
        self.space();
        self.s.get(self.at).copied()
    }

    fn eat(&mut self, c: u8) -> Result<(), BadRequeue> {
        if self.peek() == Some(c) {
            self.at += 1;
            Ok(())
        } else {
            Err(BadRequeue::Body(format!(
                "expected '{}' at byte {}",
                c as char, self.at
            )))
        }
    }

    /// A string without escapes (none of this body's strings needs one).
    fn string(&mut self) -> Result<&str, BadRequeue> {
        self.eat(b'"')?;
        let start = self.at;
        while let Some(&b) = self.s.get(self.at) {
            match b {
                b'"' => {
                    let text = std::str::from_utf8(&self.s[start..self.at])
                        .map_err(|_| BadRequeue::Body("a string is not UTF-8".into()))?;
                    self.at += 1;
                    return Ok(text);
                }
                b'\\' => return Err(BadRequeue::Body("escapes are not taken in strings".into())),
                b if b < 0x20 => {
                    return Err(BadRequeue::Body("a control character in a string".into()))
                }
                _ => self.at += 1,
            }
        }
        Err(BadRequeue::Body("a string is not closed".into()))
    }

    /// A whole number from 0 to `u32::MAX`.
    fn number(&mut self) -> Result<u32, BadRequeue> {
        self.space();
        let start = self.at;
        while self.s.get(self.at).is_some_and(u8::is_ascii_digit) {
            self.at += 1;
        }
        std::str::from_utf8(&self.s[start..self.at])
            .ok()
            .and_then(number)
            .ok_or_else(|| {
                BadRequeue::Body(format!(
                    "expected a whole number from 0 to {} at byte {start}",
                    u32::MAX
                ))
            })
    }

    fn null(&mut self) -> bool {
        self.space();
        if self.s[self.at..].starts_with(b"null") {
            self.at += 4;
            true
        } else {
            false
        }
    }
}

/// Reads a requeue body: `{"frames": "A-B", "rect": [x, y, w, h]}`, both
/// keys optional (or `null`), no other. Over [`MAX_BODY_BYTES`] bytes it is
/// refused before it is read.
pub fn parse_body(body: &[u8]) -> Result<Requeue, BadRequeue> {
    if body.len() > MAX_BODY_BYTES {
        return Err(BadRequeue::TooLong {
            what: "the body",
            max: MAX_BODY_BYTES,
            unit: "bytes",
        });
    }
    let mut j = Json { s: body, at: 0 };
    let mut r = Requeue::default();
    let (mut frames, mut rect) = (false, false);
    j.eat(b'{')?;
    if j.peek() == Some(b'}') {
        j.at += 1;
    } else {
        loop {
            let key = j.string()?.to_string();
            j.eat(b':')?;
            let seen = match key.as_str() {
                "frames" => &mut frames,
                "rect" => &mut rect,
                _ => {
                    return Err(BadRequeue::Body(format!(
                        "unknown key \"{}\" (frames and rect are)",
                        key.chars().take(MAX_ARG_CHARS).collect::<String>()
                    )))
                }
            };
            if std::mem::replace(seen, true) {
                return Err(BadRequeue::Body(format!("\"{key}\" is given twice")));
            }
            if !j.null() {
                if key == "frames" {
                    r.frames = Some(parse_frames(j.string()?)?);
                } else {
                    let mut v = [0u32; 4];
                    j.eat(b'[')?;
                    for (i, x) in v.iter_mut().enumerate() {
                        if i > 0 {
                            j.eat(b',')
                                .map_err(|_| BadRequeue::Body("rect takes four numbers".into()))?;
                        }
                        *x = j.number()?;
                    }
                    j.eat(b']')
                        .map_err(|_| BadRequeue::Body("rect takes four numbers".into()))?;
                    r.rect = Some(v);
                }
            }
            match j.peek() {
                Some(b',') => j.at += 1,
                Some(b'}') => {
                    j.at += 1;
                    break;
                }
                _ => {
                    return Err(BadRequeue::Body(format!(
                        "expected ',' or '}}' at byte {}",
                        j.at
                    )))
                }
            }
        }
    }
    if j.peek().is_some() {
        return Err(BadRequeue::Body(format!(
            "something follows the object at byte {}",
            j.at
        )));
    }
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_and_rects_are_read_or_refused() {
        assert_eq!(parse_frames("3-7"), Ok((3, 7)));
        assert_eq!(parse_frames(" 5 "), Ok((5, 5)));
        assert_eq!(parse_rect("1,2,30,40"), Ok([1, 2, 30, 40]));
        for bad in ["7-3", "-1", "a-b", "", "1-2-3", "99999999999", "+1"] {
            assert!(parse_frames(bad).is_err(), "{bad}");
        }
        for bad in [
            "1,2,3",
            "1,2,3,4,5",
            "1,2,3,-4",
            "1,,3,4",
            "4294967296,0,1,1",
        ] {
            assert!(parse_rect(bad).is_err(), "{bad}");
        }
        let long = "1".repeat(MAX_ARG_CHARS + 1);
        assert!(matches!(
            parse_frames(&long),
            Err(BadRequeue::TooLong { .. })
        ));
        assert!(matches!(parse_rect(&long), Err(BadRequeue::TooLong { .. })));
    }

    #[test]
    fn bodies_are_read_or_refused_naming_why() {
        assert_eq!(parse_body(b"{}"), Ok(Requeue::default()));
        assert_eq!(
            parse_body(br#" { "frames" : "2-4", "rect": [0, 1, 2, 3] } "#),
            Ok(Requeue {
                frames: Some((2, 4)),
                rect: Some([0, 1, 2, 3])
            })
        );
        assert_eq!(
            parse_body(br#"{"frames":null,"rect":null}"#),
            Ok(Requeue::default())
        );
        for (body, says) in [
            (r#"{"frames":"4-2"}"#, "frames"),
            (r#"{"rect":[1,2,3]}"#, "four numbers"),
            (r#"{"rect":[1,2,3,4,5]}"#, "four numbers"),
            (r#"{"rect":[1,2,3,-4]}"#, "whole number"),
            (r#"{"rect":[1,2,3,4294967296]}"#, "whole number"),
            (r#"{"rect":[1,2,3,4]"#, "expected"),
            (r#"{"x":1}"#, "unknown key"),
            (r#"{"rect":[1,2,3,4],"rect":null}"#, "twice"),
            (r#"{"frames":"1\"-2"}"#, "escapes"),
            (r#"{} {}"#, "follows"),
            ("[]", "expected '{'"),
            ("", "expected '{'"),
        ] {
            let e = parse_body(body.as_bytes()).unwrap_err().to_string();
            assert!(e.contains(says), "{body:?}: {e}");
        }
        let big = format!(r#"{{"frames":"1-2"{}}}"#, " ".repeat(MAX_BODY_BYTES));
        assert!(matches!(
            parse_body(big.as_bytes()),
            Err(BadRequeue::TooLong { .. })
        ));
    }
}
