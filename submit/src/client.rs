//! The client of a coordinator: upload a bundle, submit jobs, watch them,
//! download the images; and `status`, `list`, `cancel`, `fetch`.
//!
//! It drives a farm's coordinator and the one embedded in `trevi-submit`
//! for a local render (see `local.rs`) alike, so both produce the same
//! bytes.

use anyhow::{bail, Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::time::Duration;
use trevi_core::output::Format;
use trevi_core::Bundle;
use trevi_proto::pb::{self, bundles_client::BundlesClient, jobs_client::JobsClient, JobState};
use trevi_proto::{AuthChannel, Bearer, ClientTls, CHUNK_SIZE, MAX_MESSAGE_SIZE};

/// How long `trevi-submit` keeps retrying an upload that a coordinator
/// refuses only because all its upload slots (`--max-uploads`) are busy.
const UPLOAD_BUSY_PATIENCE: Duration = Duration::from_secs(300);

/// How progress is shown.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Progress {
    Quiet,
    /// A progress bar (stderr is a terminal).
    Bar,
    /// Plain lines every 10 %.
    Lines,
}

/// A bundle as it travels: its encoding and the hash of that encoding,
/// computed once (the local render's embedded farm and the upload share it).
pub struct Encoded {
    pub bytes: Vec<u8>,
    pub hash: String,
}

impl Encoded {
    pub fn new(bundle: &Bundle) -> Encoded {
        let bytes = bundle.encode();
        let hash = trevi_core::bundle::sha256_hex(&bytes);
        Encoded { bytes, hash }
    }
}

/// A connection to a coordinator.
pub struct Client {
    url: String,
    /// Say which jobs were queued where (off for the embedded farm).
    pub announce: bool,
    /// Keep the watched job's live preview in this PNG file (`--preview`).
    pub preview: Option<PathBuf>,
    /// The jobs submitted through this connection, in order.
    pub submitted: Vec<u64>,
    jobs: JobsClient<AuthChannel>,
    bundles: BundlesClient<AuthChannel>,
}

/// One camera to render and where its image goes.
pub struct Target {
    pub camera: String,
    /// Its extension decides the format the coordinator writes (see
    /// [`Target::new`]).
    pub out: PathBuf,
    pub format: Format,
}

impl Target {
    /// Checks `out` before anything is rendered: its extension must name a
    /// format (.png or .exr) and it must not be anything but a regular file
    /// if it exists (see [`trevi_core::output::check_output`]).
    pub fn new(camera: String, out: PathBuf) -> Result<Target> {
        crate::cli::still_output(&out)?;
        let format = trevi_core::output::check_output(&out)?;
        Ok(Target {
            camera,
            out,
            format,
        })
    }
}

impl Client {
    /// Connects to `url`, sending `token` (the coordinator's submit token)
    /// with every call.
    pub async fn connect(url: &str, token: Option<&str>) -> Result<Client> {
        Client::connect_with(url, token, &ClientTls::default()).await
    }

    /// [`Client::connect`] with TLS settings for an `https://` coordinator.
    pub async fn connect_with(url: &str, token: Option<&str>, tls: &ClientTls) -> Result<Client> {
        let bearer = Bearer::new(token).map_err(|e| anyhow::anyhow!("--token: {e}"))?;
        let channel = trevi_proto::endpoint(url, tls)?
            .connect_timeout(Duration::from_secs(10))
            .tcp_nodelay(true)
            .connect()
            .await
            .map_err(|e| {
                let why = trevi_proto::connect::error_chain(&e);
                anyhow::anyhow!("cannot reach the coordinator at {url}: {why}")
            })?;
        Ok(Client {
            url: url.to_string(),
            announce: true,
            preview: None,
            submitted: Vec::new(),
            jobs: JobsClient::with_interceptor(channel.clone(), bearer.clone())
                .max_decoding_message_size(MAX_MESSAGE_SIZE),
            bundles: BundlesClient::with_interceptor(channel, bearer)
                .max_decoding_message_size(MAX_MESSAGE_SIZE),
        })
    }

