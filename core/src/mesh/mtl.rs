//! Wavefront MTL material libraries, as far as Trevi's surface can show
//! them.
//!
//! Read, per `newmtl NAME`: `Kd`, `Ka`, `Ks` (three numbers; one means
//! grey), `Ns`, `d` (opacity) or `Tr` (1 − opacity), `Ni`, `illum` and
//! `map_Kd [options] FILE` (of the options `-s u [v [w]]` and `-clamp on|off`
//! are used, the others skipped with their arguments). Every other statement
//! (`map_Ks`, `bump`, `Ke`, `Tf`, PBR extensions, nvdiffrec's `bsdf`, …) is
//! skipped. Comments run from `#` to the end of the line. A malformed number
//! or a statement before the first `newmtl` is an error at its line and
//! column, and so is a colour component below 0, a number that is not
//! finite in 32 bits, and a `map_Kd -s` whose scale is.
//!
//! Cost: one pass over the bytes. A statement Trevi reads may have at most
//! [`MAX_MTL_ARGS`] arguments (a skipped one any number, never collected),
//! and a file at most [`MAX_MTL_MATERIALS`] materials, so what the parse
//! holds is linear in the file and small beside it; past either bound the
//! error is at the token that passes it.

use glam::{Vec2, Vec3};

use super::read::{parse_token, show, MeshFile};
use crate::error::SceneError;

/// One `newmtl`: what it gave (absent values are `None`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Material {
    /// The name after `newmtl` (what `usemtl` names), lossily UTF-8.
    pub name: String,
    /// `Kd`: the diffuse colour, each component ≥ 0.
    pub kd: Option<Vec3>,
    /// `Ka`: the ambient colour, each component ≥ 0.
    pub ka: Option<Vec3>,
    /// `Ks`: the specular colour, each component ≥ 0.
    pub ks: Option<Vec3>,
    /// `Ns`: the specular exponent (finite, unchecked otherwise).
    pub ns: Option<f32>,
    /// Opacity, from `d` or `1 − Tr`.
    pub d: Option<f32>,
    /// `Ni`: the index of refraction (finite, unchecked otherwise).
    pub ni: Option<f32>,
    /// `illum`: the MTL illumination model number.
    pub illum: Option<u32>,
    /// nvdiffrec's `bsdf`: its `Ks` is packed PBR parameters, not a colour.
    pub bsdf: bool,
    /// `map_Kd`: the diffuse colour's texture.
    pub map_kd: Option<MapKd>,
}

/// `map_Kd`: the file (relative to the `.mtl`), where it was named, scale
/// and clamp.
#[derive(Debug, Clone, PartialEq)]
pub struct MapKd {
    /// The image file as written, relative to the `.mtl`'s folder (not yet
    /// resolved or checked).
    pub file: String,
    /// The byte offset of the file name in the `.mtl`, for errors about it.
    pub at: usize,
    /// `-s u v`: texture coordinates are multiplied by it (1 1 without
    /// `-s`; `-s u` is `u u`, a third value is ignored).
    pub scale: Vec2,
    /// `-clamp on`: coordinates clamp to the image's edge instead of
    /// repeating.
    pub clamp: bool,
}

/// The most materials (`newmtl`) one `.mtl` file may define: what one
/// mesh can use (its triangles name their surface in 16 bits), with room.
pub const MAX_MTL_MATERIALS: usize = 65_536;

/// The most arguments a statement Trevi reads may have (`map_Kd` with
/// every option of the format has about 20).
pub const MAX_MTL_ARGS: usize = 64;

/// Arguments each skipped `map_` option takes (at most; numbers stop early).
fn option_args(opt: &[u8]) -> usize {
    match opt {
        b"-o" | b"-t" => 3,
        b"-mm" => 2,
        _ => 1,
    }
}

