//! The usage history's tables (see [`crate::usage`]): `usage`, one row an
//! hour per (job, submitter, worker), and `usage_jobs`, each job's wall
//! time. Neither is touched by the jobs' retention; both are bounded by
//! their own (`--usage-retention`) and by `--max-usage-rows` each, checked
//! before a new row is inserted: the oldest hour's rows (the jobs that
//! ended first) are deleted to make room.
//!
//! The functions take a connection, so that a farm without a database
//! keeps the same tables in memory ([`crate::usage::Usage`]).

use super::{db_err, Store};
use crate::error::FarmError;
use crate::usage::{
    Pending, UsageAgg, UsageBy, UsageQuery, UsageReport, UsageRow, MAX_ANSWER_ROWS,
};
use rusqlite::{params, Connection, OptionalExtension};
use std::collections::HashMap;

/// Creates the usage tables if missing (a database of an earlier version
/// gets them empty).
pub fn usage_tables(conn: &Connection) -> rusqlite::Result<()> {
    conn.execute_batch(
        "CREATE TABLE IF NOT EXISTS usage (
             hour_ms INTEGER NOT NULL,
             job INTEGER NOT NULL,
             submitter TEXT NOT NULL,
             worker TEXT NOT NULL,
             cpu_micros INTEGER NOT NULL,
             tiles INTEGER NOT NULL,
             rays INTEGER NOT NULL,
             unmeasured INTEGER NOT NULL,
             PRIMARY KEY (hour_ms, job, submitter, worker)
         );
         CREATE TABLE IF NOT EXISTS usage_jobs (
             job INTEGER PRIMARY KEY,
             submitter TEXT NOT NULL,
             started_ms INTEGER NOT NULL,
             ended_ms INTEGER NOT NULL
         );
         CREATE INDEX IF NOT EXISTS usage_jobs_ended ON usage_jobs (ended_ms);",
    )
}

/// SQLite keeps signed 64-bit integers: counts are clamped to them.
fn int(v: u64) -> i64 {
    v.min(i64::MAX as u64) as i64
}

/// Adds `p` in one transaction: first deletes what is older than
/// `cutoff_ms`, then adds each row to its hour's (a new row only after
/// making room under `max_rows`); the same for the jobs' wall times.
/// Returns how many rows were deleted to make room.
pub fn add_usage(
    conn: &mut Connection,
    p: &Pending,
    max_rows: u64,
    cutoff_ms: u64,
) -> rusqlite::Result<u64> {
    let tx = conn.transaction()?;
    tx.execute("DELETE FROM usage WHERE hour_ms < ?1", [int(cutoff_ms)])?;
    tx.execute(
        "DELETE FROM usage_jobs WHERE ended_ms < ?1",
        [int(cutoff_ms)],
    )?;
    let max_rows = max_rows.max(1);
    let mut evicted = 0;
    let mut rows: u64 =
        tx.query_row("SELECT COUNT(*) FROM usage", [], |r| r.get::<_, i64>(0))? as u64;
    {
        let mut update = tx.prepare_cached(
            "UPDATE usage SET cpu_micros = cpu_micros + ?5, tiles = tiles + ?6,
                 rays = rays + ?7, unmeasured = unmeasured + ?8
             WHERE hour_ms = ?1 AND job = ?2 AND submitter = ?3 AND worker = ?4",
        )?;
        let mut insert = tx.prepare_cached(
            "INSERT INTO usage (hour_ms, job, submitter, worker, cpu_micros, tiles, rays,
                 unmeasured) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
        )?;
        let mut evict = tx
            .prepare_cached("DELETE FROM usage WHERE hour_ms = (SELECT MIN(hour_ms) FROM usage)")?;
        // Oldest first, so that a full table drops what came first.
        let mut keys: Vec<_> = p.rows.iter().collect();
        keys.sort_by_key(|(k, _)| k.hour_ms);
        for (k, a) in keys {
            let values = params![
                int(k.hour_ms),
                int(k.job),
                k.submitter,
                k.worker,
                int(a.cpu_micros),
                int(a.tiles),
                int(a.rays),
                int(a.unmeasured)
            ];
            if update.execute(values)? > 0 {
                continue;
            }
            // A new row: room first.
            while rows >= max_rows {
                let gone = evict.execute([])? as u64;
                if gone == 0 {
                    break;
                }
                rows = rows.saturating_sub(gone);
                evicted += gone;
            }
            insert.execute(values)?;
            rows += 1;
        }
    }
    {
        let mut jobs: u64 = tx.query_row("SELECT COUNT(*) FROM usage_jobs", [], |r| {
            r.get::<_, i64>(0)
        })? as u64;
        let mut known = tx.prepare_cached("SELECT 1 FROM usage_jobs WHERE job = ?1")?;
        let mut upsert = tx.prepare_cached(
            "INSERT INTO usage_jobs (job, submitter, started_ms, ended_ms) VALUES (?1, ?2, ?3, ?4)
             ON CONFLICT (job) DO UPDATE SET started_ms = MIN(started_ms, excluded.started_ms),
                 ended_ms = MAX(ended_ms, excluded.ended_ms)",
        )?;
        let mut evict = tx.prepare_cached(
            "DELETE FROM usage_jobs WHERE job =
                 (SELECT job FROM usage_jobs ORDER BY ended_ms, job LIMIT 1)",
        )?;
        for w in &p.walls {
            let new = known
                .query_row([int(w.job)], |_| Ok(()))
                .optional()?
                .is_none();
            if new {
                while jobs >= max_rows {
                    let gone = evict.execute([])? as u64;
                    if gone == 0 {
                        break;
                    }
                    jobs = jobs.saturating_sub(gone);
                    evicted += gone;
                }
                jobs += 1;
            }
            upsert.execute(params![
                int(w.job),
                w.submitter,
                int(w.started_ms),
                int(w.ended_ms.max(w.started_ms))
            ])?;
        }
    }
    tx.commit()?;
    Ok(evicted)
}

