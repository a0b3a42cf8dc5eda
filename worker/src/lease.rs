//! Where a tile is leased and what becomes of it: each of a session's
//! `tiles_in_flight` loops takes the render threads, leases a tile, has it
//! rendered ([`crate::render`]) and then uploads it ([`crate::upload`]),
//! gives the lease back (stopped, paused, failed) or declines it (its scene
//! is bigger than `--max-memory`, [`crate::memory`]).

use crate::memory;
use crate::pass::Pass;
use crate::render::TileEnd;
use crate::session::{reconnect, span_ids, End, Me, Session};
use std::time::Duration;
use tokio::sync::watch;
use tonic::Code;
use trevi_proto::{pb, rect_from};

impl Session {
    /// One lease → render → send loop.
    pub(crate) async fn work(
        &mut self,
        me: Me,
        beat: Duration,
        poll: Duration,
        mut shutdown: watch::Receiver<bool>,
    ) -> End {
        loop {
            if *shutdown.borrow() {
                return End::Shutdown;
            }
            if self.paused.borrow_and_update().is_some() {
                // Lease nothing until the pause ends.
                tokio::select! {
                    r = self.paused.changed() => if r.is_err() { return End::Shutdown },
                    r = shutdown.changed() => if r.is_err() { return End::Shutdown },
                }
                continue;
            }
            let permit = tokio::select! {
                p = self.render.clone().acquire_owned() => match p {
                    Ok(p) => p,
                    Err(_) => return End::Shutdown,
                },
                // A closed channel: no one can stop us any more, so stop.
                r = shutdown.changed() => match r {
                    Ok(()) => continue,
                    Err(_) => return End::Shutdown,
                },
            };
            // Not interrupted by `shutdown`: a lease granted while the answer
            // is on its way would be lost until it expires. The call returns
            // within `poll`, and a tile it brings is given back at once.
            let lease = self
                .workers
                .lease_tile(pb::LeaseRequest {
                    worker_id: me.id,
                    session: me.session.clone(),
                    max_wait_ms: poll.as_millis().clamp(1, u32::MAX as u128) as u32,
                })
                .await;
            let lease = match lease {
                Ok(r) => match r.into_inner().lease {
                    Some(l) => l,
                    None => continue,
                },
                Err(s) => return reconnect("lease", s),
            };
            let rect = match rect_from(lease.rect) {
                Ok(r) => r,
                Err(e) => {
                    tracing::error!(lease = lease.lease_id, "bad lease: {e}");
                    continue;
                }
            };
            // A pass of a progressive job: its range and rect checked first.
            let pass = lease
                .samples
                .map(|r| Pass::check(lease.lease_id, rect, r))
                .transpose();
            // What the lease needs: its scene, and a pass's state.
            let needs = match pass {
                Ok(Some(_)) => lease
                    .memory_estimate
                    .saturating_add(memory::pass_state_bytes(rect)),
                _ => lease.memory_estimate,
            };
            let end = if *shutdown.borrow() {
                TileEnd::Stopped
            } else if self.paused.borrow().is_some() {
                TileEnd::Paused
            } else {
                match pass {
                    Err(e) => TileEnd::Failed(e.to_string()),
                    // The coordinator's estimate (and the state) says no:
                    // not even downloaded.
                    Ok(_) if !self.max_memory.allows(needs) => TileEnd::Declined(needs),
                    Ok(pass) => {
                        self.tile(&me, &lease, rect, pass, beat, &mut shutdown)
                            .await
                    }
                }
            };
            drop(permit);
            let (x, y, id) = (rect.x, rect.y, lease.lease_id);
            match end {
                TileEnd::Rendered(payload, rendered) => {
                    // One line per tile, also for a span of several: the
                    // logs count tiles, not leases.
                    for id in span_ids(&lease) {
                        tracing::debug!(lease = id, job = lease.job_id, x, y, "tile rendered");
                    }
                    if let Err(s) = self.send(&me, &lease, rect, rendered, payload).await {
                        if s.code() == Code::InvalidArgument {
                            tracing::error!(lease = id, "tile rejected: {}", s.message());
                        } else {
                            return reconnect("sending a tile", s);
                        }
                    }
                }
                TileEnd::Dropped => {
                    tracing::info!(
                        lease = id,
                        x,
                        y,
                        "lease dropped by the coordinator; render cancelled"
                    );
                    // The other tiles of a span may still be ours.
                    if lease.tiles > 1 {
                        for id in span_ids(&lease) {
                            self.give_back(&me, id, String::new()).await;
                        }
                    }
                }
                TileEnd::Stopped => {
                    tracing::info!(
                        lease = id,
                        x,
                        y,
                        "stopping: render cancelled, lease given back"
                    );
                    for id in span_ids(&lease) {
                        self.give_back(&me, id, String::new()).await;
                    }
                    return End::Shutdown;
                }
                TileEnd::Paused => {
                    tracing::info!(
                        lease = id,
                        x,
                        y,
                        "paused: render cancelled, lease given back"
                    );
                    for id in span_ids(&lease) {
                        self.give_back(&me, id, String::new()).await;
                    }
                }
                TileEnd::Declined(needs) => {
                    tracing::warn!(
                        lease = id,
                        "{}",
                        memory::declined(lease.job_id, needs, self.max_memory)
                    );
                    for id in span_ids(&lease) {
                        self.decline(&me, id, needs).await;
                    }
                }
                TileEnd::Lost(s) => {
                    // The connection (or the session) is gone: the lease
                    // runs out on the coordinator, like the others.
                    return reconnect("fetching a tile's state", s);
                }
                TileEnd::Failed(why) => {
                    tracing::error!(lease = id, job = lease.job_id, x, y, "tile failed: {why}");
                    for id in span_ids(&lease) {
                        self.give_back(&me, id, why.clone()).await;
                    }
                    // Do not take the next tile of a broken job in a tight loop.
                    tokio::select! {
                        _ = tokio::time::sleep(Duration::from_secs(1)) => {}
                        _ = shutdown.changed() => {}
                    }
                }
            }
        }
    }

    /// Returns a lease unfinished (`error` empty: unrendered, no fault).
    async fn give_back(&mut self, me: &Me, lease: u64, error: String) {
        let r = self
            .workers
            .return_tile(pb::TileReturn {
                worker_id: me.id,
                session: me.session.clone(),
                lease_id: lease,
                error,
                memory_needed: 0,
            })
            .await;
        if let Err(s) = r {
            // The lease then runs out on its own.
            tracing::warn!(lease, "cannot give the lease back: {}", s.message());
        }
    }

    /// Declines a lease: its scene needs about `needs` bytes, more than
    /// `--max-memory` (not a failure; the coordinator leases the job to
    /// workers that can hold it).
    async fn decline(&mut self, me: &Me, lease: u64, needs: u64) {
        let r = self
            .workers
            .return_tile(pb::TileReturn {
                worker_id: me.id,
                session: me.session.clone(),
                lease_id: lease,
                error: String::new(),
                memory_needed: needs.max(1),
            })
            .await;
        if let Err(s) = r {
            tracing::warn!(lease, "cannot decline the lease: {}", s.message());
        }
    }
}
