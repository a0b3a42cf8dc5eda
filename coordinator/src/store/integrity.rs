//! Refusing a database SQLite would open by quietly dropping what it holds:
//! an empty or missing `state.db` beside a write-ahead log that holds
//! frames, a log whose header is damaged, or a log with a damaged frame
//! before frames of the same generation (see the module docs of
//! [`crate::store`]).

use crate::error::FarmError;
use std::path::Path;

pub(super) fn damaged(dir: &Path, why: &str) -> FarmError {
    FarmError::Damaged(format!(
        "the state database {} is damaged ({why}); refusing to start, since going on would \
         lose or mix up jobs. Restore it from a backup, or move state.db, state.db-wal and \
         state.db-shm away to start with no jobs",
        dir.join("state.db").display()
    ))
}

/// The additive checksum of SQLite's write-ahead log over `data` (a multiple
/// of 8 bytes), continuing from `s`; words big-endian when `big`.
fn wal_checksum(big: bool, mut s: (u32, u32), data: &[u8]) -> (u32, u32) {
    let word = |b: &[u8]| {
        let b = [b[0], b[1], b[2], b[3]];
        if big {
            u32::from_be_bytes(b)
        } else {
            u32::from_le_bytes(b)
        }
    };
    for pair in data.chunks_exact(8) {
        s.0 = s.0.wrapping_add(word(&pair[..4]).wrapping_add(s.1));
        s.1 = s.1.wrapping_add(word(&pair[4..]).wrapping_add(s.0));
    }
    s
}

/// Refuses database files SQLite would open by silently dropping committed
/// data (see the module docs); called before SQLite touches them.
pub fn check_files(dir: &Path) -> Result<(), FarmError> {
    let db = dir.join("state.db");
    let wal_path = dir.join("state.db-wal");
    let wal = match std::fs::read(&wal_path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => {
            return Err(FarmError::io(
                format!("cannot read {}", wal_path.display()),
                e,
            ))
        }
    };
    if wal.is_empty() {
        return Ok(());
    }
    let db_len = std::fs::metadata(&db).map(|m| m.len()).ok();
    if db_len.unwrap_or(0) == 0 {
        let what = if db_len.is_some() { "empty" } else { "missing" };
        return Err(damaged(
            dir,
            &format!(
                "state.db is {what} but its write-ahead log state.db-wal holds {} bytes: \
                 the database was truncated or deleted, and SQLite would delete the log",
                wal.len()
            ),
        ));
    }
    let be = |at: usize| u32::from_be_bytes([wal[at], wal[at + 1], wal[at + 2], wal[at + 3]]);
    let bad_header = |why: &str| {
        damaged(
            dir,
            &format!("the header of its write-ahead log state.db-wal is damaged ({why}), so SQLite would ignore the whole log"),
        )
    };
    if wal.len() < 32 {
        return Err(bad_header(&format!("the file is {} bytes", wal.len())));
    }
    let magic = be(0);
    if magic & !1 != 0x377f_0682 {
        return Err(bad_header("not a write-ahead log"));
    }
    let big = magic & 1 == 1;
    let page = be(8) as usize;
    if be(4) != 3_007_000 || !page.is_power_of_two() || !(512..=65536).contains(&page) {
        return Err(bad_header("unknown version or page size"));
    }
    let mut sum = wal_checksum(big, (0, 0), &wal[..24]);
    if sum != (be(24), be(28)) {
        return Err(bad_header("checksum mismatch"));
    }
    let salts = (be(16), be(20));
    let frame = 24 + page;
    let mut at = 32;
    let mut chained = true;
    while at + frame <= wal.len() {
        let own_salts = (be(at + 8), be(at + 12)) == salts;
        if chained {
            let s = wal_checksum(big, sum, &wal[at..at + 8]);
            let s = wal_checksum(big, s, &wal[at + 24..at + frame]);
            if own_salts && s == (be(at + 16), be(at + 20)) {
                sum = s;
            } else {
                // SQLite stops reading here. Stale frames of an earlier
                // generation (other salts) and a torn last write are normal.
                chained = false;
            }
        } else if own_salts {
            return Err(damaged(
                dir,
                &format!(
                    "its write-ahead log state.db-wal has a damaged frame before frame {} of \
                     the same generation, so SQLite would drop the commits after the damage",
                    (at - 32) / frame
                ),
            ));
        }
        at += frame;
    }
    Ok(())
}
