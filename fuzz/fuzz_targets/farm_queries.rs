//! The job-control queries a user (or anyone reaching the monitor) types,
//! on arbitrary text: the tile log's query (`GET /api/jobs/{id}/log?…`,
//! `LogFilter::parse_query`), the usage query (`GET /api/usage?since=…&by=…`
//! and `trevi-submit usage --since/--by`, `UsageQuery::parse`), the cost
//! per core-hour (`--cost-per-core-hour`, `cost=`), the usage retention
//! (`--usage-retention`), the worker named by `unblock` and the named
//! submit tokens file (`--submit-tokens-file`). Each gives a
//! value within its documented bounds or an error, never a panic, and each
//! costs one pass over its (bounded) input.
//!
//! The first byte picks the parser; the rest is the text.
#![no_main]
use libfuzzer_sys::fuzz_target;
use trevi_coordinator::auth::{parse_named_tokens, MAX_NAMED_TOKENS, MAX_TOKEN_NAME_CHARS};
use trevi_coordinator::grpc::{check_unblock_worker, MAX_UNBLOCK_WORKER_CHARS};
use trevi_coordinator::store::{LogFilter, MAX_LOG_QUERY_CHARS};
use trevi_coordinator::usage::{
    parse_cost, parse_retention, UsageQuery, MAX_COST_PER_CORE_HOUR, MAX_SINCE,
    MAX_USAGE_RETENTION, MIN_SINCE, MIN_USAGE_RETENTION,
};

fuzz_target!(|data: &[u8]| {
    let Some((&pick, rest)) = data.split_first() else {
        return;
    };
    let Ok(s) = std::str::from_utf8(rest) else {
        return;
    };
    match pick % 6 {
        0 => {
            if LogFilter::parse_query(s).is_ok() {
                assert!(s.len() <= MAX_LOG_QUERY_CHARS);
            }
        }
        1 => {
            // "since" and "by" split at the first newline, as two fields.
            let (since, by) = s.split_once('\n').unwrap_or((s, ""));
            if let Ok(q) = UsageQuery::parse(Some(since), Some(by)) {
                assert!((MIN_SINCE..=MAX_SINCE).contains(&q.since), "{s:?}");
                assert!(q.bucket_ms() >= 3_600_000);
            }
        }
        2 => {
            if let Ok(c) = parse_cost(s) {
                assert!(c.is_finite() && (0.0..=MAX_COST_PER_CORE_HOUR).contains(&c));
            }
        }
        3 => {
            if let Ok(d) = parse_retention(s) {
                assert!((MIN_USAGE_RETENTION..=MAX_USAGE_RETENTION).contains(&d));
            }
        }
        4 => {
            if let Ok(tokens) = parse_named_tokens(s) {
                assert!(tokens.len() <= MAX_NAMED_TOKENS);
                for t in &tokens {
                    assert!(!t.name.is_empty() && t.name.chars().count() <= MAX_TOKEN_NAME_CHARS);
                    assert!(!t.token.is_empty() && t.token.chars().all(|c| c.is_ascii_graphic()));
                }
            }
        }
        _ => {
            if let Ok(who) = check_unblock_worker(s) {
                assert!(!who.is_empty() && who.chars().count() <= MAX_UNBLOCK_WORKER_CHARS);
            }
        }
    }
});
