//! The noisy frame read from a multi-layer OpenEXR file, a band at a time.
//!
//! Channels are found by their full names, whether the layers are one part
//! with prefixed channel names or parts named after their layers: the beauty
//! `R G B`, the albedo `albedo.R albedo.G albedo.B` and the normal
//! `N.X N.Y N.Z` (the names compositing tools and the farm's writer use); in
//! a file of several parts the first part's channels also answer to their
//! own names, so a beauty part of any name gives `R G B`.
//! Only the beauty is required. Scanline and tiled files both read; a band
//! read decodes only the blocks that hold its rows: memory is the band's
//! pixels plus one block.

use crate::{DenoiseError, Inputs, Source};
use exr::block::reader::ChunksReader;
use std::fs::File;
use std::io::BufReader;
use std::ops::Range;
use std::path::{Path, PathBuf};

/// Where one channel is: (part, channel index in that part).
type Slot = (usize, usize);

/// A scanline EXR file whose channels include `R G B`.
pub struct ExrSource {
    path: PathBuf,
    width: u32,
    height: u32,
    color: [Slot; 3],
    albedo: Option<[Slot; 3]>,
    normal: Option<[Slot; 3]>,
}

fn io(path: &Path, what: impl std::fmt::Display) -> DenoiseError {
    DenoiseError::Io(format!("{}: {what}", path.display()))
}

impl ExrSource {
    /// Reads the file's headers and finds its channels; refused when the
    /// beauty is missing, a layer is partial (albedo without all three
    /// channels), or the parts differ in size.
    pub fn open(path: &Path) -> Result<ExrSource, DenoiseError> {
        let file = File::open(path).map_err(|e| io(path, e))?;
        let reader = exr::block::read(BufReader::new(file), false).map_err(|e| io(path, e))?;
        let headers = &reader.meta_data().headers;
        let mut names: Vec<(String, Slot)> = Vec::new();
        let mut size = None;
        for (part, header) in headers.iter().enumerate() {
            let this = (header.layer_size.width(), header.layer_size.height());
            if *size.get_or_insert(this) != this {
                return Err(io(path, "its parts differ in size"));
            }
            let prefix = header
                .own_attributes
                .layer_name
                .as_ref()
                .map(|n| format!("{n}."))
                .unwrap_or_default();
            for (i, channel) in header.channels.list.iter().enumerate() {
                names.push((format!("{prefix}{}", channel.name), (part, i)));
                // Multi-part files name every part: the first part's channels
                // are also found by their own names (a beauty part "rgba").
                if part == 0 && !prefix.is_empty() {
                    names.push((channel.name.to_string(), (part, i)));
                }
            }
        }
        let find = |name: &str| names.iter().find(|(n, _)| n == name).map(|&(_, s)| s);
        let triple = |names: [&str; 3]| -> Result<Option<[Slot; 3]>, DenoiseError> {
            match names.map(find) {
                [Some(a), Some(b), Some(c)] => Ok(Some([a, b, c])),
                [None, None, None] => Ok(None),
                _ => Err(io(path, format!("has only some of the channels {names:?}"))),
            }
        };
        let color = triple(["R", "G", "B"])?.ok_or_else(|| io(path, "has no R G B channels"))?;
        let albedo = triple(["albedo.R", "albedo.G", "albedo.B"])?;
        let normal = triple(["N.X", "N.Y", "N.Z"])?;
        let (w, h) = size.ok_or_else(|| io(path, "has no parts"))?;
        let too_big = |_| io(path, "is too large");
        Ok(ExrSource {
            path: path.to_path_buf(),
            width: u32::try_from(w).map_err(too_big)?,
            height: u32::try_from(h).map_err(too_big)?,
            color,
            albedo,
            normal,
        })
    }

    /// Whether the file has an albedo layer.
    pub fn has_albedo(&self) -> bool {
        self.albedo.is_some()
    }

    /// Whether the file has a normal layer.
    pub fn has_normal(&self) -> bool {
        self.normal.is_some()
    }
}

impl Source for ExrSource {
    fn width(&self) -> u32 {
        self.width
    }

    fn height(&self) -> u32 {
        self.height
    }

    fn read(&mut self, rows: Range<u32>, into: &mut Inputs) -> Result<(), DenoiseError> {
        crate::check_rows(&rows, self.width, self.height)?;
        let w = self.width as usize;
        let n = w * (rows.end - rows.start) as usize;
        let fresh = |v: &mut Vec<[f32; 3]>| {
            v.clear();
            v.resize(n, [0.0; 3]);
        };
        fresh(&mut into.color);
        // Normals only with albedo, as the filter takes them.
        let albedo = self.albedo;
        let normal = self.normal.filter(|_| albedo.is_some());
        for (slots, out) in [(albedo, &mut into.albedo), (normal, &mut into.normal)] {
            match slots {
                Some(_) => fresh(out.get_or_insert_with(Vec::new)),
                None => *out = None,
            }
        }
        let path = self.path.clone();
        let file = File::open(&path).map_err(|e| io(&path, e))?;
        let (y0, y1) = (rows.start as usize, rows.end as usize);
        let chunks = exr::block::read(BufReader::new(file), false)
            .map_err(|e| io(&path, e))?
            .filter_chunks(false, |_, _, block| {
                let top = block.pixel_position.y();
                block.level == exr::math::Vec2(0, 0)
                    && top < y1
                    && top + block.pixel_size.height() > y0
            })
            .map_err(|e| io(&path, e))?;
        let headers = chunks.meta_data().headers.clone();
        let mut line_buf = vec![0f32; w];
        for block in chunks.sequential_decompressor(false) {
            let block = block.map_err(|e| io(&path, e))?;
            let part = block.index.layer;
            let channels = &headers[part].channels;
            for line in block.lines(channels) {
                // A line of a scanline block spans the frame; one of a tile,
                // the tile's columns.
                let (x, y) = (line.location.position.x(), line.location.position.y());
                let count = line.location.sample_count;
                if !(y0..y1).contains(&y) || x + count > w {
                    continue;
                }
                let slot = (part, line.location.channel);
                let targets = [
                    (Some(self.color), Some(&mut into.color)),
                    (albedo, into.albedo.as_mut()),
                    (normal, into.normal.as_mut()),
                ];
                for (slots, out) in targets {
                    let (Some(slots), Some(out)) = (slots, out) else {
                        continue;
                    };
                    if let Some(c) = slots.iter().position(|&s| s == slot) {
                        line.read_samples_into_slice(&mut line_buf[..count])
                            .map_err(|e| io(&path, e))?;
                        let start = (y - y0) * w + x;
                        let row = &mut out[start..start + count];
                        for (px, v) in row.iter_mut().zip(&line_buf) {
                            px[c] = *v;
                        }
                        break;
                    }
                }
            }
        }
        Ok(())
    }
}
