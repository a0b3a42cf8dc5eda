//! `trevi-submit`: what users type.
//!
//! `trevi-submit SCENE.xml [--camera ID] [-o OUT]` renders every camera of
//! the scene (or the one named) to its `output` file. With `--coordinator
//! URL` the frames are rendered on a farm; without it, by a coordinator and a
//! worker embedded in this process with every core, through the same client
//! code. `trevi-submit status|list|cancel|fetch` manage a farm's jobs.
//!
//! The output's format follows its name (`-o FILE`, else the camera's
//! `output`): `.png` or `.exr`, anything else is refused before rendering.
//! A local render stopped by SIGINT or SIGTERM removes its temporary files
//! and any half-written output, and exits with 128 + the signal's number.

mod client;
mod local;
mod sequence;

use anyhow::{bail, Context, Result};
use clap::Parser;
use std::io::IsTerminal;
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(
    name = "trevi-submit",
    version,
    about = "Render an AISXML scene",
    args_conflicts_with_subcommands = true
)]
struct Args {
    #[command(subcommand)]
    command: Option<Command>,
    /// The scene file (AISXML).
    scene: Option<PathBuf>,
    /// The farm's coordinator, like http://host:50051, or https:// for TLS
    /// (default: render on this machine).
    #[arg(long, env = "TREVI_COORDINATOR", global = true)]
    coordinator: Option<String>,
    /// The coordinator's submit token (sent as `authorization: Bearer`).
    #[arg(long, env = "TREVI_TOKEN", global = true, hide_env_values = true)]
    token: Option<String>,
    /// For an https:// coordinator: trust this PEM CA certificate instead of
    /// the system roots (a farm with its own CA, see deploy/make-certs.sh).
    #[arg(long, env = "TREVI_TLS_CA", global = true)]
    tls_ca: Option<PathBuf>,
    /// For an https:// coordinator: the name its certificate must carry, if
    /// not the URL's host.
    #[arg(long, env = "TREVI_TLS_DOMAIN", global = true)]
    tls_domain: Option<String>,
    /// Job priority on the farm: higher runs first.
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    priority: i32,
    /// Submit and print the job ids without waiting (needs --coordinator).
    #[arg(long)]
    detach: bool,
    /// Render only this camera (default: every camera in the scene).
    #[arg(long)]
    camera: Option<String>,
    /// Output file (.png or .exr); only with a single camera. Default: the
    /// camera's `output`, relative to the scene's directory.
    #[arg(short = 'o', long = "output")]
    output: Option<PathBuf>,
    /// Render these frames of the camera's sequence, `first-last` or one
    /// frame (default: the scene's `frames=`, if any). Each frame goes to
    /// its own file: the output's run of `#` replaced by the frame number.
    /// On a farm the range is one job (`status`, `cancel`, `fetch` take its
    /// id).
    #[arg(long, value_parser = sequence::parse_frames)]
    frames: Option<trevi_core::scene::animation::Frames>,
    /// Worker threads on this machine (default: every core).
    #[arg(long, env = "TREVI_THREADS")]
    threads: Option<usize>,
    /// Tile edge in pixels (at least 1).
    #[arg(long, default_value_t = default_tile(), value_parser = tile_edge)]
    tile: u32,
    /// No progress output.
    #[arg(short, long, global = true)]
    quiet: bool,
    /// Keep the live preview of the frame being rendered in this PNG file
    /// (at most 512 pixels a side, updated about once a second); with
    /// `status ID`, write the job's preview once.
    #[arg(long, global = true)]
    preview: Option<PathBuf>,
}

#[derive(clap::Subcommand, Debug)]
enum Command {
    /// Show a job.
    Status { id: u64 },
    /// List the farm's jobs (every page of them, by id).
    List {
        /// Show at most this many jobs (the oldest first).
        #[arg(long)]
        limit: Option<usize>,
    },
    /// Cancel a job: it takes no more worker time and leaves no output.
    Cancel { id: u64 },
    /// Download a finished job's image, e.g. of a job submitted with
    /// --detach.
    Fetch {
        id: u64,
        /// Where to write it (default: the job's output file name, in the
        /// current directory). Its extension must be the job's format.
        #[arg(short = 'o', long = "output")]
        output: Option<PathBuf>,
    },
}

