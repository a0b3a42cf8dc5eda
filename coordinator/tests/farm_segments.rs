//! Leases taken as encoded PNG segments (docs/farm.md, "Encoded
//! segments"): the file made from segments (mixed with float tiles) is the
//! file a `FrameWriter` makes from the floats, also across a restart; a
//! damaged stored segment is rendered again; every refusal says why and
//! re-queues the span; and the gRPC path on loopback.
//!
//! Until the scheduler asks for segments (`Lease.png_segments`), these
//! tests upload segments for leases of whole bands: frames no wider than a
//! tile, so that every lease is full-width rows from a multiple of 16.

mod common;

use common::spec;
use std::path::Path;
use trevi_coordinator::farm::{SegmentUpload, TileOutcome};
use trevi_coordinator::preview::Preview;
use trevi_coordinator::scheduler::Lease;
use trevi_coordinator::{Farm, FarmConfig, FarmError, JobState, SubmitOptions};
use trevi_coordinator::{LeaseResult, WorkerOptions};
use trevi_core::output::{
    encode_segment, max_segment_deflate_len, segment_rows, PngSegment, SEGMENT_ROWS, SYNC_FLUSH,
};
use trevi_core::{FrameWriter, Rect};

/// Pixel values in quarters: every preview sum is exact, whatever the
/// order it is added in, so previews compare bit for bit.
fn pixel(x: u32, y: u32) -> [f32; 3] {
    [
        (x % 5) as f32 * 0.25,
        ((y * 3 + x) % 7) as f32 * 0.25,
        ((x / 3 + y) % 3) as f32 * 0.5,
    ]
}

fn pixels(r: Rect) -> Vec<[f32; 3]> {
    (r.y..r.y + r.h)
        .flat_map(|y| (r.x..r.x + r.w).map(move |x| pixel(x, y)))
        .collect()
}

fn farm(dir: &Path, durable: bool) -> Farm {
    Farm::new(FarmConfig {
        durable,
        ..FarmConfig::new(dir)
    })
    .unwrap()
}

/// A worker that registered with the coordinator's encoder.
fn segment_worker(f: &Farm) -> u64 {
    f.register_worker(WorkerOptions {
        name: "seg",
        threads: 4,
        png_segments: true,
        ..WorkerOptions::default()
    })
    .unwrap()
    .id
}

/// The frame as a `FrameWriter` writes it from floats alone, in bands.
fn reference(dir: &Path, w: u32, h: u32) -> Vec<u8> {
    let path = dir.join("reference.png");
    let mut fw = FrameWriter::create(&path, w, h).unwrap();
    fw.write_tile(Rect::new(0, 0, w, h), &pixels(Rect::new(0, 0, w, h)))
        .unwrap();
    fw.finish().unwrap();
    std::fs::read(path).unwrap()
}

/// What a worker uploads for `rect` of a `w` × `h` frame: its segments,
/// encoded, and the preview's box sums computed pixel by pixel.
fn upload_parts(rect: Rect, w: u32, h: u32) -> (Vec<PngSegment>, Vec<f32>) {
    let mut segments = Vec::new();
    let mut y = rect.y;
    while y < rect.y + rect.h {
        let rows = segment_rows(h, y / SEGMENT_ROWS);
        let r = Rect::new(0, rows.start, w, rows.end - rows.start);
        segments.push(encode_segment(w, &pixels(r)));
        y = rows.end;
    }
    let p = Preview::new(w, h);
    let (cx0, cy0, cols, rows) = p.cells(rect);
    let mut sums = vec![0.0f32; 3 * (cols * rows) as usize];
    for y in rect.y..rect.y + rect.h {
        for x in rect.x..rect.x + rect.w {
            let i = ((y / p.scale - cy0) * cols + (x / p.scale - cx0)) as usize;
            for (s, v) in sums[3 * i..3 * i + 3].iter_mut().zip(pixel(x, y)) {
                *s += v;
            }
        }
    }
    (segments, sums)
}

fn put_segments(f: &Farm, l: &Lease, w: u32, h: u32, worker: u64) -> TileOutcome {
    let (segments, sums) = upload_parts(l.rect, w, h);
    f.put_segments(
        SegmentUpload {
            lease: l.id,
            job: l.job,
            rect: l.rect,
            rays: 7,
            worker: Some(worker),
            segments: &segments,
            sums: &sums,
        },
        &[l.rect],
        None,
    )
    .unwrap()
}

