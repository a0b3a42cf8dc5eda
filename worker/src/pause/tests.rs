use super::*;

fn stat(user: u64, idle: u64) -> String {
    // Two cores; the per-core lines must not be mistaken for the total.
    format!(
        "cpu  {user} 0 0 {idle} 0 0 0 0 0 0\ncpu0 1 2 3 4 5 6 7 8 0 0\n\
         cpu1 1 2 3 4 5 6 7 8 0 0\nintr 5\n"
    )
}

fn me(utime: u64, stime: u64) -> String {
    format!("42 (a (weird) name) S 1 42 42 0 -1 4194560 1 0 0 0 {utime} {stime} 0 0 39 19 9 0")
}

#[test]
fn a_sample_reads_the_machine_total_and_our_own_time() {
    let s = CpuSample::parse(&stat(100, 300), &me(30, 10)).unwrap();
    assert_eq!(
        s,
        CpuSample {
            total: 400,
            busy: 100,
            own: 40
        }
    );
    assert_eq!(count_cores(&stat(1, 1)), 2);
    assert_eq!(CpuSample::parse("intr 5\n", &me(1, 1)), None);
    assert_eq!(CpuSample::parse(&stat(1, 1), "42 (x) S 1"), None);
}

#[test]
fn the_load_not_ours_leaves_our_own_time_out() {
    // Two cores for 100 ticks each: 200 ticks. The machine was busy
    // for 150 of them, 90 of which were ours: 60 ticks = 0.6 of a core.
    let a = CpuSample::parse(&stat(1000, 1000), &me(500, 0)).unwrap();
    let b = CpuSample::parse(&stat(1150, 1050), &me(580, 10)).unwrap();
    let load = b.foreign_load(&a, 2).unwrap();
    assert!((load - 0.6).abs() < 1e-12, "{load}");
    // Only our own work: nothing foreign.
    let c = CpuSample::parse(&stat(1350, 1050), &me(780, 10)).unwrap();
    assert_eq!(c.foreign_load(&b, 2), Some(0.0));
    // No time passed, or the counters went back: no reading.
    assert_eq!(b.foreign_load(&b, 2), None);
    assert_eq!(a.foreign_load(&b, 2), None);
}

#[test]
fn busy_only_after_busy_for_and_quiet_only_after_quiet_for() {
    let t0 = Instant::now();
    let s = |n: u64| t0 + Duration::from_secs(n);
    let mut w = BusyWatch::new(0.5, Duration::from_secs(3), Duration::from_secs(10));
    assert_eq!(w.feed(s(0), 0.1), None);
    // A spike of two seconds does not count.
    assert_eq!(w.feed(s(1), 0.9), None);
    assert_eq!(w.feed(s(2), 0.9), None);
    assert_eq!(w.feed(s(3), 0.2), None);
    // Three seconds above: busy, with the highest load seen.
    assert_eq!(w.feed(s(4), 0.8), None);
    assert_eq!(w.feed(s(5), 1.7), None);
    assert_eq!(w.feed(s(6), 0.9), None);
    assert_eq!(w.feed(s(7), 0.9), Some(1.7));
    assert!(w.is_busy());
    // Quiet for less than ten seconds, then busy again: still busy.
    for n in 8..15 {
        assert!(w.feed(s(n), 0.0).is_some(), "second {n}");
    }
    assert!(w.feed(s(15), 2.0).is_some());
    for n in 16..26 {
        assert!(w.feed(s(n), 0.1).is_some(), "second {n}");
    }
    assert_eq!(w.feed(s(26), 0.1), None, "ten quiet seconds");
    assert!(!w.is_busy());
}

#[test]
fn hours_wrap_over_midnight() {
    let h: ActiveHours = "19:00-07:00".parse().unwrap();
    assert_eq!(
        h,
        ActiveHours {
            from: 1140,
            to: 420
        }
    );
    assert_eq!(h.to_string(), "19:00-07:00");
    assert!(h.contains(19 * 60));
    assert!(h.contains(23 * 60 + 59));
    assert!(h.contains(0));
    assert!(h.contains(6 * 60 + 59));
    assert!(!h.contains(7 * 60));
    assert!(!h.contains(12 * 60));
    assert!(!h.contains(18 * 60 + 59));
    let day: ActiveHours = "09:00-17:30".parse().unwrap();
    assert!(day.contains(9 * 60) && day.contains(17 * 60 + 29));
    assert!(!day.contains(17 * 60 + 30) && !day.contains(8 * 60));
    let all: ActiveHours = "00:00-24:00".parse().unwrap();
    assert!(all.contains(0) && all.contains(1439));
    for bad in ["19:00", "19-07", "25:00-07:00", "19:60-07:00", "x:00-07:00"] {
        assert!(bad.parse::<ActiveHours>().is_err(), "{bad}");
    }
}

