//! The hooks the end-to-end tests (`tests/`) drive the worker with, compiled
//! in only with the `test-hooks` feature (which `trevi-tests` turns on; a
//! normal build has none of them and reads none of their variables):
//!
//! - `TREVI_TEST_ABORT_ON_TILE=x,y` and `TREVI_TEST_PANIC_ON_TILE=x,y`
//!   ([`TestFault`], read by `trevi-worker`): the render of the tile at
//!   (`x`, `y`) aborts the process or panics, standing in for a scene that
//!   crashes the renderer;
//! - `TREVI_TEST_PROC_STAT` ([`crate::pause::PROC_STAT_VAR`]): a file read in
//!   place of `/proc/stat`, so a test decides the machine's load;
//! - `TREVI_TEST_LEASE_DELAY_MS=N` ([`LEASE_DELAY_MS`]): every lease's render
//!   takes at least N ms more, so a job lasts long enough for a test to act
//!   in its middle however fast the machine is;
//! - `TREVI_TEST_FAIL_JOB=ID[,BYTES]` ([`FAIL_JOB`]): every lease of job
//!   `ID` fails at once with an error text (of `BYTES` bytes when given, at
//!   most 16 MiB), standing in for a machine that cannot render one job
//!   (the blocklist tests).

use trevi_core::Rect;

/// The variable whose `x,y` makes the render of that tile abort the process.
pub const ABORT_ON_TILE: &str = "TREVI_TEST_ABORT_ON_TILE";
/// The variable whose `x,y` makes the render of that tile panic.
pub const PANIC_ON_TILE: &str = "TREVI_TEST_PANIC_ON_TILE";
/// The variable whose milliseconds every lease's render waits first.
pub const LEASE_DELAY_MS: &str = "TREVI_TEST_LEASE_DELAY_MS";

/// The variable whose `ID[,BYTES]` makes every lease of job `ID` fail.
pub const FAIL_JOB: &str = "TREVI_TEST_FAIL_JOB";

/// Tests only: the error every lease of `job` fails with when [`FAIL_JOB`]
/// names it (padded with `x` to `BYTES` bytes when given).
pub(crate) fn job_fault(job: u64) -> Option<String> {
    let v = std::env::var(FAIL_JOB).ok()?;
    let (id, bytes) = match v.split_once(',') {
        Some((id, b)) => (id, b.trim().parse::<usize>().ok()),
        None => (v.as_str(), None),
    };
    if id.trim().parse::<u64>().ok()? != job {
        return None;
    }
    let mut why = format!("test fault: every tile of job {job} fails");
    if let Some(n) = bytes {
        let n = n.min(16 << 20);
        if n > why.len() {
            why.push_str(&"x".repeat(n - why.len()));
        }
    }
    Some(why)
}

/// Tests only: waits [`LEASE_DELAY_MS`] milliseconds (at most a minute)
/// when it is set, on the render thread.
pub(crate) fn lease_delay() {
    let ms = std::env::var(LEASE_DELAY_MS)
        .ok()
        .and_then(|v| v.trim().parse::<u64>().ok());
    if let Some(ms) = ms {
        std::thread::sleep(std::time::Duration::from_millis(ms.min(60_000)));
    }
}

/// Tests only: a deliberate failure when rendering the tile whose top-left
/// corner is at (`x`, `y`), standing in for a scene that crashes the
/// renderer. Set by `trevi-worker` from [`ABORT_ON_TILE`] or [`PANIC_ON_TILE`].
#[doc(hidden)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TestFault {
    pub x: u32,
    pub y: u32,
    /// Abort the process (like a stack overflow) rather than panic.
    pub abort: bool,
}

impl TestFault {
    /// Reads `x,y` from `var`; `None` when it is unset or malformed.
    pub fn from_env(var: &str, abort: bool) -> Option<TestFault> {
        let v = std::env::var(var).ok()?;
        let (x, y) = v.split_once(',')?;
        Some(TestFault {
            x: x.trim().parse().ok()?,
            y: y.trim().parse().ok()?,
            abort,
        })
    }

    pub(crate) fn strike(&self, rect: Rect) {
        if (rect.x, rect.y) == (self.x, self.y) {
            if self.abort {
                eprintln!(
                    "test fault: aborting on the tile at ({}, {})",
                    rect.x, rect.y
                );
                std::process::abort();
            }
            panic!("test fault: panic on the tile at ({}, {})", rect.x, rect.y);
        }
    }
}
