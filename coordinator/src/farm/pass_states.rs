//! A progressive job's accumulation states on the coordinator's disk: what
//! its workers continue from, pass after pass (docs/progressive.md).
//!
//! Every pixel of the frame has a 64-byte record
//! ([`trevi_core::passes::PIXEL_BYTES`], the encoding's pixel) at
//! `64 · (y · width + x)` of a file of the job's directory: a state is read
//! and written by rows of its rectangle, never whole, so the coordinator
//! holds at most one lease's state at a time for each upload or fetch.
//! There are two files, `state.0` and `state.1`: pass `k` reads the
//! records pass `k − 1` wrote in `state.{(k − 1) mod 2}` and writes its
//! own to `state.{k mod 2}`. A tile rendered twice in one pass (an expired
//! lease that still delivered) writes the same bytes twice (renders are
//! deterministic), and a coordinator that stops between writing a tile's
//! records and recording the tile finds the records it reads unchanged.
//! Both files together are 128 bytes a pixel, counted against the job's
//! disk (see `docs/farm.md`, "Limits").

use crate::error::FarmError;
use std::fs::{File, OpenOptions};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use trevi_core::passes::{Noise, StateError, TileState, HEADER_BYTES, PIXEL_BYTES};
use trevi_core::Rect;

/// The bytes the state files of a `width` × `height` frame take together.
pub fn state_bytes(width: u32, height: u32) -> u64 {
    2 * PIXEL_BYTES as u64 * u64::from(width) * u64::from(height)
}

/// The file pass `pass` writes its states to (and pass `pass + 1` reads).
pub fn state_path(dir: &Path, pass: u32) -> PathBuf {
    dir.join(format!("state.{}", pass % 2))
}

/// One pass's state file of a frame `width` pixels wide.
#[derive(Debug)]
pub struct StateFile {
    file: File,
    path: PathBuf,
    width: u32,
    /// The file's length when opened for reading (what a pass wrote
    /// before; records past it were never written): one `stat`, not one
    /// a row.
    len: u64,
}

impl StateFile {
    /// Opens (creating when `write`) the state file at `path`.
    pub fn open(path: &Path, width: u32, write: bool) -> Result<StateFile, FarmError> {
        if let (true, Some(dir)) = (write, path.parent()) {
            std::fs::create_dir_all(dir)
                .map_err(|e| FarmError::io(format!("creating {}", dir.display()), e))?;
        }
        let file = OpenOptions::new()
            .read(true)
            .write(write)
            .create(write)
            .truncate(false)
            .open(path)
            .map_err(|e| FarmError::io(format!("opening {}", path.display()), e))?;
        let len = match write {
            true => u64::MAX,
            false => file
                .metadata()
                .map_err(|e| FarmError::io(format!("reading {}", path.display()), e))?
                .len(),
        };
        Ok(StateFile {
            file,
            path: path.to_path_buf(),
            width,
            len,
        })
    }

    fn offset(&self, x: u32, y: u32) -> u64 {
        PIXEL_BYTES as u64 * (u64::from(y) * u64::from(self.width) + u64::from(x))
    }

    /// The records of row `y` of `rect` into `out` (one row's bytes).
    pub fn read_row(&self, rect: Rect, y: u32, out: &mut [u8]) -> Result<(), FarmError> {
        debug_assert_eq!(out.len(), PIXEL_BYTES * rect.w as usize);
        let at = self.offset(rect.x, y);
        // Past the end: records never written (a file is sparse until its
        // first pass is complete), read as zeros.
        let len = match self.len {
            u64::MAX => self
                .file
                .metadata()
                .map_err(|e| FarmError::io(format!("reading {}", self.path.display()), e))?
                .len(),
            len => len,
        };
        out.fill(0);
        let have = len.saturating_sub(at).min(out.len() as u64) as usize;
        self.file
            .read_exact_at(&mut out[..have], at)
            .map_err(|e| FarmError::io(format!("reading {}", self.path.display()), e))
    }

    /// The encoded state of `rect` at `next` (the header, then the records
    /// row by row), one piece at a time to `sink`: the header, then each
    /// row; what is held is one row.
    pub fn read_encoded(
        &self,
        rect: Rect,
        next: u32,
        mut sink: impl FnMut(Vec<u8>) -> Result<(), FarmError>,
    ) -> Result<(), FarmError> {
        sink(TileState::encode_header(rect, next).to_vec())?;
        for y in rect.y..rect.y + rect.h {
            let mut row = vec![0u8; PIXEL_BYTES * rect.w as usize];
            self.read_row(rect, y, &mut row)?;
            sink(row)?;
        }
        Ok(())
    }

    /// Writes the records of a decoded-and-checked encoded state (`bytes`,
    /// whose rectangle is `rect`) to their places.
    pub fn write(&self, rect: Rect, bytes: &[u8]) -> Result<(), FarmError> {
        let row = PIXEL_BYTES * rect.w as usize;
        debug_assert_eq!(bytes.len(), TileState::encoded_len(rect));
        for (i, records) in bytes[HEADER_BYTES..].chunks_exact(row).enumerate() {
            let at = self.offset(rect.x, rect.y + i as u32);
            self.file
                .write_all_at(records, at)
                .map_err(|e| FarmError::io(format!("writing {}", self.path.display()), e))?;
        }
        Ok(())
    }

