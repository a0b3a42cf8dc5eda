//! Jobs held out of the queue, as stored: paused by a user, or waiting for
//! other jobs (`crate::farm::control`). One row a held job (a sequence's
//! row holds for its frames), written before the hold takes effect and
//! deleted when the job is neither paused nor waiting any more, or is
//! forgotten; a restart reads them back before it queues anything.

use super::{db_err, Store};
use crate::error::FarmError;
use crate::scheduler::JobId;
use rusqlite::params;

/// Why a job is held, as stored.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct StoredHold {
    /// Paused by a user.
    pub paused: bool,
    /// The jobs it still waits for, in the order given.
    pub after: Vec<JobId>,
}

impl StoredHold {
    /// Whether the job is held at all.
    pub fn holds(&self) -> bool {
        self.paused || !self.after.is_empty()
    }
}

/// `after` as stored: ids separated by commas.
fn after_text(after: &[JobId]) -> String {
    after
        .iter()
        .map(JobId::to_string)
        .collect::<Vec<_>>()
        .join(",")
}

/// The ids of a stored `after`; anything else is a database this
/// coordinator did not write, refused naming the job.
fn after_ids(job: JobId, text: &str) -> Result<Vec<JobId>, FarmError> {
    if text.is_empty() {
        return Ok(Vec::new());
    }
    text.split(',')
        .map(|t| t.parse::<JobId>())
        .collect::<Result<_, _>>()
        .map_err(|_| {
            FarmError::Damaged(format!(
                "the state database says job {job} waits for \"{}\", which is not a list of \
                 job ids",
                text.chars().take(40).collect::<String>()
            ))
        })
}

impl Store {
    /// Records `job`'s hold; a hold that holds nothing deletes its row.
    pub fn set_hold(&self, job: JobId, hold: &StoredHold) -> Result<(), FarmError> {
        let guard = self.inner.lock();
        if hold.holds() {
            guard
                .conn
                .execute(
                    "INSERT INTO holds (job, paused, after) VALUES (?1, ?2, ?3)
                     ON CONFLICT(job) DO UPDATE SET paused = excluded.paused,
                         after = excluded.after",
                    params![job as i64, hold.paused, after_text(&hold.after)],
                )
                .map_err(db_err)?;
        } else {
            guard
                .conn
                .execute("DELETE FROM holds WHERE job = ?1", params![job as i64])
                .map_err(db_err)?;
        }
        Ok(())
    }

    /// Every stored hold, by job.
    pub fn holds(&self) -> Result<Vec<(JobId, StoredHold)>, FarmError> {
        let guard = self.inner.lock();
        let mut q = guard
            .conn
            .prepare("SELECT job, paused, after FROM holds ORDER BY job")
            .map_err(db_err)?;
        let rows = q
            .query_map([], |r| {
                Ok((
                    r.get::<_, i64>(0)? as JobId,
                    r.get::<_, bool>(1)?,
                    r.get::<_, String>(2)?,
                ))
            })
            .map_err(db_err)?
            .collect::<Result<Vec<_>, _>>()
            .map_err(db_err)?;
        rows.into_iter()
            .map(|(job, paused, after)| {
                Ok((
                    job,
                    StoredHold {
                        paused,
                        after: after_ids(job, &after)?,
                    },
                ))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn holds_are_kept_changed_and_dropped() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let waits = StoredHold {
            paused: false,
            after: vec![3, 1 << 40],
        };
        store.set_hold(7, &waits).unwrap();
        let paused = StoredHold {
            paused: true,
            after: vec![],
        };
        store.set_hold(9, &paused).unwrap();
        drop(store);
        let store = Store::open(dir.path()).unwrap();
        assert_eq!(
            store.holds().unwrap(),
            vec![(7, waits.clone()), (9, paused)]
        );
        store.set_hold(9, &StoredHold::default()).unwrap();
        store.delete_jobs(&[7]).unwrap();
        assert!(store.holds().unwrap().is_empty());
    }

    #[test]
    fn a_stored_list_that_is_not_ids_is_refused_naming_the_job() {
        assert_eq!(after_ids(4, "1,2").unwrap(), vec![1, 2]);
        let e = after_ids(4, "1,x").unwrap_err().to_string();
        assert!(e.contains("job 4") && e.contains("1,x"), "{e}");
    }
}
