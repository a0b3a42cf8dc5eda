//! When a worker on a spare machine steps aside: the machine's owner is
//! using it (`--yield-when-busy`: its CPU load, and with `--idle-after` its
//! keyboard and mouse, see [`input`]), or it is outside the hours the worker
//! may work (`--active-hours`).
//!
//! Everything here is pure: the load sampler reads `/proc/stat` and
//! `/proc/self/stat` *text* handed to it, and the watchers are fed the time,
//! so the tests give them made-up numbers. The machine watcher
//! (`machine.rs`) reads the files once a [`PauseConfig::sample`] and
//! publishes the [`Pause`] the watchers decide; the render loops stop their
//! tiles and hand the leases back when it turns to paused, and lease nothing
//! until it turns back.
//!
//! The load that is not ours is the machine's busy CPU time (every state of
//! `/proc/stat`'s `cpu` line but idle and iowait) less this process's own
//! (`utime + stime` of `/proc/self/stat`, all its threads), over the time
//! between two samples, in cores: 1.0 is one core kept busy by other
//! programs. Our own render threads run at idle priority, so they never
//! hold the machine back; what is left is the owner's work.
//!
//! With the `test-hooks` feature, tests set `PROC_STAT_VAR` to a file of
//! their own in `/proc/stat`'s format: the machine's load is then theirs to
//! decide, whatever else the machine they run on is doing
//! (tests/tests/spare.rs). A normal build reads `/proc/stat` only.

use std::fmt;
use std::time::{Duration, Instant};

pub mod input;

/// `--busy-threshold`'s default, in cores of load not ours: half a core
/// busy for [`BUSY_FOR`] is somebody working (a browser, a compile), while a
/// desktop at rest stays well below it (a few percent of one core).
pub const BUSY_THRESHOLD: f64 = 0.5;
/// `--busy-for-ms`'s default: how long the load must stay above the
/// threshold before the worker pauses (a short spike does not count).
pub const BUSY_FOR: Duration = Duration::from_secs(3);
/// `--quiet-for-ms`'s default: how long the load must stay below the
/// threshold before a paused worker works again.
pub const QUIET_FOR: Duration = Duration::from_secs(60);
/// `--sample-ms`'s default: how often the load is sampled. A pause reaches
/// the render threads at the next sample, and a render stops within a
/// pixel of that.
pub const SAMPLE: Duration = Duration::from_secs(1);

/// Why a worker is not taking tiles.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pause {
    /// Other programs kept the machine busy.
    Busy {
        /// The load not ours, in cores (the highest sample that made the
        /// machine busy).
        load: f64,
    },
    /// Outside `--active-hours`.
    OutsideHours,
    /// Keyboard or mouse input came within `--idle-after`.
    InUse {
        /// How long ago the last input came (when the pause was decided).
        ago: Duration,
    },
}

impl Pause {
    /// The word the coordinator's monitor and metrics show.
    pub fn reason(&self) -> &'static str {
        match self {
            Pause::Busy { .. } => "busy",
            Pause::OutsideHours => "outside hours",
            Pause::InUse { .. } => "in use",
        }
    }
}

impl fmt::Display for Pause {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Pause::Busy { load } => write!(
                f,
                "busy: other programs use {:.2} cores of this machine",
                load
            ),
            Pause::OutsideHours => write!(f, "outside hours"),
            Pause::InUse { ago } => write!(
                f,
                "in use: keyboard or mouse input {:.0} s ago",
                ago.as_secs_f64()
            ),
        }
    }
}

/// What the worker watches, and how quickly it reacts.
#[derive(Debug, Clone, PartialEq)]
pub struct PauseConfig {
    /// Watch the load that is not ours (`--yield-when-busy`).
    pub yield_when_busy: bool,
    /// Cores of load not ours above which the machine is busy.
    pub busy_threshold: f64,
    /// How long the load stays above the threshold before the worker
    /// pauses (`--busy-for-ms`).
    pub busy_for: Duration,
    /// How long the load stays at or below the threshold before a paused
    /// worker works again (`--quiet-for-ms`).
    pub quiet_for: Duration,
    /// How often the load is sampled (`--sample-ms`, more than zero).
    pub sample: Duration,
    /// Work only within these hours (`--active-hours`).
    pub active_hours: Option<ActiveHours>,
    /// With `yield_when_busy`: the machine is in use until no keyboard or
    /// mouse input came for this long (`--idle-after`; `None`: input is not
    /// watched).
    pub idle_after: Option<Duration>,
}

impl Default for PauseConfig {
    fn default() -> Self {
        PauseConfig {
            yield_when_busy: false,
            busy_threshold: BUSY_THRESHOLD,
            busy_for: BUSY_FOR,
            quiet_for: QUIET_FOR,
            sample: SAMPLE,
            active_hours: None,
            idle_after: None,
        }
    }
}

impl PauseConfig {
    /// Whether anything is watched at all.
    pub fn watches(&self) -> bool {
        self.yield_when_busy || self.active_hours.is_some()
    }

