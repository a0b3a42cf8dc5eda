//! The monitor's requeue and retry (docs/farm.md, "Running a farm"):
//!
//! - `POST /api/jobs/{id}/requeue` (body `{"frames": "A-B", "rect": [x, y,
//!   w, h]}`, both optional): as `trevi-submit requeue ID [--frames A-B]
//!   [--rect X,Y,W,H]`. The body is at most
//!   [`MAX_BODY_BYTES`](trevi_proto::requeue::MAX_BODY_BYTES) bytes, checked
//!   before it is read (its declared length) and while it is (413); one
//!   that does not parse is refused (400) with the reason.
//! - `POST /api/jobs/{id}/retry`: as `trevi-submit retry ID`.
//!
//! Both answer with the job as `/api/state` shows it.

use super::{ApiError, App, JobView, SameSite};
use axum::body::Body;
use axum::extract::{Path, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::Json;
use trevi_core::Rect;
use trevi_proto::requeue::{parse_body, MAX_BODY_BYTES};

fn too_large() -> ApiError {
    ApiError(
        StatusCode::PAYLOAD_TOO_LARGE,
        format!("the body is longer than {MAX_BODY_BYTES} bytes"),
    )
}

/// `POST /api/jobs/{id}/requeue`.
pub(super) async fn api_requeue(
    State(app): State<App>,
    _: SameSite,
    headers: HeaderMap,
    Path(id): Path<u64>,
    body: Body,
) -> Result<Json<JobView>, ApiError> {
    app.need_submitter(&headers, "requeueing a job")?;
    let declared = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    if declared.is_some_and(|n| n > MAX_BODY_BYTES as u64) {
        return Err(too_large());
    }
    let bytes = axum::body::to_bytes(body, MAX_BODY_BYTES)
        .await
        .map_err(|_| too_large())?;
    let r = parse_body(&bytes).map_err(|e| ApiError(StatusCode::BAD_REQUEST, e.to_string()))?;
    let rect = r.rect.map(|[x, y, w, h]| Rect::new(x, y, w, h));
    app.job_action(&headers, "requeueing a job", move |farm| {
        farm.requeue(id, r.frames, rect)
    })
    .await
}

/// `POST /api/jobs/{id}/retry`.
pub(super) async fn api_retry(
    State(app): State<App>,
    _: SameSite,
    headers: HeaderMap,
    Path(id): Path<u64>,
) -> Result<Json<JobView>, ApiError> {
    app.job_action(&headers, "retrying a job", move |farm| farm.retry_job(id))
        .await
}