    /// Uploads exactly this bundle, in chunks; returns its hash.
    pub async fn upload(&mut self, bundle: &Encoded) -> Result<String> {
        let (bytes, want) = (&bundle.bytes, bundle.hash.clone());
        let chunks: Vec<pb::BundleChunk> = bytes
            .chunks(CHUNK_SIZE)
            .map(|c| pb::BundleChunk { data: c.to_vec() })
            .collect();
        // A busy coordinator (its --max-uploads slots all taken by other
        // submitters) says "try again shortly": wait and retry, doubling
        // the wait to 5 s, for at most UPLOAD_BUSY_PATIENCE.
        let started = std::time::Instant::now();
        let mut backoff = Duration::from_millis(100);
        let got = loop {
            match self
                .bundles
                .upload_bundle(tokio_stream::iter(chunks.clone()))
                .await
            {
                Err(s)
                    if s.code() == tonic::Code::ResourceExhausted
                        && s.message().contains("--max-uploads")
                        && started.elapsed() < UPLOAD_BUSY_PATIENCE =>
                {
                    tokio::time::sleep(backoff).await;
                    backoff = (backoff * 2).min(Duration::from_secs(5));
                }
                r => {
                    break r
                        .map_err(status_error)
                        .context("the coordinator refused the scene bundle")?
                        .into_inner()
                }
            }
        };
        if got.hash != want {
            bail!(
                "the coordinator stored the bundle as {} instead of {want}",
                got.hash
            );
        }
        Ok(want)
    }

    pub async fn submit(
        &mut self,
        bundle_hash: &str,
        camera: &str,
        priority: i32,
        tile_size: u32,
        format: Format,
    ) -> Result<pb::JobStatus> {
        Ok(self
            .jobs
            .submit_job(pb::SubmitJobRequest {
                bundle_hash: bundle_hash.to_string(),
                camera: camera.to_string(),
                priority,
                tile_size,
                output_format: format.extension().to_string(),
                frames: None,
            })
            .await
            .map_err(status_error)
            .with_context(|| format!("the coordinator refused camera \"{camera}\""))?
            .into_inner())
    }

    /// Follows a job until it ends, showing progress; returns its last status.
    ///
    /// When the coordinator goes away (it keeps its jobs across a restart),
    /// keeps asking again with backoff for up to [`RECONNECT_FOR`].
    pub async fn watch(&mut self, id: u64, progress: Progress) -> Result<pb::JobStatus> {
        let mut view = ProgressView::new(progress);
        let mut last: Option<pb::JobStatus> = None;
        let mut preview = PreviewFile::new(self.preview.clone());
        let mut backoff = Duration::from_millis(100);
        let mut lost_since: Option<std::time::Instant> = None;
        loop {
            let why = match self.jobs.watch_job(pb::JobId { id, frame: None }).await {
                Ok(r) => {
                    let mut stream = r.into_inner();
                    loop {
                        match stream.message().await {
                            Ok(Some(s)) => {
                                lost_since = None;
                                backoff = Duration::from_millis(100);
                                view.show(&s);
                                preview.update(self, &s).await;
                                last = Some(s);
                            }
                            Ok(None) => break "the progress stream ended".to_string(),
                            Err(s) if reconnectable(&s) => break s.message().to_string(),
                            Err(s) => {
                                view.done();
                                return Err(status_error(s));
                            }
                        }
                    }
                }
                Err(s) if reconnectable(&s) => s.message().to_string(),
                Err(s) => {
                    view.done();
                    return Err(status_error(s));
                }
            };
            if let Some(l) = &last {
                if l.state().is_final() {
                    break;
                }
            }
            let since = *lost_since.get_or_insert_with(std::time::Instant::now);
            if since.elapsed() > RECONNECT_FOR {
                view.done();
                match &last {
                    Some(l) => bail!(
                        "lost the coordinator while job {id} was {}: {why}",
                        l.state().label()
                    ),
                    None => bail!("lost the coordinator watching job {id}: {why}"),
                }
            }
            if progress != Progress::Quiet && backoff == Duration::from_millis(100) {
                eprintln!("lost the coordinator ({why}); reconnecting");
            }
            tokio::time::sleep(backoff).await;
            backoff = (backoff * 2).min(Duration::from_secs(2));
        }
        view.done();
        Ok(last.expect("checked above"))
    }

    /// Downloads a finished job's image, which must be a `format` file, to
    /// `out` (through a temporary file beside it, renamed into place when
    /// complete; removed on failure, or when this future is dropped).
    pub async fn download(&mut self, id: u64, out: &Path, format: Format) -> Result<u64> {
        self.download_frame(id, None, out, format).await
    }