fn put_floats(f: &Farm, l: &Lease, worker: u64) -> TileOutcome {
    f.put_tile(LeaseResult {
        lease: l.id,
        job: l.job,
        rect: l.rect,
        rays: 7,
        pixels: &pixels(l.rect),
        worker: Some(worker),
    })
    .unwrap()
}

fn lease_all(f: &Farm, worker: u64) -> Vec<Lease> {
    std::iter::from_fn(|| f.lease(worker).unwrap()).collect()
}

/// A farm in `data` with one job of `w` × `h` in tiles of `tile` to
/// "out.png", a segment worker, and every lease the worker gets (a band
/// each).
struct Started {
    f: Farm,
    job: u64,
    wk: u64,
    leases: Vec<Lease>,
}

fn start(data: &Path, durable: bool, (w, h, tile): (u32, u32, u32)) -> Started {
    let f = farm(data, durable);
    let job = f
        .submit(spec(w, h, tile, "out.png"), SubmitOptions::default())
        .unwrap()
        .id;
    let wk = segment_worker(&f);
    let leases = lease_all(&f, wk);
    Started { f, job, wk, leases }
}

// 540 × 1100 with 544-pixel tiles: three bands (544, 544 and 12 rows), each
// a lease of whole segments; the preview's scale is 3, so cells straddle
// the band edges (544 = 3 × 181 + 1).
const W: u32 = 540;
const H: u32 = 1100;
const TILE: u32 = 544;

#[test]
fn a_frame_taken_as_segments_and_floats_is_the_float_file_and_preview() {
    let dir = tempfile::tempdir().unwrap();
    let expected = reference(dir.path(), W, H);
    // Which bands come as segments, in which order the results arrive.
    let plans: [(&[bool], &[usize]); 4] = [
        (&[true, true, true], &[0, 1, 2]),
        (&[true, true, true], &[2, 0, 1]),
        (&[false, true, false], &[1, 2, 0]),
        (&[true, false, true], &[2, 1, 0]),
    ];
    let mut previews = Vec::new();
    for (n, (as_segments, order)) in plans.iter().enumerate() {
        let data = dir.path().join(format!("farm{n}"));
        let Started { f, job, wk, leases } = start(&data, n % 2 == 0, (W, H, TILE));
        assert_eq!(leases.len(), 3);
        assert_eq!(f.preview_scale(job), 3);
        let mut segments = 0;
        for &i in order.iter() {
            let l = &leases[i];
            let outcome = if as_segments[i] {
                segments += l.rect.h.div_ceil(SEGMENT_ROWS);
                put_segments(&f, l, W, H, wk)
            } else {
                put_floats(&f, l, wk)
            };
            assert_eq!(outcome, TileOutcome::Accepted);
        }
        let info = f.info(job).unwrap();
        assert_eq!(
            (info.state, info.tiles_done, info.rays),
            (JobState::Done, 3, 21)
        );
        let got = std::fs::read(f.output_file(job).unwrap()).unwrap();
        assert!(
            got == expected,
            "plan {n}: the file differs from the float one"
        );
        assert_eq!(f.metrics().png_segments(), u64::from(segments));
        let text = trevi_coordinator::metrics::render(&f.snapshot(), f.metrics());
        assert!(
            text.contains(&format!("\ntrevi_png_segments_total {segments}\n")),
            "{text}"
        );
        previews.push(f.preview(job).unwrap().png);
    }
    // The preview from sums is the one from pixels (plan 2 has a band of
    // each kind; all share one image).
    assert!(previews.windows(2).all(|p| p[0] == p[1]));
}

