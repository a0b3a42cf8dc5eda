//! Render passes (AOVs, "arbitrary output variables"): what a frame writes
//! beside its beauty image when `<render aovs="albedo normal depth">` asks
//! for them (docs/aisxml-extensions.md, "Render passes").
//!
//! Every pass is computed from the same camera samples as the beauty and
//! averaged over them like it (integrator/aov.rs):
//!
//! | pass | channels | value of one camera sample |
//! |---|---|---|
//! | `albedo` | 3 | the diffuse colour (texture included) of the first hit that is not a perfect mirror or clear glass; the background on a miss |
//! | `normal` | 3 | that hit's unit shading normal in world space, on the side the ray came from; 0 on a miss |
//! | `depth` | 1 | the distance from the ray's origin to the first hit (`t·|d|`, `d` unit); +∞ on a miss |
//!
//! A tile's passes travel as one `Vec<f32>`, [`Aovs::channels`] values a
//! pixel, in the order of [`Aov::ALL`] (albedo R G B, normal X Y Z, depth),
//! pixels row by row: [`AovTile`].

use std::fmt;
use std::path::{Path, PathBuf};

/// One render pass.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Aov {
    /// The first non-specular hit's diffuse colour (linear RGB).
    Albedo,
    /// That hit's shading normal in world space (X Y Z).
    Normal,
    /// The camera distance of the first hit.
    Depth,
}

impl Aov {
    /// Every pass, in the order their channels are laid out.
    pub const ALL: [Aov; 3] = [Aov::Albedo, Aov::Normal, Aov::Depth];

    /// The name `aovs=` and `--aovs` take.
    pub fn name(self) -> &'static str {
        match self {
            Aov::Albedo => "albedo",
            Aov::Normal => "normal",
            Aov::Depth => "depth",
        }
    }

    /// The pass named `name`, if any (exact, lower case).
    pub fn from_name(name: &str) -> Option<Aov> {
        Aov::ALL.into_iter().find(|a| a.name() == name)
    }

    /// How many values a pixel of this pass has.
    pub fn channels(self) -> usize {
        match self {
            Aov::Albedo | Aov::Normal => 3,
            Aov::Depth => 1,
        }
    }

    /// The OpenEXR channel names of this pass in a multi-layer file, in the
    /// order of its values: the names compositing tools and denoisers read.
    pub fn exr_channels(self) -> &'static [&'static str] {
        match self {
            Aov::Albedo => &["albedo.R", "albedo.G", "albedo.B"],
            Aov::Normal => &["N.X", "N.Y", "N.Z"],
            Aov::Depth => &["Z"],
        }
    }

    fn bit(self) -> u8 {
        1 << self as u8
    }
}

/// A set of render passes; the default is none (a plain render).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Aovs(u8);

/// A name that is not a render pass (the caller says where it was).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown render pass \"{name}\" (expected albedo, normal or depth)")]
pub struct UnknownAov {
    /// The name given (cut to 64 bytes).
    pub name: String,
}

impl Aovs {
    /// No passes.
    pub const NONE: Aovs = Aovs(0);

    /// Every pass.
    pub const ALL: Aovs = Aovs(0b111);

    /// Whether the set holds no pass.
    pub fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// Whether the set holds `aov`.
    pub fn contains(self, aov: Aov) -> bool {
        self.0 & aov.bit() != 0
    }

    /// The set with `aov` added.
    #[must_use]
    pub fn with(self, aov: Aov) -> Aovs {
        Aovs(self.0 | aov.bit())
    }

    /// The passes of the set, in layout order.
    pub fn iter(self) -> impl Iterator<Item = Aov> {
        Aov::ALL.into_iter().filter(move |a| self.contains(*a))
    }

    /// Values a pixel of the set's passes has (0 to 7).
    pub fn channels(self) -> usize {
        self.iter().map(Aov::channels).sum()
    }

    /// Where `aov`'s first value sits among a pixel's values, if in the set.
    pub fn offset(self, aov: Aov) -> Option<usize> {
        self.contains(aov).then(|| {
            self.iter()
                .take_while(|a| *a != aov)
                .map(Aov::channels)
                .sum()
        })
    }

