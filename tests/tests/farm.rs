//! The render farm end to end: a real `trevi-coordinator`, real
//! `trevi-worker`s and `trevi-submit`, on 127.0.0.1 ephemeral ports.
//!
//! The binaries are the workspace's own: `cargo test --workspace` builds them
//! next to this test's executable (its grandparent directory).
//!
//! Each test works in its own temporary directory; on failure the message
//! carries every process's log.

mod common;

use common::fake_worker::grey;
use common::*;
use std::process::Command;
use trevi_proto::pb;

const SCENE: &str = r#"<scene version="1">
  <settings background="0.1 0.1 0.2" ambient="0.1 0.1 0.1"/>
  <sphere id="ball" center="0 1 0" radius="1">
    <surface diffuse="0.8 0.3 0.2" specular="0.5 0.5 0.5" shininess="40" reflectivity="0.2"/>
  </sphere>
  <plane id="ground" point="0 0 0" normal="0 1 0"> <surface diffuse="0.5 0.5 0.5"/> </plane>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1"/>
  <camera id="main" position="0 2 6" lookat="0 1 0" up="0 1 0" fov="50">
    <render width="64" height="48" supersample="2" output="main.png"/>
  </camera>
</scene>
"#;

fn coordinator(dir: &Dir, lease_ttl_ms: u64) -> Coordinator {
    coordinator_at(dir, lease_ttl_ms, "127.0.0.1:0", "coordinator")
}

fn coordinator_at(dir: &Dir, lease_ttl_ms: u64, listen: &str, name: &str) -> Coordinator {
    let ttl = lease_ttl_ms.to_string();
    coordinator_with(dir, listen, name, &["--lease-ttl-ms", &ttl], &[])
}

fn worker(dir: &Dir, url: &str, name: &str) -> Proc {
    worker_with(dir, url, name, &[], &[])
}

#[test]
fn three_workers_render_the_same_bytes_as_the_embedded_render() {
    let dir = Dir::new();
    let scene = dir.write("scene/s.xml", SCENE);
    let expected = embedded(&dir, &scene, "embedded.png");
    let c = coordinator(&dir, 10_000);
    let _w: Vec<Proc> = (0..3)
        .map(|i| worker(&dir, &c.url, &format!("worker{i}")))
        .collect();
    let got = farm_render(&dir, &c.url, &scene, "farm.png", 16);
    assert!(got == expected, "farm output differs\n{}", dir.logs());
    // And both are what core renders by itself, with no farm code.
    assert_same_pixels(
        &got,
        &core_render(&dir, &scene, "core.png"),
        "the farm's PNG",
    );
    // The farm's jobs can be listed and looked at.
    let list = submit(&dir, &["list", "--coordinator", &c.url]);
    let text = String::from_utf8_lossy(&list.stdout);
    assert!(
        list.status.success() && text.contains("done"),
        "{text}\n{}",
        dir.logs()
    );
    let status = submit(&dir, &["status", "1", "--coordinator", &c.url]);
    assert!(String::from_utf8_lossy(&status.stdout).contains("12/12 tiles"));
}

#[test]
fn health_and_reflection_answer() {
    let dir = Dir::new();
    let c = coordinator(&dir, 10_000);
    let rt = runtime();
    rt.block_on(async {
        use tonic_health::pb::{health_client::HealthClient, HealthCheckRequest};
        let channel = channel(&c).await;
        let mut h = HealthClient::new(channel.clone());
        for service in ["", "trevi.v1.Jobs", "trevi.v1.Workers", "trevi.v1.Bundles"] {
            let r = h
                .check(HealthCheckRequest {
                    service: service.into(),
                })
                .await
                .unwrap()
                .into_inner();
            assert_eq!(r.status, 1, "{service} is not SERVING");
        }

        use tonic_reflection::pb::v1::{
            server_reflection_client::ServerReflectionClient,
            server_reflection_request::MessageRequest, server_reflection_response::MessageResponse,
            ServerReflectionRequest,
        };
        let mut r = ServerReflectionClient::new(channel);
        let req = ServerReflectionRequest {
            host: String::new(),
            message_request: Some(MessageRequest::ListServices(String::new())),
        };
        let mut stream = r
            .server_reflection_info(tokio_stream::iter([req]))
            .await
            .unwrap()
            .into_inner();
        let msg = stream.message().await.unwrap().unwrap();
        let Some(MessageResponse::ListServicesResponse(list)) = msg.message_response else {
            panic!("unexpected reflection answer {msg:?}");
        };
        let names: Vec<String> = list.service.into_iter().map(|s| s.name).collect();
        for s in [
            "trevi.v1.Jobs",
            "trevi.v1.Workers",
            "trevi.v1.Bundles",
            "grpc.health.v1.Health",
        ] {
            assert!(names.iter().any(|n| n == s), "{s} missing from {names:?}");
        }
    });
}

