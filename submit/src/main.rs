//! `trevi-submit`: what users type.
//!
//! `trevi-submit SCENE.xml [--camera ID] [-o OUT]` renders every camera of
//! the scene (or the one named) to its `output` file: a still, or a
//! sequence for a camera with frames. With `--coordinator URL` the frames
//! are rendered on a farm; without it, by a coordinator and a worker
//! embedded in this process with every core, through the same client code.
//! `trevi-submit status|list|cancel|fetch|wait` manage a farm's jobs
//! (commands.rs).
//!
//! The output's format follows its name (`-o FILE`, else the camera's
//! `output`): `.png` or `.exr`, anything else is refused before rendering.
//! A local render stopped by SIGINT or SIGTERM removes its temporary files
//! and any half-written output, and exits with 128 + the signal's number,
//! within a second even inside one very expensive pixel. A farm submission
//! stopped so leaves its jobs running and says how to follow (`wait ID`)
//! or cancel them.

mod cli;
mod client;
mod commands;
mod local;
mod progress;
mod sequence;

use anyhow::{bail, Context, Result};
use clap::Parser;
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(
    name = "trevi-submit",
    version,
    about = "Render an AISXML scene, on this machine or on a farm",
    args_conflicts_with_subcommands = true
)]
struct Args {
    #[command(subcommand)]
    command: Option<Command>,
    /// The scene file (AISXML).
    scene: Option<PathBuf>,
    /// Arguments after the scene: none are taken, but a mistyped
    /// subcommand's (`canel 3`) are read so that it can be named.
    #[arg(hide = true)]
    rest: Vec<std::ffi::OsString>,
    /// The farm's coordinator, like http://host:50051, or https:// for TLS
    /// (default: render on this machine).
    #[arg(long, env = "TREVI_COORDINATOR")]
    coordinator: Option<String>,
    #[command(flatten)]
    auth: Auth,
    /// Job priority on the farm: higher runs first (a worker's CPU class is
    /// trevi-worker --cpu-priority).
    #[arg(
        long,
        env = "TREVI_JOB_PRIORITY",
        default_value_t = 0,
        allow_negative_numbers = true
    )]
    priority: i32,
    /// Submit and print the job ids without waiting (needs --coordinator).
    #[arg(long, env = "TREVI_DETACH")]
    detach: bool,
    /// Render only this camera (default: every camera in the scene).
    #[arg(long, env = "TREVI_CAMERA")]
    camera: Option<String>,
    /// Output file (.png or .exr); only with a single camera. Default: the
    /// camera's `output`, relative to the scene's directory. No `#` but one
    /// run in a sequence's file name.
    #[arg(short = 'o', long = "output", env = "TREVI_OUTPUT")]
    output: Option<PathBuf>,
    /// Render these frames of the camera's sequence, `first-last` or one
    /// frame (default: the scene's `frames=`, if any). Each frame goes to
    /// its own file: the output's run of `#` replaced by the frame number.
    /// On a farm the range is one job (`status`, `cancel`, `fetch` take its
    /// id).
    #[arg(long, env = "TREVI_FRAMES", value_parser = sequence::parse_frames)]
    frames: Option<trevi_core::scene::animation::Frames>,
    /// Worker threads on this machine (default: every core).
    #[arg(long, env = "TREVI_THREADS")]
    threads: Option<usize>,
    /// Tile edge in pixels (at least 1); the coordinator's --tile-size
    /// when not given. Old name: --tile.
    #[arg(long = "tile-size", alias = "tile", env = "TREVI_TILE_SIZE",
          default_value_t = default_tile(), value_parser = tile_edge)]
    tile_size: u32,
    /// No progress output.
    #[arg(short, long, env = "TREVI_QUIET")]
    quiet: bool,
    /// Keep the live preview of the frame being rendered in this PNG file
    /// (at most 512 pixels a side, updated about once a second).
    #[arg(long, env = "TREVI_PREVIEW")]
    preview: Option<PathBuf>,
}