#[test]
fn the_watcher_combines_load_and_hours() {
    let t0 = Instant::now();
    let cfg = PauseConfig {
        yield_when_busy: true,
        busy_threshold: 0.5,
        busy_for: Duration::from_secs(1),
        quiet_for: Duration::from_secs(1),
        active_hours: Some("19:00-07:00".parse().unwrap()),
        ..PauseConfig::default()
    };
    let mut w = Watcher::new(cfg, 2);
    let night = 22 * 60;
    let sample = |user, idle| CpuSample::parse(&stat(user, idle), &me(0, 0));
    assert_eq!(w.step(t0, sample(0, 0), None, night), None);
    // A core and a half busy (others) for two one-second samples.
    let t = |n| t0 + Duration::from_secs(n);
    assert_eq!(w.step(t(1), sample(150, 50), None, night), None);
    assert_eq!(
        w.step(t(2), sample(300, 100), None, night),
        Some(Pause::Busy { load: 1.5 })
    );
    // No reading at all: the last decision stands.
    assert!(matches!(
        w.step(t(3), None, None, night),
        Some(Pause::Busy { .. })
    ));
    assert_eq!(
        w.step(t(3), sample(300, 300), None, 12 * 60),
        Some(Pause::OutsideHours)
    );
    assert_eq!(w.step(t(4), sample(300, 500), None, night), None);
}

/// A normal build reads the machine's own counters: the tests' variable
/// means nothing to it (the hook is compiled out).
#[cfg(all(target_os = "linux", not(feature = "test-hooks")))]
#[test]
fn a_normal_build_ignores_the_tests_load_file() {
    std::env::set_var("TREVI_TEST_PROC_STAT", "/nonexistent/trevi-proc-stat");
    let read = read_proc_stat();
    std::env::remove_var("TREVI_TEST_PROC_STAT");
    let stat = read.expect("/proc/stat is read, not the variable's file");
    assert!(count_cores(&stat) >= 1, "{stat}");
}

/// With the `test-hooks` feature, the file the variable names stands in for
/// `/proc/stat`.
#[cfg(feature = "test-hooks")]
#[test]
fn the_test_hook_reads_the_named_file() {
    let path = std::env::temp_dir().join(format!("trevi-proc-stat-{}", std::process::id()));
    std::fs::write(&path, stat(7, 9)).unwrap();
    std::env::set_var(PROC_STAT_VAR, &path);
    let read = read_proc_stat();
    std::env::remove_var(PROC_STAT_VAR);
    let _ = std::fs::remove_file(&path);
    assert_eq!(read.unwrap(), stat(7, 9));
}

/// `/proc/interrupts` of a two-core laptop: a PS/2 keyboard and touchpad
/// (i8042), an I2C touchpad, and lines that are not input.
const INTERRUPTS: &str = "           CPU0       CPU1       
  0:         40          0   IO-APIC   2-edge      timer
  1:       1000        234   IO-APIC   1-edge      i8042
  8:          0          1   IO-APIC   8-edge      rtc0
 12:         50          7   IO-APIC  12-edge      i8042
 16:         10         20   IO-APIC  16-fasteoi   i801_smbus, i2c_hid_acpi
 24:     999999     888888   PCI-MSI 327680-edge      xhci_hcd
NMI:          3          4   Non-maskable interrupts
ERR:          0
";

#[test]
fn input_interrupts_count_the_ps2_and_i2c_hid_lines_only() {
    use super::input::input_interrupts;
    // i8042: 1000 + 234 + 50 + 7; i2c_hid: 10 + 20; not the USB controller.
    assert_eq!(input_interrupts(INTERRUPTS), Some(1291 + 30));
    // No input line: nothing counts, but the text is read.
    let none = "  CPU0\n  0:  5  IO-APIC 2-edge timer\n";
    assert_eq!(input_interrupts(none), Some(0));
    assert_eq!(input_interrupts(""), None);
    assert_eq!(input_interrupts("garbage\n 1: 5 i8042\n"), None);
}

