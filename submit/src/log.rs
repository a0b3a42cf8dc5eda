//! What `trevi-submit log` prints (a job's tile log as a table), the
//! blocked workers `status` and `unblock` list under a job, and the
//! `--tile X,Y` flag's reader.

use trevi_proto::pb;

/// Reads `--tile X,Y`: a pixel of the frame (the tile holding it).
pub fn pixel(s: &str) -> Result<(u32, u32), String> {
    let (x, y) = s
        .split_once(',')
        .ok_or_else(|| format!("\"{s}\" is not X,Y (a pixel of the frame, like 64,128)"))?;
    let n = |v: &str| {
        v.trim()
            .parse::<u32>()
            .map_err(|_| format!("\"{v}\" in \"{s}\" is not a whole number of pixels"))
    };
    Ok((n(x)?, n(y)?))
}

/// One line a blocked worker, for under a job's status.
pub fn blocked_lines(blocked: &[pb::BlockedWorker]) -> Vec<String> {
    blocked
        .iter()
        .map(|b| {
            let who = match (b.worker_id, b.name.is_empty()) {
                (0, _) => format!("{} (before the coordinator restarted)", b.name),
                (id, true) => format!("worker {id}"),
                (id, false) => format!("{} (worker {id})", b.name),
            };
            let frame = b.frame.map(|f| format!(" frame {f}")).unwrap_or_default();
            format!(
                "  blocked{frame}: {who}, {} tiles failed, last: {}",
                b.failures,
                one_line(&b.last_error)
            )
        })
        .collect()
}

/// `text` on one line (a worker's error may hold line breaks).
fn one_line(text: &str) -> String {
    text.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// Milliseconds since the Unix epoch as a UTC time of day.
fn clock(ms: u64) -> String {
    let s = ms / 1000;
    format!("{:02}:{:02}:{:02}", s / 3600 % 24, s / 60 % 60, s % 60)
}

/// Microseconds as seconds with three decimals; `-` when not reported.
fn seconds(us: Option<u64>) -> String {
    us.map_or_else(|| "-".into(), |u| format!("{:.3}", u as f64 / 1e6))
}

/// The table's header line.
pub const HEADER: &str = "TILE                 FRAME  WORKER               AT (UTC)   RENDER s   CPU s       RAYS  RETRIES  ERROR";

/// A job's tile log as a table: a header, a row a lease (oldest first),
/// then what the bound dropped.
pub fn table(log: &pb::TileLog) -> String {
    let mut out = String::from(HEADER);
    out.push('\n');
    for e in &log.entries {
        let r = e.rect.unwrap_or_default();
        let tile = format!("{},{} {}x{}", r.x, r.y, r.w, r.h);
        let frame = match (e.frame, e.pass) {
            (Some(f), _) => f.to_string(),
            (None, Some(p)) => format!("p{p}"),
            (None, None) => "-".into(),
        };
        let worker = match e.worker_name.as_str() {
            "" => e.worker_id.to_string(),
            n => format!("{n} ({})", e.worker_id),
        };
        let error = if e.error.is_empty() {
            "-".to_string()
        } else {
            one_line(&e.error)
        };
        out.push_str(&format!(
            "{tile:<20} {frame:>5}  {worker:<20} {:>8}  {:>9}  {:>6}  {:>9}  {:>7}  {error}\n",
            clock(e.at_ms),
            seconds(e.render_micros),
            seconds(e.cpu_micros),
            e.rays,
            e.retries,
        ));
    }
    if log.omitted > 0 {
        out.push_str(&format!(
            "({} older entries matched but are not shown: the reply holds about 3 MiB)\n",
            log.omitted
        ));
    }
    if log.dropped > 0 || log.errors_dropped > 0 {
        out.push_str(&format!(
            "({} oldest entries dropped to keep the job's log bounded, {} of the errors)\n",
            log.dropped.max(log.errors_dropped),
            log.errors_dropped
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pixel_is_two_whole_numbers() {
        assert_eq!(pixel("64, 128"), Ok((64, 128)));
        assert!(pixel("64").unwrap_err().contains("X,Y"));
        assert!(pixel("a,1").unwrap_err().contains("\"a\""));
    }

    #[test]
    fn the_table_shows_the_worker_times_and_errors_with_a_dash_for_what_is_missing() {
        let log = pb::TileLog {
            entries: vec![
                pb::TileLogEntry {
                    at_ms: 3_723_000,
                    worker_id: 9,
                    worker_name: "bad".into(),
                    rect: Some(pb::Rect {
                        x: 64,
                        y: 0,
                        w: 64,
                        h: 64,
                    }),
                    tiles: 1,
                    error: "worker 9: the render\npanicked".into(),
                    ..Default::default()
                },
                pb::TileLogEntry {
                    worker_id: 3,
                    worker_name: "good".into(),
                    tiles: 1,
                    render_micros: Some(1_500_000),
                    rays: 4096,
                    retries: 1,
                    ..Default::default()
                },
            ],
            errors_dropped: 2,
            ..Default::default()
        };
        let t = table(&log);
        let lines: Vec<&str> = t.lines().collect();
        assert_eq!(lines[0], HEADER);
        assert!(lines[1].starts_with("64,0 64x64"), "{}", lines[1]);
        assert!(lines[1].contains("bad (9)") && lines[1].contains("01:02:03"));
        assert!(
            lines[1].ends_with("worker 9: the render panicked"),
            "{}",
            lines[1]
        );
        assert!(lines[2].contains("1.500") && lines[2].contains("4096"));
        // No CPU time reported, no error: dashes.
        assert_eq!(lines[2].matches(" - ").count() + 1, 3, "{}", lines[2]);
        assert!(lines[3].contains("2 of the errors"), "{}", lines[3]);
        // The header's columns sit over the rows'.
        assert_eq!(
            HEADER.find("RAYS").map(|i| i + 4),
            lines[2].find("4096").map(|i| i + 4)
        );
    }
}
