//! The worker's old environment variable names: read where the
//! old name meant only this, with a warning; refused where it was ambiguous.
//!
//! - `TREVI_PRIORITY` (now `TREVI_CPU_PRIORITY`) and `TREVI_TOKEN_FILE`
//!   (now `TREVI_WORKER_TOKEN_FILE`) were read by the worker alone: still
//!   read, with a warning.
//! - `TREVI_TOKEN` was read by trevi-worker for the worker token and by
//!   trevi-submit for the submit token, two different secrets: it is
//!   refused with a message naming the new variable, rather than ignored
//!   (which would show up only as "unauthenticated" from the coordinator).

use anyhow::{bail, Result};

/// The value of `old` when `new` is unset, with a warning (empty values
/// count as unset, as clap counts them).
pub fn deprecated_env(new: &str, old: &str) -> Option<String> {
    let set = |name: &str| std::env::var(name).ok().filter(|v| !v.is_empty());
    if set(new).is_some() {
        return None;
    }
    let v = set(old)?;
    tracing::warn!("{old} is deprecated: set {new} instead");
    Some(v)
}

/// Refuses `TREVI_TOKEN` when no token was given under a current name.
pub fn refuse_ambiguous_token(given: bool) -> Result<()> {
    let old = std::env::var("TREVI_TOKEN").ok().filter(|v| !v.is_empty());
    if !given && old.is_some() {
        bail!(
            "TREVI_TOKEN is no longer read (trevi-submit read it for another token): \
             set TREVI_WORKER_TOKEN (or pass --token / --token-file)"
        );
    }
    Ok(())
}
