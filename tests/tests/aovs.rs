//! Render passes (AOVs) end to end: a scene with `<render aovs>` rendered on
//! a farm of two workers (trevi-submit --coordinator) and by trevi-submit
//! alone (`TREVI_AOVS` naming the same passes) gives the same EXR, byte for
//! byte, as core's own render of the whole frame in one tile; its channels
//! read back by the `exr` crate; a PNG output gets the same pass files
//! beside it from all three. A sequence carries them in every frame: in
//! its EXR frames' layers, or beside each of its PNG frames (on a farm, as
//! `fetch` downloads them, and alone), core's own bytes each time; a pass
//! file asked for by a frame outside the range is refused naming it.
//! Unknown names, an over-long list and a progressive render with passes
//! are refused before anything renders.

mod common;

use common::*;
use std::path::Path;
use trevi_core::{Aovs, FrameWriter, Rect};
use trevi_proto::pb;

/// A small scene whose camera asks for every pass; part of the frame is
/// the background (a miss: depth +∞), part a sphere, part the ground.
fn scene(output: &str) -> String {
    format!(
        r#"<scene version="1">
  <settings background="0.1 0.1 0.2" ambient="0.1 0.1 0.1"/>
  <sphere id="ball" center="0 1 0" radius="1">
    <surface diffuse="0.8 0.3 0.2" specular="0.5 0.5 0.5" reflectivity="0.2"/>
  </sphere>
  <plane id="ground" point="0 0 0" normal="0 1 0"> <surface diffuse="0.5 0.5 0.5"/> </plane>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1"/>
  <camera id="main" position="0 2 6" lookat="0 1.5 0" up="0 1 0" fov="50">
    <render width="40" height="28" supersample="2" output="{output}" aovs="albedo normal depth"/>
  </camera>
</scene>
"#
    )
}

/// The frame and its passes as core renders them without farm code: the
/// whole frame in one tile, written by core's `FrameWriter` to `out`.
fn core_aovs(scene: &Path, out: &Path) {
    core_frame(scene, 0, out)
}

/// [`core_aovs`] of frame `frame` of the scene's sequence.
fn core_frame(scene: &Path, frame: u32, out: &Path) {
    let bundle = trevi_core::Bundle::from_scene_file(scene).unwrap_or_else(|e| panic!("{e}"));
    let mut scene = trevi_core::Scene::from_bundle(&bundle).unwrap_or_else(|e| panic!("{e}"));
    if scene.desc.cameras[0].render.frames.is_some() {
        scene.set_frame(0, frame).unwrap();
    }
    let r = &scene.desc.cameras[0].render;
    let rect = Rect::new(0, 0, r.width, r.height);
    let never = std::sync::atomic::AtomicBool::new(false);
    let (beauty, passes) =
        trevi_core::tile::render_tile_aovs(&scene, 0, rect, Aovs::ALL, &never).unwrap();
    let mut fw = FrameWriter::create_with_aovs(out, r.width, r.height, Aovs::ALL).unwrap();
    fw.write_tile_aovs(rect, &beauty.pixels, &passes).unwrap();
    fw.finish().unwrap();
}

/// The files a render to `out` wrote: the output and its pass files.
fn files(out: &Path) -> Vec<(String, Vec<u8>)> {
    let mut names = vec![out.to_path_buf()];
    for aov in Aovs::ALL.iter() {
        names.extend(trevi_core::aov::aov_path(out, aov));
    }
    names
        .into_iter()
        .map(|p| {
            let bytes = std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            (name, bytes)
        })
        .collect()
}

/// The same files, named apart from their stem (`shot.albedo.png` of
/// `shot.png` is `.albedo.png`), so that renders to other names compare.
fn by_suffix(out: &Path) -> Vec<(String, Vec<u8>)> {
    let stem = out.file_stem().unwrap().to_string_lossy().into_owned();
    files(out)
        .into_iter()
        .map(|(n, b)| (n[stem.len()..].to_string(), b))
        .collect()
}

