//! The per-tile log: for every lease a job's tiles went out under, which
//! worker rendered it, when, how long, its CPU time (when the worker says),
//! its rays, or the error it failed with ([`LogEntry`]); read back with
//! each entry's retries counted ([`Store::tile_log`]).
//!
//! Bounded per job (the user's job: a sequence's frames and a progressive
//! job's passes log under it): at most [`LogBounds::entries`] entries and
//! [`LogBounds::error_bytes`] bytes of error text (each error is already at
//! most `--max-return-error-chars` characters). Past either, the oldest
//! entries (for the error bound: the oldest errors) are deleted, and how
//! many is kept beside the log ([`JobLog::dropped`],
//! [`JobLog::errors_dropped`]). The counters live in one row a job
//! (`tile_log_jobs`), so keeping the bound costs no scan. Deleted with the
//! job by retention.

use super::{db_err, Store};
use crate::error::FarmError;
use crate::scheduler::JobId;
use rusqlite::{params, Connection, OptionalExtension, Transaction};
use std::collections::BTreeMap;
use trevi_core::tile::Rect;

/// One lease of a job's tiles: rendered (no `error`), or failed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogEntry {
    /// When the coordinator took the result or saw the failure
    /// (milliseconds since the Unix epoch).
    pub at_ms: u64,
    /// The worker's id in the coordinator run that logged it, and its name.
    pub worker: u64,
    /// See `worker`.
    pub worker_name: String,
    /// For a frame of a sequence: the frame.
    pub frame: Option<u32>,
    /// For a pass of a progressive job: the pass (0 first).
    pub pass: Option<u32>,
    /// The pixels: one tile, or a span of adjacent tiles (`tiles` of them).
    pub rect: Rect,
    /// How many tiles `rect` covers.
    pub tiles: u32,
    /// The render time the worker reported (`TileHeader.render_micros`).
    pub render_micros: Option<u64>,
    /// The CPU time the worker reported, when it reports one.
    pub cpu_micros: Option<u64>,
    /// Rays traced.
    pub rays: u64,
    /// Failures of its tiles logged before it (filled when read back).
    pub retries: u32,
    /// Why it failed; `None`: rendered.
    pub error: Option<String>,
}

/// How big a job's log may grow (the coordinator's `--tile-log-entries`
/// and `--tile-log-error-kib`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LogBounds {
    /// Most entries.
    pub entries: u64,
    /// Most bytes of error text.
    pub error_bytes: u64,
}

/// Which entries [`Store::tile_log`] gives.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LogFilter {
    /// Only this frame's.
    pub frame: Option<u32>,
    /// Only those whose rectangle holds this pixel (x, y).
    pub pixel: Option<(u32, u32)>,
    /// Only failures.
    pub errors_only: bool,
}

/// Longest query string `GET /api/jobs/{id}/log` reads
/// ([`LogFilter::parse_query`]).
pub const MAX_LOG_QUERY_CHARS: usize = 128;

impl LogFilter {
    /// Reads the query of `GET /api/jobs/{id}/log`:
    /// `frame=N`, `x=X&y=Y` (the tile holding that pixel; both or
    /// neither), `errors=1` (also `errors`, `errors=true`). Refused, with
    /// what is wrong: a query over [`MAX_LOG_QUERY_CHARS`], another
    /// parameter, a number that is not a whole `u32`.
    pub fn parse_query(q: &str) -> Result<LogFilter, String> {
        if q.len() > MAX_LOG_QUERY_CHARS {
            return Err(format!(
                "the query is longer than {MAX_LOG_QUERY_CHARS} characters"
            ));
        }
        let mut f = LogFilter::default();
        let (mut x, mut y) = (None, None);
        for pair in q.split('&').filter(|p| !p.is_empty()) {
            let (k, v) = pair.split_once('=').unwrap_or((pair, ""));
            let num = |v: &str| {
                v.parse::<u32>()
                    .map_err(|_| format!("{k}={v}: not a whole number"))
            };
            match k {
                "frame" => f.frame = Some(num(v)?),
                "x" => x = Some(num(v)?),
                "y" => y = Some(num(v)?),
                "errors" => f.errors_only = matches!(v, "1" | "true" | ""),
                _ => {
                    return Err(format!(
                        "unknown parameter \"{k}\" (frame, x, y and errors are)"
                    ))
                }
            }
        }
        f.pixel = match (x, y) {
            (Some(x), Some(y)) => Some((x, y)),
            (None, None) => None,
            _ => return Err("a tile is named by both x and y".into()),
        };
        Ok(f)
    }
}

