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
//!   `{"priority": N}`), `POST /api/jobs/{id}/pause` and `.../resume`;
//!   `POST /api/jobs/{id}/requeue` and `.../retry` (`http/control.rs`).
//! - `GET /api/jobs/{id}/log` and `POST /api/jobs/{id}/unblock`: the tile
//!   log and the blocklists (`http/log.rs`).
//! - `GET /events`: the job events ([`crate::events`]) as server-sent
//!   events, which the page listens to before falling back to polling.
//! - `GET /usage` and `GET /api/usage?since=7d&by=worker`: the usage
//!   history's page and its JSON (`http/usage.rs`).
//! - `GET /metrics` (Prometheus text, [`crate::metrics`]) and `GET /healthz`.
//!
//! State-changing requests (the `POST`s) must come from the monitor's own
//! page: a request whose `Origin` (or, lacking one, `Referer`) names another
//! site is refused (403), and the body must be declared JSON
//! (`content-type: application/json`, else 415), which a cross-site form
//! cannot send and a cross-site script may send only after a CORS preflight
//! this server never grants. So with no token configured, a page elsewhere
//! still cannot cancel jobs through a visitor's browser.
//!
//! Connections ([`Limits`](crate::limits::Limits)): a client has
//! `http_header_timeout` to send each request's headers (and to
//! finish a TLS handshake), or the connection is closed, which also ends
//! idle keep-alive connections; at most `http_max_connections` are
//! open at once, and one more is closed as soon as it is accepted. The
//! listener is separate from gRPC's, so a flood here leaves gRPC serving.
//!
//! The API needs the submit token when one is configured (as
//! `authorization: Bearer TOKEN`, the same rule as `trevi.v1.Jobs`): jobs,
//! previews and the buttons are a submitter's business. `/metrics`, `/healthz`
//! and the page itself are open, as the gRPC health service is; they show no
//! job's pixels.

use crate::auth::Tokens;
use crate::farm::Farm;
use crate::scheduler::{JobInfo, JobState};
use crate::workers::{WorkerInfo, WorkerState};
use crate::FarmError;
use axum::extract::{FromRequestParts, Path, State};
use axum::http::request::Parts;
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use serde::{Deserialize, Serialize};
use std::convert::Infallible;
use std::future::Future;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::{watch, Semaphore};
use tokio::task::JoinSet;
use tokio_stream::wrappers::BroadcastStream;
use tokio_stream::{Stream, StreamExt};

mod control;
mod log;
mod usage;

pub use usage::MAX_QUERY_LEN as MAX_USAGE_QUERY_LEN;

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
    /// A submitter's action on a job (`what` names it for a refusal): the
    /// token checked, `act` run off the async threads (it may wait for the
    /// farm's lock or the database), its result as the monitor's job card.
    pub(super) async fn job_action(
        &self,
        headers: &HeaderMap,
        what: &str,
        act: impl FnOnce(&Farm) -> Result<JobInfo, FarmError> + Send + 'static,
    ) -> Result<Json<JobView>, ApiError> {
        self.need_submitter(headers, what)?;
        let farm = self.farm.clone();
        let info = tokio::task::spawn_blocking(move || act(&farm))
            .await
            .map_err(|e| ApiError(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))??;
        Ok(Json(JobView::from(&info)))
    }

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

/// Refuses a state-changing request that a page on another site could have
/// made (see the module documentation).
fn same_site(headers: &HeaderMap) -> Result<(), ApiError> {
    let text = |name: header::HeaderName| headers.get(name).and_then(|v| v.to_str().ok());
    let host = text(header::HOST).unwrap_or_default();
    if let Some(from) = text(header::ORIGIN).or_else(|| text(header::REFERER)) {
        if !same_authority(from, host) {
            return Err(ApiError(
                StatusCode::FORBIDDEN,
                format!(
                    "refused: this request comes from {from}, not from this server's own page \
                     (host {host}); state-changing requests must come from the monitor itself"
                ),
            ));
        }
    }
    let json = text(header::CONTENT_TYPE)
        .and_then(|t| t.split(';').next())
        .is_some_and(|t| t.trim().eq_ignore_ascii_case("application/json"));
    if !json {
        return Err(ApiError(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "refused: state-changing requests must be sent with content-type: application/json"
                .into(),
        ));
    }
    Ok(())
}