    /// The noise of the records of `rect` (written by a pass that ended at
    /// sample `next`), read a row at a time.
    pub fn noise(&self, rect: Rect, next: u32) -> Result<Noise, FarmError> {
        let mut total = Noise::default();
        let mut row = vec![0u8; PIXEL_BYTES * rect.w as usize];
        for y in rect.y..rect.y + rect.h {
            self.read_row(rect, y, &mut row)?;
            let one = Rect::new(rect.x, y, rect.w, 1);
            let mut bytes = TileState::encode_header(one, next).to_vec();
            bytes.extend_from_slice(&row);
            let state = TileState::decode(&bytes).map_err(|e| damaged(&self.path, one, e))?;
            total += state.noise();
        }
        Ok(total)
    }

    /// Makes what was written durable (before the pass's end is recorded).
    pub fn sync(&self) -> Result<(), FarmError> {
        self.file
            .sync_data()
            .map_err(|e| FarmError::io(format!("syncing {}", self.path.display()), e))
    }
}

fn damaged(path: &Path, rect: Rect, e: StateError) -> FarmError {
    FarmError::Damaged(format!(
        "the state of rows {}..{} in {} is damaged: {e}",
        rect.y,
        rect.y + rect.h,
        path.display()
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicBool;
    use trevi_core::scene::aisxml::parse_scene_str;
    use trevi_core::{Bundle, Scene};

    fn scene(xml: &str) -> Scene {
        let bundle = Bundle {
            scene: "s.xml".into(),
            files: Default::default(),
        };
        Scene::build(parse_scene_str("s.xml", xml, &bundle).unwrap())
    }

    const SCENE: &str = r#"<scene version="1">
  <sphere id="s" center="0 0 0" radius="1"><surface diffuse="0.8 0.3 0.2"/></sphere>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1" radius="1"/>
  <camera id="c" position="0 0 5" lookat="0 0 0" up="0 1 0" fov="30">
    <render width="9" height="7" noise-threshold="0.5" min-samples="6" max-samples="6"
            shadow-samples="1" output="o.png"/>
  </camera>
</scene>"#;

    /// Tiles written to the file come back as the same encoded states, and
    /// a tile read across the tiles that wrote it is their pixels; the
    /// noise read back is the states' own.
    #[test]
    fn states_written_by_tiles_read_back_by_any_rect() {
        let s = scene(SCENE);
        let dir = tempfile::tempdir().unwrap();
        let never = AtomicBool::new(false);
        let f = StateFile::open(&state_path(dir.path(), 0), 9, true).unwrap();
        let mut whole = TileState::new(Rect::new(0, 0, 9, 7));
        whole.render(&s, 0, 0..4, &never).unwrap();
        for t in [
            Rect::new(0, 0, 5, 4),
            Rect::new(5, 0, 4, 4),
            Rect::new(0, 4, 9, 3),
        ] {
            let mut st = TileState::new(t);
            st.render(&s, 0, 0..4, &never).unwrap();
            f.write(t, &st.encode()).unwrap();
        }
        let read = |r: Rect| {
            let mut bytes = Vec::new();
            f.read_encoded(r, 4, |p| {
                bytes.extend(p);
                Ok(())
            })
            .unwrap();
            bytes
        };
        assert_eq!(read(Rect::new(0, 0, 9, 7)), whole.encode());
        let mid = Rect::new(3, 2, 4, 3);
        let mut part = TileState::new(mid);
        part.render(&s, 0, 0..4, &never).unwrap();
        assert_eq!(read(mid), part.encode());
        // Summed a row at a time, the whole's pixel by pixel: equal but
        // for the rounding of the order.
        let (n, w) = (f.noise(Rect::new(0, 0, 9, 7), 4).unwrap(), whole.noise());
        assert_eq!(n.unknown, w.unknown);
        for (a, b) in [(n.error_sq, w.error_sq), (n.signal_sq, w.signal_sq)] {
            assert!((a - b).abs() <= 1e-12 * b.abs() && b > 0.0, "{a} {b}");
        }
        // Never written: empty records, which decode as no samples.
        let g = StateFile::open(&state_path(dir.path(), 1), 9, true).unwrap();
        let mut bytes = Vec::new();
        g.read_encoded(mid, 0, |p| {
            bytes.extend(p);
            Ok(())
        })
        .unwrap();
        assert_eq!(bytes, TileState::new(mid).encode());
    }

    #[test]
    fn damaged_records_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let f = StateFile::open(&state_path(dir.path(), 0), 2, true).unwrap();
        let r = Rect::new(0, 0, 2, 1);
        let mut bytes = TileState::new(r).encode();
        // A count above `next`.
        bytes[HEADER_BYTES + 12] = 9;
        f.write(r, &bytes).unwrap();
        let e = f.noise(r, 4).unwrap_err().to_string();
        assert!(e.contains("rows 0..1") && e.contains("state.0"), "{e}");
    }
}
