//! The usage history: what the workers' CPU time, tiles and rays went to,
//! per job, per submitter and per worker, hour by hour, kept whatever
//! becomes of the jobs (docs/farm.md, "Usage history").
//!
//! - Each accepted result adds to its hour's row for (job, submitter,
//!   worker) ([`UsageKey`], [`UsageAgg`]): the CPU time the worker says its
//!   render threads spent on it (`TileHeader.cpu_micros`; a result without
//!   it counts as an unmeasured tile), its tiles and rays. A job of a
//!   sequence or of passes counts under the id its submitter sees.
//! - Each job's wall time, from its first lease to its end ([`JobWall`]).
//! - Both gather in memory ([`Usage`]) and go to the database in one
//!   transaction every [`FLUSH_EVERY`] (or once [`MAX_PENDING`] rows
//!   wait), and before every query: a coordinator killed loses at most the
//!   last few seconds of usage, never a job.
//! - Bounded: rows older than `--usage-retention` are deleted, and past
//!   `--max-usage-rows` the oldest hour's rows go first, checked before
//!   each new row is inserted (`store/usage.rs`).
//! - A query ([`UsageQuery`]: how far back, grouped by what) is answered
//!   by the database's own grouping: at most [`MAX_ANSWER_ROWS`] rows, the
//!   largest first, and the CPU time in at most [`MAX_BUCKETS`] buckets of
//!   whole hours for the chart; `usage/json.rs` gives it the one JSON
//!   shape of the monitor's API and of `trevi-submit usage`.

mod json;

pub use json::{core_seconds, cost, usage_json, usage_to_pb};

use std::collections::HashMap;
use std::sync::{Mutex, MutexGuard};
use std::time::Duration;

/// An hour in milliseconds: the usage history's grain.
pub const HOUR_MS: u64 = 3_600_000;
/// `--usage-retention` by default: 90 days.
pub const DEFAULT_USAGE_RETENTION: Duration = Duration::from_secs(90 * 86400);
/// The shortest `--usage-retention`: an hour (the grain).
pub const MIN_USAGE_RETENTION: Duration = Duration::from_secs(3600);
/// The longest `--usage-retention`: ten years.
pub const MAX_USAGE_RETENTION: Duration = Duration::from_secs(3650 * 86400);
/// `--max-usage-rows` by default: a million rows (about 100 MB of
/// database), 90 days of a farm with 460 (job, submitter, worker) rows an
/// hour.
pub const DEFAULT_MAX_USAGE_ROWS: u64 = 1_000_000;
/// The largest `--max-usage-rows`.
pub const MAX_USAGE_ROWS: u64 = 100_000_000;
/// How far back a query looks when it does not say: 7 days.
pub const DEFAULT_SINCE: Duration = Duration::from_secs(7 * 86400);
/// The shortest window a query may ask for.
pub const MIN_SINCE: Duration = Duration::from_secs(60);
/// The longest window a query may ask for (the longest retention).
pub const MAX_SINCE: Duration = MAX_USAGE_RETENTION;
/// Rows in one answer at most (the largest CPU time first).
pub const MAX_ANSWER_ROWS: usize = 10_000;
/// Buckets of the chart in one answer at most.
pub const MAX_BUCKETS: u64 = 500;
/// How often what was gathered goes to the database.
pub const FLUSH_EVERY: Duration = Duration::from_secs(5);
/// Rows gathered in memory at most before they go to the database at once.
pub const MAX_PENDING: usize = 4096;
/// The largest `--cost-per-core-hour` (and `cost=` of `/api/usage`).
pub const MAX_COST_PER_CORE_HOUR: f64 = 1e6;

/// A usage query or setting that makes no sense.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum UsageError {
    /// A window outside [`MIN_SINCE`]..=[`MAX_SINCE`], or not a duration.
    #[error("since: \"{0}\" is not a duration from 1m to 3650d (like 90m, 12h, 7d)")]
    Since(String),
    /// A grouping other than job, submitter or worker.
    #[error("by: \"{0}\" is not one of job, submitter, worker")]
    By(String),
    /// A cost that is negative, not a number, or past
    /// [`MAX_COST_PER_CORE_HOUR`].
    #[error("cost per core-hour: \"{0}\" is not a number from 0 to 1000000")]
    Cost(String),
    /// A `--usage-retention` outside its range.
    #[error("--usage-retention: \"{0}\" is not a duration from 1h to 3650d")]
    Retention(String),
}

