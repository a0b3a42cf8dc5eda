//! `<transform>` and its steps `<translate>`, `<rotate>`, `<scale>` and
//! `<matrix>`, composed in document order.

use super::table::{attr, Attribute, REQUIRED};
use super::xml::Elem;
use super::{Resolver, Result};
use glam::{DMat4, DVec3};

/// The attributes of `<translate>`.
pub(super) const TRANSLATE: &[Attribute] =
    &[attr("v", "three reals", REQUIRED, "the offset \"x y z\"")];

/// The attributes of `<rotate>`.
pub(super) const ROTATE: &[Attribute] = &[
    attr(
        "axis",
        "direction",
        REQUIRED,
        "the axis \"x y z\" (non-zero)",
    ),
    attr("angle", "real", REQUIRED, "the angle in degrees"),
];

/// The attributes of `<scale>`.
pub(super) const SCALE: &[Attribute] = &[attr(
    "v",
    "one or three reals",
    REQUIRED,
    "a uniform factor or the factors \"x y z\"",
)];

/// The attributes of `<matrix>`.
pub(super) const MATRIX: &[Attribute] = &[attr(
    "m",
    "16 reals",
    REQUIRED,
    "a 4×4 matrix, row by row, with the last row \"0 0 0 1\"",
)];

impl<'a> Resolver<'a> {
    pub(super) fn transform(&self, e: &'a Elem) -> Result<DMat4> {
        let el = self.el(e);
        el.check_attrs(&[])?;
        let mut m = DMat4::IDENTITY;
        for c in &e.children {
            let cl = self.el(c);
            let step = match c.name.as_str() {
                "translate" => {
                    cl.check_attrs(TRANSLATE)?;
                    let a = cl.req("v")?;
                    let v = cl.reals(a, &[3], "three numbers \"x y z\"")?;
                    DMat4::from_translation(DVec3::new(v[0], v[1], v[2]))
                }
                "rotate" => {
                    cl.check_attrs(ROTATE)?;
                    cl.req("axis")?;
                    let a = cl.req("angle")?;
                    let axis = cl.direction("axis")?.unwrap_or(DVec3::Y);
                    let angle = cl.reals(a, &[1], "an angle in degrees")?[0];
                    DMat4::from_axis_angle(axis, angle.to_radians())
                }
                "scale" => {
                    cl.check_attrs(SCALE)?;
                    let a = cl.req("v")?;
                    let v = cl.reals(a, &[1, 3], "one number or three numbers \"x y z\"")?;
                    match v[..] {
                        [s] => DMat4::from_scale(DVec3::splat(s)),
                        [x, y, z] => DMat4::from_scale(DVec3::new(x, y, z)),
                        _ => DMat4::IDENTITY,
                    }
                }
                _ => {
                    cl.check_attrs(MATRIX)?;
                    let a = cl.req("m")?;
                    let v = cl.reals(a, &[16], "16 numbers (a 4×4 matrix, row by row)")?;
                    if v[12..16] != [0.0, 0.0, 0.0, 1.0] {
                        return Err(cl.attr_err(
                            a,
                            format!(
                                "expected the last row \"0 0 0 1\", found \"{} {} {} {}\"",
                                v[12], v[13], v[14], v[15]
                            ),
                        ));
                    }
                    let mut cols = [0.0; 16];
                    cols.copy_from_slice(&v);
                    DMat4::from_cols_array(&cols).transpose()
                }
            };
            if singular(&step) {
                return Err(cl.err(format!(
                    "singular <{}> (expected an invertible transform)",
                    c.name
                )));
            }
            // Document order: the first child is applied first.
            m = step * m;
        }
        if singular(&m) {
            return Err(el.err(
                "the <transform> is singular or out of range as a whole (expected an invertible transform)",
            ));
        }
        Ok(m)
    }
}

/// Singular, or not representable: determinant zero or not finite, tiny
/// relative to the product of the column lengths, or entries beyond `f32`.
fn singular(m: &DMat4) -> bool {
    let det = m.determinant();
    let scale =
        m.x_axis.truncate().length() * m.y_axis.truncate().length() * m.z_axis.truncate().length();
    let in_range = m
        .to_cols_array()
        .iter()
        .all(|v| v.is_finite() && v.abs() <= f64::from(f32::MAX));
    !in_range || !det.is_finite() || !scale.is_finite() || det == 0.0 || det.abs() <= 1e-12 * scale
}
