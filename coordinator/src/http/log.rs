//! The monitor's blocklists and tile log (docs/farm.md, "Running a farm"):
//!
//! - `GET /api/jobs/{id}/log[?frame=N][&x=X&y=Y][&errors=1]`: the job's tile
//!   log as JSON (`{"entries": [...], "dropped", "errors_dropped",
//!   "omitted"}`), as `trevi-submit log` prints it: `x`, `y` pick the tile
//!   holding that pixel (what a click on the preview sends), `errors=1`
//!   only failures. A query longer than [`MAX_LOG_QUERY_CHARS`](crate::store::MAX_LOG_QUERY_CHARS), or with
//!   another parameter, is refused (400).
//! - `POST /api/jobs/{id}/unblock` (body `{"worker": "ID or name"}`): as
//!   `trevi-submit unblock ID WORKER`; the job as `/api/state` shows it.
//!
//! A job's blocked workers are in its card of `/api/state` ([`BlockedView`]).

use super::{ApiError, App, JobView, SameSite};
use crate::grpc::{check_unblock_worker, MAX_UNBLOCK_WORKER_CHARS};
use crate::scheduler::Blocked;
use crate::store::{JobLog, LogFilter};
use axum::extract::{Path, State};
use axum::http::{HeaderMap, StatusCode, Uri};
use axum::Json;
use serde::{Deserialize, Serialize};

/// A worker kept from a job, in its card.
#[derive(Serialize)]
pub(super) struct BlockedView {
    /// `null` for a block kept across a restart not claimed since.
    worker_id: Option<u64>,
    name: String,
    failures: u32,
    last_error: String,
    frame: Option<u32>,
}

impl From<&Blocked> for BlockedView {
    fn from(b: &Blocked) -> Self {
        BlockedView {
            worker_id: b.worker,
            name: b.name.clone(),
            failures: b.failures,
            last_error: b.last_error.clone(),
            frame: b.frame,
        }
    }
}

#[derive(Serialize)]
struct EntryView {
    at_ms: u64,
    worker_id: u64,
    worker_name: String,
    frame: Option<u32>,
    pass: Option<u32>,
    x: u32,
    y: u32,
    w: u32,
    h: u32,
    tiles: u32,
    render_micros: Option<u64>,
    cpu_micros: Option<u64>,
    rays: u64,
    retries: u32,
    error: Option<String>,
}

#[derive(Serialize)]
pub(super) struct LogView {
    entries: Vec<EntryView>,
    dropped: u64,
    errors_dropped: u64,
    omitted: u64,
}

impl From<JobLog> for LogView {
    fn from(log: JobLog) -> Self {
        LogView {
            entries: log
                .entries
                .into_iter()
                .map(|e| EntryView {
                    at_ms: e.at_ms,
                    worker_id: e.worker,
                    worker_name: e.worker_name,
                    frame: e.frame,
                    pass: e.pass,
                    x: e.rect.x,
                    y: e.rect.y,
                    w: e.rect.w,
                    h: e.rect.h,
                    tiles: e.tiles,
                    render_micros: e.render_micros,
                    cpu_micros: e.cpu_micros,
                    rays: e.rays,
                    retries: e.retries,
                    error: e.error,
                })
                .collect(),
            dropped: log.dropped,
            errors_dropped: log.errors_dropped,
            omitted: log.omitted,
        }
    }
}

fn bad(why: String) -> ApiError {
    ApiError(StatusCode::BAD_REQUEST, why)
}

/// The filter a log query asks for (see the module documentation and
/// [`LogFilter::parse_query`]).
pub(super) fn parse_query(q: &str) -> Result<LogFilter, ApiError> {
    LogFilter::parse_query(q).map_err(bad)
}

/// `GET /api/jobs/{id}/log`.
pub(super) async fn api_log(
    State(app): State<App>,
    headers: HeaderMap,
    Path(id): Path<u64>,
    uri: Uri,
) -> Result<Json<LogView>, ApiError> {
    app.need_submitter(&headers, "reading a job's tile log")?;
    let filter = parse_query(uri.query().unwrap_or_default())?;
    let farm = app.farm.clone();
    let log = tokio::task::spawn_blocking(move || farm.tile_log(id, filter))
        .await
        .map_err(|e| ApiError(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))??;
    Ok(Json(log.into()))
}

#[derive(Deserialize)]
pub(super) struct UnblockBody {
    worker: String,
}

/// `POST /api/jobs/{id}/unblock`.
pub(super) async fn api_unblock(
    State(app): State<App>,
    _: SameSite,
    headers: HeaderMap,
    Path(id): Path<u64>,
    Json(body): Json<UnblockBody>,
) -> Result<Json<JobView>, ApiError> {
    app.job_action(&headers, "unblocking a worker", move |farm| {
        let who = check_unblock_worker(&body.worker)?;
        debug_assert!(who.chars().count() <= MAX_UNBLOCK_WORKER_CHARS);
        farm.unblock(id, who)
    })
    .await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_log_query_is_read_or_refused_naming_what_is_wrong() {
        let f = parse_query("frame=3&x=10&y=20&errors=1").unwrap();
        assert_eq!(f.frame, Some(3));
        assert_eq!(f.pixel, Some((10, 20)));
        assert!(f.errors_only);
        assert_eq!(parse_query("").unwrap(), LogFilter::default());
        for (q, says) in [
            ("x=1", "both x and y"),
            ("frame=-1", "not a whole number"),
            ("tile=1", "unknown parameter"),
        ] {
            let e = parse_query(q).map(|_| ()).unwrap_err();
            assert_eq!(e.0, StatusCode::BAD_REQUEST);
            assert!(e.1.contains(says), "{q}: {}", e.1);
        }
        assert!(parse_query(&"errors=1&".repeat(20)).is_err());
    }
}
