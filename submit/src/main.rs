//! `trevi-submit`: what users type.
//!
//! `trevi-submit SCENE.xml [--camera ID] [-o OUT]` renders every camera of
//! the scene (or the one named) to its `output` file. Without a farm address
//! the frame is rendered on this machine with every core.

mod local;

use anyhow::{bail, Context, Result};
use clap::Parser;
use std::io::IsTerminal;
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(name = "trevi-submit", version, about = "Render an AISXML scene")]
struct Args {
    /// The scene file (AISXML).
    scene: PathBuf,
    /// Render only this camera (default: every camera in the scene).
    #[arg(long)]
    camera: Option<String>,
    /// Output file (.png or .exr); only with a single camera. Default: the
    /// camera's `output`, relative to the scene's directory.
    #[arg(short = 'o', long = "output")]
    output: Option<PathBuf>,
    /// Worker threads on this machine (default: every core).
    #[arg(long, env = "TREVI_THREADS")]
    threads: Option<usize>,
    /// Tile edge in pixels.
    #[arg(long, default_value_t = 64)]
    tile: u32,
    /// No progress output.
    #[arg(short, long)]
    quiet: bool,
}

fn main() {
    let args = Args::parse();
    if let Err(e) = run(args) {
        eprintln!("trevi-submit: error: {e:#}");
        std::process::exit(1);
    }
}

fn run(args: Args) -> Result<()> {
    if args.tile == 0 {
        bail!("--tile must be at least 1");
    }
    let bundle = trevi_core::Bundle::from_scene_file(&args.scene)
        .map_err(|e| anyhow::anyhow!("{}", with_dir(&args.scene, e)))?;
    let scene = trevi_core::Scene::from_bundle(&bundle)
        .map_err(|e| anyhow::anyhow!("{}", with_dir(&args.scene, e)))?;
    let cameras: Vec<usize> = match &args.camera {
        Some(id) => vec![scene.camera_index(id).with_context(|| {
            let ids: Vec<_> = scene.desc.cameras.iter().map(|c| c.id.as_str()).collect();
            format!(
                "no camera \"{id}\" in the scene (cameras: {})",
                ids.join(", ")
            )
        })?],
        None => (0..scene.desc.cameras.len()).collect(),
    };
    if args.output.is_some() && cameras.len() > 1 {
        bail!(
            "-o names one file but the scene has {} cameras: add --camera ID",
            cameras.len()
        );
    }
    let scene_dir = args
        .scene
        .parent()
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("."));
    let progress = if args.quiet {
        local::Progress::Quiet
    } else if std::io::stderr().is_terminal() {
        local::Progress::Bar
    } else {
        local::Progress::Lines
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads.unwrap_or(0))
        .build()
        .context("cannot start the worker threads")?;
    for cam in cameras {
        let desc = &scene.desc.cameras[cam];
        let out = match &args.output {
            Some(o) => o.clone(),
            None => scene_dir.join(&desc.render.output),
        };
        let stats =
            pool.install(|| local::render_camera(&scene, cam, &out, args.tile, progress))?;
        if !args.quiet {
            eprintln!(
                "{}: {}x{} -> {} in {:.2} s, {:.1} M rays ({:.2} M rays/s)",
                desc.id,
                desc.render.width,
                desc.render.height,
                out.display(),
                stats.seconds,
                stats.rays as f64 / 1e6,
                stats.rays as f64 / 1e6 / stats.seconds.max(1e-9)
            );
        }
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
