//! A JPEG's structure read from its markers alone, before anything is
//! decoded: the frame's size (from its SOF segment) and how many scans
//! (SOS segments) it has. One pass over the bytes, no allocation.
//!
//! Why: a progressive JPEG's decoder walks every block of the frame once
//! per scan, so its cost is (scans × blocks), and a scan costs the file
//! about ten bytes: a 713 KB file of repeated scans took 23 s of CPU to
//! decode. [`scan`] lets the caller refuse such a file, and one whose frame
//! is larger than the texel budget, for the cost of reading its markers.
//!
//! What is read: SOI, then segments up to EOI or the end of the bytes.
//! Every marker segment is skipped by its length; after an SOS the
//! entropy-coded data is skipped up to the next marker that is not a
//! restart (RSTn) or a stuffed `FF 00`. Fill bytes (`FF FF …`) before a
//! marker are allowed. Anything else malformed (a truncated segment, a
//! second frame, a scan before the frame) is an error here, which the
//! decoder would also refuse.

/// The most scans a JPEG texture may have. A baseline file has one (three
/// when its components are not interleaved); progressive encoders write
/// about 10 (libjpeg's default script) and rarely more than 20.
pub const MAX_JPEG_SCANS: u32 = 64;

/// What [`scan`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct JpegShape {
    /// The frame's width in pixels, from its SOF segment.
    pub width: u32,
    /// The frame's height in pixels, from its SOF segment.
    pub height: u32,
    /// SOS segments seen.
    pub scans: u32,
    /// A progressive frame (SOF2, SOF6, SOF10 or SOF14).
    pub progressive: bool,
}

/// Why [`scan`] refused the bytes.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum JpegScanError {
    /// The bytes do not start with `FF D8`.
    #[error("not a JPEG file (no SOI marker)")]
    NotJpeg,
    /// A segment (at the byte offset given) runs past the end.
    #[error("truncated JPEG: the segment at byte {0} runs past the end of the file")]
    Truncated(usize),
    /// A marker where none may be, or a segment that cannot be one.
    #[error("malformed JPEG: {what} at byte {at}")]
    Malformed {
        /// What was found.
        what: &'static str,
        /// Its byte offset in the file.
        at: usize,
    },
    /// The markers end with no SOF segment.
    #[error("JPEG has no frame header (SOF) before its end")]
    NoFrame,
    /// More scans than the caller's `max_scans`: refused at the first scan
    /// past it.
    #[error("JPEG has more than {MAX_JPEG_SCANS} scans (the {nth}th starts at byte {at}); each scan costs a pass over the whole image when decoded")]
    TooManyScans {
        /// The scan's number, from 1.
        nth: u32,
        /// The byte offset of its SOS marker.
        at: usize,
    },
}

