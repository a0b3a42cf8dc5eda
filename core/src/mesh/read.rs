//! What the OBJ and PLY readers share: the file being read (for errors that
//! point at a byte of it), tokens shown in messages, numbers read from
//! tokens, and file normals made unit length.

use glam::Vec3;

use crate::error::{Location, SceneError};

/// A mesh file being read: its bundle-relative name and its bytes, so that
/// an error can say where in it it was found.
#[derive(Clone, Copy)]
pub(super) struct MeshFile<'a> {
    pub name: &'a str,
    pub bytes: &'a [u8],
}

impl MeshFile<'_> {
    /// An error at byte offset `at` (reported as line:column).
    pub fn error_at(&self, at: usize, msg: impl Into<String>) -> SceneError {
        SceneError::new(Location::at_offset(self.name, self.bytes, at), msg)
    }

    /// An error at an explicit line and column, for text that has no lines
    /// of its own (a binary body).
    pub fn error_at_line(&self, line: u32, column: u32, msg: impl Into<String>) -> SceneError {
        SceneError::new(Location::new(self.name, line, column), msg)
    }
}

/// A token for an error message: lossy, and cut short if it is very long.
pub(super) fn show(tok: &[u8]) -> String {
    const MAX: usize = 40;
    if tok.len() > MAX {
        format!("{}…", String::from_utf8_lossy(&tok[..MAX]))
    } else {
        String::from_utf8_lossy(tok).into_owned()
    }
}

/// `tok` parsed as a `T` (a number), or `None` if it is not UTF-8 or not
/// in `T`'s syntax.
pub(super) fn parse_token<T: std::str::FromStr>(tok: &[u8]) -> Option<T> {
    std::str::from_utf8(tok).ok()?.parse().ok()
}

/// `n` normalised, or `None` if it has no direction. `-0.0` becomes `0.0`
/// so that equal normals compare equal bit for bit.
pub(super) fn unit_normal(n: Vec3) -> Option<Vec3> {
    let d = n.as_dvec3();
    let len = d.length();
    if len > 0.0 && len.is_finite() {
        Some((d / len).as_vec3() + Vec3::ZERO)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_are_shown_cut_short_and_parsed_strictly() {
        assert_eq!(show(b"abc"), "abc");
        assert_eq!(show(&[b'x'; 50]), format!("{}…", "x".repeat(40)));
        assert_eq!(show(b"\xffa"), "\u{fffd}a");
        assert_eq!(parse_token::<f32>(b"1.5"), Some(1.5));
        assert_eq!(parse_token::<i64>(b"1.5"), None);
        assert_eq!(parse_token::<i64>(b"\xff1"), None);
        assert_eq!(parse_token::<u64>(b"-1"), None);
    }

    #[test]
    fn unit_normals_have_no_negative_zero_and_zero_has_none() {
        let n = unit_normal(Vec3::new(-0.0, 0.0, -3.0)).unwrap();
        assert_eq!(n.to_array().map(f32::to_bits), [0, 0, (-1.0f32).to_bits()]);
        assert_eq!(unit_normal(Vec3::ZERO), None);
        assert_eq!(unit_normal(Vec3::new(f32::INFINITY, 0.0, 0.0)), None);
        assert_eq!(unit_normal(Vec3::new(f32::NAN, 0.0, 0.0)), None);
        // Large enough that squaring overflows f32: still a direction.
        assert_eq!(unit_normal(Vec3::new(0.0, 1e30, 0.0)), Some(Vec3::Y));
    }

    #[test]
    fn errors_point_at_a_byte_or_a_line() {
        let f = MeshFile {
            name: "m.obj",
            bytes: b"v 0\nv 1 x\n",
        };
        assert_eq!(f.error_at(8, "bad").to_string(), "m.obj:2:5: bad");
        assert_eq!(f.error_at_line(7, 3, "bad").to_string(), "m.obj:7:3: bad");
    }
}
