use super::*;

#[test]
fn a_target_without_frames_is_a_still_and_with_them_a_sequence() {
    let still = Target::new("a".into(), PathBuf::from("out/a.exr"), None).unwrap();
    assert!(matches!(&still.output, Output::Still(p) if p == Path::new("out/a.exr")));
    assert_eq!((still.format, still.frames()), (Format::Exr, None));

    let frames = Frames { first: 3, last: 4 };
    let seq = Target::new("b".into(), PathBuf::from("out/b.##.png"), Some(frames)).unwrap();
    assert_eq!((seq.format, seq.frames()), (Format::Png, Some(frames)));
    let Output::Sequence(s) = &seq.output else {
        panic!("a sequence");
    };
    assert_eq!(s.output(3), PathBuf::from("out/b.03.png"));
}

#[test]
fn each_kind_follows_its_rule_for_hash() {
    let frames = Some(Frames { first: 1, last: 2 });
    let e = Target::new("a".into(), PathBuf::from("a.#.png"), None).err();
    assert!(format!("{:#}", e.unwrap()).contains("only for a sequence"));
    let e = Target::new("a".into(), PathBuf::from("a.png"), frames).err();
    assert!(format!("{:#}", e.unwrap()).contains("one run of #"));
    let e = Target::new("a".into(), PathBuf::from("a.#.tga"), frames).err();
    assert!(e.is_some(), "an unknown format is refused");
}

#[test]
fn the_request_carries_the_job_s_settings() {
    let still = Target::new("a".into(), PathBuf::from("a.png"), None).unwrap();
    let progressive = Some(pb::Progressive {
        samples: 64,
        pass: 8,
        ..Default::default()
    });
    let job = JobSpec {
        priority: 3,
        tile_size: 32,
        progressive,
        notify: vec!["https://hooks.example.com/trevi".into()],
        after: vec![4, 9],
        aovs: Some(trevi_core::Aovs::parse("depth albedo").unwrap()),
    };
    let r = still.request("h", &job);
    assert_eq!(r.aovs.as_deref(), Some("albedo depth"));
    assert_eq!(r.progressive, progressive);
    assert_eq!(r.notify, job.notify);
    assert_eq!((r.bundle_hash.as_str(), r.camera.as_str()), ("h", "a"));
    assert_eq!((r.priority, r.tile_size, r.frames), (3, 32, None));
    assert_eq!(r.output_format, "png");
    assert_eq!(r.after, [4, 9]);
    let plain = still.request("h", &JobSpec::default());
    assert_eq!(plain.progressive, None);
}
