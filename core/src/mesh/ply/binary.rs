//! The binary PLY body, little- or big-endian: values of the header's
//! types back to back. Errors point at the line after the header, column
//! 1 + the byte offset into the body, and the message says "byte N".

use super::body::{Body, Ctx};
use super::header::Scalar;
use crate::error::SceneError;
use crate::mesh::read::MeshFile;

pub(super) struct BinaryBody<'a> {
    file: MeshFile<'a>,
    body: &'a [u8],
    pos: usize,
    /// Offset of the value read last.
    last: usize,
    big_endian: bool,
    /// Line number of the body's first byte.
    line: u32,
}

impl<'a> BinaryBody<'a> {
    /// The body of `file` from byte `start`, which is on line `line`.
    pub(super) fn new(file: MeshFile<'a>, start: usize, line: u32, big_endian: bool) -> Self {
        BinaryBody {
            file,
            body: &file.bytes[start..],
            pos: 0,
            last: 0,
            big_endian,
            line,
        }
    }

    fn at(&self, pos: usize, msg: String) -> SceneError {
        let column = u32::try_from(pos).unwrap_or(u32::MAX - 1) + 1;
        self.file.error_at_line(
            self.line,
            column,
            format!("byte {pos} of the binary body: {msg}"),
        )
    }

    fn bytes<const N: usize>(&self) -> [u8; N] {
        let mut a = [0u8; N];
        a.copy_from_slice(&self.body[self.pos..self.pos + N]);
        if self.big_endian {
            a.reverse();
        }
        a
    }
}

impl Body for BinaryBody<'_> {
    fn read(&mut self, ty: Scalar, ctx: &Ctx) -> Result<f64, SceneError> {
        let size = ty.size();
        if self.body.len() - self.pos < size {
            return Err(self.at(
                self.pos,
                format!("unexpected end of file: expected {ctx} ({})", ty.name()),
            ));
        }
        let v = match ty {
            Scalar::I8 => f64::from(i8::from_le_bytes(self.bytes())),
            Scalar::U8 => f64::from(self.body[self.pos]),
            Scalar::I16 => f64::from(i16::from_le_bytes(self.bytes())),
            Scalar::U16 => f64::from(u16::from_le_bytes(self.bytes())),
            Scalar::I32 => f64::from(i32::from_le_bytes(self.bytes())),
            Scalar::U32 => f64::from(u32::from_le_bytes(self.bytes())),
            Scalar::F32 => f64::from(f32::from_le_bytes(self.bytes())),
            Scalar::F64 => f64::from_le_bytes(self.bytes()),
        };
        self.last = self.pos;
        self.pos += size;
        Ok(v)
    }

    fn skip(&mut self, n: u64, ty: Scalar, ctx: &Ctx) -> Result<(), SceneError> {
        let len = n.checked_mul(ty.size() as u64);
        match len {
            Some(len) if len <= (self.body.len() - self.pos) as u64 => {
                self.pos += len as usize;
                Ok(())
            }
            // Reported at the list's count, the value that is wrong.
            _ => Err(self.at(
                self.last,
                format!(
                    "unexpected end of file: {ctx} claims {n} {} items but only {} bytes remain",
                    ty.name(),
                    self.body.len() - self.pos
                ),
            )),
        }
    }

    fn error(&self, msg: String) -> SceneError {
        self.at(self.last, msg)
    }

    fn finish(&self) -> Result<(), SceneError> {
        let rest = &self.body[self.pos..];
        if rest.iter().all(|c| c.is_ascii_whitespace()) {
            Ok(())
        } else {
            Err(self.at(
                self.pos,
                format!(
                    "{} bytes of unexpected data after the last element",
                    rest.len()
                ),
            ))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_files::*;

    #[test]
    fn binary_body_errors_name_the_byte() {
        for format in ["binary_little_endian", "binary_big_endian"] {
            let rows = |last: i32| {
                vec![
                    vec![V::F32(0.0), V::F32(0.0), V::F32(0.0)],
                    vec![V::F32(1.0), V::F32(f32::NAN), V::F32(0.0)],
                    vec![V::F32(0.0), V::F32(1.0), V::F32(0.0)],
                    vec![V::U8(3), V::I32(0), V::I32(1), V::I32(last)],
                ]
            };
            let mut good = rows(2);
            good[1][1] = V::F32(0.0);
            let bytes = ply(format, TRI_HEADER, &good);
            assert_eq!(ok(&bytes).triangles, vec![[0, 1, 2]]);
            // The header has 9 lines; vertices take bytes 0..36, the face 36..49.
            let mut bad = rows(3);
            bad[1][1] = V::F32(0.0);
            fails(&ply(format, TRI_HEADER, &bad), 10, 46, "byte 45 of the binary body: property \"vertex_indices\" of face 0: vertex index 3 out of range");
            fails(
                &ply(format, TRI_HEADER, &rows(2)),
                10,
                17,
                "byte 16 of the binary body: property \"y\" of vertex 1",
            );
            fails(
                &bytes[..bytes.len() - 2],
                10,
                46,
                "byte 45 of the binary body: unexpected end of file",
            );
            let mut trailing = bytes.clone();
            trailing.extend_from_slice(b"\r\n");
            assert_eq!(ok(&trailing).triangles, vec![[0, 1, 2]]);
            trailing.extend_from_slice(b"xyz");
            fails(
                &trailing,
                10,
                50,
                "byte 49 of the binary body: 5 bytes of unexpected data",
            );
            // A skipped list claiming four billion items ends in an error, quickly.
            let header = format!("{TRI_HEADER}element junk 1\nproperty list uint uchar stuff\n");
            let mut junk = good.clone();
            junk.push(vec![V::U32(4_000_000_000), V::U8(1)]);
            fails(&ply(format, &header, &junk), 12, 50, "byte 49 of the binary body: unexpected end of file: property \"stuff\" of junk 0 claims 4000000000 uchar items but only 1 bytes remain");
        }
    }
}
