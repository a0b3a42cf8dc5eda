//! The accepted tiles: their bytes appended to the job's tile file
//! (`tiles/<job>.f32`, written outside the store's lock) and a row in
//! `tile_refs` pointing at them with their CRC-32, committed before the
//! tile is acknowledged; the list of a job's intact stored tiles on start,
//! and the files no row points into removed.

use super::{db_err, Store};
use crate::error::FarmError;
use crate::scheduler::lease_size::MAX_SPAN_TILES;
use crate::scheduler::JobId;
use rusqlite::{params, Connection, OptionalExtension};
use std::collections::HashMap;
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::Path;
use std::sync::Arc;

/// A stored row: (first tile, tiles, rays, offset, len, crc, kind) — where
/// its pixels are in the job's file and their CRC-32; `kind` 1 when they
/// are the encoded segments of a span, of which the row's `tiles`
/// consecutive tiles from the first are part (a span of rows written by an
/// earlier version has a row of one tile for each of its tiles, all
/// pointing at the same bytes).
pub(super) type TileRef = (u32, u32, u64, u64, usize, u32, u8);

/// Row kind: the tile's own float pixels.
pub(super) const KIND_FLOATS: u8 = 0;

/// Row kind: a run of tiles of a span stored as encoded segments.
pub(super) const KIND_SEGMENTS: u8 = 1;

impl Store {
    /// Writes `pieces`, one record in order, at the end of `job`'s tile
    /// file and returns where it starts. The store's lock is held only to
    /// reserve the range; the bytes are written after it is released, so
    /// uploads (of any jobs) write in parallel on as many cores as run
    /// them. A failed write leaves its range unreferenced, like bytes
    /// whose commit never happened: the next record goes after it.
    pub(super) fn append(&self, job: JobId, pieces: &[&[u8]]) -> Result<u64, FarmError> {
        let len: u64 = pieces.iter().map(|p| p.len() as u64).sum();
        let (file, offset, path) = {
            let mut guard = self.inner.lock();
            let inner = &mut *guard;
            let path = inner.dir.join(format!("{job}.f32"));
            let io = |e| tile_file_error(&path, e);
            let (file, end) = match inner.files.entry(job) {
                std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
                std::collections::hash_map::Entry::Vacant(e) => {
                    let f = std::fs::OpenOptions::new()
                        .create(true)
                        .truncate(false)
                        .write(true)
                        .read(true)
                        .open(&path)
                        .map_err(io)?;
                    // Bytes past the last stored row (a write whose commit
                    // never happened) stay unreferenced: writing after them
                    // is safe.
                    let end = f.metadata().map_err(io)?.len();
                    e.insert((Arc::new(f), end))
                }
            };
            let offset = *end;
            *end += len;
            (file.clone(), offset, path)
        };
        let mut at = offset;
        for p in pieces {
            file.write_all_at(p, at)
                .map_err(|e| tile_file_error(&path, e))?;
            at += p.len() as u64;
        }
        Ok(offset)
    }

