//! One job event as receivers see it: what happened, to which job, and the
//! coordinator's sequence number that orders every event it emits.

use crate::scheduler::JobId;
use serde::Serialize;
use std::sync::Arc;

/// What happened to a job.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum EventKind {
    /// The job was queued (a still, a sequence or a progressive job).
    Submitted,
    /// A worker took the job's first tile (after a coordinator restart, the
    /// first tile after the restart).
    Started,
    /// The job was paused: it takes no more tiles until resumed.
    Paused,
    /// A paused job takes tiles again.
    Resumed,
    /// One frame of a sequence is done (`frame` says which).
    FrameDone,
    /// The job's output is finished.
    Done,
    /// The job failed (`error` says why).
    Failed,
    /// The job was cancelled.
    Cancelled,
}

impl EventKind {
    /// The name the JSON carries (`"frame_done"`), also sent as the
    /// `X-Trevi-Event` header and the SSE `event:` field.
    pub fn name(self) -> &'static str {
        match self {
            EventKind::Submitted => "submitted",
            EventKind::Started => "started",
            EventKind::Paused => "paused",
            EventKind::Resumed => "resumed",
            EventKind::FrameDone => "frame_done",
            EventKind::Done => "done",
            EventKind::Failed => "failed",
            EventKind::Cancelled => "cancelled",
        }
    }

    /// Whether the job is over after this event (no more follow).
    pub fn is_final(self) -> bool {
        matches!(
            self,
            EventKind::Done | EventKind::Failed | EventKind::Cancelled
        )
    }
}

/// One event, as POSTed (its JSON body) and streamed on `GET /events`.
#[derive(Debug, Clone, Serialize)]
pub struct Event {
    /// This coordinator's sequence number: 1 for the first event it emitted,
    /// one more for each later one, across all jobs. A gap means events were
    /// dropped (the queue was full); a repeat means a delivery was retried
    /// after the receiver took it but its answer was lost.
    pub seq: u64,
    /// What happened.
    pub event: EventKind,
    /// The job (for a frame of a sequence: the sequence).
    pub job: JobId,
    /// When, in milliseconds since the Unix epoch (the coordinator's clock).
    pub time_ms: u64,
    /// For [`EventKind::FrameDone`]: the frame.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub frame: Option<u32>,
    /// For [`EventKind::Failed`]: why, as `trevi-submit status` says it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// For [`EventKind::Submitted`]: the job's own `--notify` URLs, which
    /// receive this and every later event of the job (not sent).
    #[serde(skip)]
    pub notify: Arc<[String]>,
}

impl Event {
    /// The JSON body of the event.
    pub fn json(&self) -> String {
        // A struct of plain fields: serializing it cannot fail.
        serde_json::to_string(self).unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_json_names_the_event_and_leaves_out_what_does_not_apply() {
        let e = Event {
            seq: 7,
            event: EventKind::FrameDone,
            job: 42,
            time_ms: 1000,
            frame: Some(3),
            error: None,
            notify: Arc::from(vec!["http://x/".to_string()]),
        };
        let v: serde_json::Value = serde_json::from_str(&e.json()).unwrap();
        assert_eq!(
            v,
            serde_json::json!({"seq": 7, "event": "frame_done", "job": 42, "time_ms": 1000, "frame": 3})
        );
        assert_eq!(v["event"], EventKind::FrameDone.name());
    }
}
