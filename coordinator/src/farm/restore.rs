//! Picking up after a restart: the jobs the database holds come back
//! (ended ones for status and download, unfinished ones with their output
//! rebuilt from the stored tiles, float pixels and encoded segments alike),
//! and new jobs never reuse an id given before.

use super::segments::decode_stored;
use super::{lock, validate_aovs, validate_pixels, Farm, Output};
use crate::error::FarmError;
use crate::preview::Preview;
use crate::scheduler::JobFailure;
use crate::scheduler::{JobInfo, Restored};
use crate::store::{wall_ms, Replayed, Store};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::watch;
use trevi_core::FrameWriter;

impl Farm {
    /// Keeps new jobs out of every id given before: the largest the
    /// database remembers, and every `jobs/<id>` directory on disk (a
    /// database lost or replaced must not make two jobs share one).
    pub(super) fn skip_used_ids(&self) -> Result<(), FarmError> {
        let mut max = match &self.store {
            Some(store) => store.max_job_id()?,
            None => 0,
        };
        let jobs = self.cfg.data_dir.join("jobs");
        if let Ok(entries) = std::fs::read_dir(&jobs) {
            for e in entries.flatten() {
                if let Some(id) = e.file_name().to_str().and_then(|n| n.parse::<u64>().ok()) {
                    max = max.max(id);
                }
            }
        }
        self.state.lock().sched.skip_ids_through(max);
        Ok(())
    }

    /// Picks up the jobs in the database: finished ones for status and
    /// download, unfinished ones by rebuilding their output from the stored
    /// tiles and queueing the rest.
    pub(super) fn restore(&self) -> Result<(), FarmError> {
        let Some(store) = &self.store else {
            return Ok(());
        };
        let (now, wall) = (Instant::now(), wall_ms());
        self.load_holds()?;
        let rows = store.jobs()?;
        // A frame that completes while it is restored queues the next
        // frames: their ids must not be those of rows not restored yet.
        let max = store.max_job_id()?;
        self.state.lock().sched.skip_ids_through(max);
        self.restore_sequences(&rows);
        for j in rows {
            if j.seq.frames.is_some() {
                continue; // A sequence: restored above.
            }
            let ago = Duration::from_millis(wall.saturating_sub(j.submitted_ms));
            let submitted = now.checked_sub(ago).unwrap_or(now);
            let done_tiles = if j.state.is_final() {
                Vec::new()
            } else {
                store.tile_list(j.id)?
            };
            let rays = if j.state.is_final() {
                j.rays
            } else {
                done_tiles.iter().fold(0u64, |a, t| a.saturating_add(t.1))
            };
            let id = j.id;
            let mut st = self.state.lock();
            st.sched.restore(
                Restored {
                    id,
                    spec: j.spec.clone(),
                    state: j.state,
                    submitted,
                    elapsed: j.elapsed,
                    render: j.render,
                    error: j.error.clone(),
                    finish_order: j.finish_order,
                    tiles_done: j.tiles_done,
                    rays,
                    done_tiles: done_tiles.iter().map(|t| t.0).collect(),
                },
                now,
            );
            if !j.state.is_final() {
                // Paused or waiting (itself, or the sequence it is a part of).
                st.park_if_held(id, j.seq.parent);
            }
            let info = st.sched.info(id, now).expect("just restored");
            st.watchers.insert(id, watch::channel(info.clone()).0);
            if !j.state.is_final() && j.seq.parent.is_none() {
                st.submitters.insert(id, j.spec.submitter.clone());
            }
            drop(st);
            if j.state.is_final() {
                continue;
            }
            tracing::info!(
                job = id,
                tiles_stored = done_tiles.len(),
                tiles_total = info.tiles_total,
                "resuming job"
            );
            let rebuilt = if done_tiles.is_empty() {
                // Nothing stored: its file is opened at its first tile.
                self.remove_stale_temp_files(&info);
                let path = self.output_path(id, &info.spec.output_name);
                Ok(Output::deferred(path, &info.spec, info.tiles_total))
            } else {
                self.rebuild_output(store, &info)
            };
            match rebuilt {
                Ok(out) => {
                    let complete = out.written == out.total;
                    let out = Arc::new(Mutex::new(out));
                    self.state.lock().outputs.insert(id, out.clone());
                    if complete {
                        let sink = lock(&out).sink.take().expect("just made");
                        let result = sink.finish();
                        self.end_job(
                            id,
                            result.map_err(|e| {
                                JobFailure::Output(format!("finishing the output: {e}"))
                            }),
                        );
                    }
                }
                Err(e) => self.end_job(
                    id,
                    Err(JobFailure::Output(format!("resuming after a restart: {e}"))),
                ),
            }
        }
        self.resume_sequences();
        self.recheck_holds();
        Ok(())
    }