/// A request [`same_site`] lets through. As an extractor placed before the
/// body's, it is checked before the body is read.
struct SameSite;

impl<S: Send + Sync> FromRequestParts<S> for SameSite {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, ApiError> {
        same_site(&parts.headers).map(|()| SameSite)
    }
}

/// Whether the origin or URL `from` (`scheme://host[:port][/...]`) names the
/// server at `host` (`host[:port]`, a request's Host header); a default port
/// (80 for http, 443 for https) may be written or not.
fn same_authority(from: &str, host: &str) -> bool {
    let Some((scheme, rest)) = from.split_once("://") else {
        return false; // Includes `Origin: null`.
    };
    let authority = rest.split(['/', '?', '#']).next().unwrap_or_default();
    let default = match scheme.to_ascii_lowercase().as_str() {
        "http" => ":80",
        "https" => ":443",
        _ => return false,
    };
    let norm = |a: &str| {
        let a = a.to_ascii_lowercase();
        a.strip_suffix(default).map(str::to_string).unwrap_or(a)
    };
    !host.is_empty() && !authority.contains('@') && norm(authority) == norm(host)
}

/// The HTTP routes over `farm`.
pub fn router(farm: Arc<Farm>, tokens: Tokens) -> Router {
    Router::new()
        .route("/", get(monitor))
        .route("/healthz", get(healthz))
        .route("/metrics", get(metrics))
        .route("/events", get(events))
        .route("/api/state", get(api_state))
        .route("/api/jobs/{id}/preview.png", get(api_preview))
        .route("/api/jobs/{id}/cancel", post(api_cancel))
        .route("/api/jobs/{id}/priority", post(api_priority))
        .route("/api/jobs/{id}/pause", post(api_pause))
        .route("/api/jobs/{id}/resume", post(api_resume))
        .route("/api/jobs/{id}/requeue", post(control::api_requeue))
        .route("/api/jobs/{id}/retry", post(control::api_retry))
        .route("/api/jobs/{id}/log", get(log::api_log))
        .route("/api/jobs/{id}/unblock", post(log::api_unblock))
        .route("/usage", get(usage::page))
        .route("/api/usage", get(usage::api))
        .with_state(App {
            farm,
            tokens: Arc::new(tokens),
        })
}

/// How long connections may finish their requests after `shutdown`.
const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);

/// Serves [`router`] on `listener` until `shutdown` resolves; over HTTPS
/// when given a TLS acceptor (the coordinator's `--tls-cert`, so that the
/// submit token typed into the page is not sent in the clear). Each
/// connection is served in a task of its own, within the farm's
/// [`Limits`](crate::limits::Limits) for the monitor.
pub async fn serve(
    farm: Arc<Farm>,
    tokens: Tokens,
    listener: tokio::net::TcpListener,
    tls: Option<tokio_rustls::TlsAcceptor>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    let limits = farm.config().limits;
    let app = router(farm, tokens);
    let slots = Arc::new(Semaphore::new(limits.http_max_connections));
    let (stop_tx, stop_rx) = watch::channel(false);
    let mut conns = JoinSet::new();
    let mut warned: Option<Instant> = None;
    tokio::pin!(shutdown);
    loop {
        let (tcp, peer) = tokio::select! {
            c = crate::listen::accept(&listener, "monitor") => c,
            _ = &mut shutdown => break,
        };
        while conns.try_join_next().is_some() {}
        let Ok(slot) = slots.clone().try_acquire_owned() else {
            // Closed at once (dropped): a client waiting for a slot would
            // hold a file descriptor all the same.
            if warned.is_none_or(|t| t.elapsed() >= Duration::from_secs(5)) {
                tracing::warn!(%peer, max = limits.http_max_connections,
                    "monitor: too many connections (--http-max-connections); closing new ones");
                warned = Some(Instant::now());
            }
            continue;
        };
        let (app, tls, stop) = (app.clone(), tls.clone(), stop_rx.clone());
        conns.spawn(async move {
            let _slot = slot;
            match tls {
                None => serve_connection(tcp, app, limits.http_header_timeout, stop).await,
                Some(acceptor) => {
                    let handshake = acceptor.accept(tcp);
                    match tokio::time::timeout(limits.http_header_timeout, handshake).await {
                        Ok(Ok(tls)) => {
                            serve_connection(tls, app, limits.http_header_timeout, stop).await
                        }
                        Ok(Err(e)) => {
                            tracing::debug!(%peer, error = %e, "monitor: TLS handshake failed")
                        }
                        Err(_) => tracing::debug!(%peer, "monitor: TLS handshake timed out"),
                    }
                }
            }
        });
    }
    drop(listener);
    let _ = stop_tx.send(true);
    let drained = async { while conns.join_next().await.is_some() {} };
    let _ = tokio::time::timeout(SHUTDOWN_GRACE, drained).await;
    Ok(())
}

