//! The render threads' CPU priority. A worker on somebody's desk must not
//! slow its owner down, so by default its render threads run under Linux's
//! `SCHED_IDLE` policy: they get CPU time only when no other thread wants
//! it. Where `SCHED_IDLE` is refused they run at nice 19 instead. Dedicated
//! render nodes (the compose and Kubernetes manifests) ask for
//! [`Priority::Normal`]. On systems other than Linux the request is not
//! applied and the worker says so in its log. Only the render threads are
//! lowered: the threads that talk to the coordinator keep normal priority,
//! so heartbeats arrive on time however busy the machine is.

use std::fmt;
use std::str::FromStr;

/// The priority a worker's render threads run at.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Priority {
    /// CPU time only when nothing else wants it (`SCHED_IDLE`, else nice 19).
    #[default]
    Idle,
    /// The scheduler's normal share: for machines that do nothing but render.
    Normal,
}

impl FromStr for Priority {
    type Err = String;
    fn from_str(s: &str) -> Result<Priority, String> {
        match s {
            "idle" => Ok(Priority::Idle),
            "normal" => Ok(Priority::Normal),
            _ => Err(format!("\"{s}\" is not a priority (idle or normal)")),
        }
    }
}

impl fmt::Display for Priority {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Priority::Idle => "idle",
            Priority::Normal => "normal",
        })
    }
}

/// What a thread got when it asked for a priority.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Applied {
    /// Linux's `SCHED_IDLE` policy.
    SchedIdle,
    /// `SCHED_IDLE` was refused; nice 19 instead.
    Nice19,
    /// The scheduler's default: asked for, or nothing lower was allowed.
    Normal,
    /// This system has no way to ask (not Linux).
    Unsupported,
}

impl fmt::Display for Applied {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Applied::SchedIdle => "idle priority (SCHED_IDLE)",
            Applied::Nice19 => "nice 19 (SCHED_IDLE was refused)",
            Applied::Normal => "normal priority",
            Applied::Unsupported => "normal priority (idle priority is not supported here)",
        })
    }
}

/// Puts the calling thread at `priority` and says what it got.
pub fn apply_to_this_thread(priority: Priority) -> Applied {
    match priority {
        Priority::Normal => Applied::Normal,
        Priority::Idle => idle(),
    }
}

#[cfg(target_os = "linux")]
fn idle() -> Applied {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: `sched_setscheduler` only reads `param`, a valid initialised
    // struct that outlives the call; pid 0 names the calling thread.
    // Lowering one's own policy needs no privilege.
    if unsafe { libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) } == 0 {
        return Applied::SchedIdle;
    }
    // SAFETY: plain integer arguments; on Linux, who = 0 with PRIO_PROCESS
    // names the calling thread (each thread has its own nice value).
    if unsafe { libc::setpriority(libc::PRIO_PROCESS, 0, 19) } == 0 {
        return Applied::Nice19;
    }
    Applied::Normal
}

#[cfg(not(target_os = "linux"))]
fn idle() -> Applied {
    Applied::Unsupported
}

#[cfg(test)]
mod tests;