    /// Like [`Client::download`], for frame `frame` of a sequence.
    pub async fn download_frame(
        &mut self,
        id: u64,
        frame: Option<u32>,
        out: &Path,
        format: Format,
    ) -> Result<u64> {
        use tokio::io::AsyncWriteExt;
        let mut stream = self
            .jobs
            .download_output(pb::JobId { id, frame })
            .await
            .map_err(status_error)?
            .into_inner();
        let mut tmp = PartFile::new(out).await?;
        let mut file = tokio::fs::File::create(&tmp.path)
            .await
            .with_context(|| format!("cannot write {}", tmp.path.display()))?;
        let mut size = None;
        let mut got = 0u64;
        while let Some(c) = stream.message().await.map_err(status_error)? {
            if size.is_none() {
                size = Some(c.size);
                // A coordinator that ignores `output_format` (older than
                // it) sends the scene's format: never store those bytes
                // under a name that promises another.
                let is = Format::sniff(&c.data);
                if is != Some(format) {
                    bail!(
                        "job {id}'s output is {}, not the {} file {} must be; \
                         submit again with -o FILE.{}, or to a newer coordinator",
                        is.map_or("not an image", |f| f.extension()),
                        format.extension(),
                        out.display(),
                        is.map_or("png", |f| f.extension()),
                    );
                }
            }
            got += c.data.len() as u64;
            file.write_all(&c.data).await?;
        }
        file.sync_all().await?;
        drop(file);
        if size != Some(got) {
            bail!("the download of job {id} stopped at {got} of {size:?} bytes");
        }
        tmp.persist(out).await?;
        Ok(got)
    }

    /// Writes job `id`'s live preview (a PNG) to `out`, through a temporary
    /// file renamed into place so a viewer never sees half an image.
    pub async fn save_preview(&mut self, id: u64, out: &Path) -> Result<pb::Preview> {
        let p = self
            .jobs
            .get_preview(pb::JobId { id, frame: None })
            .await
            .map_err(status_error)?
            .into_inner();
        let mut tmp = PartFile::new(out).await?;
        tokio::fs::write(&tmp.path, &p.png)
            .await
            .with_context(|| format!("cannot write {}", tmp.path.display()))?;
        tmp.persist(out).await?;
        Ok(p)
    }

    /// `trevi-submit fetch`: downloads finished job `id`'s image to `out`,
    /// by default the job's output file name in the current directory.
    /// Returns where it went and the job's status.
    pub async fn fetch(&mut self, id: u64, out: Option<&Path>) -> Result<(PathBuf, pb::JobStatus)> {
        let s = self.status(id).await?;
        if s.frames.is_some() {
            return self.fetch_frames(s, out).await;
        }
        match s.state() {
            JobState::Done => {}
            JobState::Failed => bail!("job {id} failed, it has no image: {}", s.error),
            JobState::Cancelled => bail!("job {id} was cancelled, it has no image"),
            other => bail!(
                "job {id} is {} ({}/{} tiles): fetch it once it is done \
                 (trevi-submit status {id})",
                other.label(),
                s.tiles_done,
                s.tiles_total
            ),
        }
        // Only the name: the coordinator does not choose the directory.
        let name = Path::new(&s.output_name)
            .file_name()
            .map(PathBuf::from)
            .with_context(|| format!("job {id} names no output file ({:?})", s.output_name))?;
        let format = Format::from_path(&name)
            .with_context(|| format!("job {id}'s output {} is not .png or .exr", name.display()))?;
        let out = out.map_or(name, Path::to_path_buf);
        let want = trevi_core::output::check_output(&out)?;
        if want != format {
            bail!(
                "job {id}'s image is a {} file ({}): -o must end in .{}",
                format.extension(),
                s.output_name,
                format.extension()
            );
        }
        self.download(id, &out, format).await?;
        Ok((out, s))
    }

