//! The usage history without a network: accepted results counted under
//! their job, submitter and worker, kept after the job is forgotten and
//! across a restart, and the same in a farm without a database.

mod common;

use std::time::Duration;
use trevi_coordinator::farm::Retention;
use trevi_coordinator::scheduler::Lease;
use trevi_coordinator::usage::{UsageBy, UsageQuery};
use trevi_coordinator::{Farm, FarmConfig, LeaseResult, SubmitOptions, TileOutcome, WorkerOptions};

fn query(by: UsageBy) -> UsageQuery {
    UsageQuery {
        since: Duration::from_secs(3600),
        by,
    }
}

/// Renders `job` (black pixels) with worker `w`, counting each accepted
/// result as the gRPC service does: `cpu` microseconds each.
fn render_all(f: &Farm, w: u64, cpu: Option<u64>) {
    let leases: Vec<Lease> = std::iter::from_fn(|| f.lease(w).unwrap()).collect();
    for l in leases {
        let px = vec![[0.0f32; 3]; l.rect.pixel_count()];
        let r = LeaseResult {
            lease: l.id,
            job: l.job,
            rect: l.rect,
            rays: 10,
            pixels: &px,
            worker: Some(w),
        };
        assert_eq!(f.put_tile(r).unwrap(), TileOutcome::Accepted);
        f.count_usage(l.job, w, cpu, 1, 10);
    }
}

#[test]
fn usage_is_kept_after_the_job_is_forgotten_and_across_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = FarmConfig {
        retention: Retention {
            keep_ended: 1,
            ..Retention::default()
        },
        ..FarmConfig::new(dir.path())
    };
    {
        let f = Farm::new(cfg.clone()).unwrap();
        let w = f
            .register_worker(WorkerOptions {
                name: "render-01",
                threads: 1,
                ..WorkerOptions::default()
            })
            .unwrap()
            .id;
        let from = SubmitOptions {
            who: "10.1.2.3",
            ..SubmitOptions::default()
        };
        let a = f
            .submit(common::spec(32, 16, 16, "a.png"), from)
            .unwrap()
            .id;
        render_all(&f, w, Some(1_500_000));
        // Downloaded, so the count of --keep-ended may forget it once
        // another job ends.
        f.fetched(a, None);
        let b = f
            .submit(common::spec(16, 16, 16, "b.png"), SubmitOptions::default())
            .unwrap()
            .id;
        render_all(&f, w, None);
        assert!(f.info(a).is_err(), "job {a} is forgotten");
        let jobs = f.usage(&query(UsageBy::Job)).unwrap();
        let row = jobs.rows.iter().find(|r| r.key == a.to_string()).unwrap();
        assert_eq!(
            (row.agg.cpu_micros, row.agg.tiles, row.agg.unmeasured),
            (3_000_000, 2, 0)
        );
        assert!(row.wall_ms.is_some(), "{row:?}");
        let unmeasured = jobs.rows.iter().find(|r| r.key == b.to_string()).unwrap();
        assert_eq!(
            (unmeasured.agg.cpu_micros, unmeasured.agg.unmeasured),
            (0, 1)
        );
        let subs = f.usage(&query(UsageBy::Submitter)).unwrap();
        let keys: Vec<&str> = subs.rows.iter().map(|r| r.key.as_str()).collect();
        assert_eq!(keys, ["10.1.2.3", "local"]);
        let workers = f.usage(&query(UsageBy::Worker)).unwrap();
        assert_eq!(workers.rows.len(), 1);
        assert_eq!(workers.rows[0].key, "render-01");
        assert_eq!(workers.rows[0].agg.tiles, 3);
        let charted: u64 = workers.buckets.iter().map(|b| b.1).sum();
        assert_eq!(charted, 3_000_000);
    }
    // A restart reads the same history back.
    let f = Farm::new(cfg).unwrap();
    let workers = f.usage(&query(UsageBy::Worker)).unwrap();
    assert_eq!(workers.rows[0].agg.cpu_micros, 3_000_000);
}

#[test]
fn a_farm_without_a_database_keeps_its_usage_in_memory() {
    let dir = tempfile::tempdir().unwrap();
    let f = Farm::new(FarmConfig {
        durable: false,
        ..FarmConfig::new(dir.path())
    })
    .unwrap();
    let w = f.register_worker(WorkerOptions::default()).unwrap().id;
    f.submit(common::spec(16, 16, 16, "a.png"), SubmitOptions::default())
        .unwrap();
    render_all(&f, w, Some(42));
    let workers = f.usage(&query(UsageBy::Worker)).unwrap();
    assert_eq!(workers.rows.len(), 1);
    assert_eq!(workers.rows[0].key, format!("worker {w}"));
    assert_eq!(workers.rows[0].agg.cpu_micros, 42);
    assert!(!dir.path().join("state.db").exists());
}
