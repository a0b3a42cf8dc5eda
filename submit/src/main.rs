//! `trevi-submit`: what users type.
//!
//! `trevi-submit SCENE.xml [--camera ID] [-o OUT]` renders every camera of
//! the scene (or the one named) to its `output` file: a still, or a
//! sequence for a camera with frames. With `--coordinator URL` the frames
//! are rendered on a farm; without it, by a coordinator and a worker
//! embedded in this process with every core, through the same client code.
//! `trevi-submit status|list|cancel|pause|resume|retry|requeue|unblock|log|fetch|wait|extend`
//! manage a farm's jobs (commands.rs; `--after` orders them, control.rs;
//! log.rs prints the tile log and the blocked workers); `trevi-submit usage`
//! prints its usage history (usage.rs).
//! `--samples`, `--pass`, `--time-limit` and `--noise-target` make a still
//! progressive (passes.rs); a local render with `--samples` keeps its job
//! for `extend` (kept.rs).
//!
//! The output's format follows its name (`-o FILE`, else the camera's
//! `output`): `.png` or `.exr`, anything else is refused before rendering.
//! A local render stopped by SIGINT or SIGTERM removes its temporary files
//! and any half-written output, and exits with 128 + the signal's number,
//! within a second even inside one very expensive pixel. A farm submission
//! stopped so leaves its jobs running and says how to follow (`wait ID`)
//! or cancel them.
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

mod args;
mod cli;
mod client;
mod commands;
mod control;
mod data_dir;
mod denoise;
mod kept;
mod local;
mod log;
mod passes;
mod progress;
mod sequence;
mod usage;

use anyhow::{bail, Context, Result};
use args::Args;
use std::path::PathBuf;

