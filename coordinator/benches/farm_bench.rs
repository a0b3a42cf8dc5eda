//! Benchmarks of the farm (not timed tests; results go in docs/benchmarks.md).
//!
//! ```text
//! cargo bench -p trevi-coordinator --bench farm_bench -- ingest --coordinator URL \
//!     [--width 4096] [--height 4096] [--tile 64] [--workers 8] [--format png] [--pid PID]
//! cargo bench -p trevi-coordinator --bench farm_bench -- farm [--width 4096] [--height 4096]
//! cargo bench -p trevi-coordinator --bench farm_bench -- direct SCENE.xml OUT.png [--tile 64]
//! cargo bench -p trevi-coordinator --bench farm_bench -- cost SCENE.xml [--camera ID] [--tiles 16]
//! cargo bench -p trevi-coordinator --bench farm_bench -- encode SCENE.xml [--camera ID] [--reps 5]
//! cargo bench -p trevi-coordinator --bench farm_bench -- scale --coordinator URL --pid PID \
//!     --workers N [--cores 16] --cost-ns NS [--multi] [--secs 8] [--warmup 3] [--jobs K] \
//!     [--width 2048] [--height 2048] [--tile 64] \
//!     [--segments [--seg-bytes-per-pixel 0.55 | --segments-from RENDER.png] [--lease-pixels P]] \
//!     [--metrics HOST:PORT]
//! ```
//!
//! `ingest`: synthetic workers that replay ready tiles (noise, so the PNG
//! encoder gets no easy rows) as fast as the coordinator takes them, for one
//! job of `width`×`height`. Reports tiles per second from the first lease to
//! the output in place, and with `--pid` the coordinator's peak RSS (VmHWM).
//!
//! `farm`: the same replay without the network, through `Farm::put_tile` on
//! this thread, into a discarding sink and into the real PNG writer: what
//! validation and scheduling cost alone, and with the encoder.
//!
//! `cost`: what a pixel of a real scene costs one core: `--tiles` 64×64
//! tiles spread over the camera's frame rendered on one thread; prints
//! nanoseconds per pixel (the `--cost-ns` of `scale`).
//!
//! `scale`: `--workers` simulated workers against a real coordinator, each
//! registered with `--cores` threads and, like `trevi-worker`, two leases
//! in flight of which one renders at a time: a lease "renders" by sleeping
//! its pixels × `--cost-ns` / `--cores` and returns ready pixels, telling
//! that modelled time as its render time (`render_micros`). With
//! `--multi` the workers announce leases of several tiles. `--jobs` frames
//! are kept queued (a finished one is replaced). After `--warmup` seconds,
//! measures for `--secs`: tiles/s against what the modelled workers could
//! render (the demand), lease latency p50/p99 (the `LeaseTile` calls that
//! brought work), the coordinator's CPU and peak RSS from /proc. With
//! `--metrics` (the coordinator's `--http` address), also how long its
//! state lock was held over those seconds
//! (`trevi_state_lock_held_seconds_total`): the serial part of its work,
//! and so the most cores its ingest could use, and how long the last
//! `/metrics` scrape took. Then the simulator's own CPU against the cores
//! it may use, and a verdict: the coordinator kept up when it took 95 % of
//! the demand or more, and a run short of it is not conclusive when the
//! simulator used over 90 % of its cores (`bench/scale-goal.sh` runs the
//! issue's goal this way).
//!
//! `scale --segments`: the workers also announce the coordinator's PNG
//! encoder (`RegisterRequest.png_encoder` = `PNG_ENCODER`, implying
//! `--multi`) and upload a lease with `png_segments` as `trevi-worker`
//! does: its 16-row segments, encoded before the clock starts (one per
//! segment index of the frame, from a smooth ramp with noise whose
//! amplitude is chosen so that the segments come to about
//! `--seg-bytes-per-pixel` bytes a pixel: 0.55 is the cheap scene's at
//! 480×360, see `encode`; or, with `--segments-from`, re-encoded from the
//! rows of a real render, an 8-bit RGB PNG whose size becomes the frame's),
//! and its preview sums (one cell per `preview_scale` square the
//! rect overlaps). A lease without `png_segments` is uploaded as floats,
//! as without the flag, so the mode runs against any coordinator; the
//! report says how many leases came as segments. Frames kept queued
//! (`--jobs`, 4 by default without `--segments`) are derived from N with
//! it, so that every worker has work: each of the N workers holds up to two
//! leases of about `--lease-pixels` pixels (default: a second of its
//! `--cores` at `--cost-ns`, what a lease aims at), so
//! K = ceil(2 × N × lease pixels / frame pixels) + 2, at least 4; the
//! coordinator must allow that many unfinished jobs per submitter
//! (`--max-jobs-per-submitter`, 1000 by default).
//!
//! `encode`: what the PNG part of ingesting costs per pixel, and what is
//! left to the coordinator when workers encode row segments themselves
//! (docs/benchmarks.md "The farm at scale"): renders the camera's frame,
//! then times (a) sRGB conversion, filtering and deflate of the whole frame
//! through the `png` crate's `Fast` stream writer, the farm's writer before
//! the segmented encoder, (b) the segmented encoder of trevi_core (sRGB,
//! filters and deflate of each 16-row segment alone, what `FrameWriter`,
//! and a worker encoding its own segments, do), and (c) joining those
//! segments into the file (`png_from_segments`: IDAT chunks, CRC-32,
//! Adler-32 combination), all the coordinator has left to do per pixel for
//! the image when the segments arrive encoded.
//!
//! `direct`: renders a scene's first camera in this process with no farm at
//! all (band by band, the tiles of a band in parallel on every core, straight
//! into a FrameWriter): the baseline for "one worker through the coordinator".

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tonic::transport::Channel;
use trevi_core::{Bundle, Rect};
use trevi_proto::pb::{
    self, bundles_client::BundlesClient, jobs_client::JobsClient, workers_client::WorkersClient,
};

