//! The noisy frame read from a multi-layer OpenEXR file, a band at a time.
//!
//! Channels are found by their full names, whether the layers are one part
//! with prefixed channel names or parts named after their layers: the beauty
//! `R G B`, the albedo `albedo.R albedo.G albedo.B` and the normal
//! `N.X N.Y N.Z` and the depth `Z` (the names compositing tools and the
//! farm's writer use); in
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
use trevi_core::scene::MAX_IMAGE_SIDE;
use trevi_core::texture::header::probe_exr;
#[cfg(doc)]
use trevi_core::texture::header::TextureHeader;
use trevi_core::{Aov, AovTile, Aovs};

/// Where one channel is: (part, channel index in that part).
type Slot = (usize, usize);

/// Checks the file's headers before anything is allocated for its pixels:
/// the layout bounds every OpenEXR reader of the project checks
/// ([`TextureHeader::check_blocks`]: offset tables within the file, no
/// deep part, at most 64 channels, one block at most 64 MiB uncompressed) and
/// each side of every part at most [`MAX_IMAGE_SIDE`], the largest frame a
/// scene can ask for, so a band read holds at most
/// `(band_rows + 2·overlap) × MAX_IMAGE_SIDE` pixels plus one block.
fn check_layout(path: &Path) -> Result<(), DenoiseError> {
    let file = File::open(path).map_err(|e| io(path, e))?;
    let bytes = file.metadata().map_err(|e| io(path, e))?.len();
    let header = probe_exr(BufReader::new(file), bytes).map_err(|e| io(path, e))?;
    header.check_blocks().map_err(|e| io(path, e))?;
    for p in &header.parts {
        if p.width > u64::from(MAX_IMAGE_SIDE) || p.height > u64::from(MAX_IMAGE_SIDE) {
            return Err(io(
                path,
                format!(
                    "is {}x{}: a side is over {MAX_IMAGE_SIDE} pixels, the largest frame a \
                     scene can render",
                    p.width, p.height
                ),
            ));
        }
    }
    Ok(())
}

/// A scanline EXR file whose channels include `R G B`.
pub struct ExrSource {
    path: PathBuf,
    width: u32,
    height: u32,
    color: [Slot; 3],
    albedo: Option<[Slot; 3]>,
    normal: Option<[Slot; 3]>,
    depth: Option<Slot>,
}

fn io(path: &Path, what: impl std::fmt::Display) -> DenoiseError {
    DenoiseError::Io(format!("{}: {what}", path.display()))
}

impl ExrSource {
    /// Reads the file's headers and finds its channels; refused when the
    /// beauty is missing, a layer is partial (albedo without all three
    /// channels), or the parts differ in size.
    pub fn open(path: &Path) -> Result<ExrSource, DenoiseError> {
        check_layout(path)?;
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
        let depth = find("Z");
        let (w, h) = size.ok_or_else(|| io(path, "has no parts"))?;
        let too_big = |_| io(path, "is too large");
        Ok(ExrSource {
            path: path.to_path_buf(),
            width: u32::try_from(w).map_err(too_big)?,
            height: u32::try_from(h).map_err(too_big)?,
            color,
            albedo,
            normal,
            depth,
        })
    }

    /// The render passes the file holds (`albedo.R…`, `N.X…`, `Z`).
    pub fn aovs(&self) -> Aovs {
        let mut aovs = Aovs::NONE;
        for (has, aov) in [
            (self.albedo.is_some(), Aov::Albedo),
            (self.normal.is_some(), Aov::Normal),
            (self.depth.is_some(), Aov::Depth),
        ] {
            if has {
                aovs = aovs.with(aov);
            }
        }
        aovs
    }

    /// Refuses render passes `aovs` unless the file holds every one.
    pub fn check_holds(&self, aovs: Aovs) -> Result<(), DenoiseError> {
        let held = self.aovs();
        if aovs.iter().all(|a| held.contains(a)) {
            return Ok(());
        }
        Err(io(
            &self.path,
            format!("has not every render pass of \"{aovs}\" (it has \"{held}\")"),
        ))
    }

