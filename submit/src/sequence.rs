//! A sequence's frames and files: `--frames` (or the scene's `frames=`)
//! and the output pattern whose run of `#` is replaced by each frame's
//! number. A sequence renders like a still, on a farm or on the embedded
//! one, as one job of frames (see `client/submit.rs`).

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use trevi_core::output::Format;
use trevi_core::scene::animation::{frame_output, Frames, MAX_FRAME};

/// `--frames`: `first-last` or one frame number, in [0, MAX_FRAME].
pub fn parse_frames(s: &str) -> Result<Frames, String> {
    let num = |t: &str| {
        t.trim()
            .parse::<u32>()
            .ok()
            .filter(|&n| n <= MAX_FRAME)
            .ok_or_else(|| format!("\"{t}\" is not a frame number in [0, {MAX_FRAME}]"))
    };
    let (first, last) = match s.split_once('-') {
        Some((a, b)) => (num(a)?, num(b)?),
        None => (num(s)?, num(s)?),
    };
    if first > last {
        return Err(format!("{first}-{last} is reversed (write first-last)"));
    }
    Ok(Frames { first, last })
}

/// A sequence's frames and the pattern of their files.
#[derive(Debug, Clone)]
pub struct Sequence {
    pub frames: Frames,
    /// With one run of `#` in its file name (see [`frame_output`]).
    pub pattern: PathBuf,
}

impl Sequence {
    /// Checks `pattern` (one run of `#` in the file name) and every frame's
    /// output (format, not a directory or device) before anything renders.
    pub fn new(frames: Frames, pattern: PathBuf) -> Result<Sequence> {
        let text = pattern
            .to_str()
            .with_context(|| format!("{}: not a path in UTF-8", pattern.display()))?;
        // The scene parser's rule for `output=`: one run of `#`, in the file
        // name (a `#` in a directory would make a directory named by it).
        if trevi_core::scene::animation::frame_runs(text) != Some(1) {
            bail!(
                "{}: a sequence's output needs one run of # in its file name for the frame number, like shot.####.png (give -o or output= on <render>)",
                pattern.display()
            );
        }
        let s = Sequence { frames, pattern };
        for f in frames.first..=frames.last {
            trevi_core::output::check_output(&s.output(f))?;
        }
        Ok(s)
    }

    pub fn output(&self, frame: u32) -> PathBuf {
        let dir = self.pattern.parent().unwrap_or(Path::new(""));
        let name = self
            .pattern
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("");
        dir.join(frame_output(name, frame))
    }

    /// The format of every frame's file, from the pattern's extension.
    pub fn format(&self) -> Result<Format> {
        Format::from_path(&self.pattern)
            .with_context(|| format!("{} is not .png or .exr", self.pattern.display()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_ranges() {
        assert_eq!(
            parse_frames("1-100"),
            Ok(Frames {
                first: 1,
                last: 100
            })
        );
        assert_eq!(parse_frames("7"), Ok(Frames { first: 7, last: 7 }));
        assert!(parse_frames("5-2").unwrap_err().contains("reversed"));
        assert!(parse_frames("1-10000000").is_err());
        assert!(parse_frames("x").is_err());
    }

    #[test]
    fn outputs_follow_the_pattern() {
        let s = Sequence::new(
            Frames { first: 9, last: 10 },
            PathBuf::from("out/shot.###.png"),
        )
        .unwrap();
        assert_eq!(s.output(9), PathBuf::from("out/shot.009.png"));
        assert_eq!(s.output(10), PathBuf::from("out/shot.010.png"));
        let e = Sequence::new(s.frames, PathBuf::from("shot.png"));
        assert!(format!("{:#}", e.err().unwrap()).contains("one run of #"));
        // The parser's rule: a `#` in a directory is refused, not made into
        // a directory named `d#`.
        for bad in ["d#/f.#.png", "a/#/f.#.png", "f.#.#.png"] {
            let e = Sequence::new(s.frames, PathBuf::from(bad));
            assert!(e.is_err(), "{bad}");
        }
    }
}