/// Reads the markers of `b` (see the module's documentation), refusing a
/// file with more than `max_scans` scans as soon as its next scan is seen.
pub fn scan(b: &[u8], max_scans: u32) -> Result<JpegShape, JpegScanError> {
    if !b.starts_with(&[0xFF, 0xD8]) {
        return Err(JpegScanError::NotJpeg);
    }
    let mut frame: Option<(u32, u32, bool)> = None;
    let mut scans = 0u32;
    let mut i = 2;
    loop {
        // A marker: FF (possibly repeated as fill) and a code.
        if i >= b.len() {
            break;
        }
        if b[i] != 0xFF {
            return Err(JpegScanError::Malformed {
                what: "expected a marker",
                at: i,
            });
        }
        let at = i;
        while i < b.len() && b[i] == 0xFF {
            i += 1;
        }
        let Some(&code) = b.get(i) else {
            break;
        };
        i += 1;
        match code {
            0xD9 => break,                  // EOI
            0x01 | 0xD0..=0xD7 => continue, // TEM, RSTn: no length
            0x00 => {
                return Err(JpegScanError::Malformed {
                    what: "a stuffed 00 outside entropy-coded data",
                    at,
                })
            }
            0xD8 => {
                return Err(JpegScanError::Malformed {
                    what: "a second SOI",
                    at,
                })
            }
            _ => {}
        }
        let len = match (b.get(i), b.get(i + 1)) {
            (Some(&h), Some(&l)) => usize::from(u16::from_be_bytes([h, l])),
            _ => return Err(JpegScanError::Truncated(at)),
        };
        if len < 2 {
            return Err(JpegScanError::Malformed {
                what: "a segment length below 2",
                at,
            });
        }
        let body = i + 2;
        let end = i + len;
        if end > b.len() {
            return Err(JpegScanError::Truncated(at));
        }
        match code {
            // SOFn (not DHT C4, JPG C8, DAC CC).
            0xC0..=0xC3 | 0xC5..=0xC7 | 0xC9..=0xCB | 0xCD..=0xCF => {
                if frame.is_some() {
                    return Err(JpegScanError::Malformed {
                        what: "a second frame header (SOF)",
                        at,
                    });
                }
                if len < 8 {
                    return Err(JpegScanError::Truncated(at));
                }
                let be = |k: usize| u32::from(u16::from_be_bytes([b[body + k], b[body + k + 1]]));
                let (height, width) = (be(1), be(3));
                frame = Some((width, height, matches!(code, 0xC2 | 0xC6 | 0xCA | 0xCE)));
                i = end;
            }
            0xDA => {
                if frame.is_none() {
                    return Err(JpegScanError::Malformed {
                        what: "a scan (SOS) before the frame header (SOF)",
                        at,
                    });
                }
                scans += 1;
                if scans > max_scans {
                    return Err(JpegScanError::TooManyScans { nth: scans, at });
                }
                // Entropy-coded data up to the next real marker.
                i = end;
                while i < b.len() {
                    if b[i] == 0xFF {
                        match b.get(i + 1) {
                            Some(0x00 | 0xD0..=0xD7) => i += 2,
                            Some(0xFF) => i += 1,
                            _ => break,
                        }
                    } else {
                        i += 1;
                    }
                }
            }
            _ => i = end,
        }
    }
    let (width, height, progressive) = frame.ok_or(JpegScanError::NoFrame)?;
    Ok(JpegShape {
        width,
        height,
        scans,
        progressive,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A segment: marker code and body (its length is added).
    fn seg(code: u8, body: &[u8]) -> Vec<u8> {
        let mut v = vec![0xFF, code];
        v.extend_from_slice(&((body.len() + 2) as u16).to_be_bytes());
        v.extend_from_slice(body);
        v
    }

    fn sof(code: u8, w: u16, h: u16) -> Vec<u8> {
        let mut body = vec![8];
        body.extend_from_slice(&h.to_be_bytes());
        body.extend_from_slice(&w.to_be_bytes());
        body.extend_from_slice(&[1, 1, 0x11, 0]);
        seg(code, &body)
    }

    #[test]
    fn markers_give_the_size_and_the_scans_of_a_file() {
        let mut f = vec![0xFF, 0xD8];
        f.extend(seg(0xE0, b"JFIF\0\x01\x01\0\0\x01\0\x01\0\0"));
        f.extend(sof(0xC2, 300, 200));
        for _ in 0..3 {
            f.extend(seg(0xDA, &[1, 1, 0, 0, 63, 0]));
            // Entropy-coded data with a stuffed FF, a restart and fill.
            f.extend_from_slice(&[0x12, 0xFF, 0x00, 0x34, 0xFF, 0xD3, 0x56, 0xFF, 0xFF]);
        }
        f.extend_from_slice(&[0xFF, 0xD9]);
        let s = scan(&f, 64).unwrap();
        assert_eq!(
            s,
            JpegShape {
                width: 300,
                height: 200,
                scans: 3,
                progressive: true
            }
        );
        // The third SOS: after the frame and two scans of 10 + 9 bytes.
        let third = f.len() - 2 - (10 + 9);
        assert_eq!(&f[third..third + 2], &[0xFF, 0xDA]);
        assert_eq!(
            scan(&f, 2),
            Err(JpegScanError::TooManyScans { nth: 3, at: third })
        );
    }

    #[test]
    fn malformed_files_are_refused_not_misread() {
        assert_eq!(scan(b"\x89PNG", 64), Err(JpegScanError::NotJpeg));
        assert_eq!(
            scan(&[0xFF, 0xD8, 0xFF, 0xD9], 64),
            Err(JpegScanError::NoFrame)
        );
        let mut f = vec![0xFF, 0xD8];
        f.extend(sof(0xC0, 1, 1));
        f.truncate(f.len() - 3);
        assert_eq!(scan(&f, 64), Err(JpegScanError::Truncated(2)));
        let mut f = vec![0xFF, 0xD8];
        f.extend(seg(0xDA, &[0; 6]));
        assert!(matches!(
            scan(&f, 64),
            Err(JpegScanError::Malformed { at: 2, .. })
        ));
        let mut f = vec![0xFF, 0xD8];
        f.extend(sof(0xC0, 1, 1));
        f.extend(sof(0xC0, 1, 1));
        assert!(matches!(scan(&f, 64), Err(JpegScanError::Malformed { .. })));
        assert!(matches!(
            scan(&[0xFF, 0xD8, 0x00], 64),
            Err(JpegScanError::Malformed { at: 2, .. })
        ));
    }
}