/// What usage is grouped by.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UsageBy {
    /// The job, as its submitter sees it (a sequence is one).
    Job,
    /// Who submitted it (see [`submitter_label`]).
    Submitter,
    /// The worker that rendered it, by the name it registered with.
    Worker,
}

impl UsageBy {
    /// Reads `job`, `submitter` or `worker` (empty: `job`).
    pub fn parse(s: &str) -> Result<UsageBy, UsageError> {
        match s {
            "" | "job" => Ok(UsageBy::Job),
            "submitter" => Ok(UsageBy::Submitter),
            "worker" => Ok(UsageBy::Worker),
            other => Err(UsageError::By(other.chars().take(32).collect())),
        }
    }

    /// The name [`UsageBy::parse`] reads.
    pub fn name(self) -> &'static str {
        match self {
            UsageBy::Job => "job",
            UsageBy::Submitter => "submitter",
            UsageBy::Worker => "worker",
        }
    }
}

/// A usage query: the last `since`, grouped `by`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UsageQuery {
    /// How far back (within [`MIN_SINCE`]..=[`MAX_SINCE`]).
    pub since: Duration,
    /// What the rows are.
    pub by: UsageBy,
}

impl UsageQuery {
    /// The query of a `UsageRequest`: `since_s` seconds (0: [`DEFAULT_SINCE`])
    /// and `by`; both checked.
    pub fn new(since_s: u64, by: &str) -> Result<UsageQuery, UsageError> {
        let since = match since_s {
            0 => DEFAULT_SINCE,
            s => Duration::from_secs(s),
        };
        if !(MIN_SINCE..=MAX_SINCE).contains(&since) {
            return Err(UsageError::Since(format!("{since_s}s")));
        }
        Ok(UsageQuery {
            since,
            by: UsageBy::parse(by)?,
        })
    }

    /// The query of `GET /api/usage?since=7d&by=worker`: `since` in the
    /// farm's duration grammar (`None`: [`DEFAULT_SINCE`]).
    pub fn parse(since: Option<&str>, by: Option<&str>) -> Result<UsageQuery, UsageError> {
        let since_s = match since {
            None => 0,
            Some(s) => trevi_proto::duration::parse(s)
                .ok()
                .filter(|d| d.as_secs() > 0)
                .ok_or_else(|| UsageError::Since(s.chars().take(32).collect()))?
                .as_secs(),
        };
        UsageQuery::new(since_s, by.unwrap_or_default())
    }

    /// Where the window starts at `now_ms`: the start of the hour `since`
    /// ago (rows are per hour).
    pub fn since_ms(&self, now_ms: u64) -> u64 {
        let from = now_ms.saturating_sub(self.since.as_millis() as u64);
        from - from % HOUR_MS
    }

    /// The chart's bucket: whole hours, so that the window is at most
    /// [`MAX_BUCKETS`] of them.
    pub fn bucket_ms(&self) -> u64 {
        let hours = self.since.as_secs().div_ceil(3600) + 1;
        hours.div_ceil(MAX_BUCKETS).max(1) * HOUR_MS
    }
}

/// Reads a cost per core-hour (`--cost-per-core-hour`, `cost=`): a finite
/// number from 0 to [`MAX_COST_PER_CORE_HOUR`].
pub fn parse_cost(s: &str) -> Result<f64, UsageError> {
    s.trim()
        .parse::<f64>()
        .ok()
        .filter(|c| c.is_finite() && (0.0..=MAX_COST_PER_CORE_HOUR).contains(c))
        .ok_or_else(|| UsageError::Cost(s.chars().take(32).collect()))
}

/// Reads `--usage-retention`: within [`MIN_USAGE_RETENTION`] and
/// [`MAX_USAGE_RETENTION`].
pub fn parse_retention(s: &str) -> Result<Duration, UsageError> {
    trevi_proto::duration::parse(s)
        .ok()
        .filter(|d| (MIN_USAGE_RETENTION..=MAX_USAGE_RETENTION).contains(d))
        .ok_or_else(|| UsageError::Retention(s.trim().chars().take(32).collect()))
}