fn arg(args: &[String], name: &str) -> Option<String> {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

fn num(args: &[String], name: &str, default: u64) -> u64 {
    arg(args, name).map_or(default, |v| v.parse().expect("a number"))
}

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| a != "--bench")
        .collect();
    match args.first().map(String::as_str) {
        Some("ingest") => ingest(&args),
        Some("direct") => direct(&args),
        Some("farm") => farm(&args),
        Some("cost") => cost(&args),
        Some("encode") => encode(&args),
        Some("scale") => scale(&args),
        _ => {
            // `cargo bench` with no arguments: nothing to do (the benchmarks
            // need a running coordinator or a scene).
            eprintln!("usage: farm_bench ingest --coordinator URL ... | direct SCENE OUT");
        }
    }
}

fn peak_rss_kib(pid: &str) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))?
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()
}

/// utime + stime of a process, in seconds (clock ticks at 100 Hz).
fn cpu_seconds(pid: &str) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: u64 = f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?;
    Some(ticks as f64 / 100.0)
}

/// `trevi_state_lock_held_seconds_total` and
/// `trevi_store_lock_held_seconds_total` from the coordinator's `/metrics`
/// at `addr` (its `--http` address), by a plain HTTP/1.0 GET.
fn lock_held_seconds(addr: &str) -> Option<[f64; 2]> {
    use std::io::{Read, Write};
    let mut c = std::net::TcpStream::connect(addr).ok()?;
    write!(c, "GET /metrics HTTP/1.0\r\nHost: {addr}\r\n\r\n").ok()?;
    let mut page = String::new();
    c.read_to_string(&mut page).ok()?;
    let read = |name: &str| -> Option<f64> {
        page.lines()
            .find_map(|l| l.strip_prefix(name)?.strip_prefix(' '))?
            .trim()
            .parse()
            .ok()
    };
    Some([
        read("trevi_state_lock_held_seconds_total")?,
        read("trevi_store_lock_held_seconds_total")?,
    ])
}

/// A render-like tile: smooth gradients with a little noise.
fn smooth_tile(seed: u32, w: u32, h: u32) -> Vec<u8> {
    let mut x = seed.wrapping_mul(2654435761).wrapping_add(777);
    let mut px = Vec::with_capacity((w * h) as usize);
    for j in 0..h {
        for i in 0..w {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let n = (x % 100) as f32 / 10000.0;
            let (u, v) = (i as f32 / w as f32, j as f32 / h as f32);
            px.push([0.2 + 0.6 * u + n, 0.3 + 0.4 * v + n, 0.5 + 0.3 * u * v + n]);
        }
    }
    trevi_proto::pixels_to_bytes(&px)
}

fn noise_tile(seed: u32, n: usize) -> Vec<u8> {
    let mut x = seed.wrapping_mul(2654435761).wrapping_add(12345);
    let px: Vec<[f32; 3]> = (0..n)
        .map(|_| {
            let mut c = [0.0; 3];
            for v in &mut c {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                *v = (x % 1000) as f32 / 1000.0;
            }
            c
        })
        .collect();
    trevi_proto::pixels_to_bytes(&px)
}