#[test]
fn a_restart_replays_stored_segments_and_floats_to_the_same_file() {
    let dir = tempfile::tempdir().unwrap();
    let expected = reference(dir.path(), W, H);
    let data = dir.path().join("farm");
    let job = {
        let Started { f, job, wk, leases } = start(&data, true, (W, H, TILE));
        // The last band as segments, the first as floats; the middle one
        // is still out when the coordinator dies.
        assert_eq!(
            put_segments(&f, &leases[2], W, H, wk),
            TileOutcome::Accepted
        );
        assert_eq!(put_floats(&f, &leases[0], wk), TileOutcome::Accepted);
        job
    };
    let f = farm(&data, true);
    let info = f.info(job).unwrap();
    assert_eq!((info.state, info.tiles_done), (JobState::Running, 2));
    let wk = segment_worker(&f);
    let leases = lease_all(&f, wk);
    assert_eq!(leases.len(), 1, "only the middle band is rendered again");
    assert_eq!(leases[0].rect, Rect::new(0, TILE, W, TILE));
    assert_eq!(
        put_segments(&f, &leases[0], W, H, wk),
        TileOutcome::Accepted
    );
    assert_eq!(f.info(job).unwrap().state, JobState::Done);
    assert!(std::fs::read(f.output_file(job).unwrap()).unwrap() == expected);
}

#[test]
fn a_damaged_stored_segment_is_forgotten_and_rendered_again() {
    let dir = tempfile::tempdir().unwrap();
    let expected = reference(dir.path(), W, H);
    let data = dir.path().join("farm");
    let job = {
        let Started { f, job, wk, leases } = start(&data, true, (W, H, TILE));
        assert_eq!(put_floats(&f, &leases[0], wk), TileOutcome::Accepted);
        assert_eq!(
            put_segments(&f, &leases[1], W, H, wk),
            TileOutcome::Accepted
        );
        job
    };
    // Flip a byte in the middle band's stored segments (after the first
    // band's 544 × 540 floats).
    let file = data.join("tiles").join(format!("{job}.f32"));
    let mut bytes = std::fs::read(&file).unwrap();
    let floats = (TILE * W * 12) as usize;
    assert!(bytes.len() > floats + 100);
    bytes[floats + 100] ^= 0x40;
    std::fs::write(&file, bytes).unwrap();
    let f = farm(&data, true);
    assert_eq!(f.info(job).unwrap().tiles_done, 1);
    let wk = segment_worker(&f);
    let leases = lease_all(&f, wk);
    let rects: Vec<Rect> = leases.iter().map(|l| l.rect).collect();
    assert_eq!(
        rects,
        [
            Rect::new(0, TILE, W, TILE),
            Rect::new(0, 2 * TILE, W, H - 2 * TILE)
        ]
    );
    for l in &leases {
        assert_eq!(put_segments(&f, l, W, H, wk), TileOutcome::Accepted);
    }
    assert!(std::fs::read(f.output_file(job).unwrap()).unwrap() == expected);
}

/// A farm with one job of 40 × 100 in 64-pixel tiles (bands of 64 rows,
/// four segments, and 36 rows, three), a segment worker and its leases.
fn small() -> (tempfile::TempDir, Farm, u64, Vec<Lease>) {
    let dir = tempfile::tempdir().unwrap();
    let Started { f, wk, leases, .. } = start(dir.path(), true, (40, 100, 64));
    assert_eq!(leases.len(), 2);
    (dir, f, wk, leases)
}

#[test]
fn every_refusal_says_why_and_re_queues_the_span() {
    type Spoil = fn(&mut Vec<PngSegment>, &mut Vec<f32>);
    let cases: [(&str, Spoil); 8] = [
        (
            "3 segments uploaded, but rows 0..64 are 4 segments",
            |s, _| {
                s.pop();
            },
        ),
        ("segment 1 holds 1935 filtered bytes, not 1936", |s, _| {
            s[1].filtered_len -= 1;
        }),
        ("segment 2 does not end in a sync flush", |s, _| {
            s[2].deflate.pop();
        }),
        (
            "segment 3 has 3000 deflate bytes, more than the 2968",
            |s, _| {
                s[3].deflate = vec![0; 2996];
                s[3].deflate.extend_from_slice(&SYNC_FLUSH);
            },
        ),
        (
            "119 preview sums uploaded, but the rect overlaps 2560 preview cells of 1 pixels: \
             7680 sums",
            |_, p| p.truncate(119),
        ),
        ("preview sum 4 (cell 1) is NaN", |_, p| p[4] = f32::NAN),
        ("preview sum 5 (cell 1) is -1", |_, p| p[5] = -1.0),
        ("Adler-32", |s, _| {
            for seg in s.iter_mut() {
                seg.adler32 ^= 0x10;
            }
        }),
    ];
    for (want, spoil) in cases {
        let (_dir, f, wk, leases) = small();
        let l = &leases[0];
        let (mut segments, mut sums) = upload_parts(l.rect, 40, 100);
        spoil(&mut segments, &mut sums);
        let e = f
            .put_segments(
                SegmentUpload {
                    lease: l.id,
                    job: l.job,
                    rect: l.rect,
                    rays: 1,
                    worker: Some(wk),
                    segments: &segments,
                    sums: &sums,
                },
                &[l.rect],
                None,
            )
            .unwrap_err();
        let msg = e.to_string();
        assert!(matches!(e, FarmError::BadTile(_)), "{e:?}");
        assert!(msg.contains(want), "{want}: {msg}");
        // Re-queued at once: the same band is leased again.
        let again = f.lease(wk).unwrap().expect("re-queued");
        assert_eq!(again.rect, l.rect, "{want}");
        assert_eq!(f.metrics().png_segments(), 0);
    }
}