/// A submitter as the history shows it: the name of its token
/// (`--submit-tokens-file`), else its address, or `local` for a job
/// submitted in-process (`trevi-submit` rendering on its own machine).
pub fn submitter_label(submitter: &str) -> &str {
    if submitter.is_empty() {
        "local"
    } else {
        submitter
    }
}

/// A worker as the history shows it: the name it registered with, else
/// `worker ID`.
pub fn worker_label(name: &str, id: u64) -> String {
    if name.is_empty() {
        format!("worker {id}")
    } else {
        name.to_string()
    }
}

/// One row of the history: an hour, a job, a submitter, a worker.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct UsageKey {
    /// The hour's start, in milliseconds since the Unix epoch.
    pub hour_ms: u64,
    /// The job as its submitter sees it.
    pub job: u64,
    /// See [`submitter_label`].
    pub submitter: String,
    /// See [`worker_label`].
    pub worker: String,
}

/// What a row counts.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct UsageAgg {
    /// CPU time of the measured results, in microseconds.
    pub cpu_micros: u64,
    /// Tiles accepted.
    pub tiles: u64,
    /// Rays traced for them.
    pub rays: u64,
    /// Tiles whose worker did not say its CPU time (an older worker).
    pub unmeasured: u64,
}

impl UsageAgg {
    /// One accepted result of `tiles` tiles.
    pub fn result(cpu_micros: Option<u64>, tiles: u64, rays: u64) -> UsageAgg {
        UsageAgg {
            cpu_micros: cpu_micros.unwrap_or(0),
            tiles,
            rays,
            unmeasured: if cpu_micros.is_none() { tiles } else { 0 },
        }
    }

    /// Adds `o` (saturating).
    pub fn add(&mut self, o: &UsageAgg) {
        self.cpu_micros = self.cpu_micros.saturating_add(o.cpu_micros);
        self.tiles = self.tiles.saturating_add(o.tiles);
        self.rays = self.rays.saturating_add(o.rays);
        self.unmeasured = self.unmeasured.saturating_add(o.unmeasured);
    }
}

/// A job's wall time: from its first lease to its end (a sequence's from
/// its first frame's first lease to its last frame's end).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct JobWall {
    /// The job as its submitter sees it.
    pub job: u64,
    /// See [`submitter_label`].
    pub submitter: String,
    /// Its first lease, in milliseconds since the Unix epoch.
    pub started_ms: u64,
    /// Its end.
    pub ended_ms: u64,
}

/// What waits to go to the database.
#[derive(Debug, Default)]
pub struct Pending {
    /// The rows' additions.
    pub rows: HashMap<UsageKey, UsageAgg>,
    /// Jobs ended.
    pub walls: Vec<JobWall>,
}

impl Pending {
    /// Nothing waits.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty() && self.walls.is_empty()
    }
}

/// One row of an answer.
#[derive(Debug, Clone, PartialEq)]
pub struct UsageRow {
    /// The job id, the submitter or the worker.
    pub key: String,
    /// What it counts.
    pub agg: UsageAgg,
    /// For a job: its wall time once ended; for a submitter: the sum over
    /// its ended jobs; `None` for a worker.
    pub wall_ms: Option<u64>,
    /// The first hour with usage (its start, ms since the Unix epoch).
    pub first_ms: u64,
    /// The last hour with usage.
    pub last_ms: u64,
}

/// The answer to a [`UsageQuery`].
#[derive(Debug, Clone, PartialEq, Default)]
pub struct UsageReport {
    /// The largest CPU time first, at most [`MAX_ANSWER_ROWS`].
    pub rows: Vec<UsageRow>,
    /// More rows than [`MAX_ANSWER_ROWS`] matched.
    pub truncated: bool,
    /// (bucket start, CPU microseconds), oldest first; empty buckets left
    /// out.
    pub buckets: Vec<(u64, u64)>,
    /// The buckets' width in milliseconds (whole hours).
    pub bucket_ms: u64,
    /// Where the window starts (ms since the Unix epoch, a whole hour).
    pub since_ms: u64,
}