fn ingest(args: &[String]) {
    let url = arg(args, "--coordinator").expect("--coordinator URL");
    let (w, h) = (
        num(args, "--width", 4096) as u32,
        num(args, "--height", 4096) as u32,
    );
    let tile = num(args, "--tile", 64) as u32;
    let workers = num(args, "--workers", 8) as usize;
    let format = arg(args, "--format").unwrap_or_else(|| "png".into());
    let smooth = arg(args, "--content").as_deref() != Some("noise");
    let pid = arg(args, "--pid");
    let make = move |seed: u32, w: u32, h: u32| {
        if smooth {
            smooth_tile(seed, w, h)
        } else {
            noise_tile(seed, (w * h) as usize)
        }
    };
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async move {
        let channel = Channel::from_shared(url.clone())
            .unwrap()
            .connect()
            .await
            .unwrap();
        let scene = format!(
            r#"<scene version="1">
  <light type="point" position="0 5 0"/>
  <camera id="bench" position="0 0 5" lookat="0 0 0" fov="40">
    <render width="{w}" height="{h}" output="bench.{format}"/>
  </camera>
</scene>
"#
        );
        let mut files = BTreeMap::new();
        files.insert("bench.xml".to_string(), scene.into_bytes());
        let bundle = Bundle {
            scene: "bench.xml".into(),
            files,
        };
        let hash = BundlesClient::new(channel.clone())
            .upload_bundle(tokio_stream::iter([pb::BundleChunk {
                data: bundle.encode(),
            }]))
            .await
            .unwrap()
            .into_inner()
            .hash;
        // Ready tiles, made before the clock starts.
        let full: Arc<Vec<Vec<u8>>> = Arc::new((0..16).map(|s| make(s, tile, tile)).collect());
        let mut jobs = JobsClient::new(channel.clone());
        let cpu0 = pid.as_deref().and_then(cpu_seconds);
        let start = Instant::now();
        let job = jobs
            .submit_job(pb::SubmitJobRequest {
                bundle_hash: hash,
                camera: String::new(),
                priority: 0,
                tile_size: tile,
                output_format: String::new(),
                frames: None,
                progressive: None,
                ..Default::default()
            })
            .await
            .unwrap()
            .into_inner();
        let sent = Arc::new(AtomicU64::new(0));
        let mut tasks = Vec::new();
        for _ in 0..workers {
            let channel = Channel::from_shared(url.clone())
                .unwrap()
                .tcp_nodelay(true)
                .connect()
                .await
                .unwrap();
            let (full, sent) = (full.clone(), sent.clone());
            tasks.push(tokio::spawn(async move {
                let mut wc = WorkersClient::new(channel);
                let reg = wc
                    .register(pb::RegisterRequest {
                        name: "synthetic".into(),
                        threads: 1,
                        ..Default::default()
                    })
                    .await
                    .unwrap()
                    .into_inner();
                let (id, session) = (reg.worker_id, reg.session);
                loop {
                    let lease = wc
                        .lease_tile(pb::LeaseRequest {
                            worker_id: id,
                            session: session.clone(),
                            ..Default::default()
                        })
                        .await
                        .unwrap()
                        .into_inner()
                        .lease;
                    let Some(lease) = lease else { break };
                    let rect: Rect = lease.rect.unwrap().into();
                    let n = sent.fetch_add(1, Ordering::Relaxed);
                    let pixels = if rect.w == tile && rect.h == tile {
                        full[(n % 16) as usize].clone()
                    } else {
                        make(n as u32, rect.w, rect.h)
                    };
                    let msgs = vec![
                        pb::TileUpload {
                            part: Some(pb::tile_upload::Part::Header(pb::TileHeader {
                                worker_id: id,
                                lease_id: lease.lease_id,
                                job_id: lease.job_id,
                                rect: lease.rect,
                                rays: rect.pixel_count() as u64,
                                session: session.clone(),
                                frame: None,
                                render_micros: None,
                                cpu_micros: None,
                            })),
                        },
                        pb::TileUpload {
                            part: Some(pb::tile_upload::Part::Pixels(pixels)),
                        },
                    ];
                    wc.submit_tile(tokio_stream::iter(msgs)).await.unwrap();
                }
            }));
        }
        // Wait for the job to end (workers stop when no lease comes in 2 s).
        let mut watch = jobs
            .watch_job(pb::JobId { id: job.id, frame: None })
            .await
            .unwrap()
            .into_inner();
        let mut last = None;
        while let Some(s) = watch.message().await.unwrap() {
            last = Some(s);
        }
        let secs = start.elapsed().as_secs_f64();
        let last = last.unwrap();
        assert_eq!(last.state(), pb::JobState::Done, "{last:?}");
        println!(
            "ingest: {w}x{h} {format} ({} tiles), {} tiles of {tile}x{tile}, {workers} synthetic workers: \
             {secs:.2} s, {:.0} tiles/s, {:.1} Mpixel/s",
            if smooth { "smooth" } else { "noise" },
            last.tiles_total,
            last.tiles_total as f64 / secs,
            (w as f64 * h as f64) / secs / 1e6
        );
        if let (Some(a), Some(b)) = (cpu0, pid.as_deref().and_then(cpu_seconds)) {
            println!(
                "coordinator CPU: {:.2} s ({:.0} % of one core), {:.0} tiles per CPU-second",
                b - a,
                (b - a) / secs * 100.0,
                last.tiles_total as f64 / (b - a).max(1e-9)
            );
        }
        if let Some(me) = cpu_seconds("self") {
            println!("bench client CPU: {me:.2} s ({:.0} % of one core)", me / secs * 100.0);
        }
        if let Some(pid) = &pid {
            match peak_rss_kib(pid) {
                Some(k) => println!("coordinator peak RSS (VmHWM): {:.1} MiB", k as f64 / 1024.0),
                None => println!("cannot read /proc/{pid}/status"),
            }
        }
        for t in tasks {
            t.abort();
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    });
}

fn direct(args: &[String]) {
    use rayon::prelude::*;
    let scene_path = args.get(1).expect("SCENE");
    let out = args.get(2).expect("OUT");
    let tile = num(args, "--tile", 64) as u32;
    let parsed =
        trevi_core::ParsedBundle::from_scene_file(std::path::Path::new(scene_path)).expect("scene");
    let scene = trevi_core::Scene::build(parsed.desc);
    let r = &scene.desc.cameras[0].render;
    let (w, h) = (r.width, r.height);
    let start = Instant::now();
    let mut fw = trevi_core::FrameWriter::create(std::path::Path::new(out), w, h).unwrap();
    let tiles = trevi_core::tile::band_order_tiles(w, h, tile);
    for band in tiles.chunk_by(|a, b| a.y == b.y) {
        let results: Vec<_> = band
            .par_iter()
            .map(|&r| (r, trevi_core::render_tile(&scene, 0, r)))
            .collect();
        for (r, res) in results {
            fw.write_tile(r, &res.pixels).unwrap();
        }
    }
    fw.finish().unwrap();
    println!("direct: {w}x{h} in {:.3} s", start.elapsed().as_secs_f64());
}

struct NullSink;

impl trevi_coordinator::TileSink for NullSink {
    fn write_tile(&mut self, _: Rect, _: &[[f32; 3]]) -> Result<(), trevi_coordinator::SinkError> {
        Ok(())
    }
    fn finish(self: Box<Self>) -> Result<(), trevi_coordinator::SinkError> {
        Ok(())
    }
    fn rows_held(&self) -> usize {
        0
    }
}

