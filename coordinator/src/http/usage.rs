//! The monitor's usage history: `GET /usage`, its page (one file,
//! `assets/usage.html`, embedded: a chart drawn by hand in SVG and the
//! table), and `GET /api/usage?since=7d&by=worker&cost=0.05`, the JSON it
//! draws ([`crate::usage::usage_json`], the shape `trevi-submit usage
//! --format json` prints).
//!
//! The query is checked before any work: at most [`MAX_QUERY_LEN`]
//! characters, only the parameters `since` (1m to 3650d), `by` (`job`,
//! `submitter`, `worker`) and `cost` (0 to 1000000), each at most once;
//! anything else is 400 naming it. It needs the submit token, as the
//! other API calls do.

use super::{ApiError, App};
use crate::usage::{parse_cost, usage_json, usage_to_pb, UsageQuery};
use axum::extract::{RawQuery, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::IntoResponse;
use axum::Json;

const USAGE_HTML: &str = include_str!("../../assets/usage.html");

/// The longest query string `/api/usage` reads.
pub const MAX_QUERY_LEN: usize = 256;

/// `GET /usage`: the page.
pub(super) async fn page() -> impl IntoResponse {
    (
        [
            (header::CONTENT_TYPE, "text/html; charset=utf-8"),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        USAGE_HTML,
    )
}

/// The parameters of `/api/usage`, checked.
#[derive(Debug, PartialEq)]
pub(super) struct Params {
    query: UsageQuery,
    cost: Option<f64>,
}

/// Reads `/api/usage`'s query string (see the module documentation).
pub(super) fn params(raw: Option<&str>) -> Result<Params, String> {
    let raw = raw.unwrap_or_default();
    if raw.len() > MAX_QUERY_LEN {
        return Err(format!(
            "the query string has {} characters, more than {MAX_QUERY_LEN}",
            raw.len()
        ));
    }
    let (mut since, mut by, mut cost) = (None, None, None);
    for pair in raw.split('&').filter(|p| !p.is_empty()) {
        let (name, value) = pair.split_once('=').unwrap_or((pair, ""));
        let slot = match name {
            "since" => &mut since,
            "by" => &mut by,
            "cost" => &mut cost,
            other => {
                let other: String = other.chars().take(32).collect();
                return Err(format!(
                    "unknown parameter \"{other}\" (since, by and cost are read)"
                ));
            }
        };
        if slot.replace(value).is_some() {
            return Err(format!("{name} is given twice"));
        }
    }
    let query = UsageQuery::parse(since, by).map_err(|e| e.to_string())?;
    let cost = cost
        .map(parse_cost)
        .transpose()
        .map_err(|e| e.to_string())?;
    Ok(Params { query, cost })
}

/// `GET /api/usage`.
pub(super) async fn api(
    State(app): State<App>,
    headers: HeaderMap,
    RawQuery(raw): RawQuery,
) -> Result<impl IntoResponse, ApiError> {
    app.need_submitter(&headers, "reading the usage history")?;
    let p = params(raw.as_deref()).map_err(|m| ApiError(StatusCode::BAD_REQUEST, m))?;
    let farm = app.farm.clone();
    let q = p.query;
    let report = tokio::task::spawn_blocking(move || farm.usage(&q))
        .await
        .map_err(|e| ApiError(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))??;
    Ok(Json(usage_json(&usage_to_pb(&report), p.query.by, p.cost)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::usage::{UsageBy, DEFAULT_SINCE};

    #[test]
    fn hostile_queries_are_refused_naming_what_is_wrong() {
        let p = params(Some("since=12h&by=worker&cost=0.05")).unwrap();
        assert_eq!(p.query.by, UsageBy::Worker);
        assert_eq!(p.query.since.as_secs(), 12 * 3600);
        assert_eq!(p.cost, Some(0.05));
        assert_eq!(params(None).unwrap().query.since, DEFAULT_SINCE);
        for (q, says) in [
            ("since=1s", "since"),
            ("since=3651d", "since"),
            ("by=hostname", "by"),
            ("cost=-1", "cost"),
            ("cost=NaN", "cost"),
            ("limit=5", "unknown parameter"),
            ("by=job&by=worker", "twice"),
        ] {
            let e = params(Some(q)).unwrap_err();
            assert!(e.contains(says), "{q}: {e}");
        }
        let long = format!("since=7d&by=job{}", "&".repeat(MAX_QUERY_LEN));
        assert!(params(Some(&long)).unwrap_err().contains("more than"));
    }
}
