//! `--max-memory`: the most memory the worker lets one scene take, so that a
//! worker on somebody's desk does not push its owner's programs out of RAM.
//!
//! The limit is compared with the scene's estimate
//! ([`trevi_core::scene::estimate`]: what building and rendering it holds,
//! from its description, before the build). The worker tells the
//! coordinator its limit when it registers, and the coordinator leases it
//! only jobs whose estimate fits; a lease that does not fit anyway (the
//! coordinator's estimate came later, or the coordinator is older) is
//! declined: handed back at once with the estimate, which is not a failure,
//! and the job is kept from this worker from then on. A worker declines
//! before downloading the bundle when the lease carries the estimate, and
//! otherwise after parsing it but before building.
//!
//! A pass of a progressive job (`Lease.samples`, `crate::pass`) also holds
//! its rect's accumulation state, 64 bytes a pixel, at most twice at once
//! ([`pass_state_bytes`]): the lease's check adds it to the scene's
//! estimate, and so does the check before a build, so a pass lease is
//! declined when scene and state together pass the limit (and the
//! coordinator hears that sum as what the job needs).
//!
//! By default the limit is [`DEFAULT_SHARE`] of the machine's RAM
//! (`MemTotal` in `/proc/meminfo`); where that cannot be read, no limit.

use std::fmt;
use std::str::FromStr;
use trevi_core::passes::{HEADER_BYTES, PIXEL_BYTES};
use trevi_core::scene::estimate::human_bytes;
use trevi_core::Rect;

/// The share of the machine's RAM a worker allows a scene by default.
pub const DEFAULT_SHARE: f64 = 0.5;

/// A `--max-memory` value: a size in bytes, 0 for "no limit".
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MaxMemory(pub u64);

impl MaxMemory {
    /// No limit.
    pub const NONE: MaxMemory = MaxMemory(0);

    /// [`DEFAULT_SHARE`] of this machine's RAM, or no limit when it cannot
    /// be read.
    pub fn default_for_this_machine() -> MaxMemory {
        std::fs::read_to_string("/proc/meminfo")
            .ok()
            .and_then(|s| mem_total(&s))
            .map_or(MaxMemory::NONE, |total| {
                MaxMemory((total as f64 * DEFAULT_SHARE) as u64)
            })
    }

    /// Whether a scene needing about `bytes` fits.
    pub fn allows(self, bytes: u64) -> bool {
        self.0 == 0 || bytes <= self.0
    }
}

/// The most memory a pass lease of `rect` holds for its accumulation
/// state: twice its encoding (`TileState::encoded_len`, 32 + 64 bytes a
/// pixel), since a pass holds two copies at once at most: the fetched
/// bytes and the decoded state, the state and the copy it renders on, the
/// state and its encoding, the encoding and its upload chunks. Saturates
/// rather than overflows for any rect.
pub fn pass_state_bytes(rect: Rect) -> u64 {
    let pixels = u64::from(rect.w) * u64::from(rect.h);
    (PIXEL_BYTES as u64)
        .saturating_mul(pixels)
        .saturating_add(HEADER_BYTES as u64)
        .saturating_mul(2)
}

/// `MemTotal` of a `/proc/meminfo` text, in bytes.
pub fn mem_total(meminfo: &str) -> Option<u64> {
    let line = meminfo.lines().find(|l| l.starts_with("MemTotal:"))?;
    let mut words = line["MemTotal:".len()..].split_whitespace();
    let n: u64 = words.next()?.parse().ok()?;
    match words.next() {
        Some("kB") => n.checked_mul(1024),
        None => Some(n),
        Some(_) => None,
    }
}

/// Why a `--max-memory` value is not a size.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "\"{0}\" is not a size: write a number of bytes with an optional unit K, M, G or T \
     (powers of 1024, like 2G or 512M), or 0 for no limit"
)]
pub struct BadSize(String);

impl FromStr for MaxMemory {
    type Err = BadSize;

    /// `2G`, `512M`, `1.5G`, `2GiB`, `800000K`, `1073741824`; units are
    /// powers of 1024, any case, with an optional `B` or `iB`.
    fn from_str(s: &str) -> Result<MaxMemory, BadSize> {
        let bad = || BadSize(s.to_string());
        let t = s.trim();
        let split = t
            .find(|c: char| !(c.is_ascii_digit() || c == '.'))
            .unwrap_or(t.len());
        let (num, unit) = t.split_at(split);
        let unit = unit.trim().to_ascii_uppercase();
        let unit = unit
            .strip_suffix("IB")
            .or_else(|| unit.strip_suffix('B'))
            .unwrap_or(&unit);
        let scale: u64 = match unit {
            "" => 1,
            "K" => 1 << 10,
            "M" => 1 << 20,
            "G" => 1 << 30,
            "T" => 1 << 40,
            _ => return Err(bad()),
        };
        let v: f64 = num.parse().map_err(|_| bad())?;
        let bytes = v * scale as f64;
        if !bytes.is_finite() || bytes < 0.0 || bytes >= u64::MAX as f64 {
            return Err(bad());
        }
        // Only a literal 0 means "no limit": a size that rounds down to 0
        // bytes (0.0000001K) is a mistake, not a wish for no limit.
        if bytes < 1.0 && v != 0.0 {
            return Err(bad());
        }
        Ok(MaxMemory(bytes as u64))
    }
}

impl fmt::Display for MaxMemory {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.0 == 0 {
            return f.write_str("0");
        }
        // Exact in the largest unit that divides it, so it reads back the same.
        for (unit, shift) in [("T", 40), ("G", 30), ("M", 20), ("K", 10)] {
            if self.0 % (1u64 << shift) == 0 {
                return write!(f, "{}{unit}", self.0 >> shift);
            }
        }
        write!(f, "{}", self.0)
    }
}

/// The log line of a declined scene.
pub fn declined(job: u64, needs: u64, limit: MaxMemory) -> String {
    format!(
        "declining job {job}: its scene needs about {}, more than this worker's --max-memory \
         of {}; handed back for a worker with more",
        human_bytes(needs),
        human_bytes(limit.0)
    )
}

#[cfg(test)]
mod tests;
