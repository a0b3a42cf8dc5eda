//! A coordinator refuses a state database SQLite would open by quietly
//! dropping jobs: `state.db` truncated beside its write-ahead log, or a log
//! damaged before its last frames. Real processes: jobs submitted, the
//! coordinator killed (`kill -9`, so the log is not checkpointed away), the
//! files damaged, and the coordinator started again.

mod common;

use common::*;
use std::path::Path;
use std::process::{Command, Stdio};

/// Submits three jobs (no worker: they stay queued), cancels one, and kills
/// the coordinator; returns its data directory.
fn killed_farm(dir: &Dir) -> std::path::PathBuf {
    let scene = dir.write("s.xml", &tiny_scene(3));
    let c = coordinator_with(dir, "127.0.0.1:0", "coordinator", &[], &[]);
    for _ in 0..3 {
        let o = submit(
            dir,
            &[scene.to_str().unwrap(), "--coordinator", &c.url, "--detach"],
        );
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let o = submit(dir, &["cancel", "2", "--coordinator", &c.url]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let data = c.data.clone();
    drop(c); // SIGKILL
    data
}

/// Starts the coordinator on `data`; returns (exit success, stderr), failing
/// if it is still running after 20 s (it started on the damaged files).
fn start_on(dir: &Dir, data: &Path, name: &str) -> (bool, String) {
    let child = Command::new(bin("trevi-coordinator"))
        .args(["--listen", "127.0.0.1:0", "--data-dir"])
        .arg(data)
        .stdout(Stdio::null())
        .stderr(dir.log(name))
        .spawn()
        .unwrap();
    let mut p = Proc(child);
    let status = wait_child(dir, &mut p.0, 20);
    (status.success(), dir.read_log(name))
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap().flatten() {
        let t = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &t);
        } else {
            std::fs::copy(e.path(), t).unwrap();
        }
    }
}

#[test]
fn a_truncated_database_beside_its_log_is_refused() {
    let dir = Dir::new();
    let data = killed_farm(&dir);
    let wal = data.join("state.db-wal");
    assert!(std::fs::metadata(&wal).unwrap().len() > 32, "no log left");
    std::fs::write(data.join("state.db"), b"").unwrap();
    let (ok, err) = start_on(&dir, &data, "restart");
    assert!(!ok, "started on an empty state.db\n{}", dir.logs());
    assert!(
        err.contains("state.db is empty") && err.contains("refusing to start"),
        "{err}"
    );
    // Nothing was repaired away: the log is still there.
    assert!(std::fs::metadata(&wal).unwrap().len() > 32);
}

#[test]
fn a_damaged_log_is_refused_and_an_intact_one_resumes() {
    let dir = Dir::new();
    let data = killed_farm(&dir);
    let intact = Dir::new();
    copy_dir(&data, &intact.path().join("data"));
    let wal = data.join("state.db-wal");
    let mut bytes = std::fs::read(&wal).unwrap();
    let page = u32::from_be_bytes(bytes[8..12].try_into().unwrap()) as usize;
    assert!(
        bytes.len() >= 32 + 3 * (24 + page),
        "{} bytes of log",
        bytes.len()
    );
    // A byte in the first frame's page: SQLite would drop every later commit.
    bytes[32 + 24 + 200] ^= 0x5a;
    std::fs::write(&wal, &bytes).unwrap();
    let (ok, err) = start_on(&dir, &data, "damaged");
    assert!(!ok, "started on a damaged log\n{}", dir.logs());
    assert!(
        err.contains("damaged frame") && err.contains("refusing to start"),
        "{err}"
    );
    // The same files undamaged: the jobs are all there.
    let c = coordinator_with(&intact, "127.0.0.1:0", "intact", &[], &[]);
    let o = submit(&intact, &["list", "--coordinator", &c.url]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert_eq!(out.lines().count(), 3, "{out}");
    assert!(out.lines().nth(1).unwrap().contains("cancelled"), "{out}");
}
