//! `trevi-submit`'s command line: the flags of a render and of the farm
//! commands (clap's definitions), read by `main.rs` and `commands.rs`.

use crate::client;
use crate::passes::{self, PassFlags};
use anyhow::{bail, Result};
use clap::error::ErrorKind;
use clap::{CommandFactory, Parser};
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(
    name = "trevi-submit",
    version,
    about = "Render an AISXML scene, on this machine or on a farm",
    args_conflicts_with_subcommands = true
)]
pub struct Args {
    #[command(subcommand)]
    pub command: Option<Command>,
    /// The scene file (AISXML).
    pub scene: Option<PathBuf>,
    /// Arguments after the scene: none are taken, but a mistyped
    /// subcommand's (`canel 3`) are read so that it can be named.
    #[arg(hide = true)]
    pub rest: Vec<std::ffi::OsString>,
    /// The farm's coordinator, like http://host:50051, or https:// for TLS
    /// (default: render on this machine).
    #[arg(long, env = "TREVI_COORDINATOR")]
    pub coordinator: Option<String>,
    #[command(flatten)]
    pub auth: Auth,
    /// Job priority on the farm: higher runs first (a worker's CPU class is
    /// trevi-worker --cpu-priority).
    #[arg(
        long,
        env = "TREVI_JOB_PRIORITY",
        default_value_t = 0,
        allow_negative_numbers = true
    )]
    pub priority: i32,
    /// Submit and print the job ids without waiting (needs --coordinator).
    #[arg(long, env = "TREVI_DETACH")]
    pub detach: bool,
    /// Render only this camera (default: every camera in the scene).
    #[arg(long, env = "TREVI_CAMERA")]
    pub camera: Option<String>,
    /// Output file (.png or .exr); only with a single camera. Default: the
    /// camera's `output`, relative to the scene's directory. No `#` but one
    /// run in a sequence's file name.
    #[arg(short = 'o', long = "output", env = "TREVI_OUTPUT")]
    pub output: Option<PathBuf>,
    /// Render these frames of the camera's sequence, `first-last` or one
    /// frame (default: the scene's `frames=`, if any). Each frame goes to
    /// its own file: the output's run of `#` replaced by the frame number.
    /// On a farm the range is one job (`status`, `cancel`, `fetch` take its
    /// id).
    #[arg(long, env = "TREVI_FRAMES", value_parser = crate::sequence::parse_frames)]
    pub frames: Option<trevi_core::scene::animation::Frames>,
    /// Worker threads on this machine (default: every core).
    #[arg(long, env = "TREVI_THREADS")]
    pub threads: Option<usize>,
    /// Tile edge in pixels (at least 1); the coordinator's --tile-size
    /// when not given. Old name: --tile.
    #[arg(long = "tile-size", alias = "tile", env = "TREVI_TILE_SIZE",
          default_value_t = default_tile(), value_parser = tile_edge)]
    pub tile_size: u32,
    /// No progress output.
    #[arg(short, long, env = "TREVI_QUIET")]
    pub quiet: bool,
    /// Denoise every still and every frame of a sequence (Intel Open Image
    /// Denoise, with the albedo and normal passes) after it is rendered,
    /// here, band by band: the noisy frame is kept beside a PNG output as
    /// NAME.noisy.exr, an EXR output holds it as its layer "noisy". A camera's
    /// denoise="true" does the same for it. Needs a build with the
    /// `denoise` feature (docs/denoise.md); refused before rendering
    /// otherwise.
    #[arg(long, env = "TREVI_DENOISE")]
    pub denoise: bool,
    /// Keep the live preview of the frame being rendered in this PNG file
    /// (at most 512 pixels a side, updated about once a second).
    #[arg(long, env = "TREVI_PREVIEW")]
    pub preview: Option<PathBuf>,
    /// Render this many samples per pixel (1 to 1048576) instead of the
    /// scene's, progressively: in passes over the whole frame, the output
    /// rewritten after each, extendable later (`trevi-submit extend`). This,
    /// --pass, --time-limit or --noise-target makes a still progressive; a
    /// sequence (--frames) renders each frame in passes with --samples and
    /// --pass, and takes no --time-limit or --noise-target.
    #[arg(long, env = "TREVI_SAMPLES", value_parser = passes::samples)]
    pub samples: Option<u32>,
    #[command(flatten)]
    pub passes: PassFlags,
    /// On a farm: POST each job's events (submitted, started, frame done,
    /// done, failed, cancelled) as signed JSON to this http:// or https://
    /// URL; repeat for more (at most 4). See docs/farm.md, "Events".
    #[arg(long = "notify", value_name = "URL", requires = "coordinator")]
    pub notify: Vec<String>,
    #[command(flatten)]
    pub local: crate::kept::LocalDir,
    /// Start only once these farm jobs are done (ids, comma-separated, at
    /// most 64): the job waits on the farm (state `waiting`), and fails
    /// naming the cause if one of them fails or is cancelled. Needs
    /// --coordinator.
    #[arg(long, env = "TREVI_AFTER", value_delimiter = ',')]
    pub after: Vec<u64>,
    /// Render these passes with the beauty (albedo, normal, depth;
    /// comma-separated, at most 64 bytes; "" for none) instead of the
    /// camera's `<render aovs>`: an EXR output holds them as layers
    /// (albedo.R…, N.X…, Z), a PNG output gets NAME.albedo.png,
    /// NAME.normal.png and NAME.depth.exr beside it (each frame of a PNG
    /// sequence: shot_01.albedo.png… beside shot_01.png). Not
    /// progressive.
    #[arg(long, env = "TREVI_AOVS", value_parser = aovs_arg)]
    pub aovs: Option<trevi_core::Aovs>,
}

