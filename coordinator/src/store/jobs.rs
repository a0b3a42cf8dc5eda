//! The jobs' rows: a job as stored ([`StoredJob`], with its link to a
//! sequence), inserted when it is submitted, updated when its priority
//! changes or it ends, read back on start, and deleted by retention (the
//! largest id kept so that no id is given twice).

use super::{db_err, wall_ms, Store};
use crate::error::FarmError;
use crate::scheduler::{JobId, JobSpec, JobState, SampleRange, StopReason};
use rusqlite::{params, OptionalExtension};
use std::time::Duration;
use trevi_core::Aovs;

/// A job as stored.
#[derive(Debug, Clone)]
pub struct StoredJob {
    /// The job's number (the row's key).
    pub id: JobId,
    /// What to render; its `submitter` is stored as the row's submitter.
    pub spec: JobSpec,
    /// Its state when last recorded (the name [`JobState::name`] gives).
    pub state: JobState,
    /// Wall-clock submission time, milliseconds since the Unix epoch.
    pub submitted_ms: u64,
    /// Set for finished jobs.
    pub elapsed: Option<Duration>,
    /// Set for finished jobs that started: the part of `elapsed` after the
    /// first tile was leased.
    pub render: Option<Duration>,
    /// For a failed job: why.
    pub error: Option<String>,
    /// For a finished job: its place in the finishing order (1 first); 0
    /// otherwise.
    pub finish_order: u64,
    /// For a finished job: its tiles done (an unfinished job's are its
    /// rows in the tile table).
    pub tiles_done: u64,
    /// For a finished job: the rays traced for its tiles.
    pub rays: u64,
    /// How the job belongs to a sequence, or is one.
    pub seq: SeqLink,
}

impl StoredJob {
    /// The row of a job submitted now: nothing rendered, nothing finished.
    pub fn submitted(id: JobId, spec: JobSpec, state: JobState, seq: SeqLink) -> StoredJob {
        StoredJob {
            id,
            spec,
            state,
            submitted_ms: wall_ms(),
            elapsed: None,
            render: None,
            error: None,
            finish_order: 0,
            tiles_done: 0,
            rays: 0,
            seq,
        }
    }
}

/// A sequence's row, or a frame's link to its sequence (see
/// `crate::farm::sequences`): a sequence is a row of its own, its frames
/// jobs whose `parent` it is. Both `None` for a still.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SeqLink {
    /// For a frame: its sequence.
    pub parent: Option<JobId>,
    /// For a sequence: its first and last frame.
    pub frames: Option<(u32, u32)>,
    /// For an ended sequence: how many frames it finished.
    pub frames_done: u32,
    /// For a progressive job: its passes (then `frames` are its passes'
    /// indices and `frames_done` the passes done).
    pub passes: Option<StoredPasses>,
}

/// A progressive job's passes as stored (see `crate::farm::progressive`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StoredPasses {
    /// Samples per pixel asked for, and whether they are the job's own
    /// (`--samples`: extendable) or the scene's.
    pub total: u32,
    /// See `total`.
    pub own: bool,
    /// Samples per pass.
    pub pass: u32,
    /// 0: none.
    pub time_limit_ms: u64,
    /// 0: none.
    pub noise_target: f64,
    /// Samples per pixel of the passes done.
    pub samples_done: u32,
    /// The estimated relative error after the last pass done.
    pub error: Option<f64>,
    /// Why it ended before its total, if it did.
    pub stopped_by: Option<StopReason>,
    /// The passes are each frame's of a sequence, not a still's.
    pub frames: bool,
    /// The coordinator sizes the passes (no `--pass`).
    pub auto: bool,
}