    /// `fetch` of a sequence: every frame done, named by the sequence's
    /// pattern (`shot.####.png`), into `out`: a pattern with a run of `#`,
    /// or a directory (default: the current one). Returns the pattern.
    async fn fetch_frames(
        &mut self,
        s: pb::JobStatus,
        out: Option<&Path>,
    ) -> Result<(PathBuf, pb::JobStatus)> {
        let id = s.id;
        let f = s.frames.expect("a sequence");
        if s.state() != JobState::Done && s.frames_done == 0 {
            bail!(
                "sequence {id} is {} with no frame done yet (trevi-submit status {id})",
                s.state().label()
            );
        }
        let name = Path::new(&s.output_name)
            .file_name()
            .map(PathBuf::from)
            .with_context(|| format!("job {id} names no output pattern ({:?})", s.output_name))?;
        let pattern = match out {
            Some(o) if o.to_string_lossy().contains('#') => o.to_path_buf(),
            // A name like x.png is one file, not a directory to make.
            Some(o) if (o.extension().is_some() || o.exists()) && !o.is_dir() => {
                bail!(
                    "sequence {id} has {} frames: -o {} names one file; give a pattern \
                     with a run of # (like shot.####.png) or a directory",
                    f.last - f.first + 1,
                    o.display()
                )
            }
            Some(dir) => dir.join(&name),
            None => name,
        };
        // Only where the frames done can be: one request per frame done,
        // plus at most one per frame in progress (or cancelled by the end
        // of a sequence that failed), never one per frame of the range.
        let last = done_frames_end(&s, &f);
        let seq = crate::sequence::Sequence::new(
            0,
            s.camera.clone(),
            trevi_core::scene::animation::Frames {
                first: f.first,
                last,
            },
            pattern.clone(),
        )?;
        let format = Format::from_path(&pattern)
            .with_context(|| format!("{} is not .png or .exr", pattern.display()))?;
        let mut got = 0;
        for frame in f.first..=last {
            if got >= s.frames_done {
                break;
            }
            let out = seq.output(frame);
            match self.download_frame(id, Some(frame), &out, format).await {
                Ok(_) => got += 1,
                // A sequence that did not finish has frames without output.
                Err(_) if s.state() != JobState::Done => {}
                Err(e) => return Err(e.context(format!("frame {frame}"))),
            }
        }
        if got == 0 {
            bail!("sequence {id}: no frame could be fetched");
        }
        Ok((pattern, s))
    }

    /// Submits frames `first..=last` of `camera` as one sequence.
    #[allow(clippy::too_many_arguments)]
    pub async fn submit_sequence(
        &mut self,
        bundle_hash: &str,
        camera: &str,
        priority: i32,
        tile_size: u32,
        format: Format,
        first: u32,
        last: u32,
    ) -> Result<pb::JobStatus> {
        Ok(self
            .jobs
            .submit_job(pb::SubmitJobRequest {
                bundle_hash: bundle_hash.to_string(),
                camera: camera.to_string(),
                priority,
                tile_size,
                output_format: format.extension().to_string(),
                frames: Some(pb::FrameRange { first, last }),
            })
            .await
            .map_err(status_error)
            .with_context(|| format!("the coordinator refused camera \"{camera}\"'s sequence"))?
            .into_inner())
    }

    /// Renders a sequence on the farm: uploads, submits, and unless
    /// `detach` follows it (frames done, the current frame, an ETA) and
    /// downloads every frame to `seq`'s outputs.
    #[allow(clippy::too_many_arguments)]
    pub async fn render_sequence(
        &mut self,
        bundle: &Encoded,
        seq: &crate::sequence::Sequence,
        priority: i32,
        tile_size: u32,
        detach: bool,
        progress: Progress,
    ) -> Result<()> {
        let hash = self.upload(bundle).await?;
        let format = Format::from_path(&seq.pattern)
            .with_context(|| format!("{} is not .png or .exr", seq.pattern.display()))?;
        let s = self
            .submit_sequence(
                &hash,
                &seq.id,
                priority,
                tile_size,
                format,
                seq.frames.first,
                seq.frames.last,
            )
            .await?;
        self.submitted.push(s.id);
        if detach {
            println!("{}", s.id);
            return Ok(());
        }
        if progress != Progress::Quiet {
            eprintln!(
                "sequence {}: camera {}, frames {}-{}",
                s.id, seq.id, seq.frames.first, seq.frames.last
            );
        }
        let end = self.watch(s.id, progress).await?;
        if end.state() != JobState::Done {
            // The frames it finished are kept, as a local render keeps them.
            if end.frames_done > 0 {
                match self.fetch_frames(end.clone(), Some(&seq.pattern)).await {
                    Ok(_) if progress != Progress::Quiet => eprintln!(
                        "sequence {}: kept the {} frames it finished ({})",
                        s.id,
                        end.frames_done,
                        seq.pattern.display()
                    ),
                    Ok(_) => {}
                    Err(e) => eprintln!("sequence {}: its finished frames: {e:#}", s.id),
                }
            }
            bail!("sequence {} {}: {}", s.id, end.state().label(), end.error);
        }
        for f in seq.frames.first..=seq.frames.last {
            let out = seq.output(f);
            self.download_frame(s.id, Some(f), &out, format)
                .await
                .with_context(|| format!("frame {f}"))?;
            if progress != Progress::Quiet {
                eprintln!("{}: frame {f} -> {}", seq.id, out.display());
            }
        }
        Ok(())
    }

