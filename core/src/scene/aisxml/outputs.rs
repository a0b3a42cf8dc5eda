//! The output files of a scene's cameras, checked at parse time to name
//! distinct files. A still writes one name; a sequence's pattern
//! `prefix###suffix` writes `prefix` + the frame number zero-padded to the
//! run's length + `suffix` for each frame of its range, so `x.#.png` and
//! `x.##.png` both write `x.10.png`, and a still `x.10.png` is frame 10 of
//! `x.#.png`. Two outputs that would write one file are refused at the
//! second `<render>`, naming the file and the first.
//!
//! Cost: nothing is expanded per frame (a range may have 10⁷ frames). Two
//! outputs are compared symbolically ([`first_shared`]): for each pair of
//! number lengths the two can write (at most 8 × 8: frame numbers have at
//! most 7 digits, plus the run's own length), the names' characters are
//! matched position by position, and the frame numbers' digits that are left
//! free must lie in both ranges, which is an intersection of two intervals.
//! Candidates are found by prefix in sorted maps, so an output is compared
//! only with those that could share a name with it: a pattern with the
//! stills and patterns that start with its prefix, a still with the
//! patterns whose prefix starts it.

use std::collections::BTreeMap;

use crate::scene::animation::{split_pattern, Frames};

/// The longest run of `#` in an output pattern: the frame numbers' digits
/// are compared as integers of at most this many digits (10³² fits in an
/// i128 with room).
pub const MAX_PATTERN_RUN: usize = 32;

/// One camera's output: a still's name (`run == 0`) or a sequence's
/// pattern, split at its run of `#`, with its frames.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) struct Output {
    pub prefix: String,
    pub run: usize,
    pub suffix: String,
    pub first: u32,
    pub last: u32,
}

impl Output {
    /// `path` (a still's name, or a pattern with one run of `#`, at most
    /// [`MAX_PATTERN_RUN`] long) and the frames of its `<render>`.
    pub fn new(path: &str, frames: Option<Frames>) -> Output {
        let (prefix, run, suffix) = split_pattern(path);
        let (first, last) = match frames {
            Some(f) if run > 0 => (f.first, f.last),
            _ => (0, 0),
        };
        Output {
            prefix: prefix.to_string(),
            run,
            suffix: suffix.to_string(),
            first,
            last,
        }
    }

    /// The output as written: a still's name, or the pattern.
    pub fn pattern(&self) -> String {
        format!("{}{}{}", self.prefix, "#".repeat(self.run), self.suffix)
    }

    /// The name this output writes for `frame`.
    pub fn name(&self, frame: u32) -> String {
        if self.run == 0 {
            return self.prefix.clone();
        }
        let n = self.run;
        format!("{}{frame:0n$}{}", self.prefix, self.suffix)
    }

    /// The lengths its frame numbers can be written with, each with the
    /// range of values written with that length.
    fn lengths(&self) -> Vec<(usize, i128, i128)> {
        if self.run == 0 {
            return vec![(0, 0, 0)];
        }
        let digits = |v: u32| v.to_string().len();
        let (a, b) = (i128::from(self.first), i128::from(self.last));
        (self.run.max(digits(self.first))..=self.run.max(digits(self.last)))
            .filter_map(|len| {
                let lo = if len > self.run {
                    a.max(pow10(len - 1))
                } else {
                    a
                };
                let hi = b.min(pow10(len) - 1);
                (lo <= hi).then_some((len, lo, hi))
            })
            .collect()
    }
}

fn pow10(n: usize) -> i128 {
    10i128.pow(n as u32)
}

/// A name both `a` and `b` write, as (frame of `a`, frame of `b`), if any.
pub(super) fn first_shared(a: &Output, b: &Output) -> Option<(u32, u32)> {
    for (la, loa, hia) in a.lengths() {
        for (lb, lob, hib) in b.lengths() {
            if let Some(v) = shared_with_lengths(a, la, (loa, hia), b, lb, (lob, hib)) {
                return Some(v);
            }
        }
    }
    None
}