    /// Whether keyboard and mouse input is watched.
    pub fn watches_input(&self) -> bool {
        self.yield_when_busy && self.idle_after.is_some()
    }
}

/// CPU time counters at one moment, in clock ticks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CpuSample {
    /// Every core's time in every state (the machine's `cpu` line summed).
    pub total: u64,
    /// The part of `total` not idle and not waiting for I/O.
    pub busy: u64,
    /// This process's user + system time (all its threads).
    pub own: u64,
}

impl CpuSample {
    /// Reads the counters from the text of `/proc/stat` and
    /// `/proc/self/stat`; `None` if either is not as Linux writes it.
    pub fn parse(proc_stat: &str, self_stat: &str) -> Option<CpuSample> {
        let line = proc_stat
            .lines()
            .find(|l| l.split_whitespace().next() == Some("cpu"))?;
        // user nice system idle iowait irq softirq steal [guest guest_nice]:
        // guest time is already counted in user, so only the first eight.
        let f: Vec<u64> = line
            .split_whitespace()
            .skip(1)
            .take(8)
            .map(|v| v.parse().ok())
            .collect::<Option<_>>()?;
        if f.len() < 4 {
            return None;
        }
        let total: u64 = f.iter().sum();
        let idle = f[3] + f.get(4).copied().unwrap_or(0);
        // The command name (field 2) may hold spaces and parentheses: count
        // fields from the last ')'. utime and stime are fields 14 and 15.
        let rest = &self_stat[self_stat.rfind(')')? + 1..];
        let mut fields = rest.split_whitespace().skip(11);
        let utime: u64 = fields.next()?.parse().ok()?;
        let stime: u64 = fields.next()?.parse().ok()?;
        Some(CpuSample {
            total,
            busy: total - idle,
            own: utime + stime,
        })
    }

    /// Cores kept busy by other programs between `earlier` and `self`, on a
    /// machine of `cores` cores; `None` when no time passed.
    pub fn foreign_load(&self, earlier: &CpuSample, cores: usize) -> Option<f64> {
        let total = self.total.checked_sub(earlier.total)?;
        if total == 0 {
            return None;
        }
        let busy = self.busy.saturating_sub(earlier.busy);
        let own = self.own.saturating_sub(earlier.own);
        // Elapsed ticks of one core = total / cores.
        let foreign = busy.saturating_sub(own) as f64;
        Some(foreign * cores.max(1) as f64 / total as f64)
    }
}

/// The environment variable naming a file read in place of `/proc/stat`
/// (for tests: a load they make up). Only with the `test-hooks` feature.
#[cfg(feature = "test-hooks")]
pub const PROC_STAT_VAR: &str = "TREVI_TEST_PROC_STAT";

/// The machine's CPU counters: the text of `/proc/stat` (or, with the
/// `test-hooks` feature, of the file `PROC_STAT_VAR` names, if it is set).
pub fn read_proc_stat() -> std::io::Result<String> {
    #[cfg(feature = "test-hooks")]
    if let Some(path) = std::env::var_os(PROC_STAT_VAR) {
        return std::fs::read_to_string(path);
    }
    std::fs::read_to_string("/proc/stat")
}

/// Reads a [`CpuSample`] from this machine (`None` where there is no
/// `/proc`, or it cannot be read).
pub fn sample_now() -> Option<CpuSample> {
    let stat = read_proc_stat().ok()?;
    let me = std::fs::read_to_string("/proc/self/stat").ok()?;
    CpuSample::parse(&stat, &me)
}

/// Decides from load samples whether the machine is busy: busy once the
/// load stayed above the threshold for `busy_for`, quiet again once it
/// stayed at or below it for `quiet_for`.
#[derive(Debug, Clone)]
pub struct BusyWatch {
    threshold: f64,
    busy_for: Duration,
    quiet_for: Duration,
    busy: bool,
    /// Since when the samples disagree with `busy` (none: they agree).
    since: Option<Instant>,
    /// The highest load of the samples that disagree.
    peak: f64,
}

impl BusyWatch {
    /// A watch that starts quiet; `threshold` is in cores of load not ours.
    pub fn new(threshold: f64, busy_for: Duration, quiet_for: Duration) -> Self {
        BusyWatch {
            threshold,
            busy_for,
            quiet_for,
            busy: false,
            since: None,
            peak: 0.0,
        }
    }

    /// Takes the load measured over the sample ending at `now`; returns
    /// `Some(load)` while the machine is busy (the highest load of the
    /// samples that made it so), `None` while it is quiet.
    pub fn feed(&mut self, now: Instant, load: f64) -> Option<f64> {
        let above = load > self.threshold;
        if above == self.busy {
            self.since = None;
            if !above {
                self.peak = 0.0;
            }
        } else {
            let since = *self.since.get_or_insert(now);
            if above {
                self.peak = self.peak.max(load);
            }
            let need = if above { self.busy_for } else { self.quiet_for };
            if now.saturating_duration_since(since) >= need {
                self.busy = above;
                self.since = None;
            }
        }
        if !self.busy && self.since.is_none() {
            self.peak = 0.0;
        }
        self.busy.then_some(self.peak)
    }

