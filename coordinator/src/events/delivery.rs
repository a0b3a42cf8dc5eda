//! Delivering events to their URLs: in order per URL, retried with backoff
//! while a receiver is down, within fixed bounds.
//!
//! The farm's code paths hand events to [`dispatch`] through a bounded
//! channel ([`QUEUE_EVENTS`], `try_send`: a full channel drops the event,
//! never waits). `dispatch` routes each event to the coordinator's
//! `--events-url`s and its job's `--notify` URLs, each URL with a queue of
//! its own (at most [`URL_QUEUE_EVENTS`] waiting, at most [`MAX_URLS`] URLs
//! with events waiting at once) and a task that POSTs the queue's first
//! event until the receiver takes it, then the next. Every event dropped
//! for a bound is counted (`trevi_events_dropped_total`) and logged.
//! Undelivered events are not kept across a coordinator restart.

use super::client::{Answer, Poster};
use super::event::{Event, EventKind};
use super::sign::{signature, SIGNATURE_HEADER};
use crate::scheduler::JobId;
use hyper::body::Bytes;
use std::collections::{HashMap, VecDeque};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::mpsc;

/// Events the channel from the farm to the dispatcher holds.
pub const QUEUE_EVENTS: usize = 1024;
/// Events waiting for one URL at most; one more is dropped.
pub const URL_QUEUE_EVENTS: usize = 1000;
/// URLs with events waiting at once at most; an event for one more is
/// dropped.
pub const MAX_URLS: usize = 64;
/// The first wait after a failed attempt; it doubles after each failure
/// up to [`MAX_BACKOFF`].
pub const FIRST_BACKOFF: Duration = Duration::from_millis(250);
/// The longest wait between two attempts.
pub const MAX_BACKOFF: Duration = Duration::from_secs(5);

/// What happened to events so far (the `/metrics` counters).
#[derive(Debug, Default)]
pub struct Stats {
    /// Events emitted (given a sequence number).
    pub emitted: AtomicU64,
    /// Deliveries (one event to one URL) dropped for a bound.
    pub dropped: AtomicU64,
    /// Deliveries a receiver took.
    pub delivered: AtomicU64,
    /// Deliveries a receiver refused for good (a 4xx status).
    pub refused: AtomicU64,
    /// Attempts that failed and will be retried.
    pub failed_attempts: AtomicU64,
    /// Deliveries waiting in the URLs' queues.
    pub waiting: AtomicU64,
}

impl Stats {
    /// The counters in Prometheus' text format (appended to `/metrics`).
    pub fn render(&self) -> String {
        let mut out = String::new();
        for (name, kind, help, v) in [
            (
                "emitted_total",
                "counter",
                "Job events emitted.",
                &self.emitted,
            ),
            (
                "dropped_total",
                "counter",
                "Event deliveries dropped because a queue was full (see docs/farm.md, Events).",
                &self.dropped,
            ),
            (
                "delivered_total",
                "counter",
                "Event deliveries a receiver took.",
                &self.delivered,
            ),
            (
                "refused_total",
                "counter",
                "Event deliveries a receiver refused with a 4xx status (not retried).",
                &self.refused,
            ),
            (
                "failed_attempts_total",
                "counter",
                "Event delivery attempts that failed and were retried.",
                &self.failed_attempts,
            ),
            (
                "waiting",
                "gauge",
                "Event deliveries waiting in the queues.",
                &self.waiting,
            ),
        ] {
            let v = v.load(Ordering::Relaxed);
            out += &format!(
                "# HELP trevi_events_{name} {help}\n# TYPE trevi_events_{name} {kind}\ntrevi_events_{name} {v}\n"
            );
        }
        out
    }

    /// Counts one drop and logs it, at most once a second.
    pub(super) fn drop_one(&self, why: &str) {
        static LAST: Mutex<Option<Instant>> = Mutex::new(None);
        let n = self.dropped.fetch_add(1, Ordering::Relaxed) + 1;
        let mut last = LAST.lock().unwrap_or_else(|p| p.into_inner());
        if last.is_none_or(|t| t.elapsed() >= Duration::from_secs(1)) {
            *last = Some(Instant::now());
            tracing::warn!(dropped_total = n, "job event dropped: {why}");
        }
    }
}