/// Parses an MTL file's bytes; `file` is its bundle-relative name for errors.
pub fn parse(file: &str, bytes: &[u8]) -> Result<Vec<Material>, SceneError> {
    let f = MeshFile { name: file, bytes };
    let mut out: Vec<Material> = Vec::new();
    let mut line_start = 0;
    while line_start < bytes.len() {
        let end = bytes[line_start..]
            .iter()
            .position(|&c| c == b'\n')
            .map_or(bytes.len(), |i| line_start + i);
        let line = &bytes[line_start..end];
        let line = &line[..line.iter().position(|&c| c == b'#').unwrap_or(line.len())];
        let mut toks = tokens(line, line_start);
        line_start = end + 1;
        let Some((at, key)) = toks.next() else {
            continue;
        };
        let known = matches!(
            key,
            b"newmtl"
                | b"Kd"
                | b"Ka"
                | b"Ks"
                | b"Ns"
                | b"d"
                | b"Tr"
                | b"Ni"
                | b"illum"
                | b"map_Kd"
                | b"bsdf"
        );
        if !known {
            continue;
        }
        let args: Vec<(usize, &[u8])> = toks.by_ref().take(MAX_MTL_ARGS).collect();
        if let Some((extra, _)) = toks.next() {
            return Err(f.error_at(
                extra,
                format!("more than {MAX_MTL_ARGS} arguments after \"{}\"", show(key)),
            ));
        }
        let args = &args[..];
        if key == b"newmtl" {
            let Some(&(_, name)) = args.first() else {
                return Err(f.error_at(at, "expected a material name after \"newmtl\""));
            };
            if out.len() == MAX_MTL_MATERIALS {
                return Err(f.error_at(
                    at,
                    format!("more than {MAX_MTL_MATERIALS} materials in one file"),
                ));
            }
            out.push(Material {
                name: String::from_utf8_lossy(name).into_owned(),
                ..Material::default()
            });
            continue;
        }
        let Some(m) = out.last_mut() else {
            return Err(f.error_at(at, format!("\"{}\" before any \"newmtl\"", show(key))));
        };
        let number = |&(at, tok): &(usize, &[u8])| -> Result<f32, SceneError> {
            let x = parse_token::<f32>(tok)
                .ok_or_else(|| f.error_at(at, format!("malformed number \"{}\"", show(tok))))?;
            if !x.is_finite() {
                return Err(f.error_at(
                    at,
                    format!(
                        "number \"{}\" is not finite in 32 bits (out of range, or nan/inf)",
                        show(tok)
                    ),
                ));
            }
            Ok(x)
        };
        // A colour component: finite and ≥ 0 (a negative one would make
        // negative light).
        let component = |a: &(usize, &[u8])| -> Result<f32, SceneError> {
            let x = number(a)?;
            if x < 0.0 {
                return Err(f.error_at(
                    a.0,
                    format!(
                        "colour component {} of \"{}\" is negative (expected a number ≥ 0)",
                        show(a.1),
                        show(key)
                    ),
                ));
            }
            Ok(x)
        };
        let one = |what: &str| -> Result<f32, SceneError> {
            match args {
                [a] => number(a),
                _ => Err(f.error_at(at, format!("expected one number after \"{what}\""))),
            }
        };
        match key {
            b"Kd" | b"Ka" | b"Ks" => {
                let c = match args {
                    [a] => Vec3::splat(component(a)?),
                    [a, b, c] => Vec3::new(component(a)?, component(b)?, component(c)?),
                    _ => {
                        return Err(
                            f.error_at(at, format!("expected r g b after \"{}\"", show(key)))
                        )
                    }
                };
                match key {
                    b"Kd" => m.kd = Some(c),
                    b"Ka" => m.ka = Some(c),
                    _ => m.ks = Some(c),
                }
            }
            b"Ns" => m.ns = Some(one("Ns")?),
            b"d" => m.d = Some(one("d")?),
            b"Tr" => m.d = Some(1.0 - one("Tr")?),
            b"Ni" => m.ni = Some(one("Ni")?),
            b"illum" => {
                let [(a, tok)] = args else {
                    return Err(f.error_at(at, "expected one integer after \"illum\""));
                };
                m.illum = Some(parse_token::<u32>(tok).ok_or_else(|| {
                    f.error_at(
                        *a,
                        format!("malformed illumination model \"{}\"", show(tok)),
                    )
                })?);
            }
            b"bsdf" => m.bsdf = true,
            _ => {
                // map_Kd [options] file
                let mut map = MapKd {
                    file: String::new(),
                    at,
                    scale: Vec2::ONE,
                    clamp: false,
                };
                let mut i = 0;
                while i + 1 < args.len() && args[i].1.starts_with(b"-") {
                    let opt = args[i].1;
                    i += 1;
                    let mut nums = Vec::new();
                    let max = if opt == b"-s" { 3 } else { option_args(opt) };
                    while nums.len() < max && i + 1 < args.len() {
                        if opt == b"-clamp" {
                            map.clamp = args[i].1 == b"on";
                            i += 1;
                            break;
                        }
                        match parse_token::<f32>(args[i].1) {
                            Some(x) if x.is_finite() => {
                                nums.push(x);
                                i += 1;
                            }
                            // A number, but not one of 32 bits: say so
                            // (not "expected u [v [w]]").
                            Some(_) => return Err(f.error_at(
                                args[i].0,
                                format!(
                                    "\"{}\" value \"{}\" is not finite in 32 bits (out of range, or nan/inf)",
                                    show(opt),
                                    show(args[i].1)
                                ),
                            )),
                            None => break,
                        }
                    }
                    if opt == b"-s" {
                        match nums[..] {
                            [u] => map.scale = Vec2::splat(u),
                            [u, v, ..] => map.scale = Vec2::new(u, v),
                            [] => {
                                return Err(
                                    f.error_at(args[i - 1].0, "expected u [v [w]] after \"-s\"")
                                )
                            }
                        }
                    }
                }
                let Some(&(file_at, name)) = args.get(i) else {
                    return Err(f.error_at(at, "expected a file name after \"map_Kd\""));
                };
                if i + 1 != args.len() {
                    return Err(f.error_at(
                        args[i + 1].0,
                        "expected one file name after \"map_Kd\" (names with blanks are not supported)",
                    ));
                }
                map.file = String::from_utf8_lossy(name).into_owned();
                map.at = file_at;
                m.map_kd = Some(map);
            }
        }
    }
    Ok(out)
}