    pub async fn status(&mut self, id: u64) -> Result<pb::JobStatus> {
        Ok(self
            .jobs
            .get_job(pb::JobId { id, frame: None })
            .await
            .map_err(status_error)?
            .into_inner())
    }

    /// The farm's jobs by id, page by page (at most `limit` of them).
    pub async fn list(&mut self, limit: Option<usize>) -> Result<Vec<pb::JobStatus>> {
        let mut jobs = Vec::new();
        let mut page_token = String::new();
        loop {
            let want = limit.map_or(0, |l| l.saturating_sub(jobs.len()).min(u32::MAX as usize));
            let reply = self
                .jobs
                .list_jobs(pb::ListJobsRequest {
                    limit: want as u32,
                    page_token,
                })
                .await
                .map_err(status_error)?
                .into_inner();
            jobs.extend(reply.jobs);
            if let Some(l) = limit {
                jobs.truncate(l);
                if jobs.len() == l {
                    break;
                }
            }
            if reply.next_page_token.is_empty() {
                break;
            }
            page_token = reply.next_page_token;
        }
        Ok(jobs)
    }

    pub async fn cancel(&mut self, id: u64) -> Result<pb::JobStatus> {
        Ok(self
            .jobs
            .cancel_job(pb::JobId { id, frame: None })
            .await
            .map_err(status_error)?
            .into_inner())
    }

    /// Uploads the bundle, submits one job per target, and unless `detach`
    /// follows each and downloads its image.
    pub async fn render(
        &mut self,
        bundle: &Encoded,
        targets: &[Target],
        priority: i32,
        tile_size: u32,
        detach: bool,
        progress: Progress,
    ) -> Result<()> {
        let hash = self.upload(bundle).await?;
        let mut jobs = Vec::new();
        for t in targets {
            let s = self
                .submit(&hash, &t.camera, priority, tile_size, t.format)
                .await?;
            self.submitted.push(s.id);
            if detach || (self.announce && progress != Progress::Quiet) {
                eprintln!(
                    "job {} queued: camera {} ({}x{}, {} tiles) on {}",
                    s.id, s.camera, s.width, s.height, s.tiles_total, self.url
                );
            }
            if detach {
                println!("{}", s.id);
            }
            jobs.push(s.id);
        }
        if detach {
            return Ok(());
        }
        for (t, id) in targets.iter().zip(jobs) {
            let s = self.watch(id, progress).await?;
            match s.state() {
                JobState::Done => {}
                JobState::Cancelled => bail!("job {id} (camera {}) was cancelled", t.camera),
                other => bail!(
                    "job {id} (camera {}) {}: {}",
                    t.camera,
                    other.label(),
                    s.error
                ),
            }
            // The coordinator may restart between the end and the download.
            let mut tries = 0;
            while let Err(e) = self.download(id, &t.out, t.format).await {
                tries += 1;
                let again = e
                    .downcast_ref::<StatusError>()
                    .is_some_and(|s| reconnectable(&s.0));
                if !again || tries >= 20 {
                    return Err(e);
                }
                tokio::time::sleep(Duration::from_millis(250 * tries)).await;
            }
            if progress != Progress::Quiet {
                let secs = s.elapsed_ms as f64 / 1e3;
                eprintln!(
                    "{}: {}x{} -> {} in {:.2} s, {:.1} M rays ({:.2} M rays/s)",
                    s.camera,
                    s.width,
                    s.height,
                    t.out.display(),
                    secs,
                    s.rays as f64 / 1e6,
                    s.rays as f64 / 1e6 / secs.max(1e-9)
                );
            }
        }
        Ok(())
    }
}

/// Where a file bound for `out` is written until it is complete: a hidden
/// name beside it (the directory is created), so a rename moves it into
/// place and nobody ever sees half a file under `out`. Removed when dropped
/// unless [`PartFile::persist`] moved it into place: after an error, and
/// when the future writing it is dropped (a signal, a cancelled render).
struct PartFile {
    path: PathBuf,
    armed: bool,
}