/// A job's log as read back.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct JobLog {
    /// The entries the filter kept, oldest first.
    pub entries: Vec<LogEntry>,
    /// Entries deleted to keep the entry bound.
    pub dropped: u64,
    /// Errors deleted to keep the error-text bound.
    pub errors_dropped: u64,
    /// Entries the filter kept but the reply left out, the oldest (past
    /// [`MAX_REPLY_BYTES`]).
    pub omitted: u64,
}

/// About how many bytes of entries one read gives (the newest), well under
/// the 4 MiB message limit of the clients.
pub const MAX_REPLY_BYTES: usize = 3 << 20;

/// Creates the log's tables (on every open; nothing to migrate).
pub(super) fn create(conn: &Connection) -> Result<(), FarmError> {
    conn.execute_batch(
        "CREATE TABLE IF NOT EXISTS tile_log (
             id INTEGER PRIMARY KEY,
             job INTEGER NOT NULL,
             at_ms INTEGER NOT NULL,
             worker INTEGER NOT NULL,
             worker_name TEXT NOT NULL,
             frame INTEGER,
             pass INTEGER,
             x INTEGER NOT NULL,
             y INTEGER NOT NULL,
             w INTEGER NOT NULL,
             h INTEGER NOT NULL,
             tiles INTEGER NOT NULL,
             render_us INTEGER,
             cpu_us INTEGER,
             rays INTEGER NOT NULL,
             error TEXT,
             error_bytes INTEGER NOT NULL DEFAULT 0
         );
         CREATE INDEX IF NOT EXISTS tile_log_by_job ON tile_log (job, id);
         CREATE TABLE IF NOT EXISTS tile_log_jobs (
             job INTEGER PRIMARY KEY,
             entries INTEGER NOT NULL,
             error_bytes INTEGER NOT NULL,
             dropped INTEGER NOT NULL DEFAULT 0,
             errors_dropped INTEGER NOT NULL DEFAULT 0
         );",
    )
    .map_err(db_err)
}

/// Deletes `job`'s log (retention).
pub(super) fn delete(tx: &Transaction, job: JobId) -> Result<(), FarmError> {
    tx.execute("DELETE FROM tile_log WHERE job = ?1", params![job as i64])
        .map_err(db_err)?;
    tx.execute(
        "DELETE FROM tile_log_jobs WHERE job = ?1",
        params![job as i64],
    )
    .map_err(db_err)?;
    Ok(())
}