fn set_passes(tx: &rusqlite::Transaction, job: JobId, p: &StoredPasses) -> Result<(), FarmError> {
    tx.execute(
        "UPDATE jobs SET passes_total = ?2, samples_done = ?3, noise_error = ?4, stopped_by = ?5,
             pass_samples = ?6, time_limit_ms = ?7, noise_target = ?8 WHERE id = ?1",
        params![
            job as i64,
            p.total,
            p.samples_done,
            p.error,
            p.stopped_by.map(StopReason::label),
            p.pass,
            p.time_limit_ms as i64,
            p.noise_target,
        ],
    )
    .map_err(db_err)?;
    Ok(())
}

/// A job's stored state: one of [`JobState::name`]'s words. Any other is a
/// database this coordinator did not write, refused naming the job.
fn state_from(job: JobId, s: &str) -> Result<JobState, FarmError> {
    JobState::ALL
        .into_iter()
        .find(|st| st.name() == s)
        .ok_or_else(|| {
            FarmError::Damaged(format!(
                "the state database says job {job} is \"{}\", not a state this coordinator \
                 knows ({})",
                s.chars().take(40).collect::<String>(),
                JobState::ALL.map(JobState::name).join(", ")
            ))
        })
}

impl Store {
    /// Stores a newly submitted job's row (with its sequence link and its
    /// passes' settings).
    pub fn insert_job(&self, j: &StoredJob) -> Result<(), FarmError> {
        let s = &j.spec;
        self.inner
            .lock()
            .conn
            .execute(
                "INSERT INTO jobs (id, bundle_hash, camera, priority, width, height, tile_size,
                     output_name, submitter, state, submitted_ms, frame, parent, first_frame,
                     last_frame, scene, pass, sample_start, sample_end, sample_total,
                     passes_total, passes_own, pass_samples, time_limit_ms, noise_target,
                     pass_frames, pass_auto, aovs)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16,
                     ?17, ?18, ?19, ?20, ?21, ?22, ?23, ?24, ?25, ?26, ?27, ?28)",
                params![
                    j.id as i64,
                    s.bundle_hash,
                    s.camera,
                    s.priority,
                    s.width,
                    s.height,
                    s.tile_size,
                    s.output_name,
                    s.submitter,
                    j.state.name(),
                    j.submitted_ms as i64,
                    s.frame,
                    j.seq.parent.map(|p| p as i64),
                    j.seq.frames.map(|f| f.0),
                    j.seq.frames.map(|f| f.1),
                    s.scene,
                    s.samples.map(|r| r.pass),
                    s.samples.map(|r| r.start),
                    s.samples.map(|r| r.end),
                    s.samples.map(|r| r.total),
                    j.seq.passes.map(|p| p.total),
                    j.seq.passes.map(|p| p.own),
                    j.seq.passes.map(|p| p.pass),
                    j.seq.passes.map(|p| p.time_limit_ms as i64),
                    j.seq.passes.map(|p| p.noise_target),
                    j.seq.passes.map(|p| p.frames),
                    j.seq.passes.map(|p| p.auto),
                    (!s.aovs.is_empty()).then(|| s.aovs.bits()),
                ],
            )
            .map_err(db_err)?;
        Ok(())
    }

    /// Changes a job's priority (the monitor's priority buttons).
    pub fn set_priority(&self, job: JobId, priority: i32) -> Result<(), FarmError> {
        self.inner
            .lock()
            .conn
            .execute(
                "UPDATE jobs SET priority = ?2 WHERE id = ?1",
                params![job as i64, priority],
            )
            .map_err(db_err)?;
        Ok(())
    }

    /// Records a job's end and drops its stored tiles.
    pub fn finish_job(&self, j: &StoredJob) -> Result<(), FarmError> {
        self.finish_frame(j, None, None)
    }

    /// Stores a progressive job's passes (its samples, its last error, its
    /// frame range of passes) and state: an extension, or a stop.
    pub fn set_passes(
        &self,
        job: JobId,
        passes: &StoredPasses,
        last: u32,
        state: JobState,
    ) -> Result<(), FarmError> {
        let mut guard = self.inner.lock();
        let tx = guard.conn.transaction().map_err(db_err)?;
        set_passes(&tx, job, passes)?;
        tx.execute(
            "UPDATE jobs SET last_frame = ?2, state = ?3, elapsed_ms = NULL, render_ms = NULL,
                 error = NULL WHERE id = ?1",
            params![job as i64, last, state.name()],
        )
        .map_err(db_err)?;
        tx.commit().map_err(db_err)
    }

    /// Like [`Store::finish_job`], and for a frame of a sequence in the same
    /// transaction the sequence's count of finished frames (`(sequence,
    /// frames_done)`), so a restart never finds one without the other.
    /// For a pass of a progressive job, `passes` is the job's passes after
    /// it, stored with the count.
    pub fn finish_frame(
        &self,
        j: &StoredJob,
        seq: Option<(JobId, u32)>,
        passes: Option<&StoredPasses>,
    ) -> Result<(), FarmError> {
        let mut guard = self.inner.lock();
        let inner = &mut *guard;
        let tx = inner.conn.transaction().map_err(db_err)?;
        if let Some((seq, done)) = seq {
            tx.execute(
                "UPDATE jobs SET frames_done = ?2 WHERE id = ?1",
                params![seq as i64, done],
            )
            .map_err(db_err)?;
            if let Some(p) = passes {
                set_passes(&tx, seq, p)?;
            }
        }
        tx.execute(
            "UPDATE jobs SET state = ?2, elapsed_ms = ?3, error = ?4, finish_order = ?5,
                 tiles_done = ?6, rays = ?7, frames_done = ?8, render_ms = ?9 WHERE id = ?1",
            params![
                j.id as i64,
                j.state.name(),
                j.elapsed.map(|d| d.as_millis() as i64),
                j.error,
                j.finish_order as i64,
                j.tiles_done as i64,
                j.rays as i64,
                j.seq.frames_done,
                j.render.map(|d| d.as_millis() as i64),
            ],
        )
        .map_err(db_err)?;
        // A failed still keeps its tiles for a retry (`crate::farm::retry`)
        // until it is forgotten; every other end drops them.
        let keep = j.state == JobState::Failed && j.seq == SeqLink::default();
        if !keep {
            tx.execute("DELETE FROM tile_refs WHERE job = ?1", params![j.id as i64])
                .map_err(db_err)?;
        }
        tx.commit().map_err(db_err)?;
        inner.files.remove(&j.id);
        if !keep {
            let _ = std::fs::remove_file(inner.dir.join(format!("{}.f32", j.id)));
        }
        Ok(())
    }

    /// Makes failed job `id` unfinished again (a retry): queued, its end
    /// forgotten; its stored tiles stay.
    pub fn reopen_job(&self, id: JobId) -> Result<(), FarmError> {
        self.inner
            .lock()
            .conn
            .execute(
                "UPDATE jobs SET state = ?2, elapsed_ms = NULL, error = NULL, finish_order = 0,
                     tiles_done = 0, rays = 0, render_ms = NULL WHERE id = ?1",
                params![id as i64, JobState::Queued.name()],
            )
            .map_err(db_err)?;
        Ok(())
    }

    /// Makes ended job `id` unfinished again with none of its tiles (a
    /// requeue, `crate::farm::requeue`): queued, its end and any tiles it
    /// kept forgotten, in one transaction.
    pub fn requeue_job(&self, id: JobId) -> Result<(), FarmError> {
        let mut guard = self.inner.lock();
        let inner = &mut *guard;
        let tx = inner.conn.transaction().map_err(db_err)?;
        tx.execute(
            "UPDATE jobs SET state = ?2, elapsed_ms = NULL, error = NULL, finish_order = 0,
                 tiles_done = 0, rays = 0, render_ms = NULL WHERE id = ?1",
            params![id as i64, JobState::Queued.name()],
        )
        .map_err(db_err)?;
        tx.execute("DELETE FROM tile_refs WHERE job = ?1", params![id as i64])
            .map_err(db_err)?;
        tx.commit().map_err(db_err)?;
        inner.files.remove(&id);
        let _ = std::fs::remove_file(inner.dir.join(format!("{id}.f32")));
        Ok(())
    }

    /// Records that sequence `id` renders frames again: `frames_done` of
    /// its frames done, and with `reopen` (it had ended) unfinished again.
    pub fn requeue_frames(
        &self,
        id: JobId,
        frames_done: u32,
        reopen: bool,
    ) -> Result<(), FarmError> {
        let inner = self.inner.lock();
        let conn = &inner.conn;
        if reopen {
            conn.execute(
                "UPDATE jobs SET state = ?3, elapsed_ms = NULL, error = NULL, finish_order = 0,
                     render_ms = NULL, frames_done = ?2 WHERE id = ?1",
                params![id as i64, frames_done, JobState::Queued.name()],
            )
        } else {
            conn.execute(
                "UPDATE jobs SET frames_done = ?2 WHERE id = ?1",
                params![id as i64, frames_done],
            )
        }
        .map_err(db_err)?;
        Ok(())
    }

    /// Every job, by id.
    pub fn jobs(&self) -> Result<Vec<StoredJob>, FarmError> {
        let inner = self.inner.lock();
        let mut q = inner
            .conn
            .prepare(
                "SELECT id, bundle_hash, camera, priority, width, height, tile_size, output_name,
                     submitter, state, submitted_ms, elapsed_ms, error, finish_order, tiles_done,
                     rays, frame, parent, first_frame, last_frame, frames_done, render_ms, scene,
                     pass, sample_start, sample_end, sample_total, passes_total, passes_own,
                     pass_samples, time_limit_ms, noise_target, samples_done, noise_error,
                     stopped_by, pass_frames, pass_auto, aovs
                 FROM jobs ORDER BY id",
            )
            .map_err(db_err)?;
        let rows = q
            .query_map([], |r| {
                // The state is read below, where a bad one can name its job.
                let state: String = r.get(9)?;
                let aov_bits: Option<u8> = r.get(37)?;
                let job = StoredJob {
                    id: r.get::<_, i64>(0)? as u64,
                    spec: JobSpec {
                        bundle_hash: r.get(1)?,
                        camera: r.get(2)?,
                        priority: r.get(3)?,
                        width: r.get(4)?,
                        height: r.get(5)?,
                        tile_size: r.get(6)?,
                        output_name: r.get(7)?,
                        frame: r.get(16)?,
                        scene: r.get(22)?,
                        submitter: r.get(8)?,
                        samples: match (
                            r.get::<_, Option<u32>>(23)?,
                            r.get::<_, Option<u32>>(24)?,
                            r.get::<_, Option<u32>>(25)?,
                            r.get::<_, Option<u32>>(26)?,
                        ) {
                            (Some(pass), Some(start), Some(end), Some(total)) => {
                                Some(SampleRange {
                                    pass,
                                    start,
                                    end,
                                    total,
                                })
                            }
                            _ => None,
                        },
                        aovs: Aovs::NONE,
                    },
                    state: JobState::Queued,
                    submitted_ms: r.get::<_, i64>(10)? as u64,
                    elapsed: r
                        .get::<_, Option<i64>>(11)?
                        .map(|ms| Duration::from_millis(ms.max(0) as u64)),
                    render: r
                        .get::<_, Option<i64>>(21)?
                        .map(|ms| Duration::from_millis(ms.max(0) as u64)),
                    error: r.get(12)?,
                    finish_order: r.get::<_, i64>(13)? as u64,
                    tiles_done: r.get::<_, i64>(14)? as u64,
                    rays: r.get::<_, i64>(15)? as u64,
                    seq: SeqLink {
                        parent: r.get::<_, Option<i64>>(17)?.map(|p| p as u64),
                        frames: match (r.get::<_, Option<u32>>(18)?, r.get::<_, Option<u32>>(19)?) {
                            (Some(a), Some(b)) => Some((a, b)),
                            _ => None,
                        },
                        frames_done: r.get::<_, Option<u32>>(20)?.unwrap_or(0),
                        passes: match r.get::<_, Option<u32>>(27)? {
                            None => None,
                            Some(total) => Some(StoredPasses {
                                total,
                                own: r.get::<_, Option<bool>>(28)?.unwrap_or(false),
                                pass: r.get::<_, Option<u32>>(29)?.unwrap_or(1),
                                time_limit_ms: r.get::<_, Option<i64>>(30)?.unwrap_or(0).max(0)
                                    as u64,
                                noise_target: r.get::<_, Option<f64>>(31)?.unwrap_or(0.0),
                                samples_done: r.get::<_, Option<u32>>(32)?.unwrap_or(0),
                                error: r.get(33)?,
                                stopped_by: r
                                    .get::<_, Option<String>>(34)?
                                    .as_deref()
                                    .and_then(StopReason::from_label),
                                frames: r.get::<_, Option<bool>>(35)?.unwrap_or(false),
                                auto: r.get::<_, Option<bool>>(36)?.unwrap_or(false),
                            }),
                        },
                    },
                };
                Ok((job, state, aov_bits))
            })
            .map_err(db_err)?;
        let rows: Vec<(StoredJob, String, Option<u8>)> =
            rows.collect::<Result<Vec<_>, _>>().map_err(db_err)?;
        rows.into_iter()
            .map(|(mut j, state, aov_bits)| {
                j.state = state_from(j.id, &state)?;
                j.spec.aovs = match aov_bits {
                    None => Aovs::NONE,
                    Some(b) => Aovs::from_bits(b).ok_or_else(|| {
                        FarmError::Damaged(format!(
                            "the state database says job {} has render passes {b}, not a set \
                             this coordinator knows",
                            j.id
                        ))
                    })?,
                };
                Ok(j)
            })
            .collect()
    }

    /// Largest job id ever stored, including jobs pruned since.
    pub fn max_job_id(&self) -> Result<u64, FarmError> {
        let v: Option<i64> = self
            .inner
            .lock()
            .conn
            .query_row(
                "SELECT MAX(m) FROM (SELECT MAX(id) AS m FROM jobs
                     UNION ALL SELECT value FROM meta WHERE key = 'max_job_id')",
                [],
                |r| r.get(0),
            )
            .optional()
            .map_err(db_err)?
            .flatten();
        Ok(v.unwrap_or(0).max(0) as u64)
    }

    /// Forgets ended jobs (retention), remembering the largest id so that it
    /// is never given again. Their tiles were dropped when they ended.
    pub fn delete_jobs(&self, ids: &[JobId]) -> Result<(), FarmError> {
        let Some(&max) = ids.iter().max() else {
            return Ok(());
        };
        let mut guard = self.inner.lock();
        let tx = guard.conn.transaction().map_err(db_err)?;
        tx.execute(
            "INSERT INTO meta (key, value) VALUES ('max_job_id', ?1)
             ON CONFLICT(key) DO UPDATE SET value = MAX(value, excluded.value)",
            params![max as i64],
        )
        .map_err(db_err)?;
        {
            let mut del = tx
                .prepare("DELETE FROM jobs WHERE id = ?1")
                .map_err(db_err)?;
            let mut unhold = tx
                .prepare("DELETE FROM holds WHERE job = ?1")
                .map_err(db_err)?;
            // A failed still's tiles, kept for a retry.
            let mut untile = tx
                .prepare("DELETE FROM tile_refs WHERE job = ?1")
                .map_err(db_err)?;
            for &id in ids {
                del.execute(params![id as i64]).map_err(db_err)?;
                unhold.execute(params![id as i64]).map_err(db_err)?;
                untile.execute(params![id as i64]).map_err(db_err)?;
                super::tile_log::delete(&tx, id)?;
                super::blocks::delete(&tx, id)?;
            }
        }
        tx.commit().map_err(db_err)?;
        for &id in ids {
            guard.files.remove(&id);
            let _ = std::fs::remove_file(guard.dir.join(format!("{id}.f32")));
        }
        Ok(())
    }
}
