//! Render passes on the farm without a network: a tile's pass values of
//! the wrong size are refused (and the tile re-queued), the right ones are
//! stitched by the job's `FrameWriter` into the very file core writes, and
//! a restart in the middle keeps the stored tiles' passes. A PNG
//! sequence's frames have their pass files filed beside them, removed
//! with them, and asked for by frame within the range (`sequences.rs`).

mod common;

use std::path::Path;
use trevi_coordinator::farm::Retention;
use trevi_coordinator::{
    Farm, FarmConfig, FarmError, JobSpec, JobState, LeaseResult, SubmitOptions, TileOutcome,
    WorkerOptions,
};
use trevi_core::{AovTile, Aovs, FrameWriter, Rect};

fn pixel(x: u32, y: u32) -> [f32; 3] {
    [x as f32 / 31.0, y as f32 / 17.0, ((x + y) % 5) as f32 / 4.0]
}

/// Pass values of pixel (x, y): albedo, normal, depth (+∞ on some, as a
/// miss has).
fn values(x: u32, y: u32) -> [f32; 7] {
    let depth = if (x + y) % 7 == 0 {
        f32::INFINITY
    } else {
        1.0 + x as f32 * 0.5 + y as f32
    };
    [
        x as f32 / 40.0,
        0.5,
        y as f32 / 20.0,
        0.0,
        if x % 2 == 0 { 1.0 } else { -1.0 },
        0.0,
        depth,
    ]
}

fn pixels(r: Rect) -> Vec<[f32; 3]> {
    (r.y..r.y + r.h)
        .flat_map(|y| (r.x..r.x + r.w).map(move |x| pixel(x, y)))
        .collect()
}

fn aovs(r: Rect) -> Vec<f32> {
    (r.y..r.y + r.h)
        .flat_map(|y| (r.x..r.x + r.w).flat_map(move |x| values(x, y)))
        .collect()
}

fn spec(name: &str) -> JobSpec {
    JobSpec {
        aovs: Aovs::ALL,
        ..common::spec(40, 20, 16, name)
    }
}

fn farm(dir: &Path) -> Farm {
    Farm::new(FarmConfig {
        durable: true,
        ..FarmConfig::new(dir)
    })
    .unwrap()
}

/// The frame written by core's writer alone, in one tile.
fn reference(dir: &Path, name: &str) -> Vec<u8> {
    let path = dir.join("reference").join(name);
    let all = Rect::new(0, 0, 40, 20);
    let mut fw = FrameWriter::create_with_aovs(&path, 40, 20, Aovs::ALL).unwrap();
    let tile = AovTile {
        aovs: Aovs::ALL,
        values: aovs(all),
    };
    fw.write_tile_aovs(all, &pixels(all), &tile).unwrap();
    fw.finish().unwrap();
    std::fs::read(path).unwrap()
}

fn put(
    f: &Farm,
    job: u64,
    lease: u64,
    rect: Rect,
    values: &[f32],
) -> Result<TileOutcome, FarmError> {
    f.put_span_aovs(
        LeaseResult {
            lease,
            job,
            rect,
            rays: 1,
            pixels: &pixels(rect),
            worker: None,
        },
        values,
        &[rect],
        None,
    )
}

#[test]
fn pass_values_of_the_wrong_size_are_refused_and_the_tile_rendered_again() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    // One tile: a re-queued tile is the next lease.
    let one = JobSpec {
        tile_size: 64,
        ..spec("o.exr")
    };
    let job = f.submit(one, SubmitOptions::default()).unwrap().id;
    let w = f.register_worker(WorkerOptions::default()).unwrap().id;
    let mut l = f.lease(w).unwrap().expect("a tile");
    assert_eq!(l.aovs, Aovs::ALL, "the lease carries the job's passes");
    assert!(!l.png_segments);
    let right = aovs(l.rect);
    // One value short, one too many: each refused, the tile re-queued.
    let long = [right.clone(), vec![0.0]].concat();
    for wrong in [&right[1..], &long[..]] {
        let e = put(&f, job, l.id, l.rect, wrong).unwrap_err();
        assert!(matches!(e, FarmError::BadTile(_)), "{e:?}");
        let msg = e.to_string();
        assert!(
            msg.contains(&format!("needs {} pass values", right.len()))
                && msg.contains("7 a pixel")
                && msg.contains(&format!("got {}", wrong.len())),
            "{msg}"
        );
        assert_eq!(f.info(job).unwrap().tiles_done, 0);
        l = f.lease(w).unwrap().expect("re-queued");
    }
    assert_eq!(
        put(&f, job, l.id, l.rect, &right).unwrap(),
        TileOutcome::Accepted
    );
    assert_eq!(f.info(job).unwrap().state, JobState::Done);
}

