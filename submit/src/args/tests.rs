use super::*;

/// The command line `words` (after the program's name), with the rules
/// across flags checked as `parse_checked` does.
fn parse(words: &[&str]) -> Result<Args, clap::Error> {
    let args = Args::try_parse_from(std::iter::once("trevi-submit").chain(words.iter().copied()))?;
    args.check()?;
    Ok(args)
}

fn refusal(words: &[&str]) -> String {
    match parse(words) {
        Ok(a) => panic!("{words:?} was taken: {a:?}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn a_render_s_progressive_flags() {
    let a = parse(&[
        "s.xml",
        "--samples",
        "64",
        "--pass",
        "8",
        "--time-limit",
        "10m",
    ])
    .unwrap();
    assert_eq!(a.samples, Some(64));
    assert_eq!(a.passes.pass, Some(8));
    let p = a.progressive().unwrap();
    assert_eq!((p.samples, p.pass, p.time_limit_ms), (64, 8, 600_000));
    let a = parse(&["s.xml", "--noise-target", "0.01"]).unwrap();
    assert_eq!(a.progressive().map(|p| p.noise_target), Some(0.01));
    assert_eq!(parse(&["s.xml"]).unwrap().progressive(), None);
}

#[test]
fn bad_values_are_refused_naming_the_flag() {
    let e = refusal(&["s.xml", "--samples", "0"]);
    assert!(
        e.contains("--samples") && e.contains("from 1 to 1048576"),
        "{e}"
    );
    let e = refusal(&["s.xml", "--time-limit", "10"]);
    assert!(
        e.contains("--time-limit") && e.contains("not a duration"),
        "{e}"
    );
    let e = refusal(&["s.xml", "--time-limit", "0s"]);
    assert!(e.contains("from 1s to 365d"), "{e}");
    let e = refusal(&["s.xml", "--noise-target", "1"]);
    assert!(e.contains("--noise-target"), "{e}");
    let e = refusal(&["s.xml", "--pass", "0"]);
    assert!(e.contains("--pass"), "{e}");
    let e = refusal(&["s.xml", "--samples", "8", "--pass", "16"]);
    assert!(e.contains("--pass 16 is more than --samples 8"), "{e}");
}

#[test]
fn a_sequence_takes_passes_but_no_stop_condition() {
    for flag in [["--time-limit", "1h"], ["--noise-target", "0.1"]] {
        let mut words = vec!["s.xml", "--frames", "1-10", "--samples", "8"];
        words.extend(flag);
        let e = parse(&words).unwrap_err();
        assert_eq!(e.kind(), ErrorKind::ArgumentConflict, "{flag:?}");
        assert!(
            e.to_string().contains("no --time-limit or --noise-target"),
            "{e}"
        );
    }
    for ok in [
        &["s.xml", "--frames", "1-10"][..],
        &[
            "s.xml",
            "--frames",
            "1-10",
            "--samples",
            "64",
            "--pass",
            "4",
        ],
    ] {
        assert!(parse(ok).is_ok(), "{ok:?}");
    }
}

#[test]
fn extend_s_arguments() {
    let a = parse(&[
        "extend",
        "12",
        "--samples",
        "32",
        "--pass",
        "8",
        "--coordinator",
        "http://h:1",
    ])
    .unwrap();
    let Some(Command::Extend {
        id,
        samples,
        passes,
        wait,
        ..
    }) = a.command
    else {
        panic!("extend");
    };
    assert_eq!((id, samples, passes.pass, wait), (12, 32, Some(8), false));
    fn with<'a>(words: &[&'a str]) -> Vec<&'a str> {
        [words, &["--coordinator", "http://h:1"][..]].concat()
    }
    // The samples to add are required, and bounded like a render's.
    let e = refusal(&with(&["extend", "12"]));
    assert!(e.contains("--samples"), "{e}");
    let e = refusal(&with(&["extend", "12", "--samples", "0"]));
    assert!(e.contains("from 1 to 1048576"), "{e}");
    let e = refusal(&with(&["extend", "12", "--samples", "4", "--pass", "8"]));
    assert!(e.contains("--pass 8 is more than --samples 4"), "{e}");
    let e = refusal(&with(&[
        "extend",
        "12",
        "--samples",
        "4",
        "--time-limit",
        "x",
    ]));
    assert!(e.contains("not a duration"), "{e}");
    // -o is where --wait downloads.
    assert!(parse(&with(&["extend", "12", "--samples", "4", "-o", "a.png"])).is_err());
    assert!(parse(&with(&[
        "extend",
        "12",
        "--samples",
        "4",
        "--wait",
        "-o",
        "a.png"
    ]))
    .is_ok());
}