/// `--aovs`: at most 64 bytes of known pass names (the coordinator's
/// bound too).
fn aovs_arg(s: &str) -> Result<trevi_core::Aovs, String> {
    if s.len() > 64 {
        return Err(format!(
            "{} bytes, more than the 64 allowed (at most albedo,normal,depth)",
            s.len()
        ));
    }
    trevi_core::Aovs::parse(s).map_err(|e| e.to_string())
}

/// How to reach a farm's coordinator: the flags every farm command shares.
#[derive(clap::Args, Debug)]
pub struct Auth {
    /// The coordinator's submit token (its --submit-token; sent as
    /// `authorization: Bearer`). TREVI_TOKEN is no longer read: it named
    /// trevi-worker's token too.
    #[arg(long, env = "TREVI_SUBMIT_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// For an https:// coordinator: trust this PEM CA certificate instead of
    /// the system roots (a farm with its own CA, see deploy/make-certs.sh).
    #[arg(long, env = "TREVI_TLS_CA")]
    pub tls_ca: Option<PathBuf>,
    /// For an https:// coordinator: the name its certificate must carry, if
    /// not the URL's host.
    #[arg(long, env = "TREVI_TLS_DOMAIN")]
    pub tls_domain: Option<String>,
}

/// A farm command's coordinator (required) and credentials.
#[derive(clap::Args, Debug)]
pub struct Farm {
    /// The farm's coordinator, like http://host:50051, or https:// for TLS.
    #[arg(long, env = "TREVI_COORDINATOR")]
    pub coordinator: String,
    #[command(flatten)]
    pub auth: Auth,
}