    /// A fresh output for a resumed job with its stored tiles written into it
    /// in band order.
    pub(super) fn rebuild_output(
        &self,
        store: &Store,
        info: &JobInfo,
    ) -> Result<Output, FarmError> {
        let job = info.id;
        let path = self.output_path(job, &info.spec.output_name);
        self.remove_stale_temp_files(info);
        let aovs = info.spec.aovs;
        let mut writer =
            FrameWriter::create_with_aovs(&path, info.spec.width, info.spec.height, aovs)
                .map_err(|e| FarmError::io("cannot create the output", e))?;
        let mut preview = Preview::new(info.spec.width, info.spec.height);
        let mut written = 0;
        let tile_rect =
            |idx: u32| {
                self.state.lock().sched.tile_rect(job, idx).ok_or_else(|| {
                    FarmError::Damaged(format!("stored tile {idx} is not in the frame"))
                })
            };
        store.replay(job, |stored| match stored {
            Replayed::Floats { tile, bytes } => {
                let rect = tile_rect(tile)?;
                written += 1;
                // The wire's format: the pixels, then the render pass
                // values (stitch.rs); a ragged length reads as no pixels,
                // which the pixel count check then refuses.
                let split = rect.pixel_count().saturating_mul(12).min(bytes.len());
                let (px, rest) = bytes.split_at(split);
                let pixels = trevi_proto::pixels_from_bytes(px).unwrap_or_default();
                validate_pixels(rect, &pixels)?;
                let values = trevi_proto::floats_from_bytes(rest);
                validate_aovs(rect, aovs, values.as_deref())?;
                preview.add_tile(rect, &pixels);
                let aov = trevi_core::AovTile {
                    aovs,
                    values: values.unwrap_or_default(),
                };
                writer
                    .write_tile_aovs(rect, &pixels, &aov)
                    .map_err(|e| FarmError::io("writing the output", e))
            }
            Replayed::Segments {
                first,
                tiles,
                bytes,
            } => {
                // Encoded segments: appended as they were taken, their
                // sums added to the preview.
                let span = decode_stored(bytes)?;
                let start = tile_rect(first)?;
                if (span.rect.x, span.rect.y) != (start.x, start.y) || span.scale != preview.scale {
                    return Err(FarmError::Damaged(format!(
                        "the stored segments of tile {first} do not start at it"
                    )));
                }
                written += u64::from(tiles);
                for (i, seg) in &span.segments {
                    writer
                        .write_segment(*i, seg)
                        .map_err(|e| FarmError::io("writing the output", e))?;
                }
                preview.add_sums(span.rect, &span.sums, u64::from(tiles));
                Ok(())
            }
        })?;
        Ok(Output::restored(
            Box::new(writer),
            written,
            info.tiles_total,
            preview,
            aovs,
        ))
    }

    /// Removes the temporary files of the writer that died with the last
    /// run in the job's directory.
    fn remove_stale_temp_files(&self, info: &JobInfo) {
        let path = self.output_path(info.id, &info.spec.output_name);
        if let Ok(entries) = std::fs::read_dir(path.parent().expect("jobs/<id>/name")) {
            for e in entries.flatten() {
                let name = e.file_name();
                let name = name.to_string_lossy();
                if name.starts_with('.') && name.contains(".trevi-tmp-") {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        }
    }
}
