//! PNG output: 8-bit sRGB RGB, written row by row with the `png` crate's
//! streaming encoder.

use crate::error::OutputError;
use std::fs::File;
use std::io::{self, BufReader, BufWriter, Write};
use std::path::Path;
use std::sync::{Arc, Mutex, PoisonError};

/// Size of the encoder's IDAT chunk buffer. Part of the file layout, so fixed.
const IDAT_CHUNK_BYTES: usize = 1 << 16;

/// Passes writes through to the file and remembers the first I/O error.
///
/// The `png` 0.17 stream writer finishes the zlib stream, writes the IEND chunk
/// and flushes its output while being dropped, discarding any error. Every
/// byte still goes through this latch, so [`PngSink::finish`] can report such
/// an error instead of renaming a truncated file into place.
struct IoLatch {
    file: File,
    error: Arc<Mutex<Option<io::Error>>>,
}

impl IoLatch {
    fn record<R>(&self, result: io::Result<R>) -> io::Result<R> {
        if let Err(e) = &result {
            if e.kind() != io::ErrorKind::Interrupted {
                let mut slot = self.error.lock().unwrap_or_else(PoisonError::into_inner);
                slot.get_or_insert_with(|| io::Error::new(e.kind(), e.to_string()));
            }
        }
        result
    }
}

impl Write for IoLatch {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let result = self.file.write(buf);
        self.record(result)
    }

    fn flush(&mut self) -> io::Result<()> {
        let result = self.file.flush();
        self.record(result)
    }
}

/// An open PNG encoder for one frame.
pub(super) struct PngSink {
    // Boxed: the stream writer is large and lives in an enum beside the EXR sink.
    stream: Box<::png::StreamWriter<'static, BufWriter<IoLatch>>>,
    error: Arc<Mutex<Option<io::Error>>>,
    path: String,
}

impl PngSink {
    /// Writes the PNG header to `file`; rows follow with [`PngSink::write_row`].
    pub(super) fn new(
        file: File,
        width: u32,
        height: u32,
        path: &str,
    ) -> Result<Self, OutputError> {
        let error = Arc::new(Mutex::new(None));
        let latch = IoLatch {
            file,
            error: Arc::clone(&error),
        };
        let mut encoder = ::png::Encoder::new(BufWriter::new(latch), width, height);
        encoder.set_color(::png::ColorType::Rgb);
        encoder.set_depth(::png::BitDepth::Eight);
        encoder.set_source_srgb(::png::SrgbRenderingIntent::Perceptual);
        // png's fast preset: its own deflate tuned for PNG rows (fdeflate)
        // with adaptive filtering. The coordinator encodes every farm frame,
        // and zlib's level 1 costs it a quarter of its time per tile.
        encoder.set_compression(::png::Compression::Fast);
        let stream = encoder
            .write_header()
            .and_then(|w| w.into_stream_writer_with_size(IDAT_CHUNK_BYTES))
            .map_err(|e| encoding_error(&error, path, e))?;
        let mut sink = PngSink {
            stream: Box::new(stream),
            error,
            path: path.to_string(),
        };
        sink.check_latch()?;
        Ok(sink)
    }

    /// Encodes the next row: `3 * width` bytes, R G B per pixel.
    pub(super) fn write_row(&mut self, row: &[u8]) -> Result<(), OutputError> {
        if let Err(e) = self.stream.write_all(row) {
            self.check_latch()?;
            return Err(OutputError::Encode {
                path: self.path.clone(),
                message: e.to_string(),
            });
        }
        self.check_latch()
    }

    /// Ends the image: finishes the zlib stream and writes IEND, all flushed to
    /// the file. The caller fsyncs.
    pub(super) fn finish(self) -> Result<(), OutputError> {
        let PngSink {
            stream,
            error,
            path,
        } = self;
        // Dropping the stream writer (inside `finish`) writes the rest and
        // flushes the BufWriter into the latch.
        let result = (*stream).finish();
        if let Some(e) = take_error(&error) {
            return Err(OutputError::Io { path, source: e });
        }
        result.map_err(|e| encoding_error(&error, &path, e))
    }

