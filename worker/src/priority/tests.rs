use super::*;

/// The policy and nice value of the calling thread, read back from the
/// kernel (fields 19 and 41 of /proc/thread-self/stat).
#[cfg(target_os = "linux")]
fn policy_and_nice() -> (i64, i64) {
    let stat = std::fs::read_to_string("/proc/thread-self/stat").unwrap();
    let after = &stat[stat.rfind(')').unwrap() + 2..];
    let f: Vec<&str> = after.split(' ').collect();
    // `after` starts at field 3.
    (f[41 - 3].parse().unwrap(), f[19 - 3].parse().unwrap())
}

#[cfg(target_os = "linux")]
#[test]
fn idle_lowers_the_calling_thread_only() {
    let got = std::thread::spawn(|| {
        let applied = apply_to_this_thread(Priority::Idle);
        (applied, policy_and_nice())
    })
    .join()
    .unwrap();
    match got.0 {
        Applied::SchedIdle => assert_eq!(got.1 .0, libc::SCHED_IDLE as i64),
        Applied::Nice19 => assert_eq!(got.1 .1, 19),
        other => panic!("idle priority was not applied: {other:?}"),
    }
    assert_eq!(
        policy_and_nice().0,
        libc::SCHED_OTHER as i64,
        "this thread is untouched"
    );
    let normal = std::thread::spawn(|| (apply_to_this_thread(Priority::Normal), policy_and_nice()))
        .join()
        .unwrap();
    assert_eq!(normal.0, Applied::Normal);
    assert_eq!(normal.1 .0, libc::SCHED_OTHER as i64);
}

#[test]
fn names_parse_and_print_back() {
    for p in [Priority::Idle, Priority::Normal] {
        assert_eq!(p.to_string().parse::<Priority>(), Ok(p));
    }
    assert!("low"
        .parse::<Priority>()
        .unwrap_err()
        .contains("idle or normal"));
}
