//! `/metrics`: the coordinator's figures in the Prometheus text exposition
//! format (version 0.0.4).
//!
//! Everything but the request latencies is read from the scheduler at scrape
//! time (a [`FarmSnapshot`], from `Farm::snapshot`), so the counters are the scheduler's own
//! bookkeeping, not a second count kept beside it that could drift. The text
//! is written here rather than through a client library because the
//! format is a few lines of `# HELP`/`# TYPE` and samples, and the Rust
//! client (`prometheus-client`) speaks OpenMetrics instead.
//!
//! Request latencies come from [`LatencyLayer`], a tower layer around the
//! gRPC server that times every call from its arrival until its response
//! headers are ready (for a streaming call, the stream's start).

use crate::scheduler::{Counters, JobInfo, JobState, QueueDepth};
use crate::workers::{WorkerInfo, WorkerState};

/// Series per worker a family of `/metrics` shows at most (the first by
/// id): a farm's thousands of workers must not make thousands of series
/// (the families by state and reason count them all).
pub const WORKER_SERIES: usize = 100;
use std::collections::BTreeMap;
use std::fmt::Write;
use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::{Duration, Instant};

/// Upper bounds of the latency histogram's buckets, in seconds.
const BUCKETS: [f64; 12] = [
    0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5,
];

/// Methods tracked by name; calls to any other path share one series, so a
/// client inventing paths cannot grow the coordinator's memory.
const MAX_METHODS: usize = 64;

#[derive(Debug, Clone, Default)]
struct Histogram {
    /// Cumulative counts per bucket of [`BUCKETS`].
    counts: [u64; BUCKETS.len()],
    count: u64,
    sum: f64,
}

impl Histogram {
    fn observe(&mut self, seconds: f64) {
        for (c, &le) in self.counts.iter_mut().zip(&BUCKETS) {
            if seconds <= le {
                *c += 1;
            }
        }
        self.count += 1;
        self.sum += seconds;
    }
}

/// What `/metrics` reports of the farm, read in one go.
#[derive(Debug, Clone)]
pub struct FarmSnapshot {
    /// Running totals since the coordinator started.
    pub counters: Counters,
    /// Work waiting in the queue.
    pub queue: QueueDepth,
    /// Every job and sequence the farm holds, finished ones included (a
    /// sequence once, not its frames).
    pub jobs: Vec<JobInfo>,
    /// Every registered worker.
    pub workers: Vec<WorkerInfo>,
    /// Rays per second of the whole farm over the last few seconds.
    pub rays_per_second: f64,
    /// How long the farm's state lock has been held since the start: the
    /// serial part of the coordinator's work.
    pub state_lock_held: Duration,
    /// The same for the store's lock (its database).
    pub store_lock_held: Duration,
}

/// Figures the servers record as they go; shared by the farm (which the
/// monitor reads them through) and the [`LatencyLayer`] that records them.
#[derive(Debug, Default)]
pub struct Metrics {
    grpc: Mutex<BTreeMap<String, Histogram>>,
    /// PNG segments taken encoded from workers (`trevi_png_segments_total`).
    png_segments: AtomicU64,
}

impl Metrics {
    /// Counts `n` PNG segments taken encoded from a worker and written.
    pub fn add_png_segments(&self, n: u64) {
        self.png_segments.fetch_add(n, Ordering::Relaxed);
    }

    /// PNG segments taken encoded from workers since the start.
    pub fn png_segments(&self) -> u64 {
        self.png_segments.load(Ordering::Relaxed)
    }

    /// Records one gRPC call to `path` (`/package.Service/Method`).
    pub fn observe_grpc(&self, path: &str, took: Duration) {
        let known = path.starts_with("/trevi.v1.")
            || path.starts_with("/grpc.health.v1.")
            || path.starts_with("/grpc.reflection.");
        let mut map = self.grpc.lock().unwrap_or_else(|p| p.into_inner());
        let key =
            if known && path.len() <= 96 && (map.len() < MAX_METHODS || map.contains_key(path)) {
                path.trim_start_matches('/')
            } else {
                "other"
            };
        map.entry(key.to_string())
            .or_default()
            .observe(took.as_secs_f64());
    }
}

/// Writes one metric family's header.
fn family(out: &mut String, name: &str, kind: &str, help: &str) {
    let _ = writeln!(out, "# HELP {name} {help}");
    let _ = writeln!(out, "# TYPE {name} {kind}");
}

