//! Queueing a job: the job a stored bundle's camera makes ([`Farm::job_spec`],
//! checked against the image bounds), its submission with the per-submitter
//! bound ([`Farm::submit`]), and moving it in the queue
//! ([`Farm::set_priority`]). What is read of the scene to admit it is
//! [`crate::summaries::summarize`], under [`crate::admission`]'s bounds; sequences queue their frames through
//! [`Farm::submit_locked`] (see `sequences.rs`).

use super::checks::output_name;
use super::control::Incoming;
use super::outputs::Output;
use super::{Farm, State};
use crate::error::{FarmError, LimitKind};
use crate::scheduler::{JobFailure, JobId, JobInfo, JobSpec};
use crate::sink::TileSink;
use crate::store::{SeqLink, StoredJob};
use std::sync::{Arc, Mutex};
use std::time::Instant;
use tokio::sync::watch;

/// What a job queued by [`Farm::submit_locked`] is.
#[derive(Clone, Copy)]
pub(super) enum Role<'a> {
    /// A job as users see it (a still), with what its submission brings.
    User(&'a Incoming),
    /// A frame or pass of the sequence or progressive job given.
    Run(JobId),
}

/// Makes a job's [`TileSink`] once its id is known.
pub type MakeSink<'a> = Box<dyn FnOnce(JobId) -> Result<Box<dyn TileSink>, FarmError> + 'a>;

/// How [`Farm::submit`] (and the sequence and progressive submissions)
/// queue a job. `"name".into()` is a submission by `name` with nothing
/// else.
#[derive(Default)]
pub struct SubmitOptions<'a> {
    /// Who submits (a client's address or its token's name), who may have
    /// at most [`Limits::max_jobs_per_submitter`](crate::limits::Limits::max_jobs_per_submitter)
    /// unfinished jobs; empty for in-process callers, who share one count.
    pub who: &'a str,
    /// Where the job's tiles go; `None`: a [`trevi_core::FrameWriter`] writing
    /// [`Farm::output_path`]. Stills only.
    pub sink: Option<MakeSink<'a>>,
    /// `--after`: jobs this one waits for (at most
    /// [`MAX_AFTER`](crate::farm::MAX_AFTER), each submitted before it):
    /// it is held from the moment it has an id and queued once they are
    /// all done; if one of them fails or is cancelled, it fails naming it.
    pub after: Vec<JobId>,
    /// `--notify`: the job's own event URLs, checked by
    /// [`check_urls`](crate::events::check_urls).
    pub notify: Vec<String>,
}

impl<'a> From<&'a str> for SubmitOptions<'a> {
    fn from(who: &'a str) -> Self {
        SubmitOptions {
            who,
            ..SubmitOptions::default()
        }
    }
}

impl Farm {
    /// Describes the job rendering `camera` (empty: the first camera) of a
    /// stored bundle's scene. The scene is read the first time a bundle is
    /// asked about, headers only and within the admission bounds (see
    /// [`crate::admission`]; it reads the bundle: call off the async threads), then
    /// its summary is kept (see [`Summaries`](crate::summaries::Summaries)).
    pub fn job_spec(
        &self,
        bundle_hash: &str,
        camera: &str,
        priority: i32,
        tile_size: u32,
    ) -> Result<JobSpec, FarmError> {
        let summary = match self.summaries.get(bundle_hash) {
            // Cached, but the stored copy must still be there and intact
            // (this also marks it used); checking it reads and hashes the
            // file but parses nothing.
            Some(summary) => {
                self.bundles.open_verified(bundle_hash)?;
                summary
            }
            None => self.summaries.get_or_admit(bundle_hash, |ticket| {
                crate::summaries::summarize(&self.bundles, bundle_hash, ticket)
            })?,
        };
        let cam = if camera.is_empty() {
            summary.cameras.first()
        } else {
            summary.cameras.iter().find(|c| c.id == camera)
        }
        .ok_or_else(|| {
            FarmError::refused_scene(if camera.is_empty() {
                "the scene has no camera".to_string()
            } else {
                format!("the scene has no camera \"{camera}\"")
            })
        })?;
        let output_name = output_name(&cam.output)?;
        let samples = cam.width as u64 * cam.height as u64 * (cam.supersample.max(1) as u64).pow(2);
        let max = self.cfg.limits.max_image_samples;
        if samples > max {
            return Err(FarmError::limit(
                LimitKind::ImageSamples,
                samples,
                max,
                format!(
                    "camera \"{}\": {}x{} at supersample {} is {samples} samples, more than the \
                 coordinator's limit of {max} (--max-image-samples)",
                    cam.id, cam.width, cam.height, cam.supersample
                ),
            ));
        }
        Ok(JobSpec {
            frame: None,
            bundle_hash: bundle_hash.to_string(),
            camera: cam.id.clone(),
            priority,
            width: cam.width,
            height: cam.height,
            tile_size: if tile_size == 0 {
                self.cfg.default_tile
            } else {
                tile_size
            },
            output_name,
            scene: summary.scene.clone(),
            submitter: String::new(),
            samples: None,
            aovs: cam.aovs,
        })
    }