    /// The set of the names in `names`, split at whitespace and commas, in
    /// any order, repeats allowed; the empty string is no passes. The first
    /// unknown name is the error.
    pub fn parse(names: &str) -> Result<Aovs, UnknownAov> {
        let mut set = Aovs::NONE;
        for name in names
            .split(|c: char| c == ',' || c.is_ascii_whitespace())
            .filter(|n| !n.is_empty())
        {
            match Aov::from_name(name) {
                Some(a) => set = set.with(a),
                None => {
                    let mut end = name.len().min(64);
                    while !name.is_char_boundary(end) {
                        end -= 1;
                    }
                    return Err(UnknownAov {
                        name: name[..end].to_string(),
                    });
                }
            }
        }
        Ok(set)
    }

    /// The set as a byte (bit i: pass i of [`Aov::ALL`]), for the wire.
    pub fn bits(self) -> u8 {
        self.0
    }

    /// The set of a byte from [`Aovs::bits`]; `None` with an unknown bit.
    pub fn from_bits(bits: u8) -> Option<Aovs> {
        (bits & !Aovs::ALL.0 == 0).then_some(Aovs(bits))
    }
}

impl fmt::Display for Aovs {
    /// The names, space-separated, in layout order (`aovs=` syntax).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let names: Vec<&str> = self.iter().map(Aov::name).collect();
        f.write_str(&names.join(" "))
    }
}

/// The render passes of a tile: [`Aovs::channels`] values a pixel, in
/// layout order, pixels row by row (see the module documentation).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct AovTile {
    /// The passes held.
    pub aovs: Aovs,
    /// The values.
    pub values: Vec<f32>,
}

impl AovTile {
    /// The values of pixel `i` (row by row in the tile).
    pub fn pixel(&self, i: usize) -> &[f32] {
        let n = self.aovs.channels();
        &self.values[i * n..(i + 1) * n]
    }

    /// The values of pass `aov` at pixel `i`; empty if it is not held.
    pub fn get(&self, i: usize, aov: Aov) -> &[f32] {
        match self.aovs.offset(aov) {
            Some(o) => &self.pixel(i)[o..o + aov.channels()],
            None => &[],
        }
    }
}

/// Where pass `aov` of a frame written to `output` goes when it is not in
/// the same file: beside a PNG, `NAME.albedo.png` (sRGB, like the beauty),
/// `NAME.normal.png` ((n+1)/2 per component, linear) and `NAME.depth.exr`
/// (one float channel `Z`: depth in a PNG would lose all but 8 bits);
/// `None` for an EXR output, which holds its passes as channels.
pub fn aov_path(output: &Path, aov: Aov) -> Option<PathBuf> {
    // The PNG test of `output::Format::from_path`, by extension in any case;
    // written here so the scene's checks need nothing of the writers.
    let png = output
        .extension()
        .is_some_and(|e| e.to_string_lossy().eq_ignore_ascii_case("png"));
    if !png {
        return None;
    }
    let stem = output.file_stem()?.to_string_lossy();
    let name = match aov {
        Aov::Albedo => format!("{stem}.albedo.png"),
        Aov::Normal => format!("{stem}.normal.png"),
        Aov::Depth => format!("{stem}.depth.exr"),
    };
    Some(output.with_file_name(name))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_in_any_order_and_unknown_ones_are_refused() {
        let all = Aovs::parse("depth, normal albedo").unwrap();
        assert_eq!(all, Aovs::ALL);
        assert_eq!(all.channels(), 7);
        assert_eq!(all.to_string(), "albedo normal depth");
        let d = Aovs::parse(" depth depth ").unwrap();
        assert_eq!((d.channels(), d.offset(Aov::Depth)), (1, Some(0)));
        assert_eq!(d.offset(Aov::Albedo), None);
        assert_eq!(Aovs::parse("").unwrap(), Aovs::NONE);
        let nd = Aovs::parse("normal,depth").unwrap();
        assert_eq!(nd.offset(Aov::Depth), Some(3));
        assert_eq!(
            Aovs::parse("albedo Albedo").unwrap_err().name,
            "Albedo".to_string()
        );
        assert!(Aovs::parse("albedo,z").is_err());
        for bits in 0..=255u8 {
            match Aovs::from_bits(bits) {
                Some(s) => assert_eq!(s.bits(), bits),
                None => assert!(bits > 7),
            }
        }
    }
}
