//! Render passes on the farm without a network: a tile's pass values of
//! the wrong size are refused (and the tile re-queued), the right ones are
//! stitched by the job's `FrameWriter` into the very file core writes, and
//! a restart in the middle keeps the stored tiles' passes.

mod common;

use std::path::Path;
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
                let side = f.aov_file(job, pass).unwrap();
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
            let e = f.aov_file(job, "albedo").unwrap_err();
            assert!(e.to_string().contains("as layers"), "{e}");
        }
        let e = f.aov_file(job, "specular").unwrap_err();
        assert!(e.to_string().contains("unknown render pass"), "{e}");
    }
}
