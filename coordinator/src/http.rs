//! The coordinator's HTTP side (`--http ADDR`): the web monitor, its JSON
//! API, `/metrics` and `/healthz`.
//!
//! - `GET /`: the monitor page. Its HTML, CSS and JavaScript are one file
//!   embedded in the binary (`assets/monitor.html`); no build step.
//! - `GET /api/state`: jobs (state, progress, ETA) and workers (state,
//!   current tiles, recent throughput) as JSON. Bounded whatever the number
//!   of jobs kept: the first [`STATE_ACTIVE_JOBS`] unfinished jobs and the
//!   newest [`STATE_ENDED_JOBS`] ended ones, with the counts of each state.
//! - `GET /api/jobs/{id}/preview.png`: the job's live preview
//!   ([`crate::preview`]).
//! - `POST /api/jobs/{id}/cancel`, `POST /api/jobs/{id}/priority` (body
//!   `{"priority": N}`).
//! - `GET /metrics` (Prometheus text, [`crate::metrics`]) and `GET /healthz`.
//!
//! The API needs the submit token when one is configured (as
//! `authorization: Bearer TOKEN`, the same rule as `trevi.v1.Jobs`): jobs,
//! previews and the buttons are a submitter's business. `/metrics`, `/healthz`
//! and the page itself are open, as the gRPC health service is; they show no
//! job's pixels.

use crate::auth::Tokens;
use crate::farm::Farm;
use crate::scheduler::{JobInfo, JobState};
use crate::workers::WorkerInfo;
use crate::FarmError;
use axum::extract::{Path, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use serde::{Deserialize, Serialize};
use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;

const MONITOR_HTML: &str = include_str!("../assets/monitor.html");

#[derive(Clone)]
struct App {
    farm: Arc<Farm>,
    tokens: Arc<Tokens>,
}

/// An API error: an HTTP status and a message, sent as `{"error": "..."}`.
#[derive(Debug)]
struct ApiError(StatusCode, String);

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        (self.0, Json(serde_json::json!({ "error": self.1 }))).into_response()
    }
}

impl From<FarmError> for ApiError {
    fn from(e: FarmError) -> Self {
        ApiError(http_code(e.code()), e.to_string())
    }
}

fn http_code(code: tonic::Code) -> StatusCode {
    use tonic::Code;
    match code {
        Code::NotFound => StatusCode::NOT_FOUND,
        Code::Unauthenticated => StatusCode::UNAUTHORIZED,
        Code::PermissionDenied => StatusCode::FORBIDDEN,
        Code::InvalidArgument => StatusCode::BAD_REQUEST,
        Code::FailedPrecondition => StatusCode::CONFLICT,
        Code::ResourceExhausted => StatusCode::TOO_MANY_REQUESTS,
        _ => StatusCode::INTERNAL_SERVER_ERROR,
    }
}

impl App {
    /// Checks the request's bearer token for the submitter role.
    fn need_submitter(&self, headers: &HeaderMap, what: &str) -> Result<(), ApiError> {
        let presented = headers
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "))
            .map(str::trim);
        self.tokens
            .grant(presented)
            .need_submitter(what)
            .map_err(|s| ApiError(http_code(s.code()), s.message().to_string()))
    }
}

/// The HTTP routes over `farm`.
pub fn router(farm: Arc<Farm>, tokens: Tokens) -> Router {
    Router::new()
        .route("/", get(monitor))
        .route("/healthz", get(healthz))
        .route("/metrics", get(metrics))
        .route("/api/state", get(api_state))
        .route("/api/jobs/{id}/preview.png", get(api_preview))
        .route("/api/jobs/{id}/cancel", post(api_cancel))
        .route("/api/jobs/{id}/priority", post(api_priority))
        .with_state(App {
            farm,
            tokens: Arc::new(tokens),
        })
}

/// Serves [`router`] on `listener` until `shutdown` resolves; over HTTPS
/// when given a TLS acceptor (the coordinator's `--tls-cert`, so that the
/// submit token typed into the page is not sent in the clear).
pub async fn serve(
    farm: Arc<Farm>,
    tokens: Tokens,
    listener: tokio::net::TcpListener,
    tls: Option<tokio_rustls::TlsAcceptor>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    let app = router(farm, tokens);
    match tls {
        None => {
            axum::serve(listener, app)
                .with_graceful_shutdown(shutdown)
                .await
        }
        Some(acceptor) => {
            axum::serve(TlsListener::new(listener, acceptor)?, app)
                .with_graceful_shutdown(shutdown)
                .await
        }
    }
}

