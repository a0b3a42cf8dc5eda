//! Local progressive renders kept for `extend`: a local render with
//! `--samples` runs its embedded coordinator on a directory that outlives
//! the process ([`LocalDir`], by default `$XDG_DATA_HOME/trevi/local`), so
//! that `trevi-submit extend ID --samples N` without `--coordinator` can
//! start the embedded coordinator on it again (it restores its jobs from
//! its database) and add samples to the job. Every other local render keeps
//! its coordinator's files in a temporary directory, removed at its end
//! (`data_dir.rs`).
//!
//! One process at a time uses a kept directory: the coordinator's lock
//! (`coordinator.lock`, see `trevi_coordinator::dir_lock`); a second one is
//! refused with a message that names the first's PID and `--local-dir`.
//! A kept job holds two accumulation states of 64 bytes a pixel and its
//! output; the coordinator's retention forgets it (and removes its files)
//! 7 days after it ended, and deleting the directory removes every one.

use crate::data_dir::DataDir;
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};

/// The directory's place under the user's data directory.
const UNDER_DATA_HOME: &str = "trevi/local";

/// `--local-dir`, shared by a render and `extend`.
#[derive(clap::Args, Debug, Clone, Default, PartialEq)]
pub struct LocalDir {
    /// Where a local render with --samples keeps its job for `trevi-submit
    /// extend` (and where `extend` without --coordinator finds it); default:
    /// $XDG_DATA_HOME/trevi/local, or ~/.local/share/trevi/local. One
    /// render or extend at a time uses it.
    #[arg(long = "local-dir", env = "TREVI_LOCAL_DIR", value_name = "DIR")]
    pub local_dir: Option<PathBuf>,
}

impl LocalDir {
    /// The directory: `--local-dir`, else [`default_dir`] of this
    /// process's environment; made absolute (it is printed for `extend`).
    pub fn path(&self) -> Result<PathBuf> {
        let dir = match &self.local_dir {
            Some(d) => d.clone(),
            None => default_dir(
                std::env::var_os("XDG_DATA_HOME").as_deref(),
                std::env::var_os("HOME").as_deref(),
            )?,
        };
        std::path::absolute(&dir).with_context(|| format!("--local-dir {}", dir.display()))
    }
}

/// The default `--local-dir`: `trevi/local` under `$XDG_DATA_HOME` when it
/// is an absolute path (the XDG rule: a relative one is ignored), else
/// under `$HOME/.local/share`.
pub fn default_dir(
    xdg_data_home: Option<&std::ffi::OsStr>,
    home: Option<&std::ffi::OsStr>,
) -> Result<PathBuf> {
    let non_empty = |v: Option<&std::ffi::OsStr>| v.filter(|v| !v.is_empty()).map(PathBuf::from);
    if let Some(xdg) = non_empty(xdg_data_home).filter(|p| p.is_absolute()) {
        return Ok(xdg.join(UNDER_DATA_HOME));
    }
    match non_empty(home) {
        Some(home) => Ok(home.join(".local/share").join(UNDER_DATA_HOME)),
        None => bail!(
            "neither XDG_DATA_HOME nor HOME is set: give --local-dir DIR for the local \
             render's job (a render with --samples keeps it for `trevi-submit extend`)"
        ),
    }
}

/// What a local render prints at its end about the jobs it kept: their ids
/// and the command that extends each (with `--local-dir` when it is not
/// the default, with `-o` the file it wrote).
pub fn extend_hint(jobs: &[(u64, PathBuf)], dir: &Path, default: Option<&Path>) -> String {
    let local = if default == Some(dir) {
        String::new()
    } else {
        format!(" --local-dir {}", dir.display())
    };
    let mut text = String::new();
    for (id, out) in jobs {
        text.push_str(&format!(
            "job {id} is kept in {}: add samples with `trevi-submit extend {id} --samples N{local} \
             -o {}`\n",
            dir.display(),
            out.display()
        ));
    }
    text
}

/// Whether a coordinator ever ran in `dir` (its lock file is there): else
/// there is no job to extend in it, and nothing is made there.
pub fn holds_jobs(dir: &Path) -> bool {
    dir.join(trevi_coordinator::dir_lock::LOCK_FILE).is_file()
}

