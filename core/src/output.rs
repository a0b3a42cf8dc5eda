//! Output images written band by band as tiles complete.
//!
//! [`FrameWriter`] writes one camera's frame to a PNG (8-bit sRGB, see
//! [`linear_to_srgb8`]) or an OpenEXR file (32-bit float linear RGB), chosen by
//! the extension of the output path (`.png` / `.exr`, any case).
//!
//! # Memory
//!
//! The farm stitches frames far larger than any process may hold (16384×16384
//! is 3 GiB of float RGB), so the writer never holds the frame. It buffers only
//! *pending rows*: rows that have received at least one pixel and have not yet
//! been handed to the encoder. Rows are handed over in file order (top to
//! bottom) as soon as their 16-row group is complete: PNG one segment of
//! [`SEGMENT_ROWS`] rows at a time (see `png.rs`: each segment is
//! filtered and compressed alone, so the file is the same whoever encodes
//! which segment), EXR one 16-row scanline block at a time (the block size of
//! ZIP compression).
//!
//! Memory held = [`FrameWriter::rows_held`] × (3·width bytes for PNG, stored
//! already converted to sRGB bytes, or 4·width bytes a channel for EXR: 12
//! for R G B, 40 with every render pass) + width/8 bytes
//! of coverage bits per pending row, plus the encoder's state (PNG: one
//! segment's filtered and compressed bytes while it is encoded, about
//! 16 × (3·width + 1) bytes and less, and a 1 MiB write buffer; EXR: one
//! 16-row block being compressed on the writer thread and at most one more
//! waiting to be handed over).
//!
//! `rows_held` depends on the order of the tiles. With tiles delivered in band
//! order (as the scheduler hands them out) and bands H rows tall it is at most
//! H + 15 (complete rows wait for the rest of their 16-row segment or block;
//! H when bands start at multiples of 16, as with 64-row tiles).
//! Out of order it is the number of rows between the first incomplete row and
//! the last row touched, up to the whole frame if the first row completes
//! last; the writer accepts any order and still produces the same bytes.
//!
//! # Render passes
//!
//! A frame created with passes ([`FrameWriter::create_with_aovs`], see
//! [`crate::aov`]) takes them with every tile
//! ([`FrameWriter::write_tile_aovs`]). An EXR frame stores them as more
//! channels of its one layer (`albedo.R`…, `N.X`…, `Z`); a PNG frame writes
//! each to a file of its own beside it ([`aov_path`]) with a writer of its
//! own, which holds the same rows as the frame's (3·width bytes a row for
//! the albedo and normal PNGs, 4·width for the depth EXR). Those files are
//! finished before the frame's own, so the PNG appears only once they all
//! have.
//!
//! # Encoded segments
//!
//! A PNG frame also takes segments already encoded elsewhere (by a worker,
//! with [`encode_segment`]): [`FrameWriter::write_segment`]. Such a segment
//! is held, as its deflate bytes, until every row above it is written, then
//! appended as it is; float rows and encoded segments mix in any order and
//! give the same bytes (the segment a worker encodes is the one the writer
//! would have encoded from the same pixels). Memory held for them =
//! [`FrameWriter::segments_held`]: the segments after the first one still
//! missing, at most every segment of the frame but that one, each at most
//! [`max_segment_deflate_len`] of its filtered bytes (in practice about
//! 0.55 bytes a pixel on a rendered scene, against 3 for a float row held as
//! sRGB). In order (each segment arriving after those above it) nothing is
//! held: a segment is written as it comes.
//!
//! # Files
//!
//! Pixels go to a temporary file `.{name}.trevi-tmp-{pid}-{n}` in the output
//! directory; [`FrameWriter::finish`] fsyncs it and renames it to the final
//! name, so a file under the final name is always complete. Dropping an
//! unfinished writer, or a failed `finish`, removes the temporary file.
//! Output bytes are a deterministic function of the pixels: any tile size,
//! tile order or machine gives the same file.

