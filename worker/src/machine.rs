//! The machine watcher: the task that samples the machine's load and the
//! clock every `--sample-ms` and publishes the [`Pause`] the rules of
//! [`crate::pause`] decide, and the loop that tells the coordinator about
//! it. The render loops ([`crate::lease`], [`crate::render`]) stop their
//! tiles and hand the leases back when it turns to paused, and lease
//! nothing until it turns back.

use crate::pause::{self, Pause, PauseConfig};
use crate::session::{End, Me, Session};
use std::time::Duration;
use tokio::sync::watch;
use trevi_proto::pb;

/// Starts watching the machine as `cfg` says; the receiver tells why the
/// worker should step aside (never anything when nothing is watched).
/// Every change is logged, with its reason.
pub(crate) fn watch_the_machine(
    cfg: &PauseConfig,
    shutdown: watch::Receiver<bool>,
) -> watch::Receiver<Option<Pause>> {
    watch_with(cfg, Box::new(pause::input::ProcInterrupts), shutdown)
}

/// [`watch_the_machine`] with the keyboard and mouse activity read from
/// `input` (tests give a source of their own).
pub(crate) fn watch_with(
    cfg: &PauseConfig,
    mut input: Box<dyn pause::input::InputSource>,
    mut shutdown: watch::Receiver<bool>,
) -> watch::Receiver<Option<Pause>> {
    let (tx, rx) = watch::channel(None);
    if !cfg.watches() {
        // Nothing will change; the channel stays open until the end.
        tokio::spawn(async move {
            let _ = shutdown.wait_for(|&s| s).await;
            drop(tx);
        });
        return rx;
    }
    let cores = pause::read_proc_stat()
        .map(|s| pause::count_cores(&s))
        .unwrap_or(0)
        .max(1);
    if cfg.yield_when_busy && pause::sample_now().is_none() {
        tracing::warn!("--yield-when-busy: cannot read /proc/stat and /proc/self/stat; the load is not watched");
    }
    let watch_input = cfg.watches_input();
    if watch_input && input.activity().is_none() {
        tracing::warn!("--idle-after: cannot read the keyboard and mouse activity (/proc/interrupts); input is not watched");
    }
    let mut watcher = pause::Watcher::new(cfg.clone(), cores);
    let (every, quiet, hours, idle) = (cfg.sample, cfg.quiet_for, cfg.active_hours, cfg.idle_after);
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(every);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tokio::select! {
                _ = tick.tick() => {}
                _ = shutdown.changed() => return,
            }
            let now = std::time::Instant::now();
            let activity = if watch_input { input.activity() } else { None };
            let p = watcher.step(now, pause::sample_now(), activity, pause::local_minute());
            let was = *tx.borrow();
            if was.map(|w| w.reason()) == p.map(|p| p.reason()) {
                continue;
            }
            match (&was, &p) {
                (_, Some(p)) => tracing::info!(
                    reason = p.reason(),
                    "paused ({p}): in-flight tiles handed back, no new ones until it ends"
                ),
                (Some(Pause::Busy { .. }), None) => tracing::info!(
                    "resumed: the machine has been quiet for {} s",
                    quiet.as_secs_f64()
                ),
                (Some(Pause::OutsideHours), None) => tracing::info!(
                    "resumed: within the active hours {}",
                    hours.map(|h| h.to_string()).unwrap_or_default()
                ),
                (Some(Pause::InUse { .. }), None) => tracing::info!(
                    "resumed: no keyboard or mouse input for {} s",
                    idle.map_or(0.0, |d| d.as_secs_f64())
                ),
                (None, None) => {}
            }
            if tx.send(p).is_err() {
                return;
            }
        }
    });
    rx
}

impl Session {
    /// Tells the coordinator why the worker is paused, at once and then
    /// every `beat` while it is (a paused worker leases nothing, so this
    /// keeps it alive in the coordinator's list and shows the reason).
    pub(crate) async fn report_pauses(
        &mut self,
        me: Me,
        beat: Duration,
        mut shutdown: watch::Receiver<bool>,
    ) -> End {
        let mut tick = tokio::time::interval(beat);
        loop {
            let reason = self.pause_reason();
            if !reason.is_empty() {
                let hb = self
                    .workers
                    .heartbeat(pb::HeartbeatRequest {
                        worker_id: me.id,
                        lease_ids: Vec::new(),
                        session: me.session.clone(),
                        paused: reason,
                    })
                    .await;
                if let Err(s) = hb {
                    tracing::warn!("heartbeat failed: {}", s.message());
                }
            }
            tokio::select! {
                _ = tick.tick() => {}
                r = self.paused.changed() => if r.is_err() {
                    // Nothing is watched (any more): nothing to report.
                    let _ = shutdown.wait_for(|&s| s).await;
                    return End::Shutdown;
                },
                r = shutdown.changed() => if r.is_err() || *shutdown.borrow() { return End::Shutdown },
            }
        }
    }

    /// The reason the coordinator is told (empty: working).
    fn pause_reason(&self) -> String {
        self.paused
            .borrow()
            .map(|p| p.reason().to_string())
            .unwrap_or_default()
    }
}