    fn check_latch(&mut self) -> Result<(), OutputError> {
        match take_error(&self.error) {
            Some(source) => Err(OutputError::Io {
                path: self.path.clone(),
                source,
            }),
            None => Ok(()),
        }
    }
}

fn take_error(error: &Mutex<Option<io::Error>>) -> Option<io::Error> {
    error.lock().unwrap_or_else(PoisonError::into_inner).take()
}

fn encoding_error(
    latch: &Mutex<Option<io::Error>>,
    path: &str,
    e: ::png::EncodingError,
) -> OutputError {
    if let Some(source) = take_error(latch) {
        return OutputError::Io {
            path: path.to_string(),
            source,
        };
    }
    match e {
        ::png::EncodingError::IoError(source) => OutputError::Io {
            path: path.to_string(),
            source,
        },
        other => OutputError::Encode {
            path: path.to_string(),
            message: other.to_string(),
        },
    }
}

/// Reads a whole 8-bit RGB PNG into memory: `(width, height, pixels)`, row by
/// row. Any other PNG kind is an [`OutputError::Encode`] error.
///
/// For tests and tools only: it holds the entire image, which the farm's
/// writers never do.
pub fn read_png_rgb8(path: &Path) -> Result<(u32, u32, Vec<[u8; 3]>), OutputError> {
    let p = path.display().to_string();
    let decode_err = |e: ::png::DecodingError| match e {
        ::png::DecodingError::IoError(source) => OutputError::Io {
            path: p.clone(),
            source,
        },
        other => OutputError::Encode {
            path: p.clone(),
            message: other.to_string(),
        },
    };
    let file = File::open(path).map_err(|source| OutputError::Io {
        path: p.clone(),
        source,
    })?;
    let decoder =
        ::png::Decoder::new_with_limits(BufReader::new(file), ::png::Limits { bytes: usize::MAX });
    let mut reader = decoder.read_info().map_err(decode_err)?;
    let info = reader.info();
    let (width, height) = (info.width, info.height);
    if info.color_type != ::png::ColorType::Rgb || info.bit_depth != ::png::BitDepth::Eight {
        return Err(OutputError::Encode {
            path: p.clone(),
            message: format!(
                "expected an 8-bit RGB PNG, found {:?} {:?}",
                info.color_type, info.bit_depth
            ),
        });
    }
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| OutputError::Encode {
            path: p.clone(),
            message: format!("a {width}x{height} image does not fit in memory"),
        })?;
    let mut buf = vec![0; size];
    let frame = reader.next_frame(&mut buf).map_err(decode_err)?;
    let pixels = buf[..frame.buffer_size()]
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    Ok((width, height, pixels))
}

/// Decodes a whole 8-bit PNG held in memory, RGB like the frames this
/// module writes or RGBA like the coordinator's previews: `(width, height,
/// samples)`, the samples row by row as stored (3 or 4 a pixel).
///
/// For tests and tools only, like [`read_png_rgb8`].
pub fn decode_png(bytes: &[u8]) -> Result<(u32, u32, Vec<u8>), OutputError> {
    let what = || "a PNG in memory".to_string();
    let decode_err = |e: ::png::DecodingError| OutputError::Encode {
        path: what(),
        message: e.to_string(),
    };
    let mut reader = ::png::Decoder::new(io::Cursor::new(bytes))
        .read_info()
        .map_err(decode_err)?;
    let info = reader.info();
    if info.bit_depth != ::png::BitDepth::Eight {
        return Err(OutputError::Encode {
            path: what(),
            message: format!("expected an 8-bit PNG, found {:?}", info.bit_depth),
        });
    }
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| OutputError::Encode {
            path: what(),
            message: "the image does not fit in memory".into(),
        })?;
    let mut buf = vec![0; size];
    let frame = reader.next_frame(&mut buf).map_err(decode_err)?;
    buf.truncate(frame.buffer_size());
    Ok((frame.width, frame.height, buf))
}
