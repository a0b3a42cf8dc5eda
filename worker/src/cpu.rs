//! The CPU time of the render threads ([`RenderClocks`]): what a result's
//! `TileHeader.cpu_micros` says the worker spent on it, the figure of the
//! coordinator's usage history (docs/farm.md, "Usage history").
//!
//! Every render thread registers its own CPU clock as it starts
//! (`pthread_getcpuclockid`, Linux); the worker reads the sum of those
//! clocks before and after a lease's work. Only one lease has the render
//! threads at a time (`Session::render`, one permit), and everything a
//! lease computes runs on them: the scene's build, a pass's state decoded,
//! the render, the PNG segments encoded. So the difference is that lease's
//! CPU time, whatever the other loops do meanwhile (uploading, which runs on
//! the async threads and is not counted; tests/tests/usage.rs measures how
//! much that leaves out of the process's own counters).
//!
//! Elsewhere than Linux the figure is not measured: results carry none, as
//! an older worker's do.

use std::sync::{Arc, Mutex};
use std::time::Duration;

/// The render threads' CPU clocks, shared by the pool's start handler and
/// the loops that read them.
#[derive(Clone, Default)]
pub(crate) struct RenderClocks {
    #[cfg_attr(not(target_os = "linux"), allow(dead_code))]
    clocks: Arc<Mutex<Vec<Clock>>>,
}

#[cfg(target_os = "linux")]
type Clock = libc::clockid_t;
#[cfg(not(target_os = "linux"))]
type Clock = ();

impl RenderClocks {
    /// Registers the calling thread's CPU clock: called by each render
    /// thread as it starts.
    pub(crate) fn register_this_thread(&self) {
        #[cfg(target_os = "linux")]
        {
            let mut id: libc::clockid_t = 0;
            // SAFETY: `pthread_self` is the calling thread, which is alive;
            // `id` is a valid place for the clock id.
            let r = unsafe { libc::pthread_getcpuclockid(libc::pthread_self(), &mut id) };
            if r == 0 {
                self.clocks
                    .lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .push(id);
            } else {
                tracing::warn!("no CPU clock for a render thread (error {r}): usage not measured");
            }
        }
    }

    /// The CPU time all render threads have spent so far; `None` where it
    /// cannot be measured (not Linux, or a clock could not be read).
    pub(crate) fn total(&self) -> Option<Duration> {
        #[cfg(target_os = "linux")]
        {
            let clocks = self.clocks.lock().unwrap_or_else(|p| p.into_inner());
            if clocks.is_empty() {
                return None;
            }
            let mut sum = Duration::ZERO;
            for &c in clocks.iter() {
                let mut ts = libc::timespec {
                    tv_sec: 0,
                    tv_nsec: 0,
                };
                // SAFETY: `ts` is a valid place for the time; `c` is the
                // clock of a render thread, which lives as long as the pool
                // (a clock of a thread gone is refused, not undefined).
                if unsafe { libc::clock_gettime(c, &mut ts) } != 0 {
                    return None;
                }
                sum += Duration::new(ts.tv_sec as u64, ts.tv_nsec as u32);
            }
            Some(sum)
        }
        #[cfg(not(target_os = "linux"))]
        None
    }
}

/// Measures the render threads' CPU time over one lease's work.
pub(crate) struct CpuMeter<'a> {
    clocks: &'a RenderClocks,
    start: Option<Duration>,
}

impl<'a> CpuMeter<'a> {
    /// Starts measuring now.
    pub(crate) fn start(clocks: &'a RenderClocks) -> Self {
        CpuMeter {
            clocks,
            start: clocks.total(),
        }
    }

    /// The CPU time since [`CpuMeter::start`], in microseconds.
    pub(crate) fn micros(&self) -> Option<u64> {
        let (start, end) = (self.start?, self.clocks.total()?);
        Some(
            end.saturating_sub(start)
                .as_micros()
                .min(u128::from(u64::MAX)) as u64,
        )
    }
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    /// Work spun on the pool's threads shows in their clocks, and not the
    /// work of a thread outside the pool.
    #[test]
    fn counts_the_pool_threads_only() {
        let clocks = RenderClocks::default();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .start_handler({
                let c = clocks.clone();
                move |_| c.register_this_thread()
            })
            .build()
            .unwrap();
        // Wait for both threads to have registered (a state, not a time).
        pool.broadcast(|_| ());
        assert_eq!(clocks.clocks.lock().unwrap().len(), 2);
        let spin = |d: Duration| {
            let t = std::time::Instant::now();
            let mut x = 0u64;
            while t.elapsed() < d {
                x = std::hint::black_box(x.wrapping_add(1));
            }
        };
        let meter = CpuMeter::start(&clocks);
        // Outside the pool: not counted.
        let outside = cpu_of_this_thread();
        spin(Duration::from_millis(200));
        let outside = cpu_of_this_thread() - outside;
        let inside_before = meter.micros().unwrap();
        // Inside: counted (at least the CPU the threads themselves saw).
        let seen: Vec<Duration> = pool.broadcast(|_| {
            let t0 = cpu_of_this_thread();
            spin(Duration::from_millis(100));
            cpu_of_this_thread() - t0
        });
        let inside = meter.micros().unwrap() - inside_before;
        let seen: u64 = seen.iter().map(|d| d.as_micros() as u64).sum();
        assert!(
            inside_before < outside.as_micros() as u64 / 4,
            "{inside_before} µs counted while only a thread outside the pool worked"
        );
        assert!(inside >= seen, "{inside} µs counted, {seen} µs spent");
    }

    fn cpu_of_this_thread() -> Duration {
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: `ts` is a valid place for the time.
        unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
        Duration::new(ts.tv_sec as u64, ts.tv_nsec as u32)
    }
}
