//! A sequence rendered on this machine: `trevi-submit SCENE.xml` on a scene
//! whose `<render>` has `frames=`, or with `--frames`. The scene is built
//! once; each frame moves it with `Scene::set_frame` (the mesh BVHs are
//! kept, only instances, the top-level tree, cameras and lights are made
//! again) and is rendered tile by tile into its own file through
//! `FrameWriter`, like a still (band by band, under a temporary name renamed
//! when the frame is complete). A frame's pixels depend only on the scene,
//! the frame number and the pixel, as on a farm.

use anyhow::{bail, Context, Result};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};
use trevi_core::scene::animation::{frame_output, Frames, MAX_FRAME};
use trevi_core::tile::{band_order_tiles, render_tile_cancellable};
use trevi_core::{FrameWriter, Scene};

use crate::client::Progress;

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

/// One camera's sequence: its frames and the pattern of its outputs.
pub struct Sequence {
    pub camera: usize,
    pub id: String,
    pub frames: Frames,
    /// With one run of `#` in its file name (see [`frame_output`]).
    pub pattern: PathBuf,
}

impl Sequence {
    /// Checks `pattern` (one run of `#` in the file name) and every frame's
    /// output (format, not a directory or device) before anything renders.
    pub fn new(camera: usize, id: String, frames: Frames, pattern: PathBuf) -> Result<Sequence> {
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
        let s = Sequence {
            camera,
            id,
            frames,
            pattern,
        };
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

    fn count(&self) -> u64 {
        u64::from(self.frames.last - self.frames.first) + 1
    }
}

/// Renders every frame of every sequence with `threads` threads (0: every
/// core) and `tile`-pixel tiles, stopping between pixels once `cancel` is
/// set (the frame in progress leaves no file).
pub fn render(
    mut scene: Scene,
    sequences: &[Sequence],
    threads: usize,
    tile: u32,
    progress: Progress,
    cancel: &AtomicBool,
) -> Result<()> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .context("cannot start the render threads")?;
    let total: u64 = sequences
        .iter()
        .map(|s| {
            let r = &scene.desc.cameras[s.camera].render;
            s.count() * u64::from(r.width) * u64::from(r.height)
        })
        .sum();
    let frames_total: u64 = sequences.iter().map(Sequence::count).sum();
    let mut shown = Shown::new(progress, total, frames_total);
    pool.install(|| {
        for s in sequences {
            for f in s.frames.first..=s.frames.last {
                scene
                    .set_frame(s.camera, f)
                    .with_context(|| format!("frame {f}"))?;
                let r = &scene.desc.cameras[s.camera].render;
                let (w, h) = (r.width, r.height);
                let out = s.output(f);
                let mut writer = FrameWriter::create(&out, w, h)?;
                let frame_pixels = u64::from(w) * u64::from(h);
                let mut done = 0u64;
                for rect in band_order_tiles(w, h, tile) {
                    let t = render_tile_cancellable(&scene, s.camera, rect, cancel)
                        .map_err(|_| anyhow::anyhow!("the render was cancelled"))?;
                    writer.write_tile(rect, &t.pixels)?;
                    done += rect.pixel_count() as u64;
                    shown.tile(&s.id, f, rect.pixel_count() as u64, done, frame_pixels);
                }
                writer.finish()?;
                shown.frame(&s.id, f, &out);
            }
        }
        shown.done();
        Ok(())
    })
}

/// Progress of a sequence: frames done, the current frame's share, an ETA.
struct Shown {
    mode: Progress,
    start: Instant,
    last: Option<Instant>,
    total: u64,
    done: u64,
    frames_total: u64,
    frames_done: u64,
}

impl Shown {
    fn new(mode: Progress, total: u64, frames_total: u64) -> Shown {
        Shown {
            mode,
            start: Instant::now(),
            last: None,
            total,
            done: 0,
            frames_total,
            frames_done: 0,
        }
    }

    fn eta(&self) -> String {
        let elapsed = self.start.elapsed().as_secs_f64();
        if self.done == 0 {
            return "?".into();
        }
        let left = elapsed * (self.total - self.done) as f64 / self.done as f64;
        let s = left.round() as u64;
        format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
    }

    fn tile(&mut self, id: &str, frame: u32, pixels: u64, done: u64, of: u64) {
        self.done += pixels;
        if self.mode != Progress::Bar {
            return;
        }
        let now = Instant::now();
        if self
            .last
            .is_some_and(|l| now - l < Duration::from_millis(200))
        {
            return;
        }
        self.last = Some(now);
        eprint!(
            "\r{id}: {}/{} frames done, frame {frame} {:>3}%, ETA {}   ",
            self.frames_done,
            self.frames_total,
            done * 100 / of.max(1),
            self.eta()
        );
        let _ = std::io::stderr().flush();
    }

    fn frame(&mut self, id: &str, frame: u32, out: &Path) {
        self.frames_done += 1;
        match self.mode {
            Progress::Quiet => {}
            Progress::Bar => {
                eprint!("\r\x1b[K");
                eprintln!("{id}: frame {frame} -> {}", out.display());
            }
            Progress::Lines => eprintln!(
                "{id}: {}/{} frames done (frame {frame} -> {}), ETA {}",
                self.frames_done,
                self.frames_total,
                out.display(),
                self.eta()
            ),
        }
    }

    fn done(&mut self) {
        if self.mode != Progress::Quiet {
            eprintln!(
                "{} frames in {:.1} s",
                self.frames_done,
                self.start.elapsed().as_secs_f64()
            );
        }
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
            0,
            "c".into(),
            Frames { first: 9, last: 10 },
            PathBuf::from("out/shot.###.png"),
        )
        .unwrap();
        assert_eq!(s.output(9), PathBuf::from("out/shot.009.png"));
        assert_eq!(s.output(10), PathBuf::from("out/shot.010.png"));
        let e = Sequence::new(0, "c".into(), s.frames, PathBuf::from("shot.png"));
        assert!(format!("{:#}", e.err().unwrap()).contains("one run of #"));
        // The parser's rule: a `#` in a directory is refused, not made into
        // a directory named `d#`.
        for bad in ["d#/f.#.png", "a/#/f.#.png", "f.#.#.png"] {
            let e = Sequence::new(0, "c".into(), s.frames, PathBuf::from(bad));
            assert!(e.is_err(), "{bad}");
        }
    }
}
