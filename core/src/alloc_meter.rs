//! A counting global allocator, for the tests and benchmarks that measure
//! how much heap a piece of work takes (a parser's cost bound, the memory
//! estimate against a real build, a benchmark's memory figures).
//!
//! It counts nothing until a binary installs it:
//!
//! ```ignore
//! #[global_allocator]
//! static METER: trevi_core::alloc_meter::AllocMeter = trevi_core::alloc_meter::AllocMeter;
//! ```
//!
//! Then every allocation goes to the system allocator and is counted twice:
//! for the whole process ([`held`], [`peak`], [`reset_peak`]), which sees
//! the work of every thread (rayon's too, so nothing else may run
//! meanwhile), and for the calling thread alone ([`thread_cost`]), which
//! tests running side by side do not disturb.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};

/// The allocator: the system's, counting bytes held and the peak.
pub struct AllocMeter;

/// Bytes the process holds, and the most it held since [`reset_peak`].
static HELD: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

// Const-initialised thread-locals without destructors: safe to touch from
// inside the allocator at any time (`try_with` covers a thread's end).
thread_local! {
    static THREAD_HELD: Cell<usize> = const { Cell::new(0) };
    static THREAD_PEAK: Cell<usize> = const { Cell::new(0) };
    static THREAD_TOTAL: Cell<usize> = const { Cell::new(0) };
}

fn add(n: usize) {
    let v = HELD.fetch_add(n, Relaxed).saturating_add(n);
    PEAK.fetch_max(v, Relaxed);
    let _ = THREAD_HELD.try_with(|h| {
        let v = h.get().saturating_add(n);
        h.set(v);
        let _ = THREAD_PEAK.try_with(|p| p.set(p.get().max(v)));
    });
    let _ = THREAD_TOTAL.try_with(|t| t.set(t.get().saturating_add(n)));
}

fn sub(n: usize) {
    HELD.fetch_sub(n, Relaxed);
    let _ = THREAD_HELD.try_with(|h| h.set(h.get().saturating_sub(n)));
}

// SAFETY: every call is passed on unchanged to the system allocator, whose
// contract is the one `GlobalAlloc` asks for; the counting around it
// neither allocates nor touches the memory.
unsafe impl GlobalAlloc for AllocMeter {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        // SAFETY: the caller upholds `alloc`'s contract for `l`.
        let p = unsafe { System.alloc(l) };
        if !p.is_null() {
            add(l.size());
        }
        p
    }

    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        // SAFETY: the caller upholds `alloc_zeroed`'s contract for `l`.
        let p = unsafe { System.alloc_zeroed(l) };
        if !p.is_null() {
            add(l.size());
        }
        p
    }

    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        // SAFETY: `p` came from this allocator, that is the system's, with
        // layout `l`, as the caller guarantees.
        unsafe { System.dealloc(p, l) };
        sub(l.size());
    }

    unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
        // SAFETY: `p` came from the system allocator with layout `l`, and
        // `new` is valid for it, as the caller guarantees.
        let q = unsafe { System.realloc(p, l, new) };
        if !q.is_null() {
            sub(l.size());
            add(new);
        }
        q
    }
}

/// Bytes the process holds now.
pub fn held() -> usize {
    HELD.load(Relaxed)
}

/// The most bytes the process held since the last [`reset_peak`].
pub fn peak() -> usize {
    PEAK.load(Relaxed)
}

/// Starts a new peak from what the process holds now.
pub fn reset_peak() {
    PEAK.store(HELD.load(Relaxed), Relaxed);
}

/// What `f` costs the calling thread: its result, the bytes it allocated
/// in all, and the most bytes the thread held during it above what it held
/// before.
pub fn thread_cost<T>(f: impl FnOnce() -> T) -> (T, usize, usize) {
    let base = THREAD_HELD.with(Cell::get);
    THREAD_PEAK.with(|p| p.set(base));
    let total = THREAD_TOTAL.with(Cell::get);
    let out = f();
    (
        out,
        THREAD_TOTAL.with(Cell::get) - total,
        THREAD_PEAK.with(Cell::get) - base,
    )
}