/// Answers `q` at `now_ms` from the tables (what is pending is not in
/// them: flush first).
pub fn query_usage(
    conn: &Connection,
    q: &UsageQuery,
    now_ms: u64,
) -> rusqlite::Result<UsageReport> {
    let since_ms = q.since_ms(now_ms);
    let key = match q.by {
        UsageBy::Job => "CAST(u.job AS TEXT)",
        UsageBy::Submitter => "u.submitter",
        UsageBy::Worker => "u.worker",
    };
    // A job's wall time joins its rows one to one (the job is the key).
    let wall = match q.by {
        UsageBy::Job => "MAX(j.ended_ms - j.started_ms)",
        _ => "NULL",
    };
    let sql = format!(
        "SELECT {key} AS k, SUM(u.cpu_micros), SUM(u.tiles), SUM(u.rays), SUM(u.unmeasured),
             MIN(u.hour_ms), MAX(u.hour_ms), {wall}
         FROM usage u LEFT JOIN usage_jobs j ON j.job = u.job
         WHERE u.hour_ms >= ?1
         GROUP BY k ORDER BY SUM(u.cpu_micros) DESC, k LIMIT ?2"
    );
    let mut stmt = conn.prepare(&sql)?;
    let mut rows: Vec<UsageRow> = stmt
        .query_map(params![int(since_ms), (MAX_ANSWER_ROWS + 1) as i64], |r| {
            let n = |i: usize| {
                r.get::<_, Option<i64>>(i)
                    .map(|v| v.unwrap_or(0).max(0) as u64)
            };
            Ok(UsageRow {
                key: r.get(0)?,
                agg: UsageAgg {
                    cpu_micros: n(1)?,
                    tiles: n(2)?,
                    rays: n(3)?,
                    unmeasured: n(4)?,
                },
                first_ms: n(5)?,
                last_ms: n(6)?,
                wall_ms: r.get::<_, Option<i64>>(7)?.map(|v| v.max(0) as u64),
            })
        })?
        .collect::<Result<_, _>>()?;
    let truncated = rows.len() > MAX_ANSWER_ROWS;
    rows.truncate(MAX_ANSWER_ROWS);
    if q.by == UsageBy::Submitter {
        // The sum of the walls of each submitter's jobs in the window, each
        // job once.
        let mut stmt = conn.prepare(
            "SELECT submitter, SUM(ended_ms - started_ms) FROM usage_jobs
             WHERE job IN (SELECT DISTINCT job FROM usage WHERE hour_ms >= ?1)
             GROUP BY submitter",
        )?;
        let walls: HashMap<String, i64> = stmt
            .query_map([int(since_ms)], |r| Ok((r.get(0)?, r.get(1)?)))?
            .collect::<Result<_, _>>()?;
        for row in &mut rows {
            row.wall_ms = walls.get(&row.key).map(|&w| w.max(0) as u64);
        }
    }
    // The chart: buckets counted from the window's start.
    let bucket_ms = q.bucket_ms();
    let mut stmt = conn.prepare(
        "SELECT ?1 + ((hour_ms - ?1) / ?2) * ?2 AS b, SUM(cpu_micros) FROM usage
         WHERE hour_ms >= ?1 GROUP BY b ORDER BY b LIMIT ?3",
    )?;
    let buckets = stmt
        .query_map(
            params![
                int(since_ms),
                int(bucket_ms),
                crate::usage::MAX_BUCKETS as i64
            ],
            |r| {
                Ok((
                    r.get::<_, i64>(0)?.max(0) as u64,
                    r.get::<_, i64>(1)?.max(0) as u64,
                ))
            },
        )?
        .collect::<Result<_, _>>()?;
    Ok(UsageReport {
        rows,
        truncated,
        buckets,
        bucket_ms,
        since_ms,
    })
}

