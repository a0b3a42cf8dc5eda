//! Open Image Denoise's ray-tracing filter on one band of rows: the only
//! code that calls the library (behind the `oidn` feature).

use crate::{DenoiseError, Inputs};

/// How to get a denoiser, for the error of a build or machine without one.
pub const HOW_TO_GET: &str =
    "build with the `denoise` cargo feature and OIDN_DIR naming a directory \
whose lib/ holds Intel Open Image Denoise 2.x (`pip install pyoidn` ships it under \
pyoidn/oidn/lib; see docs/denoise.md)";

/// Whether this build can denoise at all (the `oidn` feature).
pub const BUILT_IN: bool = cfg!(feature = "oidn");

/// A denoising device: Open Image Denoise's CPU device with a bounded
/// number of threads.
pub struct Denoiser {
    #[cfg(feature = "oidn")]
    device: oidn::Device,
}

impl Denoiser {
    /// The CPU device with `threads` threads (0: the library's choice, every
    /// core). Refused, saying how to get one, when this build has no
    /// denoiser or the library does not start.
    pub fn new(threads: u32) -> Result<Denoiser, DenoiseError> {
        #[cfg(feature = "oidn")]
        {
            device::cpu(threads).map(|device| Denoiser { device })
        }
        #[cfg(not(feature = "oidn"))]
        {
            let _ = threads;
            Err(DenoiseError::Unavailable(format!(
                "this build has no denoiser: {HOW_TO_GET}"
            )))
        }
    }

    /// Denoises `inputs` (a `width` × `rows` block, colour scaled by
    /// `input_scale` before the network, see [`crate::exposure`]) into
    /// `out`, resized to the block.
    pub fn filter(
        &self,
        width: u32,
        rows: u32,
        inputs: &Inputs,
        input_scale: f32,
        out: &mut Vec<[f32; 3]>,
    ) -> Result<(), DenoiseError> {
        let n = width as usize * rows as usize;
        if inputs.color.len() != n
            || inputs.albedo.as_ref().is_some_and(|a| a.len() != n)
            || inputs.normal.as_ref().is_some_and(|a| a.len() != n)
            || (inputs.normal.is_some() && inputs.albedo.is_none())
        {
            return Err(DenoiseError::Band {
                start: 0,
                end: rows,
                width,
                height: rows,
                what: "inputs do not match the band (or normals without albedo)",
            });
        }
        out.clear();
        out.resize(n, [0.0; 3]);
        #[cfg(feature = "oidn")]
        {
            let mut filter = oidn::RayTracing::try_new(&self.device)
                .map_err(|e| DenoiseError::Oidn(e.to_string()))?;
            filter
                .hdr(true)
                .input_scale(input_scale)
                .image_dimensions(width as usize, rows as usize);
            let flat = |v: &[[f32; 3]]| v.as_flattened().to_vec();
            match (&inputs.albedo, &inputs.normal) {
                (Some(a), Some(nrm)) => {
                    filter.albedo_normal(&flat(a), &flat(nrm));
                }
                (Some(a), None) => {
                    filter.albedo(&flat(a));
                }
                _ => {}
            }
            filter
                .filter(inputs.color.as_flattened(), out.as_flattened_mut())
                .map_err(|e| DenoiseError::Oidn(e.to_string()))?;
            self.device
                .get_error()
                .map_err(|e| DenoiseError::Oidn(e.to_string()))
        }
        #[cfg(not(feature = "oidn"))]
        {
            let _ = input_scale;
            Err(DenoiseError::Unavailable(format!(
                "this build has no denoiser: {HOW_TO_GET}"
            )))
        }
    }
}

#[cfg(feature = "oidn")]
mod device {
    //! Creating the device through the C API, to set its thread count
    //! before it is committed (the crate's constructors commit at once).
    use super::{DenoiseError, HOW_TO_GET};
    use oidn::sys;
    use std::ffi::CStr;

    pub(super) fn cpu(threads: u32) -> Result<oidn::Device, DenoiseError> {
        // SAFETY: oidnNewDevice takes a device type and returns a new handle
        // or null; it has no other preconditions.
        let raw = unsafe { sys::oidnNewDevice(sys::OIDNDeviceType_OIDN_DEVICE_TYPE_CPU) };
        if raw.is_null() {
            let mut msg: *const std::os::raw::c_char = std::ptr::null();
            // SAFETY: a null device asks for this thread's last error; `msg`
            // is a valid out pointer, set to null or a C string the library owns.
            unsafe { sys::oidnGetDeviceError(std::ptr::null_mut(), &mut msg) };
            let why = if msg.is_null() {
                "no CPU device".to_string()
            } else {
                // SAFETY: non-null messages are NUL-terminated strings valid
                // until the next call on this thread.
                unsafe { CStr::from_ptr(msg) }
                    .to_string_lossy()
                    .into_owned()
            };
            return Err(DenoiseError::Unavailable(format!(
                "Open Image Denoise has no CPU device ({why}); {HOW_TO_GET}"
            )));
        }
        let threads = i32::try_from(threads).unwrap_or(i32::MAX);
        // SAFETY: `raw` is a live, uncommitted device; the names are
        // NUL-terminated parameter names of the CPU device.
        unsafe {
            sys::oidnSetDeviceInt(raw, c"numThreads".as_ptr(), threads);
            sys::oidnSetDeviceBool(raw, c"setAffinity".as_ptr(), false);
            sys::oidnCommitDevice(raw);
        }
        // SAFETY: `raw` is valid and committed just above; the Device takes
        // over its one reference and releases it when dropped.
        let device = unsafe { oidn::Device::from_raw(raw) };
        device
            .get_error()
            .map_err(|e| DenoiseError::Unavailable(format!("{e}; {HOW_TO_GET}")))?;
        Ok(device)
    }
}

#[cfg(all(test, not(feature = "oidn")))]
mod tests {
    use super::*;

    #[test]
    fn a_build_without_the_library_refuses_and_says_how_to_get_it() {
        let Err(e) = Denoiser::new(1) else {
            panic!("a build without the oidn feature made a denoiser");
        };
        let msg = e.to_string();
        assert!(
            msg.contains("`denoise` cargo feature") && msg.contains("pyoidn"),
            "{msg}"
        );
    }
}