/// One event ready to send: its body and headers, made once for every URL.
struct Prepared {
    body: Bytes,
    headers: Vec<(&'static str, String)>,
    seq: u64,
}

/// The URLs' queues, shared by the dispatcher and the delivery tasks.
struct Queues {
    waiting: Mutex<HashMap<Arc<str>, VecDeque<Arc<Prepared>>>>,
    stats: Arc<Stats>,
    poster: Poster,
}

/// The channel end the farm emits into, and the dispatcher's task.
pub(super) fn start(
    urls: Vec<String>,
    secret: Option<Vec<u8>>,
    stats: Arc<Stats>,
    poster: Poster,
) -> mpsc::Sender<Arc<Event>> {
    let (tx, rx) = mpsc::channel(QUEUE_EVENTS);
    let queues = Arc::new(Queues {
        waiting: Mutex::default(),
        stats,
        poster,
    });
    tokio::spawn(dispatch(rx, urls, secret, queues));
    tx
}

/// Routes each event to its URLs' queues.
async fn dispatch(
    mut rx: mpsc::Receiver<Arc<Event>>,
    global: Vec<String>,
    secret: Option<Vec<u8>>,
    queues: Arc<Queues>,
) {
    let global: Vec<Arc<str>> = global.into_iter().map(Arc::from).collect();
    // The --notify URLs of each job not over yet.
    let mut own: HashMap<JobId, Vec<Arc<str>>> = HashMap::new();
    while let Some(ev) = rx.recv().await {
        if ev.event == EventKind::Submitted && !ev.notify.is_empty() {
            let urls = ev
                .notify
                .iter()
                .filter(|u| !global.iter().any(|g| **g == ***u));
            own.insert(ev.job, urls.map(|u| Arc::from(u.as_str())).collect());
        }
        let mine = if ev.event.is_final() {
            own.remove(&ev.job)
        } else {
            own.get(&ev.job).cloned()
        };
        let targets: Vec<&Arc<str>> = global.iter().chain(mine.iter().flatten()).collect();
        if targets.is_empty() {
            continue;
        }
        let prepared = Arc::new(prepare(&ev, secret.as_deref()));
        for url in targets {
            queues.push(url, prepared.clone());
        }
    }
}

fn prepare(ev: &Event, secret: Option<&[u8]>) -> Prepared {
    let body = ev.json();
    let mut headers = vec![
        ("x-trevi-event", ev.event.name().to_string()),
        ("x-trevi-seq", ev.seq.to_string()),
        ("x-trevi-job", ev.job.to_string()),
    ];
    if let Some(secret) = secret {
        headers.push((SIGNATURE_HEADER, signature(secret, body.as_bytes())));
    }
    Prepared {
        body: Bytes::from(body),
        headers,
        seq: ev.seq,
    }
}

impl Queues {
    /// Queues `ev` for `url`, starting the URL's delivery task when it has
    /// none; drops it (counted) when a bound is reached.
    fn push(self: &Arc<Self>, url: &Arc<str>, ev: Arc<Prepared>) {
        let mut waiting = self.waiting.lock().unwrap_or_else(|p| p.into_inner());
        let urls = waiting.len();
        let full = match waiting.get_mut(url) {
            Some(q) if q.len() >= URL_QUEUE_EVENTS => Some(format!(
                "{URL_QUEUE_EVENTS} events already wait for {url} (its receiver is down)"
            )),
            Some(q) => {
                q.push_back(ev);
                None
            }
            None if urls >= MAX_URLS => Some(format!(
                "{MAX_URLS} URLs already have events waiting; nothing more is queued for {url}"
            )),
            None => {
                waiting.insert(url.clone(), VecDeque::from([ev]));
                tokio::spawn(self.clone().deliver(url.clone()));
                None
            }
        };
        match full {
            // Counted before the lock is released: its task cannot take it
            // before it is counted.
            None => {
                self.stats.waiting.fetch_add(1, Ordering::Relaxed);
            }
            Some(why) => {
                drop(waiting);
                self.stats.drop_one(&why);
            }
        }
    }