/// Deletes the oldest of `job`'s entries (only errors with `errors`) while
/// `over(entries, error_bytes)` holds, and counts them.
fn trim(
    tx: &Transaction,
    job: JobId,
    errors: bool,
    over: impl Fn(u64, u64) -> bool,
) -> Result<(), FarmError> {
    let (mut entries, mut bytes): (u64, u64) = tx
        .query_row(
            "SELECT entries, error_bytes FROM tile_log_jobs WHERE job = ?1",
            params![job as i64],
            |r| Ok((r.get::<_, i64>(0)? as u64, r.get::<_, i64>(1)? as u64)),
        )
        .map_err(db_err)?;
    if !over(entries, bytes) {
        return Ok(());
    }
    let sql = if errors {
        "SELECT id, error_bytes FROM tile_log WHERE job = ?1 AND error IS NOT NULL ORDER BY id"
    } else {
        "SELECT id, error_bytes FROM tile_log WHERE job = ?1 ORDER BY id"
    };
    let mut doomed = Vec::new();
    let (mut dropped, mut errors_dropped) = (0i64, 0i64);
    {
        let mut q = tx.prepare(sql).map_err(db_err)?;
        let mut rows = q.query(params![job as i64]).map_err(db_err)?;
        while over(entries, bytes) {
            let Some(row) = rows.next().map_err(db_err)? else {
                break;
            };
            let (id, b): (i64, i64) = (row.get(0).map_err(db_err)?, row.get(1).map_err(db_err)?);
            doomed.push(id);
            entries -= 1;
            bytes = bytes.saturating_sub(b as u64);
            if errors || b > 0 {
                errors_dropped += 1;
            }
            if !errors {
                dropped += 1;
            }
        }
    }
    let mut del = tx
        .prepare("DELETE FROM tile_log WHERE id = ?1")
        .map_err(db_err)?;
    for id in doomed {
        del.execute(params![id]).map_err(db_err)?;
    }
    tx.execute(
        "UPDATE tile_log_jobs SET entries = ?2, error_bytes = ?3,
             dropped = dropped + ?4, errors_dropped = errors_dropped + ?5
         WHERE job = ?1",
        params![
            job as i64,
            entries as i64,
            bytes as i64,
            dropped,
            errors_dropped
        ],
    )
    .map_err(db_err)?;
    Ok(())
}

impl Store {
    /// Adds `entries` to `job`'s log in one transaction, then keeps it
    /// within `bounds` (the oldest entries, then the oldest errors, go).
    pub fn log_append(
        &self,
        job: JobId,
        entries: &[LogEntry],
        bounds: LogBounds,
    ) -> Result<(), FarmError> {
        if entries.is_empty() {
            return Ok(());
        }
        let mut guard = self.inner.lock();
        let tx = guard.conn.transaction().map_err(db_err)?;
        {
            let mut ins = tx
                .prepare(
                    "INSERT INTO tile_log (job, at_ms, worker, worker_name, frame, pass,
                         x, y, w, h, tiles, render_us, cpu_us, rays, error, error_bytes)
                     VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14,
                         ?15, ?16)",
                )
                .map_err(db_err)?;
            let mut count = tx
                .prepare(
                    "INSERT INTO tile_log_jobs (job, entries, error_bytes) VALUES (?1, 1, ?2)
                     ON CONFLICT(job) DO UPDATE SET entries = entries + 1,
                         error_bytes = error_bytes + excluded.error_bytes",
                )
                .map_err(db_err)?;
            for e in entries {
                let bytes = e.error.as_ref().map_or(0, |t| t.len()) as i64;
                ins.execute(params![
                    job as i64,
                    e.at_ms as i64,
                    e.worker as i64,
                    e.worker_name,
                    e.frame,
                    e.pass,
                    e.rect.x,
                    e.rect.y,
                    e.rect.w,
                    e.rect.h,
                    e.tiles,
                    e.render_micros.map(|v| v.min(i64::MAX as u64) as i64),
                    e.cpu_micros.map(|v| v.min(i64::MAX as u64) as i64),
                    e.rays.min(i64::MAX as u64) as i64,
                    e.error,
                    bytes,
                ])
                .map_err(db_err)?;
                count.execute(params![job as i64, bytes]).map_err(db_err)?;
            }
        }
        trim(&tx, job, false, |n, _| n > bounds.entries)?;
        trim(&tx, job, true, |_, b| b > bounds.error_bytes)?;
        tx.commit().map_err(db_err)
    }

    /// `job`'s log as `filter` picks it, oldest first, each entry with its
    /// retries: the failures logged before it of the tiles it covers. At
    /// most about [`MAX_REPLY_BYTES`] of entries, the newest.
    pub fn tile_log(&self, job: JobId, filter: &LogFilter) -> Result<JobLog, FarmError> {
        let guard = self.inner.lock();
        let (dropped, errors_dropped) = guard
            .conn
            .query_row(
                "SELECT dropped, errors_dropped FROM tile_log_jobs WHERE job = ?1",
                params![job as i64],
                |r| Ok((r.get::<_, i64>(0)? as u64, r.get::<_, i64>(1)? as u64)),
            )
            .optional()
            .map_err(db_err)?
            .unwrap_or((0, 0));
        let mut q = guard
            .conn
            .prepare(
                "SELECT id, at_ms, worker, worker_name, frame, pass, x, y, w, h, tiles,
                     render_us, cpu_us, rays, error
                 FROM tile_log WHERE job = ?1 ORDER BY id",
            )
            .map_err(db_err)?;
        let all = q
            .query_map(params![job as i64], |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    LogEntry {
                        at_ms: r.get::<_, i64>(1)? as u64,
                        worker: r.get::<_, i64>(2)? as u64,
                        worker_name: r.get(3)?,
                        frame: r.get(4)?,
                        pass: r.get(5)?,
                        rect: Rect::new(r.get(6)?, r.get(7)?, r.get(8)?, r.get(9)?),
                        tiles: r.get(10)?,
                        render_micros: r.get::<_, Option<i64>>(11)?.map(|v| v as u64),
                        cpu_micros: r.get::<_, Option<i64>>(12)?.map(|v| v as u64),
                        rays: r.get::<_, i64>(13)? as u64,
                        retries: 0,
                        error: r.get(14)?,
                    },
                ))
            })
            .map_err(db_err)?
            .collect::<Result<Vec<_>, _>>()
            .map_err(db_err)?;
        drop(q);
        drop(guard);
        Ok(pick(all, filter, dropped, errors_dropped))
    }
}