/// `trevi-submit extend` without `--coordinator`: starts the embedded
/// coordinator on the local directory (its jobs come back from its
/// database) and the worker, extends the job as `request` says, follows it
/// with the progress display (none with `quiet`), writing the image to
/// `output` (default: the job's output file name in the current directory)
/// after every pass, and stops. An unknown job is refused before anything
/// is made; a signal cancels the job (and so ends its extension: nothing
/// is left to come back unfinished).
pub async fn extend(
    request: trevi_proto::pb::ExtendJobRequest,
    output: Option<&Path>,
    quiet: bool,
    local: &LocalDir,
) -> Result<()> {
    let id = request.id;
    let dir = local.path()?;
    if !holds_jobs(&dir) {
        bail!(
            "no local job {id}: no local render kept a job in {} (a local render keeps its job \
             for `extend` only with --samples; give the --local-dir it used, or --coordinator \
             for a farm's job)",
            dir.display()
        );
    }
    let data = DataDir::kept(&dir)?;
    let mut signals = crate::local::Signals::catch()?;
    // The job keeps its own tile size; new jobs would take the farm's default.
    let tile = trevi_coordinator::FarmConfig::default().default_tile;
    let farm = crate::local::Embedded::start(0, tile, &data, None).await?;
    let progress = crate::progress::Progress::choose(quiet);
    let work = async {
        let mut client = crate::client::Client::connect(&farm.url, None).await?;
        client.announce = false;
        if !farm.knows(id) {
            bail!(
                "no local job {id} in {} (it was never there, or retention forgot it 7 days \
                 after it ended; a farm's job needs --coordinator)",
                dir.display()
            );
        }
        let before = client.status(id).await?;
        let out = match output {
            Some(o) => o.to_path_buf(),
            None => Path::new(&before.output_name)
                .file_name()
                .map(PathBuf::from)
                .with_context(|| format!("job {id} names no output file"))?,
        };
        // Checked before the job is extended: nothing renders for an
        // output that cannot be written.
        let target = crate::client::Target::new(before.camera.clone(), out.clone(), None)?;
        let format = trevi_core::output::Format::from_path(Path::new(&before.output_name));
        if let Some(f) = format.filter(|&f| f != target.format) {
            bail!(
                "job {id}'s image is a {} file ({}): -o must end in .{}",
                f.extension(),
                before.output_name,
                f.extension()
            );
        }
        let s = client.extend(request).await?;
        if !quiet {
            eprintln!("{}", crate::client::describe(&s));
        }
        client.finish_still(id, &target, &out, progress).await?;
        anyhow::Ok(out)
    };
    let result = tokio::select! {
        r = work => r,
        sig = signals.next() => {
            farm.cancel_unfinished();
            Err(anyhow::Error::new(sig))
        }
    };
    farm.stop().await;
    let out = result?;
    if !quiet {
        let out = std::path::absolute(&out).unwrap_or(out);
        let default = LocalDir::default().path().ok();
        eprint!("{}", extend_hint(&[(id, out)], &dir, default.as_deref()));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::ffi::OsStr;

    #[test]
    fn the_default_dir_follows_xdg_then_home() {
        let d = |x: Option<&str>, h: Option<&str>| {
            default_dir(x.map(OsStr::new), h.map(OsStr::new)).map_err(|e| e.to_string())
        };
        assert_eq!(
            d(Some("/x"), Some("/h")).unwrap(),
            Path::new("/x/trevi/local")
        );
        // A relative or empty XDG_DATA_HOME is ignored.
        for x in [Some("rel"), Some(""), None] {
            assert_eq!(
                d(x, Some("/h")).unwrap(),
                Path::new("/h/.local/share/trevi/local")
            );
        }
        let e = d(None, None).unwrap_err();
        assert!(e.contains("--local-dir"), "{e}");
    }

    #[test]
    fn a_kept_dir_is_one_process_s_and_not_a_file() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("local");
        let first = DataDir::kept(&dir).unwrap();
        assert!(first.is_kept() && dir.is_dir());
        let e = DataDir::kept(&dir).err().unwrap().to_string();
        assert!(
            e.contains("another trevi-submit") && e.contains("--local-dir"),
            "{e}"
        );
        drop(first);
        DataDir::kept(&dir).unwrap();
        let file = tmp.path().join("file");
        std::fs::write(&file, "x").unwrap();
        let e = DataDir::kept(&file).err().unwrap().to_string();
        assert!(e.contains("not a directory"), "{e}");
    }

    #[test]
    fn the_hint_names_the_dir_only_when_not_the_default() {
        let jobs = [(7, PathBuf::from("/o/a.exr"))];
        let dir = Path::new("/d");
        let h = extend_hint(&jobs, dir, Some(dir));
        assert!(
            h.contains("`trevi-submit extend 7 --samples N -o /o/a.exr`"),
            "{h}"
        );
        let h = extend_hint(&jobs, dir, Some(Path::new("/other")));
        assert!(h.contains("--local-dir /d -o"), "{h}");
    }
}
