//! The coordinator's durable state: an SQLite database (`state.db` in the
//! data directory, through `rusqlite` with SQLite built in).
//!
//! What is kept:
//! - every job: its spec, who submitted it, its state, and when it ends its
//!   result (error, finish order, time, tiles and rays);
//! - every accepted tile of an unfinished job: its rays and where its pixels
//!   are, committed before the tile is acknowledged. The pixels themselves
//!   (little-endian f32 RGB, 12 bytes a pixel) are appended to the job's
//!   file `tiles/<job>.f32` just before that commit, with a CRC-32 in the
//!   row. Kept out of the database because writing 48 KiB blobs into
//!   SQLite's log and checkpointing them again cost the coordinator a third
//!   of its time per tile (docs/benchmarks.md); a small row costs little.
//! - every span of tiles taken as encoded PNG segments
//!   ([`Store::put_segment_span`]): the segments, their index, Adler-32 and
//!   length, and the preview sums, appended once to the same file (about
//!   0.55 bytes a pixel instead of 12), with one row (`kind` 1) for each
//!   run of consecutive tiles it covers (`tile` the first, `tiles` how
//!   many: a span of whole bands is one run), pointing at them; a restart
//!   replays them ([`Store::replay`]) and a damaged one is forgotten with
//!   all its tiles. A row per tile cost the coordinator a sixth of its time
//!   on a farm of hundreds of workers (docs/benchmarks.md, "Stage 5").
//!
//! On start the coordinator reloads the jobs; for each unfinished one it
//! starts the output file afresh and replays the stored tiles into it in band
//! order (they are read one at a time, so the replay holds no more rows than
//! the live stitching does), then leases only the tiles that are not stored.
//! A stored tile whose bytes do not match its CRC (a power cut between the
//! file write and the disk) is dropped and rendered again. A job's tiles are
//! deleted when it ends (done, failed or cancelled): while it runs the data
//! directory holds up to 12 bytes for each pixel of the frame (72 MB for
//! 3000×2000), which is the price of never rendering a finished tile twice.
//!
//! The journal is a write-ahead log with `synchronous=NORMAL`: a committed
//! tile survives the coordinator being killed at any moment (its pixels were
//! handed to the kernel before the commit); on a power cut the last few
//! commits may be lost, and those tiles are rendered again.
//!
//! A database SQLite would open by quietly dropping what it holds is refused
//! instead ([`check_files`]): an empty or missing `state.db` beside a
//! write-ahead log that holds frames (SQLite deletes such a log), a log whose
//! header is damaged (SQLite ignores the whole log), or a log with a damaged
//! frame before frames of the same generation (SQLite drops everything from
//! the damaged frame on). Only a damaged *tail* of the log passes: that is
//! the last commits of a power cut, as above.
//!
//! Job ids are never reused: the largest id ever given is kept (`meta`)
//! when ended jobs are pruned, and the coordinator also skips every id whose
//! `jobs/<id>` directory exists.
//!
//! Beside this file, in `store/`: `schema.rs` (opening the database, its
//! tables and the columns later versions added), `integrity.rs` (the files
//! refused before SQLite opens them), `jobs.rs` (the jobs' rows),
//! `tiles.rs` (the tile files and their rows), `spans.rs` (spans of
//! encoded segments, and replaying what is stored), `holds.rs` (jobs
//! paused or waiting for others), `tile_log.rs` (the per-tile log, bounded
//! per job), `blocks.rs` (the workers kept from unfinished jobs) and
//! `usage.rs` (the usage history, kept beyond the jobs' retention under its
//! own; see [`crate::usage`]).

mod blocks;
mod holds;
mod integrity;
mod jobs;
mod schema;
mod spans;
mod tile_log;
mod tiles;
mod usage;

pub use blocks::StoredBlock;
pub use holds::StoredHold;
pub use integrity::check_files;
pub use jobs::{SeqLink, StoredJob, StoredPasses};
pub use spans::Replayed;
pub use tile_log::{JobLog, LogBounds, LogEntry, LogFilter, MAX_LOG_QUERY_CHARS, MAX_REPLY_BYTES};
pub use usage::{add_usage, query_usage, usage_tables};

use crate::error::FarmError;
use crate::scheduler::JobId;
use crate::timed_lock::TimedLock;
use rusqlite::Connection;
use std::collections::HashMap;
use std::fs::File;
use std::path::PathBuf;
use std::sync::Arc;

/// The database and the jobs' tile files.
pub struct Store {
    inner: TimedLock<Inner>,
}

struct Inner {
    conn: Connection,
    /// `tiles/` in the data directory.
    dir: PathBuf,
    /// Open tile files of unfinished jobs, with their length including
    /// what is reserved for writes in progress ([`Store::append`]).
    files: HashMap<JobId, (Arc<File>, u64)>,
}

fn db_err(e: rusqlite::Error) -> FarmError {
    FarmError::io("state database", e)
}

/// Milliseconds since the Unix epoch.
pub fn wall_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0)
}

impl Store {
    /// How long the store's lock (its database and the tile files' ends)
    /// has been held since the start: `trevi_store_lock_held_seconds_total`.
    pub fn lock_held(&self) -> std::time::Duration {
        self.inner.held()
    }
}

#[cfg(test)]
mod tests;
