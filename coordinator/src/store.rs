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

use crate::error::FarmError;
use crate::scheduler::lease_size::MAX_SPAN_TILES;
use crate::scheduler::{JobId, JobSpec, JobState};
use crate::timed_lock::TimedLock;
use rusqlite::{params, Connection, OptionalExtension};
use std::collections::HashMap;
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

/// A job as stored.
#[derive(Debug, Clone)]
pub struct StoredJob {
    pub id: JobId,
    /// What to render; its `submitter` is stored as the row's submitter.
    pub spec: JobSpec,
    pub state: JobState,
    /// Wall-clock submission time, milliseconds since the Unix epoch.
    pub submitted_ms: u64,
    /// Set for finished jobs.
    pub elapsed: Option<Duration>,
    /// Set for finished jobs that started: the part of `elapsed` after the
    /// first tile was leased.
    pub render: Option<Duration>,
    pub error: Option<String>,
    pub finish_order: u64,
    pub tiles_done: u64,
    pub rays: u64,
    /// How the job belongs to a sequence, or is one.
    pub seq: SeqLink,
}

impl StoredJob {
    /// The row of a job submitted now: nothing rendered, nothing finished.
    pub fn submitted(id: JobId, spec: JobSpec, state: JobState, seq: SeqLink) -> StoredJob {
        StoredJob {
            id,
            spec,
            state,
            submitted_ms: wall_ms(),
            elapsed: None,
            render: None,
            error: None,
            finish_order: 0,
            tiles_done: 0,
            rays: 0,
            seq,
        }
    }
}

/// A sequence's row, or a frame's link to its sequence (see
/// `crate::farm::sequences`): a sequence is a row of its own, its frames
/// jobs whose `parent` it is. Both `None` for a still.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SeqLink {
    /// For a frame: its sequence.
    pub parent: Option<JobId>,
    /// For a sequence: its first and last frame.
    pub frames: Option<(u32, u32)>,
    /// For an ended sequence: how many frames it finished.
    pub frames_done: u32,
}

/// A stored row: (first tile, tiles, rays, offset, len, crc, kind) — where
/// its pixels are in the job's file and their CRC-32; `kind` 1 when they
/// are the encoded segments of a span, of which the row's `tiles`
/// consecutive tiles from the first are part (a span of rows written by an
/// earlier version has a row of one tile for each of its tiles, all
/// pointing at the same bytes).
type TileRef = (u32, u32, u64, u64, usize, u32, u8);

/// Row kind: the tile's own float pixels.
const KIND_FLOATS: u8 = 0;
/// Row kind: a run of tiles of a span stored as encoded segments.
const KIND_SEGMENTS: u8 = 1;

/// A stored result, as [`Store::replay`] hands it back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Replayed<'a> {
    /// One tile's float pixels (the wire's little-endian f32 RGB).
    Floats { tile: u32, bytes: &'a [u8] },
    /// A span's encoded segments, as [`Store::put_segment_span`] took them:
    /// `tiles` tiles from `first`.
    Segments {
        first: u32,
        tiles: u32,
        bytes: &'a [u8],
    },
}

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

