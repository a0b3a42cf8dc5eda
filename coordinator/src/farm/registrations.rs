//! Bounds on worker registration: at most [`Limits::max_workers`] workers
//! registered at once, and [`Limits::max_workers_per_address`] from one
//! client address (unbounded, 40,000 `Register` calls took 76 MB, made an
//! 11 MB `/api/state` and 40,000 Prometheus series). A registration that
//! is never followed by another call is forgotten after a tenth of the
//! silence that forgets a worker (see [`crate::workers::Workers`]), so
//! registering and leaving holds a place only briefly. In-process callers
//! (an empty address) are not counted per address.
//!
//! [`Limits::max_workers`]: crate::limits::Limits::max_workers
//! [`Limits::max_workers_per_address`]: crate::limits::Limits::max_workers_per_address

use super::State;
use crate::error::{FarmError, LimitKind};
use crate::scheduler::{Scheduler, WorkerId};
use std::collections::{HashMap, HashSet};

/// Which address each registered worker came from.
#[derive(Debug, Default)]
pub(super) struct Registrations {
    by_addr: HashMap<String, HashSet<WorkerId>>,
    addr_of: HashMap<WorkerId, String>,
}

impl Registrations {
    /// Forgets the workers of `addr` (all addresses: `None`) the scheduler
    /// forgot.
    fn prune(&mut self, sched: &Scheduler, addr: Option<&str>) {
        let known = |w: &WorkerId| sched.session_is(*w, &[]).is_some();
        match addr {
            Some(a) => {
                if let Some(set) = self.by_addr.get_mut(a) {
                    let gone: Vec<WorkerId> = set.iter().copied().filter(|w| !known(w)).collect();
                    for w in gone {
                        set.remove(&w);
                        self.addr_of.remove(&w);
                    }
                    if set.is_empty() {
                        self.by_addr.remove(a);
                    }
                }
            }
            None => {
                let gone: Vec<WorkerId> =
                    self.addr_of.keys().copied().filter(|w| !known(w)).collect();
                for w in gone {
                    if let Some(a) = self.addr_of.remove(&w) {
                        if let Some(set) = self.by_addr.get_mut(&a) {
                            set.remove(&w);
                            if set.is_empty() {
                                self.by_addr.remove(&a);
                            }
                        }
                    }
                }
            }
        }
    }

    fn record(&mut self, worker: WorkerId, addr: &str) {
        self.by_addr
            .entry(addr.to_string())
            .or_default()
            .insert(worker);
        self.addr_of.insert(worker, addr.to_string());
    }
}

impl State {
    /// Refuses a registration from `addr` when it has
    /// `per_address` workers registered, or the farm `total`.
    pub(super) fn check_registration(
        &mut self,
        addr: &str,
        total: usize,
        per_address: usize,
    ) -> Result<(), FarmError> {
        let r = &mut self.registrations;
        if !addr.is_empty() && r.by_addr.get(addr).map_or(0, HashSet::len) >= per_address {
            r.prune(&self.sched, Some(addr));
            let n = r.by_addr.get(addr).map_or(0, HashSet::len);
            if n >= per_address {
                return Err(FarmError::limit(
                    LimitKind::WorkersPerAddress,
                    n as u64,
                    per_address as u64,
                    format!(
                        "{addr} already has {n} workers registered, the coordinator's limit \
                     (--max-workers-per-address); a worker that stops calling is forgotten"
                    ),
                ));
            }
        }
        if r.addr_of.len() >= total {
            r.prune(&self.sched, None);
            let n = r.addr_of.len();
            if n >= total {
                return Err(FarmError::limit(
                    LimitKind::Workers,
                    n as u64,
                    total as u64,
                    format!(
                        "{n} workers are registered, the coordinator's limit (--max-workers); a \
                     worker that stops calling is forgotten"
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Counts worker `worker`, registered from `addr`.
    pub(super) fn registered(&mut self, worker: WorkerId, addr: &str) {
        self.registrations.record(worker, addr);
    }
}