#[test]
fn a_worker_without_the_encoder_and_a_wrong_rect_are_refused() {
    let (_dir, f, _wk, _) = small();
    let job = f
        .submit(spec(40, 100, 64, "two.png"), SubmitOptions::default())
        .unwrap()
        .id;
    let plain = f.register_worker(WorkerOptions::default()).unwrap().id;
    let l = f.lease(plain).unwrap().unwrap();
    assert_eq!(l.job, job);
    let (segments, sums) = upload_parts(l.rect, 40, 100);
    let up = SegmentUpload {
        lease: l.id,
        job,
        rect: l.rect,
        rays: 1,
        worker: Some(plain),
        segments: &segments,
        sums: &sums,
    };
    let e = f.put_segments(up, &[l.rect], None).unwrap_err();
    assert!(e.to_string().contains("did not register with"), "{e}");
    assert_eq!(f.lease(plain).unwrap().unwrap().rect, l.rect, "re-queued");

    // Rows that are not whole segments, and an EXR frame.
    let e = f.segment_plan(job, Rect::new(0, 8, 40, 16)).unwrap_err();
    assert!(e.to_string().contains("not whole 16-row segments"), "{e}");
    let e = f.segment_plan(job, Rect::new(0, 0, 39, 16)).unwrap_err();
    assert!(e.to_string().contains("full width 40"), "{e}");
    let exr = f
        .submit(spec(40, 100, 64, "out.exr"), SubmitOptions::default())
        .unwrap()
        .id;
    let e = f.segment_plan(exr, Rect::new(0, 0, 40, 64)).unwrap_err();
    assert!(e.to_string().contains("not a PNG"), "{e}");

    // A lease that is not full-width rows, uploaded as segments anyway:
    // refused and re-queued like any invalid result.
    let dir = tempfile::tempdir().unwrap();
    let g = farm(dir.path(), false);
    let narrow = g
        .submit(spec(40, 32, 16, "n.png"), SubmitOptions::default())
        .unwrap()
        .id;
    let wk = segment_worker(&g);
    let l = g.lease(wk).unwrap().unwrap();
    assert_eq!(l.rect, Rect::new(0, 0, 16, 16));
    let segs = [encode_segment(16, &pixels(l.rect))];
    let e = g
        .put_segments(
            SegmentUpload {
                lease: l.id,
                job: narrow,
                rect: l.rect,
                rays: 1,
                worker: Some(wk),
                segments: &segs,
                sums: &[0.0; 3 * 256],
            },
            &[l.rect],
            None,
        )
        .unwrap_err();
    assert!(
        e.to_string().contains("not the frame's full width 40"),
        "{e}"
    );
    let rest = lease_all(&g, wk);
    assert!(rest.iter().any(|r| r.rect == l.rect), "re-queued");
}

#[test]
fn a_span_partly_done_is_ignored_whole_and_changes_nothing() {
    let (_dir, f, wk, leases) = small();
    let l = &leases[0];
    assert_eq!(put_floats(&f, l, wk), TileOutcome::Accepted);
    // The same band again as segments: ignored, the job's count unchanged.
    assert_eq!(put_segments(&f, l, 40, 100, wk), TileOutcome::Ignored);
    assert_eq!(f.info(l.job).unwrap().tiles_done, 1);
    assert_eq!(f.metrics().png_segments(), 0);
    // The other band as segments finishes the file as floats would.
    assert_eq!(
        put_segments(&f, &leases[1], 40, 100, wk),
        TileOutcome::Accepted
    );
    let dir = tempfile::tempdir().unwrap();
    assert!(
        std::fs::read(f.output_file(l.job).unwrap()).unwrap() == reference(dir.path(), 40, 100)
    );
}