/// Where a tile's entries are counted together: (frame, pass, y, x).
type TileKey = (Option<u32>, Option<u32>, u32, u32);

/// The entries of `all` (id, entry; by id) that `filter` keeps, with their
/// retries, cut to the newest [`MAX_REPLY_BYTES`].
fn pick(all: Vec<(i64, LogEntry)>, filter: &LogFilter, dropped: u64, errors: u64) -> JobLog {
    // Failures by (frame, pass, y, x) of their tile, with their ids.
    let mut failed: BTreeMap<TileKey, Vec<i64>> = BTreeMap::new();
    for (id, e) in &all {
        if e.error.is_some() {
            failed
                .entry((e.frame, e.pass, e.rect.y, e.rect.x))
                .or_default()
                .push(*id);
        }
    }
    let mut kept: Vec<LogEntry> = Vec::new();
    for (id, mut e) in all {
        let keep = filter.frame.is_none_or(|f| e.frame == Some(f))
            && filter.pixel.is_none_or(|(x, y)| {
                x >= e.rect.x && y >= e.rect.y && x - e.rect.x < e.rect.w && y - e.rect.y < e.rect.h
            })
            && (!filter.errors_only || e.error.is_some());
        if !keep {
            continue;
        }
        let r = e.rect;
        let from = (e.frame, e.pass, r.y, r.x);
        let to = (e.frame, e.pass, r.y.saturating_add(r.h), 0);
        e.retries = failed
            .range(from..to)
            .filter(|((_, _, _, x), _)| *x >= r.x && *x < r.x.saturating_add(r.w))
            .map(|(_, ids)| ids.iter().filter(|&&f| f < id).count() as u32)
            .sum();
        kept.push(e);
    }
    let mut bytes = 0usize;
    let mut start = kept.len();
    while start > 0 {
        let e = &kept[start - 1];
        bytes += 96 + e.worker_name.len() + e.error.as_ref().map_or(0, String::len);
        if bytes > MAX_REPLY_BYTES {
            break;
        }
        start -= 1;
    }
    JobLog {
        entries: kept.split_off(start),
        dropped,
        errors_dropped: errors,
        omitted: start as u64,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(x: u32, error: Option<&str>) -> LogEntry {
        LogEntry {
            at_ms: 1,
            worker: 7,
            worker_name: "w".into(),
            frame: None,
            pass: None,
            rect: Rect::new(x, 0, 4, 4),
            tiles: 1,
            render_micros: Some(10),
            cpu_micros: None,
            rays: 3,
            retries: 0,
            error: error.map(str::to_string),
        }
    }

    const WIDE: LogBounds = LogBounds {
        entries: 1000,
        error_bytes: 1 << 20,
    };

    #[test]
    fn entries_come_back_with_their_retries_and_filters() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let log = [
            entry(0, Some("boom")),
            entry(0, Some("bang")),
            entry(4, None),
            entry(0, None),
        ];
        store.log_append(3, &log, WIDE).unwrap();
        // A span over both tiles afterwards counts both failures.
        let span = LogEntry {
            rect: Rect::new(0, 0, 8, 4),
            tiles: 2,
            ..entry(0, None)
        };
        store.log_append(3, &[span], WIDE).unwrap();
        let all = store.tile_log(3, &LogFilter::default()).unwrap();
        let retries: Vec<u32> = all.entries.iter().map(|e| e.retries).collect();
        assert_eq!(retries, [0, 1, 0, 2, 2]);
        let tile = LogFilter {
            pixel: Some((5, 3)),
            ..LogFilter::default()
        };
        assert_eq!(store.tile_log(3, &tile).unwrap().entries.len(), 2);
        let errors = LogFilter {
            errors_only: true,
            ..LogFilter::default()
        };
        let e = store.tile_log(3, &errors).unwrap().entries;
        assert_eq!(e[1].error.as_deref(), Some("bang"));
        assert_eq!(e.len(), 2);
        assert!(store.tile_log(4, &errors).unwrap().entries.is_empty());
    }

    /// The bytes of the error texts a log holds.
    fn error_bytes(log: &JobLog) -> usize {
        log.entries
            .iter()
            .filter_map(|e| e.error.as_ref())
            .map(String::len)
            .sum()
    }

    #[test]
    fn a_job_s_log_keeps_its_bounds_dropping_the_oldest_and_counting() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let tight = LogBounds {
            entries: 5,
            error_bytes: 250,
        };
        let long = "x".repeat(100);
        for i in 0..8 {
            let mut e = entry(i * 4, (i % 2 == 0).then_some(long.as_str()));
            e.rays = i.into();
            store.log_append(9, &[e], tight).unwrap();
        }
        let log = store.tile_log(9, &LogFilter::default()).unwrap();
        // 8 entries, 4 of them errors of 100 bytes: the errors of 0 and 2
        // went for the error bound, 1 for the entry bound.
        let rays: Vec<u64> = log.entries.iter().map(|e| e.rays).collect();
        assert_eq!(rays, [3, 4, 5, 6, 7]);
        assert_eq!((log.dropped, log.errors_dropped), (1, 2));
        let bytes = error_bytes(&log);
        assert!(bytes <= 250, "{bytes}");
        // Three more errors: the error bound drops the oldest errors.
        for i in 8..11 {
            store
                .log_append(9, &[entry(i * 4, Some(long.as_str()))], tight)
                .unwrap();
        }
        let log = store.tile_log(9, &LogFilter::default()).unwrap();
        let bytes = error_bytes(&log);
        assert!(bytes <= 250, "{bytes}");
        assert!(log.entries.len() <= 5);
        assert!(log.errors_dropped >= 4, "{log:?}");
        // Retention takes the log with the job.
        store.delete_jobs(&[9]).unwrap();
        let gone = store.tile_log(9, &LogFilter::default()).unwrap();
        assert_eq!(gone, JobLog::default());
    }
}
