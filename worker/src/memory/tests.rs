use super::*;

#[test]
fn sizes_parse_in_powers_of_1024() {
    let p = |s: &str| s.parse::<MaxMemory>().map(|m| m.0);
    assert_eq!(p("2G"), Ok(2 << 30));
    assert_eq!(p("512M"), Ok(512 << 20));
    assert_eq!(p("512m"), Ok(512 << 20));
    assert_eq!(p("2GiB"), Ok(2 << 30));
    assert_eq!(p("2 GB"), Ok(2 << 30));
    assert_eq!(p("1.5G"), Ok(3 << 29));
    assert_eq!(p("800K"), Ok(800 << 10));
    assert_eq!(p("1T"), Ok(1 << 40));
    assert_eq!(p("1073741824"), Ok(1 << 30));
    assert_eq!(p("0"), Ok(0));
    assert_eq!(p("0.0K"), Ok(0));
    // Sizes that round to 0 bytes are not "no limit".
    for tiny in ["0.0000001K", "0.5", "0.9B", "1e-30G"] {
        assert!(p(tiny).is_err(), "{tiny}");
    }
    for bad in ["", "G", "2X", "-1G", "two", "1e3G", "99999999999T"] {
        let e = p(bad).unwrap_err();
        assert!(e.to_string().contains("is not a size"), "{bad}: {e}");
    }
}

#[test]
fn sizes_print_back_as_they_parse() {
    for s in ["2G", "512M", "1536M", "800K", "1T", "1000", "0"] {
        let m: MaxMemory = s.parse().unwrap();
        assert_eq!(m.to_string(), s);
        assert_eq!(m.to_string().parse::<MaxMemory>(), Ok(m));
    }
}

#[test]
fn the_default_is_a_share_of_memtotal() {
    let meminfo = "MemTotal:        8000000 kB\nMemFree:         1000 kB\n";
    assert_eq!(mem_total(meminfo), Some(8_000_000 * 1024));
    assert_eq!(mem_total("MemFree: 1 kB\n"), None);
    assert_eq!(mem_total("MemTotal: lots kB\n"), None);
    // On this machine: half of what /proc/meminfo says, when it says.
    match std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|s| mem_total(&s))
    {
        Some(total) => assert_eq!(MaxMemory::default_for_this_machine().0, total / 2),
        // The end-to-end tests' switch (tests/tests/common): CI must not
        // pass without having checked this machine's default.
        None if std::env::var_os("TREVI_REQUIRE_ALL").is_some_and(|v| v == "1") => {
            panic!("no MemTotal in /proc/meminfo (TREVI_REQUIRE_ALL=1: nothing may be skipped)")
        }
        None => eprintln!(
            "SKIPPED: no MemTotal in /proc/meminfo (set TREVI_REQUIRE_ALL=1 to fail instead)"
        ),
    }
}

#[test]
fn no_limit_allows_everything() {
    assert!(MaxMemory::NONE.allows(u64::MAX));
    assert!(MaxMemory(100).allows(100));
    assert!(!MaxMemory(100).allows(101));
}

#[test]
fn a_pass_counts_its_state_twice() {
    use trevi_core::passes::TileState;
    let rect = Rect::new(16, 32, 64, 48);
    assert_eq!(
        pass_state_bytes(rect),
        2 * TileState::encoded_len(rect) as u64
    );
    assert_eq!(pass_state_bytes(rect), 2 * (32 + 64 * 64 * 48));
    // No overflow for a rect no state may have.
    assert_eq!(
        pass_state_bytes(Rect::new(0, 0, u32::MAX, u32::MAX)),
        u64::MAX
    );
}