#[test]
fn passes_stitch_into_the_file_core_writes_across_a_restart() {
    for name in ["o.exr", "o.png"] {
        let dir = tempfile::tempdir().unwrap();
        let f = farm(dir.path());
        let job = f.submit(spec(name), SubmitOptions::default()).unwrap().id;
        let w = f.register_worker(WorkerOptions::default()).unwrap().id;
        let first = f.lease(w).unwrap().unwrap();
        assert_eq!(
            put(&f, job, first.id, first.rect, &aovs(first.rect)).unwrap(),
            TileOutcome::Accepted
        );
        drop(f);
        // The restart rebuilds the output from the stored tile, passes
        // and all (and knows the job's passes from its row).
        let f = farm(dir.path());
        assert_eq!(f.info(job).unwrap().spec.aovs, Aovs::ALL);
        let w = f.register_worker(WorkerOptions::default()).unwrap().id;
        while let Some(l) = f.lease(w).unwrap() {
            assert_eq!(
                put(&f, job, l.id, l.rect, &aovs(l.rect)).unwrap(),
                TileOutcome::Accepted
            );
        }
        let info = f.info(job).unwrap();
        assert_eq!(info.state, JobState::Done, "{info:?}");
        let out = f.output_file(job).unwrap();
        assert_eq!(
            std::fs::read(&out).unwrap(),
            reference(dir.path(), name),
            "{name}"
        );
        if name.ends_with(".png") {
            for pass in ["albedo", "normal", "depth"] {
                let side = f.aov_file(job, pass, None).unwrap();
                let ext = if pass == "depth" { "exr" } else { "png" };
                assert_eq!(
                    side.file_name().unwrap().to_string_lossy(),
                    format!("o.{pass}.{ext}")
                );
                assert_eq!(
                    std::fs::read(&side).unwrap(),
                    std::fs::read(dir.path().join("reference").join(format!("o.{pass}.{ext}")))
                        .unwrap(),
                    "{pass}"
                );
            }
        } else {
            let e = f.aov_file(job, "albedo", None).unwrap_err();
            assert!(e.to_string().contains("as layers"), "{e}");
        }
        let e = f.aov_file(job, "specular", None).unwrap_err();
        assert!(e.to_string().contains("unknown render pass"), "{e}");
    }
}

/// Renders every tile leased until none is left or `stop` says so.
fn render(f: &Farm, mut stop: impl FnMut(&Farm) -> bool) {
    let w = f.register_worker(WorkerOptions::default()).unwrap().id;
    while !stop(f) {
        let Some(l) = f.lease(w).unwrap() else {
            break;
        };
        assert_eq!(l.aovs, Aovs::ALL, "a frame's lease carries the passes");
        put(f, l.job, l.id, l.rect, &aovs(l.rect)).unwrap();
    }
}

