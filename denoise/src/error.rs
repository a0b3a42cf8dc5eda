//! Typed errors of denoising.

/// Why a frame was not denoised.
#[derive(Debug, thiserror::Error)]
pub enum DenoiseError {
    /// This build has no denoiser (the `denoise` feature is off) or the
    /// library did not load; the message says how to get one.
    #[error("denoising is not available: {0}")]
    Unavailable(String),
    /// Open Image Denoise refused or failed the filter.
    #[error("Open Image Denoise failed: {0}")]
    Oidn(String),
    /// The caller's bands do not fit the frame (a programming error of the
    /// caller, reported rather than panicking).
    #[error("band rows {start}..{end} of a frame {width}x{height}: {what}")]
    Band {
        /// First row of the band.
        start: u32,
        /// One past its last row.
        end: u32,
        /// Frame width in pixels.
        width: u32,
        /// Frame height in pixels.
        height: u32,
        /// What is wrong with it.
        what: &'static str,
    },
    /// Reading the noisy frame failed.
    #[error("{0}")]
    Io(String),
    /// Writing the denoised frame failed.
    #[error(transparent)]
    Output(#[from] trevi_core::OutputError),
}
