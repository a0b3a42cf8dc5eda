//! The ASCII PLY body: whitespace-separated numbers, read one token at a
//! time; errors point at the offending token (line:column).

use super::body::{Body, Ctx};
use super::header::Scalar;
use crate::error::SceneError;
use crate::mesh::read::{parse_token, show, MeshFile};

pub(super) struct AsciiBody<'a> {
    /// The whole file, so that locations count lines from its start.
    file: MeshFile<'a>,
    pos: usize,
    /// Offset of the token read last.
    last: usize,
}

impl<'a> AsciiBody<'a> {
    /// The body of `file` starting at byte `start`.
    pub(super) fn new(file: MeshFile<'a>, start: usize) -> AsciiBody<'a> {
        AsciiBody {
            file,
            pos: start,
            last: start,
        }
    }

    fn token(&mut self) -> Option<&'a [u8]> {
        let b = self.file.bytes;
        while self.pos < b.len() && b[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        if self.pos == b.len() {
            return None;
        }
        let start = self.pos;
        while self.pos < b.len() && !b[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        self.last = start;
        Some(&b[start..self.pos])
    }
}

impl Body for AsciiBody<'_> {
    fn read(&mut self, ty: Scalar, ctx: &Ctx) -> Result<f64, SceneError> {
        let Some(tok) = self.token() else {
            return Err(self.file.error_at(
                self.file.bytes.len(),
                format!("unexpected end of file: expected {ctx} ({})", ty.name()),
            ));
        };
        let value = match ty {
            Scalar::F32 => parse_token::<f32>(tok).map(f64::from),
            Scalar::F64 => parse_token::<f64>(tok),
            _ => {
                let (lo, hi) = ty.int_range();
                match parse_token::<i64>(tok) {
                    Some(i) if (lo..=hi).contains(&i) => Some(i as f64),
                    Some(i) => {
                        return Err(
                            self.error(format!("{ctx}: {i} is out of range for {}", ty.name()))
                        )
                    }
                    None => None,
                }
            }
        };
        value.ok_or_else(|| {
            self.error(format!(
                "{ctx}: expected {}, found \"{}\"",
                ty.name(),
                show(tok)
            ))
        })
    }

    fn skip(&mut self, n: u64, ty: Scalar, ctx: &Ctx) -> Result<(), SceneError> {
        // Each item is checked; the loop ends at the end of the file at the latest.
        for _ in 0..n {
            self.read(ty, ctx)?;
        }
        Ok(())
    }

    fn error(&self, msg: String) -> SceneError {
        self.file.error_at(self.last, msg)
    }

    fn finish(&self) -> Result<(), SceneError> {
        let mut rest = AsciiBody { ..*self };
        match rest.token() {
            None => Ok(()),
            Some(tok) => Err(rest.error(format!(
                "unexpected data \"{}\" after the last element",
                show(tok)
            ))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_files::*;

    #[test]
    fn ascii_body_errors_are_located() {
        let file = |body: &str| head(&format!("{TRI_HEADER}end_header\n{body}"));
        // The body starts on line 10.
        assert_eq!(
            ok(&file("0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")).triangles,
            vec![[0, 1, 2]]
        );
        assert_eq!(
            ok(&file("0 0 0 1 0 0 0 1 0 3 0 1 2")).triangles,
            vec![[0, 1, 2]]
        );
        fails(
            &file("0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n"),
            13,
            7,
            "vertex index 3 out of range (3 vertices)",
        );
        fails(
            &file("0 0 0\n1 0 0\n0 1 0\n3 0 1 -1\n"),
            13,
            7,
            "vertex index -1 out of range",
        );
        fails(
            &file("0 0 0\n1 0 zz\n0 1 0\n3 0 1 2\n"),
            11,
            5,
            "expected float, found \"zz\"",
        );
        fails(
            &file("0 0 0\n1 0 0\n0 1 0\n3 0 1.0 2\n"),
            13,
            5,
            "expected int, found \"1.0\"",
        );
        fails(
            &file("0 0 0\n1 0 0\n0 1 0\n256 0 1 2\n"),
            13,
            1,
            "256 is out of range for uchar",
        );
        fails(
            &file("0 0 0\n1 0 0\n0 1 0\n2 0 1\n"),
            13,
            1,
            "at least 3 vertices, found 2",
        );
        fails(
            &file("0 0 0\n1 0 0\n0 1 0\n3 0 1\n"),
            14,
            1,
            "unexpected end of file",
        );
        fails(
            &file("0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n  7\n"),
            14,
            3,
            "unexpected data \"7\"",
        );
        fails(
            &file("0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n"),
            11,
            1,
            "not a finite",
        );
        fails(
            &file("0 0 0\n1e39 0 0\n0 1 0\n3 0 1 2\n"),
            11,
            1,
            "not a finite",
        );
    }
}