fn main() {
    let args = Args::parse_checked();
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
        Some(c) => c.farm().map(|(url, _)| url.to_string()),
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

fn run(args: Args) -> Result<()> {
    if let Some(cmd) = args.command {
        let runtime = tokio::runtime::Runtime::new().context("cannot start the async runtime")?;
        return runtime.block_on(commands::run(cmd));
    }
    // A local render: the embedded coordinator's data directory (made once
    // the targets are known), declared before the runtime so that it is
    // removed after the runtime (and every task that could write into it)
    // has shut down.
    let data: Option<data_dir::DataDir>;
    let runtime = tokio::runtime::Runtime::new().context("cannot start the async runtime")?;
    // Caught from here on, so that a local render interrupted at any point
    // still returns through the code that removes what it wrote, and a
    // farm submission says what it leaves running.
    let mut signals = runtime.block_on(async { local::Signals::catch() })?;
    let Some(scene_path) = args.scene.clone() else {
        bail!(
            "name a scene file (or one of status, list, cancel, fetch, wait, extend); see --help"
        );
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
    let progressive = args.progressive();
    let job = client::JobSpec {
        priority: args.priority,
        tile_size: args.tile_size,
        progressive,
        notify: args.notify.clone(),
        after: args.after.clone(),
        aovs: args.aovs,
    };
    let mut targets = Vec::new();
    // Outputs denoised once rendered (see denoise.rs): checked now.
    let mut to_denoise = Vec::new();
    let denoise_threads = args.threads.unwrap_or(0).min(u32::MAX as usize) as u32;
    for &cam in &cameras {
        let c = &desc.cameras[cam];
        let mut out = match &args.output {
            Some(o) => o.clone(),
            None => scene_dir.join(&c.render.output),
        };
        let frames = args.frames.or(c.render.frames);
        if args.denoise || c.render.denoise {
            denoise::check_detach(args.detach)?;
            if to_denoise.is_empty() {
                denoise::check(denoise_threads)?;
            }
            // Checked as the output before it is swapped for the noisy frame
            // (a sequence's pattern and every frame's file).
            client::Target::new(c.id.clone(), out.clone(), frames)
                .with_context(|| format!("camera \"{}\"", c.id))?;
            let noisy = denoise::noisy_path(&out);
            to_denoise.push(denoise::Output {
                noisy: noisy.clone(),
                out,
                frames,
                // The passes asked for go on to the output; a progressive
                // job renders none.
                carry: match progressive {
                    None => args.aovs.unwrap_or(c.render.aovs),
                    Some(_) => trevi_core::Aovs::NONE,
                },
            });
            out = noisy;
        }
        let stops = progressive
            .as_ref()
            .is_some_and(|p| p.time_limit_ms > 0 || p.noise_target > 0.0);
        if frames.is_some() && stops {
            bail!(
                "camera \"{}\" renders a sequence (the scene's frames=): {}",
                c.id,
                args::SEQUENCE_STOPS
            );
        }
        let mut target = client::Target::new(c.id.clone(), out, frames)
            .with_context(|| format!("camera \"{}\"", c.id))?;
        if (args.denoise || c.render.denoise) && progressive.is_none() {
            // The noisy frame carries the passes the denoiser uses (a
            // progressive job renders none: its beauty alone is denoised).
            target.aovs = Some(denoise::with_guides(args.aovs.unwrap_or(c.render.aovs)));
        }
        targets.push(target);
    }
    targets.sort_by_key(|t| t.frames().is_some());
    // A progressive render to denoise shows each pass denoised in its
    // --preview (denoise/preview.rs).
    let denoise_preview =
        (!to_denoise.is_empty() && progressive.is_some()).then_some(denoise_threads);
    // A local still with its own samples can be extended later: its job is
    // kept in the local directory. Any other local render leaves nothing.
    let keep = args.coordinator.is_none()
        && args.samples.is_some()
        && targets.iter().any(|t| t.frames().is_none());
    let local_dir = if keep { Some(args.local.path()?) } else { None };
    data = match (&args.coordinator, &local_dir) {
        (Some(_), _) => None,
        (None, Some(dir)) => Some(data_dir::DataDir::kept(dir)?),
        (None, None) => Some(data_dir::DataDir::temporary()?),
    };
    let rendered = runtime.block_on(async {
        if let Some(url) = &args.coordinator {
            drop(desc);
            let mut client = args.auth.connect(url).await?;
            client.preview = args.preview.clone();
            client.denoise_preview = denoise_preview;
            let work = client.render(&bundle, &targets, &job, args.detach, progress);
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
        let farm = local::Embedded::start(threads, args.tile_size, data, Some(scene)).await?;
        let mut submitted = Vec::new();
        let render = async {
            let mut client = client::Client::connect(&farm.url, None).await?;
            client.announce = false;
            client.preview = args.preview.clone();
            client.denoise_preview = denoise_preview;
            let r = client
                .render(&bundle, &targets, &job, false, progress)
                .await;
            submitted = client.submitted.clone();
            r
        };
        // A signal drops the render, and with it the half-written output
        // (see client::PartFile), and the embedded worker's render (its
        // cancel flag, set when the task is dropped, stops even a pixel in
        // progress); the frames sequences finished are kept; `data` goes
        // after the runtime.
        let result = tokio::select! {
            r = render => r,
            sig = signals.next() => {
                if let Ok(mut client) = client::Client::connect(&farm.url, None).await {
                    client.keep_finished_frames(&targets, progress).await;
                }
                // Nothing is left to come back unfinished in a kept directory.
                farm.cancel_unfinished();
                Err(anyhow::Error::new(sig))
            }
        };
        farm.stop().await;
        if let (Ok(()), Some(dir)) = (&result, &local_dir) {
            if !args.quiet {
                let stills: Vec<(u64, PathBuf)> = submitted
                    .iter()
                    .zip(&targets)
                    .filter_map(|(id, t)| match &t.output {
                        client::Output::Still(out) => Some((
                            *id,
                            std::path::absolute(out).unwrap_or_else(|_| out.clone()),
                        )),
                        client::Output::Sequence(_) => None,
                    })
                    .collect();
                let default = kept::LocalDir::default().path().ok();
                eprint!("{}", kept::extend_hint(&stills, dir, default.as_deref()));
            }
        }
        result
    });
    rendered?;
    if !to_denoise.is_empty() {
        runtime.block_on(denoise::run_interruptible(
            to_denoise,
            denoise_threads,
            args.quiet,
            &mut signals,
        ))?;
    }
    Ok(())
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