/// The names in `dir`, sorted.
fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|d| {
            d.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// Frame `f`'s files in a sequence's directory: the frame, then its passes.
fn frame_files(f: u32) -> [String; 4] {
    [
        format!("shot_{f:02}.png"),
        format!("shot_{f:02}.albedo.png"),
        format!("shot_{f:02}.normal.png"),
        format!("shot_{f:02}.depth.exr"),
    ]
}

#[test]
fn a_png_sequence_files_each_frame_s_passes_beside_it() {
    let dir = tempfile::tempdir().unwrap();
    let f = Farm::new(FarmConfig {
        durable: true,
        retention: Retention {
            keep_ended: 1,
            keep_ended_for: None,
            ..Retention::default()
        },
        ..FarmConfig::new(dir.path())
    })
    .unwrap();
    let seq = f
        .submit_sequence(spec("shot_##.png"), 1, 3, SubmitOptions::default())
        .unwrap()
        .id;
    render(&f, |_| false);
    assert_eq!(f.info(seq).unwrap().state, JobState::Done);
    // Only the sequence's directory is left, with every frame's files
    // (each frame's own directory went once its files were moved).
    let jobs = dir.path().join("jobs");
    assert_eq!(names(&jobs), [seq.to_string()]);
    let mut want: Vec<String> = (1..=3).flat_map(frame_files).collect();
    want.sort();
    assert_eq!(names(&jobs.join(seq.to_string())), want);
    // Each the bytes core's writer gives (the pixels are the frame's).
    reference(dir.path(), "o.png");
    for frame in 1..=3 {
        for (pass, ext) in [("albedo", "png"), ("normal", "png"), ("depth", "exr")] {
            let side = f.aov_file(seq, pass, Some(frame)).unwrap();
            assert_eq!(
                side,
                jobs.join(seq.to_string())
                    .join(format!("shot_{frame:02}.{pass}.{ext}"))
            );
            assert!(
                std::fs::read(&side).unwrap()
                    == std::fs::read(dir.path().join("reference").join(format!("o.{pass}.{ext}")))
                        .unwrap(),
                "frame {frame} {pass}"
            );
        }
    }
    // No frame: the last one done, as a download of the output.
    assert_eq!(
        f.aov_file(seq, "normal", None).unwrap(),
        jobs.join(seq.to_string()).join("shot_03.normal.png")
    );
    // A frame outside the range, refused naming it and the range.
    for bad in [0, 4, u32::MAX] {
        let e = f.aov_file(seq, "depth", Some(bad)).unwrap_err();
        assert!(matches!(e, FarmError::NoOutput(..)), "{e:?}");
        assert!(
            e.to_string()
                .contains(&format!("frame {bad} is not in its frames 1-3")),
            "{e}"
        );
    }
    // A still has no frames.
    let still = f
        .submit(spec("o.png"), SubmitOptions::default())
        .unwrap()
        .id;
    f.fetched(seq, None);
    render(&f, |_| false);
    let e = f.aov_file(still, "albedo", Some(1)).unwrap_err();
    assert!(e.to_string().contains("it is a still"), "{e}");
    assert!(f.aov_file(still, "albedo", None).unwrap().is_file());
    // Retention forgot the fetched sequence: its frames' passes went with
    // its directory.
    assert!(matches!(f.info(seq), Err(FarmError::UnknownJob(_))));
    assert_eq!(names(&jobs), [still.to_string()]);
}

#[test]
fn cancelling_a_png_sequence_keeps_finished_frames_passes_and_no_partial_one() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path());
    let seq = f
        .submit_sequence(spec("shot_##.png"), 1, 3, SubmitOptions::default())
        .unwrap()
        .id;
    // Frame 1 done, frame 2 (in progress beside it) begun.
    let mut frame2 = 0;
    render(&f, |f| {
        let fr = f.info(seq).unwrap().frames.unwrap();
        frame2 += u32::from(fr.done == 1);
        frame2 > 1
    });
    let fr = f.info(seq).unwrap().frames.unwrap();
    assert_eq!((fr.done, fr.in_progress), (1, 2), "{fr:?}");
    f.cancel(seq).unwrap();
    let jobs = dir.path().join("jobs");
    assert_eq!(names(&jobs), [seq.to_string()], "a frame's partial files");
    let mut want = frame_files(1).to_vec();
    want.sort();
    assert_eq!(names(&jobs.join(seq.to_string())), want);
    assert!(f.aov_file(seq, "albedo", Some(1)).unwrap().is_file());
    let e = f.aov_file(seq, "albedo", Some(2)).unwrap_err();
    assert!(e.to_string().contains("frame 2 is not done"), "{e}");
}