    /// Queues a job; its tiles go where `opts` says.
    pub fn submit(&self, spec: JobSpec, opts: SubmitOptions) -> Result<JobInfo, FarmError> {
        let SubmitOptions {
            who,
            sink: make,
            after,
            notify,
        } = opts;
        let spec = JobSpec {
            submitter: who.to_string(),
            ..spec
        };
        if spec.width == 0 || spec.height == 0 {
            return Err(FarmError::refused_scene("the frame is empty"));
        }
        self.check_memory(&spec)?;
        let incoming = self.incoming(&after, notify)?;
        let mut st = self.state.lock();
        Self::check_submitter(&st, who, self.cfg.limits.max_jobs_per_submitter)?;
        let info = self.submit_locked(&mut st, spec, make, who, Role::User(&incoming))?;
        drop(st);
        self.work.notify_waiters();
        self.settle_incoming(info, incoming.hold.is_some())
    }

    /// Refuses a submission from `who` when it has `max` unfinished jobs.
    pub(super) fn check_submitter(st: &State, who: &str, max: usize) -> Result<(), FarmError> {
        let mine = st.submitters.values().filter(|s| s.as_str() == who).count();
        if mine >= max {
            let who = if who.is_empty() {
                "this submitter"
            } else {
                who
            };
            return Err(FarmError::limit(
                LimitKind::JobsPerSubmitter,
                mine as u64,
                max as u64,
                format!(
                    "{who} already has {mine} unfinished jobs, the coordinator's limit \
                 (--max-jobs-per-submitter)"
                ),
            ));
        }
        Ok(())
    }

    /// Queues a job with the state locked; a frame of sequence `parent` is
    /// not counted against its submitter (its sequence is).
    pub(super) fn submit_locked(
        &self,
        st: &mut State,
        spec: JobSpec,
        make: Option<MakeSink<'_>>,
        who: &str,
        role: Role<'_>,
    ) -> Result<JobInfo, FarmError> {
        let parent = match role {
            Role::User(_) => None,
            Role::Run(seq) => Some(seq),
        };
        let now = Instant::now();
        // The scene's memory estimate, from the summary `job_spec` made.
        let memory = self
            .summaries
            .get(&spec.bundle_hash)
            .map_or(0, |s| s.memory);
        let id = st.sched.submit(spec, now);
        st.sched.set_memory_estimate(id, memory, now);
        let info = st.sched.info(id, now).expect("just submitted");
        // The default output file is opened at the job's first tile (see
        // `outputs`); a sink given by the caller is made now.
        let out = match make {
            None => Output::deferred(
                self.output_path(id, &info.spec.output_name),
                &info.spec,
                info.tiles_total,
            ),
            Some(make) => match make(id) {
                Ok(sink) => Output::new(sink, &info.spec, info.tiles_total),
                Err(e) => {
                    st.sched
                        .finish(id, Err(JobFailure::Output(e.to_string())), now);
                    return Err(e);
                }
            },
        };
        if let Some(store) = &self.store {
            let seq = SeqLink {
                parent,
                ..SeqLink::default()
            };
            let stored = StoredJob::submitted(id, info.spec.clone(), info.state, seq);
            if let Err(e) = store.insert_job(&stored) {
                st.sched
                    .finish(id, Err(JobFailure::Output(e.to_string())), now);
                return Err(e);
            }
        }
        // Held (waiting for other jobs, or a frame of a held sequence):
        // parked before the lock that gave it its id is released.
        if let Role::User(incoming) = role {
            if let Err(e) = st.hold_incoming(id, incoming, self.store.as_ref()) {
                st.sched
                    .finish(id, Err(JobFailure::Output(e.to_string())), now);
                return Err(e);
            }
        }
        st.park_if_held(id, parent);
        let info = st.info(id, now).unwrap_or(info);
        st.outputs.insert(id, Arc::new(Mutex::new(out)));
        st.watchers.insert(id, watch::channel(info.clone()).0);
        match parent {
            None => {
                st.submitters.insert(id, who.to_string());
            }
            Some(seq) => {
                st.parent_of.insert(id, seq);
            }
        }
        tracing::info!(job = id, camera = %info.spec.camera, width = info.spec.width,
            height = info.spec.height, priority = info.spec.priority, frame = ?info.spec.frame,
            "job queued");
        if let Role::User(incoming) = role {
            self.events.submitted(id, &incoming.notify)
        }
        Ok(info)
    }

    /// Moves an unfinished job to another priority (higher runs first).
    pub fn set_priority(&self, job: JobId, priority: i32) -> Result<JobInfo, FarmError> {
        if self.state.lock().seqs.contains_key(&job) {
            return self.set_sequence_priority(job, priority);
        }
        let mut st = self.state.lock();
        // Checked, stored, then applied: a change the database did not
        // take is not made.
        match st.sched.info(job, Instant::now()) {
            None => return Err(FarmError::UnknownJob(job)),
            Some(i) if i.state.is_final() || st.unrecorded.contains_key(&job) => {
                return Err(FarmError::JobOver(job))
            }
            Some(_) => {}
        }
        if let Some(store) = &self.store {
            store.set_priority(job, priority)?;
        }
        st.sched.set_priority(job, priority)?;
        st.publish(job);
        drop(st);
        tracing::info!(job, priority, "job priority changed");
        // A job moved up may now take a worker waiting for work.
        self.work.notify_waiters();
        self.info(job)
    }
}