#[cfg(test)]
mod aov_tests;
mod deflate;
mod exr;
mod format;
mod layout;
mod patch;
mod pending;
mod png;
mod srgb;
#[cfg(test)]
mod tests;

pub use self::deflate::{adler32, adler32_combine, FINAL_EMPTY_BLOCK, SYNC_FLUSH};
pub use self::exr::{read_exr_channels, read_exr_rgb};
pub use self::format::{check_output, check_target, Format};
pub use self::patch::PngRows;
pub use self::png::{
    check_segment, decode_png, encode_segment, encode_segment_srgb, max_segment_deflate_len,
    png_from_segments, read_png_rgb8, segment_count, segment_filtered_len, segment_rows,
    whole_segments, PngSegment, PngStream, SegmentError, SegmentRectError, IDAT_MAX, PNG_ENCODER,
    SEGMENT_ROWS,
};
pub use self::srgb::{linear_to_srgb8, Srgb8};
pub use crate::aov::aov_path;

use self::exr::{ExrSink, BLOCK_ROWS};
pub use self::layout::NOISY_CHANNELS;
use self::layout::{signed_unit8, Layout};
use self::pending::PendingRows;
use self::png::PngSink;
use crate::aov::{Aov, AovTile, Aovs};
use crate::error::OutputError;
use crate::tile::Rect;
use std::collections::BTreeMap;
use std::ffi::OsString;
use std::fs::{self, File, OpenOptions};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// The temporary file, removed when dropped unless it was renamed into place.
struct TempFile {
    path: PathBuf,
    armed: bool,
}

impl TempFile {
    fn persist(&mut self, to: &Path) -> std::io::Result<()> {
        fs::rename(&self.path, to)?;
        self.armed = false;
        Ok(())
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        if self.armed {
            let _ = fs::remove_file(&self.path);
        }
    }
}

/// Pending rows and the encoder they go to.
enum Encoder {
    /// Rows as R G B sRGB bytes per pixel, and segments that came encoded
    /// ([`FrameWriter::write_segment`]) waiting for their turn, by index.
    Png {
        rows: PendingRows<u8>,
        sink: PngSink,
        held: BTreeMap<u32, PngSegment>,
        /// The values are signed unit vectors, stored as
        /// round(255·(v+1)/2) (a normal pass), not through the sRGB curve.
        signed: bool,
    },
    /// Rows as one plane of `width` floats per channel, in the file's
    /// (sorted) channel order: B, G, R for a plain frame.
    Exr {
        rows: PendingRows<f32>,
        sink: ExrSink,
        /// Per plane, where its values come from (see [`Layout`]).
        sources: Vec<usize>,
    },
}

/// Writes one camera's frame to a PNG (8-bit sRGB) or EXR (32-bit float
/// linear) file, chosen by extension. Tiles may arrive in any order; rows are
/// encoded and written as soon as they are complete, so only the rows of
/// incomplete bands are ever held (see the [module docs](self) for the bound).
/// The file appears under its final name only when [`FrameWriter::finish`]
/// succeeds; dropping an unfinished writer removes the temporary file.
pub struct FrameWriter {
    path: PathBuf,
    width: u32,
    height: u32,
    // Declared before `temp`: the encoder (and its file handle or writer
    // thread) is dropped before the temporary file is removed.
    encoder: Encoder,
    /// A handle on the temporary file, for fsync after the encoder is done.
    sync: File,
    temp: TempFile,
    /// First row not yet handed to the encoder; all rows above it are written.
    next_row: u32,
    /// Set when writing to the encoder failed; the writer is then unusable.
    failure: Option<String>,
    /// The render passes every tile brings.
    aovs: Aovs,
    /// A PNG frame's passes, each written to its own file by its own writer
    /// (see [`aov_path`]).
    sidecars: Vec<(Aov, FrameWriter)>,
    /// A denoised frame: every tile brings its noisy beauty too
    /// ([`FrameWriter::create_denoised`]).
    noisy: bool,
}