#[test]
fn a_worker_killed_mid_job_does_not_stop_the_job() {
    let dir = Dir::new();
    let scene = dir.write("s.xml", SLOW_SCENE);
    let expected = embedded(&dir, &scene, "embedded.png");
    let c = coordinator(&dir, 700);
    let mut doomed = worker(&dir, &c.url, "doomed");
    let out = dir.path().join("farm.png");
    let mut sub = spawn_farm_submit(&dir, &c.url, &scene, &out, 16);
    let rt = runtime();
    wait_for(&dir, "the first tiles", 60, || {
        try_job(&rt, &c, 1).is_some_and(|s| s.tiles_done >= 3)
    });
    doomed.0.kill().unwrap(); // SIGKILL
    doomed.0.wait().unwrap();
    let s = job(&rt, &c, 1);
    assert!(
        s.tiles_done < s.tiles_total,
        "the job ended before the kill; make the scene slower"
    );
    let _others = [worker(&dir, &c.url, "w1"), worker(&dir, &c.url, "w2")];
    let status = wait_child(&dir, &mut sub, 120);
    assert!(status.success(), "{}", dir.logs());
    let got = std::fs::read(&out).unwrap();
    assert!(got == expected, "output differs\n{}", dir.logs());
    assert_same_pixels(&got, &core_render(&dir, &scene, "core.png"), "after a kill");
}

#[test]
fn wrong_size_and_nan_tiles_are_rejected_requeued_and_the_job_completes() {
    let dir = Dir::new();
    let scene = dir.write("s.xml", SCENE);
    let expected = embedded(&dir, &scene, "embedded.png");
    let c = coordinator(&dir, 10_000);
    let out = dir.path().join("farm.png");
    let mut sub = spawn_farm_submit(&dir, &c.url, &scene, &out, 16);
    let rt = runtime();
    rt.block_on(async {
        let mut w = FakeWorker::register(&workers(&c, None).await, "liar").await;
        let lease = w.lease().await;
        let rect: trevi_core::Rect = lease.rect.unwrap().into();
        // Too few pixels.
        let short = grey(rect.pixel_count() - 1);
        let e = w.send(w.header(&lease), vec![short]).await.unwrap_err();
        assert_eq!(e.code(), tonic::Code::InvalidArgument, "{e:?}");
        // The tile is back in the queue, first.
        let again = w.try_lease().await.unwrap();
        assert_eq!(again.rect, lease.rect);
        let mut nan = vec![[0.5f32; 3]; rect.pixel_count()];
        nan[3][2] = f32::NAN;
        let nan = trevi_proto::pixels_to_bytes(&nan);
        let e = w.send(w.header(&again), vec![nan]).await.unwrap_err();
        assert_eq!(e.code(), tonic::Code::InvalidArgument, "{e:?}");
        let s = jobs(&c, None)
            .await
            .get_job(pb::JobId { id: 1, frame: None })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(s.tiles_done, 0);
    });
    let _w = worker(&dir, &c.url, "honest");
    let status = wait_child(&dir, &mut sub, 60);
    assert!(status.success(), "{}", dir.logs());
    assert!(
        std::fs::read(&out).unwrap() == expected,
        "output differs\n{}",
        dir.logs()
    );
}

