//! Job events: what happens to each job (submitted, started, paused,
//! resumed, frame done, done, failed, cancelled), numbered in the order the
//! coordinator emits them, POSTed to webhooks and streamed to the monitor.
//!
//! - `event.rs`: the [`Event`] and its JSON.
//! - `sign.rs`: the HMAC-SHA256 signature of each body.
//! - `targets.rs`: checking `--notify` and `--events-url` URLs.
//! - `delivery.rs`: the bounded queues and the tasks that POST, in order
//!   per URL, retrying with backoff; `client.rs`: one POST.
//! - [`Events`] (here): what the farm calls at each transition, and the
//!   fan-out to `GET /events` subscribers.
//!
//! Emitting never waits: the event gets its number under a short lock, is
//! handed to the delivery queue with `try_send` (dropped and counted when
//! full) and to the subscribers through a broadcast channel (a subscriber
//! that falls [`SSE_BUFFER`] events behind is dropped).
//!
//! Which jobs have events: the jobs a submitter sees (a still, a sequence,
//! a progressive job), not the frames or passes a sequence runs as jobs of
//! their own; a frame is told as [`EventKind::FrameDone`] of its sequence.

mod client;
mod delivery;
mod event;
mod sign;
mod targets;

pub use delivery::{Stats, FIRST_BACKOFF, MAX_BACKOFF, MAX_URLS, QUEUE_EVENTS, URL_QUEUE_EVENTS};
pub use event::{Event, EventKind};
pub use sign::{hmac_sha256, signature, verify, SIGNATURE_HEADER};
pub use targets::{check_urls, MAX_NOTIFY_URLS, MAX_URL_BYTES};

use crate::error::FarmError;
use crate::scheduler::{JobId, Outcome};
use std::collections::HashMap;
use std::path::Path;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use tokio::sync::{broadcast, mpsc};

/// Events a `GET /events` subscriber may fall behind before it is dropped.
pub const SSE_BUFFER: usize = 256;
/// Most `GET /events` subscribers at once; one more is refused (503).
pub const MAX_SSE_SUBSCRIBERS: usize = 16;
/// Largest `--events-secret-file`, in bytes.
pub const MAX_SECRET_BYTES: usize = 4096;

/// Where the coordinator sends every job's events.
#[derive(Debug, Clone, Default)]
pub struct EventsConfig {
    /// `--events-url`: receives every job's events (checked by
    /// [`check_urls`]).
    pub urls: Vec<String>,
    /// `--events-secret-file`'s secret: each POST carries the body's
    /// HMAC-SHA256 under it; `None`: sent unsigned.
    pub secret: Option<Vec<u8>>,
}

impl EventsConfig {
    /// Reads the secret of `--events-secret-file`: its bytes without
    /// surrounding whitespace, not empty, at most [`MAX_SECRET_BYTES`].
    pub fn read_secret(path: &Path) -> Result<Vec<u8>, FarmError> {
        let len = std::fs::metadata(path)
            .map_err(|e| FarmError::io(format!("cannot read {}", path.display()), e))?
            .len();
        if len > MAX_SECRET_BYTES as u64 {
            return Err(FarmError::Invalid(format!(
                "{}: {len} bytes, more than the {MAX_SECRET_BYTES} an events secret may have",
                path.display()
            )));
        }
        let bytes = std::fs::read(path)
            .map_err(|e| FarmError::io(format!("cannot read {}", path.display()), e))?;
        let secret = bytes.trim_ascii().to_vec();
        if secret.is_empty() {
            return Err(FarmError::Invalid(format!(
                "{}: the events secret is empty",
                path.display()
            )));
        }
        Ok(secret)
    }
}

/// What the farm calls when a job changes, and the subscribers' channel.
pub struct Events {
    inner: Mutex<Inner>,
    sse: broadcast::Sender<Arc<Event>>,
    stats: Arc<Stats>,
}

struct Inner {
    /// The last sequence number given.
    seq: u64,
    /// To the delivery queue, once [`Events::start`] ran.
    tx: Option<mpsc::Sender<Arc<Event>>>,
    /// The jobs with events not over yet, and whether each started.
    live: HashMap<JobId, bool>,
}

impl Default for Events {
    fn default() -> Self {
        Events {
            inner: Mutex::new(Inner {
                seq: 0,
                tx: None,
                live: HashMap::new(),
            }),
            sse: broadcast::channel(SSE_BUFFER).0,
            stats: Arc::default(),
        }
    }
}