/// The blank-separated tokens of `line` (which starts at byte `base` of the
/// file) with their offsets.
fn tokens(line: &[u8], base: usize) -> impl Iterator<Item = (usize, &[u8])> {
    let blank = |c: u8| matches!(c, b' ' | b'\t' | b'\r' | 0x0b | 0x0c);
    let mut i = 0;
    std::iter::from_fn(move || {
        while i < line.len() && blank(line[i]) {
            i += 1;
        }
        if i >= line.len() {
            return None;
        }
        let start = i;
        while i < line.len() && !blank(line[i]) {
            i += 1;
        }
        Some((base + start, &line[start..i]))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::assert_error_at;

    #[test]
    fn materials_with_colours_maps_and_skipped_statements() {
        let src = "# exported\nnewmtl red\nKd 0.8 0.1 0.1\r\nKa 0.2\nKs 0.5 0.5 0.5\nNs 20\nTr 0.25\n\
                   Ni 1.33\nillum 4\nmap_Ks spec.png\nbump b.png\n\
                   newmtl tex\nbsdf pbr\nKs 0 0.25 0\nmap_Kd -s 2 3 1 -o 0.1 0.2 -clamp on -bm 1 t.png\n\
                   newmtl plain\n";
        let m = parse("m.mtl", src.as_bytes()).unwrap();
        assert_eq!(m.len(), 3);
        assert_eq!(m[0].name, "red");
        assert_eq!(m[0].kd, Some(Vec3::new(0.8, 0.1, 0.1)));
        assert_eq!(m[0].ka, Some(Vec3::splat(0.2)));
        assert_eq!(m[0].ks, Some(Vec3::splat(0.5)));
        assert_eq!(
            (m[0].ns, m[0].d, m[0].ni, m[0].illum),
            (Some(20.0), Some(0.75), Some(1.33), Some(4))
        );
        assert!(m[0].map_kd.is_none() && !m[0].bsdf);
        assert!(m[1].bsdf);
        let map = m[1].map_kd.as_ref().unwrap();
        assert_eq!(
            (map.file.as_str(), map.scale, map.clamp),
            ("t.png", Vec2::new(2.0, 3.0), true)
        );
        assert_eq!(
            m[2],
            Material {
                name: "plain".into(),
                ..Material::default()
            }
        );
    }

    #[test]
    fn errors_are_located() {
        let fails = |src: &str, line, col, msg: &str| {
            assert_error_at(parse("m.mtl", src.as_bytes()), "m.mtl", line, col, msg)
        };
        fails("Kd 1 1 1\n", 1, 1, "before any \"newmtl\"");
        fails("newmtl a\nKd 1 x 1\n", 2, 6, "malformed number \"x\"");
        fails("newmtl a\nKd 1 1\n", 2, 1, "expected r g b");
        fails("newmtl a\n  Ns\n", 2, 3, "expected one number after \"Ns\"");
        fails(
            "newmtl a\nillum 2.5\n",
            2,
            7,
            "malformed illumination model",
        );
        fails("newmtl a\nmap_Kd\n", 2, 1, "expected a file name");
        fails("newmtl a\nmap_Kd my file.png\n", 2, 11, "names with blanks");
        fails("newmtl\n", 1, 1, "expected a material name");
        fails("newmtl a\nd 1e39\n", 2, 3, "not finite in 32 bits");
    }

    /// Regression: a negative or non-finite colour was accepted (Whitted
    /// then failed a job with an unlocated "pixel is negative"; path
    /// tracing rendered black), and `-s 1e39` said "expected u [v [w]]".
    #[test]
    fn colours_must_be_finite_and_not_negative_and_scales_finite() {
        let fails = |src: &str, line, col, msg: &str| {
            assert_error_at(parse("m.mtl", src.as_bytes()), "m.mtl", line, col, msg)
        };
        fails("newmtl a\nKd 0.5 -0.1 0\n", 2, 8, "is negative");
        fails(
            "newmtl a\nKa -1\n",
            2,
            4,
            "colour component -1 of \"Ka\" is negative",
        );
        fails("newmtl a\nKs 1 1 -0.5\n", 2, 8, "is negative");
        fails("newmtl a\nKd nan 0 0\n", 2, 4, "not finite");
        fails("newmtl a\nKd 1 inf 0\n", 2, 6, "not finite");
        fails("newmtl a\nKd 1 1 1e39\n", 2, 8, "not finite");
        fails(
            "newmtl a\nmap_Kd -s 1e39 t.png\n",
            2,
            11,
            "\"-s\" value \"1e39\" is not finite in 32 bits",
        );
        fails("newmtl a\nmap_Kd -s 1 nan t.png\n", 2, 13, "not finite");
        // Zero is a colour (black); -0 too.
        let m = parse("m.mtl", b"newmtl a\nKd 0 -0 0\n").unwrap();
        assert_eq!(m[0].kd, Some(Vec3::ZERO));
    }

    /// Regression: what a parse holds is bounded by the file, statement by
    /// statement (no token list of a whole line of a skipped statement),
    /// and the materials by a count.
    #[test]
    fn arguments_and_materials_are_bounded() {
        let many = format!("newmtl a\nKd{}\n", " 1".repeat(MAX_MTL_ARGS + 1));
        assert_error_at(
            parse("m.mtl", many.as_bytes()),
            "m.mtl",
            2,
            3 + 2 * MAX_MTL_ARGS as u32 + 1,
            "more than 64 arguments after \"Kd\"",
        );
        // A skipped statement may have any number.
        let skipped = format!("newmtl a\nmap_Ks{}\n", " x".repeat(10_000));
        assert_eq!(parse("m.mtl", skipped.as_bytes()).unwrap().len(), 1);
        let mut src = String::new();
        for k in 0..=MAX_MTL_MATERIALS {
            src.push_str(&format!("newmtl m{k}\n"));
        }
        assert_error_at(
            parse("m.mtl", src.as_bytes()),
            "m.mtl",
            MAX_MTL_MATERIALS as u32 + 1,
            1,
            "more than 65536 materials in one file",
        );
        src.truncate(src.len() - format!("newmtl m{MAX_MTL_MATERIALS}\n").len());
        assert_eq!(
            parse("m.mtl", src.as_bytes()).unwrap().len(),
            MAX_MTL_MATERIALS
        );
    }
}
