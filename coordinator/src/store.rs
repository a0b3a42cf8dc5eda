//! The coordinator's durable state: an SQLite database (`state.db` in the
//! data directory, through `rusqlite` with SQLite built in).
//!
//! What is kept:
//! - every job: its spec, who submitted it, its state, and when it ends its
//!   result (error, finish order, time, tiles and rays);
//! - every accepted tile of an unfinished job: its pixels as little-endian
//!   f32 RGB (12 bytes a pixel) and its rays, written and committed before
//!   the tile is acknowledged.
//!
//! On start the coordinator reloads the jobs; for each unfinished one it
//! starts the output file afresh and replays the stored tiles into it in band
//! order (they stream from the database one at a time, so the replay holds
//! no more rows than the live stitching does), then leases only the tiles that
//! are not stored. A job's tiles are deleted when it ends (done, failed or
//! cancelled): while it runs the database holds up to 12 bytes for each pixel
//! of the frame (72 MB for 3000×2000), which is the price of never
//! rendering a finished tile twice.
//!
//! The journal is a write-ahead log with `synchronous=NORMAL`: a committed
//! tile survives the coordinator being killed at any moment; on a power cut
//! the last few commits may be lost, and those tiles are rendered again.

use crate::error::FarmError;
use crate::scheduler::{JobId, JobSpec, JobState};
use rusqlite::{params, Connection, OptionalExtension};
use std::path::Path;
use std::sync::Mutex;
use std::time::Duration;

/// A job as stored.
#[derive(Debug, Clone)]
pub struct StoredJob {
    pub id: JobId,
    pub spec: JobSpec,
    pub submitter: String,
    pub state: JobState,
    /// Wall-clock submission time, milliseconds since the Unix epoch.
    pub submitted_ms: u64,
    /// Set for finished jobs.
    pub elapsed: Option<Duration>,
    pub error: Option<String>,
    pub finish_order: u64,
    pub tiles_done: u64,
    pub rays: u64,
}

/// The database.
pub struct Store {
    conn: Mutex<Connection>,
}

fn db_err(e: rusqlite::Error) -> FarmError {
    FarmError::Io(format!("state database: {e}"))
}

fn state_from(s: &str) -> JobState {
    match s {
        "done" => JobState::Done,
        "failed" => JobState::Failed,
        "cancelled" => JobState::Cancelled,
        "running" => JobState::Running,
        _ => JobState::Queued,
    }
}

/// Milliseconds since the Unix epoch.
pub fn wall_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0)
}

impl Store {
    /// Opens (creating if needed) `dir/state.db`.
    pub fn open(dir: &Path) -> Result<Store, FarmError> {
        std::fs::create_dir_all(dir)
            .map_err(|e| FarmError::Io(format!("cannot create {}: {e}", dir.display())))?;
        let conn = Connection::open(dir.join("state.db")).map_err(db_err)?;
        conn.busy_timeout(Duration::from_secs(5)).map_err(db_err)?;
        conn.execute_batch(
            "PRAGMA journal_mode=WAL;
             PRAGMA synchronous=NORMAL;
             CREATE TABLE IF NOT EXISTS jobs (
                 id INTEGER PRIMARY KEY,
                 bundle_hash TEXT NOT NULL,
                 camera TEXT NOT NULL,
                 priority INTEGER NOT NULL,
                 width INTEGER NOT NULL,
                 height INTEGER NOT NULL,
                 tile_size INTEGER NOT NULL,
                 output_name TEXT NOT NULL,
                 submitter TEXT NOT NULL,
                 state TEXT NOT NULL,
                 submitted_ms INTEGER NOT NULL,
                 elapsed_ms INTEGER,
                 error TEXT,
                 finish_order INTEGER NOT NULL DEFAULT 0,
                 tiles_done INTEGER NOT NULL DEFAULT 0,
                 rays INTEGER NOT NULL DEFAULT 0
             );
             CREATE TABLE IF NOT EXISTS tiles (
                 job INTEGER NOT NULL,
                 tile INTEGER NOT NULL,
                 rays INTEGER NOT NULL,
                 pixels BLOB NOT NULL,
                 PRIMARY KEY (job, tile)
             );",
        )
        .map_err(db_err)?;
        Ok(Store {
            conn: Mutex::new(conn),
        })
    }