/// How to reach a farm's coordinator: the flags every farm command shares.
#[derive(clap::Args, Debug)]
struct Auth {
    /// The coordinator's submit token (its --submit-token; sent as
    /// `authorization: Bearer`). TREVI_TOKEN is no longer read: it named
    /// trevi-worker's token too.
    #[arg(long, env = "TREVI_SUBMIT_TOKEN", hide_env_values = true)]
    token: Option<String>,
    /// For an https:// coordinator: trust this PEM CA certificate instead of
    /// the system roots (a farm with its own CA, see deploy/make-certs.sh).
    #[arg(long, env = "TREVI_TLS_CA")]
    tls_ca: Option<PathBuf>,
    /// For an https:// coordinator: the name its certificate must carry, if
    /// not the URL's host.
    #[arg(long, env = "TREVI_TLS_DOMAIN")]
    tls_domain: Option<String>,
}

/// A farm command's coordinator (required) and credentials.
#[derive(clap::Args, Debug)]
struct Farm {
    /// The farm's coordinator, like http://host:50051, or https:// for TLS.
    #[arg(long, env = "TREVI_COORDINATOR")]
    coordinator: String,
    #[command(flatten)]
    auth: Auth,
}

#[derive(clap::Subcommand, Debug)]
enum Command {
    /// Show a job.
    Status {
        /// The job's id (printed by --detach, listed by `list`).
        id: u64,
        /// Also write the job's live preview (a PNG) to this file.
        #[arg(long, env = "TREVI_PREVIEW")]
        preview: Option<PathBuf>,
        #[command(flatten)]
        farm: Farm,
    },
    /// List the farm's jobs (every page of them, by id), one a line.
    List {
        /// Show at most this many jobs (the oldest first).
        #[arg(long)]
        limit: Option<usize>,
        /// Print the header line even when the output is not a terminal
        /// (scripts reading the lines get none by default).
        #[arg(long)]
        header: bool,
        #[command(flatten)]
        farm: Farm,
    },
    /// Cancel a job: it takes no more worker time and leaves no output. A
    /// job that has already ended is left as it is (exit status 1).
    Cancel {
        /// The job's id (printed by --detach, listed by `list`).
        id: u64,
        #[command(flatten)]
        farm: Farm,
    },
    /// Download a finished job's image, e.g. of a job submitted with
    /// --detach.
    Fetch {
        /// The job's id (printed by --detach, listed by `list`).
        id: u64,
        /// Where to write it (default: the job's output file name, in the
        /// current directory). Its extension must be the job's format. For a
        /// sequence: a pattern with a run of # (like out/shot.####.png) or
        /// a directory.
        #[arg(short = 'o', long = "output")]
        output: Option<PathBuf>,
        /// Print nothing but errors.
        #[arg(short, long, env = "TREVI_QUIET")]
        quiet: bool,
        #[command(flatten)]
        farm: Farm,
    },
    /// Follow a job (e.g. one submitted with --detach, or left running by
    /// Ctrl-C) until it ends, showing progress, then download its image as
    /// the submission would have.
    #[command(alias = "attach")]
    Wait {
        /// The job's id (printed by --detach, listed by `list`).
        id: u64,
        /// Where to write the image (as for `fetch`).
        #[arg(short = 'o', long = "output")]
        output: Option<PathBuf>,
        /// No progress output.
        #[arg(short, long, env = "TREVI_QUIET")]
        quiet: bool,
        #[command(flatten)]
        farm: Farm,
    },
}

