//! The store's tests: what survives a reopen, spans, damaged files.

use super::*;
use crate::scheduler::{JobSpec, JobState};
use std::io::Write;
use std::path::Path;
use std::time::Duration;

fn job(id: JobId) -> StoredJob {
    StoredJob {
        id,
        spec: JobSpec {
            frame: None,
            bundle_hash: "h".into(),
            camera: "c".into(),
            priority: 0,
            width: 8,
            height: 8,
            tile_size: 4,
            output_name: "o.png".into(),
            scene: "s.xml".into(),
            submitter: "client".into(),
            samples: None,
            aovs: trevi_core::Aovs::NONE,
        },
        state: JobState::Running,
        submitted_ms: 1,
        elapsed: None,
        render: None,
        error: None,
        finish_order: 0,
        tiles_done: 0,
        rays: 0,
        seq: SeqLink::default(),
    }
}

fn replayed(s: &Store, id: JobId) -> Vec<(u32, Vec<u8>)> {
    let mut out = Vec::new();
    s.replay_tiles(id, |t, b| {
        out.push((t, b.to_vec()));
        Ok(())
    })
    .unwrap();
    out
}

/// What `list` shows of a job outlives a restart: its scene, its
/// submitter and, once it ended, how long it rendered.
#[test]
fn scene_submitter_and_render_time_are_kept() {
    let dir = tempfile::tempdir().unwrap();
    {
        let s = Store::open(dir.path()).unwrap();
        s.insert_job(&job(1)).unwrap();
        s.insert_job(&job(2)).unwrap();
        s.finish_job(&StoredJob {
            state: JobState::Done,
            elapsed: Some(Duration::from_millis(5000)),
            render: Some(Duration::from_millis(3250)),
            ..job(1)
        })
        .unwrap();
    }
    let jobs = Store::open(dir.path()).unwrap().jobs().unwrap();
    let got: Vec<_> = jobs
        .iter()
        .map(|j| {
            (
                j.id,
                j.spec.scene.as_str(),
                j.spec.submitter.as_str(),
                j.render,
            )
        })
        .collect();
    assert_eq!(
        got,
        [
            (1, "s.xml", "client", Some(Duration::from_millis(3250))),
            (2, "s.xml", "client", None)
        ]
    );
}

#[test]
fn tiles_survive_a_reopen_and_a_damaged_one_is_forgotten() {
    let dir = tempfile::tempdir().unwrap();
    {
        let s = Store::open(dir.path()).unwrap();
        s.insert_job(&job(1)).unwrap();
        s.put_tile(1, 2, 20, &[2; 48]).unwrap();
        s.put_tile(1, 0, 10, &[0; 48]).unwrap();
        s.put_tile(1, 1, 15, &[1; 48]).unwrap();
        // A second copy is ignored: the first stays.
        s.put_tile(1, 0, 99, &[9; 48]).unwrap();
        // A write whose row was never committed (killed in between).
        let mut f = std::fs::OpenOptions::new()
            .append(true)
            .open(dir.path().join("tiles/1.f32"))
            .unwrap();
        f.write_all(&[7; 100]).unwrap();
    }
    let s = Store::open(dir.path()).unwrap();
    assert_eq!(s.tile_list(1).unwrap(), vec![(0, 10), (1, 15), (2, 20)]);
    s.put_tile(1, 3, 30, &[3; 48]).unwrap();
    let r = replayed(&s, 1);
    assert_eq!(r.iter().map(|t| t.0).collect::<Vec<_>>(), [0, 1, 2, 3]);
    assert!(r.iter().all(|(t, b)| b.iter().all(|&x| x == *t as u8)));
    drop(s);
    // Damage tile 1's bytes on disk: it is dropped, the others stay.
    let path = dir.path().join("tiles/1.f32");
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[48 * 2 + 5] ^= 0xff; // tile 1 was the third write (offset 96)
    std::fs::write(&path, bytes).unwrap();
    let s = Store::open(dir.path()).unwrap();
    assert_eq!(s.tile_list(1).unwrap(), vec![(0, 10), (2, 20), (3, 30)]);
    assert_eq!(replayed(&s, 1).len(), 3);
    // The job ends: its rows and its file go.
    s.finish_job(&StoredJob {
        state: JobState::Done,
        ..job(1)
    })
    .unwrap();
    assert!(s.tile_list(1).unwrap().is_empty());
    assert!(!path.exists());
}

