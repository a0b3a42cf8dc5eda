//! Keyboard and mouse activity, as `--yield-when-busy` counts it with
//! `--idle-after` (like OpenCue's NIMBY): the machine is in use while its
//! owner has typed or moved the mouse within `--idle-after`, whatever the
//! CPU load.
//!
//! Activity is a counter that grows with input ([`InputSource`]); on Linux
//! ([`ProcInterrupts`]) the interrupts the kernel has counted, on every
//! core, for the lines of the PS/2 controller (`i8042`: a laptop's built-in
//! keyboard and touchpad, a PS/2 keyboard and mouse) and of HID devices on
//! I²C (`i2c_hid`, most touchpads and some keyboards of newer laptops), read
//! from `/proc/interrupts`, which every user may read. USB keyboards and mice
//! share their controller's interrupt (`xhci_hcd`) with every other USB
//! device (disks, network adapters), so they are not counted: their traffic
//! would keep the machine "in use". Nor are remote sessions (ssh, VNC), or
//! devices a desktop reports only through its session (logind's `IdleHint`
//! needs a session the worker's service does not have).
//!
//! The rule ([`InputWatch`]) is pure: it is fed the counter and the time.

use std::time::{Duration, Instant};

/// Where input activity is read: a counter that grows with every input
/// event (any unit; only its changes count).
pub trait InputSource: Send {
    /// The counter now; `None` when it cannot be read.
    fn activity(&mut self) -> Option<u64>;
}

/// Linux's `/proc/interrupts`: the interrupts of the input lines (see the
/// module's documentation).
#[derive(Debug, Default)]
pub struct ProcInterrupts;

impl InputSource for ProcInterrupts {
    fn activity(&mut self) -> Option<u64> {
        let text = std::fs::read_to_string("/proc/interrupts").ok()?;
        input_interrupts(&text)
    }
}

/// Whether an interrupt line's description names an input device.
fn is_input(description: &str) -> bool {
    let d = description.to_ascii_lowercase();
    d.contains("i8042") || d.contains("i2c_hid") || d.contains("i2c-hid")
}

/// The interrupts of the input lines in the text of `/proc/interrupts`,
/// summed over every core; `None` when the text is not as Linux writes it
/// (no header of `CPUn` columns). A machine without such lines counts 0
/// (and never looks in use).
pub fn input_interrupts(text: &str) -> Option<u64> {
    let mut lines = text.lines();
    let cpus = lines
        .next()?
        .split_whitespace()
        .filter(|c| c.starts_with("CPU"))
        .count();
    if cpus == 0 {
        return None;
    }
    let mut total = 0u64;
    for line in lines {
        let mut fields = line.split_whitespace();
        let Some(irq) = fields.next() else {
            continue;
        };
        if !irq.ends_with(':') {
            continue;
        }
        let mut counts = 0u64;
        let mut read = 0;
        let mut rest = Vec::new();
        for f in fields.by_ref() {
            if read < cpus {
                if let Ok(n) = f.parse::<u64>() {
                    counts = counts.saturating_add(n);
                    read += 1;
                    continue;
                }
            }
            rest.push(f);
        }
        if is_input(&rest.join(" ")) {
            total = total.saturating_add(counts);
        }
    }
    Some(total)
}

/// Decides from the activity counter whether the machine is in use: from
/// the first change seen until `idle_after` passes with none.
#[derive(Debug, Clone)]
pub struct InputWatch {
    idle_after: Duration,
    last: Option<u64>,
    /// When the counter last changed.
    active: Option<Instant>,
}

impl InputWatch {
    /// A watch that starts idle (the first reading is only a baseline).
    pub fn new(idle_after: Duration) -> Self {
        InputWatch {
            idle_after,
            last: None,
            active: None,
        }
    }

    /// Takes the counter read at `now` (`None`: unreadable, no change);
    /// returns how long ago the last input came while the machine is in
    /// use, `None` once it is idle.
    pub fn feed(&mut self, now: Instant, count: Option<u64>) -> Option<Duration> {
        if let Some(c) = count {
            if self.last.is_some_and(|l| l != c) {
                self.active = Some(now);
            }
            self.last = Some(c);
        }
        let ago = now.saturating_duration_since(self.active?);
        if ago >= self.idle_after {
            self.active = None;
            return None;
        }
        Some(ago)
    }
}