fn main() {
    let args = Args::parse();
    let url = args.coordinator.clone();
    if let Err(e) = run(args) {
        if let Some(sig) = e.downcast_ref::<local::Interrupted>() {
            eprintln!("trevi-submit: {sig}");
            std::process::exit(sig.code);
        }
        let text = format!("{e:#}");
        eprintln!("trevi-submit: error: {text}");
        if let Some(hint) = url.and_then(|u| trevi_proto::connect::hint(&u, &text)) {
            eprintln!("trevi-submit: hint: {hint}");
        }
        std::process::exit(1);
    }
}

fn run(args: Args) -> Result<()> {
    // A local render: the embedded coordinator's data directory, declared
    // before the runtime so that it is removed after the runtime (and every
    // task that could write into it) has shut down.
    let local = args.command.is_none() && args.coordinator.is_none();
    let data = if local {
        Some(local::data_dir()?)
    } else {
        None
    };
    let runtime = tokio::runtime::Runtime::new().context("cannot start the async runtime")?;
    // Caught from here on, so that a local render interrupted at any point
    // still returns through the code that removes what it wrote.
    let mut signals = if local {
        Some(runtime.block_on(async { local::Signals::catch() })?)
    } else {
        None
    };
    if let Some(cmd) = &args.command {
        let url = args.coordinator.as_deref().context(
            "status, list, cancel and fetch need --coordinator URL (or TREVI_COORDINATOR)",
        )?;
        return runtime.block_on(async {
            let mut client =
                client::Client::connect_with(url, args.token.as_deref(), &tls(&args)).await?;
            match cmd {
                Command::Status { id } => {
                    println!("{}", client::describe(&client.status(*id).await?));
                    if let Some(out) = &args.preview {
                        let p = client.save_preview(*id, out).await?;
                        println!(
                            "preview: {}x{}, {} tiles -> {}",
                            p.width,
                            p.height,
                            p.tiles,
                            out.display()
                        );
                    }
                }
                Command::List { limit } => {
                    for s in client.list(*limit).await? {
                        println!("{}", client::describe(&s));
                    }
                }
                Command::Cancel { id } => {
                    println!("{}", client::describe(&client.cancel(*id).await?))
                }
                Command::Fetch { id, output } => {
                    let (out, s) = client.fetch(*id, output.as_deref()).await?;
                    if !args.quiet {
                        eprintln!(
                            "job {id}: camera {}, {}x{} -> {}",
                            s.camera,
                            s.width,
                            s.height,
                            out.display()
                        );
                    }
                }
            }
            Ok(())
        });
    }
    let Some(scene_path) = args.scene.clone() else {
        bail!("name a scene file (or one of status, list, cancel, fetch); see --help");
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
    let progress = if args.quiet {
        client::Progress::Quiet
    } else if std::io::stderr().is_terminal() {
        client::Progress::Bar
    } else {
        client::Progress::Lines
    };
    let is_sequence = args.frames.is_some()
        || cameras
            .iter()
            .any(|&c| desc.cameras[c].render.frames.is_some());
    if is_sequence {
        let sequences = cameras
            .iter()
            .map(|&cam| {
                let c = &desc.cameras[cam];
                let frames = args.frames.or(c.render.frames).with_context(|| {
                    format!(
                        "camera \"{}\" has no frames= (give --frames or --camera)",
                        c.id
                    )
                })?;
                let pattern = match &args.output {
                    Some(o) => o.clone(),
                    None => scene_dir.join(&c.render.output),
                };
                sequence::Sequence::new(cam, c.id.clone(), frames, pattern)
                    .with_context(|| format!("camera \"{}\"", c.id))
            })
            .collect::<Result<Vec<_>>>()?;
        if let Some(url) = &args.coordinator {
            drop(desc);
            return runtime.block_on(async {
                let mut client =
                    client::Client::connect_with(url, args.token.as_deref(), &tls(&args)).await?;
                for seq in &sequences {
                    client
                        .render_sequence(
                            &bundle,
                            seq,
                            args.priority,
                            args.tile,
                            args.detach,
                            progress,
                        )
                        .await?;
                }
                Ok(())
            });
        }
        let signals = signals.as_mut().expect("caught for a local render");
        let (threads, tile) = (args.threads.unwrap_or(0), args.tile);
        return runtime.block_on(async {
            let cancel = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
            let scene = tokio::task::spawn_blocking(move || trevi_core::Scene::build(desc))
                .await
                .context("building the scene")?;
            let flag = cancel.clone();
            let mut task = tokio::task::spawn_blocking(move || {
                sequence::render(scene, &sequences, threads, tile, progress, &flag)
            });
            tokio::select! {
                r = &mut task => r.context("the render thread")?,
                sig = signals.next() => {
                    cancel.store(true, std::sync::atomic::Ordering::Relaxed);
                    let _ = task.await;
                    Err(anyhow::Error::new(sig))
                }
            }
        });
    }
    // Every output is checked (format, not a device or directory) before
    // anything renders.
    let targets: Vec<client::Target> = cameras
        .iter()
        .map(|&cam| {
            let c = &desc.cameras[cam];
            let out = match &args.output {
                Some(o) => o.clone(),
                None => scene_dir.join(&c.render.output),
            };
            client::Target::new(c.id.clone(), out).with_context(|| format!("camera \"{}\"", c.id))
        })
        .collect::<Result<_>>()?;
    runtime.block_on(async {
        match &args.coordinator {
            Some(url) => {
                drop(desc);
                let mut client =
                    client::Client::connect_with(url, args.token.as_deref(), &tls(&args)).await?;
                client.preview = args.preview.clone();
                client
                    .render(
                        &bundle,
                        &targets,
                        args.priority,
                        args.tile,
                        args.detach,
                        progress,
                    )
                    .await
            }
            None => {
                let data = data.as_ref().expect("made for a local render");
                let signals = signals.as_mut().expect("caught for a local render");
                let scene = local::Built::new(bundle.hash.clone(), desc).await?;
                let farm = local::Embedded::start(
                    args.threads.unwrap_or(0),
                    args.tile,
                    data.path(),
                    scene,
                )
                .await?;
                let render = async {
                    let mut client = client::Client::connect(&farm.url, None).await?;
                    client.announce = false;
                    client.preview = args.preview.clone();
                    client
                        .render(&bundle, &targets, args.priority, args.tile, false, progress)
                        .await
                };
                // A signal drops the render, and with it the half-written
                // output (see client::PartFile); `data` goes after the
                // runtime.
                let result = tokio::select! {
                    r = render => r,
                    sig = signals.next() => Err(anyhow::Error::new(sig)),
                };
                farm.stop().await;
                result
            }
        }
    })
}

/// `--tile`'s default: the coordinator's own, so that a local render and a
/// farm's cut a frame alike.
fn default_tile() -> u32 {
    trevi_coordinator::FarmConfig::default().default_tile
}

/// A `--tile` edge: 0 is refused, naming the flag, not clamped.
fn tile_edge(s: &str) -> Result<u32, String> {
    match s.parse::<u32>() {
        Ok(0) => Err("must be at least 1".into()),
        Ok(n) => Ok(n),
        Err(e) => Err(e.to_string()),
    }
}

/// The TLS settings of `--tls-ca` and `--tls-domain`.
fn tls(args: &Args) -> trevi_proto::ClientTls {
    trevi_proto::ClientTls {
        ca_file: args.tls_ca.clone(),
        domain: args.tls_domain.clone(),
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
