//! What the coordinator knows about its workers, for the monitor and the
//! metrics: when each was last heard from, what it is rendering, and how
//! fast it has been going. Pure bookkeeping kept by the
//! [`Scheduler`](crate::scheduler::Scheduler); time is passed in.

use std::time::{Duration, Instant};

/// Seconds kept by a [`Rate`]: the window plus the second in progress.
const RATE_SLOTS: usize = 11;
/// Whole seconds a [`Rate`] averages over.
pub const RATE_WINDOW_S: u64 = 10;

/// Tiles and rays per second over the last [`RATE_WINDOW_S`] whole seconds.
///
/// A ring of per-second buckets rather than a list of events: its size is
/// fixed however fast tiles arrive (the coordinator takes thousands a second),
/// and the average is exact, not smoothed.
#[derive(Debug, Clone, Copy, Default)]
pub struct Rate {
    /// (second, tiles, rays); a bucket holding an older second is stale.
    buckets: [(u64, u64, u64); RATE_SLOTS],
}

impl Rate {
    /// Counts `tiles` and `rays` finished during second `sec`.
    pub fn add(&mut self, sec: u64, tiles: u64, rays: u64) {
        let b = &mut self.buckets[(sec % RATE_SLOTS as u64) as usize];
        if b.0 != sec {
            *b = (sec, 0, 0);
        }
        // Rays come from the network: a huge count must not wrap.
        b.1 = b.1.saturating_add(tiles);
        b.2 = b.2.saturating_add(rays);
    }

    /// (tiles/s, rays/s) over the [`RATE_WINDOW_S`] whole seconds before
    /// second `sec` (the one in progress is left out: it is not over yet).
    pub fn per_second(&self, sec: u64) -> (f64, f64) {
        let from = sec.saturating_sub(RATE_WINDOW_S);
        let (mut tiles, mut rays) = (0, 0);
        for &(s, t, r) in &self.buckets {
            if s >= from && s < sec && (t > 0 || r > 0) {
                tiles = u64::saturating_add(tiles, t);
                rays = u64::saturating_add(rays, r);
            }
        }
        let w = RATE_WINDOW_S as f64;
        (tiles as f64 / w, rays as f64 / w)
    }
}

/// How a worker is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum WorkerState {
    /// Holds at least one lease.
    Busy,
    /// Heard from within a lease's lifetime, holds no lease.
    Idle,
    /// Silent for longer than a lease lives: crashed, cut off or stopped.
    Lost,
}

impl WorkerState {
    pub const ALL: [WorkerState; 3] = [WorkerState::Busy, WorkerState::Idle, WorkerState::Lost];

    pub fn name(self) -> &'static str {
        match self {
            WorkerState::Busy => "busy",
            WorkerState::Idle => "idle",
            WorkerState::Lost => "lost",
        }
    }
}

/// One registered worker.
#[derive(Debug, Clone)]
pub struct WorkerEntry {
    pub name: String,
    pub threads: u32,
    pub last_seen: Instant,
    pub tiles_done: u64,
    pub rays: u64,
    pub rate: Rate,
    /// The secret its registration was given, which every later call must
    /// present (none: registered in-process, not reachable over gRPC).
    pub session: Option<[u8; 32]>,
}

impl WorkerEntry {
    pub fn new(now: Instant) -> Self {
        WorkerEntry {
            name: String::new(),
            threads: 0,
            last_seen: now,
            tiles_done: 0,
            rays: 0,
            rate: Rate::default(),
            session: None,
        }
    }

    /// Whether `presented` is this worker's session secret, compared in
    /// time that does not depend on where they differ.
    pub fn session_is(&self, presented: &[u8]) -> bool {
        let Some(secret) = &self.session else {
            return false;
        };
        if presented.len() != secret.len() {
            return false;
        }
        let diff = secret
            .iter()
            .zip(presented)
            .fold(0u8, |acc, (a, b)| acc | (a ^ b));
        std::hint::black_box(diff) == 0
    }

    /// Busy, idle or lost, given how many leases it holds.
    pub fn state(&self, leases: usize, lease_ttl: Duration, now: Instant) -> WorkerState {
        if now.saturating_duration_since(self.last_seen) > lease_ttl {
            WorkerState::Lost
        } else if leases > 0 {
            WorkerState::Busy
        } else {
            WorkerState::Idle
        }
    }
}

/// A worker as the monitor shows it.
#[derive(Debug, Clone)]
pub struct WorkerInfo {
    pub id: u64,
    pub name: String,
    pub threads: u32,
    pub state: WorkerState,
    /// Time since it was last heard from.
    pub silent_for: Duration,
    /// The tiles it holds leases on: (job, tile rectangle).
    pub leases: Vec<(u64, trevi_core::Rect)>,
    pub tiles_done: u64,
    pub rays: u64,
    pub tiles_per_s: f64,
    pub rays_per_s: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rate_averages_the_last_whole_seconds_only() {
        let mut r = Rate::default();
        // 3 tiles of 100 rays in each of seconds 0..20.
        for s in 0..20 {
            r.add(s, 3, 300);
        }
        // The second in progress (20) does not count; 10..20 does.
        r.add(20, 1000, 1000);
        assert_eq!(r.per_second(20), (3.0, 300.0));
        // Ten seconds later, nothing new: only second 20 is in 20..30.
        assert_eq!(r.per_second(30), (100.0, 100.0));
        // Much later: everything is stale.
        assert_eq!(r.per_second(100), (0.0, 0.0));
    }

    #[test]
    fn rate_restarts_a_reused_bucket() {
        let mut r = Rate::default();
        r.add(1, 5, 5);
        // Second 12 lands in second 1's bucket: the old count must go.
        r.add(12, 2, 2);
        assert_eq!(r.per_second(13), (0.2, 0.2));
    }

    #[test]
    fn a_session_matches_only_its_own_secret() {
        let mut w = WorkerEntry::new(Instant::now());
        assert!(!w.session_is(&[]), "no session: nothing matches");
        w.session = Some([7; 32]);
        assert!(w.session_is(&[7; 32]));
        let mut other = [7; 32];
        other[31] = 8;
        assert!(!w.session_is(&other));
        assert!(!w.session_is(&[7; 31]));
        assert!(!w.session_is(&[]));
    }

    #[test]
    fn rate_saturates_instead_of_wrapping() {
        let mut r = Rate::default();
        r.add(1, 1, u64::MAX);
        r.add(1, 1, u64::MAX);
        assert_eq!(r.per_second(2).1, u64::MAX as f64 / RATE_WINDOW_S as f64);
    }

    #[test]
    fn a_worker_silent_longer_than_a_lease_is_lost() {
        let t0 = Instant::now();
        let w = WorkerEntry::new(t0);
        let ttl = Duration::from_secs(10);
        assert_eq!(
            w.state(0, ttl, t0 + Duration::from_secs(9)),
            WorkerState::Idle
        );
        assert_eq!(
            w.state(1, ttl, t0 + Duration::from_secs(9)),
            WorkerState::Busy
        );
        assert_eq!(
            w.state(1, ttl, t0 + Duration::from_secs(11)),
            WorkerState::Lost
        );
    }
}
