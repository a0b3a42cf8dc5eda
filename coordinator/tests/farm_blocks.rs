//! Blocklists and the tile log in the coordinator without a network: a
//! worker failing a job's tiles is kept from it and named in its status
//! with its error; its failures and the tiles rendered are in the job's
//! tile log, with retries; both survive a restart, the block going to the
//! worker of its name; an unblock by name lets it back, for good.

mod common;

use trevi_coordinator::farm::RenderedLease;
use trevi_coordinator::store::LogFilter;
use trevi_coordinator::{Farm, FarmConfig, LeaseResult, SubmitOptions, WorkerOptions};
use trevi_core::Rect;

fn pixels(r: Rect) -> Vec<[f32; 3]> {
    vec![[0.5, 0.25, 0.125]; r.pixel_count()]
}

fn worker(f: &Farm, name: &str) -> u64 {
    f.register_worker(WorkerOptions {
        name,
        threads: 1,
        ..WorkerOptions::default()
    })
    .unwrap()
    .id
}

#[test]
fn a_block_and_the_log_survive_a_restart_and_an_unblock_by_name_lets_the_worker_back() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = FarmConfig::new(dir.path());
    cfg.limits.max_worker_failures = 2;
    cfg.limits.max_tile_failures = 100;
    let f = Farm::new(cfg.clone()).unwrap();
    let job = f
        .submit(common::spec(48, 32, 16, "a.png"), SubmitOptions::default())
        .unwrap()
        .id;
    let bad = worker(&f, "bad");
    let good = worker(&f, "good");
    for n in 0..2 {
        let l = f.lease(bad).unwrap().unwrap();
        f.return_tile(bad, l.id, Some(format!("boom {n}").as_str()))
            .unwrap();
    }
    assert_eq!(f.lease(bad).unwrap(), None, "kept from its only job");
    let b = f.info(job).unwrap().blocked;
    assert_eq!(b.len(), 1, "{b:?}");
    assert_eq!(
        (b[0].name.as_str(), b[0].worker, b[0].failures),
        ("bad", Some(bad), 2)
    );
    assert!(b[0].last_error.ends_with("boom 1"), "{}", b[0].last_error);

    // good renders the tile bad failed twice.
    let l = f.lease(good).unwrap().unwrap();
    f.put_tile(LeaseResult {
        lease: l.id,
        job,
        rect: l.rect,
        rays: 7,
        pixels: &pixels(l.rect),
        worker: Some(good),
    })
    .unwrap();
    f.log_rendered(&RenderedLease {
        job,
        worker: good,
        rect: l.rect,
        tiles: 1,
        rays: 7,
        render_micros: Some(1500),
        cpu_micros: None,
    });
    let log = f.tile_log(job, LogFilter::default()).unwrap();
    let seen: Vec<(&str, Option<&str>, u32)> = log
        .entries
        .iter()
        .map(|e| (e.worker_name.as_str(), e.error.as_deref(), e.retries))
        .collect();
    assert_eq!(seen.len(), 3, "{seen:?}");
    assert!(seen[0].1.is_some_and(|e| e.contains("boom 0")), "{seen:?}");
    assert_eq!(
        (seen[2].0, seen[2].1, seen[2].2),
        ("good", None, 2),
        "{seen:?}"
    );
    drop(f);

    // After a restart: the block, by name, until a worker of that name asks.
    let f = Farm::new(cfg.clone()).unwrap();
    let b = f.info(job).unwrap().blocked;
    assert_eq!((b.len(), b[0].name.as_str(), b[0].worker), (1, "bad", None));
    assert_eq!(
        f.tile_log(job, LogFilter::default()).unwrap().entries.len(),
        3
    );
    let bad = worker(&f, "bad");
    assert_eq!(f.lease(bad).unwrap(), None, "its name's block is its own");
    assert_eq!(f.info(job).unwrap().blocked[0].worker, Some(bad));
    let e = f.unblock(job, "nobody").unwrap_err().to_string();
    assert!(e.contains("bad (worker"), "{e}");
    assert!(f.unblock(job + 1000, "bad").is_err());
    assert!(f.unblock(job, "bad").unwrap().blocked.is_empty());
    assert!(f.lease(bad).unwrap().is_some(), "let back");
    drop(f);
    // The unblock was stored too.
    let f = Farm::new(cfg).unwrap();
    assert!(f.info(job).unwrap().blocked.is_empty());
}