fn main() {
    let args = Args::parse();
    if let (None, Some(scene)) = (&args.command, &args.scene) {
        if let Some(msg) = cli::mistyped_subcommand(scene) {
            eprintln!("trevi-submit: error: {msg}");
            std::process::exit(2);
        }
        if let Some(extra) = args.rest.first() {
            eprintln!(
                "trevi-submit: error: unexpected argument {extra:?} after the scene file; see --help"
            );
            std::process::exit(2);
        }
    }
    let url = match &args.command {
        Some(c) => Some(c.farm().coordinator.clone()),
        None => args.coordinator.clone(),
    };
    if let Err(e) = run(args) {
        if let Some(sig) = e.downcast_ref::<local::Interrupted>() {
            eprintln!("trevi-submit: {sig}");
            std::process::exit(sig.code);
        }
        if let Some(left) = e.downcast_ref::<cli::LeftRunning>() {
            eprintln!("trevi-submit: {left}");
            std::process::exit(left.signal.code);
        }
        let text = cli::error_text(&e);
        eprintln!("trevi-submit: error: {text}");
        if let Some(hint) = url.and_then(|u| trevi_proto::connect::hint(&u, &text)) {
            eprintln!("trevi-submit: hint: {hint}");
        }
        std::process::exit(1);
    }
}

impl Command {
    fn farm(&self) -> &Farm {
        match self {
            Command::Status { farm, .. }
            | Command::List { farm, .. }
            | Command::Cancel { farm, .. }
            | Command::Fetch { farm, .. }
            | Command::Wait { farm, .. } => farm,
        }
    }
}

impl Auth {
    /// The submit token; refuses the old, ambiguous TREVI_TOKEN when no
    /// token is given under its current name.
    fn token(&self) -> Result<Option<&str>> {
        let old = std::env::var("TREVI_TOKEN").is_ok_and(|v| !v.is_empty());
        if self.token.is_none() && old {
            bail!(
                "TREVI_TOKEN is no longer read (trevi-worker read it for another token): \
                 set TREVI_SUBMIT_TOKEN (or pass --token)"
            );
        }
        Ok(self.token.as_deref())
    }

    /// The TLS settings of `--tls-ca` and `--tls-domain`.
    fn tls(&self) -> trevi_proto::ClientTls {
        trevi_proto::ClientTls {
            ca_file: self.tls_ca.clone(),
            domain: self.tls_domain.clone(),
        }
    }

    async fn connect(&self, url: &str) -> Result<client::Client> {
        client::Client::connect_with(url, self.token()?, &self.tls()).await
    }
}