    /// Deletes tile files no stored tile points into (their job ended, and
    /// the coordinator stopped before it removed the file).
    pub(super) fn remove_stray_files(&self) -> Result<(), FarmError> {
        let inner = self.inner.lock();
        let mut q = inner
            .conn
            .prepare("SELECT DISTINCT job FROM tile_refs")
            .map_err(db_err)?;
        let live: std::collections::HashSet<String> = q
            .query_map([], |r| r.get::<_, i64>(0))
            .map_err(db_err)?
            .filter_map(|r| r.ok())
            .map(|j| format!("{j}.f32"))
            .collect();
        if let Ok(entries) = std::fs::read_dir(&inner.dir) {
            for e in entries.flatten() {
                if !live.contains(&*e.file_name().to_string_lossy()) {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        }
        Ok(())
    }

    /// Stores an accepted tile (a second copy of the same tile is ignored):
    /// its pixels appended to the job's file, then its row committed.
    pub fn put_tile(
        &self,
        job: JobId,
        tile: u32,
        rays: u64,
        pixels: &[u8],
    ) -> Result<(), FarmError> {
        self.put_tiles(job, &[(tile, rays, pixels)])
    }

    /// Stores accepted tiles of `job` as [`Store::put_tile`] does, their
    /// rows in one transaction: `(tile, rays, pixels)` each. One commit for
    /// the tiles of a lease of several (a commit's journal write and file
    /// locks cost about as much as a tile's row; docs/benchmarks.md, "The
    /// farm at scale"). Every tile is committed or none: an error leaves
    /// their bytes unreferenced in the file, like a write whose commit never
    /// happened.
    pub fn put_tiles<B: AsRef<[u8]>>(
        &self,
        job: JobId,
        tiles: &[(u32, u64, B)],
    ) -> Result<(), FarmError> {
        // Tiles already stored keep their row; only the others are written.
        let mut fresh = Vec::with_capacity(tiles.len());
        {
            let inner = self.inner.lock();
            // Cached statements: parsing the SQL again for every tile costs
            // about as much as running it.
            // The row at or before the tile, if its run reaches the tile.
            let mut known = inner
                .conn
                .prepare_cached(
                    "SELECT 1 FROM (SELECT tile, tiles FROM tile_refs
                         WHERE job = ?1 AND tile <= ?2 ORDER BY tile DESC LIMIT 1)
                     WHERE tile + tiles > ?2",
                )
                .map_err(db_err)?;
            for t in tiles {
                let row = known.query_row(params![job as i64, t.0], |_| Ok(()));
                if row.optional().map_err(db_err)?.is_none() {
                    fresh.push(t);
                }
            }
        }
        let mut at = Vec::with_capacity(fresh.len());
        for (_, _, pixels) in &fresh {
            let pixels = pixels.as_ref();
            let offset = self.append(job, &[pixels])?;
            at.push((offset, pixels.len(), crc32fast::hash(pixels)));
        }
        let mut guard = self.inner.lock();
        let tx = guard.conn.transaction().map_err(db_err)?;
        for (&(tile, rays, _), at) in fresh.into_iter().zip(at) {
            insert_ref(&tx, job, (tile, 1), rays, at, KIND_FLOATS)?;
        }
        tx.commit().map_err(db_err)
    }

    /// The bytes of a stored tile, if its file still holds them intact.
    /// Nothing is allocated for a row pointing past the file's end (a
    /// damaged row's length could ask for any amount).
    pub(super) fn read_tile(
        dir: &Path,
        job: JobId,
        offset: u64,
        len: usize,
        crc: u32,
    ) -> Option<Vec<u8>> {
        let f = File::open(dir.join(format!("{job}.f32"))).ok()?;
        let end = offset.checked_add(len as u64)?;
        if end > f.metadata().ok()?.len() {
            return None;
        }
        let mut buf = vec![0u8; len];
        f.read_exact_at(&mut buf, offset).ok()?;
        (crc32fast::hash(&buf) == crc).then_some(buf)
    }

    /// The rows of a job's stored tiles, in tile order.
    pub(super) fn refs(conn: &Connection, job: JobId) -> Result<Vec<TileRef>, FarmError> {
        let mut q = conn
            .prepare(
                "SELECT tile, tiles, rays, offset, len, crc, kind FROM tile_refs
                 WHERE job = ?1 ORDER BY tile",
            )
            .map_err(db_err)?;
        let rows = q
            .query_map(params![job as i64], |r| {
                Ok((
                    r.get::<_, u32>(0)?,
                    r.get::<_, u32>(1)?,
                    r.get::<_, i64>(2)? as u64,
                    r.get::<_, i64>(3)? as u64,
                    r.get::<_, i64>(4)? as usize,
                    r.get::<_, u32>(5)?,
                    r.get::<_, u8>(6)?,
                ))
            })
            .map_err(db_err)?;
        rows.collect::<Result<Vec<_>, _>>().map_err(db_err)
    }

    /// The stored tiles of a job: (tile index, rays), in tile order; a run
    /// of a span's tiles has its rays on its first tile (0 on the others).
    /// A tile whose pixels are missing or do not match their CRC is
    /// forgotten here, so that it is rendered again; so is a row of more
    /// tiles than a lease can hold ([`MAX_SPAN_TILES`]: a damaged row,
    /// which would otherwise make this list as long as it says).
    pub fn tile_list(&self, job: JobId) -> Result<Vec<(u32, u64)>, FarmError> {
        let inner = self.inner.lock();
        let mut good = Vec::new();
        // A span's tiles share their bytes: read and checked once.
        let mut checked: HashMap<(u64, usize, u32), bool> = HashMap::new();
        for (tile, tiles, rays, offset, len, crc, _) in Self::refs(&inner.conn, job)? {
            let intact = (1..=MAX_SPAN_TILES).contains(&tiles)
                && *checked.entry((offset, len, crc)).or_insert_with(|| {
                    Self::read_tile(&inner.dir, job, offset, len, crc).is_some()
                });
            if intact {
                good.push((tile, rays));
                good.extend((1..tiles).map(|i| (tile.saturating_add(i), 0)));
            } else {
                tracing::warn!(job, tile, "stored tile damaged; it will be rendered again");
                inner
                    .conn
                    .execute(
                        "DELETE FROM tile_refs WHERE job = ?1 AND tile = ?2",
                        params![job as i64, tile],
                    )
                    .map_err(db_err)?;
            }
        }
        Ok(good)
    }
}

/// Records that `tiles` consecutive tiles of `job` from `tile` are done,
/// their bytes at `at` (offset, length, CRC-32) in the job's file, of
/// `kind`; a row for the same first tile keeps the one recorded first. A
/// cached statement: parsing the SQL for every row costs about as much as
/// running it.
pub(super) fn insert_ref(
    tx: &rusqlite::Transaction,
    job: JobId,
    (tile, tiles): (u32, u32),
    rays: u64,
    (offset, len, crc): (u64, usize, u32),
    kind: u8,
) -> Result<(), FarmError> {
    tx.prepare_cached(
        "INSERT OR IGNORE INTO tile_refs (job, tile, tiles, rays, offset, len, crc, kind)
         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
    )
    .and_then(|mut q| {
        q.execute(params![
            job as i64,
            tile,
            tiles,
            rays as i64,
            offset as i64,
            len as i64,
            crc,
            kind
        ])
    })
    .map_err(db_err)?;
    Ok(())
}

fn tile_file_error(path: &Path, e: std::io::Error) -> FarmError {
    FarmError::io(format!("tile file {}", path.display()), e)
}