#[test]
fn priorities_order_jobs_and_a_cancelled_job_stops_and_leaves_no_output() {
    let dir = Dir::new();
    let scene = dir.write("s.xml", SCENE);
    let slow = dir.write("slow.xml", SLOW_SCENE);
    let c = coordinator(&dir, 10_000);
    let detach =
        |scene, priority| detach(&dir, &c, scene, &["--priority", priority, "--tile", "16"]);
    let low = detach(&scene, "-1");
    let high = detach(&scene, "5");
    let doomed = detach(&slow, "9");
    let rt = runtime();
    // One tile in flight: priority orders the leases, so the finish order
    // follows from it only when the worker takes a lease after the last
    // is in. With two in flight, low's first lease (a whole-frame span,
    // its cost known from high's identical bundle) can go out while high's
    // last tile renders, and finish first: CI saw exactly that.
    let _w = worker_with(&dir, &c.url, "worker", &["--tiles-in-flight", "1"], &[]);
    wait_for(&dir, "the doomed job to start", 60, || {
        job(&rt, &c, doomed).tiles_done >= 2
    });
    let o = submit(
        &dir,
        &["cancel", &doomed.to_string(), "--coordinator", &c.url],
    );
    assert!(o.status.success(), "{}", dir.logs());
    assert!(String::from_utf8_lossy(&o.stdout).contains("cancelled"));
    let at_cancel = job(&rt, &c, doomed).tiles_done;
    wait_for(&dir, "both jobs", 60, || {
        job(&rt, &c, low).state == pb::JobState::Done as i32
    });
    let (l, h, d) = (job(&rt, &c, low), job(&rt, &c, high), job(&rt, &c, doomed));
    assert_eq!(h.state, pb::JobState::Done as i32);
    assert!(
        h.finish_order < l.finish_order,
        "high priority finished after low: {h:?} {l:?}"
    );
    assert_eq!(d.state, pb::JobState::Cancelled as i32);
    // At most the tile in hand when it was cancelled counts afterwards.
    assert!(d.tiles_done <= at_cancel + 1, "{d:?} vs {at_cancel}");
    assert!(d.tiles_done < d.tiles_total);
    // No output anywhere for the cancelled job.
    assert!(
        !c.data.join("jobs").join(doomed.to_string()).exists(),
        "{}",
        dir.logs()
    );
    assert!(!dir.path().join("slow.png").exists());
    let e = rt.block_on(async {
        let mut s = jobs(&c, None)
            .await
            .download_output(pb::JobId {
                id: doomed,
                frame: None,
            })
            .await?
            .into_inner();
        s.message().await
    });
    assert_eq!(e.unwrap_err().code(), tonic::Code::FailedPrecondition);
}

const OUTSIDE_SCENE: &str = r#"<scene version="1">
  <mesh id="m" file="../outside.obj"/>
  <model id="x" mesh="m"/>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1"/>
  <camera id="main" position="0 2 6" lookat="0 1 0" up="0 1 0" fov="50">
    <render width="8" height="8" output="o.png"/>
  </camera>
</scene>
"#;