#[test]
fn a_span_of_segments_is_stored_once_replayed_once_and_forgotten_whole() {
    let dir = tempfile::tempdir().unwrap();
    {
        let s = Store::open(dir.path()).unwrap();
        s.insert_job(&job(1)).unwrap();
        s.put_tile(1, 0, 10, &[0; 48]).unwrap();
        s.put_segment_span(1, &[(1, 11), (2, 12), (3, 13)], &[&[5; 30], &[5; 40]])
            .unwrap();
        s.put_tile(1, 4, 14, &[4; 48]).unwrap();
    }
    let s = Store::open(dir.path()).unwrap();
    // The span is one row: its rays (11 + 12 + 13) on its first tile.
    assert_eq!(
        s.tile_list(1).unwrap(),
        vec![(0, 10), (1, 36), (2, 0), (3, 0), (4, 14)]
    );
    let mut seen = Vec::new();
    s.replay(1, |r| {
        seen.push(match r {
            Replayed::Floats { tile, bytes } => (tile, 1, bytes.len()),
            Replayed::Segments {
                first,
                tiles,
                bytes,
            } => (first, tiles, bytes.len()),
        });
        Ok(())
    })
    .unwrap();
    assert_eq!(seen, [(0, 1, 48), (1, 3, 70), (4, 1, 48)]);
    // replay_tiles sees only the float tiles.
    assert_eq!(replayed(&s, 1).len(), 2);
    drop(s);
    // Damage the span's bytes (after tile 0's 48): all three tiles go.
    let path = dir.path().join("tiles/1.f32");
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[48 + 69] ^= 1;
    std::fs::write(&path, bytes).unwrap();
    let s = Store::open(dir.path()).unwrap();
    assert_eq!(s.tile_list(1).unwrap(), vec![(0, 10), (4, 14)]);
}

#[test]
fn a_span_is_a_row_for_each_run_of_consecutive_tiles_and_covers_them_all() {
    let dir = tempfile::tempdir().unwrap();
    let s = Store::open(dir.path()).unwrap();
    s.insert_job(&job(1)).unwrap();
    // Two runs: 10..13 and 20..22.
    let tiles: Vec<(u32, u64)> = [10, 11, 12, 20, 21].iter().map(|&t| (t, 1)).collect();
    s.put_segment_span(1, &tiles, &[&[7; 20]]).unwrap();
    let rows: i64 = s
        .inner
        .lock()
        .conn
        .query_row("SELECT COUNT(*) FROM tile_refs WHERE job = 1", [], |r| {
            r.get(0)
        })
        .unwrap();
    assert_eq!(rows, 2);
    // A float tile inside a run is stored already; one beside it is not.
    s.put_tiles(
        1,
        &[(11, 5, [1u8; 12]), (13, 6, [2u8; 12]), (22, 0, [3u8; 12])],
    )
    .unwrap();
    assert_eq!(
        s.tile_list(1).unwrap(),
        vec![
            (10, 3),
            (11, 0),
            (12, 0),
            (13, 6),
            (20, 2),
            (21, 0),
            (22, 0)
        ]
    );
    let mut seen = Vec::new();
    s.replay(1, |r| {
        seen.push(match r {
            Replayed::Floats { tile, .. } => (tile, 1),
            Replayed::Segments { first, tiles, .. } => (first, tiles),
        });
        Ok(())
    })
    .unwrap();
    // The span once, with all five tiles, and the two float tiles.
    assert_eq!(seen, [(10, 5), (13, 1), (22, 1)]);
}

/// Damaged rows that would make the store allocate what they say: a
/// run of 2^30 tiles, a length of 2^40 bytes. Both are forgotten; the
/// intact row stays.
#[test]
fn rows_claiming_huge_runs_or_lengths_are_forgotten_not_allocated() {
    let dir = tempfile::tempdir().unwrap();
    let s = Store::open(dir.path()).unwrap();
    s.insert_job(&job(1)).unwrap();
    s.put_segment_span(1, &[(0, 1), (1, 1)], &[&[3; 30]])
        .unwrap();
    s.put_segment_span(1, &[(5, 1)], &[&[4; 30]]).unwrap();
    s.put_tile(1, 9, 2, &[9; 12]).unwrap();
    {
        let c = &s.inner.lock().conn;
        c.execute("UPDATE tile_refs SET tiles = 1073741824 WHERE tile = 0", [])
            .unwrap();
        c.execute(
            "UPDATE tile_refs SET len = 1099511627776 WHERE tile = 5",
            [],
        )
        .unwrap();
    }
    assert_eq!(s.tile_list(1).unwrap(), vec![(9, 2)]);
}