#[derive(clap::Subcommand, Debug)]
pub enum Command {
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
    /// Pause a job: no more of its tiles are rendered until `resume`; the
    /// tiles being rendered finish, or with --now go back to the queue at
    /// once. Its finished tiles are kept (across a coordinator restart
    /// too).
    Pause {
        /// The job's id (printed by --detach, listed by `list`).
        id: u64,
        /// Stop the tiles being rendered now (their workers drop them at
        /// their next heartbeat) instead of letting them finish.
        #[arg(long)]
        now: bool,
        #[command(flatten)]
        farm: Farm,
    },
    /// Resume a paused job where it stopped.
    Resume {
        /// The job's id (printed by --detach, listed by `list`).
        id: u64,
        #[command(flatten)]
        farm: Farm,
    },
    /// Start a failed job again, keeping what it had finished: a still's
    /// tiles, a sequence's frames (they are not rendered again).
    Retry {
        /// The job's id (printed by --detach, listed by `list`).
        id: u64,
        #[command(flatten)]
        farm: Farm,
    },
    /// Render part of a job again under its id, its output rewritten in
    /// place with the bytes of a fresh render: an ended still whole or the
    /// tiles a rect touches (--rect), frames of a sequence (--frames, also
    /// while it runs).
    Requeue {
        /// The job's id (printed by --detach, listed by `list`).
        id: u64,
        /// The frames of a sequence to render again, A-B or one frame A.
        #[arg(long, value_name = "A-B", value_parser = requeue_frames)]
        frames: Option<(u32, u32)>,
        /// Only the tiles this rect of the frame touches (x, y, width,
        /// height in pixels; inside the frame, not empty; a PNG output).
        #[arg(long, value_name = "X,Y,W,H", value_parser = requeue_rect)]
        rect: Option<[u32; 4]>,
        #[command(flatten)]
        farm: Farm,
    },
    /// Let a worker kept from a job (it failed the coordinator's
    /// --max-worker-failures of its tiles; `status` lists them) take its
    /// tiles again.
    Unblock {
        /// The job's id (printed by --detach, listed by `list`).
        id: u64,
        /// The worker: its id or its name, as `status` shows it (a name
        /// unblocks every blocked worker of that name).
        worker: String,
        #[command(flatten)]
        farm: Farm,
    },
    /// Print a job's tile log: for each lease of its tiles, the worker,
    /// when, the render and CPU time, rays, retries, or the error.
    Log {
        /// The job's id (printed by --detach, listed by `list`).
        id: u64,
        /// Only the tile holding pixel X,Y of the frame.
        #[arg(long, value_name = "X,Y", value_parser = crate::log::pixel)]
        tile: Option<(u32, u32)>,
        /// Only this frame's (a sequence).
        #[arg(long)]
        frame: Option<u32>,
        /// Only the failures.
        #[arg(long)]
        errors: bool,
        #[command(flatten)]
        farm: Farm,
    },
    /// Add samples per pixel to a finished progressive job (one rendered with
    /// --samples): it runs again from where it stopped, its output replaced
    /// after every new pass. With --coordinator, a farm's job; without, a
    /// local render's (kept in --local-dir), rendered on this machine with
    /// every core and written to -o.
    Extend {
        /// The job's id (printed by --detach, listed by `list`).
        id: u64,
        /// Samples per pixel to add (1 to 1048576; the job's new total must
        /// stay within 1048576 too).
        #[arg(long, value_parser = passes::samples)]
        samples: u32,
        #[command(flatten)]
        passes: PassFlags,
        /// On a farm: follow the job until its new passes end, showing
        /// progress, then download its image (as `wait`). A local extend
        /// always does.
        #[arg(long)]
        wait: bool,
        /// Where to write the image (as for `fetch`; on a farm with --wait).
        #[arg(short = 'o', long = "output")]
        output: Option<PathBuf>,
        /// No progress output.
        #[arg(short, long, env = "TREVI_QUIET")]
        quiet: bool,
        /// The farm's coordinator, like http://host:50051, or https:// for
        /// TLS (default: a local render's job, in --local-dir).
        #[arg(long, env = "TREVI_COORDINATOR")]
        coordinator: Option<String>,
        #[command(flatten)]
        auth: Auth,
        #[command(flatten)]
        local: crate::kept::LocalDir,
    },
    /// The farm's usage history: CPU time (core-seconds), tiles, rays and
    /// wall time per job, submitter or worker, as the workers measured it.
    /// Kept by the coordinator beyond the jobs (its --usage-retention).
    Usage {
        /// How far back: 90m, 12h, 7d, 30d (from 1m to 3650d; default 7d).
        #[arg(long, value_parser = crate::usage::parse_since)]
        since: Option<std::time::Duration>,
        /// One row per job, submitter or worker.
        #[arg(long, value_enum, default_value_t = crate::usage::By::Job)]
        by: crate::usage::By,
        /// table (for people), csv or json (for programs).
        #[arg(long, value_enum, default_value_t = crate::usage::Format::Table)]
        format: crate::usage::Format,
        /// Add a cost column: the core-hours times this (a number from 0 to
        /// 1000000, in your currency).
        #[arg(long, value_parser = crate::usage::parse_cost, allow_negative_numbers = true)]
        cost_per_core_hour: Option<f64>,
        #[command(flatten)]
        farm: Farm,
    },
}

impl Args {
    /// The command line, with the rules across flags checked as clap checks
    /// each flag's own: a wrong one ends the process with clap's message and
    /// exit status 2, before anything is read or uploaded.
    pub fn parse_checked() -> Args {
        let args = Args::parse();
        if let Err(e) = args.check() {
            e.exit();
        }
        args
    }

