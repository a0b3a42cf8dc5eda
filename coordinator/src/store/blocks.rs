//! Workers kept from unfinished jobs, as stored (see
//! `crate::scheduler::blocks`): one row a job and worker name, written when
//! a failure keeps the worker from the job (or adds to its failures), and
//! deleted by an unblock or with the job. Worker ids change with every
//! coordinator run, so a block is kept under the worker's name; a restart
//! reads the blocks of its unfinished jobs back.

use super::{db_err, Store};
use crate::error::FarmError;
use crate::scheduler::JobId;
use rusqlite::{params, Connection, Transaction};

/// A worker kept from a job, as stored.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StoredBlock {
    /// The job (a frame's or a pass's own job).
    pub job: JobId,
    /// The name the worker registered with.
    pub name: String,
    /// Tiles of the job it failed.
    pub failures: u32,
    /// Why the last one failed.
    pub last_error: String,
}

/// Creates the table (on every open).
pub(super) fn create(conn: &Connection) -> Result<(), FarmError> {
    conn.execute_batch(
        "CREATE TABLE IF NOT EXISTS blocks (
             job INTEGER NOT NULL,
             worker_name TEXT NOT NULL,
             failures INTEGER NOT NULL,
             last_error TEXT NOT NULL,
             PRIMARY KEY (job, worker_name)
         );",
    )
    .map_err(db_err)
}

/// Deletes `job`'s blocks (retention).
pub(super) fn delete(tx: &Transaction, job: JobId) -> Result<(), FarmError> {
    tx.execute("DELETE FROM blocks WHERE job = ?1", params![job as i64])
        .map_err(db_err)?;
    Ok(())
}

impl Store {
    /// Records (or updates) a block.
    pub fn set_block(&self, b: &StoredBlock) -> Result<(), FarmError> {
        self.inner
            .lock()
            .conn
            .execute(
                "INSERT INTO blocks (job, worker_name, failures, last_error)
                 VALUES (?1, ?2, ?3, ?4)
                 ON CONFLICT(job, worker_name) DO UPDATE SET failures = excluded.failures,
                     last_error = excluded.last_error",
                params![b.job as i64, b.name, b.failures, b.last_error],
            )
            .map_err(db_err)?;
        Ok(())
    }

    /// Forgets the block of the worker named `name` on `job`.
    pub fn clear_block(&self, job: JobId, name: &str) -> Result<(), FarmError> {
        self.inner
            .lock()
            .conn
            .execute(
                "DELETE FROM blocks WHERE job = ?1 AND worker_name = ?2",
                params![job as i64, name],
            )
            .map_err(db_err)?;
        Ok(())
    }

    /// Every stored block, by job and name.
    pub fn blocks(&self) -> Result<Vec<StoredBlock>, FarmError> {
        let guard = self.inner.lock();
        let mut q = guard
            .conn
            .prepare(
                "SELECT job, worker_name, failures, last_error FROM blocks
                 ORDER BY job, worker_name",
            )
            .map_err(db_err)?;
        let rows = q
            .query_map([], |r| {
                Ok(StoredBlock {
                    job: r.get::<_, i64>(0)? as JobId,
                    name: r.get(1)?,
                    failures: r.get(2)?,
                    last_error: r.get(3)?,
                })
            })
            .map_err(db_err)?
            .collect::<Result<Vec<_>, _>>()
            .map_err(db_err)?;
        Ok(rows)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_are_kept_updated_cleared_and_dropped_with_their_job() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let b = |job, name: &str, failures| StoredBlock {
            job,
            name: name.into(),
            failures,
            last_error: format!("boom {failures}"),
        };
        store.set_block(&b(3, "a", 3)).unwrap();
        store.set_block(&b(3, "a", 4)).unwrap();
        store.set_block(&b(3, "b", 3)).unwrap();
        store.set_block(&b(5, "a", 3)).unwrap();
        drop(store);
        let store = Store::open(dir.path()).unwrap();
        assert_eq!(
            store.blocks().unwrap(),
            vec![b(3, "a", 4), b(3, "b", 3), b(5, "a", 3)]
        );
        store.clear_block(3, "b").unwrap();
        store.delete_jobs(&[5]).unwrap();
        assert_eq!(store.blocks().unwrap(), vec![b(3, "a", 4)]);
    }
}
