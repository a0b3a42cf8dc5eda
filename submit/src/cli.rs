//! What `trevi-submit` says to a person at a terminal: a mistyped
//! subcommand, the `list` table, what happens to a farm job when the
//! submitter is interrupted, and the rule for a still's `-o`.

use crate::local::Interrupted;
use anyhow::{bail, Result};
use std::path::Path;
use trevi_proto::pb;

/// The subcommands, for suggestions (`wait` also answers to `attach`).
pub const SUBCOMMANDS: [&str; 14] = [
    "status", "list", "cancel", "fetch", "wait", "extend", "pause", "resume", "retry", "requeue",
    "unblock", "log", "usage", "attach",
];

/// A scene argument that is no file and does not look like a scene (no
/// `.xml`, no directory): most likely a mistyped subcommand. Returns the
/// message to print (exit status 2), naming the closest subcommand if one
/// is near.
pub fn mistyped_subcommand(arg: &Path) -> Option<String> {
    if arg.exists() {
        return None;
    }
    let text = arg.to_string_lossy();
    let looks_like_a_scene = text.to_ascii_lowercase().ends_with(".xml")
        || text.contains('/')
        || text.contains(std::path::MAIN_SEPARATOR);
    if looks_like_a_scene {
        return None;
    }
    let best = SUBCOMMANDS
        .iter()
        .map(|c| (edit_distance(&text, c), *c))
        .min()
        .filter(|&(d, c)| d <= 2.max(c.len() / 3));
    Some(match best {
        Some((_, c)) => format!(
            "\"{text}\" is neither a scene file nor a subcommand: did you mean \
             `trevi-submit {c}`? (see --help)"
        ),
        None => format!(
            "\"{text}\" is neither a scene file nor a subcommand ({}); see --help",
            SUBCOMMANDS[..13].join(", ")
        ),
    })
}

/// Levenshtein distance of two short words (the first argument is
/// bounded: only words that are not files get here, and only the first
/// 64 characters count).
fn edit_distance(a: &str, b: &str) -> usize {
    let a: Vec<char> = a.chars().take(64).collect();
    let b: Vec<char> = b.chars().collect();
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.iter().enumerate() {
        let mut cur = vec![i + 1; b.len() + 1];
        for (j, cb) in b.iter().enumerate() {
            let swap = usize::from(ca != cb);
            cur[j + 1] = (prev[j] + swap).min(prev[j + 1] + 1).min(cur[j] + 1);
        }
        prev = cur;
    }
    prev[b.len()]
}

/// The header of `list`'s table (see [`list_row`]). `QUEUED` is the time a
/// job waited for its first tile to be leased, `RENDER` the time since.
pub fn list_header() -> String {
    format!(
        "{:>6}  {:<9}  {:<16}  {:<12}  {:>11}  {:>13}  {:>8}  {:>9}  {:>9}  {:<15}  {:<12}  OUTPUT",
        "ID",
        "STATE",
        "SCENE",
        "CAMERA",
        "SIZE",
        "TILES",
        "PRIORITY",
        "QUEUED",
        "RENDER",
        "SUBMITTER",
        "BUNDLE"
    )
}

/// Seconds of `ms` milliseconds, as `list` and `status` show them.
pub fn seconds(ms: u64) -> String {
    format!("{:.1} s", ms as f64 / 1e3)
}

/// One job of `list`: its id first (scripts read it), the columns of
/// [`list_header`], then a sequence's frames, a progressive job's samples
/// per pixel (`spp 16/64`: in the output and asked for) and an error if
/// any.
pub fn list_row(s: &pb::JobStatus) -> String {
    let mut line = format!(
        "{:>6}  {:<9}  {:<16}  {:<12}  {:>11}  {:>13}  {:>8}  {:>9}  {:>9}  {:<15}  {:<12}  {}",
        s.id,
        crate::control::state_word(s),
        or_dash(&s.scene),
        s.camera,
        format!("{}x{}", s.width, s.height),
        format!("{}/{}", s.tiles_done, s.tiles_total),
        s.priority,
        seconds(s.queued_ms),
        seconds(s.render_ms),
        or_dash(&s.submitter),
        s.bundle_hash.get(..12).unwrap_or(&s.bundle_hash),
        s.output_name,
    );
    if let Some(f) = s.frames {
        line.push_str(&format!(
            "  frames {}-{}: {} done",
            f.first, f.last, s.frames_done
        ));
    }
    if let Some(p) = &s.passes {
        line.push_str(&format!("  spp {}", crate::passes::spp(p)));
    }
    line.push_str(&crate::control::waiting_note(s));
    if !s.error.is_empty() {
        line.push_str(&format!("  error: {}", s.error));
    }
    line
}

/// `s`, or "-" when it is empty (a column must not vanish).
fn or_dash(s: &str) -> &str {
    if s.is_empty() {
        "-"
    } else {
        s
    }
}

/// A submitter interrupted while it followed farm jobs: the jobs go on
/// without it. Its message says so and how to follow or stop them; the
/// exit status is the signal's (128 + its number).
#[derive(Debug)]
pub struct LeftRunning {
    pub signal: Interrupted,
    what: String,
}

