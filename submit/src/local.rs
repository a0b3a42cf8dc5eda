//! Rendering on this machine: tiles in band order, each band's tiles in
//! parallel, each finished band handed to the output writer, so memory holds
//! one band of tiles, never the frame.

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use std::path::Path;
use std::time::Instant;
use trevi_core::tile::band_order_tiles;
use trevi_core::{render_tile, FrameWriter, Scene};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Progress {
    Quiet,
    Bar,
    Lines,
}

pub struct Stats {
    pub rays: u64,
    pub seconds: f64,
}

pub fn render_camera(
    scene: &Scene,
    camera: usize,
    out: &Path,
    tile: u32,
    progress: Progress,
) -> Result<Stats> {
    let desc = &scene.desc.cameras[camera];
    let (w, h) = (desc.render.width, desc.render.height);
    let start = Instant::now();
    let mut writer = FrameWriter::create(out, w, h)
        .with_context(|| format!("cannot write {}", out.display()))?;
    let tiles = band_order_tiles(w, h, tile);
    let bar = match progress {
        Progress::Bar => {
            let b = ProgressBar::new(tiles.len() as u64);
            b.set_style(
                ProgressStyle::with_template(
                    "{prefix} [{bar:40}] {pos}/{len} tiles {msg} ETA {eta}",
                )
                .expect("static template")
                .progress_chars("=> "),
            );
            b.set_prefix(desc.id.clone());
            Some(b)
        }
        _ => None,
    };
    let mut rays = 0u64;
    let mut done = 0usize;
    let mut last_line = 0usize;
    for band in tiles.chunk_by(|a, b| a.y == b.y) {
        let results: Vec<_> = band
            .par_iter()
            .map(|&r| (r, render_tile(scene, camera, r)))
            .collect();
        for (r, res) in results {
            writer.write_tile(r, &res.pixels)?;
            rays += res.rays;
        }
        done += band.len();
        let secs = start.elapsed().as_secs_f64();
        let rate = rays as f64 / secs.max(1e-9) / 1e6;
        if let Some(b) = &bar {
            b.set_position(done as u64);
            b.set_message(format!("{rate:.2} M rays/s"));
        } else if progress == Progress::Lines {
            let pct = done * 100 / tiles.len();
            if pct >= last_line + 10 || done == tiles.len() {
                last_line = pct;
                eprintln!(
                    "{}: {pct}% ({done}/{} tiles, {rate:.2} M rays/s)",
                    desc.id,
                    tiles.len()
                );
            }
        }
    }
    writer
        .finish()
        .with_context(|| format!("cannot finish {}", out.display()))?;
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    Ok(Stats {
        rays,
        seconds: start.elapsed().as_secs_f64(),
    })
}
