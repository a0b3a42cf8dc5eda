//! The worker list: who registered (with what session secret), when each
//! was last heard from, and how fast it has been going, for the scheduler's
//! rules, the monitor and the metrics. Pure bookkeeping kept by the
//! [`Scheduler`](crate::scheduler::Scheduler); time is passed in.

use std::collections::HashMap;
use std::time::{Duration, Instant};
use trevi_core::Rect;

/// A registered worker's number, given in order at registration from a
/// base that keeps different coordinator runs' ids apart ([`Workers::new`]).
pub type WorkerId = u64;

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
    /// Heard from, holds no lease, and said it takes none for now (its
    /// machine is busy, or it is outside its hours): see
    /// [`WorkerEntry::paused`].
    Paused,
    /// Silent for longer than a lease lives without having said it was
    /// stopping: crashed or cut off.
    Lost,
    /// Silent after it said it was stopping (its last heartbeat's reason
    /// was [`LEAVING`]): stopped cleanly, its leases handed back.
    Left,
}

/// The pause reason a worker gives in its last heartbeat when it stops
/// cleanly (SIGTERM, Ctrl-C): once silent it shows as "left", not "lost".
pub const LEAVING: &str = "stopping";

impl WorkerState {
    /// Every state, in the order `/metrics` lists them.
    pub const ALL: [WorkerState; 5] = [
        WorkerState::Busy,
        WorkerState::Idle,
        WorkerState::Paused,
        WorkerState::Lost,
        WorkerState::Left,
    ];

    /// The state's lower-case name, as the monitor and `/metrics` show it.
    pub fn name(self) -> &'static str {
        match self {
            WorkerState::Busy => "busy",
            WorkerState::Idle => "idle",
            WorkerState::Paused => "paused",
            WorkerState::Lost => "lost",
            WorkerState::Left => "left",
        }
    }
}

/// One registered worker.
#[derive(Debug, Clone)]
pub struct WorkerEntry {
    /// The name it registered with (at most 64 characters; empty until
    /// it said one).
    pub name: String,
    /// The render threads it registered with.
    pub threads: u32,
    /// When it was last heard from (registration or any later call).
    pub last_seen: Instant,
    /// Tiles it finished that were accepted.
    pub tiles_done: u64,
    /// Rays it traced for them (saturating).
    pub rays: u64,
    /// Its recent tiles and rays per second.
    pub rate: Rate,
    /// The secret its registration was given, which every later call must
    /// present (none: registered in-process, not reachable over gRPC).
    pub session: Option<[u8; 32]>,
    /// Why it said it takes no tiles for now ("busy", "outside hours"),
    /// from its last heartbeat; none once it asks for a tile again.
    /// "memory" when the coordinator found no queued job it can hold (see
    /// [`crate::scheduler::memory`]).
    pub paused: Option<String>,
    /// The most memory it lets a scene take, in bytes (its
    /// `--max-memory`); 0: it said nothing (no limit).
    pub memory_limit: u64,
    /// It called again after registering (a lease, a heartbeat...).
    pub heard: bool,
}

impl WorkerEntry {
    /// A worker registering at `now`, before it has said anything about
    /// itself.
    pub fn new(now: Instant) -> Self {
        WorkerEntry {
            name: String::new(),
            threads: 0,
            last_seen: now,
            tiles_done: 0,
            rays: 0,
            rate: Rate::default(),
            session: None,
            paused: None,
            memory_limit: 0,
            heard: false,
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
            if self.paused.as_deref() == Some(LEAVING) {
                WorkerState::Left
            } else {
                WorkerState::Lost
            }
        } else if leases > 0 {
            WorkerState::Busy
        } else if self.paused.is_some() {
            WorkerState::Paused
        } else {
            WorkerState::Idle
        }
    }
}

/// A worker as the monitor shows it.
#[derive(Debug, Clone)]
pub struct WorkerInfo {
    /// Its [`WorkerId`].
    pub id: u64,
    /// See [`WorkerEntry::name`].
    pub name: String,
    /// See [`WorkerEntry::threads`].
    pub threads: u32,
    /// How it is doing now.
    pub state: WorkerState,
    /// Why it is paused (see [`WorkerEntry::paused`]).
    pub paused: Option<String>,
    /// See [`WorkerEntry::memory_limit`] (0: none said).
    pub memory_limit: u64,
    /// Time since it was last heard from.
    pub silent_for: Duration,
    /// The tiles it holds leases on: (job, tile rectangle).
    pub leases: Vec<(u64, Rect)>,
    /// See [`WorkerEntry::tiles_done`].
    pub tiles_done: u64,
    /// See [`WorkerEntry::rays`].
    pub rays: u64,
    /// Tiles a second over the last [`RATE_WINDOW_S`] seconds.
    pub tiles_per_s: f64,
    /// Rays a second over the last [`RATE_WINDOW_S`] seconds.
    pub rays_per_s: f64,
}