#[test]
fn a_farm_and_trevi_submit_alone_write_the_passes_core_writes() {
    let dir = Dir::new();
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let _w0 = worker_with(&dir, &c.url, "worker0", &[], &[]);
    let _w1 = worker_with(&dir, &c.url, "worker1", &[], &[]);
    for ext in ["exr", "png"] {
        let scene = dir.write(&format!("s-{ext}.xml"), &scene(&format!("shot.{ext}")));
        let want = dir.path().join(format!("core.{ext}"));
        core_aovs(&scene, &want);
        // On the farm, in tiles of 8: the scene's own passes.
        farm_render(&dir, &c.url, &scene, &format!("farm.{ext}"), 8);
        let farm = dir.path().join(format!("farm.{ext}"));
        // Alone, in tiles of 16, the passes named by the environment.
        let local = dir.path().join(format!("local.{ext}"));
        let o = submit_env(
            &dir,
            &[
                scene.to_str().unwrap(),
                "-o",
                local.to_str().unwrap(),
                "--tile",
                "16",
                "--quiet",
            ],
            &[("TREVI_AOVS", "depth,normal,albedo")],
        );
        assert!(
            o.status.success(),
            "local render failed\n{}",
            String::from_utf8_lossy(&o.stderr)
        );
        let want = by_suffix(&want);
        assert_eq!(want.len(), if ext == "png" { 4 } else { 1 });
        for (what, got) in [("farm", by_suffix(&farm)), ("local", by_suffix(&local))] {
            assert_eq!(got.len(), want.len());
            for ((gn, gb), (wn, wb)) in got.iter().zip(&want) {
                assert_eq!(gn, wn);
                assert!(gb == wb, "{what} {ext}: {gn} differs from core's");
            }
        }
    }
    // The EXR's channels, as an independent reader finds them.
    let meta = exr::meta::MetaData::read_from_file(dir.path().join("farm.exr"), false).unwrap();
    let names: Vec<String> = meta.headers[0]
        .channels
        .list
        .iter()
        .map(|c| c.name.to_string())
        .collect();
    assert_eq!(
        names,
        ["B", "G", "N.X", "N.Y", "N.Z", "R", "Z", "albedo.B", "albedo.G", "albedo.R"]
    );
    // The job says which passes it rendered.
    let rt = runtime();
    assert_eq!(job(&rt, &c, 1).aovs, "albedo normal depth");
}

/// A sequence's frames carry the passes as layers of their EXR files, on
/// a farm and alone, each frame core's own.
#[test]
fn an_exr_sequence_carries_the_passes_in_every_frame() {
    let dir = Dir::new();
    let scene_exr = dir.write("seq.xml", &frames("shot.####.exr"));
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let _w = worker_with(&dir, &c.url, "worker0", &[], &[]);
    let farm = dir.path().join("farm/shot.####.exr");
    let alone = dir.path().join("alone/shot.####.exr");
    render_on_the_farm_and_alone(&dir, &scene_exr, &c.url, &farm, &alone, &[]);
    for f in 1..=2u32 {
        let name = format!("shot.{f:04}.exr");
        let want = dir.path().join(format!("core.{f}.exr"));
        core_frame(&scene_exr, f, &want);
        let want = std::fs::read(&want).unwrap();
        for (what, d) in [("farm", "farm"), ("alone", "alone")] {
            let got = std::fs::read(dir.path().join(d).join(&name)).unwrap();
            assert!(
                got == want,
                "{what}: frame {f} is not core's frame with its passes"
            );
        }
    }
}

/// Renders `scene` (tiles of 16, `extra` flags) into `farm` through the
/// coordinator at `url` and into `alone` without one; both must succeed.
fn render_on_the_farm_and_alone(
    dir: &Dir,
    scene: &Path,
    url: &str,
    farm: &Path,
    alone: &Path,
    extra: &[&str],
) {
    for (out, farm_url) in [(farm, Some(url)), (alone, None)] {
        let mut args = vec![scene.to_str().unwrap(), "-o", out.to_str().unwrap()];
        args.extend(["--tile", "16", "--quiet"]);
        args.extend(extra);
        args.extend(farm_url.map(|u| ["--coordinator", u]).into_iter().flatten());
        let o = submit(dir, &args);
        assert!(
            o.status.success(),
            "{args:?}: {}\n{}",
            String::from_utf8_lossy(&o.stderr),
            dir.logs()
        );
    }
}