impl Events {
    /// Starts delivering events to `cfg`'s URLs and to the jobs' own
    /// `--notify` URLs (call once, in the tokio runtime). Before this, events
    /// go to the subscribers only.
    pub fn start(&self, cfg: EventsConfig) -> Result<(), FarmError> {
        let urls = check_urls(&cfg.urls, "--events-url")?;
        let poster = client::Poster::new()
            .map_err(|e| FarmError::Invalid(format!("cannot set up TLS for events: {e}")))?;
        let tx = delivery::start(urls, cfg.secret, self.stats.clone(), poster);
        self.lock().tx = Some(tx);
        Ok(())
    }

    /// The counters `/metrics` shows.
    pub fn stats(&self) -> &Stats {
        &self.stats
    }

    /// A new `GET /events` subscriber, or `None` when
    /// [`MAX_SSE_SUBSCRIBERS`] are subscribed.
    pub fn subscribe(&self) -> Option<broadcast::Receiver<Arc<Event>>> {
        let _inner = self.lock();
        (self.sse.receiver_count() < MAX_SSE_SUBSCRIBERS).then(|| self.sse.subscribe())
    }

    /// A job was queued, with `notify` its own event URLs (`--notify`,
    /// already checked by [`check_urls`]; emitted with the farm locked, so
    /// no event of the job can go out before its URLs are known).
    pub fn submitted(&self, job: JobId, notify: &[String]) {
        let notify = (!notify.is_empty()).then(|| Arc::from(notify));
        let mut inner = self.lock();
        inner.live.insert(job, false);
        self.emit(&mut inner, job, EventKind::Submitted, None, None, notify);
    }

    /// A job found unfinished in the database at start-up, or a finished
    /// progressive job extended: it has events again, and its next lease
    /// emits [`EventKind::Started`] (a restored job's `--notify` URLs are
    /// not kept across a restart; an extended job keeps none either).
    pub fn restored(&self, job: JobId) {
        self.lock().live.entry(job).or_insert(false);
    }

    /// A worker leased a tile of `job` (a frame's: its sequence's id): the
    /// job's first lease emits [`EventKind::Started`].
    pub fn leased(&self, job: JobId) {
        let mut inner = self.lock();
        if let Some(started @ false) = inner.live.get_mut(&job) {
            *started = true;
            self.emit(&mut inner, job, EventKind::Started, None, None, None);
        }
    }

    /// `job` was paused.
    pub fn paused(&self, job: JobId) {
        self.job_event(job, EventKind::Paused, None, None);
    }

    /// `job` was resumed.
    pub fn resumed(&self, job: JobId) {
        self.job_event(job, EventKind::Resumed, None, None);
    }

    /// Frame `frame` of sequence `seq` is done (`None`: the run was not a
    /// frame, but a pass of a progressive still; nothing is emitted).
    pub fn frame_done(&self, seq: JobId, frame: Option<u32>) {
        if frame.is_some() {
            self.job_event(seq, EventKind::FrameDone, frame, None);
        }
    }

    /// `job` ended with `result` (done or failed).
    pub fn ended(&self, job: JobId, result: &Outcome) {
        match result {
            Ok(()) => self.job_event(job, EventKind::Done, None, None),
            Err(e) => self.job_event(job, EventKind::Failed, None, Some(e.to_string())),
        }
    }

