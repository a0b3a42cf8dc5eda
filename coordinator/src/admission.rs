//! Admitting a job: the bounds on what the coordinator reads of a stored
//! bundle's scene before it queues a job on it (the reading itself is
//! [`crate::summaries::summarize`]).
//!
//! The coordinator never builds a scene (workers do). To admit a job it
//! needs the cameras (id, frame size, supersampling, output) and the
//! scene's memory estimate, which it reads with the headers-only parse
//! ([`trevi_core::scene::aisxml::parse_scene_headers`]): the scene file is
//! checked in full, but of meshes only their counts are read and of
//! textures only the headers of every part (never a pixel), so a 400 KB PNG
//! claiming 4096² costs a header read here, not the 256 MiB its decoded MIP
//! chain takes. The estimate it gives is at least the full parse's (see
//! [`trevi_core::scene::estimate::estimate_sized`]); what is wrong inside a
//! mesh's or an image's data is found by the worker's full parse, which
//! fails the job with a located error.
//!
//! Bounds (both `RESOURCE_EXHAUSTED` with the flag's name when reached):
//! at most [`Limits::max_admissions`] bundles are
//! read and parsed at once, and together they may hold at most
//! [`Limits::admission_bytes`], each counted at [`admission_cost`] of its
//! bundle's size (one admission is always let through when none runs, so
//! the largest bundle the coordinator accepts can always be admitted). The
//! count is checked before anything is read, the memory once the stored
//! file is read (at most `--max-bundle-mib` for each admission in
//! progress) and before it is decoded and parsed.
//! Submissions on a bundle whose summary is cached (see
//! [`crate::summaries`]) parse nothing and are not counted.
//!
//! [`Limits::max_admissions`]: crate::limits::Limits::max_admissions
//! [`Limits::admission_bytes`]: crate::limits::Limits::admission_bytes

use crate::error::{FarmError, LimitKind};
use crate::limits::Limits;
use std::sync::Mutex;
use trevi_core::scene::estimate::human_bytes;

/// Bytes of memory an admission is counted at, for a bundle of
/// `bundle_bytes`: the stored file read whole, the bundle decoded from it
/// (a second copy), one referenced file copied while its header is read,
/// and the scene file's element tree, with a margin; plus 8 MiB for the
/// rest (the tables of ids, a mesh's per-triangle surface table while it
/// is checked).
pub fn admission_cost(bundle_bytes: u64) -> u64 {
    bundle_bytes.saturating_mul(4).saturating_add(8 << 20)
}

/// The admissions in progress and the memory they are counted at.
#[derive(Debug)]
pub struct Admissions {
    max: usize,
    budget: u64,
    state: Mutex<(usize, u64)>,
}

/// One admission in progress; dropping it ends it.
#[derive(Debug)]
pub struct Ticket<'a> {
    gate: &'a Admissions,
    bytes: u64,
}

impl Admissions {
    /// No admission in progress, with the bounds of `limits`
    /// (`--max-admissions`, `--admission-mib`).
    pub fn new(limits: &Limits) -> Admissions {
        Admissions {
            max: limits.max_admissions,
            budget: limits.admission_bytes,
            state: Mutex::new((0, 0)),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, (usize, u64)> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Starts an admission, or refuses when [`Limits::max_admissions`] run.
    ///
    /// [`Limits::max_admissions`]: crate::limits::Limits::max_admissions
    pub fn enter(&self) -> Result<Ticket<'_>, FarmError> {
        let mut s = self.lock();
        if s.0 >= self.max {
            return Err(FarmError::limit(
                LimitKind::Admissions,
                s.0 as u64,
                self.max as u64,
                format!(
                    "{} scenes are being admitted, the coordinator's limit (--max-admissions); \
                 try again shortly",
                    self.max
                ),
            ));
        }
        s.0 += 1;
        Ok(Ticket {
            gate: self,
            bytes: 0,
        })
    }

    /// Admissions in progress and the bytes they are counted at.
    pub fn in_progress(&self) -> (usize, u64) {
        *self.lock()
    }
}

impl Ticket<'_> {
    /// Counts `bytes` more against the admissions' memory budget, or
    /// refuses when they do not fit beside the other admissions' (alone, an
    /// admission always fits).
    pub fn reserve(&mut self, bytes: u64) -> Result<(), FarmError> {
        let mut s = self.gate.lock();
        let others = s.1 - self.bytes;
        let want = self.bytes.saturating_add(bytes);
        if s.0 > 1 && others.saturating_add(want) > self.gate.budget {
            return Err(FarmError::limit(
                LimitKind::AdmissionBytes,
                others.saturating_add(want),
                self.gate.budget,
                format!(
                    "admitting this scene needs about {} of memory and {} of the coordinator's {} \
                 for admissions (--admission-mib) is in use; try again shortly",
                    human_bytes(want),
                    human_bytes(others),
                    human_bytes(self.gate.budget)
                ),
            ));
        }
        s.1 = others + want;
        self.bytes = want;
        Ok(())
    }
}

impl Drop for Ticket<'_> {
    fn drop(&mut self) {
        let mut s = self.gate.lock();
        s.0 -= 1;
        s.1 -= self.bytes;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gate(max: usize, budget: u64) -> Admissions {
        Admissions::new(&Limits {
            max_admissions: max,
            admission_bytes: budget,
            ..Limits::default()
        })
    }

    #[test]
    fn one_admission_too_many_is_refused_naming_the_flag() {
        let g = gate(2, u64::MAX);
        let a = g.enter().unwrap();
        let b = g.enter().unwrap();
        let e = g.enter().unwrap_err();
        assert!(
            matches!(&e, FarmError::Limit(l) if l.flag() == Some("--max-admissions")),
            "{e}"
        );
        drop(a);
        let _c = g.enter().unwrap();
        drop(b);
        assert_eq!(g.in_progress().0, 1);
    }

    #[test]
    fn the_memory_budget_is_shared_but_one_admission_always_fits() {
        let g = gate(4, 100);
        let mut a = g.enter().unwrap();
        // Alone, more than the budget is let through.
        a.reserve(150).unwrap();
        let mut b = g.enter().unwrap();
        let e = b.reserve(10).unwrap_err();
        assert!(
            matches!(&e, FarmError::Limit(l) if l.flag() == Some("--admission-mib")),
            "{e}"
        );
        drop(a);
        b.reserve(60).unwrap();
        b.reserve(30).unwrap();
        let mut c = g.enter().unwrap();
        assert!(c.reserve(20).is_err());
        c.reserve(10).unwrap();
        assert_eq!(g.in_progress(), (2, 100));
        drop((b, c));
        assert_eq!(g.in_progress(), (0, 0));
    }
}
