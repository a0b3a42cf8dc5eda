//! Sequences: a camera over a frame range, each frame an output of its own.
//!
//! A sequence is not a scheduler job: it has an id from the same space, a
//! row of its own in the database (its frame range and how many frames are
//! done), and its frames are ordinary jobs (`JobSpec::frame` set, the
//! sequence as their `parent` in the database), each leased, streamed,
//! stitched, stored tile by tile and resumed after a restart exactly like a
//! still. So a frame in progress holds what a still holds (the band window,
//! see `crate::scheduler`), and a sequence has at most
//! [`Limits::frames_in_progress`] frames in progress (`--frames-in-progress`,
//! default [`DEFAULT_FRAMES_IN_PROGRESS`], at most
//! [`MAX_FRAMES_IN_PROGRESS`]): the next frame is queued when one ends, in
//! frame order, so a sequence's memory is that many stills'.
//!
//! A frame that is done has its output moved into the sequence's directory
//! (`jobs/<sequence>/shot.0007.png`, with the pass files beside a PNG
//! frame: `shot.0007.albedo.png`…, see `Farm::file_frame`) before its end
//! is recorded, in one transaction with the sequence's count of frames
//! done; retention removes them with the directory. A restart finds
//! every finished frame where it was, and the frames in progress resume
//! from their stored tiles. A frame that fails fails its sequence (the
//! other frames in progress are cancelled); cancelling a sequence cancels
//! its frames in progress; its priority is its frames'.
//!
//! A progressive job (`progressive.rs`) is run by the same code, its runs
//! being passes. Beside this file: `sequences/files.rs`, where a frame's
//! file is found and whose preview stands for a sequence;
//! `sequences/restore.rs`, picking sequences up after a restart.

use super::passes::Passes;
use super::submit::{Role, SubmitOptions};
use super::{Farm, State};
use crate::error::FarmError;
#[cfg(doc)]
use crate::limits::Limits;
use crate::scheduler::{
    FramesInfo, JobFailure, JobId, JobInfo, JobSpec, JobState, Outcome, Scheduler,
};
use crate::store::{wall_ms, SeqLink, StoredJob};
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::PathBuf;
use std::time::{Duration, Instant};
use tokio::sync::watch;
use trevi_core::scene::animation::{frame_output, MAX_FRAME};

mod files;
mod restore;

pub use crate::limits::{DEFAULT_FRAMES_IN_PROGRESS, MAX_FRAMES_IN_PROGRESS};

/// Most frame files a download without a frame looks for on disk (the
/// highest frame done is known in memory; this covers a restart that lost
/// which one it is).
pub const FRAME_SCAN: usize = MAX_FRAMES_IN_PROGRESS + 1;

/// A sequence's bookkeeping.
pub struct Sequence {
    /// The camera's frame: `output_name` is the pattern, `frame` is `None`.
    pub(super) spec: JobSpec,
    pub(super) first: u32,
    pub(super) last: u32,
    /// Frames done.
    pub(super) done: u32,
    /// The next frame to queue.
    pub(super) next: u32,
    /// Frames in progress and their jobs.
    pub(super) running: BTreeMap<u32, JobId>,
    /// Frames before `next` to render again, queued before it (a requeue
    /// or a retry, `requeue/frames.rs`).
    pub(super) again: BTreeSet<u32>,
    pub(super) state: JobState,
    pub(super) submitted: Instant,
    /// When its first frame got its first tile leased, once a frame that
    /// started has ended (frames in progress say it until then).
    pub(super) started: Option<Instant>,
    pub(super) finished: Option<Instant>,
    pub(super) error: Option<String>,
    /// Why a frame failed: the sequence fails at its next step.
    pub(super) failed: Option<String>,
    /// Rays of the frames done.
    pub(super) rays: u64,
    /// The highest frame done, and its job (whose last preview stands for
    /// the sequence once no frame is in progress), when known: what a
    /// download without a frame fetches, found without looking at the
    /// disk.
    pub(super) latest: Option<(u32, Option<JobId>)>,
    /// For a progressive job (see `progressive.rs`): its passes, one in
    /// progress at a time. A progressive still's passes are its "frames"
    /// (`first` 0, `last` the last pass planned); a sequence in passes
    /// renders each frame's passes before the next frame, and `done` counts
    /// passes.
    pub(super) passes: Option<Passes>,
}

