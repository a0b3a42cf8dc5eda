//! OpenEXR output: one layer, channels B G R as 32-bit float (and a frame's
//! render passes as more channels of the same layer, `albedo.R`…, `N.X`…,
//! `Z`, the names compositing tools read as layers), scanline blocks
//! of 16 rows with ZIP compression, written in increasing-Y order with the
//! `exr` crate's chunk writer.
//!
//! `exr` 1.74 hands out its `ChunkWriter` only inside the closure of
//! `exr::block::write` (its constructor and its completion, which writes the
//! offset table, are private). So that blocks can be pushed one at a time as
//! tiles complete, that closure runs on a writer thread that takes blocks from
//! a rendezvous channel; the crate stays in charge of the header, the offset
//! table and the validation. The channel has no buffer: a block is handed over
//! only when the writer thread is ready for it.

use crate::error::OutputError;
use ::exr::block::writer::ChunksWriter;
use ::exr::block::{BlockIndex, UncompressedBlock};
use ::exr::math::Vec2;
use ::exr::meta::attribute::{
    ChannelDescription, ChannelList, IntegerBounds, LineOrder, SampleType,
};
use ::exr::meta::header::{Header, ImageAttributes, LayerAttributes};
use ::exr::meta::{compute_chunk_count, BlockDescription, Headers};
use ::exr::prelude::Compression;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;
use std::sync::mpsc::{sync_channel, SyncSender};
use std::thread::JoinHandle;

/// Compression of every block: ZIP over 16 scanlines (lossless, deterministic).
const COMPRESSION: Compression = Compression::ZIP16;

/// Rows per scanline block, fixed by [`COMPRESSION`].
pub(super) const BLOCK_ROWS: u32 = 16;

enum Msg {
    Block(usize, UncompressedBlock),
    Finish,
}

/// An open EXR encoder for one frame.
pub(super) struct ExrSink {
    width: u32,
    tx: Option<SyncSender<Msg>>,
    thread: Option<JoinHandle<Result<(), OutputError>>>,
    path: String,
}

/// The header of a `width`×`height` frame of channels `names`, sorted by
/// name as EXR requires (the caller sorts; the block data follows this
/// order).
fn header(width: u32, height: u32, names: &[&str]) -> Header {
    let size = Vec2(width as usize, height as usize);
    let channels = ChannelList::new(
        names
            .iter()
            .map(|name| ChannelDescription::named(*name, SampleType::F32))
            .collect(),
    );
    let blocks = BlockDescription::ScanLines;
    Header {
        channels,
        compression: COMPRESSION,
        blocks,
        line_order: LineOrder::Increasing,
        layer_size: size,
        deep: false,
        deep_data_version: None,
        chunk_count: compute_chunk_count(COMPRESSION, size, blocks),
        max_samples_per_pixel: None,
        shared_attributes: ImageAttributes::new(IntegerBounds::from_dimensions(size)),
        own_attributes: LayerAttributes::default(),
    }
}

fn exr_error(path: &str, e: ::exr::error::Error) -> OutputError {
    match e {
        ::exr::error::Error::Io(source) => OutputError::Io {
            path: path.to_string(),
            source,
        },
        other => OutputError::Encode {
            path: path.to_string(),
            message: other.to_string(),
        },
    }
}

impl ExrSink {
    /// Starts the writer thread, which writes the header and the (still empty)
    /// offset table to `file`; returns once that is done.
    pub(super) fn new(
        file: File,
        width: u32,
        height: u32,
        channels: &[&str],
        path: &str,
    ) -> Result<Self, OutputError> {
        let headers: Headers = std::iter::once(header(width, height, channels)).collect();
        let (tx, rx) = sync_channel::<Msg>(0);
        let (ready_tx, ready_rx) = sync_channel::<()>(1);
        let thread_path = path.to_string();
        let thread = std::thread::Builder::new()
            .name("trevi-exr-writer".into())
            .spawn(move || {
                ::exr::block::write(BufWriter::new(file), headers, true, |meta, chunks| {
                    let _ = ready_tx.send(());
                    let mut compressor = chunks.sequential_blocks_compressor(&meta);
                    loop {
                        match rx.recv() {
                            Ok(Msg::Block(index, block)) => {
                                compressor.compress_block(index, block)?
                            }
                            Ok(Msg::Finish) => return Ok(()),
                            // The FrameWriter was dropped: do not complete the file.
                            Err(_) => return Err(::exr::error::Error::Aborted),
                        }
                    }
                })
                .map_err(|e| exr_error(&thread_path, e))
            })
            .map_err(|source| OutputError::Io {
                path: path.to_string(),
                source,
            })?;
        let mut sink = ExrSink {
            width,
            tx: Some(tx),
            thread: Some(thread),
            path: path.to_string(),
        };
        match ready_rx.recv() {
            Ok(()) => Ok(sink),
            // The thread ended before taking blocks: the header could not be written.
            Err(_) => Err(sink.join_error()),
        }
    }