#[test]
fn the_deflate_bound_is_what_the_farm_states() {
    // 40 wide: a 16-row segment is 16 × 121 = 1936 filtered bytes.
    assert_eq!(max_segment_deflate_len(1936), 1936 + 968 + 64);
}

mod grpc {
    use super::*;
    use std::sync::Arc;
    use trevi_proto::pb::{self, tile_upload::Part, workers_client::WorkersClient};

    async fn serve(f: Farm) -> (Arc<Farm>, WorkersClient<tonic::transport::Channel>) {
        let f = Arc::new(f);
        (f.clone(), common::serve(f).await)
    }

    fn segment_msg(index: u32, s: &PngSegment) -> pb::TileUpload {
        pb::TileUpload {
            part: Some(Part::Segment(pb::EncodedSegment {
                index,
                deflate: s.deflate.clone(),
                adler32: s.adler32,
                filtered_len: s.filtered_len,
            })),
        }
    }

    /// Registers with the encoder, leases both bands, and uploads each as
    /// `parts` makes its messages.
    async fn upload(
        client: &mut WorkersClient<tonic::transport::Channel>,
        reg: &pb::RegisterResponse,
        lease: &pb::Lease,
        parts: Vec<pb::TileUpload>,
    ) -> Result<bool, tonic::Status> {
        let r = lease.rect.unwrap();
        let header = pb::TileUpload {
            part: Some(Part::Header(pb::TileHeader {
                worker_id: reg.worker_id,
                lease_id: lease.lease_id,
                job_id: lease.job_id,
                rect: Some(r),
                rays: 5,
                session: reg.session.clone(),
                frame: None,
                render_micros: Some(1000),
                cpu_micros: None,
            })),
        };
        let msgs: Vec<pb::TileUpload> = std::iter::once(header).chain(parts).collect();
        client
            .submit_tile(tokio_stream::iter(msgs))
            .await
            .map(|r| r.into_inner().accepted)
    }

    fn good_parts(lease: &pb::Lease) -> Vec<pb::TileUpload> {
        let r = lease.rect.unwrap();
        let rect = Rect::new(r.x, r.y, r.w, r.h);
        let (segments, sums) = upload_parts(rect, 40, 100);
        let first = rect.y / SEGMENT_ROWS;
        let mut out: Vec<pb::TileUpload> = (first..)
            .zip(&segments)
            .map(|(i, s)| segment_msg(i, s))
            .collect();
        out.push(pb::TileUpload {
            part: Some(Part::Preview(pb::PreviewSums { sums })),
        });
        out
    }