#[test]
fn a_span_stored_a_row_a_tile_by_an_earlier_version_replays_once() {
    let dir = tempfile::tempdir().unwrap();
    {
        let s = Store::open(dir.path()).unwrap();
        s.insert_job(&job(1)).unwrap();
        s.put_segment_span(1, &[(0, 1)], &[&[9; 30]]).unwrap();
        // As the version before runs: the same bytes, a row per tile,
        // no `tiles` column.
        let c = &s.inner.lock().conn;
        c.execute_batch(
            "INSERT INTO tile_refs (job, tile, rays, offset, len, crc, kind)
                 SELECT job, 1, rays, offset, len, crc, kind FROM tile_refs;
             INSERT INTO tile_refs (job, tile, rays, offset, len, crc, kind)
                 SELECT job, 2, rays, offset, len, crc, kind FROM tile_refs WHERE tile = 0;
             ALTER TABLE tile_refs DROP COLUMN tiles;",
        )
        .unwrap();
    }
    let s = Store::open(dir.path()).unwrap();
    assert_eq!(s.tile_list(1).unwrap(), vec![(0, 1), (1, 1), (2, 1)]);
    let mut seen = Vec::new();
    s.replay(1, |r| {
        if let Replayed::Segments {
            first,
            tiles,
            bytes,
        } = r
        {
            seen.push((first, tiles, bytes.len()));
        }
        Ok(())
    })
    .unwrap();
    assert_eq!(seen, [(0, 3, 30)]);
}

#[test]
fn a_database_without_row_kinds_gets_them() {
    let dir = tempfile::tempdir().unwrap();
    {
        let c = Connection::open(dir.path().join("state.db")).unwrap();
        c.execute_batch(
            "CREATE TABLE tile_refs (job INTEGER NOT NULL, tile INTEGER NOT NULL,
                 rays INTEGER NOT NULL, offset INTEGER NOT NULL, len INTEGER NOT NULL,
                 crc INTEGER NOT NULL, PRIMARY KEY (job, tile));",
        )
        .unwrap();
    }
    let s = Store::open(dir.path()).unwrap();
    s.insert_job(&job(1)).unwrap();
    s.put_tile(1, 0, 1, &[1; 12]).unwrap();
    s.put_segment_span(1, &[(1, 2)], &[&[2; 9]]).unwrap();
    assert_eq!(s.tile_list(1).unwrap(), vec![(0, 1), (1, 2)]);
}

/// A data directory as a killed coordinator leaves it: the database and
/// its write-ahead log with `n` jobs committed in it, copied while the
/// store is still open (so the log is not checkpointed away).
fn killed_with_jobs(n: u64) -> (tempfile::TempDir, tempfile::TempDir) {
    let live = tempfile::tempdir().unwrap();
    let s = Store::open(live.path()).unwrap();
    for id in 1..=n {
        s.insert_job(&job(id)).unwrap();
    }
    let copy = tempfile::tempdir().unwrap();
    for f in ["state.db", "state.db-wal"] {
        std::fs::copy(live.path().join(f), copy.path().join(f)).unwrap();
    }
    drop(s);
    (live, copy)
}

