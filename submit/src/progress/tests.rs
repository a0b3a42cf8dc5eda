use super::*;

fn at(done: u64, total: u64) -> pb::JobStatus {
    pb::JobStatus {
        tiles_done: done,
        tiles_total: total,
        ..Default::default()
    }
}

#[test]
fn the_eta_is_the_time_a_tile_took_times_the_tiles_left() {
    assert_eq!(eta(&at(25, 100), 10.0), "ETA 30 s");
    assert_eq!(eta(&at(99, 100), 99.0), "ETA 1 s");
    // Nothing to go by yet, or nothing left.
    assert_eq!(eta(&at(0, 100), 10.0), "ETA -");
    assert_eq!(eta(&at(100, 100), 10.0), "ETA -");
}

#[test]
fn quiet_shows_nothing() {
    assert_eq!(Progress::choose(true), Progress::Quiet);
    assert_ne!(Progress::choose(false), Progress::Quiet);
}

fn passes(done: u32, samples_done: u32, total: u32, pass: u32) -> pb::PassesInfo {
    pb::PassesInfo {
        done,
        samples_done,
        samples_total: total,
        pass,
        ..Default::default()
    }
}

#[test]
fn a_pass_shows_its_number_samples_and_error() {
    let mut s = at(10, 40);
    s.state = pb::JobState::Running as i32;
    let mut p = passes(2, 8, 64, 4);
    assert_eq!(pass_text(&s, &p), "pass 3, 8/64 spp done");
    p.error = Some(0.031);
    assert_eq!(pass_text(&s, &p), "pass 3, 8/64 spp done, error 3.1%");
    // Once ended: the last pass, and why it stopped early.
    s.state = pb::JobState::Done as i32;
    p.stopped_by = "time limit".into();
    assert_eq!(
        pass_text(&s, &p),
        "pass 2, 8/64 spp, error 3.1%, stopped by the time limit"
    );
}

#[test]
fn a_progressive_eta_counts_the_samples_left() {
    let mut s = at(20, 40);
    s.state = pb::JobState::Running as i32;
    // 8 samples done and half a pass of 8: 12 of 64 in 12 s, 52 s left.
    let p = passes(1, 8, 64, 8);
    assert_eq!(passes_eta(&s, &p, 12.0), "ETA 52 s");
    // A time limit at 20 s ends it sooner: 8 s to the limit (the current
    // pass needs 4 s more, so the limit counts).
    let mut limited = p.clone();
    limited.time_limit_ms = 20_000;
    assert_eq!(passes_eta(&s, &limited, 12.0), "ETA 8 s");
    // At the limit the pass that runs is finished: its 4 s are left.
    limited.time_limit_ms = 13_000;
    assert_eq!(passes_eta(&s, &limited, 12.0), "ETA 4 s");
    // Nothing to go by yet.
    assert_eq!(passes_eta(&at(0, 40), &passes(0, 0, 64, 8), 1.0), "ETA -");
}
