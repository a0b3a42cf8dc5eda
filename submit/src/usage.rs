//! `trevi-submit usage`: the farm's usage history (`Jobs.Usage`, see the
//! coordinator's `usage.rs`) as a table for people, or CSV or JSON for
//! programs; its flags' bounds are the coordinator's, checked here before
//! anything is sent.

use std::fmt::Write as _;
use std::time::Duration;
use trevi_coordinator::usage::{self as farm_usage, core_seconds, cost, UsageBy};
use trevi_proto::pb;

/// `--by`.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum By {
    /// One row per job (a sequence is one).
    Job,
    /// One row per submitter (its address; "local" for renders on the
    /// submitter's own machine).
    Submitter,
    /// One row per worker, by the name it registered with.
    Worker,
}

impl By {
    fn farm(self) -> UsageBy {
        match self {
            By::Job => UsageBy::Job,
            By::Submitter => UsageBy::Submitter,
            By::Worker => UsageBy::Worker,
        }
    }

    /// The name `UsageRequest.by` takes.
    pub fn name(self) -> &'static str {
        self.farm().name()
    }
}

/// `--format`.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// Aligned columns with a header.
    Table,
    /// Comma-separated values with a header line.
    Csv,
    /// One JSON object (the shape of the monitor's `/api/usage`).
    Json,
}

/// Reads `--since`: a duration from 1m to 3650d (the coordinator's bounds).
pub fn parse_since(s: &str) -> Result<Duration, String> {
    trevi_proto::duration::parse(s)
        .ok()
        .filter(|d| (farm_usage::MIN_SINCE..=farm_usage::MAX_SINCE).contains(d))
        .ok_or_else(|| format!("\"{s}\" is not a duration from 1m to 3650d (like 90m, 12h, 7d)"))
}

/// Reads `--cost-per-core-hour` (the coordinator's bounds).
pub fn parse_cost(s: &str) -> Result<f64, String> {
    farm_usage::parse_cost(s).map_err(|e| e.to_string())
}

/// A CSV field: quoted when it holds a comma, a quote or a line break.
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// A key as a table shows it: control characters replaced (a worker's
/// name comes from the network), at most 40 characters.
fn table_key(s: &str) -> String {
    let mut k: String = s
        .chars()
        .map(|c| if c.is_control() { '?' } else { c })
        .take(40)
        .collect();
    if s.chars().count() > 40 {
        k.pop();
        k.push('…');
    }
    k
}

/// `r` (grouped `by`) in `format`, with a cost column at `per_core_hour`.
pub fn render(r: &pb::UsageResponse, by: By, format: Format, per_core_hour: Option<f64>) -> String {
    match format {
        Format::Json => {
            let v = farm_usage::usage_json(r, by.farm(), per_core_hour);
            format!("{v}\n")
        }
        Format::Csv => {
            let mut out = format!(
                "{},core_seconds,tiles,rays,wall_seconds,unmeasured_tiles,first_ms,last_ms",
                by.name()
            );
            if per_core_hour.is_some() {
                out.push_str(",cost");
            }
            out.push('\n');
            for row in &r.rows {
                let wall = row
                    .wall_ms
                    .map_or(String::new(), |w| format!("{:.3}", w as f64 / 1e3));
                let _ = write!(
                    out,
                    "{},{:.6},{},{},{},{},{},{}",
                    csv_field(&row.key),
                    core_seconds(row.cpu_micros),
                    row.tiles,
                    row.rays,
                    wall,
                    row.unmeasured_tiles,
                    row.first_ms,
                    row.last_ms
                );
                if let Some(c) = per_core_hour {
                    let _ = write!(out, ",{:.6}", cost(row.cpu_micros, c));
                }
                out.push('\n');
            }
            out
        }
        Format::Table => {
            let mut out = format!(
                "{:<40} {:>12} {:>10} {:>8} {:>14} {:>10}",
                by.name().to_uppercase(),
                "CORE-SECONDS",
                "CORE-HOURS",
                "TILES",
                "RAYS",
                "WALL"
            );
            if per_core_hour.is_some() {
                let _ = write!(out, " {:>12}", "COST");
            }
            out.push('\n');
            for row in &r.rows {
                let secs = core_seconds(row.cpu_micros);
                let wall = row
                    .wall_ms
                    .map_or("-".to_string(), |w| format!("{:.1}s", w as f64 / 1e3));
                let _ = write!(
                    out,
                    "{:<40} {:>12.2} {:>10.4} {:>8} {:>14} {:>10}",
                    table_key(&row.key),
                    secs,
                    secs / 3600.0,
                    row.tiles,
                    row.rays,
                    wall
                );
                if let Some(c) = per_core_hour {
                    let _ = write!(out, " {:>12.4}", cost(row.cpu_micros, c));
                }
                out.push('\n');
            }
            let unmeasured: u64 = r.rows.iter().map(|x| x.unmeasured_tiles).sum();
            if unmeasured > 0 {
                let _ = writeln!(
                    out,
                    "({unmeasured} tiles from workers too old to measure their CPU time are \
                     counted without it)"
                );
            }
            if r.truncated {
                let _ = writeln!(
                    out,
                    "(only the {} largest rows are shown)",
                    farm_usage::MAX_ANSWER_ROWS
                );
            }
            out
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> pb::UsageResponse {
        pb::UsageResponse {
            rows: vec![
                pb::UsageRow {
                    key: "render,01".into(),
                    cpu_micros: 3_600_000_000,
                    tiles: 10,
                    rays: 1000,
                    wall_ms: Some(1500),
                    unmeasured_tiles: 0,
                    first_ms: 0,
                    last_ms: 3_600_000,
                },
                pb::UsageRow {
                    key: "b\u{1b}[31m".into(),
                    cpu_micros: 1_000_000,
                    tiles: 1,
                    rays: 5,
                    wall_ms: None,
                    unmeasured_tiles: 1,
                    first_ms: 0,
                    last_ms: 0,
                },
            ],
            ..Default::default()
        }
    }

    #[test]
    fn csv_quotes_what_needs_it_and_adds_the_cost() {
        let out = render(&sample(), By::Worker, Format::Csv, Some(2.0));
        let lines: Vec<&str> = out.lines().collect();
        assert_eq!(
            lines[0],
            "worker,core_seconds,tiles,rays,wall_seconds,unmeasured_tiles,first_ms,last_ms,cost"
        );
        assert_eq!(
            lines[1],
            "\"render,01\",3600.000000,10,1000,1.500,0,0,3600000,2.000000"
        );
        assert!(lines[2].ends_with(",1,0,0,0.000556"), "{}", lines[2]);
    }

    #[test]
    fn the_table_shows_no_control_characters() {
        let out = render(&sample(), By::Job, Format::Table, None);
        assert!(!out.contains('\u{1b}'), "{out}");
        assert!(out.starts_with("JOB "), "{out}");
        assert!(out.contains("1 tiles from workers too old"), "{out}");
    }

    #[test]
    fn flags_are_bounded() {
        for bad in ["0s", "59s", "3651d", "1w", "-1d", ""] {
            assert!(parse_since(bad).is_err(), "{bad}");
        }
        assert_eq!(parse_since("7d"), Ok(Duration::from_secs(7 * 86400)));
        for bad in ["-0.1", "NaN", "inf", "1000001"] {
            assert!(parse_cost(bad).is_err(), "{bad}");
        }
    }
}