/// The usage gathered in memory, and (for a farm without a database) the
/// history itself, in an in-memory SQLite database with the same tables.
pub struct Usage {
    pending: Mutex<Pending>,
    /// Held for a whole flush, so that a query after a flush sees every
    /// row that was gathered before it.
    flushing: Mutex<()>,
    /// The history of a farm without a database (`None`: it is in the
    /// store's).
    pub(crate) memory: Option<Mutex<rusqlite::Connection>>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl Usage {
    /// The history in the store's database (`memory` `None`), or in
    /// `memory` (a connection with the history's tables).
    pub fn new(memory: Option<rusqlite::Connection>) -> Usage {
        Usage {
            pending: Mutex::default(),
            flushing: Mutex::default(),
            memory: memory.map(Mutex::new),
        }
    }

    /// Adds an accepted result to its row; whether enough rows wait to be
    /// flushed now ([`MAX_PENDING`]).
    pub fn add(&self, key: UsageKey, agg: UsageAgg) -> bool {
        let mut p = lock(&self.pending);
        p.rows.entry(key).or_default().add(&agg);
        p.rows.len() >= MAX_PENDING
    }

    /// Records a job's wall time.
    pub fn ended(&self, wall: JobWall) {
        lock(&self.pending).walls.push(wall);
    }

    /// Takes what waits, holding the flush lock until the guard is dropped.
    pub fn take(&self) -> (MutexGuard<'_, ()>, Pending) {
        let guard = lock(&self.flushing);
        let taken = std::mem::take(&mut *lock(&self.pending));
        (guard, taken)
    }

    /// Puts back what a failed flush took (the newer additions kept).
    pub fn put_back(&self, mut p: Pending) {
        let mut now = lock(&self.pending);
        for (k, a) in now.rows.drain() {
            p.rows.entry(k).or_default().add(&a);
        }
        p.walls.append(&mut now.walls);
        *now = p;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn queries_are_bounded_and_checked_before_the_work() {
        let q = UsageQuery::parse(Some("7d"), Some("worker")).unwrap();
        assert_eq!((q.since, q.by), (DEFAULT_SINCE, UsageBy::Worker));
        assert_eq!(UsageQuery::parse(None, None).unwrap().by, UsageBy::Job);
        for (since, by) in [
            (Some("0d"), None),
            (Some("59s"), None),
            (Some("3651d"), None),
            (Some("99999999999999999999d"), None),
            (Some("-1d"), None),
            (Some("7 days"), None),
            (Some(""), None),
            (None, Some("hostname")),
            (None, Some("JOB")),
        ] {
            assert!(UsageQuery::parse(since, by).is_err(), "{since:?} {by:?}");
        }
        assert!(UsageQuery::new(u64::MAX, "job").is_err());
        // A hostile value is not echoed whole.
        let e = UsageQuery::parse(None, Some(&"x".repeat(100_000))).unwrap_err();
        assert!(e.to_string().len() < 100, "{e}");
        for bad in ["-1", "NaN", "inf", "1e7", "", "abc"] {
            assert!(parse_cost(bad).is_err(), "{bad}");
        }
        assert_eq!(parse_cost("0.05"), Ok(0.05));
        assert!(parse_retention("30m").is_err());
        assert!(parse_retention("3651d").is_err());
        assert_eq!(
            parse_retention("90d"),
            Ok(DEFAULT_USAGE_RETENTION),
            "the default is in range"
        );
    }

    #[test]
    fn the_chart_has_at_most_max_buckets_of_whole_hours() {
        for since in [
            MIN_SINCE,
            DEFAULT_SINCE,
            MAX_SINCE,
            Duration::from_secs(500 * 3600),
        ] {
            let q = UsageQuery {
                since,
                by: UsageBy::Job,
            };
            let b = q.bucket_ms();
            assert_eq!(b % HOUR_MS, 0);
            let now = 1_800_000_000_000;
            let span = now - q.since_ms(now) + HOUR_MS;
            assert!(span.div_ceil(b) <= MAX_BUCKETS, "{since:?}: {b}");
        }
        let q = UsageQuery::new(0, "").unwrap();
        assert_eq!(
            q.since_ms(1000 * HOUR_MS + 5),
            1000 * HOUR_MS - 7 * 24 * HOUR_MS
        );
    }

    #[test]
    fn unmeasured_results_are_counted_apart() {
        let mut a = UsageAgg::result(Some(1_000), 2, 10);
        a.add(&UsageAgg::result(None, 3, 5));
        assert_eq!(
            a,
            UsageAgg {
                cpu_micros: 1_000,
                tiles: 5,
                rays: 15,
                unmeasured: 3
            }
        );
    }
}