    /// Whether the machine is busy after the samples fed so far.
    pub fn is_busy(&self) -> bool {
        self.busy
    }
}

/// Hours of the day when the worker may work, like `19:00-07:00` (local
/// time; a range whose end is before its start runs over midnight).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ActiveHours {
    /// Minutes after midnight.
    pub from: u32,
    /// Minutes after midnight; the end (out of the hours).
    pub to: u32,
}

impl ActiveHours {
    /// Whether `minute` (after local midnight) is within the hours; the
    /// start is in, the end is out. `09:00-09:00` is the whole day.
    pub fn contains(&self, minute: u32) -> bool {
        if self.from <= self.to {
            self.from == self.to || (self.from..self.to).contains(&minute)
        } else {
            minute >= self.from || minute < self.to
        }
    }
}

impl std::str::FromStr for ActiveHours {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let hm = |t: &str| -> Result<u32, String> {
            let (h, m) = t
                .trim()
                .split_once(':')
                .ok_or_else(|| format!("\"{t}\" is not HH:MM"))?;
            let h: u32 = h.parse().map_err(|_| format!("\"{t}\" is not HH:MM"))?;
            let m: u32 = m.parse().map_err(|_| format!("\"{t}\" is not HH:MM"))?;
            if h > 24 || m > 59 || (h == 24 && m != 0) {
                return Err(format!("\"{t}\" is not a time of day (00:00 to 24:00)"));
            }
            Ok(h * 60 + m)
        };
        let (a, b) = s
            .split_once('-')
            .ok_or_else(|| format!("\"{s}\" is not a range like 19:00-07:00"))?;
        Ok(ActiveHours {
            from: hm(a)? % (24 * 60),
            to: hm(b)? % (24 * 60),
        })
    }
}

impl fmt::Display for ActiveHours {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{:02}:{:02}-{:02}:{:02}",
            self.from / 60,
            self.from % 60,
            self.to / 60,
            self.to % 60
        )
    }
}

/// Minutes after local midnight now (UTC where the local offset is not
/// known: systems other than Linux).
pub fn local_minute() -> u32 {
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    #[cfg(target_os = "linux")]
    {
        let t = now as libc::time_t;
        // SAFETY: `libc::tm` is plain data (integers and a pointer that
        // may be null): all zero bytes is a valid value of it.
        let mut tm: libc::tm = unsafe { std::mem::zeroed() };
        // SAFETY: both pointers are valid for the call, and localtime_r
        // (unlike localtime) fills in `tm` and keeps no shared state.
        let local = unsafe { libc::localtime_r(&t, &mut tm) };
        if !local.is_null() {
            return (tm.tm_hour * 60 + tm.tm_min) as u32;
        }
    }
    ((now % 86_400) / 60) as u32
}

/// Both watchers together: the pause in force after a sample.
#[derive(Debug)]
pub struct Watcher {
    cfg: PauseConfig,
    busy: BusyWatch,
    input: Option<input::InputWatch>,
    last: Option<CpuSample>,
    cores: usize,
}

impl Watcher {
    /// Watchers for `cfg` on a machine of `cores` cores (the
    /// `/proc/stat` ticks are shared among them to give a load in cores).
    pub fn new(cfg: PauseConfig, cores: usize) -> Self {
        Watcher {
            busy: BusyWatch::new(cfg.busy_threshold, cfg.busy_for, cfg.quiet_for),
            input: cfg
                .idle_after
                .filter(|_| cfg.yield_when_busy)
                .map(input::InputWatch::new),
            cfg,
            last: None,
            cores,
        }
    }

    /// The pause (if any) given a CPU sample (`None`: none could be read),
    /// the input activity counter (`None`: not read) and the local minute
    /// of the day, at `now`.
    pub fn step(
        &mut self,
        now: Instant,
        sample: Option<CpuSample>,
        input: Option<u64>,
        minute: u32,
    ) -> Option<Pause> {
        let mut pause = None;
        if let Some(ago) = self.input.as_mut().and_then(|w| w.feed(now, input)) {
            pause = Some(Pause::InUse { ago });
        }
        if self.cfg.yield_when_busy {
            if let Some(s) = sample {
                if let Some(load) = self.last.and_then(|l| s.foreign_load(&l, self.cores)) {
                    self.busy.feed(now, load);
                }
                self.last = Some(s);
            }
            if self.busy.is_busy() {
                pause = Some(Pause::Busy {
                    load: self.busy.peak,
                });
            }
        }
        if let Some(h) = self.cfg.active_hours {
            if !h.contains(minute) {
                pause = Some(Pause::OutsideHours);
            }
        }
        pause
    }
}

/// The number of cores `/proc/stat` counts (`cpu0`, `cpu1`...).
pub fn count_cores(proc_stat: &str) -> usize {
    proc_stat
        .lines()
        .filter(|l| l.starts_with("cpu") && l.as_bytes().get(3).is_some_and(|b| b.is_ascii_digit()))
        .count()
}

#[cfg(test)]
mod tests;
