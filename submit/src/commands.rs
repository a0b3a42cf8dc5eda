//! The farm commands: `status`, `list`, `cancel`, `fetch` and `wait` (also
//! `attach`: follow a job to its end and download its output, as the
//! submission would have).

use anyhow::{bail, Result};
use std::io::IsTerminal;

use crate::args::Command;
use crate::cli::{self, LeftRunning};
use crate::client;
use crate::local;
use crate::progress::Progress;

pub async fn run(cmd: Command) -> Result<()> {
    let farm = cmd.farm();
    let url = farm.coordinator.clone();
    let mut client = farm.auth.connect(&url).await?;
    match cmd {
        Command::Status { id, preview, .. } => {
            println!("{}", client::describe(&client.status(id).await?));
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
        } => {
            let progress = Progress::choose(quiet);
            let mut signals = local::Signals::catch()?;
            let work = async {
                let end = client.watch(id, progress).await?;
                let (out, s) = client.fetch(id, output.as_deref()).await?;
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
                r = work => return r,
                sig = signals.next() => {
                    return Err(anyhow::Error::new(LeftRunning::new(sig, &[id], &url)));
                }
            }
        }
    }
    Ok(())
}