/// The scene of [`scene`] as a sequence of frames 1-2.
fn frames(output: &str) -> String {
    scene(output).replace(r#"output="#, r#"frames="1-2" fps="2" output="#)
}

/// A PNG sequence with passes: every frame gets its pass files beside it
/// (`shot_01.png`, `shot_01.albedo.png`, `shot_01.normal.png`,
/// `shot_01.depth.exr`), on a farm of two workers (as the render waits,
/// and as `fetch` downloads them again) and alone, each frame's files
/// core's own render of that frame. On the wire, a pass file of a frame
/// outside the range is refused naming the frame and the range; a still's
/// by frame, naming it a still.
#[test]
fn a_png_sequence_gets_each_frame_s_passes_beside_it() {
    let dir = Dir::new();
    // The scene's passes but the depth: `--aovs` asks for all three.
    let scene_png = dir.write(
        "seq.xml",
        &frames("shot_##.png").replace("albedo normal depth", "albedo normal"),
    );
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let _w0 = worker_with(&dir, &c.url, "worker0", &[], &[]);
    let _w1 = worker_with(&dir, &c.url, "worker1", &[], &[]);
    let farm = dir.path().join("farm/shot_##.png");
    let alone = dir.path().join("alone/shot_##.png");
    let aovs = ["--aovs", "albedo,normal,depth"];
    render_on_the_farm_and_alone(&dir, &scene_png, &c.url, &farm, &alone, &aovs);
    // The farm's sequence (job 1) fetched again, into a directory.
    let fetched = dir.path().join("fetched");
    let o = submit(
        &dir,
        &[
            "fetch",
            "1",
            "--coordinator",
            &c.url,
            "-o",
            fetched.to_str().unwrap(),
        ],
    );
    assert!(
        o.status.success(),
        "fetch: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let scene_all = dir.write("seq-all.xml", &frames("shot_##.png"));
    for f in 1..=2u32 {
        let want = dir.path().join(format!("core_{f}.png"));
        core_frame(&scene_all, f, &want);
        let want = by_suffix(&want);
        assert_eq!(want.len(), 4, "core wrote the frame and 3 pass files");
        for d in ["farm", "alone", "fetched"] {
            let got = by_suffix(&dir.path().join(d).join(format!("shot_{f:02}.png")));
            for ((gn, gb), (wn, wb)) in got.iter().zip(&want) {
                assert_eq!(gn, wn);
                assert!(gb == wb, "{d}: frame {f}'s {gn} differs from core's");
            }
        }
    }
    // Nothing but the frames and their passes, no part file left.
    for d in ["farm", "alone", "fetched"] {
        let mut names: Vec<String> = std::fs::read_dir(dir.path().join(d))
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(
            names,
            [
                "shot_01.albedo.png",
                "shot_01.depth.exr",
                "shot_01.normal.png",
                "shot_01.png",
                "shot_02.albedo.png",
                "shot_02.depth.exr",
                "shot_02.normal.png",
                "shot_02.png"
            ],
            "{d}"
        );
    }

    // A still with passes on the same farm: job 2.
    let still = dir.write("still.xml", &scene("still.png"));
    farm_render(&dir, &c.url, &still, "still.png", 16);
    let rt = runtime();
    rt.block_on(async {
        let mut j = jobs(&c, None).await;
        let ask = |id: u64, frame: Option<u32>| pb::AovFileRequest {
            id,
            aov: "depth".into(),
            frame,
        };
        // A frame within the range streams its file.
        let mut s = j.download_aov(ask(1, Some(2))).await.unwrap().into_inner();
        let mut got = Vec::new();
        while let Some(chunk) = s.message().await.unwrap() {
            got.extend(chunk.data);
        }
        let want = std::fs::read(dir.path().join("farm/shot_02.depth.exr")).unwrap();
        assert!(got == want, "frame 2's depth pass");
        for (req, says) in [
            (ask(1, Some(7)), "frame 7 is not in its frames 1-2"),
            (ask(1, Some(0)), "frame 0 is not in its frames 1-2"),
            (
                ask(1, Some(u32::MAX)),
                "frame 4294967295 is not in its frames 1-2",
            ),
            (ask(2, Some(1)), "it is a still"),
        ] {
            let e = j.download_aov(req).await.unwrap_err();
            assert_eq!(e.code(), tonic::Code::FailedPrecondition, "{e:?}");
            assert!(e.message().contains(says), "{}", e.message());
        }
    });
}

#[test]
fn unknown_passes_and_progressive_renders_with_passes_are_refused() {
    let dir = Dir::new();
    let path = dir.write("s.xml", &scene("shot.png"));
    let out = dir.path().join("o.png");
    let run = |extra: &[&str]| {
        let mut args = vec![path.to_str().unwrap(), "-o", out.to_str().unwrap()];
        args.extend_from_slice(extra);
        submit(&dir, &args)
    };
    let o = run(&["--aovs", "albedo,specular"]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("\"specular\""), "{err}");
    let long = "depth,".repeat(11);
    let o = run(&["--aovs", &long]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("64"), "{err}");
    // A progressive still with passes: refused by the (embedded)
    // coordinator, naming why.
    let o = run(&["--aovs", "depth", "--samples", "4"]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("progressive"), "{err}");
    assert!(!out.exists(), "nothing was written");

    // The same bounds on the wire.
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let rt = runtime();
    rt.block_on(async {
        let hash = upload(
            &mut bundles(&c, None).await,
            vec![bundle_of(&scene("s.exr")).encode()],
        )
        .await
        .unwrap();
        let ask = |aovs: &str, progressive: bool| pb::SubmitJobRequest {
            bundle_hash: hash.clone(),
            aovs: Some(aovs.to_string()),
            progressive: progressive.then(|| pb::Progressive {
                samples: 4,
                ..Default::default()
            }),
            ..Default::default()
        };
        let mut j = jobs(&c, None).await;
        for (req, says) in [
            (ask("albedo bogus", false), "\"bogus\""),
            (ask(&"albedo ".repeat(10), false), "64"),
            (ask("normal", true), "progressive"),
        ] {
            let e = j.submit_job(req).await.unwrap_err();
            assert_eq!(e.code(), tonic::Code::InvalidArgument, "{e:?}");
            assert!(e.message().contains(says), "{}", e.message());
        }
        // Nothing was queued; a still without passes (empty: none, over
        // the camera's own) is.
        let s = j.submit_job(ask("", false)).await.unwrap().into_inner();
        assert_eq!((s.id, s.aovs.as_str()), (1, ""));
        // A pass file of a job without passes is not there.
        let e = j
            .download_aov(pb::AovFileRequest {
                id: 1,
                aov: "depth".into(),
                frame: None,
            })
            .await
            .unwrap_err();
        assert_eq!(e.code(), tonic::Code::FailedPrecondition, "{e:?}");
    });
}