/// What a [`Sequence`] runs one after the other: frames of an animation,
/// or the passes of a progressive still.
pub enum Runs {
    /// Frames `first..=last` of the camera, each in `passes` when set.
    Frames {
        /// The first frame number.
        first: u32,
        /// The last frame number (inclusive).
        last: u32,
        /// Each frame's passes, for a sequence in passes.
        passes: Option<Passes>,
    },
    /// A still's passes (see `progressive.rs`).
    Passes(Passes),
}

/// The frame or pass a job of a sequence renders.
pub(super) fn run_index(spec: &JobSpec) -> Option<u32> {
    spec.frame.or(spec.samples.map(|r| r.pass))
}

impl Sequence {
    /// Whether the runs are frames (with or without passes each), not a
    /// still's passes.
    pub(super) fn frames(&self) -> bool {
        self.passes.as_ref().is_none_or(|p| p.frames)
    }

    /// The runs of one frame: its passes in a sequence in passes, else 1.
    fn runs_per_frame(&self) -> u32 {
        match &self.passes {
            Some(p) if p.frames => p.total.div_ceil(p.pass).max(1),
            _ => 1,
        }
    }

    /// The runs in all: frames, a still's passes, or frames × passes.
    fn count(&self) -> u64 {
        u64::from(self.last - self.first + 1) * u64::from(self.runs_per_frame())
    }

    fn tiles_per_frame(&self) -> u64 {
        let t = u64::from(self.spec.tile_size.max(1));
        u64::from(self.spec.width).div_ceil(t) * u64::from(self.spec.height).div_ceil(t)
    }

    /// The sequence's status: its frames' tiles as its tiles.
    pub(super) fn info(&self, id: JobId, sched: &Scheduler, now: Instant) -> JobInfo {
        let per = self.tiles_per_frame();
        let mut tiles_done = u64::from(self.done) * per;
        let mut rays = self.rays;
        let mut current = None;
        let mut started = self.done > 0;
        let mut began = self.started;
        for (&f, &job) in &self.running {
            if let Some(i) = sched.info(job, now) {
                tiles_done += i.tiles_done;
                rays = rays.saturating_add(i.rays);
                started |= i.state != JobState::Queued;
                began = earliest_start(began, &i, now);
                current.get_or_insert((f, i.tiles_done, i.tiles_total));
            }
        }
        if !self.frames() {
            // A pass's tiles are the job's: the current pass's, or all of
            // them once one is done and none is running.
            let current = current.map_or(0, |c| c.1);
            tiles_done = if self.running.is_empty() && self.done > 0 {
                per
            } else {
                current
            };
        }
        let end = self.finished.unwrap_or(now);
        let state = match self.state {
            JobState::Queued if started => JobState::Running,
            s => s,
        };
        JobInfo {
            id,
            spec: self.spec.clone(),
            state,
            tiles_total: match self.frames() {
                false => per,
                true => self.count() * per,
            },
            tiles_done,
            rays,
            elapsed: end.saturating_duration_since(self.submitted),
            queued: began
                .unwrap_or(end)
                .clamp(self.submitted, end.max(self.submitted))
                .saturating_duration_since(self.submitted),
            error: self.error.clone(),
            finish_order: 0,
            frames: self.frames().then_some(FramesInfo {
                first: self.first,
                last: self.last,
                done: self.done / self.runs_per_frame(),
                in_progress: self.running.len() as u32,
                current,
            }),
            passes: self.passes.as_ref().map(|p| match p.frames {
                // The current frame's passes.
                true => p.info(self.done % self.runs_per_frame()),
                false => p.info(self.done),
            }),
            paused: false,
            waiting_for: Vec::new(),
            blocked: self
                .running
                .values()
                .flat_map(|&j| sched.blocked(j))
                .collect(),
        }
    }
}

/// The earlier of `began` and the time frame `info` (as of `at`, when it
/// ended or now) got its first tile, if it did.
fn earliest_start(began: Option<Instant>, info: &JobInfo, at: Instant) -> Option<Instant> {
    let rendered = info.elapsed.saturating_sub(info.queued);
    if info.state == JobState::Queued && rendered.is_zero() {
        return began;
    }
    let start = at.checked_sub(rendered).unwrap_or(at);
    Some(began.map_or(start, |b| b.min(start)))
}

