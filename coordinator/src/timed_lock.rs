//! A mutex that counts how long it has been held: the coordinator's two
//! shared locks, the farm's state and the store's database, are the part
//! of its work that cannot spread over cores. With `h` seconds held a
//! second, ingest can use at most `1/h` cores however many it has
//! (`trevi_state_lock_held_seconds_total`,
//! `trevi_store_lock_held_seconds_total`; docs/benchmarks.md, "Stage 6").

use std::ops::{Deref, DerefMut};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// A value behind a mutex, with the time it has been held.
pub struct TimedLock<T> {
    value: Mutex<T>,
    held_ns: AtomicU64,
}

/// The lock, held: derefs to the value; dropping it adds the time since it
/// was taken (not the wait before) to the lock's total.
pub struct Held<'a, T> {
    guard: MutexGuard<'a, T>,
    since: Instant,
    held_ns: &'a AtomicU64,
}

impl<T> TimedLock<T> {
    /// `value` behind a lock not yet held.
    pub fn new(value: T) -> Self {
        TimedLock {
            value: Mutex::new(value),
            held_ns: AtomicU64::new(0),
        }
    }

    /// Takes the lock. A panic while holding it is a bug; the state is
    /// served as it is rather than poisoning every later call.
    pub fn lock(&self) -> Held<'_, T> {
        let guard = self.value.lock().unwrap_or_else(|p| p.into_inner());
        Held {
            guard,
            since: Instant::now(),
            held_ns: &self.held_ns,
        }
    }

    /// How long the lock has been held in all, since the start.
    pub fn held(&self) -> Duration {
        Duration::from_nanos(self.held_ns.load(Ordering::Relaxed))
    }
}

impl<T> Deref for Held<'_, T> {
    type Target = T;
    fn deref(&self) -> &T {
        &self.guard
    }
}

impl<T> DerefMut for Held<'_, T> {
    fn deref_mut(&mut self) -> &mut T {
        &mut self.guard
    }
}

impl<T> Drop for Held<'_, T> {
    fn drop(&mut self) {
        let ns = u64::try_from(self.since.elapsed().as_nanos()).unwrap_or(u64::MAX);
        self.held_ns.fetch_add(ns, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The total is the time held, measured apart around each hold, and
    /// leaves out the time spent waiting for the lock.
    #[test]
    fn the_total_is_the_time_held_not_the_wait() {
        let lock = std::sync::Arc::new(TimedLock::new(0u32));
        assert_eq!(lock.held(), Duration::ZERO);
        let outside = Instant::now();
        {
            let mut v = lock.lock();
            *v += 1;
            std::thread::sleep(Duration::from_millis(30));
        }
        let first = lock.held();
        assert!(first >= Duration::from_millis(30), "{first:?}");
        assert!(first <= outside.elapsed(), "{first:?}");
        // Another thread waits for it while this one holds it. Every bound
        // below is measured, none is a fixed time, so a busy machine only
        // loosens them: the hold is at least what this thread measured
        // inside it, and at most this thread's hold measured outside plus
        // the other's from the moment this one let go (it cannot have had
        // the lock earlier). Counting the other's wait would add the time
        // it waited before that moment, at least the sleep below.
        let before_lock = Instant::now();
        let held = lock.lock();
        let after_lock = Instant::now();
        let (asking, asked) = std::sync::mpsc::channel();
        let other = {
            let lock = lock.clone();
            std::thread::spawn(move || {
                asking.send(()).unwrap();
                *lock.lock() += 1;
                Instant::now()
            })
        };
        asked.recv().unwrap();
        std::thread::sleep(Duration::from_millis(100));
        let before_release = Instant::now();
        drop(held);
        let after_release = Instant::now();
        let other_done = other.join().unwrap();
        let added = lock.held() - first;
        let at_least = before_release - after_lock;
        let at_most = (after_release - before_lock) + (other_done - before_release);
        assert!(added >= at_least, "{added:?} < {at_least:?}");
        assert!(
            added <= at_most,
            "{added:?} > {at_most:?}: the wait was counted"
        );
        assert_eq!(*lock.lock(), 2);
    }
}
