//! Opening the database: the files checked first (see `integrity.rs`),
//! SQLite's own check, the tables created, and the columns later versions
//! added given to a database an earlier version wrote (each probed with
//! `PRAGMA table_info` and added with its default when missing).

use super::integrity::{check_files, damaged};
use super::{db_err, Inner, Store};
use crate::error::FarmError;
use crate::timed_lock::TimedLock;
use rusqlite::Connection;
use std::collections::HashMap;
use std::path::Path;
use std::time::Duration;

impl Store {
    /// Opens (creating if needed) `dir/state.db`.
    pub fn open(dir: &Path) -> Result<Store, FarmError> {
        std::fs::create_dir_all(dir)
            .map_err(|e| FarmError::io(format!("cannot create {}", dir.display()), e))?;
        check_files(dir)?;
        let conn = Connection::open(dir.join("state.db")).map_err(db_err)?;
        conn.busy_timeout(Duration::from_secs(5)).map_err(db_err)?;
        let check: String = conn
            .query_row("PRAGMA quick_check", [], |r| r.get(0))
            .map_err(|e| damaged(dir, &format!("checking it failed: {e}")))?;
        if check != "ok" {
            return Err(damaged(dir, &format!("SQLite's check says: {check}")));
        }
        conn.execute_batch(
            "PRAGMA journal_mode=WAL;
             PRAGMA synchronous=NORMAL;
             CREATE TABLE IF NOT EXISTS meta (
                 key TEXT PRIMARY KEY,
                 value INTEGER NOT NULL
             );
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
             CREATE TABLE IF NOT EXISTS tile_refs (
                 job INTEGER NOT NULL,
                 tile INTEGER NOT NULL,
                 rays INTEGER NOT NULL,
                 offset INTEGER NOT NULL,
                 len INTEGER NOT NULL,
                 crc INTEGER NOT NULL,
                 PRIMARY KEY (job, tile)
             );
             CREATE TABLE IF NOT EXISTS holds (
                 job INTEGER PRIMARY KEY,
                 paused INTEGER NOT NULL,
                 after TEXT NOT NULL
             );",
        )
        .map_err(db_err)?;
        // Sequences came later: a database of an earlier version gets
        // their columns (NULL: a still).
        let have: Vec<String> = {
            let mut q = conn.prepare("PRAGMA table_info(jobs)").map_err(db_err)?;
            let names = q
                .query_map([], |r| r.get::<_, String>(1))
                .map_err(db_err)?
                .collect::<Result<Vec<_>, _>>()
                .map_err(db_err)?;
            names
        };
        // Encoded segments came later still: a tile row's `kind` (0: the
        // tile's own float pixels; 1: one of the tiles of a span whose
        // encoded segments are the bytes it points to, shared by the span).
        let tile_cols: Vec<String> = {
            let mut q = conn
                .prepare("PRAGMA table_info(tile_refs)")
                .map_err(db_err)?;
            let names = q
                .query_map([], |r| r.get::<_, String>(1))
                .map_err(db_err)?
                .collect::<Result<Vec<_>, _>>()
                .map_err(db_err)?;
            names
        };
        if !tile_cols.iter().any(|c| c == "kind") {
            conn.execute(
                "ALTER TABLE tile_refs ADD COLUMN kind INTEGER NOT NULL DEFAULT 0",
                [],
            )
            .map_err(db_err)?;
        }
        // Then a row for a run of a span's tiles (`tiles`, 1 before).
        if !tile_cols.iter().any(|c| c == "tiles") {
            conn.execute(
                "ALTER TABLE tile_refs ADD COLUMN tiles INTEGER NOT NULL DEFAULT 1",
                [],
            )
            .map_err(db_err)?;
        }
        // Then the time a job rendered (without its queue wait) and its
        // scene file's name.
        for (col, decl) in [
            ("frame", "INTEGER"),
            ("parent", "INTEGER"),
            ("first_frame", "INTEGER"),
            ("last_frame", "INTEGER"),
            ("frames_done", "INTEGER"),
            ("render_ms", "INTEGER"),
            ("scene", "TEXT NOT NULL DEFAULT ''"),
            // Then progressive jobs: a pass's samples (its row's), and the
            // passes of the job they belong to (the parent's row).
            ("pass", "INTEGER"),
            ("sample_start", "INTEGER"),
            ("sample_end", "INTEGER"),
            ("sample_total", "INTEGER"),
            ("passes_total", "INTEGER"),
            ("passes_own", "INTEGER"),
            ("pass_samples", "INTEGER"),
            ("time_limit_ms", "INTEGER"),
            ("noise_target", "REAL"),
            ("samples_done", "INTEGER"),
            ("noise_error", "REAL"),
            ("stopped_by", "TEXT"),
            ("pass_frames", "INTEGER"),
            ("pass_auto", "INTEGER"),
            // Then render passes: the job's set as `Aovs::bits` (NULL:
            // none, a job of an earlier version).
            ("aovs", "INTEGER"),
        ] {
            if !have.iter().any(|h| h == col) {
                conn.execute(&format!("ALTER TABLE jobs ADD COLUMN {col} {decl}"), [])
                    .map_err(db_err)?;
            }
        }
        super::tile_log::create(&conn)?;
        super::blocks::create(&conn)?;
        // Then the usage history (its tables, empty for an older database).
        super::usage::usage_tables(&conn).map_err(db_err)?;
        let tiles_dir = dir.join("tiles");
        std::fs::create_dir_all(&tiles_dir)
            .map_err(|e| FarmError::io(format!("cannot create {}", tiles_dir.display()), e))?;
        let store = Store {
            inner: TimedLock::new(Inner {
                conn,
                dir: tiles_dir,
                files: HashMap::new(),
            }),
        };
        store.remove_stray_files()?;
        Ok(store)
    }
}