    /// The rules across flags: a pass no larger than the samples; a
    /// progressive render only of stills; render passes not progressive.
    pub fn check(&self) -> Result<(), clap::Error> {
        let (samples, flags) = match &self.command {
            Some(Command::Extend {
                samples, passes, ..
            }) => (Some(*samples), passes),
            Some(_) => return Ok(()),
            None => (self.samples, &self.passes),
        };
        crate::control::check_after(&self.after, self.coordinator.is_some())
            .map_err(|m| Args::command().error(ErrorKind::ValueValidation, m))?;
        if self.aovs.is_some_and(|a| !a.is_empty()) && self.progressive().is_some() {
            return Err(Args::command().error(
                ErrorKind::ArgumentConflict,
                "--aovs: render passes are not rendered for a progressive render (--samples, \
                 --pass, --time-limit, --noise-target) yet",
            ));
        }
        passes::check(samples, flags)
            .map_err(|m| Args::command().error(ErrorKind::ValueValidation, m))?;
        if let Some(Command::Extend {
            coordinator: Some(_),
            output: Some(_),
            wait: false,
            ..
        }) = &self.command
        {
            return Err(Args::command().error(
                ErrorKind::MissingRequiredArgument,
                "-o is where --wait downloads the image from a farm: add --wait (an extend \
                 without --coordinator renders here and always writes -o)",
            ));
        }
        if self.command.is_none()
            && self.frames.is_some()
            && (self.passes.time_limit.is_some() || self.passes.noise_target.is_some())
        {
            return Err(Args::command().error(ErrorKind::ArgumentConflict, SEQUENCE_STOPS));
        }
        Ok(())
    }

    /// The render's `SubmitJobRequest.progressive` (see [`passes::progressive`]).
    pub fn progressive(&self) -> Option<trevi_proto::pb::Progressive> {
        passes::progressive(self.samples, &self.passes)
    }
}

/// Why a sequence takes no stop condition (`--frames`, or a camera whose
/// scene has `frames=`).
pub const SEQUENCE_STOPS: &str = "a sequence renders each frame in passes with --samples and \
     --pass, but takes no --time-limit or --noise-target: they would stop it in the middle of a \
     frame (drop them, or render a still)";

impl Command {
    /// The coordinator the command talks to and its credentials; `None` for
    /// `extend` without --coordinator (a local render's job).
    pub fn farm(&self) -> Option<(&str, &Auth)> {
        match self {
            Command::Status { farm, .. }
            | Command::List { farm, .. }
            | Command::Cancel { farm, .. }
            | Command::Fetch { farm, .. }
            | Command::Wait { farm, .. }
            | Command::Pause { farm, .. }
            | Command::Resume { farm, .. }
            | Command::Retry { farm, .. }
            | Command::Requeue { farm, .. }
            | Command::Unblock { farm, .. }
            | Command::Log { farm, .. }
            | Command::Usage { farm, .. } => Some((farm.coordinator.as_str(), &farm.auth)),
            Command::Extend {
                coordinator, auth, ..
            } => coordinator.as_deref().map(|c| (c, auth)),
        }
    }
}

impl Auth {
    /// The submit token; refuses the old, ambiguous TREVI_TOKEN when no
    /// token is given under its current name.
    pub fn token(&self) -> Result<Option<&str>> {
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
    pub fn tls(&self) -> trevi_proto::ClientTls {
        trevi_proto::ClientTls {
            ca_file: self.tls_ca.clone(),
            domain: self.tls_domain.clone(),
        }
    }

    /// A client of the coordinator at `url` with these credentials.
    pub async fn connect(&self, url: &str) -> Result<client::Client> {
        client::Client::connect_with(url, self.token()?, &self.tls()).await
    }
}

/// `--tile-size`'s default: the coordinator's own, so that a local render and a
/// farm's cut a frame alike.
pub fn default_tile() -> u32 {
    trevi_coordinator::FarmConfig::default().default_tile
}

/// A `--tile-size` edge: 0 is refused, naming the flag, not clamped.
pub fn tile_edge(s: &str) -> Result<u32, String> {
    match s.parse::<u32>() {
        Ok(0) => Err("must be at least 1".into()),
        Ok(n) => Ok(n),
        Err(e) => Err(e.to_string()),
    }
}

#[cfg(test)]
mod tests;

/// `requeue --frames A-B` (trevi_proto::requeue's grammar and bound).
fn requeue_frames(s: &str) -> Result<(u32, u32), String> {
    trevi_proto::requeue::parse_frames(s).map_err(|e| e.to_string())
}

/// `requeue --rect X,Y,W,H` (trevi_proto::requeue's grammar and bound).
fn requeue_rect(s: &str) -> Result<[u32; 4], String> {
    trevi_proto::requeue::parse_rect(s).map_err(|e| e.to_string())
}