/// Every registered worker, by id.
#[derive(Debug)]
pub struct Workers {
    entries: HashMap<WorkerId, WorkerEntry>,
    next: WorkerId,
    /// Time zero of the per-second rates.
    epoch: Instant,
}

impl Workers {
    /// Ids are given from `id_base` on (at least 1), so those of different
    /// coordinator runs stay apart.
    pub fn new(id_base: u64) -> Self {
        Workers {
            entries: HashMap::new(),
            next: id_base.max(1),
            epoch: Instant::now(),
        }
    }

    /// Adds a worker; with a `session`, its every later call must present
    /// that secret.
    pub fn register(&mut self, now: Instant, session: Option<[u8; 32]>) -> WorkerId {
        let id = self.next;
        self.next += 1;
        let mut w = WorkerEntry::new(now);
        w.session = session;
        self.entries.insert(id, w);
        id
    }

    /// Whether `presented` is `worker`'s session secret (`None`: no such
    /// worker).
    pub fn session_is(&self, worker: WorkerId, presented: &[u8]) -> Option<bool> {
        self.entries.get(&worker).map(|w| w.session_is(presented))
    }

    /// Records what a worker said about itself when it registered.
    pub fn describe(&mut self, worker: WorkerId, name: &str, threads: u32) {
        if let Some(w) = self.entries.get_mut(&worker) {
            // Names come from the network: keep them short.
            w.name = name.chars().take(64).collect();
            w.threads = threads;
        }
    }

    /// The name `worker` registered with (`None`: no such worker).
    pub fn name_of(&self, worker: WorkerId) -> Option<&str> {
        self.entries.get(&worker).map(|w| w.name.as_str())
    }

    /// Records why `worker` takes no tiles for now (`None`: it works).
    pub fn set_paused(&mut self, worker: WorkerId, why: Option<&str>) {
        if let Some(w) = self.entries.get_mut(&worker) {
            // Reasons come from the network: keep them short.
            w.paused = why.map(|s| s.chars().take(32).collect());
        }
    }

    /// Records the memory limit `worker` registered with (0: none).
    pub fn set_memory_limit(&mut self, worker: WorkerId, bytes: u64) {
        if let Some(w) = self.entries.get_mut(&worker) {
            w.memory_limit = bytes;
        }
    }

    /// The memory limit `worker` registered with (0: none, or no such
    /// worker).
    pub fn memory_limit(&self, worker: WorkerId) -> u64 {
        self.entries.get(&worker).map_or(0, |w| w.memory_limit)
    }

    /// The render threads `worker` registered with (`None`: no such worker).
    pub fn threads(&self, worker: WorkerId) -> Option<u32> {
        self.entries.get(&worker).map(|w| w.threads)
    }

    /// Notes that `worker` was heard from; `false`: no such worker.
    pub fn touch(&mut self, worker: WorkerId, now: Instant) -> bool {
        match self.entries.get_mut(&worker) {
            Some(w) => {
                w.last_seen = now;
                w.heard = true;
                true
            }
            None => false,
        }
    }

    /// Counts a tile `worker` finished with `rays` rays.
    pub fn credit(&mut self, worker: WorkerId, rays: u64, now: Instant) {
        self.credit_tiles(worker, 1, rays, now);
    }

    /// [`Workers::credit`] for `tiles` tiles at once (a span taken whole).
    pub fn credit_tiles(&mut self, worker: WorkerId, tiles: u64, rays: u64, now: Instant) {
        let sec = self.sec(now);
        if let Some(w) = self.entries.get_mut(&worker) {
            w.tiles_done += tiles;
            // Ray counts come from workers: a huge one saturates, never wraps.
            w.rays = w.rays.saturating_add(rays);
            w.rate.add(sec, tiles, rays);
        }
    }

    /// The workers heard from within `ttl`.
    pub fn live(&self, ttl: Duration, now: Instant) -> Vec<WorkerId> {
        self.entries
            .iter()
            .filter(|(_, w)| now.saturating_duration_since(w.last_seen) <= ttl)
            .map(|(&id, _)| id)
            .collect()
    }

