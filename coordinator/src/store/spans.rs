//! Spans stored as encoded PNG segments, and replaying what is stored: a
//! span's record (segments, index, Adler-32 and length, preview sums) is
//! appended once to the job's tile file with one row (`kind` 1) for each
//! run of consecutive tiles it covers; on start each stored result, a
//! tile's floats or a span's segments, is handed back once, in tile order.

use super::tiles::{insert_ref, KIND_FLOATS, KIND_SEGMENTS};
use super::{db_err, Store};
use crate::error::FarmError;
use crate::scheduler::JobId;
use std::collections::HashMap;

/// A stored result, as [`Store::replay`] hands it back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Replayed<'a> {
    /// One tile's float pixels (the wire's little-endian f32 RGB).
    Floats {
        /// The tile's index in the job's tiles (band order).
        tile: u32,
        /// `12 × pixels` bytes, row by row.
        bytes: &'a [u8],
    },
    /// A span's encoded segments, as [`Store::put_segment_span`] took them:
    /// `tiles` tiles from `first`.
    Segments {
        /// The index of the span's first tile in the job's tiles.
        first: u32,
        /// How many tiles the span covers.
        tiles: u32,
        /// The stored record, as the farm encoded it (`farm::segments`).
        bytes: &'a [u8],
    },
}

impl Store {
    /// Stores the tiles of a span taken as encoded segments: `pieces`, one
    /// record in order (the segments, their index, Adler-32 and length, and
    /// the preview sums: see `farm::segments`), appended once to the job's
    /// file, then a row for each run of consecutive tiles among `tiles`
    /// (`(tile, rays)`, in tile order; a span of whole bands is one run)
    /// pointing at them, with the run's rays, in one transaction, committed
    /// before the upload is acknowledged. A run whose first tile is stored
    /// already keeps that row (the farm never sends one: it takes a span
    /// only when none of its tiles is done).
    pub fn put_segment_span(
        &self,
        job: JobId,
        tiles: &[(u32, u64)],
        pieces: &[&[u8]],
    ) -> Result<(), FarmError> {
        let mut crc = crc32fast::Hasher::new();
        pieces.iter().for_each(|p| crc.update(p));
        let len = pieces.iter().map(|p| p.len()).sum();
        let offset = self.append(job, pieces)?;
        let at = (offset, len, crc.finalize());
        let mut guard = self.inner.lock();
        let tx = guard.conn.transaction().map_err(db_err)?;
        for run in tiles.chunk_by(|a, b| a.0.checked_add(1) == Some(b.0)) {
            let rays = run.iter().fold(0u64, |a, t| a.saturating_add(t.1));
            insert_ref(
                &tx,
                job,
                (run[0].0, run.len() as u32),
                rays,
                at,
                KIND_SEGMENTS,
            )?;
        }
        tx.commit().map_err(db_err)
    }

    /// Calls `f` with each stored tile's index and pixel bytes, in tile
    /// (band) order, one tile in memory at a time. Spans stored as encoded
    /// segments are left out (see [`Store::replay`]).
    pub fn replay_tiles(
        &self,
        job: JobId,
        mut f: impl FnMut(u32, &[u8]) -> Result<(), FarmError>,
    ) -> Result<(), FarmError> {
        self.replay(job, |r| match r {
            Replayed::Floats { tile, bytes } => f(tile, bytes),
            Replayed::Segments { .. } => Ok(()),
        })
    }

    /// Calls `f` with each stored result in order of its first tile: a
    /// tile's float pixels, or a span's encoded segments once for all its
    /// tiles; one result in memory at a time.
    pub fn replay(
        &self,
        job: JobId,
        mut f: impl FnMut(Replayed) -> Result<(), FarmError>,
    ) -> Result<(), FarmError> {
        let inner = self.inner.lock();
        // (first tile, tiles, offset, len, crc, kind), a span's rows merged.
        let mut results: Vec<(u32, u32, u64, usize, u32, u8)> = Vec::new();
        let mut span_at: HashMap<u64, usize> = HashMap::new();
        for (tile, tiles, _, offset, len, crc, kind) in Self::refs(&inner.conn, job)? {
            if kind == KIND_SEGMENTS {
                if let Some(&i) = span_at.get(&offset) {
                    results[i].1 += tiles;
                    continue;
                }
                span_at.insert(offset, results.len());
            }
            results.push((tile, tiles, offset, len, crc, kind));
        }
        for (first, tiles, offset, len, crc, kind) in results {
            let bytes = Self::read_tile(&inner.dir, job, offset, len, crc).ok_or_else(|| {
                FarmError::Damaged(format!(
                    "tile {first} of job {job}: its stored pixels are damaged"
                ))
            })?;
            f(if kind == KIND_FLOATS {
                Replayed::Floats {
                    tile: first,
                    bytes: &bytes,
                }
            } else {
                Replayed::Segments {
                    first,
                    tiles,
                    bytes: &bytes,
                }
            })?;
        }
        Ok(())
    }
}