#[test]
fn a_bundle_reaching_outside_its_directory_is_refused_by_submit_and_coordinator() {
    let dir = Dir::new();
    dir.write("outside.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let scene = dir.write("scene/s.xml", OUTSIDE_SCENE);
    let c = coordinator(&dir, 10_000);
    let o = submit(&dir, &[scene.to_str().unwrap(), "--coordinator", &c.url]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "submit accepted it");
    assert!(err.contains("outside.obj"), "{err}");
    assert!(!dir.path().join("scene/o.png").exists());

    // A hand-made client sends the same scene anyway; and a bundle whose
    // file list itself climbs out.
    let rt = runtime();
    rt.block_on(async {
        use trevi_core::Bundle;
        let mut b = bundles(&c, None).await;
        let mut files = std::collections::BTreeMap::new();
        files.insert("s.xml".to_string(), OUTSIDE_SCENE.as_bytes().to_vec());
        let bundle = Bundle {
            scene: "s.xml".into(),
            files: files.clone(),
        };
        let hash = upload(&mut b, vec![bundle.encode()]).await.unwrap();
        let e = submit_job(&c, &hash).await.unwrap_err();
        assert_eq!(e.code(), tonic::Code::InvalidArgument);
        assert!(e.message().contains("outside.obj"), "{}", e.message());

        files.insert("../outside.obj".to_string(), b"v 0 0 0".to_vec());
        let sneaky = Bundle {
            scene: "s.xml".into(),
            files,
        };
        let e = upload(&mut b, vec![sneaky.encode()]).await.unwrap_err();
        assert_eq!(e.code(), tonic::Code::InvalidArgument, "{e:?}");
    });
}

#[test]
fn sigterm_makes_a_worker_give_its_tiles_back_and_exit() {
    let dir = Dir::new();
    let scene = dir.write("s.xml", SLOW_SCENE);
    let expected = embedded(&dir, &scene, "embedded.png");
    // Leases that outlive their worker would stall the job for a minute:
    // the stopping worker gives its lease back instead.
    let c = coordinator(&dir, 60_000);
    let mut first = worker(&dir, &c.url, "first");
    let out = dir.path().join("farm.png");
    let mut sub = spawn_farm_submit(&dir, &c.url, &scene, &out, 16);
    let rt = runtime();
    wait_for(&dir, "the first tiles", 60, || {
        try_job(&rt, &c, 1).is_some_and(|s| s.tiles_done >= 2)
    });
    signal(&first, "TERM");
    let status = wait_child(&dir, &mut first.0, 30);
    assert!(status.success(), "worker exit {status:?}\n{}", dir.logs());
    let s = job(&rt, &c, 1);
    assert!(
        s.tiles_done < s.tiles_total,
        "the job ended before the signal"
    );
    let _second = worker(&dir, &c.url, "second");
    let status = wait_child(&dir, &mut sub, 30);
    assert!(status.success(), "{}", dir.logs());
    assert!(
        std::fs::read(&out).unwrap() == expected,
        "output differs\n{}",
        dir.logs()
    );
}

#[test]
fn a_worker_survives_a_coordinator_restart() {
    let dir = Dir::new();
    let scene = dir.write("s.xml", SCENE);
    let expected = embedded(&dir, &scene, "embedded.png");
    let c = coordinator(&dir, 10_000);
    let addr = c.url.trim_start_matches("http://").to_string();
    let _w = worker(&dir, &c.url, "worker");
    let out1 = dir.path().join("one.png");
    let o = submit(
        &dir,
        &[
            scene.to_str().unwrap(),
            "--coordinator",
            &c.url,
            "-o",
            out1.to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", dir.logs());
    drop(c); // SIGKILL
    let c = coordinator_at(&dir, 10_000, &addr, "coordinator2");
    let out2 = dir.path().join("two.png");
    let o = submit(
        &dir,
        &[
            scene.to_str().unwrap(),
            "--coordinator",
            &c.url,
            "-o",
            out2.to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", dir.logs());
    assert!(std::fs::read(&out1).unwrap() == expected);
    assert!(std::fs::read(&out2).unwrap() == expected);
}

/// The format follows `-o`, on the farm as on this machine: `-o y.exr` for
/// a scene whose `output` is `.png` gets EXR bytes, never PNG bytes under
/// the EXR name.
#[test]
fn the_farm_writes_the_format_that_dash_o_names() {
    let dir = Dir::new();
    let scene = dir.write("scene/s.xml", SCENE);
    let expected = embedded(&dir, &scene, "embedded.exr");
    assert_eq!(
        trevi_core::output::Format::sniff(&expected),
        Some(trevi_core::output::Format::Exr)
    );
    let c = coordinator(&dir, 10_000);
    let _w = worker(&dir, &c.url, "worker");
    let out = dir.path().join("farm.exr");
    let s = scene.to_str().unwrap();
    let o = submit(
        &dir,
        &[s, "--coordinator", &c.url, "-o", out.to_str().unwrap()],
    );
    assert!(o.status.success(), "{}", dir.logs());
    let got = std::fs::read(&out).unwrap();
    assert!(got == expected, "{}", dir.logs());
    assert_same_pixels(
        &got,
        &core_render(&dir, &scene, "core.exr"),
        "the farm's EXR",
    );
    // An extension that names no format is refused before a job exists.
    let jpg = dir.path().join("x.jpg");
    let o = submit(
        &dir,
        &[s, "--coordinator", &c.url, "-o", jpg.to_str().unwrap()],
    );
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("x.jpg") && err.contains(".png or .exr"),
        "{err}"
    );
    assert!(!jpg.exists());
    let list = submit(&dir, &["list", "--coordinator", &c.url]);
    assert_eq!(String::from_utf8_lossy(&list.stdout).lines().count(), 1);
}

/// A detached job's image could only be taken off the coordinator's disk:
/// `trevi-submit fetch ID` downloads it later.
#[test]
fn fetch_downloads_a_detached_job_s_image_once_it_is_done() {
    let dir = Dir::new();
    let scene = dir.write("scene/s.xml", SCENE);
    let expected = embedded(&dir, &scene, "embedded.png");
    let c = coordinator(&dir, 10_000);
    let s = scene.to_str().unwrap();
    let o = submit(&dir, &[s, "--coordinator", &c.url, "--detach"]);
    assert!(o.status.success(), "{}", dir.logs());
    let id = String::from_utf8_lossy(&o.stdout).trim().to_string();
    assert_eq!(id, "1");
    let fetch = |args: &[&str]| {
        let mut cmd = submit_cmd(&[&["fetch", &id, "--coordinator", &c.url], args].concat());
        let o = cmd.current_dir(dir.path()).output().unwrap();
        (
            o.status.code(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };

    // No worker yet: the job is queued, and there is nothing to fetch.
    let (code, err) = fetch(&[]);
    assert_eq!(code, Some(1));
    assert!(
        err.contains("job 1 is queued") && err.contains("once it is done"),
        "{err}"
    );
    assert!(!dir.path().join("main.png").exists());

    let _w = worker(&dir, &c.url, "worker");
    let rt = runtime();
    wait_for(&dir, "job 1 to finish", 60, || {
        job(&rt, &c, 1).state() == pb::JobState::Done
    });
    // By default the job's output name, in the current directory.
    let (code, err) = fetch(&[]);
    assert_eq!(code, Some(0), "{err}");
    assert!(std::fs::read(dir.path().join("main.png")).unwrap() == expected);
    let (code, err) = fetch(&["-o", "sub/again.png", "-q"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(std::fs::read(dir.path().join("sub/again.png")).unwrap() == expected);

    // The image is a PNG: another extension is refused, nothing written.
    let (code, err) = fetch(&["-o", "x.exr"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("-o must end in .png"), "{err}");
    assert!(!dir.path().join("x.exr").exists());
    // An unknown job.
    let mut cmd = submit_cmd(&["fetch", "99", "--coordinator", &c.url]);
    let o = cmd.current_dir(dir.path()).output().unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("99"));
}

/// A target that exists and is not a regular file is refused, by `fetch`
/// as by a render: renaming the downloaded file onto `-o /dev/full` would
/// replace the device node.
#[cfg(unix)]
#[test]
fn fetch_and_render_refuse_a_target_that_is_not_a_regular_file() {
    let dir = Dir::new();
    let scene = dir.write("scene/s.xml", SCENE);
    let c = coordinator(&dir, 10_000);
    let _w = worker(&dir, &c.url, "worker");
    let fifo = dir.path().join("fifo.png");
    let made = Command::new("mkfifo").arg(&fifo).status().unwrap();
    assert!(made.success());
    let is_fifo = || {
        use std::os::unix::fs::FileTypeExt;
        std::fs::symlink_metadata(&fifo)
            .unwrap()
            .file_type()
            .is_fifo()
    };
    let s = scene.to_str().unwrap();
    let f = fifo.to_str().unwrap();
    let o = submit(&dir, &[s, "--coordinator", &c.url, "-o", f]);
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("is a FIFO, not a regular file"), "{err}");
    assert!(is_fifo());

    let done = dir.path().join("done.png");
    let d = done.to_str().unwrap();
    let o = submit(&dir, &[s, "--coordinator", &c.url, "-o", d, "-q"]);
    assert!(o.status.success(), "{}", dir.logs());
    let o = submit(&dir, &["fetch", "1", "--coordinator", &c.url, "-o", f]);
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("is a FIFO, not a regular file"), "{err}");
    assert!(is_fifo());
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".part"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}

/// A closed form, no renderer involved: a scene of nothing but its
/// background is that colour at every pixel, on the farm as anywhere.
#[test]
fn the_farm_renders_an_empty_scene_as_its_background_everywhere() {
    let dir = Dir::new();
    let scene = dir.write(
        "scene/empty.xml",
        r#"<scene version="1">
  <settings background="0.2 0.4 0.6"/>
  <camera id="c" position="0 0 5" lookat="0 0 0" fov="50">
    <render width="40" height="24" output="empty.png"/>
  </camera>
</scene>"#,
    );
    let c = coordinator(&dir, 10_000);
    let _w = worker(&dir, &c.url, "worker");
    let got = farm_render(&dir, &c.url, &scene, "farm.png", 16);
    let (w, h, rgb) = trevi_core::output::decode_png(&got).unwrap();
    assert_eq!((w, h), (40, 24));
    // Linear to 8-bit sRGB, rounded: the sRGB curve in closed form (std's
    // powf: an independent computation, not a pixel of ours).
    #[allow(clippy::disallowed_methods)]
    let code = |c: f64| {
        let s = if c <= 0.003_130_8 {
            12.92 * c
        } else {
            1.055 * c.powf(1.0 / 2.4) - 0.055
        };
        (s * 255.0).round() as u8
    };
    let want = [code(0.2), code(0.4), code(0.6)];
    for (k, px) in rgb.chunks(3).enumerate() {
        assert_eq!(px, want, "pixel {k}");
    }
}