/// Serves HTTP/1.1 on one connection until the client or `stop` ends it.
async fn serve_connection<I>(
    io: I,
    app: Router,
    header_timeout: Duration,
    mut stop: watch::Receiver<bool>,
) where
    I: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send + 'static,
{
    let conn = hyper::server::conn::http1::Builder::new()
        .timer(hyper_util::rt::TokioTimer::new())
        .header_read_timeout(header_timeout)
        .serve_connection(
            hyper_util::rt::TokioIo::new(io),
            hyper_util::service::TowerToHyperService::new(app),
        );
    tokio::pin!(conn);
    let result = tokio::select! {
        r = conn.as_mut() => r,
        () = async { let _ = stop.wait_for(|&s| s).await; } => {
            conn.as_mut().graceful_shutdown();
            conn.await
        }
    };
    if let Err(e) = result {
        tracing::debug!(error = %e, "monitor: connection ended");
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
        crate::metrics::render(&app.farm.snapshot(), app.farm.metrics())
            + &app.farm.events().stats().render(),
    )
}

/// `GET /events`: the job events as server-sent events (`event:` the kind,
/// `id:` the sequence number, `data:` the JSON a webhook gets). At most
/// [`MAX_SSE_SUBSCRIBERS`](crate::events::MAX_SSE_SUBSCRIBERS) at once; a
/// subscriber that falls [`SSE_BUFFER`](crate::events::SSE_BUFFER) events
/// behind is disconnected (the page falls back to polling and reconnects).
async fn events(
    State(app): State<App>,
    headers: HeaderMap,
) -> Result<Sse<impl Stream<Item = Result<SseEvent, Infallible>>>, ApiError> {
    app.need_submitter(&headers, "watch the job events")?;
    let rx = app.farm.events().subscribe().ok_or_else(|| {
        ApiError(
            StatusCode::SERVICE_UNAVAILABLE,
            format!(
                "{} event subscribers already; try again later",
                crate::events::MAX_SSE_SUBSCRIBERS
            ),
        )
    })?;
    // A lagging subscriber's stream ends: it is dropped, never waited for.
    let stream = BroadcastStream::new(rx).map_while(|ev| {
        let ev = ev.ok()?;
        Some(Ok(SseEvent::default()
            .event(ev.event.name())
            .id(ev.seq.to_string())
            .data(ev.json())))
    });
    Ok(Sse::new(stream).keep_alive(KeepAlive::default()))
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
    /// Since submission: `queued_ms` waiting, then `render_ms` rendering.
    elapsed_ms: u64,
    queued_ms: u64,
    render_ms: u64,
    /// The scene file's name, and who submitted the job.
    scene: String,
    submitter: String,
    /// Remaining time at the pace so far; `null` unless running with
    /// tiles done.
    eta_ms: Option<u64>,
    error: Option<String>,
    /// A sequence's frames (see farm/sequences.rs); `null` for a still.
    frames: Option<FramesView>,
    /// A progressive job's passes (see farm/progressive.rs); `null` for
    /// any other.
    passes: Option<PassesView>,
    /// Paused (`trevi-submit pause`), and the jobs it still waits for
    /// (`--after`); see farm/control.rs.
    paused: bool,
    waiting_for: Vec<u64>,
    /// The workers kept from it (see http/log.rs).
    blocked: Vec<log::BlockedView>,
}

