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
