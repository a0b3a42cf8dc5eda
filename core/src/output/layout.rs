//! How a frame's files are laid out: which values each file's samples
//! hold ([`Layout`]); where a PNG frame's render passes go is
//! [`crate::aov::aov_path`].

use super::Format;
use crate::aov::Aovs;

/// The channels of a denoised EXR frame's beauty before denoising (its
/// layer `noisy`), in R G B order.
pub const NOISY_CHANNELS: [&str; 3] = ["noisy.R", "noisy.G", "noisy.B"];

/// What a file's samples are made of. A tile's values are numbered: 0, 1, 2
/// its R, G, B; 3 onwards its render passes' values in layout order (see
/// [`crate::aov`]).
pub(super) enum Layout {
    /// PNG: values 0..3, through the sRGB curve or, `signed`, mapped from
    /// [-1, 1] linearly.
    Png { signed: bool },
    /// EXR: the named channels (sorted by name, as EXR requires), each
    /// with the value it stores.
    Exr(Vec<(&'static str, usize)>),
}

impl Layout {
    /// The layout of a frame in `format` with passes `aovs`: the beauty
    /// alone in a PNG (the passes go to files beside it), every pass as
    /// channels of the same file in an EXR; with `noisy` (a denoised
    /// frame), an EXR also holds the beauty before denoising as
    /// [`NOISY_CHANNELS`], the values after the passes'.
    pub(super) fn of(format: Format, aovs: Aovs, noisy: bool) -> Layout {
        match format {
            Format::Png => Layout::Png { signed: false },
            Format::Exr => {
                let mut channels = vec![("R", 0), ("G", 1), ("B", 2)];
                for aov in aovs.iter() {
                    let at = 3 + aovs.offset(aov).unwrap_or(0);
                    channels.extend((at..).zip(aov.exr_channels()).map(|(i, n)| (*n, i)));
                }
                if noisy {
                    let at = 3 + aovs.channels();
                    channels.extend((at..).zip(NOISY_CHANNELS).map(|(i, n)| (n, i)));
                }
                channels.sort_by(|a, b| a.0.as_bytes().cmp(b.0.as_bytes()));
                Layout::Exr(channels)
            }
        }
    }
}

/// A signed unit value (a normal's component) as an 8-bit sample:
/// round(255·(v+1)/2), clamped; NaN is 128 (the value of 0).
pub(super) fn signed_unit8(v: f32) -> u8 {
    let v = if v.is_nan() { 0.0 } else { v.clamp(-1.0, 1.0) };
    ((v + 1.0) * 0.5 * 255.0 + 0.5) as u8
}