#[derive(Serialize)]
struct PassesView {
    done: u32,
    samples_done: u32,
    samples_total: u32,
    /// The estimated relative error after the last pass; `null` until known.
    error: Option<f64>,
    /// "time limit" or "noise target" when it stopped before its total.
    stopped_by: Option<&'static str>,
}

#[derive(Serialize)]
struct FramesView {
    first: u32,
    last: u32,
    done: u32,
    in_progress: u32,
    /// The earliest frame in progress, its tiles done and its tiles.
    current: Option<u32>,
    current_tiles_done: u64,
    current_tiles_total: u64,
}

/// Time left if the rest of the tiles go as fast as those done so far.
pub fn eta_ms(info: &JobInfo) -> Option<u64> {
    if info.state != JobState::Running || info.tiles_done == 0 {
        return None;
    }
    let left = info.tiles_total.saturating_sub(info.tiles_done);
    let per_tile = info.render().as_secs_f64() / info.tiles_done as f64;
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
            queued_ms: j.queued.as_millis() as u64,
            render_ms: j.render().as_millis() as u64,
            scene: j.spec.scene.clone(),
            submitter: j.spec.submitter.clone(),
            eta_ms: eta_ms(j),
            error: j.error.clone(),
            frames: j.frames.map(|f| FramesView {
                first: f.first,
                last: f.last,
                done: f.done,
                in_progress: f.in_progress,
                current: f.current.map(|c| c.0),
                current_tiles_done: f.current.map_or(0, |c| c.1),
                current_tiles_total: f.current.map_or(0, |c| c.2),
            }),
            passes: j.passes.as_ref().map(|p| PassesView {
                done: p.done,
                samples_done: p.samples_done,
                samples_total: p.samples_total,
                error: p.error,
                stopped_by: p.stopped_by.map(|r| r.label()),
            }),
            paused: j.paused,
            waiting_for: j.waiting_for.clone(),
            blocked: j.blocked.iter().map(Into::into).collect(),
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
    /// Why a paused worker is paused ("busy", "outside hours", "memory":
    /// no queued job fits its memory limit); null otherwise.
    paused: Option<String>,
    /// Its `--max-memory` in bytes; null when it said none.
    memory_limit: Option<u64>,
    /// The same for people ("2.0 GiB"); null when none.
    memory_limit_text: Option<String>,
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
            paused: w.paused.clone().filter(|_| w.state == WorkerState::Paused),
            memory_limit: (w.memory_limit > 0).then_some(w.memory_limit),
            memory_limit_text: (w.memory_limit > 0)
                .then(|| trevi_core::scene::estimate::human_bytes(w.memory_limit)),
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
/// Workers `/api/state` shows at most (busy and paused ones first, then by
/// id); `workers_total` counts them all.
pub const STATE_WORKERS: usize = 500;

#[derive(Serialize)]
struct StateView {
    jobs: Vec<JobView>,
    /// Jobs in each state, counting those not in `jobs`.
    jobs_running: usize,
    jobs_queued: usize,
    jobs_ended: usize,
    workers: Vec<WorkerView>,
    /// Workers known, counting those not in `workers`.
    workers_total: usize,
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
        workers: {
            // Busy and paused ones first: what is happening now.
            let mut w: Vec<&WorkerInfo> = s.workers.iter().collect();
            w.sort_by_key(|w| {
                (
                    !matches!(w.state, WorkerState::Busy | WorkerState::Paused),
                    w.id,
                )
            });
            w.truncate(STATE_WORKERS);
            w.sort_by_key(|w| w.id);
            w.into_iter().map(WorkerView::from).collect()
        },
        workers_total: s.workers.len(),
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
    _: SameSite,
    headers: HeaderMap,
    Path(id): Path<u64>,
) -> Result<Json<JobView>, ApiError> {
    app.job_action(&headers, "cancelling a job", move |farm| farm.cancel(id))
        .await
}

#[derive(Deserialize)]
struct PriorityBody {
    priority: i32,
}

async fn api_priority(
    State(app): State<App>,
    _: SameSite,
    headers: HeaderMap,
    Path(id): Path<u64>,
    Json(body): Json<PriorityBody>,
) -> Result<Json<JobView>, ApiError> {
    app.job_action(&headers, "changing a job's priority", move |farm| {
        farm.set_priority(id, body.priority)
    })
    .await
}

/// `POST /api/jobs/{id}/pause`: as `trevi-submit pause ID` (the tiles out
/// finish); docs/farm.md, "Running a farm".
async fn api_pause(
    State(app): State<App>,
    _: SameSite,
    headers: HeaderMap,
    Path(id): Path<u64>,
) -> Result<Json<JobView>, ApiError> {
    app.job_action(&headers, "pausing a job", move |farm| farm.pause(id, false))
        .await
}

/// `POST /api/jobs/{id}/resume`: as `trevi-submit resume ID`.
async fn api_resume(
    State(app): State<App>,
    _: SameSite,
    headers: HeaderMap,
    Path(id): Path<u64>,
) -> Result<Json<JobView>, ApiError> {
    app.job_action(&headers, "resuming a job", move |farm| farm.resume(id))
        .await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_this_servers_own_origin_is_the_same_site() {
        assert!(same_authority("http://127.0.0.1:8080", "127.0.0.1:8080"));
        assert!(same_authority("https://Farm.example", "farm.example:443"));
        assert!(same_authority(
            "http://farm.example/monitor?x",
            "farm.example"
        ));
        for other in [
            "http://evil.example:8080",
            "http://127.0.0.1:8081",
            "null",
            "file:///tmp/x.html",
            "http://127.0.0.1:8080@evil.example",
        ] {
            assert!(!same_authority(other, "127.0.0.1:8080"), "{other}");
        }
        assert!(!same_authority("http://x", ""));
    }

    #[test]
    fn a_state_change_needs_the_same_site_and_a_json_body() {
        let h = |pairs: &[(header::HeaderName, &str)]| {
            let mut m = HeaderMap::new();
            for (k, v) in pairs {
                m.insert(k.clone(), v.parse().unwrap());
            }
            same_site(&m).map_err(|e| e.0)
        };
        let host = (header::HOST, "h:1");
        let json = (header::CONTENT_TYPE, "application/json; charset=utf-8");
        assert_eq!(h(&[host.clone(), json.clone()]), Ok(()));
        assert_eq!(
            h(&[host.clone(), json.clone(), (header::ORIGIN, "http://h:1")]),
            Ok(())
        );
        assert_eq!(
            h(&[host.clone(), json.clone(), (header::ORIGIN, "http://e:1")]),
            Err(StatusCode::FORBIDDEN)
        );
        assert_eq!(
            h(&[
                host.clone(),
                json.clone(),
                (header::REFERER, "http://e:1/p")
            ]),
            Err(StatusCode::FORBIDDEN)
        );
        let form = (header::CONTENT_TYPE, "application/x-www-form-urlencoded");
        assert_eq!(
            h(&[host.clone(), form, (header::ORIGIN, "http://h:1")]),
            Err(StatusCode::UNSUPPORTED_MEDIA_TYPE)
        );
        assert_eq!(h(&[host]), Err(StatusCode::UNSUPPORTED_MEDIA_TYPE));
    }
}