    /// Forgets the workers silent for longer than `after`, and those that
    /// never called again after registering for longer than a tenth of it
    /// (a registration alone holds a place only briefly, see
    /// `crate::farm`'s registrations); one that comes back is told to
    /// register again.
    pub fn forget_silent(&mut self, after: Duration, now: Instant) {
        self.entries.retain(|id, w| {
            let silent = now.saturating_duration_since(w.last_seen);
            let keep = silent <= after && (w.heard || silent <= after / 10);
            if !keep {
                let how = if w.heard { "silent" } else { "never called after registering" };
                tracing::info!(worker = id, name = %w.name, silent_s = silent.as_secs(), "worker forgotten ({how})");
            }
            keep
        });
    }

    /// Every worker by id, with the tiles it holds (`held`: job and
    /// rectangle by worker) and its rates.
    pub fn list(
        &self,
        mut held: HashMap<WorkerId, Vec<(u64, Rect)>>,
        lease_ttl: Duration,
        now: Instant,
    ) -> Vec<WorkerInfo> {
        let sec = self.sec(now);
        let mut out: Vec<WorkerInfo> = self
            .entries
            .iter()
            .map(|(&id, w)| {
                let mut leases = held.remove(&id).unwrap_or_default();
                leases.sort_unstable_by_key(|&(j, r)| (j, r.y, r.x));
                let (tiles_per_s, rays_per_s) = w.rate.per_second(sec);
                WorkerInfo {
                    id,
                    name: w.name.clone(),
                    threads: w.threads,
                    state: w.state(leases.len(), lease_ttl, now),
                    paused: w.paused.clone(),
                    memory_limit: w.memory_limit,
                    silent_for: now.saturating_duration_since(w.last_seen),
                    leases,
                    tiles_done: w.tiles_done,
                    rays: w.rays,
                    tiles_per_s,
                    rays_per_s,
                }
            })
            .collect();
        out.sort_unstable_by_key(|w| w.id);
        out
    }

    /// Rays per second of all workers over the last few seconds.
    pub fn rays_per_second(&self, now: Instant) -> f64 {
        let sec = self.sec(now);
        self.entries
            .values()
            .map(|w| w.rate.per_second(sec).1)
            .sum()
    }

    /// Time zero of the rates.
    pub fn epoch(&self) -> Instant {
        self.epoch
    }

    /// Whole seconds from the epoch to `now` (0 before it).
    fn sec(&self, now: Instant) -> u64 {
        now.saturating_duration_since(self.epoch).as_secs()
    }
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

    #[test]
    fn a_paused_worker_is_paused_until_lost_and_busy_while_it_holds_a_lease() {
        let t0 = Instant::now();
        let mut ws = Workers::new(1);
        let a = ws.register(t0, None);
        let ttl = Duration::from_secs(10);
        ws.set_paused(a, Some(&"busy".repeat(20)));
        let list = ws.list(HashMap::new(), ttl, t0);
        assert_eq!(list[0].state, WorkerState::Paused);
        assert_eq!(list[0].paused.as_deref().map(str::len), Some(32));
        let mut held = HashMap::new();
        held.insert(a, vec![(1, Rect::new(0, 0, 1, 1))]);
        assert_eq!(ws.list(held, ttl, t0)[0].state, WorkerState::Busy);
        let late = t0 + Duration::from_secs(11);
        assert_eq!(
            ws.list(HashMap::new(), ttl, late)[0].state,
            WorkerState::Lost
        );
        ws.set_paused(a, None);
        assert_eq!(ws.list(HashMap::new(), ttl, t0)[0].state, WorkerState::Idle);
    }

    #[test]
    fn sessions_names_and_forgetting() {
        let t0 = Instant::now();
        let mut ws = Workers::new(0);
        let a = ws.register(t0, Some([1; 32]));
        let b = ws.register(t0, None);
        assert_eq!((a, b), (1, 2), "ids start at 1");
        assert_eq!(ws.session_is(a, &[1; 32]), Some(true));
        assert_eq!(ws.session_is(b, &[0; 32]), Some(false));
        assert_eq!(ws.session_is(9, &[1; 32]), None);
        ws.describe(a, &"x".repeat(100), 8);
        let later = t0 + Duration::from_secs(30);
        assert!(ws.touch(a, later));
        assert!(!ws.touch(9, later));
        assert_eq!(ws.live(Duration::from_secs(10), later), vec![a]);
        let list = ws.list(HashMap::new(), Duration::from_secs(10), later);
        assert_eq!((list[0].name.len(), list[0].threads), (64, 8));
        assert_eq!(list[1].state, WorkerState::Lost);
        ws.forget_silent(Duration::from_secs(20), later);
        assert_eq!(ws.session_is(b, &[]), None, "b was forgotten");
    }
}
