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
//! column.

use glam::{Vec2, Vec3};

use super::read::{parse_token, show, MeshFile};
use crate::error::SceneError;

/// One `newmtl`: what it gave (absent values are `None`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Material {
    pub name: String,
    pub kd: Option<Vec3>,
    pub ka: Option<Vec3>,
    pub ks: Option<Vec3>,
    pub ns: Option<f32>,
    /// Opacity, from `d` or `1 − Tr`.
    pub d: Option<f32>,
    pub ni: Option<f32>,
    pub illum: Option<u32>,
    /// nvdiffrec's `bsdf`: its `Ks` is packed PBR parameters, not a colour.
    pub bsdf: bool,
    pub map_kd: Option<MapKd>,
}

/// `map_Kd`: the file (relative to the `.mtl`), where it was named, scale
/// and clamp.
#[derive(Debug, Clone, PartialEq)]
pub struct MapKd {
    pub file: String,
    pub at: usize,
    pub scale: Vec2,
    pub clamp: bool,
}

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
        let toks: Vec<(usize, &[u8])> = tokens(line, line_start).collect();
        line_start = end + 1;
        let Some(&(at, key)) = toks.first() else {
            continue;
        };
        let args = &toks[1..];
        if key == b"newmtl" {
            let Some(&(_, name)) = args.first() else {
                return Err(f.error_at(at, "expected a material name after \"newmtl\""));
            };
            out.push(Material {
                name: String::from_utf8_lossy(name).into_owned(),
                ..Material::default()
            });
            continue;
        }
        let known = matches!(
            key,
            b"Kd" | b"Ka" | b"Ks" | b"Ns" | b"d" | b"Tr" | b"Ni" | b"illum" | b"map_Kd" | b"bsdf"
        );
        if !known {
            continue;
        }
        let Some(m) = out.last_mut() else {
            return Err(f.error_at(at, format!("\"{}\" before any \"newmtl\"", show(key))));
        };
        let number = |&(at, tok): &(usize, &[u8])| -> Result<f32, SceneError> {
            parse_token::<f32>(tok)
                .filter(|x| x.is_finite())
                .ok_or_else(|| f.error_at(at, format!("malformed number \"{}\"", show(tok))))
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
                    [a] => Vec3::splat(number(a)?),
                    [a, b, c] => Vec3::new(number(a)?, number(b)?, number(c)?),
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
                            _ => break,
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
        fails("newmtl a\nd 1e39\n", 2, 3, "malformed number");
    }
}