    /// `job` was cancelled.
    pub fn cancelled(&self, job: JobId) {
        self.job_event(job, EventKind::Cancelled, None, None);
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Emits `kind` for `job` if the job has events (see the module
    /// documentation).
    fn job_event(&self, job: JobId, kind: EventKind, frame: Option<u32>, error: Option<String>) {
        let mut inner = self.lock();
        if inner.live.contains_key(&job) {
            self.emit(&mut inner, job, kind, frame, error, None);
        }
    }

    fn emit(
        &self,
        inner: &mut Inner,
        job: JobId,
        kind: EventKind,
        frame: Option<u32>,
        error: Option<String>,
        notify: Option<Arc<[String]>>,
    ) {
        inner.seq += 1;
        if kind.is_final() {
            inner.live.remove(&job);
        }
        let time_ms = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_millis() as u64);
        let ev = Arc::new(Event {
            seq: inner.seq,
            event: kind,
            job,
            time_ms,
            frame,
            error,
            notify: notify.unwrap_or_else(|| Arc::from(Vec::new())),
        });
        self.stats.emitted.fetch_add(1, Ordering::Relaxed);
        tracing::debug!(seq = ev.seq, job, event = kind.name(), "job event");
        // No subscriber: an error, nothing to do.
        let _ = self.sse.send(ev.clone());
        if let Some(tx) = &inner.tx {
            match tx.try_send(ev) {
                Ok(()) => {}
                Err(mpsc::error::TrySendError::Full(_)) => self.stats.drop_one(&format!(
                    "the delivery queue holds {QUEUE_EVENTS} events already"
                )),
                Err(mpsc::error::TrySendError::Closed(_)) => {
                    self.stats.drop_one("the delivery task stopped")
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scheduler::JobFailure;

    fn kinds(rx: &mut broadcast::Receiver<Arc<Event>>) -> Vec<(u64, EventKind, JobId)> {
        let mut out = Vec::new();
        while let Ok(e) = rx.try_recv() {
            out.push((e.seq, e.event, e.job));
        }
        out
    }

    #[test]
    fn a_job_s_events_are_numbered_in_order_and_only_its_first_lease_starts_it() {
        let ev = Events::default();
        let mut rx = ev.subscribe().unwrap();
        ev.submitted(1, &[]);
        ev.leased(1);
        ev.leased(1);
        ev.leased(7); // A frame (or a job without events): nothing.
        ev.frame_done(1, Some(3));
        ev.frame_done(1, None);
        ev.paused(1);
        ev.resumed(1);
        ev.submitted(2, &[]);
        ev.ended(2, &Err(JobFailure::Output("disk full".into())));
        ev.ended(1, &Ok(()));
        ev.cancelled(1); // Over already: nothing.
        use EventKind::*;
        assert_eq!(
            kinds(&mut rx),
            vec![
                (1, Submitted, 1),
                (2, Started, 1),
                (3, FrameDone, 1),
                (4, Paused, 1),
                (5, Resumed, 1),
                (6, Submitted, 2),
                (7, Failed, 2),
                (8, Done, 1),
            ]
        );
        assert_eq!(ev.stats().emitted.load(Ordering::Relaxed), 8);
    }

    #[test]
    fn notify_urls_reach_only_the_submission_made_with_them() {
        let ev = Events::default();
        let mut rx = ev.subscribe().unwrap();
        let urls = vec!["http://127.0.0.1:1/a".to_string()];
        ev.submitted(1, &urls);
        ev.submitted(2, &[]);
        let a = rx.try_recv().unwrap();
        let b = rx.try_recv().unwrap();
        assert_eq!((a.job, &a.notify[..]), (1, &urls[..]));
        assert_eq!((b.job, b.notify.len()), (2, 0));
    }

    #[test]
    fn subscribers_are_bounded_and_a_slow_one_is_dropped() {
        let ev = Events::default();
        let mut subs: Vec<_> = (0..MAX_SSE_SUBSCRIBERS)
            .map(|_| ev.subscribe().unwrap())
            .collect();
        assert!(ev.subscribe().is_none());
        subs.pop();
        let mut slow = ev.subscribe().unwrap();
        for job in 0..SSE_BUFFER as u64 + 1 {
            ev.submitted(job, &[]);
        }
        assert!(matches!(
            slow.try_recv(),
            Err(broadcast::error::TryRecvError::Lagged(1))
        ));
    }

    /// The farm never waits on delivery: with the dispatcher's channel full
    /// (its task not running), more events are dropped and counted.
    #[tokio::test]
    async fn a_full_delivery_queue_drops_and_counts() {
        let ev = Events::default();
        ev.start(EventsConfig {
            urls: vec!["http://127.0.0.1:1/".into()],
            secret: None,
        })
        .unwrap();
        // The dispatcher has not run (this runtime has one thread and the
        // test does not yield), so the channel holds QUEUE_EVENTS.
        for job in 0..QUEUE_EVENTS as u64 + 10 {
            ev.submitted(job, &[]);
        }
        assert_eq!(ev.stats().dropped.load(Ordering::Relaxed), 10);
        assert_eq!(
            ev.stats().emitted.load(Ordering::Relaxed),
            QUEUE_EVENTS as u64 + 10
        );
    }

    #[test]
    fn a_secret_file_is_bounded_and_not_empty() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("secret");
        std::fs::write(&p, "  s3cret\n").unwrap();
        assert_eq!(EventsConfig::read_secret(&p).unwrap(), b"s3cret");
        std::fs::write(&p, " \n").unwrap();
        let e = EventsConfig::read_secret(&p).unwrap_err().to_string();
        assert!(e.contains("empty"), "{e}");
        std::fs::write(&p, vec![b'a'; MAX_SECRET_BYTES + 1]).unwrap();
        let e = EventsConfig::read_secret(&p).unwrap_err().to_string();
        assert!(e.contains("4097 bytes"), "{e}");
        let e = EventsConfig::read_secret(&dir.path().join("none"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("cannot read"), "{e}");
    }
}