impl Store {
    /// [`add_usage`] on the store's database.
    pub fn add_usage(&self, p: &Pending, max_rows: u64, cutoff_ms: u64) -> Result<u64, FarmError> {
        add_usage(&mut self.inner.lock().conn, p, max_rows, cutoff_ms).map_err(db_err)
    }

    /// [`query_usage`] on the store's database.
    pub fn query_usage(&self, q: &UsageQuery, now_ms: u64) -> Result<UsageReport, FarmError> {
        query_usage(&self.inner.lock().conn, q, now_ms).map_err(db_err)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::usage::{JobWall, UsageKey, HOUR_MS};

    fn key(hour: u64, job: u64, sub: &str, worker: &str) -> UsageKey {
        UsageKey {
            hour_ms: hour * HOUR_MS,
            job,
            submitter: sub.into(),
            worker: worker.into(),
        }
    }

    fn pending(rows: &[(UsageKey, u64)]) -> Pending {
        let mut p = Pending::default();
        for (k, cpu) in rows {
            p.rows
                .entry(k.clone())
                .or_default()
                .add(&UsageAgg::result(Some(*cpu), 1, 10));
        }
        p
    }

    fn count(conn: &Connection) -> i64 {
        conn.query_row("SELECT COUNT(*) FROM usage", [], |r| r.get(0))
            .unwrap()
    }

    #[test]
    fn rows_add_up_per_hour_and_group_by_what_is_asked() {
        let mut conn = Connection::open_in_memory().unwrap();
        usage_tables(&conn).unwrap();
        let now = 100 * HOUR_MS + 5;
        let p = pending(&[
            (key(99, 1, "10.0.0.1", "a"), 2_000_000),
            (key(99, 1, "10.0.0.1", "b"), 1_000_000),
            (key(100, 2, "local", "a"), 500_000),
        ]);
        add_usage(&mut conn, &p, 100, 0).unwrap();
        // The same rows again: added to, not duplicated.
        add_usage(&mut conn, &p, 100, 0).unwrap();
        assert_eq!(count(&conn), 3);
        let mut p = Pending::default();
        p.walls.push(JobWall {
            job: 1,
            submitter: "10.0.0.1".into(),
            started_ms: 99 * HOUR_MS,
            ended_ms: 99 * HOUR_MS + 60_000,
        });
        add_usage(&mut conn, &p, 100, 0).unwrap();
        let q = |by| UsageQuery {
            since: std::time::Duration::from_secs(7200),
            by,
        };
        let jobs = query_usage(&conn, &q(UsageBy::Job), now).unwrap();
        let got: Vec<_> = jobs
            .rows
            .iter()
            .map(|r| (r.key.as_str(), r.agg.cpu_micros, r.agg.tiles, r.wall_ms))
            .collect();
        assert_eq!(
            got,
            [("1", 6_000_000, 4, Some(60_000)), ("2", 1_000_000, 2, None)]
        );
        let workers = query_usage(&conn, &q(UsageBy::Worker), now).unwrap();
        let got: Vec<_> = workers
            .rows
            .iter()
            .map(|r| (r.key.as_str(), r.agg.cpu_micros))
            .collect();
        assert_eq!(got, [("a", 5_000_000), ("b", 2_000_000)]);
        let subs = query_usage(&conn, &q(UsageBy::Submitter), now).unwrap();
        assert_eq!(subs.rows[0].wall_ms, Some(60_000));
        assert_eq!(
            subs.buckets,
            [(99 * HOUR_MS, 6_000_000), (100 * HOUR_MS, 1_000_000)]
        );
        // A window that starts after hour 99 leaves it out.
        let late = UsageQuery {
            since: std::time::Duration::from_secs(60),
            by: UsageBy::Job,
        };
        let later = 100 * HOUR_MS + 120_000;
        assert_eq!(query_usage(&conn, &late, later).unwrap().rows.len(), 1);
    }

    #[test]
    fn the_row_cap_drops_the_oldest_hour_first_and_retention_the_old_rows() {
        let mut conn = Connection::open_in_memory().unwrap();
        usage_tables(&conn).unwrap();
        let rows: Vec<_> = (0..6).map(|h| (key(h, 1, "s", "w"), 1)).collect();
        let evicted = add_usage(&mut conn, &pending(&rows), 4, 0).unwrap();
        assert_eq!((count(&conn), evicted), (4, 2));
        let oldest: i64 = conn
            .query_row("SELECT MIN(hour_ms) FROM usage", [], |r| r.get(0))
            .unwrap();
        assert_eq!(oldest as u64, 2 * HOUR_MS);
        // Past the retention: gone before anything is added.
        add_usage(&mut conn, &Pending::default(), 4, 4 * HOUR_MS).unwrap();
        assert_eq!(count(&conn), 2);
    }
}