    /// Compresses and writes the block of rows `y0 .. y0 + rows.len()`; `y0` is
    /// a multiple of [`BLOCK_ROWS`] and there are `BLOCK_ROWS` rows except in
    /// the last block. Each row holds the channels' planes in the header's
    /// order, `width` values each.
    pub(super) fn write_block(&mut self, y0: u32, rows: &[Vec<f32>]) -> Result<(), OutputError> {
        debug_assert_eq!(y0 % BLOCK_ROWS, 0);
        let mut data = Vec::with_capacity(rows.iter().map(|r| r.len() * 4).sum());
        for row in rows {
            for v in row {
                data.extend_from_slice(&v.to_ne_bytes());
            }
        }
        let block = UncompressedBlock {
            index: BlockIndex {
                layer: 0,
                pixel_position: Vec2(0, y0 as usize),
                pixel_size: Vec2(self.width as usize, rows.len()),
                level: Vec2(0, 0),
            },
            data,
        };
        self.send(Msg::Block((y0 / BLOCK_ROWS) as usize, block))
    }

    /// Lets the crate write the offset table and flush. The caller fsyncs.
    pub(super) fn finish(mut self) -> Result<(), OutputError> {
        self.send(Msg::Finish)?;
        self.tx = None;
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(result)) => result,
            Some(Err(_)) => Err(self.panicked()),
            None => Err(self.panicked()),
        }
    }

    fn send(&mut self, msg: Msg) -> Result<(), OutputError> {
        let sent = self.tx.as_ref().is_some_and(|tx| tx.send(msg).is_ok());
        if sent {
            Ok(())
        } else {
            // The writer thread has stopped, which it does only on an error.
            Err(self.join_error())
        }
    }

    fn join_error(&mut self) -> OutputError {
        self.tx = None;
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(Err(e))) => e,
            Some(Ok(Ok(()))) | None => OutputError::Encode {
                path: self.path.clone(),
                message: "the EXR writer has already stopped".into(),
            },
            Some(Err(_)) => self.panicked(),
        }
    }

    fn panicked(&self) -> OutputError {
        OutputError::Encode {
            path: self.path.clone(),
            message: "the EXR writer thread panicked".into(),
        }
    }
}

impl Drop for ExrSink {
    /// Stops the writer thread without completing the file and waits for it,
    /// so that the file is closed before the caller removes it.
    fn drop(&mut self) {
        self.tx = None;
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// Reads the first RGB layer of an EXR file into memory as 32-bit floats:
/// `(width, height, pixels)`, row by row, read with the `exr` crate's reader.
///
/// For tests and tools only: it holds the entire image, which the farm's
/// writers never do.
pub fn read_exr_rgb(path: &Path) -> Result<(u32, u32, Vec<[f32; 3]>), OutputError> {
    let p = path.display().to_string();
    use ::exr::prelude::{ReadChannels, ReadLayers};
    let image = ::exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .rgb_channels(
            |size: Vec2<usize>, _| (size.width(), size.height(), vec![[0f32; 3]; size.area()]),
            |img: &mut (usize, usize, Vec<[f32; 3]>),
             pos: Vec2<usize>,
             (r, g, b): (f32, f32, f32)| {
                img.2[pos.y() * img.0 + pos.x()] = [r, g, b];
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|e| exr_error(&p, e))?;
    let (width, height, pixels) = image.layer_data.channel_data.pixels;
    let too_big = |_| OutputError::Encode {
        path: p.clone(),
        message: "image too large".into(),
    };
    Ok((
        u32::try_from(width).map_err(too_big)?,
        u32::try_from(height).map_err(too_big)?,
        pixels,
    ))
}

/// Every channel of the first layer of an EXR file, by name, as 32-bit
/// floats row by row: `(width, height, channels)`, the channels in the
/// file's (sorted) order, read with the `exr` crate's reader.
///
/// For tests and tools only, like [`read_exr_rgb`]: it holds the whole
/// image.
#[allow(clippy::type_complexity)]
pub fn read_exr_channels(path: &Path) -> Result<(u32, u32, Vec<(String, Vec<f32>)>), OutputError> {
    let p = path.display().to_string();
    use ::exr::prelude::{ReadChannels, ReadLayers};
    let image = ::exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|e| exr_error(&p, e))?;
    let size = image.layer_data.size;
    let too_big = |_| OutputError::Encode {
        path: p.clone(),
        message: "image too large".into(),
    };
    let channels = image
        .layer_data
        .channel_data
        .list
        .into_iter()
        .map(|c| {
            let values = c.sample_data.values_as_f32().collect();
            (c.name.to_string(), values)
        })
        .collect();
    Ok((
        u32::try_from(size.width()).map_err(too_big)?,
        u32::try_from(size.height()).map_err(too_big)?,
        channels,
    ))
}