/// The output pattern of a sequence from its camera's output name: kept
/// when it has a run of `#`, else `.####` goes before the extension
/// (`shot.png` → `shot.####.png`).
pub fn sequence_pattern(output_name: &str) -> String {
    if output_name.contains('#') {
        return output_name.to_string();
    }
    match output_name.rfind('.') {
        Some(i) => format!("{}.####{}", &output_name[..i], &output_name[i..]),
        None => format!("{output_name}.####"),
    }
}

impl State {
    /// A frame job of sequence `seq` ended as `ending` says (`counted`: it
    /// is done and counted in the database).
    pub(super) fn frame_ended(&mut self, seq: JobId, job: JobId, ending: &JobInfo, counted: bool) {
        self.parent_of.remove(&job);
        if let Some(f) = run_index(&ending.spec) {
            self.ended.frame(job, seq, f);
        }
        let Some(s) = self.seqs.get_mut(&seq) else {
            return;
        };
        if let Some(f) = run_index(&ending.spec) {
            s.running.remove(&f);
        }
        if ending.tiles_done > 0 {
            s.started = earliest_start(s.started, ending, Instant::now());
        }
        if counted {
            s.done += 1;
            s.rays = s.rays.saturating_add(ending.rays);
            if let Some(f) = run_index(&ending.spec) {
                if s.latest.is_none_or(|(l, _)| f >= l) {
                    s.latest = Some((f, Some(job)));
                }
            }
        } else if !s.state.is_final() && s.failed.is_none() {
            let what = match (ending.spec.frame, ending.spec.samples) {
                (None, Some(r)) => format!("pass {} (samples {}..{})", r.pass + 1, r.start, r.end),
                (f, _) => format!("frame {}", f.unwrap_or_default()),
            };
            s.failed = Some(format!(
                "{what}: {}",
                ending.error.as_deref().unwrap_or("failed")
            ));
        }
    }

    /// Ended jobs and sequences with when they ended, newest first (a
    /// sequence's frames count as jobs of their own).
    pub(super) fn ended(&self) -> Vec<(JobId, Instant)> {
        let mut v = self.sched.ended();
        v.extend(
            self.seqs
                .iter()
                .filter(|(_, s)| s.state.is_final())
                .map(|(&id, s)| (id, s.finished.unwrap_or(s.submitted))),
        );
        v.sort_unstable_by_key(|&(id, t)| std::cmp::Reverse((t, id)));
        v
    }

    /// Up to `limit` jobs and sequences by id from `from` on (frames of
    /// sequences are not listed: their sequence is), and where the next
    /// page starts.
    pub(super) fn list_from(
        &self,
        from: JobId,
        limit: usize,
        now: Instant,
    ) -> (Vec<JobInfo>, Option<JobId>) {
        let mut ids: Vec<JobId> = self
            .sched
            .list_from(from, usize::MAX, now)
            .0
            .into_iter()
            .filter(|i| run_index(&i.spec).is_none())
            .map(|i| i.id)
            .chain(self.seqs.keys().copied().filter(|&id| id >= from))
            .collect();
        ids.sort_unstable();
        let next = ids.get(limit).copied();
        ids.truncate(limit);
        let page = ids
            .into_iter()
            .filter_map(|id| self.info(id, now))
            .collect();
        (page, next)
    }
}