    fn conn(&self) -> std::sync::MutexGuard<'_, Connection> {
        self.conn.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub fn insert_job(&self, j: &StoredJob) -> Result<(), FarmError> {
        let s = &j.spec;
        self.conn()
            .execute(
                "INSERT INTO jobs (id, bundle_hash, camera, priority, width, height, tile_size,
                     output_name, submitter, state, submitted_ms)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11)",
                params![
                    j.id as i64,
                    s.bundle_hash,
                    s.camera,
                    s.priority,
                    s.width,
                    s.height,
                    s.tile_size,
                    s.output_name,
                    j.submitter,
                    j.state.name(),
                    j.submitted_ms as i64,
                ],
            )
            .map_err(db_err)?;
        Ok(())
    }

    /// Stores an accepted tile (a second copy of the same tile is ignored).
    pub fn put_tile(
        &self,
        job: JobId,
        tile: u32,
        rays: u64,
        pixels: &[u8],
    ) -> Result<(), FarmError> {
        self.conn()
            .execute(
                "INSERT OR IGNORE INTO tiles (job, tile, rays, pixels) VALUES (?1, ?2, ?3, ?4)",
                params![job as i64, tile, rays as i64, pixels],
            )
            .map_err(db_err)?;
        Ok(())
    }

    /// Changes a job's priority (the monitor's priority buttons).
    pub fn set_priority(&self, job: JobId, priority: i32) -> Result<(), FarmError> {
        self.conn()
            .execute(
                "UPDATE jobs SET priority = ?2 WHERE id = ?1",
                params![job as i64, priority],
            )
            .map_err(db_err)?;
        Ok(())
    }

    /// Records a job's end and drops its stored tiles.
    pub fn finish_job(&self, j: &StoredJob) -> Result<(), FarmError> {
        let mut conn = self.conn();
        let tx = conn.transaction().map_err(db_err)?;
        tx.execute(
            "UPDATE jobs SET state = ?2, elapsed_ms = ?3, error = ?4, finish_order = ?5,
                 tiles_done = ?6, rays = ?7 WHERE id = ?1",
            params![
                j.id as i64,
                j.state.name(),
                j.elapsed.map(|d| d.as_millis() as i64),
                j.error,
                j.finish_order as i64,
                j.tiles_done as i64,
                j.rays as i64,
            ],
        )
        .map_err(db_err)?;
        tx.execute("DELETE FROM tiles WHERE job = ?1", params![j.id as i64])
            .map_err(db_err)?;
        tx.commit().map_err(db_err)
    }

    /// Every job, by id.
    pub fn jobs(&self) -> Result<Vec<StoredJob>, FarmError> {
        let conn = self.conn();
        let mut q = conn
            .prepare(
                "SELECT id, bundle_hash, camera, priority, width, height, tile_size, output_name,
                     submitter, state, submitted_ms, elapsed_ms, error, finish_order, tiles_done,
                     rays FROM jobs ORDER BY id",
            )
            .map_err(db_err)?;
        let rows = q
            .query_map([], |r| {
                Ok(StoredJob {
                    id: r.get::<_, i64>(0)? as u64,
                    spec: JobSpec {
                        bundle_hash: r.get(1)?,
                        camera: r.get(2)?,
                        priority: r.get(3)?,
                        width: r.get(4)?,
                        height: r.get(5)?,
                        tile_size: r.get(6)?,
                        output_name: r.get(7)?,
                    },
                    submitter: r.get(8)?,
                    state: state_from(&r.get::<_, String>(9)?),
                    submitted_ms: r.get::<_, i64>(10)? as u64,
                    elapsed: r
                        .get::<_, Option<i64>>(11)?
                        .map(|ms| Duration::from_millis(ms.max(0) as u64)),
                    error: r.get(12)?,
                    finish_order: r.get::<_, i64>(13)? as u64,
                    tiles_done: r.get::<_, i64>(14)? as u64,
                    rays: r.get::<_, i64>(15)? as u64,
                })
            })
            .map_err(db_err)?;
        rows.collect::<Result<Vec<_>, _>>().map_err(db_err)
    }

    /// The stored tiles of a job: (tile index, rays), in tile order.
    pub fn tile_list(&self, job: JobId) -> Result<Vec<(u32, u64)>, FarmError> {
        let conn = self.conn();
        let mut q = conn
            .prepare("SELECT tile, rays FROM tiles WHERE job = ?1 ORDER BY tile")
            .map_err(db_err)?;
        let rows = q
            .query_map(params![job as i64], |r| {
                Ok((r.get::<_, u32>(0)?, r.get::<_, i64>(1)? as u64))
            })
            .map_err(db_err)?;
        rows.collect::<Result<Vec<_>, _>>().map_err(db_err)
    }

    /// Calls `f` with each stored tile's index and pixel bytes, in tile
    /// (band) order, one tile in memory at a time.
    pub fn replay_tiles(
        &self,
        job: JobId,
        mut f: impl FnMut(u32, &[u8]) -> Result<(), FarmError>,
    ) -> Result<(), FarmError> {
        let conn = self.conn();
        let mut q = conn
            .prepare("SELECT tile, pixels FROM tiles WHERE job = ?1 ORDER BY tile")
            .map_err(db_err)?;
        let mut rows = q.query(params![job as i64]).map_err(db_err)?;
        while let Some(r) = rows.next().map_err(db_err)? {
            let tile: u32 = r.get(0).map_err(db_err)?;
            let blob = r.get_ref(1).map_err(db_err)?.as_blob().map_err(|e| {
                FarmError::Io(format!("state database: tile {tile} of job {job}: {e}"))
            })?;
            f(tile, blob)?;
        }
        Ok(())
    }

    /// Largest job id ever stored.
    pub fn max_job_id(&self) -> Result<u64, FarmError> {
        let v: Option<i64> = self
            .conn()
            .query_row("SELECT MAX(id) FROM jobs", [], |r| r.get(0))
            .optional()
            .map_err(db_err)?
            .flatten();
        Ok(v.unwrap_or(0).max(0) as u64)
    }
}