impl PartFile {
    async fn new(out: &Path) -> Result<PartFile> {
        let dir = out
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        tokio::fs::create_dir_all(dir)
            .await
            .with_context(|| format!("cannot create {}", dir.display()))?;
        let name = out.file_name().and_then(|n| n.to_str()).unwrap_or("out");
        Ok(PartFile {
            path: dir.join(format!(".{name}.{}.part", std::process::id())),
            armed: true,
        })
    }

    /// Renames the finished file onto `out`, unless `out` exists and is not
    /// a regular file (a rename would replace a device or a directory).
    async fn persist(&mut self, out: &Path) -> Result<()> {
        trevi_core::output::check_target(out)?;
        tokio::fs::rename(&self.path, out)
            .await
            .with_context(|| format!("cannot move the file to {}", out.display()))?;
        self.armed = false;
        Ok(())
    }
}

impl Drop for PartFile {
    fn drop(&mut self) {
        if self.armed {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

/// The `--preview` file while a job is watched: rewritten at most once a
/// second while tiles arrive, and once more when the job ends.
struct PreviewFile {
    path: Option<PathBuf>,
    last: Option<std::time::Instant>,
    tiles: Option<u64>,
    warned: bool,
}

impl PreviewFile {
    fn new(path: Option<PathBuf>) -> Self {
        PreviewFile {
            path,
            last: None,
            tiles: None,
            warned: false,
        }
    }

    async fn update(&mut self, client: &mut Client, s: &pb::JobStatus) {
        let Some(path) = self.path.clone() else {
            return;
        };
        let due = self
            .last
            .is_none_or(|t| t.elapsed() >= Duration::from_secs(1));
        let changed = self.tiles != Some(s.tiles_done);
        if !(changed && (due || s.state().is_final())) {
            return;
        }
        self.last = Some(std::time::Instant::now());
        match client.save_preview(s.id, &path).await {
            Ok(_) => self.tiles = Some(s.tiles_done),
            // The render matters more than its preview: say so once, go on.
            Err(e) if !self.warned => {
                self.warned = true;
                eprintln!("trevi-submit: cannot update the preview: {e:#}");
            }
            Err(_) => {}
        }
    }
}

/// How long `watch` keeps trying to reach a coordinator that went away.
pub const RECONNECT_FOR: Duration = Duration::from_secs(300);

/// Whether a failed call may succeed once the coordinator is back.
/// The last frame of sequence `s` (frames `f`) that may be done. Frames
/// are started in order and a failed frame ends its sequence: the frames
/// done are among the first `frames_done + frames_in_progress` of the
/// range, or, once it failed or was cancelled, `frames_done` plus the
/// frames that were in progress then (at most the coordinator's maximum
/// of frames in progress).
fn done_frames_end(s: &pb::JobStatus, f: &pb::FrameRange) -> u32 {
    if s.state() == JobState::Done {
        return f.last;
    }
    let slack = if matches!(s.state(), JobState::Failed | JobState::Cancelled) {
        trevi_coordinator::limits::MAX_FRAMES_IN_PROGRESS as u32
    } else {
        s.frames_in_progress
    };
    let past = u64::from(f.first) + u64::from(s.frames_done) + u64::from(slack);
    past.saturating_sub(1)
        .clamp(u64::from(f.first), u64::from(f.last)) as u32
}

fn reconnectable(s: &tonic::Status) -> bool {
    matches!(
        s.code(),
        tonic::Code::Unavailable
            | tonic::Code::Unknown
            | tonic::Code::Internal
            | tonic::Code::Cancelled
    )
}

/// A gRPC status as an error that reads well.
fn status_error(s: tonic::Status) -> anyhow::Error {
    anyhow::Error::new(StatusError(s))
}

/// A gRPC status kept inside an `anyhow::Error`, so callers can still look
/// at its code.
#[derive(Debug)]
struct StatusError(tonic::Status);

impl std::fmt::Display for StatusError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ({:?})", self.0.message(), self.0.code())
    }
}

impl std::error::Error for StatusError {
    // What lies under a transport failure (a TLS alert, a reset connection).
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        std::error::Error::source(&self.0)
    }
}