fn run(args: Args) -> Result<()> {
    if let Some(cmd) = args.command {
        let runtime = tokio::runtime::Runtime::new().context("cannot start the async runtime")?;
        return runtime.block_on(commands::run(cmd));
    }
    // A local render: the embedded coordinator's data directory, declared
    // before the runtime so that it is removed after the runtime (and every
    // task that could write into it) has shut down.
    let local = args.coordinator.is_none();
    let data = if local {
        Some(local::data_dir()?)
    } else {
        None
    };
    let runtime = tokio::runtime::Runtime::new().context("cannot start the async runtime")?;
    // Caught from here on, so that a local render interrupted at any point
    // still returns through the code that removes what it wrote, and a
    // farm submission says what it leaves running.
    let mut signals = runtime.block_on(async { local::Signals::catch() })?;
    let Some(scene_path) = args.scene.clone() else {
        bail!("name a scene file (or one of status, list, cancel, fetch, wait); see --help");
    };
    if args.detach && args.coordinator.is_none() {
        bail!("--detach needs --coordinator URL: the embedded farm ends with this process");
    }
    // The scene is parsed here, once: the cameras are listed from its
    // description, and a local render hands the description on (see
    // local::Embedded::start) instead of parsing the bundle again.
    let trevi_core::ParsedBundle { bundle, desc } =
        trevi_core::ParsedBundle::from_scene_file(&scene_path)
            .map_err(|e| anyhow::anyhow!("{}", with_dir(&scene_path, e)))?;
    // Encoded and hashed once, for the upload and the embedded worker.
    let bundle_scene = bundle.scene.clone();
    let bundle = client::Encoded::new(&bundle);
    let cameras: Vec<usize> = match &args.camera {
        Some(id) => vec![desc
            .cameras
            .iter()
            .position(|c| c.id == *id)
            .with_context(|| {
                let ids: Vec<_> = desc.cameras.iter().map(|c| c.id.as_str()).collect();
                format!(
                    "no camera \"{id}\" in the scene (cameras: {})",
                    ids.join(", ")
                )
            })?],
        None => (0..desc.cameras.len()).collect(),
    };
    if args.output.is_some() && cameras.len() > 1 {
        bail!(
            "-o names one file but the scene has {} cameras: add --camera ID",
            cameras.len()
        );
    }
    let scene_dir = scene_path
        .parent()
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("."));
    let progress = progress::Progress::choose(args.quiet);
    // Every output is checked (format, pattern, not a device or directory)
    // before anything renders. A camera with frames (its own, or --frames)
    // renders a sequence, the others a still, in one run: the stills first.
    let mut targets = Vec::new();
    for &cam in &cameras {
        let c = &desc.cameras[cam];
        let out = match &args.output {
            Some(o) => o.clone(),
            None => scene_dir.join(&c.render.output),
        };
        let frames = args.frames.or(c.render.frames);
        targets.push(
            client::Target::new(c.id.clone(), out, frames)
                .with_context(|| format!("camera \"{}\"", c.id))?,
        );
    }
    targets.sort_by_key(|t| t.frames().is_some());
    runtime.block_on(async {
        if let Some(url) = &args.coordinator {
            drop(desc);
            let mut client = args.auth.connect(url).await?;
            client.preview = args.preview.clone();
            let work = client.render(
                &bundle,
                &targets,
                args.priority,
                args.tile_size,
                args.detach,
                progress,
            );
            let signal = tokio::select! {
                r = work => return r,
                sig = signals.next() => sig,
            };
            return Err(anyhow::Error::new(cli::LeftRunning::new(
                signal,
                &client.submitted,
                url,
            )));
        }
        // A local render: the same jobs on a farm embedded in this process.
        let data = data.as_ref().expect("made for a local render");
        let stills = targets.iter().any(|t| t.frames().is_none());
        let scene = local::Prepared::new(bundle.hash.clone(), bundle_scene, desc, stills).await?;
        let threads = args.threads.unwrap_or(0);
        let farm = local::Embedded::start(threads, args.tile_size, data.path(), scene).await?;
        let render = async {
            let mut client = client::Client::connect(&farm.url, None).await?;
            client.announce = false;
            client.preview = args.preview.clone();
            client
                .render(
                    &bundle,
                    &targets,
                    args.priority,
                    args.tile_size,
                    false,
                    progress,
                )
                .await
        };
        // A signal drops the render, and with it the half-written output
        // (see client::PartFile), and the embedded worker's render (its
        // cancel flag, set when the task is dropped, stops even a pixel in
        // progress); `data` goes after the runtime.
        let result = tokio::select! {
            r = render => r,
            sig = signals.next() => Err(anyhow::Error::new(sig)),
        };
        farm.stop().await;
        result
    })
}

/// `--tile-size`'s default: the coordinator's own, so that a local render and a
/// farm's cut a frame alike.
fn default_tile() -> u32 {
    trevi_coordinator::FarmConfig::default().default_tile
}

/// A `--tile-size` edge: 0 is refused, naming the flag, not clamped.
fn tile_edge(s: &str) -> Result<u32, String> {
    match s.parse::<u32>() {
        Ok(0) => Err("must be at least 1".into()),
        Ok(n) => Ok(n),
        Err(e) => Err(e.to_string()),
    }
}

/// Scene errors name bundle-relative files; show them as the user typed the
/// scene's path so the location can be opened directly.
fn with_dir(scene: &std::path::Path, e: trevi_core::SceneError) -> String {
    match scene.parent().filter(|p| !p.as_os_str().is_empty()) {
        Some(dir) => {
            let mut e = e;
            e.location.file = dir.join(&e.location.file).display().to_string();
            e.to_string()
        }
        None => e.to_string(),
    }
}
