//! The farm's own periodic work while it serves: re-queueing the tiles whose
//! leases ran out ([`Farm::expire`], a few times per lease lifetime) and
//! removing bundles no job uses once past their grace period
//! ([`Farm::collect_bundles`], first at start-up), and writing the usage
//! history gathered ([`Farm::flush_usage`], every
//! [`FLUSH_EVERY`](crate::usage::FLUSH_EVERY)).

use super::Farm;
use std::sync::Arc;
use std::time::Duration;
use tokio::task::JoinHandle;

/// The farm's periodic tasks; they stop when this is dropped.
pub struct Upkeep {
    tasks: Vec<JoinHandle<()>>,
}

impl Drop for Upkeep {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
    }
}

impl Farm {
    /// Starts the lease reaper, the bundle collector and the usage flusher
    /// on the current tokio runtime.
    pub fn start_upkeep(self: &Arc<Self>) -> Upkeep {
        let reaper = {
            let farm = self.clone();
            let period = (farm.cfg.limits.lease_ttl / 4).max(Duration::from_millis(20));
            tokio::spawn(async move {
                let mut tick = tokio::time::interval(period);
                loop {
                    tick.tick().await;
                    farm.expire();
                }
            })
        };
        let collector = {
            let farm = self.clone();
            let period = (farm.cfg.retention.bundle_grace / 4)
                .clamp(Duration::from_millis(100), Duration::from_secs(600));
            tokio::spawn(async move {
                let mut tick = tokio::time::interval(period);
                loop {
                    tick.tick().await;
                    let farm = farm.clone();
                    let _ = tokio::task::spawn_blocking(move || farm.collect_bundles()).await;
                }
            })
        };
        let usage = {
            let farm = self.clone();
            tokio::spawn(async move {
                let mut tick = tokio::time::interval(crate::usage::FLUSH_EVERY);
                loop {
                    tick.tick().await;
                    let farm = farm.clone();
                    let _ = tokio::task::spawn_blocking(move || farm.flush_usage()).await;
                }
            })
        };
        Upkeep {
            tasks: vec![reaper, collector, usage],
        }
    }
}

impl Farm {
    /// Removes the bundles no job uses that are older than
    /// [`super::Retention::bundle_grace`]; returns how many went.
    ///
    /// A job uses its bundle as long as the farm keeps it, ended or not: an
    /// ended job may still be extended, retried or requeued, which renders
    /// from the same bundle. So a sequence's or a progressive job's bundle
    /// stays until retention forgets the job itself, not only its frame or
    /// pass jobs (which `--keep-ended` counts apart and forgets sooner).
    pub fn collect_bundles(&self) -> usize {
        let mut keep: std::collections::HashSet<String> = self
            .list()
            .into_iter()
            .map(|j| j.spec.bundle_hash)
            .collect();
        keep.extend(
            self.state
                .lock()
                .seqs
                .values()
                .map(|s| s.spec.bundle_hash.clone()),
        );
        self.bundles.collect(&keep, self.cfg.retention.bundle_grace)
    }
}