fn open_err(dir: &Path) -> String {
    match Store::open(dir) {
        Ok(_) => panic!("opened a damaged database"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn a_killed_coordinator_s_log_is_replayed() {
    let (_live, copy) = killed_with_jobs(5);
    assert!(
        std::fs::metadata(copy.path().join("state.db-wal"))
            .unwrap()
            .len()
            > 32
    );
    let s = Store::open(copy.path()).unwrap();
    assert_eq!(s.jobs().unwrap().len(), 5);
}

#[test]
fn an_empty_database_beside_its_log_is_refused() {
    let (_live, copy) = killed_with_jobs(3);
    std::fs::write(copy.path().join("state.db"), b"").unwrap();
    let e = open_err(copy.path());
    assert!(
        e.contains("state.db is empty") && e.contains("refusing to start"),
        "{e}"
    );
    std::fs::remove_file(copy.path().join("state.db")).unwrap();
    assert!(open_err(copy.path()).contains("state.db is missing"));
    // The log is still there for whoever repairs it.
    assert!(copy.path().join("state.db-wal").exists());
}

#[test]
fn a_damaged_log_is_refused_but_a_torn_last_frame_is_not() {
    let (_live, copy) = killed_with_jobs(40);
    let wal = copy.path().join("state.db-wal");
    let good = std::fs::read(&wal).unwrap();
    let page = u32::from_be_bytes(good[8..12].try_into().unwrap()) as usize;
    let frames = (good.len() - 32) / (24 + page);
    assert!(frames >= 3, "{frames} frames");

    // A byte of the first frame's page: the later frames would be lost.
    let mut bad = good.clone();
    bad[32 + 24 + 100] ^= 0x55;
    std::fs::write(&wal, &bad).unwrap();
    let e = open_err(copy.path());
    assert!(e.contains("damaged frame before frame 1"), "{e}");

    // The header: the whole log would be ignored.
    let mut bad = good.clone();
    bad[17] ^= 0x01;
    std::fs::write(&wal, &bad).unwrap();
    assert!(open_err(copy.path()).contains("header"));

    // The last frame torn (a power cut): its commit is lost, as
    // documented, and the rest opens.
    let mut torn = good.clone();
    let last = 32 + (frames - 1) * (24 + page);
    torn[last + 24 + 7] ^= 0x55;
    std::fs::write(&wal, &torn).unwrap();
    Store::open(copy.path()).unwrap();
}

#[test]
fn an_unknown_job_state_is_refused_naming_the_job_and_the_value() {
    let dir = tempfile::tempdir().unwrap();
    let s = Store::open(dir.path()).unwrap();
    s.insert_job(&job(1)).unwrap();
    s.insert_job(&job(2)).unwrap();
    s.inner
        .lock()
        .conn
        .execute("UPDATE jobs SET state = 'paused' WHERE id = 2", [])
        .unwrap();
    let e = s.jobs().unwrap_err();
    assert!(matches!(e, FarmError::Damaged(_)), "{e:?}");
    let msg = e.to_string();
    assert!(msg.contains("job 2") && msg.contains("\"paused\""), "{msg}");
}

#[test]
fn pruned_job_ids_are_never_given_again() {
    let dir = tempfile::tempdir().unwrap();
    let s = Store::open(dir.path()).unwrap();
    for id in 1..=4 {
        s.insert_job(&job(id)).unwrap();
    }
    s.delete_jobs(&[3, 4]).unwrap();
    drop(s);
    let s = Store::open(dir.path()).unwrap();
    assert_eq!(s.jobs().unwrap().len(), 2);
    assert_eq!(s.max_job_id().unwrap(), 4);
}

#[test]
fn stray_tile_files_are_removed_on_open() {
    let dir = tempfile::tempdir().unwrap();
    drop(Store::open(dir.path()).unwrap());
    std::fs::write(dir.path().join("tiles/42.f32"), [1u8; 10]).unwrap();
    drop(Store::open(dir.path()).unwrap());
    assert!(!dir.path().join("tiles/42.f32").exists());
}

/// Records written by many threads at once (their ranges reserved
/// under the lock, written outside it) never overlap: every span and
/// tile comes back byte for byte, none dropped as damaged.
#[test]
fn records_written_at_once_from_many_threads_come_back_intact() {
    let dir = tempfile::tempdir().unwrap();
    let s = Store::open(dir.path()).unwrap();
    s.insert_job(&job(1)).unwrap();
    // Thread t writes 25 spans of two tiles, tiles 1000 t + 2 i and the
    // next, of 1 + (7 t + 13 i) % 300 bytes of value t + i, in two
    // pieces; and 25 float tiles of 48 bytes, tiles 100000 + 100 t + i.
    let bytes = |t: u32, i: u32| vec![(t + i) as u8; 1 + ((7 * t + 13 * i) % 300) as usize];
    std::thread::scope(|sc| {
        for t in 0..8u32 {
            let s = &s;
            sc.spawn(move || {
                for i in 0..25u32 {
                    let b = bytes(t, i);
                    let (a, z) = b.split_at(b.len() / 2);
                    let first = 1000 * t + 2 * i;
                    s.put_segment_span(1, &[(first, 1), (first + 1, 1)], &[a, z])
                        .unwrap();
                    s.put_tile(1, 100_000 + 100 * t + i, 1, &[(t * i) as u8; 48])
                        .unwrap();
                }
            });
        }
    });
    let (mut spans, mut floats) = (0, 0);
    s.replay(1, |r| {
        match r {
            Replayed::Segments {
                first,
                tiles,
                bytes: b,
            } => {
                let (t, i) = (first / 1000, first % 1000 / 2);
                assert_eq!((tiles, b), (2, &bytes(t, i)[..]), "span at tile {first}");
                spans += 1;
            }
            Replayed::Floats { tile, bytes: b } => {
                let (t, i) = ((tile - 100_000) / 100, tile % 100);
                assert_eq!(b, &[(t * i) as u8; 48][..], "tile {tile}");
                floats += 1;
            }
        }
        Ok(())
    })
    .unwrap();
    assert_eq!((spans, floats), (200, 200));
}