    /// Sends `url`'s queue in order; ends when it is empty.
    async fn deliver(self: Arc<Self>, url: Arc<str>) {
        let uri: Option<http::Uri> = url.parse().ok();
        loop {
            let next = {
                let mut waiting = self.waiting.lock().unwrap_or_else(|p| p.into_inner());
                match waiting.get(&url).and_then(|q| q.front()) {
                    Some(ev) => ev.clone(),
                    None => {
                        waiting.remove(&url);
                        return;
                    }
                }
            };
            match &uri {
                Some(uri) => self.send(&url, uri, &next).await,
                // Checked when it was given: cannot happen; dropped, counted.
                None => self.stats.drop_one(&format!("{url} is not a URL")),
            }
            let mut waiting = self.waiting.lock().unwrap_or_else(|p| p.into_inner());
            if let Some(q) = waiting.get_mut(&url) {
                q.pop_front();
            }
            self.stats.waiting.fetch_sub(1, Ordering::Relaxed);
        }
    }

    /// Posts `ev` to `url` until the receiver takes or refuses it.
    async fn send(&self, url: &str, uri: &http::Uri, ev: &Prepared) {
        let headers: Vec<(&str, String)> =
            ev.headers.iter().map(|(n, v)| (*n, v.clone())).collect();
        let mut backoff = FIRST_BACKOFF;
        let mut failures = 0u64;
        loop {
            match self.poster.post(uri, &headers, ev.body.clone()).await {
                Answer::Taken => {
                    self.stats.delivered.fetch_add(1, Ordering::Relaxed);
                    if failures > 0 {
                        tracing::info!(url, seq = ev.seq, failures, "event receiver is back");
                    }
                    return;
                }
                Answer::Refused(status) => {
                    self.stats.refused.fetch_add(1, Ordering::Relaxed);
                    tracing::warn!(
                        url,
                        seq = ev.seq,
                        status,
                        "event refused by its receiver; not retried"
                    );
                    return;
                }
                Answer::Retry(why) => {
                    self.stats.failed_attempts.fetch_add(1, Ordering::Relaxed);
                    if failures == 0 {
                        tracing::warn!(url, seq = ev.seq, error = %why,
                            "cannot deliver a job event; retrying with backoff");
                    }
                    failures += 1;
                    tokio::time::sleep(backoff).await;
                    backoff = (backoff * 2).min(MAX_BACKOFF);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn event(seq: u64) -> Arc<Prepared> {
        Arc::new(Prepared {
            body: Bytes::from(format!("{{\"seq\":{seq}}}")),
            headers: Vec::new(),
            seq,
        })
    }

    /// A URL nobody answers (a port closed at once): its queue fills, and
    /// every event past the bound is dropped and counted, none waits. (The
    /// test's runtime has one thread and the test never yields: the
    /// delivery task does not run before the checks.)
    #[tokio::test]
    async fn a_full_url_queue_drops_and_counts() {
        let closed = {
            let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
            l.local_addr().unwrap()
        };
        let stats = Arc::new(Stats::default());
        let queues = Arc::new(Queues {
            waiting: Mutex::default(),
            stats: stats.clone(),
            poster: Poster::new().unwrap(),
        });
        let url: Arc<str> = Arc::from(format!("http://{closed}/hook"));
        let extra = 25;
        for seq in 0..(URL_QUEUE_EVENTS + extra) as u64 {
            queues.push(&url, event(seq));
        }
        // The first event is being tried (and re-tried): it still counts
        // as waiting until it is taken.
        assert_eq!(stats.dropped.load(Ordering::Relaxed), extra as u64);
        assert_eq!(
            stats.waiting.load(Ordering::Relaxed),
            URL_QUEUE_EVENTS as u64
        );
        let q = queues.waiting.lock().unwrap();
        let seqs: Vec<u64> = q[&url].iter().map(|e| e.seq).collect();
        assert_eq!(seqs, (0..URL_QUEUE_EVENTS as u64).collect::<Vec<_>>());
    }

    /// More URLs than the bound: events for the ones past it are dropped.
    #[tokio::test]
    async fn urls_past_the_bound_are_dropped_and_counted() {
        let stats = Arc::new(Stats::default());
        let queues = Arc::new(Queues {
            waiting: Mutex::default(),
            stats: stats.clone(),
            poster: Poster::new().unwrap(),
        });
        // The delivery tasks do not run before the checks (see above).
        for i in 0..MAX_URLS + 3 {
            let url: Arc<str> = Arc::from(format!("http://192.0.2.1:9/{i}"));
            queues.push(&url, event(i as u64));
        }
        assert_eq!(stats.dropped.load(Ordering::Relaxed), 3);
        assert_eq!(queues.waiting.lock().unwrap().len(), MAX_URLS);
    }
}
