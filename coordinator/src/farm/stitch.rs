//! Stitching: an admitted tile is stored (one transaction for a span,
//! committed before it is acknowledged), then written into its job's output
//! file and preview; the output's last tile finishes the file and ends the
//! job. Encoded PNG segments are written the same way (see `segments.rs`).

use super::outputs::Output;
use super::results::Admitted;
use super::{lock, Farm};
use crate::error::FarmError;
use crate::preview::Preview;
use crate::scheduler::JobFailure;
use crate::scheduler::JobId;
use crate::sink::TileSink;
use std::sync::Mutex;
use trevi_core::{AovTile, Rect};

impl Farm {
    /// Stores admitted tiles of `job` (one transaction: committed before
    /// they are acknowledged, so after a crash they are replayed, not
    /// rendered again), then writes each to the job's output and preview.
    /// False when the output was gone (the job was cancelled meanwhile).
    pub(super) fn store_and_write<P: AsRef<[[f32; 3]]>>(
        &self,
        job: JobId,
        tiles: &[Admitted<P>],
    ) -> Result<bool, FarmError> {
        let Some(first) = tiles.first() else {
            return Ok(true);
        };
        if let Some(store) = &self.store {
            // A tile's stored bytes: its pixels, then its render pass
            // values (none for a job without passes): restore.rs cuts them
            // apart by the tile's pixel count.
            let rows: Vec<_> = tiles
                .iter()
                .map(|t| {
                    let pixels = trevi_proto::pixels_as_bytes(t.pixels.as_ref());
                    let bytes = if t.aovs.is_empty() {
                        pixels
                    } else {
                        let mut b = pixels.into_owned();
                        b.extend_from_slice(&trevi_proto::floats_to_bytes(&t.aovs));
                        std::borrow::Cow::Owned(b)
                    };
                    (t.idx, t.rays, bytes)
                })
                .collect();
            let stored = store.put_tiles(job, &rows);
            self.state.lock().stored(job, tiles.len() as u64);
            if let Err(e) = stored {
                lock(&first.out).close();
                self.end_job(
                    job,
                    Err(JobFailure::Output(format!(
                        "storing tile {}: {e}",
                        first.idx
                    ))),
                );
                return Err(e);
            }
        }
        let mut all = true;
        for t in tiles {
            all &= self.write_out(job, &t.out, t.rect, t.pixels.as_ref(), &t.aovs)?;
        }
        Ok(all)
    }

    /// Writes a stored tile to the job's output and preview; finishes the
    /// output with its last tile. False when the output is gone (the job
    /// was cancelled meanwhile).
    pub(super) fn write_out(
        &self,
        job: JobId,
        out: &Mutex<Output>,
        rect: Rect,
        pixels: &[[f32; 3]],
        aovs: &[f32],
    ) -> Result<bool, FarmError> {
        let aovs = AovTile {
            aovs: lock(out).aovs,
            values: aovs.to_vec(),
        };
        self.write_output(job, out, 1, |sink, preview| {
            sink.write_tile_aovs(rect, pixels, &aovs)?;
            preview.add_tile(rect, pixels);
            Ok(())
        })
    }

    /// Writes to `job`'s output with `write` (given the sink and the
    /// preview: it adds to the preview what it wrote) and counts `tiles`
    /// more tiles written; the output's last tile finishes it. A write error
    /// drops the output and fails the job. False when the output is gone
    /// (the job was cancelled meanwhile).
    pub(super) fn write_output(
        &self,
        job: JobId,
        out: &Mutex<Output>,
        tiles: u64,
        write: impl FnOnce(&mut dyn TileSink, &mut Preview) -> Result<(), crate::sink::SinkError>,
    ) -> Result<bool, FarmError> {
        let mut guard = lock(out);
        let o = &mut *guard;
        let opened = o.open();
        let Some(sink) = o.sink.as_mut() else {
            return match opened {
                Ok(_) => Ok(false),
                Err(e) => {
                    drop(guard); // end_job takes the output's lock for its preview.
                    let e = FarmError::io(format!("creating the output of job {job}"), e);
                    self.end_job(job, Err(JobFailure::Output(e.to_string())));
                    Err(e)
                }
            };
        };
        if let Err(e) = write(sink.as_mut(), &mut o.preview) {
            o.close();
            drop(guard); // end_job takes the output's lock for its preview.
            let e = FarmError::io(format!("writing the output of job {job}"), e);
            self.end_job(job, Err(JobFailure::Output(e.to_string())));
            return Err(e);
        }
        o.max_rows_held = o.max_rows_held.max(sink.rows_held());
        o.written += tiles;
        if o.written == o.total {
            let sink = o.sink.take().expect("checked above");
            let result = sink.finish();
            drop(guard);
            self.end_job(
                job,
                result.map_err(|e| JobFailure::Output(format!("finishing the output: {e}"))),
            );
        }
        Ok(true)
    }
}