    #[tokio::test]
    async fn segments_over_grpc_make_the_float_file_and_refusals_say_why() {
        let dir = tempfile::tempdir().unwrap();
        // Six refusals of one band: more failures than a tile is allowed.
        let f = Farm::new(FarmConfig {
            limits: trevi_coordinator::Limits {
                max_tile_failures: 100,
                max_worker_failures: 100,
                ..Default::default()
            },
            ..FarmConfig::new(dir.path())
        })
        .unwrap();
        let job = f
            .submit(spec(40, 100, 64, "out.png"), SubmitOptions::default())
            .unwrap()
            .id;
        let (f, mut client) = serve(f).await;
        let reg = client
            .register(pb::RegisterRequest {
                name: "w".into(),
                threads: 2,
                png_encoder: trevi_core::output::PNG_ENCODER.into(),
                ..Default::default()
            })
            .await
            .unwrap()
            .into_inner();
        let lease = |c: &mut WorkersClient<_>| {
            let req = pb::LeaseRequest {
                worker_id: reg.worker_id,
                session: reg.session.clone(),
                max_wait_ms: 100,
            };
            let mut c: WorkersClient<tonic::transport::Channel> = std::mem::replace(c, c.clone());
            async move { c.lease_tile(req).await.unwrap().into_inner().lease.unwrap() }
        };
        let first = lease(&mut client).await;
        if first.png_segments {
            assert_eq!(first.preview_scale, 1, "the preview's cell edge");
        }

        // Refusals, each re-queueing the band (leased again next).
        let mut l = first;
        type Spoil = Box<dyn Fn(&mut Vec<pb::TileUpload>)>;
        let refusals: Vec<(&str, Spoil)> = vec![
            (
                "segment 1 came where segment 0 was due",
                Box::new(|m| {
                    m.remove(0);
                }),
            ),
            (
                "ends with its preview sums",
                Box::new(|m| {
                    m.pop();
                }),
            ),
            (
                "more than the 2968 its rows can take",
                Box::new(|m| {
                    if let Some(Part::Segment(s)) = &mut m[2].part {
                        s.deflate = vec![0; 3000];
                    }
                }),
            ),
            (
                "and nothing else",
                Box::new(|m| {
                    m.push(pb::TileUpload {
                        part: Some(Part::Pixels(vec![0; 12])),
                    });
                }),
            ),
            (
                "preview sums uploaded, but the rect overlaps 2560",
                Box::new(|m| {
                    if let Some(Part::Preview(p)) = &mut m.last_mut().unwrap().part {
                        p.sums.pop();
                    }
                }),
            ),
            (
                "more than the 4 segments",
                Box::new(|m| {
                    let extra = m[3].clone();
                    m.insert(4, extra);
                    if let Some(Part::Segment(s)) = &mut m[4].part {
                        s.index = 4;
                    }
                }),
            ),
        ];
        for (want, spoil) in &refusals {
            let mut parts = good_parts(&l);
            spoil(&mut parts);
            let e = upload(&mut client, &reg, &l, parts).await.unwrap_err();
            assert_eq!(e.code(), tonic::Code::InvalidArgument, "{want}: {e:?}");
            assert!(e.message().contains(want), "{want}: {}", e.message());
            let again = lease(&mut client).await;
            assert_eq!(again.rect, l.rect, "{want}: re-queued");
            l = again;
        }
        // Both bands as segments: accepted, the file is the float one.
        assert!(upload(&mut client, &reg, &l, good_parts(&l)).await.unwrap());
        let other = lease(&mut client).await;
        assert_ne!(other.rect, l.rect);
        assert!(upload(&mut client, &reg, &other, good_parts(&other))
            .await
            .unwrap());
        // Again: ignored, not an error.
        assert!(!upload(&mut client, &reg, &other, good_parts(&other))
            .await
            .unwrap());
        let info = f.info(job).unwrap();
        assert_eq!(info.state, JobState::Done);
        assert_eq!(f.metrics().png_segments(), 7);
        let got = std::fs::read(f.output_file(job).unwrap()).unwrap();
        assert!(got == reference(dir.path(), 40, 100));
    }
}

#[test]
fn a_float_span_over_several_bands_is_cut_by_x_and_y() {
    let dir = tempfile::tempdir().unwrap();
    let f = farm(dir.path(), true);
    // 32 × 40 in 16-pixel tiles: bands of two tiles, the last 8 rows tall.
    let job = f
        .submit(spec(32, 40, 16, "out.png"), SubmitOptions::default())
        .unwrap()
        .id;
    let wk = f.register_worker(WorkerOptions::default()).unwrap().id;
    let leases = lease_all(&f, wk);
    assert_eq!(leases.len(), 6);
    assert!(leases.windows(2).all(|p| p[1].id == p[0].id + 1));
    // Bands 1 and 2 as one span: four tiles, row-major, their union's
    // pixels row by row.
    let parts: Vec<Rect> = leases[2..].iter().map(|l| l.rect).collect();
    let union = Rect::new(0, 16, 32, 24);
    let out = f
        .put_span(
            LeaseResult {
                lease: leases[2].id,
                job,
                rect: union,
                rays: 40,
                pixels: &pixels(union),
                worker: Some(wk),
            },
            &parts,
        )
        .unwrap();
    assert_eq!(out, TileOutcome::Accepted);
    let band0 = Rect::new(0, 0, 32, 16);
    f.put_span(
        LeaseResult {
            lease: leases[0].id,
            job,
            rect: band0,
            rays: 2,
            pixels: &pixels(band0),
            worker: Some(wk),
        },
        &[leases[0].rect, leases[1].rect],
    )
    .unwrap();
    let info = f.info(job).unwrap();
    assert_eq!((info.state, info.rays), (JobState::Done, 42));
    assert!(std::fs::read(f.output_file(job).unwrap()).unwrap() == reference(dir.path(), 32, 40));
}
