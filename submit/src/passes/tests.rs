use super::*;

fn flags(pass: Option<u32>, limit: Option<u64>, noise: Option<f64>) -> PassFlags {
    PassFlags {
        pass,
        time_limit: limit.map(Duration::from_secs),
        noise_target: noise,
    }
}

#[test]
fn each_flag_has_its_bounds() {
    assert_eq!(samples("1"), Ok(1));
    assert_eq!(samples("1048576"), Ok(MAX_SAMPLES));
    for bad in ["0", "1048577", "-4", "x", "", "4.5"] {
        let e = samples(bad).unwrap_err();
        assert!(e.contains("from 1 to 1048576"), "{bad}: {e}");
    }
    assert_eq!(pass_samples("16"), Ok(16));
    assert!(pass_samples("0").is_err());

    assert_eq!(time_limit("90s"), Ok(Duration::from_secs(90)));
    assert_eq!(time_limit("365d"), Ok(MAX_TIME_LIMIT));
    for bad in ["0s", "366d", "90", "1.5m", "soon", "99999999999999999999d"] {
        assert!(time_limit(bad).is_err(), "{bad}");
    }
    assert!(time_limit("10").unwrap_err().contains("not a duration"));

    assert_eq!(noise_target("0.01"), Ok(0.01));
    for bad in ["0", "1", "-0.1", "1.5", "NaN", "inf", "x"] {
        let e = noise_target(bad).unwrap_err();
        assert!(e.contains("above 0 and below 1"), "{bad}: {e}");
    }
}

#[test]
fn a_pass_is_no_larger_than_the_samples() {
    assert!(check(Some(64), &flags(Some(64), None, None)).is_ok());
    assert!(check(None, &flags(Some(64), None, None)).is_ok());
    let e = check(Some(8), &flags(Some(16), None, None)).unwrap_err();
    assert!(e.contains("--pass 16 is more than --samples 8"), "{e}");
}

#[test]
fn any_flag_makes_the_request_progressive() {
    assert_eq!(progressive(None, &PassFlags::default()), None);
    assert_eq!(
        progressive(Some(64), &PassFlags::default()),
        Some(pb::Progressive {
            samples: 64,
            ..Default::default()
        })
    );
    assert_eq!(
        progressive(None, &flags(None, Some(90), None)),
        Some(pb::Progressive {
            time_limit_ms: 90_000,
            ..Default::default()
        })
    );
    assert_eq!(
        progressive(Some(256), &flags(Some(16), Some(600), Some(0.02))),
        Some(pb::Progressive {
            samples: 256,
            pass: 16,
            time_limit_ms: 600_000,
            noise_target: 0.02,
        })
    );
    assert_eq!(
        progressive(None, &flags(None, None, Some(0.5))).map(|p| p.noise_target),
        Some(0.5)
    );
    assert_eq!(
        progressive(None, &flags(Some(4), None, None)).map(|p| p.pass),
        Some(4)
    );
}

#[test]
fn extend_sends_the_new_passes_settings_only_when_given() {
    let r = extend_request(7, 32, &PassFlags::default());
    assert_eq!((r.id, r.samples, r.passes), (7, 32, None));
    let r = extend_request(7, 32, &flags(Some(8), Some(60), None));
    assert_eq!(
        r.passes,
        Some(pb::Progressive {
            samples: 0,
            pass: 8,
            time_limit_ms: 60_000,
            noise_target: 0.0,
        })
    );
}

#[test]
fn passes_read_as_samples_and_error() {
    let mut p = pb::PassesInfo {
        done: 2,
        samples_done: 8,
        samples_total: 64,
        pass: 4,
        ..Default::default()
    };
    // No estimate before a pass with two samples a pixel.
    assert_eq!(describe(&p), "pass 2, 8 of 64 samples per pixel");
    p.error = Some(0.0042);
    assert_eq!(
        describe(&p),
        "pass 2, 8 of 64 samples per pixel, estimated error 0.42%"
    );
    p.stopped_by = "noise target".into();
    assert!(describe(&p).ends_with(", stopped by the noise target"));
    p.stopped_by = "time limit".into();
    assert!(describe(&p).ends_with(", stopped by the time limit"));
    assert_eq!(spp(&p), "8/64");
    assert_eq!(percent(0.25), "25%");
    assert_eq!(percent(0.021), "2.1%");
    assert_eq!(percent(f64::INFINITY), "unknown");
}