static TEMP_COUNTER: AtomicU64 = AtomicU64::new(0);

impl FrameWriter {
    /// Opens a writer for a `width`×`height` frame (each 1 ..= 2³¹−1) to be
    /// stored at `path`, creating missing parent directories. The format comes
    /// from the extension; anything but `.png` / `.exr` is
    /// [`OutputError::UnsupportedFormat`], and a `path` that exists but is not
    /// a regular file is [`OutputError::NotARegularFile`] (see
    /// [`check_target`]); in both cases nothing is created.
    pub fn create(path: &Path, width: u32, height: u32) -> Result<Self, OutputError> {
        FrameWriter::create_with_aovs(path, width, height, Aovs::NONE)
    }

    /// [`FrameWriter::create`] for a frame with render passes `aovs`, which
    /// every tile then brings ([`FrameWriter::write_tile_aovs`]): an EXR
    /// file holds them as channels (`albedo.R`…, `N.X`…, `Z`) beside the
    /// beauty's R G B, a PNG gets a file beside it for each (see
    /// [`aov_path`]). Every file appears only when [`FrameWriter::finish`]
    /// succeeds.
    pub fn create_with_aovs(
        path: &Path,
        width: u32,
        height: u32,
        aovs: Aovs,
    ) -> Result<Self, OutputError> {
        FrameWriter::create_layers(path, width, height, aovs, false)
    }

    /// [`FrameWriter::create_with_aovs`] for a denoised frame: an EXR file
    /// also holds the beauty before denoising, as the layer `noisy`
    /// ([`NOISY_CHANNELS`]); a PNG holds the denoised beauty alone (its
    /// passes beside it, as for any frame; keeping the noisy beauty is the
    /// caller's affair). Its tiles come through
    /// [`FrameWriter::write_tile_denoised`].
    pub fn create_denoised(
        path: &Path,
        width: u32,
        height: u32,
        aovs: Aovs,
    ) -> Result<Self, OutputError> {
        FrameWriter::create_layers(path, width, height, aovs, true)
    }

    fn create_layers(
        path: &Path,
        width: u32,
        height: u32,
        aovs: Aovs,
        noisy: bool,
    ) -> Result<Self, OutputError> {
        let format = check_output(path)?;
        let layout = Layout::of(format, aovs, noisy);
        let mut writer = FrameWriter::open(path, width, height, layout)?;
        writer.aovs = aovs;
        writer.noisy = noisy;
        for aov in aovs.iter() {
            let Some(side) = aov_path(path, aov) else {
                continue;
            };
            let layout = match aov {
                Aov::Albedo => Layout::Png { signed: false },
                Aov::Normal => Layout::Png { signed: true },
                Aov::Depth => Layout::Exr(vec![("Z", 0)]),
            };
            let side = FrameWriter::open(&side, width, height, layout)?;
            writer.sidecars.push((aov, side));
        }
        Ok(writer)
    }