/// A label value with `\`, `"` and newlines escaped, as the format requires.
fn label(v: &str) -> String {
    v.replace('\\', r"\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

/// The whole `/metrics` page: the farm's figures in `s`, the request
/// latencies in `m`.
pub fn render(s: &FarmSnapshot, m: &Metrics) -> String {
    let mut out = String::with_capacity(4096);
    let c = &s.counters;
    for (name, help, v) in [
        (
            "trevi_tiles_rendered_total",
            "Tiles whose first valid result was accepted and stitched.",
            c.tiles_accepted,
        ),
        (
            "trevi_tiles_requeued_total",
            "Tiles put back in the queue after an expired lease or an invalid result.",
            c.tiles_requeued,
        ),
        (
            "trevi_tiles_rejected_total",
            "Tile results refused as invalid (wrong size, not finite, not a tile).",
            c.tiles_rejected,
        ),
        (
            "trevi_tiles_ignored_total",
            "Valid tile results that arrived after another result for the same tile.",
            c.tiles_ignored,
        ),
        (
            "trevi_lease_expiries_total",
            "Tile leases that ran out without a heartbeat.",
            c.lease_expiries,
        ),
        (
            "trevi_leases_granted_total",
            "Tile leases handed to workers.",
            c.leases_granted,
        ),
        (
            "trevi_rays_total",
            "Rays traced for the accepted tiles.",
            c.rays,
        ),
        (
            "trevi_jobs_submitted_total",
            "Jobs submitted since the coordinator started.",
            c.jobs_submitted,
        ),
        (
            "trevi_png_segments_total",
            "PNG segments (16 full-width rows) taken encoded from workers and appended to outputs.",
            m.png_segments(),
        ),
    ] {
        family(&mut out, name, "counter", help);
        let _ = writeln!(out, "{name} {v}");
    }

    for (name, help, held) in [
        (
            "trevi_state_lock_held_seconds_total",
            "Time the coordinator's state lock was held: serial work (ingest can use at most \
             one core per second of this a second).",
            s.state_lock_held,
        ),
        (
            "trevi_store_lock_held_seconds_total",
            "Time the store's lock (its database) was held: serial work, as for the state lock.",
            s.store_lock_held,
        ),
    ] {
        family(&mut out, name, "counter", help);
        let _ = writeln!(out, "{name} {:.6}", held.as_secs_f64());
    }

    family(
        &mut out,
        "trevi_rays_per_second",
        "gauge",
        "Rays per second over the last 10 s, all workers.",
    );
    let _ = writeln!(out, "trevi_rays_per_second {:.3}", s.rays_per_second);
    family(
        &mut out,
        "trevi_queue_depth_jobs",
        "gauge",
        "Jobs queued or running.",
    );
    let _ = writeln!(out, "trevi_queue_depth_jobs {}", s.queue.jobs);
    family(
        &mut out,
        "trevi_queue_depth_tiles",
        "gauge",
        "Tiles of unfinished jobs that are neither done nor leased.",
    );
    let _ = writeln!(out, "trevi_queue_depth_tiles {}", s.queue.tiles);

    family(&mut out, "trevi_jobs", "gauge", "Jobs known, by state.");
    for st in JobState::ALL {
        let n = s.jobs.iter().filter(|j| j.state == st).count();
        let _ = writeln!(out, "trevi_jobs{{state=\"{}\"}} {n}", st.name());
    }
    family(
        &mut out,
        "trevi_workers",
        "gauge",
        "Workers known, by state.",
    );
    for st in WorkerState::ALL {
        let n = s.workers.iter().filter(|w| w.state == st).count();
        let _ = writeln!(out, "trevi_workers{{state=\"{}\"}} {n}", st.name());
    }
    family(
        &mut out,
        "trevi_workers_paused",
        "gauge",
        "Paused workers, by reason (busy, outside hours: the worker's; memory: no queued job fits its limit).",
    );
    let mut reasons = std::collections::BTreeMap::<&str, usize>::new();
    for w in &s.workers {
        if let (WorkerState::Paused, Some(r)) = (w.state, &w.paused) {
            *reasons.entry(r.as_str()).or_default() += 1;
        }
    }
    for (r, n) in reasons {
        let _ = writeln!(out, "trevi_workers_paused{{reason=\"{}\"}} {n}", label(r));
    }
    family(
        &mut out,
        "trevi_worker_paused",
        "gauge",
        "1 for each worker that is paused, with its id, name and reason (the first 100 by id).",
    );
    let paused = s
        .workers
        .iter()
        .filter(|w| w.state == WorkerState::Paused)
        .take(WORKER_SERIES);
    for w in paused {
        if let (WorkerState::Paused, Some(r)) = (w.state, &w.paused) {
            let _ = writeln!(
                out,
                "trevi_worker_paused{{worker=\"{}\",name=\"{}\",reason=\"{}\"}} 1",
                w.id,
                label(&w.name),
                label(r)
            );
        }
    }

    family(
        &mut out,
        "trevi_worker_memory_limit_bytes",
        "gauge",
        "Each live worker's --max-memory in bytes (workers that gave none are left out; the first 100 by id).",
    );
    let limited = s
        .workers
        .iter()
        .filter(|w| w.memory_limit > 0 && !matches!(w.state, WorkerState::Lost | WorkerState::Left))
        .take(WORKER_SERIES);
    for w in limited {
        let _ = writeln!(
            out,
            "trevi_worker_memory_limit_bytes{{worker=\"{}\",name=\"{}\"}} {}",
            w.id,
            label(&w.name),
            w.memory_limit
        );
    }

    let name = "trevi_grpc_request_duration_seconds";
    family(
        &mut out,
        name,
        "histogram",
        "gRPC calls from arrival to response headers, by method.",
    );
    let map = m.grpc.lock().unwrap_or_else(|p| p.into_inner());
    for (method, h) in map.iter() {
        let method = label(method);
        for (le, n) in BUCKETS.iter().zip(&h.counts) {
            let _ = writeln!(out, "{name}_bucket{{method=\"{method}\",le=\"{le}\"}} {n}");
        }
        let _ = writeln!(
            out,
            "{name}_bucket{{method=\"{method}\",le=\"+Inf\"}} {}",
            h.count
        );
        let _ = writeln!(out, "{name}_sum{{method=\"{method}\"}} {}", h.sum);
        let _ = writeln!(out, "{name}_count{{method=\"{method}\"}} {}", h.count);
    }
    out
}

/// Times every request through the wrapped service into [`Metrics`].
#[derive(Clone)]
pub struct LatencyLayer {
    /// Where the latencies go.
    pub metrics: Arc<Metrics>,
}

impl<S> tower::Layer<S> for LatencyLayer {
    type Service = Latency<S>;
    fn layer(&self, inner: S) -> Latency<S> {
        Latency {
            inner,
            metrics: self.metrics.clone(),
        }
    }
}

/// The service [`LatencyLayer`] makes.
#[derive(Clone)]
pub struct Latency<S> {
    inner: S,
    metrics: Arc<Metrics>,
}

impl<S, B> tower::Service<http::Request<B>> for Latency<S>
where
    S: tower::Service<http::Request<B>>,
    S::Future: Send + 'static,
{
    type Response = S::Response;
    type Error = S::Error;
    type Future = Pin<Box<dyn Future<Output = Result<S::Response, S::Error>> + Send>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), S::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, req: http::Request<B>) -> Self::Future {
        let path = req.uri().path().to_string();
        let start = Instant::now();
        let metrics = self.metrics.clone();
        let fut = self.inner.call(req);
        Box::pin(async move {
            let r = fut.await;
            metrics.observe_grpc(&path, start.elapsed());
            r
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_buckets_are_cumulative() {
        let mut h = Histogram::default();
        for s in [0.0001, 0.003, 0.003, 0.2, 10.0] {
            h.observe(s);
        }
        assert_eq!(h.count, 5);
        assert!((h.sum - 10.2061).abs() < 1e-9);
        // le=0.0005: 1; le=0.005: 3; le=0.25: 4; le=2.5: 4 (10 s is only in +Inf).
        assert_eq!(h.counts[0], 1);
        assert_eq!(h.counts[3], 3);
        assert_eq!(h.counts[8], 4);
        assert_eq!(h.counts[11], 4);
        assert!(h.counts.windows(2).all(|w| w[0] <= w[1]));
    }

    #[test]
    fn invented_paths_share_one_series() {
        let m = Metrics::default();
        for i in 0..1000 {
            m.observe_grpc(&format!("/evil.Service/M{i}"), Duration::from_millis(1));
            m.observe_grpc(&format!("/trevi.v1.Jobs/M{i}"), Duration::from_millis(1));
        }
        let map = m.grpc.lock().unwrap();
        assert!(map.len() <= MAX_METHODS + 1, "{} series", map.len());
        assert_eq!(map["other"].count, 1000 + 1000 - (MAX_METHODS as u64 - 1));
    }

    #[test]
    fn label_values_are_escaped() {
        assert_eq!(label("a\"b\\c\nd"), "a\\\"b\\\\c\\nd");
    }
}