    /// Rows `rows` of the beauty and of the passes `aovs` (which the file
    /// must hold, see [`ExrSource::aovs`]), as a writer takes them: what a
    /// denoised output carries beside its denoised beauty.
    pub fn read_layers(
        &self,
        rows: Range<u32>,
        aovs: Aovs,
    ) -> Result<(Vec<[f32; 3]>, AovTile), DenoiseError> {
        self.check_holds(aovs)?;
        let mut slots: Vec<Slot> = self.color.to_vec();
        for aov in aovs.iter() {
            match aov {
                Aov::Albedo => slots.extend(self.albedo.into_iter().flatten()),
                Aov::Normal => slots.extend(self.normal.into_iter().flatten()),
                Aov::Depth => slots.extend(self.depth),
            }
        }
        let mut values = Vec::new();
        self.read_channels(rows, &slots, &mut values)?;
        let stride = slots.len();
        let color = values
            .chunks_exact(stride)
            .map(|v| [v[0], v[1], v[2]])
            .collect();
        let passes = values
            .chunks_exact(stride)
            .flat_map(|v| v[3..].iter().copied())
            .collect();
        Ok((
            color,
            AovTile {
                aovs,
                values: passes,
            },
        ))
    }

    /// Reads rows `rows` of the channels at `slots` into `out`,
    /// `slots.len()` values a pixel in the order of `slots`, pixels row by
    /// row. Decodes only the blocks that hold those rows.
    fn read_channels(
        &self,
        rows: Range<u32>,
        slots: &[Slot],
        out: &mut Vec<f32>,
    ) -> Result<(), DenoiseError> {
        crate::check_rows(&rows, self.width, self.height)?;
        let w = self.width as usize;
        let stride = slots.len();
        out.clear();
        out.resize(w * (rows.end - rows.start) as usize * stride, 0.0);
        let path = &self.path;
        let file = File::open(path).map_err(|e| io(path, e))?;
        let (y0, y1) = (rows.start as usize, rows.end as usize);
        let chunks = exr::block::read(BufReader::new(file), false)
            .map_err(|e| io(path, e))?
            .filter_chunks(false, |_, _, block| {
                let top = block.pixel_position.y();
                block.level == exr::math::Vec2(0, 0)
                    && top < y1
                    && top + block.pixel_size.height() > y0
            })
            .map_err(|e| io(path, e))?;
        let headers = chunks.meta_data().headers.clone();
        let mut line_buf = vec![0f32; w];
        for block in chunks.sequential_decompressor(false) {
            let block = block.map_err(|e| io(path, e))?;
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
                // A channel may fill several places (the same slot twice).
                let mut read = false;
                for (c, _) in slots.iter().enumerate().filter(|(_, s)| **s == slot) {
                    if !read {
                        line.read_samples_into_slice(&mut line_buf[..count])
                            .map_err(|e| io(path, e))?;
                        read = true;
                    }
                    let start = ((y - y0) * w + x) * stride;
                    for (i, v) in line_buf[..count].iter().enumerate() {
                        out[start + i * stride + c] = *v;
                    }
                }
            }
        }
        Ok(())
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
        // Normals only with albedo, as the filter takes them.
        let albedo = self.albedo;
        let normal = self.normal.filter(|_| albedo.is_some());
        let mut slots: Vec<Slot> = self.color.to_vec();
        slots.extend(albedo.into_iter().flatten());
        slots.extend(normal.into_iter().flatten());
        let mut values = Vec::new();
        self.read_channels(rows, &slots, &mut values)?;
        let stride = slots.len();
        let take = |at: usize| -> Vec<[f32; 3]> {
            values
                .chunks_exact(stride)
                .map(|v| [v[at], v[at + 1], v[at + 2]])
                .collect()
        };
        into.color = take(0);
        into.albedo = albedo.map(|_| take(3));
        into.normal = normal.map(|_| take(6));
        Ok(())
    }
}