fn farm(args: &[String]) {
    use trevi_coordinator::{Farm, FarmConfig, JobSpec, LeaseResult, SubmitOptions, WorkerOptions};
    let (w, h) = (
        num(args, "--width", 4096) as u32,
        num(args, "--height", 4096) as u32,
    );
    let tile = num(args, "--tile", 64) as u32;
    let ready: Vec<Vec<[f32; 3]>> = (0..16)
        .map(|s| trevi_proto::pixels_from_bytes(&smooth_tile(s, tile, tile)).unwrap())
        .collect();
    for sink in ["discard", "png"] {
        let dir = tempfile::tempdir().unwrap();
        let farm = Farm::new(FarmConfig::new(dir.path())).unwrap();
        let spec = JobSpec {
            frame: None,
            bundle_hash: "0".repeat(64),
            camera: "bench".into(),
            priority: 0,
            width: w,
            height: h,
            tile_size: tile,
            output_name: "bench.png".into(),
            scene: String::new(),
            submitter: String::new(),
            samples: None,
            aovs: trevi_core::Aovs::NONE,
        };
        let start = Instant::now();
        let job = if sink == "png" {
            farm.submit(spec, SubmitOptions::default()).unwrap().id
        } else {
            farm.submit(
                spec,
                SubmitOptions {
                    sink: Some(Box::new(|_| Ok(Box::new(NullSink)))),
                    ..SubmitOptions::default()
                },
            )
            .unwrap()
            .id
        };
        let worker = farm.register_worker(WorkerOptions::default()).unwrap().id;
        let mut n = 0usize;
        while let Some(l) = farm.lease(worker).unwrap() {
            let pixels = if l.rect.w == tile && l.rect.h == tile {
                ready[n % 16].clone()
            } else {
                trevi_proto::pixels_from_bytes(&smooth_tile(n as u32, l.rect.w, l.rect.h)).unwrap()
            };
            n += 1;
            farm.put_tile(LeaseResult {
                lease: l.id,
                job,
                rect: l.rect,
                rays: 1,
                pixels: &pixels,
                worker: None,
            })
            .unwrap();
        }
        let secs = start.elapsed().as_secs_f64();
        assert_eq!(
            farm.info(job).unwrap().state,
            trevi_coordinator::JobState::Done
        );
        println!(
            "farm (no network), {w}x{h}, {n} tiles of {tile}x{tile} into {sink}: {secs:.2} s, {:.0} tiles/s",
            n as f64 / secs
        );
    }
}

fn cost(args: &[String]) {
    let scene_path = args.get(1).expect("SCENE");
    let tiles = num(args, "--tiles", 16) as usize;
    let parsed =
        trevi_core::ParsedBundle::from_scene_file(std::path::Path::new(scene_path)).expect("scene");
    let scene = trevi_core::Scene::build(parsed.desc);
    let camera = match arg(args, "--camera") {
        Some(id) => scene.camera_index(&id).expect("no such camera"),
        None => 0,
    };
    let r = &scene.desc.cameras[camera].render;
    let all = trevi_core::tile::band_order_tiles(r.width, r.height, 64);
    let step = (all.len() / tiles.max(1)).max(1);
    let pick: Vec<Rect> = all.iter().step_by(step).take(tiles).copied().collect();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let (mut pixels, start) = (0u64, Instant::now());
    pool.install(|| {
        for &t in &pick {
            trevi_core::render_tile(&scene, camera, t);
            pixels += t.pixel_count() as u64;
        }
    });
    let secs = start.elapsed().as_secs_f64();
    println!(
        "cost: {scene_path} camera {camera}: {} tiles, {pixels} pixels in {secs:.3} s on one thread: \
         {:.0} ns per pixel, {:.4} core-seconds per 64x64 tile",
        pick.len(),
        secs / pixels as f64 * 1e9,
        secs / pixels as f64 * 4096.0
    );
}