/// A job's stored state: one of [`JobState::name`]'s words. Any other is a
/// database this coordinator did not write, refused naming the job.
fn state_from(job: JobId, s: &str) -> Result<JobState, FarmError> {
    JobState::ALL
        .into_iter()
        .find(|st| st.name() == s)
        .ok_or_else(|| {
            FarmError::Damaged(format!(
                "the state database says job {job} is \"{}\", not a state this coordinator \
                 knows ({})",
                s.chars().take(40).collect::<String>(),
                JobState::ALL.map(JobState::name).join(", ")
            ))
        })
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
        ] {
            if !have.iter().any(|h| h == col) {
                conn.execute(&format!("ALTER TABLE jobs ADD COLUMN {col} {decl}"), [])
                    .map_err(db_err)?;
            }
        }
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

    /// How long the store's lock (its database and the tile files' ends)
    /// has been held since the start: `trevi_store_lock_held_seconds_total`.
    pub fn lock_held(&self) -> std::time::Duration {
        self.inner.held()
    }

    /// Writes `pieces`, one record in order, at the end of `job`'s tile
    /// file and returns where it starts. The store's lock is held only to
    /// reserve the range; the bytes are written after it is released, so
    /// uploads (of any jobs) write in parallel on as many cores as run
    /// them. A failed write leaves its range unreferenced, like bytes
    /// whose commit never happened: the next record goes after it.
    fn append(&self, job: JobId, pieces: &[&[u8]]) -> Result<u64, FarmError> {
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
    fn remove_stray_files(&self) -> Result<(), FarmError> {
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

    pub fn insert_job(&self, j: &StoredJob) -> Result<(), FarmError> {
        let s = &j.spec;
        self.inner
            .lock()
            .conn
            .execute(
                "INSERT INTO jobs (id, bundle_hash, camera, priority, width, height, tile_size,
                     output_name, submitter, state, submitted_ms, frame, parent, first_frame,
                     last_frame, scene)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16)",
                params![
                    j.id as i64,
                    s.bundle_hash,
                    s.camera,
                    s.priority,
                    s.width,
                    s.height,
                    s.tile_size,
                    s.output_name,
                    s.submitter,
                    j.state.name(),
                    j.submitted_ms as i64,
                    s.frame,
                    j.seq.parent.map(|p| p as i64),
                    j.seq.frames.map(|f| f.0),
                    j.seq.frames.map(|f| f.1),
                    s.scene,
                ],
            )
            .map_err(db_err)?;
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

    /// The bytes of a stored tile, if its file still holds them intact.
    /// Nothing is allocated for a row pointing past the file's end (a
    /// damaged row's length could ask for any amount).
    fn read_tile(dir: &Path, job: JobId, offset: u64, len: usize, crc: u32) -> Option<Vec<u8>> {
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
    fn refs(conn: &Connection, job: JobId) -> Result<Vec<TileRef>, FarmError> {
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

    /// Changes a job's priority (the monitor's priority buttons).
    pub fn set_priority(&self, job: JobId, priority: i32) -> Result<(), FarmError> {
        self.inner
            .lock()
            .conn
            .execute(
                "UPDATE jobs SET priority = ?2 WHERE id = ?1",
                params![job as i64, priority],
            )
            .map_err(db_err)?;
        Ok(())
    }

    /// Records a job's end and drops its stored tiles.
    pub fn finish_job(&self, j: &StoredJob) -> Result<(), FarmError> {
        self.finish_frame(j, None)
    }

    /// Like [`Store::finish_job`], and for a frame of a sequence in the same
    /// transaction the sequence's count of finished frames (`(sequence,
    /// frames_done)`), so a restart never finds one without the other.
    pub fn finish_frame(&self, j: &StoredJob, seq: Option<(JobId, u32)>) -> Result<(), FarmError> {
        let mut guard = self.inner.lock();
        let inner = &mut *guard;
        let tx = inner.conn.transaction().map_err(db_err)?;
        if let Some((seq, done)) = seq {
            tx.execute(
                "UPDATE jobs SET frames_done = ?2 WHERE id = ?1",
                params![seq as i64, done],
            )
            .map_err(db_err)?;
        }
        tx.execute(
            "UPDATE jobs SET state = ?2, elapsed_ms = ?3, error = ?4, finish_order = ?5,
                 tiles_done = ?6, rays = ?7, frames_done = ?8, render_ms = ?9 WHERE id = ?1",
            params![
                j.id as i64,
                j.state.name(),
                j.elapsed.map(|d| d.as_millis() as i64),
                j.error,
                j.finish_order as i64,
                j.tiles_done as i64,
                j.rays as i64,
                j.seq.frames_done,
                j.render.map(|d| d.as_millis() as i64),
            ],
        )
        .map_err(db_err)?;
        tx.execute("DELETE FROM tile_refs WHERE job = ?1", params![j.id as i64])
            .map_err(db_err)?;
        tx.commit().map_err(db_err)?;
        inner.files.remove(&j.id);
        let _ = std::fs::remove_file(inner.dir.join(format!("{}.f32", j.id)));
        Ok(())
    }

    /// Every job, by id.
    pub fn jobs(&self) -> Result<Vec<StoredJob>, FarmError> {
        let inner = self.inner.lock();
        let mut q = inner
            .conn
            .prepare(
                "SELECT id, bundle_hash, camera, priority, width, height, tile_size, output_name,
                     submitter, state, submitted_ms, elapsed_ms, error, finish_order, tiles_done,
                     rays, frame, parent, first_frame, last_frame, frames_done, render_ms, scene
                 FROM jobs ORDER BY id",
            )
            .map_err(db_err)?;
        let rows = q
            .query_map([], |r| {
                // The state is read below, where a bad one can name its job.
                let state: String = r.get(9)?;
                let job = StoredJob {
                    id: r.get::<_, i64>(0)? as u64,
                    spec: JobSpec {
                        bundle_hash: r.get(1)?,
                        camera: r.get(2)?,
                        priority: r.get(3)?,
                        width: r.get(4)?,
                        height: r.get(5)?,
                        tile_size: r.get(6)?,
                        output_name: r.get(7)?,
                        frame: r.get(16)?,
                        scene: r.get(22)?,
                        submitter: r.get(8)?,
                    },
                    state: JobState::Queued,
                    submitted_ms: r.get::<_, i64>(10)? as u64,
                    elapsed: r
                        .get::<_, Option<i64>>(11)?
                        .map(|ms| Duration::from_millis(ms.max(0) as u64)),
                    render: r
                        .get::<_, Option<i64>>(21)?
                        .map(|ms| Duration::from_millis(ms.max(0) as u64)),
                    error: r.get(12)?,
                    finish_order: r.get::<_, i64>(13)? as u64,
                    tiles_done: r.get::<_, i64>(14)? as u64,
                    rays: r.get::<_, i64>(15)? as u64,
                    seq: SeqLink {
                        parent: r.get::<_, Option<i64>>(17)?.map(|p| p as u64),
                        frames: match (r.get::<_, Option<u32>>(18)?, r.get::<_, Option<u32>>(19)?) {
                            (Some(a), Some(b)) => Some((a, b)),
                            _ => None,
                        },
                        frames_done: r.get::<_, Option<u32>>(20)?.unwrap_or(0),
                    },
                };
                Ok((job, state))
            })
            .map_err(db_err)?;
        let rows: Vec<(StoredJob, String)> = rows.collect::<Result<Vec<_>, _>>().map_err(db_err)?;
        rows.into_iter()
            .map(|(mut j, state)| {
                j.state = state_from(j.id, &state)?;
                Ok(j)
            })
            .collect()
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

    /// Largest job id ever stored, including jobs pruned since.
    pub fn max_job_id(&self) -> Result<u64, FarmError> {
        let v: Option<i64> = self
            .inner
            .lock()
            .conn
            .query_row(
                "SELECT MAX(m) FROM (SELECT MAX(id) AS m FROM jobs
                     UNION ALL SELECT value FROM meta WHERE key = 'max_job_id')",
                [],
                |r| r.get(0),
            )
            .optional()
            .map_err(db_err)?
            .flatten();
        Ok(v.unwrap_or(0).max(0) as u64)
    }

    /// Forgets ended jobs (retention), remembering the largest id so that it
    /// is never given again. Their tiles were dropped when they ended.
    pub fn delete_jobs(&self, ids: &[JobId]) -> Result<(), FarmError> {
        let Some(&max) = ids.iter().max() else {
            return Ok(());
        };
        let mut guard = self.inner.lock();
        let tx = guard.conn.transaction().map_err(db_err)?;
        tx.execute(
            "INSERT INTO meta (key, value) VALUES ('max_job_id', ?1)
             ON CONFLICT(key) DO UPDATE SET value = MAX(value, excluded.value)",
            params![max as i64],
        )
        .map_err(db_err)?;
        {
            let mut del = tx
                .prepare("DELETE FROM jobs WHERE id = ?1")
                .map_err(db_err)?;
            for &id in ids {
                del.execute(params![id as i64]).map_err(db_err)?;
            }
        }
        tx.commit().map_err(db_err)
    }
}

/// Records that `tiles` consecutive tiles of `job` from `tile` are done,
/// their bytes at `at` (offset, length, CRC-32) in the job's file, of
/// `kind`; a row for the same first tile keeps the one recorded first. A
/// cached statement: parsing the SQL for every row costs about as much as
/// running it.
fn insert_ref(
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

fn damaged(dir: &Path, why: &str) -> FarmError {
    FarmError::Damaged(format!(
        "the state database {} is damaged ({why}); refusing to start, since going on would \
         lose or mix up jobs. Restore it from a backup, or move state.db, state.db-wal and \
         state.db-shm away to start with no jobs",
        dir.join("state.db").display()
    ))
}

/// The additive checksum of SQLite's write-ahead log over `data` (a multiple
/// of 8 bytes), continuing from `s`; words big-endian when `big`.
fn wal_checksum(big: bool, mut s: (u32, u32), data: &[u8]) -> (u32, u32) {
    let word = |b: &[u8]| {
        let b = [b[0], b[1], b[2], b[3]];
        if big {
            u32::from_be_bytes(b)
        } else {
            u32::from_le_bytes(b)
        }
    };
    for pair in data.chunks_exact(8) {
        s.0 = s.0.wrapping_add(word(&pair[..4]).wrapping_add(s.1));
        s.1 = s.1.wrapping_add(word(&pair[4..]).wrapping_add(s.0));
    }
    s
}

/// Refuses database files SQLite would open by silently dropping committed
/// data (see the module docs); called before SQLite touches them.
pub fn check_files(dir: &Path) -> Result<(), FarmError> {
    let db = dir.join("state.db");
    let wal_path = dir.join("state.db-wal");
    let wal = match std::fs::read(&wal_path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => {
            return Err(FarmError::io(
                format!("cannot read {}", wal_path.display()),
                e,
            ))
        }
    };
    if wal.is_empty() {
        return Ok(());
    }
    let db_len = std::fs::metadata(&db).map(|m| m.len()).ok();
    if db_len.unwrap_or(0) == 0 {
        let what = if db_len.is_some() { "empty" } else { "missing" };
        return Err(damaged(
            dir,
            &format!(
                "state.db is {what} but its write-ahead log state.db-wal holds {} bytes: \
                 the database was truncated or deleted, and SQLite would delete the log",
                wal.len()
            ),
        ));
    }
    let be = |at: usize| u32::from_be_bytes([wal[at], wal[at + 1], wal[at + 2], wal[at + 3]]);
    let bad_header = |why: &str| {
        damaged(
            dir,
            &format!("the header of its write-ahead log state.db-wal is damaged ({why}), so SQLite would ignore the whole log"),
        )
    };
    if wal.len() < 32 {
        return Err(bad_header(&format!("the file is {} bytes", wal.len())));
    }
    let magic = be(0);
    if magic & !1 != 0x377f_0682 {
        return Err(bad_header("not a write-ahead log"));
    }
    let big = magic & 1 == 1;
    let page = be(8) as usize;
    if be(4) != 3_007_000 || !page.is_power_of_two() || !(512..=65536).contains(&page) {
        return Err(bad_header("unknown version or page size"));
    }
    let mut sum = wal_checksum(big, (0, 0), &wal[..24]);
    if sum != (be(24), be(28)) {
        return Err(bad_header("checksum mismatch"));
    }
    let salts = (be(16), be(20));
    let frame = 24 + page;
    let mut at = 32;
    let mut chained = true;
    while at + frame <= wal.len() {
        let own_salts = (be(at + 8), be(at + 12)) == salts;
        if chained {
            let s = wal_checksum(big, sum, &wal[at..at + 8]);
            let s = wal_checksum(big, s, &wal[at + 24..at + frame]);
            if own_salts && s == (be(at + 16), be(at + 20)) {
                sum = s;
            } else {
                // SQLite stops reading here. Stale frames of an earlier
                // generation (other salts) and a torn last write are normal.
                chained = false;
            }
        } else if own_salts {
            return Err(damaged(
                dir,
                &format!(
                    "its write-ahead log state.db-wal has a damaged frame before frame {} of \
                     the same generation, so SQLite would drop the commits after the damage",
                    (at - 32) / frame
                ),
            ));
        }
        at += frame;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn job(id: JobId) -> StoredJob {
        StoredJob {
            id,
            spec: JobSpec {
                frame: None,
                bundle_hash: "h".into(),
                camera: "c".into(),
                priority: 0,
                width: 8,
                height: 8,
                tile_size: 4,
                output_name: "o.png".into(),
                scene: "s.xml".into(),
                submitter: "client".into(),
            },
            state: JobState::Running,
            submitted_ms: 1,
            elapsed: None,
            render: None,
            error: None,
            finish_order: 0,
            tiles_done: 0,
            rays: 0,
            seq: SeqLink::default(),
        }
    }

    fn replayed(s: &Store, id: JobId) -> Vec<(u32, Vec<u8>)> {
        let mut out = Vec::new();
        s.replay_tiles(id, |t, b| {
            out.push((t, b.to_vec()));
            Ok(())
        })
        .unwrap();
        out
    }

    /// What `list` shows of a job outlives a restart: its scene, its
    /// submitter and, once it ended, how long it rendered.
    #[test]
    fn scene_submitter_and_render_time_are_kept() {
        let dir = tempfile::tempdir().unwrap();
        {
            let s = Store::open(dir.path()).unwrap();
            s.insert_job(&job(1)).unwrap();
            s.insert_job(&job(2)).unwrap();
            s.finish_job(&StoredJob {
                state: JobState::Done,
                elapsed: Some(Duration::from_millis(5000)),
                render: Some(Duration::from_millis(3250)),
                ..job(1)
            })
            .unwrap();
        }
        let jobs = Store::open(dir.path()).unwrap().jobs().unwrap();
        let got: Vec<_> = jobs
            .iter()
            .map(|j| {
                (
                    j.id,
                    j.spec.scene.as_str(),
                    j.spec.submitter.as_str(),
                    j.render,
                )
            })
            .collect();
        assert_eq!(
            got,
            [
                (1, "s.xml", "client", Some(Duration::from_millis(3250))),
                (2, "s.xml", "client", None)
            ]
        );
    }

    #[test]
    fn tiles_survive_a_reopen_and_a_damaged_one_is_forgotten() {
        let dir = tempfile::tempdir().unwrap();
        {
            let s = Store::open(dir.path()).unwrap();
            s.insert_job(&job(1)).unwrap();
            s.put_tile(1, 2, 20, &[2; 48]).unwrap();
            s.put_tile(1, 0, 10, &[0; 48]).unwrap();
            s.put_tile(1, 1, 15, &[1; 48]).unwrap();
            // A second copy is ignored: the first stays.
            s.put_tile(1, 0, 99, &[9; 48]).unwrap();
            // A write whose row was never committed (killed in between).
            let mut f = std::fs::OpenOptions::new()
                .append(true)
                .open(dir.path().join("tiles/1.f32"))
                .unwrap();
            f.write_all(&[7; 100]).unwrap();
        }
        let s = Store::open(dir.path()).unwrap();
        assert_eq!(s.tile_list(1).unwrap(), vec![(0, 10), (1, 15), (2, 20)]);
        s.put_tile(1, 3, 30, &[3; 48]).unwrap();
        let r = replayed(&s, 1);
        assert_eq!(r.iter().map(|t| t.0).collect::<Vec<_>>(), [0, 1, 2, 3]);
        assert!(r.iter().all(|(t, b)| b.iter().all(|&x| x == *t as u8)));
        drop(s);
        // Damage tile 1's bytes on disk: it is dropped, the others stay.
        let path = dir.path().join("tiles/1.f32");
        let mut bytes = std::fs::read(&path).unwrap();
        bytes[48 * 2 + 5] ^= 0xff; // tile 1 was the third write (offset 96)
        std::fs::write(&path, bytes).unwrap();
        let s = Store::open(dir.path()).unwrap();
        assert_eq!(s.tile_list(1).unwrap(), vec![(0, 10), (2, 20), (3, 30)]);
        assert_eq!(replayed(&s, 1).len(), 3);
        // The job ends: its rows and its file go.
        s.finish_job(&StoredJob {
            state: JobState::Done,
            ..job(1)
        })
        .unwrap();
        assert!(s.tile_list(1).unwrap().is_empty());
        assert!(!path.exists());
    }

    #[test]
    fn a_span_of_segments_is_stored_once_replayed_once_and_forgotten_whole() {
        let dir = tempfile::tempdir().unwrap();
        {
            let s = Store::open(dir.path()).unwrap();
            s.insert_job(&job(1)).unwrap();
            s.put_tile(1, 0, 10, &[0; 48]).unwrap();
            s.put_segment_span(1, &[(1, 11), (2, 12), (3, 13)], &[&[5; 30], &[5; 40]])
                .unwrap();
            s.put_tile(1, 4, 14, &[4; 48]).unwrap();
        }
        let s = Store::open(dir.path()).unwrap();
        // The span is one row: its rays (11 + 12 + 13) on its first tile.
        assert_eq!(
            s.tile_list(1).unwrap(),
            vec![(0, 10), (1, 36), (2, 0), (3, 0), (4, 14)]
        );
        let mut seen = Vec::new();
        s.replay(1, |r| {
            seen.push(match r {
                Replayed::Floats { tile, bytes } => (tile, 1, bytes.len()),
                Replayed::Segments {
                    first,
                    tiles,
                    bytes,
                } => (first, tiles, bytes.len()),
            });
            Ok(())
        })
        .unwrap();
        assert_eq!(seen, [(0, 1, 48), (1, 3, 70), (4, 1, 48)]);
        // replay_tiles sees only the float tiles.
        assert_eq!(replayed(&s, 1).len(), 2);
        drop(s);
        // Damage the span's bytes (after tile 0's 48): all three tiles go.
        let path = dir.path().join("tiles/1.f32");
        let mut bytes = std::fs::read(&path).unwrap();
        bytes[48 + 69] ^= 1;
        std::fs::write(&path, bytes).unwrap();
        let s = Store::open(dir.path()).unwrap();
        assert_eq!(s.tile_list(1).unwrap(), vec![(0, 10), (4, 14)]);
    }

    #[test]
    fn a_span_is_a_row_for_each_run_of_consecutive_tiles_and_covers_them_all() {
        let dir = tempfile::tempdir().unwrap();
        let s = Store::open(dir.path()).unwrap();
        s.insert_job(&job(1)).unwrap();
        // Two runs: 10..13 and 20..22.
        let tiles: Vec<(u32, u64)> = [10, 11, 12, 20, 21].iter().map(|&t| (t, 1)).collect();
        s.put_segment_span(1, &tiles, &[&[7; 20]]).unwrap();
        let rows: i64 = s
            .inner
            .lock()
            .conn
            .query_row("SELECT COUNT(*) FROM tile_refs WHERE job = 1", [], |r| {
                r.get(0)
            })
            .unwrap();
        assert_eq!(rows, 2);
        // A float tile inside a run is stored already; one beside it is not.
        s.put_tiles(
            1,
            &[(11, 5, [1u8; 12]), (13, 6, [2u8; 12]), (22, 0, [3u8; 12])],
        )
        .unwrap();
        assert_eq!(
            s.tile_list(1).unwrap(),
            vec![
                (10, 3),
                (11, 0),
                (12, 0),
                (13, 6),
                (20, 2),
                (21, 0),
                (22, 0)
            ]
        );
        let mut seen = Vec::new();
        s.replay(1, |r| {
            seen.push(match r {
                Replayed::Floats { tile, .. } => (tile, 1),
                Replayed::Segments { first, tiles, .. } => (first, tiles),
            });
            Ok(())
        })
        .unwrap();
        // The span once, with all five tiles, and the two float tiles.
        assert_eq!(seen, [(10, 5), (13, 1), (22, 1)]);
    }

    /// Damaged rows that would make the store allocate what they say: a
    /// run of 2^30 tiles, a length of 2^40 bytes. Both are forgotten; the
    /// intact row stays.
    #[test]
    fn rows_claiming_huge_runs_or_lengths_are_forgotten_not_allocated() {
        let dir = tempfile::tempdir().unwrap();
        let s = Store::open(dir.path()).unwrap();
        s.insert_job(&job(1)).unwrap();
        s.put_segment_span(1, &[(0, 1), (1, 1)], &[&[3; 30]])
            .unwrap();
        s.put_segment_span(1, &[(5, 1)], &[&[4; 30]]).unwrap();
        s.put_tile(1, 9, 2, &[9; 12]).unwrap();
        {
            let c = &s.inner.lock().conn;
            c.execute("UPDATE tile_refs SET tiles = 1073741824 WHERE tile = 0", [])
                .unwrap();
            c.execute(
                "UPDATE tile_refs SET len = 1099511627776 WHERE tile = 5",
                [],
            )
            .unwrap();
        }
        assert_eq!(s.tile_list(1).unwrap(), vec![(9, 2)]);
    }

    #[test]
    fn a_span_stored_a_row_a_tile_by_an_earlier_version_replays_once() {
        let dir = tempfile::tempdir().unwrap();
        {
            let s = Store::open(dir.path()).unwrap();
            s.insert_job(&job(1)).unwrap();
            s.put_segment_span(1, &[(0, 1)], &[&[9; 30]]).unwrap();
            // As the version before runs: the same bytes, a row per tile,
            // no `tiles` column.
            let c = &s.inner.lock().conn;
            c.execute_batch(
                "INSERT INTO tile_refs (job, tile, rays, offset, len, crc, kind)
                     SELECT job, 1, rays, offset, len, crc, kind FROM tile_refs;
                 INSERT INTO tile_refs (job, tile, rays, offset, len, crc, kind)
                     SELECT job, 2, rays, offset, len, crc, kind FROM tile_refs WHERE tile = 0;
                 ALTER TABLE tile_refs DROP COLUMN tiles;",
            )
            .unwrap();
        }
        let s = Store::open(dir.path()).unwrap();
        assert_eq!(s.tile_list(1).unwrap(), vec![(0, 1), (1, 1), (2, 1)]);
        let mut seen = Vec::new();
        s.replay(1, |r| {
            if let Replayed::Segments {
                first,
                tiles,
                bytes,
            } = r
            {
                seen.push((first, tiles, bytes.len()));
            }
            Ok(())
        })
        .unwrap();
        assert_eq!(seen, [(0, 3, 30)]);
    }

    #[test]
    fn a_database_without_row_kinds_gets_them() {
        let dir = tempfile::tempdir().unwrap();
        {
            let c = Connection::open(dir.path().join("state.db")).unwrap();
            c.execute_batch(
                "CREATE TABLE tile_refs (job INTEGER NOT NULL, tile INTEGER NOT NULL,
                     rays INTEGER NOT NULL, offset INTEGER NOT NULL, len INTEGER NOT NULL,
                     crc INTEGER NOT NULL, PRIMARY KEY (job, tile));",
            )
            .unwrap();
        }
        let s = Store::open(dir.path()).unwrap();
        s.insert_job(&job(1)).unwrap();
        s.put_tile(1, 0, 1, &[1; 12]).unwrap();
        s.put_segment_span(1, &[(1, 2)], &[&[2; 9]]).unwrap();
        assert_eq!(s.tile_list(1).unwrap(), vec![(0, 1), (1, 2)]);
    }

    /// A data directory as a killed coordinator leaves it: the database and
    /// its write-ahead log with `n` jobs committed in it, copied while the
    /// store is still open (so the log is not checkpointed away).
    fn killed_with_jobs(n: u64) -> (tempfile::TempDir, tempfile::TempDir) {
        let live = tempfile::tempdir().unwrap();
        let s = Store::open(live.path()).unwrap();
        for id in 1..=n {
            s.insert_job(&job(id)).unwrap();
        }
        let copy = tempfile::tempdir().unwrap();
        for f in ["state.db", "state.db-wal"] {
            std::fs::copy(live.path().join(f), copy.path().join(f)).unwrap();
        }
        drop(s);
        (live, copy)
    }

    fn open_err(dir: &Path) -> String {
        match Store::open(dir) {
            Ok(_) => panic!("opened a damaged database"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn a_killed_coordinator_s_log_is_replayed() {
        let (_live, copy) = killed_with_jobs(5);
        assert!(
            std::fs::metadata(copy.path().join("state.db-wal"))
                .unwrap()
                .len()
                > 32
        );
        let s = Store::open(copy.path()).unwrap();
        assert_eq!(s.jobs().unwrap().len(), 5);
    }

    #[test]
    fn an_empty_database_beside_its_log_is_refused() {
        let (_live, copy) = killed_with_jobs(3);
        std::fs::write(copy.path().join("state.db"), b"").unwrap();
        let e = open_err(copy.path());
        assert!(
            e.contains("state.db is empty") && e.contains("refusing to start"),
            "{e}"
        );
        std::fs::remove_file(copy.path().join("state.db")).unwrap();
        assert!(open_err(copy.path()).contains("state.db is missing"));
        // The log is still there for whoever repairs it.
        assert!(copy.path().join("state.db-wal").exists());
    }

    #[test]
    fn a_damaged_log_is_refused_but_a_torn_last_frame_is_not() {
        let (_live, copy) = killed_with_jobs(40);
        let wal = copy.path().join("state.db-wal");
        let good = std::fs::read(&wal).unwrap();
        let page = u32::from_be_bytes(good[8..12].try_into().unwrap()) as usize;
        let frames = (good.len() - 32) / (24 + page);
        assert!(frames >= 3, "{frames} frames");

        // A byte of the first frame's page: the later frames would be lost.
        let mut bad = good.clone();
        bad[32 + 24 + 100] ^= 0x55;
        std::fs::write(&wal, &bad).unwrap();
        let e = open_err(copy.path());
        assert!(e.contains("damaged frame before frame 1"), "{e}");

        // The header: the whole log would be ignored.
        let mut bad = good.clone();
        bad[17] ^= 0x01;
        std::fs::write(&wal, &bad).unwrap();
        assert!(open_err(copy.path()).contains("header"));

        // The last frame torn (a power cut): its commit is lost, as
        // documented, and the rest opens.
        let mut torn = good.clone();
        let last = 32 + (frames - 1) * (24 + page);
        torn[last + 24 + 7] ^= 0x55;
        std::fs::write(&wal, &torn).unwrap();
        Store::open(copy.path()).unwrap();
    }

    #[test]
    fn an_unknown_job_state_is_refused_naming_the_job_and_the_value() {
        let dir = tempfile::tempdir().unwrap();
        let s = Store::open(dir.path()).unwrap();
        s.insert_job(&job(1)).unwrap();
        s.insert_job(&job(2)).unwrap();
        s.inner
            .lock()
            .conn
            .execute("UPDATE jobs SET state = 'paused' WHERE id = 2", [])
            .unwrap();
        let e = s.jobs().unwrap_err();
        assert!(matches!(e, FarmError::Damaged(_)), "{e:?}");
        let msg = e.to_string();
        assert!(msg.contains("job 2") && msg.contains("\"paused\""), "{msg}");
    }

    #[test]
    fn pruned_job_ids_are_never_given_again() {
        let dir = tempfile::tempdir().unwrap();
        let s = Store::open(dir.path()).unwrap();
        for id in 1..=4 {
            s.insert_job(&job(id)).unwrap();
        }
        s.delete_jobs(&[3, 4]).unwrap();
        drop(s);
        let s = Store::open(dir.path()).unwrap();
        assert_eq!(s.jobs().unwrap().len(), 2);
        assert_eq!(s.max_job_id().unwrap(), 4);
    }

    #[test]
    fn stray_tile_files_are_removed_on_open() {
        let dir = tempfile::tempdir().unwrap();
        drop(Store::open(dir.path()).unwrap());
        std::fs::write(dir.path().join("tiles/42.f32"), [1u8; 10]).unwrap();
        drop(Store::open(dir.path()).unwrap());
        assert!(!dir.path().join("tiles/42.f32").exists());
    }

    /// Records written by many threads at once (their ranges reserved
    /// under the lock, written outside it) never overlap: every span and
    /// tile comes back byte for byte, none dropped as damaged.
    #[test]
    fn records_written_at_once_from_many_threads_come_back_intact() {
        let dir = tempfile::tempdir().unwrap();
        let s = Store::open(dir.path()).unwrap();
        s.insert_job(&job(1)).unwrap();
        // Thread t writes 25 spans of two tiles, tiles 1000 t + 2 i and the
        // next, of 1 + (7 t + 13 i) % 300 bytes of value t + i, in two
        // pieces; and 25 float tiles of 48 bytes, tiles 100000 + 100 t + i.
        let bytes = |t: u32, i: u32| vec![(t + i) as u8; 1 + ((7 * t + 13 * i) % 300) as usize];
        std::thread::scope(|sc| {
            for t in 0..8u32 {
                let s = &s;
                sc.spawn(move || {
                    for i in 0..25u32 {
                        let b = bytes(t, i);
                        let (a, z) = b.split_at(b.len() / 2);
                        let first = 1000 * t + 2 * i;
                        s.put_segment_span(1, &[(first, 1), (first + 1, 1)], &[a, z])
                            .unwrap();
                        s.put_tile(1, 100_000 + 100 * t + i, 1, &[(t * i) as u8; 48])
                            .unwrap();
                    }
                });
            }
        });
        let (mut spans, mut floats) = (0, 0);
        s.replay(1, |r| {
            match r {
                Replayed::Segments {
                    first,
                    tiles,
                    bytes: b,
                } => {
                    let (t, i) = (first / 1000, first % 1000 / 2);
                    assert_eq!((tiles, b), (2, &bytes(t, i)[..]), "span at tile {first}");
                    spans += 1;
                }
                Replayed::Floats { tile, bytes: b } => {
                    let (t, i) = ((tile - 100_000) / 100, tile % 100);
                    assert_eq!(b, &[(t * i) as u8; 48][..], "tile {tile}");
                    floats += 1;
                }
            }
            Ok(())
        })
        .unwrap();
        assert_eq!((spans, floats), (200, 200));
    }
}