#[test]
fn input_makes_the_machine_in_use_until_idle_after_passes() {
    use super::input::InputWatch;
    let t0 = Instant::now();
    let t = |n| t0 + Duration::from_secs(n);
    let mut w = InputWatch::new(Duration::from_secs(10));
    // The first reading is a baseline; no change is no input.
    assert_eq!(w.feed(t0, Some(5)), None);
    assert_eq!(w.feed(t(1), Some(5)), None);
    // A key: in use from now, for ten seconds after the last input.
    assert_eq!(w.feed(t(2), Some(6)), Some(Duration::ZERO));
    assert_eq!(w.feed(t(5), None), Some(Duration::from_secs(3)));
    assert_eq!(w.feed(t(8), Some(9)), Some(Duration::ZERO));
    assert_eq!(w.feed(t(17), Some(9)), Some(Duration::from_secs(9)));
    assert_eq!(w.feed(t(18), Some(9)), None);
    assert_eq!(w.feed(t(19), Some(9)), None);
}

#[test]
fn the_watcher_pauses_for_input_only_with_idle_after() {
    let t0 = Instant::now();
    let t = |n| t0 + Duration::from_secs(n);
    let cfg = PauseConfig {
        yield_when_busy: true,
        idle_after: Some(Duration::from_secs(60)),
        ..PauseConfig::default()
    };
    let quiet = |n| CpuSample::parse(&stat(0, n), &me(0, 0));
    let mut w = Watcher::new(cfg.clone(), 2);
    assert_eq!(w.step(t0, quiet(0), Some(1), 0), None);
    assert_eq!(
        w.step(t(1), quiet(100), Some(2), 0),
        Some(Pause::InUse {
            ago: Duration::ZERO
        })
    );
    assert_eq!(
        Pause::InUse {
            ago: Duration::ZERO
        }
        .reason(),
        "in use"
    );
    assert!(matches!(
        w.step(t(30), quiet(200), Some(2), 0),
        Some(Pause::InUse { .. })
    ));
    assert_eq!(w.step(t(61), quiet(300), Some(2), 0), None);
    // Without --idle-after, or without --yield-when-busy, input is not
    // watched.
    for cfg in [
        PauseConfig {
            idle_after: None,
            ..cfg.clone()
        },
        PauseConfig {
            yield_when_busy: false,
            ..cfg
        },
    ] {
        assert!(!cfg.watches_input());
        let mut w = Watcher::new(cfg, 2);
        assert_eq!(w.step(t0, quiet(0), Some(1), 0), None);
        assert_eq!(w.step(t(1), quiet(100), Some(2), 0), None);
    }
}

/// Input activity a test makes up: a counter it bumps.
struct FakeInput(std::sync::Arc<std::sync::atomic::AtomicU64>);

impl super::input::InputSource for FakeInput {
    fn activity(&mut self) -> Option<u64> {
        Some(self.0.load(std::sync::atomic::Ordering::SeqCst))
    }
}

#[tokio::test]
async fn the_machine_watcher_pauses_on_input_and_resumes_when_idle() {
    use std::sync::atomic::Ordering::SeqCst;
    let counter = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    let cfg = PauseConfig {
        yield_when_busy: true,
        // No CPU load makes this machine busy; only input pauses it.
        busy_threshold: f64::MAX,
        idle_after: Some(Duration::from_millis(300)),
        sample: Duration::from_millis(10),
        ..PauseConfig::default()
    };
    let (_stop, shutdown) = tokio::sync::watch::channel(false);
    let mut rx = crate::machine::watch_with(&cfg, Box::new(FakeInput(counter.clone())), shutdown);
    // Keys are pressed until the watcher says the machine is in use.
    let bump = counter.clone();
    let typing = tokio::spawn(async move {
        loop {
            bump.fetch_add(1, SeqCst);
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    });
    let paused = tokio::time::timeout(
        Duration::from_secs(60),
        rx.wait_for(|p| matches!(p, Some(Pause::InUse { .. }))),
    )
    .await;
    typing.abort();
    assert!(paused.expect("paused within a minute").is_ok());
    // No more input: idle again once --idle-after has passed.
    let resumed = tokio::time::timeout(Duration::from_secs(60), rx.wait_for(|p| p.is_none())).await;
    assert!(resumed.expect("resumed within a minute").is_ok());
}