/// `rows` (sRGB bytes, 3 a pixel) as a PNG in memory, encoded row by row
/// with the settings of trevi_core's PNG writer.
fn png_bytes(width: u32, rows: &[Vec<u8>]) -> Vec<u8> {
    use std::io::Write;
    // The stream writer wants to own a 'static writer: share the buffer.
    struct Shared(std::rc::Rc<std::cell::RefCell<Vec<u8>>>);
    impl Write for Shared {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.borrow_mut().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }
    let out = std::rc::Rc::new(std::cell::RefCell::new(Vec::new()));
    {
        let mut enc = png::Encoder::new(Shared(out.clone()), width, rows.len() as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
        enc.set_compression(png::Compression::Fast);
        let mut w = enc
            .write_header()
            .unwrap()
            .into_stream_writer_with_size(1 << 16)
            .unwrap();
        for r in rows {
            w.write_all(r).unwrap();
        }
        w.finish().unwrap();
    }
    out.take()
}

fn encode(args: &[String]) {
    use rayon::prelude::*;
    let scene_path = args.get(1).expect("SCENE");
    let reps = num(args, "--reps", 5).max(1) as usize;
    let parsed =
        trevi_core::ParsedBundle::from_scene_file(std::path::Path::new(scene_path)).expect("scene");
    let scene = trevi_core::Scene::build(parsed.desc);
    let camera = match arg(args, "--camera") {
        Some(id) => scene.camera_index(&id).expect("no such camera"),
        None => 0,
    };
    let r = &scene.desc.cameras[camera].render;
    let (w, h) = (r.width, r.height);
    // The frame's pixels, row by row (a bench may hold a small frame).
    let lines: Vec<Vec<[f32; 3]>> = (0..h)
        .into_par_iter()
        .map(|y| trevi_core::render_tile(&scene, camera, Rect::new(0, y, w, 1)).pixels)
        .collect();
    let px = f64::from(w) * f64::from(h);
    let srgb = trevi_core::output::Srgb8::new();
    let to_rows = |ls: &[Vec<[f32; 3]>]| -> Vec<Vec<u8>> {
        ls.iter()
            .map(|l| l.iter().flatten().map(|&c| srgb.encode(c)).collect())
            .collect()
    };
    let best = |f: &mut dyn FnMut() -> usize| {
        let mut t = f64::INFINITY;
        let mut n = 0;
        for _ in 0..reps {
            let s = Instant::now();
            n = f();
            t = t.min(s.elapsed().as_secs_f64());
        }
        (t, n)
    };
    // (a) The whole frame through one encoder, as the coordinator does.
    let (whole, whole_bytes) = best(&mut || png_bytes(w, &to_rows(&lines)).len());
    // (b) The segmented encoder: each 16-row segment from linear pixels.
    let seg_h = trevi_core::output::SEGMENT_ROWS as usize;
    let mut segments = Vec::new();
    let (seg, seg_bytes) = best(&mut || {
        segments = lines
            .chunks(seg_h)
            .map(|c| trevi_core::output::encode_segment(w, &c.concat()))
            .collect();
        trevi_core::output::png_from_segments(w, h, &segments)
            .expect("segments")
            .len()
    });
    // (c) What is left to the coordinator: the file from encoded segments.
    let (append, _) = best(&mut || {
        let file = trevi_core::output::png_from_segments(w, h, &segments).expect("segments");
        std::hint::black_box(file.len())
    });
    let ns = |t: f64| t / px * 1e9;
    println!(
        "encode: {scene_path} camera {camera}, {w}x{h}, best of {reps}:\n  \
         png crate, whole frame (sRGB + filter + deflate): {:.2} ns/pixel, {whole_bytes} bytes \
         ({:.2} bytes/pixel)\n  \
         segmented encoder, 16-row segments (sRGB + filter + deflate + file): {:.2} ns/pixel, \
         {seg_bytes} bytes ({:+.1} %)\n  \
         the file from encoded segments (chunks, CRC-32, Adler-32): {:.3} ns/pixel \
         ({:.0}x less than encoding)",
        ns(whole),
        whole_bytes as f64 / px,
        ns(seg),
        (seg_bytes as f64 / whole_bytes as f64 - 1.0) * 100.0,
        ns(append),
        whole / append.max(1e-12),
    );
}

/// What the simulated workers saw.
#[derive(Default)]
struct ScaleStats {
    measuring: bool,
    tiles: u64,
    leases: u64,
    /// Microseconds of the `LeaseTile` calls that brought work.
    latency_us: Vec<u32>,
    /// Leases uploaded as encoded segments, and their pixels and bytes.
    segment_leases: u64,
    segment_pixels: u64,
    segment_bytes: u64,
}

/// A frame's PNG segments, encoded once, and the bytes a pixel they take.
struct ReadySegments {
    segments: Vec<pb::EncodedSegment>,
    width: u32,
    height: u32,
    bytes_per_pixel: f64,
    noise: f32,
}

/// Linear pixels of rows `y0..y1` of a `w`-wide frame: a smooth ramp with
/// `noise` (linear units, deterministic) on it.
fn ramp_rows(w: u32, y0: u32, y1: u32, h: u32, noise: f32) -> Vec<[f32; 3]> {
    let mut out = Vec::with_capacity(w as usize * (y1 - y0) as usize);
    for y in y0..y1 {
        for x in 0..w {
            let mut k =
                (x.wrapping_mul(73856093) ^ y.wrapping_mul(19349663)).wrapping_mul(2654435761);
            let (u, v) = (x as f32 / w as f32, y as f32 / h.max(1) as f32);
            let base = [0.15 + 0.6 * u, 0.25 + 0.5 * v, 0.4 + 0.3 * u * v];
            out.push(base.map(|b| {
                k ^= k >> 15;
                k = k.wrapping_mul(2246822519);
                b + noise * ((k >> 8) as f32 / (1u32 << 24) as f32)
            }));
        }
    }
    out
}

/// Every segment of a `w`×`h` frame encoded with `encode_segment`, from
/// [`ramp_rows`] with the noise that brings them to about `target` bytes a
/// pixel (bisected on three of them).
fn ready_segments(w: u32, h: u32, target: f64) -> ReadySegments {
    use trevi_core::output::{encode_segment, segment_count, segment_rows};
    // Calibrated on three segments spread over the frame (the ramp makes
    // them differ).
    let n = segment_count(h);
    let sample: Vec<_> = [0, n / 2, n.saturating_sub(1)]
        .into_iter()
        .map(|i| segment_rows(h, i))
        .collect();
    let px0: f64 = sample
        .iter()
        .map(|r| f64::from(w) * f64::from(r.end - r.start))
        .sum();
    let size = |noise: f32| {
        let bytes: usize = sample
            .iter()
            .map(|r| {
                encode_segment(w, &ramp_rows(w, r.start, r.end, h, noise))
                    .deflate
                    .len()
            })
            .sum();
        bytes as f64 / px0
    };
    let (mut lo, mut hi) = (0f32, 1f32);
    for _ in 0..20 {
        let mid = 0.5 * (lo + hi);
        if size(mid) < target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let noise = 0.5 * (lo + hi);
    encode_all(w, h, noise, |rows| {
        encode_segment(w, &ramp_rows(w, rows.start, rows.end, h, noise))
    })
}

/// Every segment of a `w`×`h` frame, `encode` making segment `i` from its
/// rows, in parallel; `noise` is recorded as the ramp's.
fn encode_all(
    w: u32,
    h: u32,
    noise: f32,
    encode: impl Fn(std::ops::Range<u32>) -> trevi_core::output::PngSegment + Sync,
) -> ReadySegments {
    use rayon::prelude::*;
    use trevi_core::output::{segment_count, segment_rows};
    let segments: Vec<pb::EncodedSegment> = (0..segment_count(h))
        .into_par_iter()
        .map(|i| {
            let s = encode(segment_rows(h, i));
            pb::EncodedSegment {
                index: i,
                deflate: s.deflate,
                adler32: s.adler32,
                filtered_len: s.filtered_len,
            }
        })
        .collect();
    let bytes: usize = segments.iter().map(|s| s.deflate.len()).sum();
    ReadySegments {
        segments,
        width: w,
        height: h,
        bytes_per_pixel: bytes as f64 / (f64::from(w) * f64::from(h)),
        noise,
    }
}

/// Every segment of a real render (an 8-bit RGB PNG, such as trevi-submit
/// writes) re-encoded from its rows with `encode_segment_srgb`, as the
/// workers that rendered it would have sent them.
fn segments_from_png(path: &str) -> ReadySegments {
    use trevi_core::output::encode_segment_srgb;
    let file = std::fs::File::open(path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let mut reader = png::Decoder::new(std::io::BufReader::new(file))
        .read_info()
        .unwrap_or_else(|e| panic!("{path}: {e}"));
    let info = reader.info();
    let (w, h) = (info.width, info.height);
    assert_eq!(
        (info.color_type, info.bit_depth),
        (png::ColorType::Rgb, png::BitDepth::Eight),
        "{path}: not 8-bit RGB"
    );
    let mut pixels = vec![0u8; 3 * w as usize * h as usize];
    reader
        .next_frame(&mut pixels)
        .unwrap_or_else(|e| panic!("{path}: {e}"));
    let stride = 3 * w as usize;
    encode_all(w, h, 0.0, |r| {
        let rows: Vec<&[u8]> = pixels[r.start as usize * stride..r.end as usize * stride]
            .chunks_exact(stride)
            .collect();
        encode_segment_srgb(w, &rows)
    })
}

/// Plausible preview sums for `rect` in cells of `scale` (half-grey
/// pixels): as many floats as the proto's `PreviewSums` asks.
fn preview_for(rect: Rect, scale: u32) -> Vec<f32> {
    let s = scale.max(1);
    if rect.w == 0 || rect.h == 0 {
        return Vec::new();
    }
    let cells = |a: u32, n: u32| {
        (a / s..=(a + n - 1) / s).map(move |c| (c * s).max(a)..((c + 1) * s).min(a + n))
    };
    let mut out = Vec::new();
    for ys in cells(rect.y, rect.h) {
        for xs in cells(rect.x, rect.w) {
            let n = ((ys.end - ys.start) * (xs.end - xs.start)) as f32;
            out.extend([0.5 * n; 3]);
        }
    }
    out
}

fn scale(args: &[String]) {
    use std::sync::Mutex;
    let url = arg(args, "--coordinator").expect("--coordinator URL");
    let pid = arg(args, "--pid");
    let metrics = arg(args, "--metrics");
    let workers = num(args, "--workers", 10) as usize;
    let cores = num(args, "--cores", 16) as u32;
    let cost_ns = arg(args, "--cost-ns")
        .expect("--cost-ns (see the cost mode)")
        .parse::<f64>()
        .expect("a number");
    let segments = args
        .iter()
        .any(|a| a == "--segments" || a == "--segments-from");
    let multi = segments || args.iter().any(|a| a == "--multi");
    let secs = num(args, "--secs", 8);
    let warmup = num(args, "--warmup", 3);
    // A real render's segments fix the frame's size; the ramp's are made
    // for the size given.
    let t0 = Instant::now();
    let from_png = arg(args, "--segments-from").map(|p| segments_from_png(&p));
    let (w, h) = match &from_png {
        Some(r) => (r.width, r.height),
        None => (
            num(args, "--width", 2048) as u32,
            num(args, "--height", 2048) as u32,
        ),
    };
    let tile = num(args, "--tile", 64) as u32;
    // Frames kept queued: given, 4 for floats, or enough for N workers
    // holding two leases of about a second each (see the module's doc).
    let lease_pixels = arg(args, "--lease-pixels").map_or(f64::from(cores) * 1e9 / cost_ns, |v| {
        v.parse::<f64>().expect("a number")
    });
    let derived =
        ((2.0 * workers as f64 * lease_pixels / (f64::from(w) * f64::from(h))).ceil() as usize + 2)
            .max(4);
    let jobs_kept = match arg(args, "--jobs") {
        Some(k) => k.parse().expect("a number"),
        None if segments => derived,
        None => 4,
    };
    // Ready pixels for a band; bigger leases repeat them.
    let ready: Arc<Vec<u8>> = Arc::new(smooth_tile(1, w, tile));
    let encoded = segments.then(|| {
        let target = arg(args, "--seg-bytes-per-pixel").map_or(0.55, |v| v.parse().expect("a number"));
        let r = from_png.unwrap_or_else(|| ready_segments(w, h, target));
        eprintln!(
            "scale: {} segments of {w}x{h} encoded in {:.1} s: {:.3} bytes/pixel (noise {:.4}), {jobs_kept} frames kept queued",
            r.segments.len(),
            t0.elapsed().as_secs_f64(),
            r.bytes_per_pixel,
            r.noise
        );
        Arc::new(r)
    });
    let seg_bpp = encoded.as_ref().map(|r| r.bytes_per_pixel);
    let stats = Arc::new(Mutex::new(ScaleStats::default()));
    let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async move {
        let connect = || async {
            Channel::from_shared(url.clone())
                .unwrap()
                .tcp_nodelay(true)
                .connect()
                .await
                .unwrap()
        };
        let channel = connect().await;
        let scene = format!(
            r#"<scene version="1">
  <light type="point" position="0 5 0"/>
  <camera id="bench" position="0 0 5" lookat="0 0 0" fov="40">
    <render width="{w}" height="{h}" output="bench.png"/>
  </camera>
</scene>
"#
        );
        let mut files = BTreeMap::new();
        files.insert("bench.xml".to_string(), scene.into_bytes());
        let bundle = Bundle {
            scene: "bench.xml".into(),
            files,
        };
        let hash = BundlesClient::new(channel.clone())
            .upload_bundle(tokio_stream::iter([pb::BundleChunk {
                data: bundle.encode(),
            }]))
            .await
            .unwrap()
            .into_inner()
            .hash;
        // Keeps `jobs_kept` frames queued: each slot submits a frame, waits
        // for its end, and submits the next.
        let mut tasks = Vec::new();
        for _ in 0..jobs_kept {
            let (channel, hash, stop) = (channel.clone(), hash.clone(), stop.clone());
            tasks.push(tokio::spawn(async move {
                let mut jobs = JobsClient::new(channel);
                while !stop.load(Ordering::Relaxed) {
                    let job = jobs
                        .submit_job(pb::SubmitJobRequest {
                            bundle_hash: hash.clone(),
                            camera: String::new(),
                            priority: 0,
                            tile_size: tile,
                            output_format: String::new(),
                            frames: None,
                            progressive: None,
                            ..Default::default()
                        })
                        .await
                        .unwrap()
                        .into_inner();
                    let mut watch = jobs.watch_job(pb::JobId { id: job.id, frame: None }).await.unwrap().into_inner();
                    while let Ok(Some(_)) = watch.message().await {}
                }
            }));
        }
        // One connection per worker up to 256 (the rest share them), so
        // the bench stays under its open-files limit.
        let mut channels = Vec::new();
        for _ in 0..workers.min(256) {
            channels.push(connect().await);
        }
        // Registered all at once: one after the other, the last of 1,000
        // waited minutes behind the lease loops of the first.
        let mut registering = tokio::task::JoinSet::new();
        for i in 0..workers {
            let mut wc = WorkersClient::new(channels[i % channels.len()].clone())
                .max_decoding_message_size(usize::MAX);
            registering.spawn(async move {
                let reg = wc
                    .register(pb::RegisterRequest {
                        name: format!("sim-{i}"),
                        threads: cores,
                        multi_tile: multi,
                        png_encoder: if segments {
                            trevi_core::output::PNG_ENCODER.into()
                        } else {
                            String::new()
                        },
                        ..Default::default()
                    })
                    .await
                    .unwrap()
                    .into_inner();
                (wc, reg)
            });
        }
        while let Some(registered) = registering.join_next().await {
            let (wc, reg) = registered.unwrap();
            let render = Arc::new(tokio::sync::Semaphore::new(1));
            for _ in 0..2 {
                let (mut wc, session, render) = (wc.clone(), reg.session.clone(), render.clone());
                let (ready, stats, stop) = (ready.clone(), stats.clone(), stop.clone());
                let encoded = encoded.clone();
                let id = reg.worker_id;
                tasks.push(tokio::spawn(async move {
                    while !stop.load(Ordering::Relaxed) {
                        let permit = render.clone().acquire_owned().await.unwrap();
                        let t0 = Instant::now();
                        let Ok(lease) = wc
                            .lease_tile(pb::LeaseRequest {
                                worker_id: id,
                                session: session.clone(),
                                max_wait_ms: 500,
                            })
                            .await
                        else {
                            return;
                        };
                        let latency = t0.elapsed();
                        let Some(lease) = lease.into_inner().lease else {
                            continue;
                        };
                        let rect: Rect = lease.rect.unwrap().into();
                        let px = rect.pixel_count() as u64;
                        let render = Duration::from_nanos(
                            (px as f64 * cost_ns / f64::from(cores)) as u64,
                        );
                        tokio::time::sleep(render).await;
                        drop(permit);
                        let mut msgs = vec![pb::TileUpload {
                            part: Some(pb::tile_upload::Part::Header(pb::TileHeader {
                                worker_id: id,
                                lease_id: lease.lease_id,
                                job_id: lease.job_id,
                                rect: lease.rect,
                                rays: px,
                                session: session.clone(),
                                frame: None,
                                // Like trevi-worker: the render's own time
                                // (the modelled one), which sizes leases.
                                render_micros: Some(render.as_micros() as u64),
                                cpu_micros: None,
                            })),
                        }];
                        let mut seg_bytes = 0u64;
                        match encoded.as_deref().filter(|_| lease.png_segments) {
                            Some(enc) => {
                                // The rect's segments, as trevi-worker uploads them.
                                let first = rect.y / trevi_core::output::SEGMENT_ROWS;
                                let n = rect.h.div_ceil(trevi_core::output::SEGMENT_ROWS);
                                for s in enc.segments.iter().skip(first as usize).take(n as usize) {
                                    seg_bytes += s.deflate.len() as u64;
                                    msgs.push(pb::TileUpload {
                                        part: Some(pb::tile_upload::Part::Segment(s.clone())),
                                    });
                                }
                                msgs.push(pb::TileUpload {
                                    part: Some(pb::tile_upload::Part::Preview(pb::PreviewSums {
                                        sums: preview_for(rect, lease.preview_scale),
                                    })),
                                });
                            }
                            None => {
                                // Floats: the ready band's bytes, repeated
                                // for a lease bigger than a band.
                                let mut left = px as usize * 12;
                                while left > 0 {
                                    let n = left.min(trevi_proto::CHUNK_SIZE).min(ready.len());
                                    msgs.push(pb::TileUpload {
                                        part: Some(pb::tile_upload::Part::Pixels(ready[..n].to_vec())),
                                    });
                                    left -= n;
                                }
                            }
                        }
                        let Ok(ack) = wc.submit_tile(tokio_stream::iter(msgs)).await else {
                            return;
                        };
                        let mut st = stats.lock().unwrap();
                        if st.measuring {
                            if lease.png_segments && encoded.is_some() {
                                st.segment_leases += 1;
                                st.segment_pixels += px;
                                st.segment_bytes += seg_bytes;
                            }
                            st.leases += 1;
                            st.latency_us.push(latency.as_micros().min(u32::MAX as u128) as u32);
                            if ack.into_inner().accepted {
                                st.tiles += u64::from(lease.tiles.max(1));
                            }
                        }
                    }
                }));
            }
        }
        tokio::time::sleep(Duration::from_secs(warmup)).await;
        let cpu0 = pid.as_deref().and_then(cpu_seconds);
        let own0 = cpu_seconds("self");
        let held0 = metrics.as_deref().and_then(lock_held_seconds);
        stats.lock().unwrap().measuring = true;
        let start = Instant::now();
        tokio::time::sleep(Duration::from_secs(secs)).await;
        let st = std::mem::take(&mut *stats.lock().unwrap());
        let elapsed = start.elapsed().as_secs_f64();
        let cpu1 = pid.as_deref().and_then(cpu_seconds);
        let own1 = cpu_seconds("self");
        let scrape = Instant::now();
        let held1 = metrics.as_deref().and_then(lock_held_seconds);
        let scrape = scrape.elapsed();
        let cpu = match (cpu0, cpu1) {
            (Some(a), Some(b)) => format!("{:.0} %", (b - a) / elapsed * 100.0),
            _ => "?".into(),
        };
        let rss = pid
            .as_deref()
            .and_then(peak_rss_kib)
            .map_or("?".into(), |k| format!("{:.0} MiB", k as f64 / 1024.0));
        stop.store(true, Ordering::Relaxed);
        let mut lat = st.latency_us;
        lat.sort_unstable();
        let pct = |p: f64| {
            lat.get(((lat.len() as f64 * p) as usize).min(lat.len().saturating_sub(1)))
                .map_or(f64::NAN, |&us| us as f64 / 1000.0)
        };
        let tiles_s = st.tiles as f64 / elapsed;
        let demand = workers as f64 * f64::from(cores) * 1e9 / (cost_ns * f64::from(tile * tile));
        println!(
            "scale: workers {workers} x {cores} cores, {cost_ns:.0} ns/pixel, {}: {tiles_s:.0} tiles/s \
             ({:.1} Mpixel/s) of {demand:.0} modelled ({:.0} %), {:.1} tiles/lease, lease p50 {:.2} ms \
             p99 {:.2} ms, coordinator CPU {cpu} of one core, peak RSS {rss}",
            if segments {
                "sized leases, encoded segments"
            } else if multi {
                "multi-tile leases"
            } else {
                "one tile per lease"
            },
            tiles_s * f64::from(tile * tile) / 1e6,
            tiles_s / demand * 100.0,
            st.tiles as f64 / st.leases.max(1) as f64,
            pct(0.5),
            pct(0.99),
        );
        if let (Some(a), Some(b)) = (held0, held1) {
            let [state, store] = [0, 1].map(|i| (b[i] - a[i]) / elapsed);
            let of_cpu = match (cpu0, cpu1) {
                (Some(c0), Some(c1)) if c1 > c0 => format!(
                    " ({:.1} % and {:.1} % of its CPU)",
                    state * elapsed / (c1 - c0) * 100.0,
                    store * elapsed / (c1 - c0) * 100.0
                ),
                _ => String::new(),
            };
            println!(
                "locks: the coordinator's state lock was held {:.1} % of the time, the store's \
                 {:.1} %{of_cpu}: its ingest could use at most {:.1} cores at this load; a \
                 /metrics scrape under this load took {:.1} ms",
                state * 100.0,
                store * 100.0,
                1.0 / state.max(store).max(1e-9),
                scrape.as_secs_f64() * 1e3,
            );
        }
        // The simulator's own CPU against the cores it may use: a simulator
        // that used nearly all of them may have limited the run itself.
        let own_cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let own = own0.zip(own1).map(|(a, b)| (b - a) / elapsed);
        if let Some(own) = own {
            println!(
                "simulator: {:.0} % of one core, of the {own_cores} it may use",
                own * 100.0
            );
        }
        let verdict = if tiles_s >= 0.95 * demand {
            "the coordinator kept up with the demand (95 % of it or more)"
        } else if own.is_some_and(|c| c > 0.9 * own_cores as f64) {
            "short of the demand, but the simulator used over 90 % of its cores: not conclusive"
        } else {
            "the coordinator did not keep up with the demand"
        };
        println!("verdict: {verdict}");
        if let Some(bpp) = seg_bpp {
            println!(
                "segments: {jobs_kept} frames kept queued; {} of {} leases uploaded as segments \
                 ({:.3} bytes/pixel sent, {:.3} prepared), the rest as floats",
                st.segment_leases,
                st.leases,
                st.segment_bytes as f64 / st.segment_pixels.max(1) as f64,
                bpp,
            );
        }
        for t in tasks {
            t.abort();
        }
    });
    rt.shutdown_timeout(Duration::from_millis(100));
}
