//! A job's output while it runs: where its accepted tiles go, how many are
//! written, and its live preview.
//!
//! A job's output file is opened when its first tile is written, not when
//! the job is queued: a queued job holds no file descriptor, so a farm with
//! thousands of jobs waiting needs no more descriptors than it has jobs
//! rendering (when each queued job held two, 504 of 600 queued jobs failed
//! under a limit of 1024 as a worker connected).

use crate::preview::Preview;
use crate::scheduler::JobSpec;
use crate::sink::{SinkError, TileSink};
use std::path::PathBuf;
use trevi_core::{Aovs, FrameWriter};

/// The output file a job writes once its first tile comes.
struct Pending {
    path: PathBuf,
    width: u32,
    height: u32,
    aovs: Aovs,
}

pub(super) struct Output {
    /// The open sink; `None` before the first tile (see `pending`) and
    /// once the output is gone (finished, cancelled or failed).
    pub(super) sink: Option<Box<dyn TileSink>>,
    /// The file to open at the first tile; `None` once opened or gone.
    pending: Option<Pending>,
    pub(super) written: u64,
    pub(super) total: u64,
    pub(super) max_rows_held: usize,
    pub(super) preview: Preview,
    /// The job's render passes: what every tile brings with its pixels.
    pub(super) aovs: Aovs,
}

impl Output {
    /// An output writing to `sink` (open now).
    pub(super) fn new(sink: Box<dyn TileSink>, spec: &JobSpec, total: u64) -> Output {
        Output {
            sink: Some(sink),
            pending: None,
            written: 0,
            total,
            max_rows_held: 0,
            preview: Preview::new(spec.width, spec.height),
            aovs: spec.aovs,
        }
    }

    /// An output that opens a [`FrameWriter`] on `path` when its first
    /// tile is written (see the module's doc).
    pub(super) fn deferred(path: PathBuf, spec: &JobSpec, total: u64) -> Output {
        Output {
            sink: None,
            pending: Some(Pending {
                path,
                width: spec.width,
                height: spec.height,
                aovs: spec.aovs,
            }),
            written: 0,
            total,
            max_rows_held: 0,
            preview: Preview::new(spec.width, spec.height),
            aovs: spec.aovs,
        }
    }

    /// An output rebuilt after a restart, `written` tiles in it already.
    pub(super) fn restored(
        sink: Box<dyn TileSink>,
        written: u64,
        total: u64,
        preview: Preview,
        aovs: Aovs,
    ) -> Output {
        Output {
            max_rows_held: sink.rows_held(),
            sink: Some(sink),
            pending: None,
            written,
            total,
            preview,
            aovs,
        }
    }

    /// Opens the output file if it is still to be opened. True when there
    /// is a sink to write to; false when the output is gone.
    pub(super) fn open(&mut self) -> Result<bool, SinkError> {
        if let Some(p) = self.pending.take() {
            let writer = FrameWriter::create_with_aovs(&p.path, p.width, p.height, p.aovs)?;
            self.sink = Some(Box::new(writer));
        }
        Ok(self.sink.is_some())
    }

    /// Drops the output (an unfinished file's writer removes its
    /// temporary file); nothing more is written to it.
    pub(super) fn close(&mut self) {
        self.sink = None;
        self.pending = None;
    }
}