/// [`first_shared`] for frame numbers written with `la` and `lb` digits,
/// whose values lie in `ra` and `rb`.
fn shared_with_lengths(
    a: &Output,
    la: usize,
    ra: (i128, i128),
    b: &Output,
    lb: usize,
    rb: (i128, i128),
) -> Option<(u32, u32)> {
    let (pa, xa, pb, xb) = (
        a.prefix.as_bytes(),
        a.suffix.as_bytes(),
        b.prefix.as_bytes(),
        b.suffix.as_bytes(),
    );
    let n = pa.len() + la + xa.len();
    if n != pb.len() + lb + xb.len() {
        return None;
    }
    // Each position: a literal byte, or the slot (the frame number).
    let at = |p: &[u8], l: usize, x: &[u8], i: usize| -> Option<u8> {
        if i < p.len() {
            Some(p[i])
        } else if i < p.len() + l {
            None
        } else {
            Some(x[i - p.len() - l])
        }
    };
    // Digits of each number fixed by the other's literals; the overlap of
    // the two slots is free but shared.
    let mut da: Vec<Option<u8>> = vec![None; la];
    let mut db: Vec<Option<u8>> = vec![None; lb];
    for i in 0..n {
        match (at(pa, la, xa, i), at(pb, lb, xb, i)) {
            (Some(x), Some(y)) if x != y => return None,
            (Some(_), Some(_)) | (None, None) => {}
            (Some(x), None) => {
                if !x.is_ascii_digit() {
                    return None;
                }
                db[i - pb.len()] = Some(x - b'0');
            }
            (None, Some(y)) => {
                if !y.is_ascii_digit() {
                    return None;
                }
                da[i - pa.len()] = Some(y - b'0');
            }
        }
    }
    let start = pa.len().max(pb.len());
    let end = (pa.len() + la).min(pb.len() + lb);
    let k = end.saturating_sub(start);
    // value(D) = high · 10^(k + low_len) + O · 10^low_len + low, where
    // high and low are its fixed digits before and after the overlap O.
    let bounds = |d: &[Option<u8>], s: usize, (lo, hi): (i128, i128)| -> (i128, i128) {
        let o0 = start.saturating_sub(s).min(d.len());
        let o1 = (o0 + k).min(d.len());
        let num = |ds: &[Option<u8>]| {
            ds.iter()
                .fold(0i128, |v, x| v * 10 + i128::from(x.unwrap_or(0)))
        };
        let (high, low) = (num(&d[..o0]), num(&d[o1..]));
        let low_len = d.len() - o1;
        let base = high * pow10(k + low_len) + low;
        let unit = pow10(low_len);
        // O in [ceil((lo - base) / unit), floor((hi - base) / unit)].
        let omin = (lo - base + unit - 1).div_euclid(unit);
        let omax = (hi - base).div_euclid(unit);
        (omin.max(0), omax.min(pow10(k) - 1))
    };
    let (amin, amax) = bounds(&da, pa.len(), ra);
    let (bmin, bmax) = bounds(&db, pb.len(), rb);
    let (omin, omax) = (amin.max(bmin), amax.min(bmax));
    if omin > omax {
        return None;
    }
    let value = |d: &[Option<u8>], s: usize| -> i128 {
        let o0 = start.saturating_sub(s).min(d.len());
        let digits = omin.to_string();
        let o: Vec<u8> = format!("{}{digits}", "0".repeat(k - digits.len().min(k)))
            .bytes()
            .map(|c| c - b'0')
            .collect();
        d.iter().enumerate().fold(0i128, |v, (i, x)| {
            let digit = match x {
                Some(x) => *x,
                None => o[i - o0],
            };
            v * 10 + i128::from(digit)
        })
    };
    Some((value(&da, pa.len()) as u32, value(&db, pb.len()) as u32))
}

/// The outputs seen so far, each with the offset of its `<render>`.
#[derive(Debug, Default)]
pub(super) struct Outputs {
    stills: BTreeMap<String, usize>,
    /// Patterns by prefix.
    patterns: BTreeMap<String, Vec<(Output, usize)>>,
}

impl Outputs {
    /// An output written by an earlier `<render>` that shares a name with
    /// `o`: (that name, the other output as written, the other `<render>`'s
    /// offset). Otherwise records `o` (its `<render>` at `pos`) and returns
    /// `None`.
    pub fn add(&mut self, o: Output, pos: usize) -> Option<(String, String, usize)> {
        if let Some(hit) = self.meets(&o) {
            return Some(hit);
        }
        if o.run == 0 {
            self.stills.insert(o.prefix, pos);
        } else {
            self.patterns
                .entry(o.prefix.clone())
                .or_default()
                .push((o, pos));
        }
        None
    }

