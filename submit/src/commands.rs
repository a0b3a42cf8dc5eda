//! The farm commands: `status`, `list`, `cancel`, `pause`, `resume`,
//! `retry`, `requeue`, `unblock`, `log` (log.rs prints it), `usage` (the farm's usage
//! history, usage.rs), `fetch`, `wait` (also `attach`: follow a job to its end and
//! download its output, as the submission would have) and `extend` (more
//! samples for a progressive job; with `--wait`, followed as `wait` does;
//! without `--coordinator`, a local render's job, see `kept.rs`).

use anyhow::{bail, Result};
use std::io::IsTerminal;

use std::path::Path;

use crate::args::Command;
use crate::cli::{self, LeftRunning};
use crate::client::{self, Client};
use crate::local;
use crate::passes;
use crate::progress::Progress;

pub async fn run(cmd: Command) -> Result<()> {
    if let Command::Extend {
        id,
        samples,
        passes,
        output,
        quiet,
        local,
        coordinator: None,
        ..
    } = &cmd
    {
        // `extend` of a local render's job: rendered here.
        let request = passes::extend_request(*id, *samples, passes);
        return crate::kept::extend(request, output.as_deref(), *quiet, local).await;
    }
    let Some((url, auth)) = cmd.farm() else {
        bail!("this command needs --coordinator URL");
    };
    let url = url.to_string();
    let mut client = auth.connect(&url).await?;
    match cmd {
        Command::Status { id, preview, .. } => {
            let s = client.status(id).await?;
            println!("{}", client::describe(&s));
            for line in crate::log::blocked_lines(&s.blocked) {
                println!("{line}");
            }
            if let Some(out) = &preview {
                let p = client.save_preview(id, out).await?;
                println!(
                    "preview: {}x{}, {} tiles -> {}",
                    p.width,
                    p.height,
                    p.tiles,
                    out.display()
                );
            }
        }
        Command::List { limit, header, .. } => {
            let jobs = client.list(limit).await?;
            if header || std::io::stdout().is_terminal() {
                println!("{}", cli::list_header());
            }
            for s in jobs {
                println!("{}", cli::list_row(&s));
            }
        }
        Command::Cancel { id, .. } => {
            // A job that has ended stays as it ended: say so, not "cancelled".
            let before = client.status(id).await?;
            if before.state().is_final() {
                bail!(
                    "job {id} had already ended ({}): nothing to cancel",
                    before.state().label()
                );
            }
            println!("{}", client::describe(&client.cancel(id).await?));
        }
        Command::Pause { id, now, .. } => {
            println!("{}", client::describe(&client.pause(id, now).await?));
        }
        Command::Resume { id, .. } => {
            println!("{}", client::describe(&client.resume(id).await?));
        }
        Command::Retry { id, .. } => {
            println!("{}", client::describe(&client.retry(id).await?));
        }
        Command::Requeue {
            id, frames, rect, ..
        } => {
            println!(
                "{}",
                client::describe(&client.requeue(id, frames, rect).await?)
            );
        }
        Command::Unblock { id, worker, .. } => {
            let s = client.unblock(id, &worker).await?;
            println!("{}", client::describe(&s));
            for line in crate::log::blocked_lines(&s.blocked) {
                println!("{line}");
            }
        }
        Command::Log {
            id,
            tile,
            frame,
            errors,
            ..
        } => {
            let log = client
                .tile_log(trevi_proto::pb::TileLogRequest {
                    id,
                    frame,
                    x: tile.map(|t| t.0),
                    y: tile.map(|t| t.1),
                    errors_only: errors,
                })
                .await?;
            print!("{}", crate::log::table(&log));
        }
        Command::Usage {
            since,
            by,
            format,
            cost_per_core_hour,
            ..
        } => {
            let r = client.usage(since, by).await?;
            print!(
                "{}",
                crate::usage::render(&r, by, format, cost_per_core_hour)
            );
        }
        Command::Fetch {
            id, output, quiet, ..
        } => {
            let (out, s) = client.fetch(id, output.as_deref()).await?;
            if !quiet {
                eprintln!(
                    "job {id}: camera {}, {}x{} -> {}",
                    s.camera,
                    s.width,
                    s.height,
                    out.display()
                );
            }
        }
        Command::Wait {
            id, output, quiet, ..
        } => return wait(&mut client, id, output.as_deref(), quiet, &url).await,
        Command::Extend {
            id,
            samples,
            passes,
            wait: follow,
            output,
            quiet,
            ..
        } => {
            let s = client
                .extend(passes::extend_request(id, samples, &passes))
                .await?;
            println!("{}", client::describe(&s));
            if follow {
                return wait(&mut client, id, output.as_deref(), quiet, &url).await;
            }
        }
    }
    Ok(())
}

/// `wait`: follows job `id` to its end with the progress display (none with
/// `quiet`), then downloads its output to `output` as `fetch` does. A
/// signal stops only the following: the job goes on.
async fn wait(
    client: &mut Client,
    id: u64,
    output: Option<&Path>,
    quiet: bool,
    url: &str,
) -> Result<()> {
    let progress = Progress::choose(quiet);
    let mut signals = local::Signals::catch()?;
    let work = async {
        let end = client.watch(id, progress).await?;
        let (out, s) = client.fetch(id, output).await?;
        if !quiet {
            eprintln!(
                "job {id} {}: camera {}, {}x{} -> {}",
                end.state().label(),
                s.camera,
                s.width,
                s.height,
                out.display()
            );
        }
        anyhow::Ok(())
    };
    tokio::select! {
        r = work => r,
        sig = signals.next() => Err(anyhow::Error::new(LeftRunning::new(sig, &[id], url))),
    }
}