/// TLS connections ready for HTTP. Handshakes run in tasks of their own,
/// with a time limit, so a slow or silent client cannot hold up the others.
struct TlsListener {
    ready: tokio::sync::mpsc::Receiver<(TlsStream, SocketAddr)>,
    addr: SocketAddr,
    acceptor_task: tokio::task::JoinHandle<()>,
}

type TlsStream = tokio_rustls::server::TlsStream<tokio::net::TcpStream>;

/// How long a client may take to finish its TLS handshake.
const HANDSHAKE_LIMIT: std::time::Duration = std::time::Duration::from_secs(10);

impl TlsListener {
    fn new(
        listener: tokio::net::TcpListener,
        acceptor: tokio_rustls::TlsAcceptor,
    ) -> std::io::Result<TlsListener> {
        let addr = listener.local_addr()?;
        let (tx, ready) = tokio::sync::mpsc::channel(64);
        let acceptor_task = tokio::spawn(async move {
            loop {
                let (tcp, peer) = match listener.accept().await {
                    Ok(c) => c,
                    Err(e) => {
                        tracing::warn!(error = %e, "monitor: accept failed");
                        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
                        continue;
                    }
                };
                let (acceptor, tx) = (acceptor.clone(), tx.clone());
                tokio::spawn(async move {
                    match tokio::time::timeout(HANDSHAKE_LIMIT, acceptor.accept(tcp)).await {
                        Ok(Ok(tls)) => {
                            let _ = tx.send((tls, peer)).await;
                        }
                        Ok(Err(e)) => {
                            tracing::debug!(%peer, error = %e, "monitor: TLS handshake failed")
                        }
                        Err(_) => tracing::debug!(%peer, "monitor: TLS handshake timed out"),
                    }
                });
            }
        });
        Ok(TlsListener {
            ready,
            addr,
            acceptor_task,
        })
    }
}

impl Drop for TlsListener {
    fn drop(&mut self) {
        self.acceptor_task.abort();
    }
}

impl axum::serve::Listener for TlsListener {
    type Io = TlsStream;
    type Addr = SocketAddr;

    async fn accept(&mut self) -> (TlsStream, SocketAddr) {
        match self.ready.recv().await {
            Some(c) => c,
            // The accepting task is gone (aborted at shutdown): no more.
            None => std::future::pending().await,
        }
    }

    fn local_addr(&self) -> std::io::Result<SocketAddr> {
        Ok(self.addr)
    }
}