impl Farm {
    /// Queues a sequence: frames `first..=last` of `spec`'s camera, each
    /// output named from `spec.output_name` by [`sequence_pattern`]. It
    /// counts as one job of its submitter.
    pub fn submit_sequence<'a>(
        &self,
        spec: JobSpec,
        first: u32,
        last: u32,
        opts: impl Into<SubmitOptions<'a>>,
    ) -> Result<JobInfo, FarmError> {
        self.submit_frames(spec, first, last, None, opts.into())
    }

    /// [`Farm::submit_sequence`], each frame in `passes` when given.
    pub(super) fn submit_frames(
        &self,
        spec: JobSpec,
        first: u32,
        last: u32,
        passes: Option<Passes>,
        opts: SubmitOptions,
    ) -> Result<JobInfo, FarmError> {
        if first > last || last > MAX_FRAME {
            return Err(FarmError::Invalid(format!(
                "frames {first}-{last}: a range is first-last, both in [0, {MAX_FRAME}]"
            )));
        }
        self.submit_runs(
            spec,
            Runs::Frames {
                first,
                last,
                passes,
            },
            opts,
        )
    }

    /// Queues a sequence of `runs`: frames, or a progressive still's passes.
    pub(super) fn submit_runs(
        &self,
        mut spec: JobSpec,
        runs: Runs,
        opts: SubmitOptions,
    ) -> Result<JobInfo, FarmError> {
        let who = opts.who;
        if opts.sink.is_some() {
            return Err(FarmError::Invalid(
                "a sink of its own is for a still: a sequence's frames and passes are \
                 written by the farm"
                    .into(),
            ));
        }
        if spec.width == 0 || spec.height == 0 {
            return Err(FarmError::refused_scene("the frame is empty"));
        }
        self.check_memory(&spec)?;
        let incoming = self.incoming(&opts.after, opts.notify)?;
        let (first, last, passes) = match runs {
            Runs::Frames {
                first,
                last,
                passes,
            } => {
                spec.output_name = sequence_pattern(&spec.output_name);
                (first, last, passes)
            }
            Runs::Passes(p) => (0, p.remaining().max(1) - 1, Some(p)),
        };
        spec.frame = None;
        spec.samples = None;
        spec.submitter = who.to_string();
        let now = Instant::now();
        let mut st = self.state.lock();
        Self::check_submitter(&st, who, self.cfg.limits.max_jobs_per_submitter)?;
        let id = st.sched.reserve_id();
        if let Some(store) = &self.store {
            let link = SeqLink {
                frames: Some((first, last)),
                passes: passes.as_ref().map(Passes::stored),
                ..SeqLink::default()
            };
            store.insert_job(&StoredJob::submitted(
                id,
                spec.clone(),
                JobState::Queued,
                link,
            ))?;
        }
        let seq = Sequence {
            spec,
            first,
            last,
            done: 0,
            next: first,
            running: BTreeMap::new(),
            again: BTreeSet::new(),
            state: JobState::Queued,
            submitted: now,
            started: None,
            finished: None,
            error: None,
            failed: None,
            rays: 0,
            latest: None,
            passes,
        };
        st.hold_incoming(id, &incoming, self.store.as_ref())?;
        st.seqs.insert(id, seq);
        let info = st.info(id, now).expect("just inserted");
        st.watchers.insert(id, watch::channel(info.clone()).0);
        st.submitters.insert(id, who.to_string());
        self.events.submitted(id, &incoming.notify);
        drop(st);
        tracing::info!(job = id, first, last, camera = %info.spec.camera, "sequence queued");
        self.advance(id);
        let info = self.info(id)?;
        self.settle_incoming(info, incoming.hold.is_some())
    }

    /// Moves a sequence on: queues its next frames while fewer than
    /// [`Limits::frames_in_progress`] are in progress, ends it when every frame is
    /// done, or fails it when a frame failed.
    pub(super) fn advance(&self, seq: JobId) {
        loop {
            let mut st = self.state.lock();
            let Some(s) = st.seqs.get(&seq) else {
                return;
            };
            if s.state.is_final() {
                return;
            }
            if let Some(why) = s.failed.clone() {
                let running: Vec<JobId> = s.running.values().copied().collect();
                drop(st);
                self.end_sequence(seq, Err(JobFailure::Part(why)));
                for job in running {
                    let _ = self.cancel(job);
                }
                return;
            }
            // A still's passes left, as sized now (its pass size may
            // change after each pass), unless it was stopped.
            let replan = s
                .passes
                .as_ref()
                .filter(|p| !p.frames && p.stopped_by.is_none())
                .map(|p| s.done + p.remaining());
            if let Some(runs) = replan.filter(|&r| r > 0) {
                st.seqs.get_mut(&seq).expect("checked above").last = runs - 1;
            }
            let Some(s) = st.seqs.get(&seq) else {
                return;
            };
            if u64::from(s.done) >= s.count() {
                drop(st);
                self.end_sequence(seq, Ok(()));
                return;
            }
            let most = match s.passes {
                // Each pass continues the states of the one before.
                Some(_) => 1,
                None => self.cfg.limits.frames_in_progress.max(1),
            };
            // A sequence in passes between two passes of a frame.
            let mid_frame = s
                .passes
                .as_ref()
                .is_some_and(|p| p.frames && p.samples_done > 0 && p.samples_done < p.total);
            // A frame to render again goes first.
            let again = s.again.first().copied().filter(|_| !mid_frame);
            if s.running.len() >= most || (again.is_none() && s.next > s.last && !mid_frame) {
                return;
            }
            let rendered = s.started.map_or(Duration::ZERO, |t| t.elapsed());
            if let Some(why) = s.passes.as_ref().and_then(|p| p.stop(rendered)) {
                let s = st.seqs.get_mut(&seq).expect("checked above");
                let p = s.passes.as_mut().expect("checked above");
                p.stopped_by = Some(why);
                s.last = s.done.saturating_sub(1);
                tracing::info!(
                    job = seq,
                    passes = s.done,
                    why = why.label(),
                    "passes stopped"
                );
                continue;
            }
            // The frame (or a still's pass) the run renders, and whether it
            // starts a frame.
            let (f, starts) = if mid_frame {
                (s.next - 1, false)
            } else {
                (again.unwrap_or(s.next), true)
            };
            let done = s.done;
            let s = st.seqs.get_mut(&seq).expect("checked above");
            if let Some(p) = s.passes.as_mut().filter(|p| p.frames && starts) {
                p.samples_done = 0;
            }
            let spec = match &s.passes {
                Some(p) if !p.frames => JobSpec {
                    samples: Some(p.range(f)),
                    ..s.spec.clone()
                },
                passes => JobSpec {
                    frame: Some(f),
                    output_name: frame_output(&s.spec.output_name, f),
                    // A sequence's passes are counted across its frames
                    // (which state file each uses).
                    samples: passes.as_ref().map(|p| p.range(done)),
                    ..s.spec.clone()
                },
            };
            let who = s.spec.submitter.clone();
            let queued = self.submit_locked(&mut st, spec, None, &who, Role::Run(seq));
            let s = st.seqs.get_mut(&seq).expect("checked above");
            if again.is_some() {
                s.again.remove(&f);
            } else if starts {
                s.next = f + 1;
            }
            match queued {
                Ok(info) => {
                    s.running.insert(f, info.id);
                    st.publish(seq);
                    drop(st);
                    self.work.notify_waiters();
                }
                Err(e) => s.failed = Some(format!("frame {f}: {e}")),
            }
        }
    }

    /// Runs finished progressive job `seq` again with `passes` (an
    /// extension): recorded first, then its next pass is queued.
    pub(super) fn reopen_runs(&self, seq: JobId, passes: Passes) -> Result<(), FarmError> {
        {
            let mut st = self.state.lock();
            let s = st.seqs.get_mut(&seq).ok_or(FarmError::UnknownJob(seq))?;
            let last = s.done + passes.remaining().max(1) - 1;
            if let Some(store) = &self.store {
                store.set_passes(seq, &passes.stored(), last, JobState::Running)?;
            }
            s.last = last;
            s.next = s.done;
            s.passes = Some(passes);
            s.state = JobState::Running;
            s.finished = None;
            s.error = None;
            s.failed = None;
            let who = s.spec.submitter.clone();
            st.submitters.insert(seq, who);
            self.events.restored(seq);
            st.publish(seq);
        }
        tracing::info!(job = seq, "progressive job extended");
        self.advance(seq);
        Ok(())
    }

    /// Moves a finished frame's output into its sequence's directory, with
    /// the pass files beside a PNG frame (`aovs::pass_files`). Each move
    /// is a rename (a whole file or none is seen); the passes go first and
    /// the frame last, so a frame whose file is there (what
    /// [`Farm::frame_file`] looks for) has its passes there too. A pass that
    /// cannot be moved leaves the frame where it was (the frame fails; a
    /// render again rewrites them all).
    pub(super) fn file_frame(
        &self,
        seq: JobId,
        job: JobId,
        spec: &JobSpec,
    ) -> Result<(), FarmError> {
        let from = self.output_path(job, &spec.output_name);
        let to = self.output_path(seq, &spec.output_name);
        let dir = to.parent().expect("jobs/<id>/name");
        std::fs::create_dir_all(dir)
            .map_err(|e| FarmError::io(format!("cannot create {}", dir.display()), e))?;
        let passes = super::aovs::pass_files(&from, spec.aovs);
        let filed = super::aovs::pass_files(&to, spec.aovs);
        for (from, to) in passes.iter().zip(&filed).chain([(&from, &to)]) {
            std::fs::rename(from, to).map_err(|e| {
                FarmError::io(format!("moving {} to {}", from.display(), to.display()), e)
            })?;
        }
        let _ = std::fs::remove_dir(from.parent().expect("jobs/<id>/name"));
        Ok(())
    }

    /// Ends a sequence and records it.
    fn end_sequence(&self, seq: JobId, result: Outcome) {
        let mut st = self.state.lock();
        let now = Instant::now();
        let Some(s) = st.seqs.get_mut(&seq) else {
            return;
        };
        if s.state.is_final() {
            return;
        }
        s.finished = Some(now);
        self.events.ended(seq, &result);
        match result {
            Ok(()) => s.state = JobState::Done,
            Err(e) => {
                s.state = JobState::Failed;
                s.error = Some(e.message());
            }
        }
        let info = st.info(seq, now).expect("just ended");
        if let (Some(store), Some(p)) = (
            &self.store,
            st.seqs.get(&seq).and_then(|s| s.passes.as_ref()),
        ) {
            let last = st.seqs.get(&seq).map_or(0, |s| s.last);
            if let Err(e) = store.set_passes(seq, &p.stored(), last, info.state) {
                tracing::error!(job = seq, error = %e, "cannot record the passes");
            }
        }
        match &info.error {
            None => tracing::info!(job = seq, "sequence done"),
            Some(e) => tracing::error!(job = seq, error = %e, "sequence failed"),
        }
        // Not recorded (a full disk): a restart finds it unfinished and
        // ends it again from its frames.
        if let Err(e) = self.persist_end(&info) {
            tracing::error!(job = seq, error = %e, "cannot record the end of the sequence");
        }
        st.submitters.remove(&seq);
        st.publish(seq);
        drop(st);
        self.release_waiters(seq);
    }

    /// Cancels a sequence and its frames in progress (their partial outputs
    /// are removed; finished frames stay).
    pub(super) fn cancel_sequence(&self, seq: JobId) -> Result<JobInfo, FarmError> {
        let running: Vec<JobId> = {
            let mut st = self.state.lock();
            let now = Instant::now();
            let Some(s) = st.seqs.get(&seq) else {
                return Err(FarmError::UnknownJob(seq));
            };
            if s.state.is_final() {
                return Ok(st.info(seq, now).expect("exists"));
            }
            let mut ending = st.info(seq, now).expect("exists");
            ending.state = JobState::Cancelled;
            self.persist_end(&ending).map_err(|e| {
                FarmError::io(format!("cannot record the cancellation of job {seq}"), e)
            })?;
            let s = st.seqs.get_mut(&seq).expect("exists");
            s.state = JobState::Cancelled;
            s.finished = Some(now);
            let running = s.running.values().copied().collect();
            st.submitters.remove(&seq);
            self.events.cancelled(seq);
            running
        };
        for job in running {
            let _ = self.cancel(job);
        }
        tracing::info!(job = seq, "sequence cancelled");
        self.release_waiters(seq);
        let info = self.info(seq);
        self.state.lock().publish(seq);
        info
    }

    /// Moves a sequence and its frames in progress to `priority`.
    pub(super) fn set_sequence_priority(
        &self,
        seq: JobId,
        priority: i32,
    ) -> Result<JobInfo, FarmError> {
        let running: Vec<JobId> = {
            let mut st = self.state.lock();
            let s = st.seqs.get(&seq).ok_or(FarmError::UnknownJob(seq))?;
            if s.state.is_final() {
                return Err(FarmError::JobOver(seq));
            }
            if let Some(store) = &self.store {
                store.set_priority(seq, priority)?;
            }
            let s = st.seqs.get_mut(&seq).expect("exists");
            s.spec.priority = priority;
            s.running.values().copied().collect()
        };
        for job in running {
            // A frame that just ended is over: nothing to move.
            match self.set_priority(job, priority) {
                Ok(_) | Err(FarmError::JobOver(_)) | Err(FarmError::UnknownJob(_)) => {}
                Err(e) => return Err(e),
            }
        }
        tracing::info!(job = seq, priority, "sequence priority changed");
        self.info(seq)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns() {
        assert_eq!(sequence_pattern("shot.##.png"), "shot.##.png");
        assert_eq!(sequence_pattern("shot.png"), "shot.####.png");
        assert_eq!(sequence_pattern("out"), "out.####");
    }
}