    fn meets(&self, o: &Output) -> Option<(String, String, usize)> {
        let check = |other: &Output, at: usize| {
            first_shared(o, other).map(|(f, _)| (o.name(f), other.pattern(), at))
        };
        if o.run == 0 {
            if let Some(&at) = self.stills.get(&o.prefix) {
                return Some((o.prefix.clone(), o.prefix.clone(), at));
            }
        } else {
            // Stills starting with the prefix.
            for (s, &at) in self.stills.range(o.prefix.clone()..) {
                if !s.starts_with(&o.prefix) {
                    break;
                }
                let still = Output::new(s, None);
                if let Some(hit) = check(&still, at) {
                    return Some(hit);
                }
            }
            // Patterns whose prefix starts with this one's.
            for (p, list) in self.patterns.range(o.prefix.clone()..) {
                if !p.starts_with(&o.prefix) {
                    break;
                }
                for (other, at) in list {
                    if let Some(hit) = check(other, *at) {
                        return Some(hit);
                    }
                }
            }
        }
        // Patterns whose prefix is a (shorter) start of this name.
        let name = &o.prefix;
        for i in (0..name.len()).filter(|&i| name.is_char_boundary(i)) {
            if let Some(list) = self.patterns.get(&name[..i]) {
                for (other, at) in list {
                    if let Some(hit) = check(other, *at) {
                        return Some(hit);
                    }
                }
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn out(p: &str, frames: Option<(u32, u32)>) -> Output {
        Output::new(p, frames.map(|(first, last)| Frames { first, last }))
    }

    /// The slow way: every name of both.
    fn brute(a: &Output, b: &Output) -> bool {
        let names = |o: &Output| -> Vec<String> { (o.first..=o.last).map(|f| o.name(f)).collect() };
        let nb = names(b);
        names(a).iter().any(|n| nb.contains(n))
    }

    #[test]
    fn patterns_and_stills_that_write_one_file_are_found() {
        let seq = |p, a, b| out(p, Some((a, b)));
        let shared = |a: &Output, b: &Output| first_shared(a, b).map(|(f, _)| a.name(f));
        assert_eq!(
            shared(&seq("x.#.png", 0, 20), &seq("x.##.png", 0, 20)),
            Some("x.10.png".into())
        );
        assert_eq!(
            shared(&out("x.10.png", None), &seq("x.#.png", 0, 20)),
            Some("x.10.png".into())
        );
        assert_eq!(shared(&out("x.10.png", None), &seq("x.#.png", 0, 9)), None);
        assert_eq!(shared(&out("x.05.png", None), &seq("x.#.png", 0, 9)), None);
        assert_eq!(
            shared(&out("x.05.png", None), &seq("x.##.png", 0, 9)),
            Some("x.05.png".into())
        );
        // Digits of a prefix meet another's frame number.
        assert_eq!(
            shared(&seq("x1#.png", 0, 99), &seq("x#.png", 100, 200)),
            Some("x110.png".into())
        );
        assert_eq!(
            shared(&seq("a/x.#.png", 0, 99), &seq("b/x.#.png", 0, 99)),
            None
        );
        // Ten million frames each, compared without expanding them.
        assert_eq!(
            shared(
                &seq("s.#######.exr", 0, 9_999_999),
                &seq("s.#.exr", 9_999_999, 9_999_999)
            ),
            Some("s.9999999.exr".into())
        );
        assert_eq!(
            shared(
                &seq("s.#######.exr", 0, 9_999_998),
                &seq("s.#.exr", 9_999_999, 9_999_999)
            ),
            None
        );
    }

    #[test]
    fn the_symbolic_comparison_agrees_with_expanding_every_frame() {
        let pats = [
            "x#.png", "x##.png", "x1#.png", "x#1.png", "x.#.png", "x10#.png", "x#0.png", "x0#.png",
            "x###.png", "x.png", "x1.png", "x10.png", "x012.png", "x#.0.png",
        ];
        let ranges = [(0, 0), (0, 12), (5, 120), (99, 101), (1, 9), (100, 1500)];
        for pa in pats {
            for pb in pats {
                for ra in ranges {
                    for rb in ranges {
                        let a = out(pa, pa.contains('#').then_some(ra));
                        let b = out(pb, pb.contains('#').then_some(rb));
                        let got = first_shared(&a, &b);
                        assert_eq!(got.is_some(), brute(&a, &b), "{a:?} {b:?}");
                        if let Some((fa, fb)) = got {
                            assert_eq!(a.name(fa), b.name(fb));
                            assert!((a.first..=a.last).contains(&fa));
                            assert!((b.first..=b.last).contains(&fb));
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn outputs_are_compared_with_the_candidates_that_could_meet() {
        let mut o = Outputs::default();
        assert_eq!(o.add(out("x.#.png", Some((0, 20))), 1), None);
        assert_eq!(o.add(out("x.png", None), 2), None);
        assert_eq!(o.add(out("y.10.png", None), 3), None);
        let clash = |name: &str, other: &str, at| Some((name.to_string(), other.to_string(), at));
        assert_eq!(
            o.add(out("x.15.png", None), 4),
            clash("x.15.png", "x.#.png", 1)
        );
        assert_eq!(
            o.add(out("y.##.png", Some((0, 99))), 5),
            clash("y.10.png", "y.10.png", 3)
        );
        assert_eq!(o.add(out("x.png", None), 6), clash("x.png", "x.png", 2));
        assert_eq!(
            o.add(out("x.#.png", Some((5, 6))), 8),
            clash("x.5.png", "x.#.png", 1)
        );
        // x.007.png … x.200.png: none of x.0.png … x.20.png.
        assert_eq!(o.add(out("x.###.png", Some((7, 200))), 7), None);
    }
}
