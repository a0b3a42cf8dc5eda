//! `trevi-coordinator`'s flags as the binary reads them: a value that makes
//! no sense is refused before anything starts, naming the flag.

use std::process::Command;

#[test]
fn a_zero_window_is_refused_naming_the_flag() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_trevi-coordinator"))
        .args(["--window-mib", "0", "--listen", "127.0.0.1:0", "--data-dir"])
        .arg(dir.path())
        .env_remove("TREVI_WINDOW_MIB")
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--window-mib"), "{err}");
    // Refused before the data directory was used.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}