impl LeftRunning {
    pub fn new(signal: Interrupted, jobs: &[u64], url: &str) -> LeftRunning {
        let what = match jobs {
            [] => "nothing was submitted".to_string(),
            [one] => format!(
                "job {one} keeps running on the farm: follow it and download its \
                 output with `trevi-submit wait {one} --coordinator {url}`, or stop \
                 it with `trevi-submit cancel {one} --coordinator {url}`"
            ),
            _ => {
                let list: Vec<String> = jobs.iter().map(u64::to_string).collect();
                format!(
                    "jobs {} keep running on the farm: follow each and download its \
                     output with `trevi-submit wait ID --coordinator {url}`, or stop \
                     each with `trevi-submit cancel ID --coordinator {url}`",
                    list.join(", ")
                )
            }
        };
        LeftRunning { signal, what }
    }
}

impl std::fmt::Display for LeftRunning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "interrupted by {}: {}", self.signal.name, self.what)
    }
}

impl std::error::Error for LeftRunning {}

/// An error and its causes, `: `-separated like anyhow's `{:#}`, but a
/// cause that its error's message already ends with is not repeated (an
/// I/O error wrapped with its path would read "…: Not a directory: Not a
/// directory").
pub fn error_text(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if out.ends_with(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
    }
    out
}

/// A still's `-o` (or `output=`): the scene parser's rule, no `#` at all
/// (a frame-number pattern is for a sequence; in a directory it would
/// make a directory named by it).
pub fn still_output(out: &Path) -> Result<()> {
    let text = out.to_string_lossy();
    match trevi_core::scene::animation::frame_runs(&text) {
        Some(0) => Ok(()),
        Some(_) => bail!(
            "{}: a frame-number pattern (#) is only for a sequence (give --frames, \
             or a name without #)",
            out.display()
        ),
        None => bail!(
            "{}: # may only be in the file name, as one run for the frame number \
             (like shot.####.png)",
            out.display()
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mistyped_subcommand_is_named_and_a_scene_is_not() {
        let m = mistyped_subcommand(Path::new("lsit")).unwrap();
        assert!(m.contains("trevi-submit list"), "{m}");
        let m = mistyped_subcommand(Path::new("fecth")).unwrap();
        assert!(m.contains("trevi-submit fetch"), "{m}");
        let m = mistyped_subcommand(Path::new("render")).unwrap();
        assert!(!m.contains("did you mean"), "{m}");
        assert_eq!(mistyped_subcommand(Path::new("missing.xml")), None);
        assert_eq!(mistyped_subcommand(Path::new("scenes/missing")), None);
        // Long words cost at most 64 characters of work.
        assert!(mistyped_subcommand(Path::new(&"x".repeat(100_000))).is_some());
    }

    #[test]
    fn an_interrupted_submission_names_its_jobs_and_the_commands() {
        let sig = Interrupted {
            name: "SIGINT",
            code: 130,
        };
        let m = LeftRunning::new(sig, &[7], "http://h:1").to_string();
        assert!(m.contains("job 7 keeps running"), "{m}");
        assert!(
            m.contains("trevi-submit wait 7 --coordinator http://h:1"),
            "{m}"
        );
        assert!(
            m.contains("trevi-submit cancel 7 --coordinator http://h:1"),
            "{m}"
        );
        let m = LeftRunning::new(sig, &[], "u").to_string();
        assert!(m.contains("nothing was submitted"), "{m}");
    }

    #[test]
    fn an_error_s_cause_is_said_once() {
        let io = std::io::Error::from_raw_os_error(20);
        let said = io.to_string();
        let e = trevi_core::OutputError::Io {
            path: "/dev/full/x.png".into(),
            source: io,
        };
        let e = anyhow::Error::new(e).context("frame 3");
        let text = error_text(&e);
        assert_eq!(text.matches(&said).count(), 1, "{text}");
        assert!(text.starts_with("frame 3: /dev/full/x.png: "), "{text}");
    }

    #[test]
    fn a_still_output_has_no_hash() {
        assert!(still_output(Path::new("out/a.png")).is_ok());
        for bad in ["a.#.png", "d#/a.png", "d#/f.#.png"] {
            assert!(still_output(Path::new(bad)).is_err(), "{bad}");
        }
    }

    #[test]
    fn the_list_header_lines_up_with_its_rows() {
        let s = pb::JobStatus {
            id: 7,
            camera: "main".into(),
            scene: "shot.xml".into(),
            submitter: "10.0.0.7".into(),
            queued_ms: 2500,
            render_ms: 12_000,
            ..Default::default()
        };
        let (h, r) = (list_header(), list_row(&s));
        assert_eq!(h.find("STATE"), r.find(s.state().label()));
        assert_eq!(h.find("SCENE"), r.find("shot.xml"));
        assert_eq!(h.find("SUBMITTER"), r.find("10.0.0.7"));
        // The times are right-aligned under their headers.
        let end = |hay: &str, needle: &str| hay.find(needle).map(|i| i + needle.len());
        assert_eq!(end(&h, "QUEUED"), end(&r, "2.5 s"));
        assert_eq!(end(&h, "RENDER"), end(&r, "12.0 s"));
        assert_eq!(r.split_whitespace().next(), Some("7"));
    }

    #[test]
    fn a_progressive_job_s_row_ends_with_its_samples() {
        let mut s = pb::JobStatus {
            id: 7,
            output_name: "a.png".into(),
            ..Default::default()
        };
        let plain = list_row(&s);
        assert!(!plain.contains("spp"), "{plain}");
        s.passes = Some(pb::PassesInfo {
            samples_done: 16,
            samples_total: 64,
            ..Default::default()
        });
        assert_eq!(list_row(&s), format!("{plain}  spp 16/64"));
    }
}