async fn monitor() -> impl IntoResponse {
    (
        [
            (header::CONTENT_TYPE, "text/html; charset=utf-8"),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        MONITOR_HTML,
    )
}

async fn healthz(State(app): State<App>) -> impl IntoResponse {
    // Taking the state lock shows the coordinator is not wedged.
    let jobs = app.farm.queue_depth().jobs;
    format!("ok: {jobs} unfinished jobs\n")
}

async fn metrics(State(app): State<App>) -> impl IntoResponse {
    (
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        crate::metrics::render(&app.farm),
    )
}

#[derive(Serialize)]
struct JobView {
    id: u64,
    state: &'static str,
    camera: String,
    priority: i32,
    width: u32,
    height: u32,
    output_name: String,
    tiles_total: u64,
    tiles_done: u64,
    rays: u64,
    elapsed_ms: u64,
    /// Remaining time at the pace so far; `null` unless running with
    /// tiles done.
    eta_ms: Option<u64>,
    error: Option<String>,
}

/// Time left if the rest of the tiles go as fast as those done so far.
pub fn eta_ms(info: &JobInfo) -> Option<u64> {
    if info.state != JobState::Running || info.tiles_done == 0 {
        return None;
    }
    let left = info.tiles_total.saturating_sub(info.tiles_done);
    let per_tile = info.elapsed.as_secs_f64() / info.tiles_done as f64;
    Some((per_tile * left as f64 * 1000.0).round() as u64)
}

impl From<&JobInfo> for JobView {
    fn from(j: &JobInfo) -> Self {
        JobView {
            id: j.id,
            state: j.state.name(),
            camera: j.spec.camera.clone(),
            priority: j.spec.priority,
            width: j.spec.width,
            height: j.spec.height,
            output_name: j.spec.output_name.clone(),
            tiles_total: j.tiles_total,
            tiles_done: j.tiles_done,
            rays: j.rays,
            elapsed_ms: j.elapsed.as_millis() as u64,
            eta_ms: eta_ms(j),
            error: j.error.clone(),
        }
    }
}

#[derive(Serialize)]
struct TileView {
    job: u64,
    x: u32,
    y: u32,
    w: u32,
    h: u32,
}

#[derive(Serialize)]
struct WorkerView {
    id: u64,
    name: String,
    threads: u32,
    state: &'static str,
    silent_ms: u64,
    tiles: Vec<TileView>,
    tiles_done: u64,
    rays: u64,
    tiles_per_s: f64,
    rays_per_s: f64,
}

impl From<&WorkerInfo> for WorkerView {
    fn from(w: &WorkerInfo) -> Self {
        WorkerView {
            id: w.id,
            name: w.name.clone(),
            threads: w.threads,
            state: w.state.name(),
            silent_ms: w.silent_for.as_millis() as u64,
            tiles: w
                .leases
                .iter()
                .map(|&(job, r)| TileView {
                    job,
                    x: r.x,
                    y: r.y,
                    w: r.w,
                    h: r.h,
                })
                .collect(),
            tiles_done: w.tiles_done,
            rays: w.rays,
            tiles_per_s: w.tiles_per_s,
            rays_per_s: w.rays_per_s,
        }
    }
}

/// Unfinished jobs `/api/state` shows at most (by id).
pub const STATE_ACTIVE_JOBS: usize = 500;
/// Ended jobs `/api/state` shows at most (the newest by id).
pub const STATE_ENDED_JOBS: usize = 50;

#[derive(Serialize)]
struct StateView {
    jobs: Vec<JobView>,
    /// Jobs in each state, counting those not in `jobs`.
    jobs_running: usize,
    jobs_queued: usize,
    jobs_ended: usize,
    workers: Vec<WorkerView>,
    rays_per_second: f64,
    queued_tiles: u64,
}

async fn api_state(
    State(app): State<App>,
    headers: HeaderMap,
) -> Result<Json<StateView>, ApiError> {
    app.need_submitter(&headers, "reading the farm's jobs")?;
    let s = app.farm.snapshot();
    let count = |st: JobState| s.jobs.iter().filter(|j| j.state == st).count();
    let (running, queued) = (count(JobState::Running), count(JobState::Queued));
    let active = s.jobs.iter().filter(|j| !j.state.is_final());
    let ended = s.jobs.iter().rev().filter(|j| j.state.is_final());
    let mut jobs: Vec<&JobInfo> = active.take(STATE_ACTIVE_JOBS).collect();
    jobs.extend(ended.take(STATE_ENDED_JOBS));
    jobs.sort_unstable_by_key(|j| std::cmp::Reverse(j.id));
    Ok(Json(StateView {
        // Newest first: the page lists what is happening now at the top.
        jobs: jobs.into_iter().map(JobView::from).collect(),
        jobs_running: running,
        jobs_queued: queued,
        jobs_ended: s.jobs.len() - running - queued,
        workers: s.workers.iter().map(WorkerView::from).collect(),
        rays_per_second: s.rays_per_second,
        queued_tiles: s.queue.tiles,
    }))
}

async fn api_preview(
    State(app): State<App>,
    headers: HeaderMap,
    Path(id): Path<u64>,
) -> Result<Response, ApiError> {
    app.need_submitter(&headers, "reading a job's preview")?;
    let farm = app.farm.clone();
    let image = tokio::task::spawn_blocking(move || farm.preview(id))
        .await
        .map_err(|e| ApiError(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))??;
    Ok((
        [
            (header::CONTENT_TYPE, "image/png".to_string()),
            (header::CACHE_CONTROL, "no-store".to_string()),
            (
                header::HeaderName::from_static("x-trevi-preview-tiles"),
                image.tiles.to_string(),
            ),
        ],
        image.png.as_ref().clone(),
    )
        .into_response())
}

async fn api_cancel(
    State(app): State<App>,
    headers: HeaderMap,
    Path(id): Path<u64>,
) -> Result<Json<JobView>, ApiError> {
    app.need_submitter(&headers, "cancelling a job")?;
    let farm = app.farm.clone();
    let info = tokio::task::spawn_blocking(move || farm.cancel(id))
        .await
        .map_err(|e| ApiError(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))??;
    Ok(Json(JobView::from(&info)))
}

#[derive(Deserialize)]
struct PriorityBody {
    priority: i32,
}

async fn api_priority(
    State(app): State<App>,
    headers: HeaderMap,
    Path(id): Path<u64>,
    Json(body): Json<PriorityBody>,
) -> Result<Json<JobView>, ApiError> {
    app.need_submitter(&headers, "changing a job's priority")?;
    let farm = app.farm.clone();
    let info = tokio::task::spawn_blocking(move || farm.set_priority(id, body.priority))
        .await
        .map_err(|e| ApiError(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))??;
    Ok(Json(JobView::from(&info)))
}
