//! The blocklists and the tile log on the wire: `UnblockWorker` and
//! `GetTileLog` of `trevi.v1.Jobs` (their handlers in `jobs.rs` call these),
//! and a job's blocked workers in its `JobStatus`.

use super::blocking;
use crate::farm::Farm;
use crate::scheduler::Blocked;
use crate::store::{JobLog, LogFilter};
use crate::FarmError;
use std::sync::Arc;
use tonic::Status;
use trevi_proto::pb;

/// Most characters of the worker an unblock names (a name is at most 64).
pub const MAX_UNBLOCK_WORKER_CHARS: usize = 64;

/// The blocked workers as `JobStatus.blocked` carries them.
pub fn blocked_status(blocked: &[Blocked]) -> Vec<pb::BlockedWorker> {
    blocked
        .iter()
        .map(|b| pb::BlockedWorker {
            worker_id: b.worker.unwrap_or(0),
            name: b.name.clone(),
            failures: b.failures,
            last_error: b.last_error.clone(),
            frame: b.frame,
        })
        .collect()
}

/// Checks the worker an unblock names: not empty, at most
/// [`MAX_UNBLOCK_WORKER_CHARS`] characters.
pub fn check_unblock_worker(who: &str) -> Result<&str, FarmError> {
    let who = who.trim();
    if who.is_empty() {
        return Err(FarmError::Invalid(
            "name the worker to unblock: its id or its name, as `status` shows it".into(),
        ));
    }
    if who.chars().count() > MAX_UNBLOCK_WORKER_CHARS {
        return Err(FarmError::Invalid(format!(
            "a worker is named by at most {MAX_UNBLOCK_WORKER_CHARS} characters (its id or \
             its name)"
        )));
    }
    Ok(who)
}

/// A log request's filter; a pixel needs both coordinates.
pub fn log_filter(r: &pb::TileLogRequest) -> Result<LogFilter, FarmError> {
    let pixel = match (r.x, r.y) {
        (Some(x), Some(y)) => Some((x, y)),
        (None, None) => None,
        _ => {
            return Err(FarmError::Invalid(
                "a tile is named by both x and y (a pixel it holds)".into(),
            ))
        }
    };
    Ok(LogFilter {
        frame: r.frame,
        pixel,
        errors_only: r.errors_only,
    })
}

/// A job's log as `GetTileLog` answers it.
pub fn log_reply(log: JobLog) -> pb::TileLog {
    pb::TileLog {
        entries: log
            .entries
            .into_iter()
            .map(|e| pb::TileLogEntry {
                at_ms: e.at_ms,
                worker_id: e.worker,
                worker_name: e.worker_name,
                frame: e.frame,
                pass: e.pass,
                rect: Some(e.rect.into()),
                tiles: e.tiles,
                render_micros: e.render_micros,
                cpu_micros: e.cpu_micros,
                rays: e.rays,
                retries: e.retries,
                error: e.error.unwrap_or_default(),
            })
            .collect(),
        dropped: log.dropped,
        errors_dropped: log.errors_dropped,
        omitted: log.omitted,
    }
}

/// `GetTileLog`.
pub async fn get_tile_log(farm: &Arc<Farm>, r: pb::TileLogRequest) -> Result<pb::TileLog, Status> {
    let filter = log_filter(&r)?;
    let farm = farm.clone();
    let log = blocking(move || farm.tile_log(r.id, filter)).await?;
    Ok(log_reply(log))
}

/// `UnblockWorker`.
pub async fn unblock(
    farm: &Arc<Farm>,
    r: pb::UnblockWorkerRequest,
) -> Result<pb::JobStatus, Status> {
    let who = check_unblock_worker(&r.worker)?.to_string();
    let farm = farm.clone();
    let info = blocking(move || farm.unblock(r.id, &who)).await?;
    Ok(super::job_status(&info))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_request_naming_half_a_pixel_or_no_worker_is_refused() {
        let half = pb::TileLogRequest {
            id: 1,
            x: Some(3),
            ..Default::default()
        };
        assert!(log_filter(&half)
            .unwrap_err()
            .to_string()
            .contains("both x and y"));
        let whole = pb::TileLogRequest {
            x: Some(3),
            y: Some(4),
            errors_only: true,
            ..half
        };
        let f = log_filter(&whole).unwrap();
        assert_eq!((f.pixel, f.errors_only), (Some((3, 4)), true));
        assert!(check_unblock_worker("  ").is_err());
        assert!(check_unblock_worker(&"w".repeat(65)).is_err());
        assert_eq!(check_unblock_worker(" w1 ").unwrap(), "w1");
    }
}