/// One line about a job, for `status` and `list`.
pub fn describe(s: &pb::JobStatus) -> String {
    let mut line = format!(
        "{:>6}  {:<9}  camera {}  {}x{}  {}/{} tiles  priority {}  {:.1} s",
        s.id,
        s.state().label(),
        s.camera,
        s.width,
        s.height,
        s.tiles_done,
        s.tiles_total,
        s.priority,
        s.elapsed_ms as f64 / 1e3
    );
    if let Some(f) = s.frames {
        line.push_str(&format!(
            "  frames {}-{}: {} done",
            f.first, f.last, s.frames_done
        ));
        if let Some(c) = s.current_frame {
            line.push_str(&format!(
                ", frame {c} {}/{} tiles",
                s.current_tiles_done, s.current_tiles_total
            ));
        }
    }
    if !s.error.is_empty() {
        line.push_str(&format!("  error: {}", s.error));
    }
    line
}

struct ProgressView {
    mode: Progress,
    bar: Option<ProgressBar>,
    last_pct: Option<u64>,
}

impl ProgressView {
    fn new(mode: Progress) -> Self {
        ProgressView {
            mode,
            bar: None,
            last_pct: None,
        }
    }

    fn show(&mut self, s: &pb::JobStatus) {
        let secs = s.elapsed_ms as f64 / 1e3;
        let rate = s.rays as f64 / secs.max(1e-9) / 1e6;
        if let Some(f) = s.frames {
            return self.show_frames(s, f, secs);
        }
        let eta = if s.tiles_done > 0 && s.tiles_done < s.tiles_total {
            let left = secs * (s.tiles_total - s.tiles_done) as f64 / s.tiles_done as f64;
            format!("ETA {left:.0} s")
        } else {
            "ETA -".to_string()
        };
        match self.mode {
            Progress::Quiet => {}
            Progress::Bar => {
                let bar = self.bar.get_or_insert_with(|| {
                    let b = ProgressBar::new(s.tiles_total);
                    b.set_style(
                        ProgressStyle::with_template("{prefix} [{bar:40}] {pos}/{len} tiles {msg}")
                            .expect("static template")
                            .progress_chars("=> "),
                    );
                    b.set_prefix(s.camera.clone());
                    b
                });
                bar.set_position(s.tiles_done);
                bar.set_message(format!("{rate:.2} M rays/s {eta}"));
            }
            Progress::Lines => {
                let pct = s.tiles_done * 100 / s.tiles_total.max(1);
                let due = match self.last_pct {
                    None => true,
                    Some(p) => pct >= p + 10 || (pct == 100 && p != 100),
                };
                if due {
                    self.last_pct = Some(pct);
                    eprintln!(
                        "{}: {pct}% ({}/{} tiles, {rate:.2} M rays/s, {eta})",
                        s.camera, s.tiles_done, s.tiles_total
                    );
                }
            }
        }
    }

    /// A sequence: frames done, the current frame's share, an ETA from the
    /// tiles of every frame.
    fn show_frames(&mut self, s: &pb::JobStatus, f: pb::FrameRange, secs: f64) {
        let count = u64::from(f.last - f.first) + 1;
        let eta = if s.tiles_done > 0 && s.tiles_done < s.tiles_total {
            let left = secs * (s.tiles_total - s.tiles_done) as f64 / s.tiles_done as f64;
            format!("ETA {left:.0} s")
        } else {
            "ETA -".to_string()
        };
        let current = match s.current_frame {
            Some(c) => format!(
                ", frame {c} {}%",
                s.current_tiles_done * 100 / s.current_tiles_total.max(1)
            ),
            None => String::new(),
        };
        let line = format!(
            "{}: {}/{count} frames done{current}, {eta}",
            s.camera, s.frames_done
        );
        match self.mode {
            Progress::Quiet => {}
            Progress::Bar => {
                let bar = self.bar.get_or_insert_with(|| {
                    let b = ProgressBar::new(count);
                    b.set_style(ProgressStyle::with_template("{msg}").expect("static template"));
                    b
                });
                bar.set_message(line);
            }
            Progress::Lines => {
                let pct = u64::from(s.frames_done);
                if self.last_pct != Some(pct) {
                    self.last_pct = Some(pct);
                    eprintln!("{line}");
                }
            }
        }
    }

    fn done(&mut self) {
        if let Some(b) = self.bar.take() {
            b.finish_and_clear();
        }
    }
}