    /// A writer of `layout` to `path` (no passes, no sidecars).
    fn open(path: &Path, width: u32, height: u32, layout: Layout) -> Result<Self, OutputError> {
        let display = path.display().to_string();
        // Refused now rather than after the whole frame is rendered.
        check_output(path)?;
        let io_err = |source| OutputError::Io {
            path: display.clone(),
            source,
        };
        // Both PNG and EXR store sizes as 31-bit integers.
        if width == 0 || height == 0 || width > i32::MAX as u32 || height > i32::MAX as u32 {
            return Err(OutputError::Encode {
                path: display,
                message: format!("unsupported frame size {width}x{height}"),
            });
        }
        let name = path
            .file_name()
            .ok_or_else(|| OutputError::UnsupportedFormat {
                path: display.clone(),
            })?;
        let dir = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        fs::create_dir_all(dir).map_err(io_err)?;

        let mut temp_name = OsString::from(".");
        temp_name.push(name);
        temp_name.push(format!(
            ".trevi-tmp-{}-{}",
            std::process::id(),
            TEMP_COUNTER.fetch_add(1, Ordering::Relaxed)
        ));
        let temp_path = dir.join(temp_name);
        let file = OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&temp_path)
            .map_err(io_err)?;
        let temp = TempFile {
            path: temp_path,
            armed: true,
        };
        let sync = file.try_clone().map_err(io_err)?;
        let encoder = match layout {
            Layout::Png { signed } => Encoder::Png {
                rows: PendingRows::new(width, 3 * width as usize),
                sink: PngSink::new(file, width, height, &display)?,
                held: BTreeMap::new(),
                signed,
            },
            Layout::Exr(channels) => {
                let names: Vec<&str> = channels.iter().map(|c| c.0).collect();
                Encoder::Exr {
                    rows: PendingRows::new(width, channels.len() * width as usize),
                    sink: ExrSink::new(file, width, height, &names, &display)?,
                    sources: channels.iter().map(|c| c.1).collect(),
                }
            }
        };
        Ok(FrameWriter {
            path: path.to_path_buf(),
            width,
            height,
            encoder,
            sync,
            temp,
            next_row: 0,
            failure: None,
            aovs: Aovs::NONE,
            sidecars: Vec::new(),
            noisy: false,
        })
    }

    /// The output format.
    pub fn format(&self) -> Format {
        match self.encoder {
            Encoder::Png { .. } => Format::Png,
            Encoder::Exr { .. } => Format::Exr,
        }
    }

    /// How many rows are buffered right now (see the module docs): rows
    /// that came as floats, not those of encoded segments held
    /// ([`FrameWriter::segments_held`]).
    pub fn rows_held(&self) -> usize {
        match &self.encoder {
            Encoder::Png { rows, .. } => rows.len(),
            Encoder::Exr { rows, .. } => rows.len(),
        }
    }

    /// The render passes this frame writes.
    pub fn aovs(&self) -> Aovs {
        self.aovs
    }

    /// How many encoded segments wait for an earlier segment right now, and
    /// their deflate bytes (see the module docs, "Encoded segments").
    pub fn segments_held(&self) -> (usize, usize) {
        match &self.encoder {
            Encoder::Png { held, .. } => (held.len(), held.values().map(|s| s.deflate.len()).sum()),
            Encoder::Exr { .. } => (0, 0),
        }
    }

    /// Adds segment `index` of a PNG frame, already encoded (by a worker,
    /// with [`encode_segment`]): it waits until every row above it is
    /// written, then goes into the file as it is. Rows that come as floats
    /// ([`FrameWriter::write_tile`]) and encoded segments mix freely.
    ///
    /// Refused, changing nothing and leaving the writer usable: an EXR
    /// frame, or a segment whose framing is wrong ([`check_segment`]:
    /// index, filtered length, deflate bound, sync flush), as
    /// [`OutputError::BadSegment`]; a segment whose rows were already given,
    /// as floats or as a segment, as [`OutputError::BadTile`] (with the
    /// segment's rows as the tile).
    pub fn write_segment(&mut self, index: u32, segment: &PngSegment) -> Result<(), OutputError> {
        if let Some(message) = &self.failure {
            return Err(OutputError::Encode {
                path: self.path.display().to_string(),
                message: format!("an earlier write failed: {message}"),
            });
        }
        let (width, height, next_row) = (self.width, self.height, self.next_row);
        if !self.aovs.is_empty() {
            return Err(OutputError::BadSegment {
                index,
                message: "the frame has render passes, which come with float tiles".to_string(),
            });
        }
        let Encoder::Png {
            rows, held, sink, ..
        } = &mut self.encoder
        else {
            return Err(OutputError::BadSegment {
                index,
                message: "the frame is an EXR file, which takes no PNG segments".to_string(),
            });
        };
        check_segment(width, height, index, segment).map_err(|e| OutputError::BadSegment {
            index,
            message: e.to_string(),
        })?;
        let range = segment_rows(height, index);
        let overlaps = range.start < next_row
            || held.contains_key(&index)
            || range.clone().any(|y| rows.any_written(y, 0, width));
        if overlaps {
            return Err(OutputError::BadTile {
                x: 0,
                y: range.start,
                w: width,
                h: range.end - range.start,
                width,
                height,
            });
        }
        // The next one due goes straight into the file; a later one is
        // copied and held until the rows above it are written.
        let placed = if range.start == next_row {
            sink.write_segment(segment)
                .map(|()| self.next_row = range.end)
        } else {
            held.insert(index, segment.clone());
            Ok(())
        };
        placed
            .and_then(|()| self.flush_complete_rows())
            .inspect_err(|e| {
                self.failure = Some(e.to_string());
            })
    }

    /// Adds a tile. `pixels` holds `rect.w * rect.h` linear RGB values, row by
    /// row. Complete rows are encoded and written before this returns.
    ///
    /// A tile that does not fit the frame or overlaps pixels already written is
    /// [`OutputError::BadTile`]; a wrong pixel count is
    /// [`OutputError::TilePixelCount`]. A rejected tile changes nothing, and the
    /// writer stays usable. Non-finite values are accepted: PNG maps NaN to 0
    /// and clamps, EXR stores them as they are.
    pub fn write_tile(&mut self, rect: Rect, pixels: &[[f32; 3]]) -> Result<(), OutputError> {
        self.write_tile_aovs(rect, pixels, &AovTile::default())
    }

    /// [`FrameWriter::write_tile`] with the tile's render passes, which
    /// must be the frame's ([`FrameWriter::aovs`]; none for a plain
    /// frame), `aovs.channels()` values a pixel, or
    /// [`OutputError::AovMismatch`] (nothing written).
    pub fn write_tile_aovs(
        &mut self,
        rect: Rect,
        pixels: &[[f32; 3]],
        aov: &AovTile,
    ) -> Result<(), OutputError> {
        self.write_layers(rect, pixels, aov, None)
    }

    /// [`FrameWriter::write_tile_aovs`] for a denoised frame
    /// ([`FrameWriter::create_denoised`]): `pixels` denoised, `noisy` the
    /// same pixels before denoising, or [`OutputError::NoisyMismatch`]
    /// (nothing written).
    pub fn write_tile_denoised(
        &mut self,
        rect: Rect,
        pixels: &[[f32; 3]],
        aov: &AovTile,
        noisy: &[[f32; 3]],
    ) -> Result<(), OutputError> {
        self.write_layers(rect, pixels, aov, Some(noisy))
    }

    fn write_layers(
        &mut self,
        rect: Rect,
        pixels: &[[f32; 3]],
        aov: &AovTile,
        noisy: Option<&[[f32; 3]]>,
    ) -> Result<(), OutputError> {
        let mismatch = |what| OutputError::NoisyMismatch {
            x: rect.x,
            y: rect.y,
            what,
        };
        match noisy {
            None if self.noisy => {
                return Err(mismatch("a denoised frame's tile needs its noisy beauty"))
            }
            Some(_) if !self.noisy => return Err(mismatch("this frame keeps no noisy beauty")),
            Some(v) if v.len() != pixels.len() => {
                return Err(mismatch("the noisy beauty's pixel count is not the tile's"))
            }
            _ => {}
        }
        let n = self.aovs.channels();
        if aov.aovs != self.aovs || aov.values.len() != pixels.len().saturating_mul(n) {
            return Err(OutputError::AovMismatch {
                x: rect.x,
                y: rect.y,
                expected: self.aovs,
                channels: n,
                got: aov.aovs,
                values: aov.values.len(),
            });
        }
        self.check_tile(rect, pixels)?;
        // Every file's checks pass before any is written to: the sidecars
        // have the frame's size and took the same tiles.
        let sides: Vec<Vec<[f32; 3]>> = self
            .sidecars
            .iter()
            .map(|(a, _)| {
                (0..pixels.len())
                    .map(|i| {
                        let v = aov.get(i, *a);
                        match v {
                            [x, y, z] => [*x, *y, *z],
                            [d] => [*d, 0.0, 0.0],
                            _ => [0.0; 3],
                        }
                    })
                    .collect()
            })
            .collect();
        for ((_, side), values) in self.sidecars.iter_mut().zip(&sides) {
            side.check_tile(rect, values)?;
        }
        for ((_, side), values) in self.sidecars.iter_mut().zip(&sides) {
            side.put_tile(rect, values, &[], 0).inspect_err(|e| {
                self.failure = Some(e.to_string());
            })?;
        }
        match noisy {
            // The noisy beauty's values follow each pixel's passes
            // (Layout::of).
            Some(noisy) => {
                let values: Vec<f32> = (0..pixels.len())
                    .flat_map(|i| aov.pixel(i).iter().chain(&noisy[i]).copied())
                    .collect();
                self.put_tile(rect, pixels, &values, n + 3)
            }
            None => self.put_tile(rect, pixels, &aov.values, n),
        }
    }

    /// The checks of [`FrameWriter::write_tile`], writing nothing.
    fn check_tile(&self, rect: Rect, pixels: &[[f32; 3]]) -> Result<(), OutputError> {
        self.check_rect(rect, pixels.len())
    }

    /// [`FrameWriter::check_tile`] for a tile of `count` pixels.
    fn check_rect(&self, rect: Rect, count: usize) -> Result<(), OutputError> {
        if let Some(message) = &self.failure {
            return Err(OutputError::Encode {
                path: self.path.display().to_string(),
                message: format!("an earlier write failed: {message}"),
            });
        }
        let bad_tile = OutputError::BadTile {
            x: rect.x,
            y: rect.y,
            w: rect.w,
            h: rect.h,
            width: self.width,
            height: self.height,
        };
        if !rect.fits(self.width, self.height) {
            return Err(bad_tile);
        }
        if count != rect.pixel_count() {
            return Err(OutputError::TilePixelCount {
                x: rect.x,
                y: rect.y,
                w: rect.w,
                h: rect.h,
                expected: rect.pixel_count(),
                got: count,
            });
        }
        // Rows above `next_row` are complete, so any tile reaching them overlaps.
        // So do rows of an encoded segment waiting for its turn.
        let (x0, x1) = (rect.x, rect.x + rect.w);
        let overlaps = rect.y < self.next_row
            || (rect.y..rect.y + rect.h).any(|y| match &self.encoder {
                Encoder::Png { rows, held, .. } => {
                    held.contains_key(&(y / SEGMENT_ROWS)) || rows.any_written(y, x0, x1)
                }
                Encoder::Exr { rows, .. } => rows.any_written(y, x0, x1),
            });
        if overlaps {
            return Err(bad_tile);
        }
        Ok(())
    }

    /// Writes a tile [`FrameWriter::check_tile`] accepted: `pixels`, and
    /// `n` pass values a pixel in `aov`.
    fn put_tile(
        &mut self,
        rect: Rect,
        pixels: &[[f32; 3]],
        aov: &[f32],
        n: usize,
    ) -> Result<(), OutputError> {
        let (x0, x1) = (rect.x, rect.x + rect.w);
        let width = self.width as usize;
        let lines = pixels.chunks_exact(rect.w as usize);
        match &mut self.encoder {
            Encoder::Png { rows, signed, .. } => {
                let srgb = Srgb8::new();
                let signed = *signed;
                for (y, line) in (rect.y..).zip(lines) {
                    let row = rows.claim(y, x0, x1);
                    let dst = &mut row[3 * x0 as usize..3 * x1 as usize];
                    for (d, p) in dst.chunks_exact_mut(3).zip(line) {
                        if signed {
                            d.copy_from_slice(&p.map(signed_unit8));
                        } else {
                            d.copy_from_slice(&p.map(|c| srgb.encode(c)));
                        }
                    }
                }
            }
            Encoder::Exr { rows, sources, .. } => {
                let w = rect.w as usize;
                for (j, (y, line)) in (rect.y..).zip(lines).enumerate() {
                    let row = rows.claim(y, x0, x1);
                    for (k, &src) in sources.iter().enumerate() {
                        let plane = &mut row[k * width..(k + 1) * width];
                        for (i, (px, p)) in (x0 as usize..).zip(line.iter().enumerate()) {
                            plane[i] = if src < 3 {
                                p[src]
                            } else {
                                aov[(j * w + px) * n + src - 3]
                            };
                        }
                    }
                }
            }
        }
        self.flush_complete_rows().inspect_err(|e| {
            self.failure = Some(e.to_string());
        })
    }

    /// Hands every complete row at the top of the pending rows to the encoder.
    fn flush_complete_rows(&mut self) -> Result<(), OutputError> {
        match &mut self.encoder {
            Encoder::Png {
                rows, sink, held, ..
            } => loop {
                // `next_row` is always the start of a segment here.
                let index = self.next_row / SEGMENT_ROWS;
                if let Some(segment) = held.remove(&index) {
                    sink.write_segment(&segment)?;
                    self.next_row = segment_rows(self.height, index).end;
                } else if let Some(rows) = rows.take_block(self.next_row, SEGMENT_ROWS, self.height)
                {
                    sink.write_rows(self.width, &rows)?;
                    self.next_row += rows.len() as u32;
                } else {
                    break;
                }
            },
            Encoder::Exr { rows, sink, .. } => {
                while let Some(block) = rows.take_block(self.next_row, BLOCK_ROWS, self.height) {
                    sink.write_block(self.next_row, &block)?;
                    self.next_row += block.len() as u32;
                }
            }
        }
        Ok(())
    }

    /// Completes the file: [`OutputError::Incomplete`] if any pixel is
    /// missing; otherwise finishes the encoder, fsyncs, and atomically renames
    /// the temporary file to the final path. On any error the temporary file is
    /// removed and the final path is left as it was.
    pub fn finish(self) -> Result<(), OutputError> {
        let FrameWriter {
            path,
            height,
            encoder,
            sync,
            mut temp,
            next_row,
            failure,
            sidecars,
            ..
        } = self;
        // The files beside a PNG first: the frame's own file appears only
        // once they all have.
        for (_, side) in sidecars {
            side.finish()?;
        }
        let display = path.display().to_string();
        if let Some(message) = failure {
            return Err(OutputError::Encode {
                path: display,
                message: format!("an earlier write failed: {message}"),
            });
        }
        if next_row < height {
            let complete = match &encoder {
                Encoder::Png { rows, held, .. } => {
                    let segments: u32 = held
                        .keys()
                        .map(|&i| segment_rows(height, i).len() as u32)
                        .sum();
                    rows.complete_count() + segments as usize
                }
                Encoder::Exr { rows, .. } => rows.complete_count(),
            };
            return Err(OutputError::Incomplete {
                missing: height - next_row - complete as u32,
            });
        }
        match encoder {
            Encoder::Png { sink, .. } => sink.finish()?,
            Encoder::Exr { sink, .. } => sink.finish()?,
        }
        let io_err = |source| OutputError::Io {
            path: display.clone(),
            source,
        };
        sync.sync_all().map_err(io_err)?;
        drop(sync);
        // Something may have appeared under the name while rendering.
        check_target(&path)?;
        temp.persist(&path).map_err(io_err)?;
        // Make the rename itself durable; the file is already in place, so
        // a failure here is not worth reporting.
        #[cfg(unix)]
        if let Some(dir) = path.parent() {
            let dir = if dir.as_os_str().is_empty() {
                Path::new(".")
            } else {
                dir
            };
            if let Ok(d) = File::open(dir) {
                let _ = d.sync_all();
            }
        }
        Ok(())
    }
}
