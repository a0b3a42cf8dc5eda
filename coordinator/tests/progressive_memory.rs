//! A big progressive job's memory on the coordinator: the accumulation
//! states of a pass (64 bytes a pixel) and the frame's pixels go through
//! the coordinator lease by lease, to and from its disk, and are never held
//! whole. The coordinator is driven in this process by a stand-in worker
//! that costs next to nothing (it writes valid states of one sample a pass
//! without rendering), through the same calls a worker's RPCs make: lease,
//! fetch the state to continue (a later pass), put the new state, put the
//! tile. The heap's peak (every allocation of the process, counted by
//! `trevi_core::alloc_meter`) and the resident peak (`VmHWM`, reset before
//! the job) must stay below an eighth of one pass's states.
//!
//! The edge is 2048 pixels (one pass's states: 256 MiB; the frame's RGB
//! `f32` pixels: 48 MiB): measured 5.0 s for the test on this two-core
//! machine under a load of about 9 (`cargo test -p trevi-coordinator --test
//! progressive_memory -- --nocapture`: heap peak 9 MiB, resident peak
//! +10 MiB). The per-pass cost grows with the pixels (about 140–250 ns a
//! pixel a pass in a release build) and 8192² writes 8 GiB of state files,
//! so the default stays at 2048² for `cargo test --workspace`;
//! `TREVI_MEMORY_EDGE=8192` runs it at that size: measured 2026-11-28 under
//! a load of about 10 (`TREVI_MEMORY_EDGE=8192 cargo test --workspace
//! --test progressive_memory -- --nocapture`): 32 768 leases over 2 passes,
//! heap peak 19 MiB, resident peak +23 MiB against a bound of 512 MiB (one
//! pass's states: 4096 MiB), 204 s. bench/progressive.py measures the
//! processes of a real farm at 4096² and 8192².

use std::sync::atomic::{AtomicBool, Ordering};
use trevi_coordinator::farm::progressive::Progressive;
use trevi_coordinator::{Farm, FarmConfig, JobSpec, JobState, LeaseResult, WorkerOptions};
use trevi_core::alloc_meter::{self, AllocMeter};
use trevi_core::passes::{TileState, HEADER_BYTES, PIXEL_BYTES};
use trevi_core::Rect;

#[global_allocator]
static METER: AllocMeter = AllocMeter;

/// The frame's edge in pixels, unless `TREVI_MEMORY_EDGE` says otherwise.
const EDGE: u32 = 2048;

fn edge() -> u32 {
    std::env::var("TREVI_MEMORY_EDGE")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(EDGE)
}

/// A state of `rect` after samples `0..next`, every pixel with `next`
/// samples of 0.5 (a valid encoding: `TileState::decode` takes it), with
/// its finished pixels.
fn state(rect: Rect, next: u32) -> (Vec<u8>, Vec<[f32; 3]>) {
    let n = f64::from(next);
    let mut pixel = [0u8; PIXEL_BYTES];
    // block (3 × f32): the open block's sum is unused here, zero.
    pixel[12..16].copy_from_slice(&next.to_le_bytes());
    for c in 0..3 {
        let at = 16 + 8 * c;
        pixel[at..at + 8].copy_from_slice(&(0.5 * n).to_le_bytes());
        let at = 40 + 8 * c;
        pixel[at..at + 8].copy_from_slice(&(0.25 * n).to_le_bytes());
    }
    let pixels = rect.w as usize * rect.h as usize;
    let mut bytes = Vec::with_capacity(HEADER_BYTES + PIXEL_BYTES * pixels);
    bytes.extend_from_slice(&TileState::encode_header(rect, next));
    for _ in 0..pixels {
        bytes.extend_from_slice(&pixel);
    }
    (bytes, vec![[0.5; 3]; pixels])
}

fn rss_peak_kib() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .expect("VmHWM in /proc/self/status")
}

#[test]
fn a_big_progressive_job_s_states_never_sit_whole_in_memory() {
    let edge = edge();
    let dir = tempfile::tempdir().unwrap();
    let farm = Farm::new(FarmConfig::new(dir.path())).unwrap();
    let spec = JobSpec {
        frame: None,
        bundle_hash: "0".repeat(64),
        camera: "cam".into(),
        priority: 0,
        width: edge,
        height: edge,
        tile_size: 64,
        output_name: "big.exr".into(),
        scene: String::new(),
        submitter: String::new(),
        samples: None,
        aovs: trevi_core::Aovs::NONE,
    };
    // Two passes of one sample: the second reads the first's states back.
    let p = Progressive {
        samples: 2,
        pass: 1,
        ..Default::default()
    };
    // What was held before the job: the meter counts from here.
    let base = alloc_meter::held();
    alloc_meter::reset_peak();
    // Writing 5 to clear_refs resets VmHWM to the resident size now.
    std::fs::write("/proc/self/clear_refs", "5").expect("reset VmHWM");
    let rss_before = rss_peak_kib();
    let job = farm.submit_progressive(spec, p, "test").unwrap().id;
    let worker = farm.register_worker(WorkerOptions::default()).unwrap().id;
    let read_back = AtomicBool::new(false);
    let (mut leases, mut served) = (0u64, 0u64);
    while let Some(l) = farm.lease(worker).unwrap() {
        let r = l.samples.expect("a pass's lease names its samples");
        if r.start > 0 {
            // A later pass: the state the worker continues, as FetchState
            // streams it.
            let (file, rect, next) = farm.state_source(worker, l.id).unwrap();
            file.read_encoded(rect, next, |chunk| {
                served += chunk.len() as u64;
                Ok(())
            })
            .unwrap();
            read_back.store(true, Ordering::Relaxed);
        }
        let (bytes, pixels) = state(l.rect, r.end);
        farm.put_state(l.job, l.rect, &[l.rect], Some(&bytes))
            .unwrap();
        farm.put_tile(LeaseResult {
            lease: l.id,
            job: l.job,
            rect: l.rect,
            rays: 1,
            pixels: &pixels,
            worker: Some(worker),
        })
        .unwrap();
        leases += 1;
    }
    let info = farm.info(job).unwrap();
    assert_eq!(info.state, JobState::Done, "{info:?}");
    let pixels = u64::from(edge) * u64::from(edge);
    // Every pixel's state was served once, to the second pass.
    assert!(read_back.load(Ordering::Relaxed));
    assert!(
        served >= pixels * PIXEL_BYTES as u64,
        "{served} bytes served"
    );
    let heap = alloc_meter::peak().saturating_sub(base) as u64;
    let rss = rss_peak_kib().saturating_sub(rss_before) * 1024;
    let states = pixels * PIXEL_BYTES as u64;
    let bound = states / 8;
    eprintln!(
        "{edge}x{edge}, {leases} leases over 2 passes: heap peak {} MiB, resident peak +{} MiB; \
         one pass's states {} MiB, bound {} MiB",
        heap >> 20,
        rss >> 20,
        states >> 20,
        bound >> 20
    );
    assert!(heap < bound, "heap peak {heap} bytes, bound {bound}");
    assert!(
        rss < bound,
        "resident peak grew by {rss} bytes, bound {bound}"
    );
    // The image is whole: every tile of the last pass reached the output.
    let out = farm.output_file(job).unwrap();
    assert!(std::fs::metadata(out).unwrap().len() > 0);
}
