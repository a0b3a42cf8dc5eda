//! Benchmarks of the farm (not timed tests; results go in docs/benchmarks.md).
//!
//! ```text
//! cargo bench -p trevi-coordinator --bench farm_bench -- ingest --coordinator URL \
//!     [--width 4096] [--height 4096] [--tile 64] [--workers 8] [--format png] [--pid PID]
//! cargo bench -p trevi-coordinator --bench farm_bench -- farm [--width 4096] [--height 4096]
//! cargo bench -p trevi-coordinator --bench farm_bench -- direct SCENE.xml OUT.png [--tile 64]
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
            .watch_job(pb::JobId { id: job.id })
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
    use trevi_coordinator::{Farm, FarmConfig, JobSpec, SubmitOptions, TileResult, WorkerOptions};
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
            bundle_hash: "0".repeat(64),
            camera: "bench".into(),
            priority: 0,
            width: w,
            height: h,
            tile_size: tile,
            output_name: "bench.png".into(),
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
            farm.put_tile(TileResult {
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
