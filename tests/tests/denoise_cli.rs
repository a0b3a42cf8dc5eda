//! `trevi-submit --denoise` end to end (docs/denoise.md, "trevi-submit
//! --denoise").
//!
//! Which build runs decides what is checked. A build without the `denoise`
//! feature (what `cargo test --workspace` builds) must refuse `--denoise`
//! and `denoise="true"` before anything renders, saying how to get a
//! denoiser, and write nothing. A build with it (CI builds one:
//! `OIDN_DIR=… TREVI_REQUIRE_DENOISE=1 TREVI_BUILD_FEATURES=trevi-submit/denoise
//! cargo test --workspace --features trevi-submit/denoise --test denoise_cli`:
//! the binaries are built again by the tests' harness, which needs the
//! features named in TREVI_BUILD_FEATURES) must denoise: the output is
//! closer to a converged reference than the noisy frame is (by a factor,
//! not a threshold we tuned: OIDN on 4 samples a pixel of a path-traced
//! scene), the noisy frame is kept beside a PNG and is a layer of an EXR
//! (with the passes asked for), and the frame denoised after a farm render
//! is byte-identical to the one a local render denoises.
//! `TREVI_REQUIRE_DENOISE=1` turns a build without the feature into a
//! failure, so CI cannot pass by building the wrong thing.

mod common;

use common::{coordinator_with, submit, worker_with, Dir};
use std::path::Path;

/// A path-traced floor, wall and sphere under a small area light: noisy at
/// a few samples a pixel. `SS` is replaced by the supersampling (samples a
/// pixel = SS²).
const SCENE: &str = r#"<scene version="1">
<settings background="0 0 0"/>
<mesh id="q"><vertices>-2 0 -2 2 0 -2 2 0 2 -2 0 2</vertices><triangles>0 2 1 0 3 2</triangles></mesh>
<mesh id="w"><vertices>-2 0 -2 2 0 -2 2 3 -2 -2 3 -2</vertices><triangles>0 1 2 0 2 3</triangles></mesh>
<mesh id="l"><vertices>-0.3 2.5 -0.3 0.3 2.5 -0.3 0.3 2.5 0.3 -0.3 2.5 0.3</vertices><triangles>0 1 2 0 2 3</triangles></mesh>
<sphere id="ball" center="0 0.6 0" radius="0.6"><surface diffuse="0.2 0.4 0.7"/></sphere>
<model id="floor" mesh="q"><surface diffuse="0.7 0.7 0.7"/></model>
<model id="wall" mesh="w"><surface diffuse="0.7 0.3 0.2"/></model>
<model id="lamp" mesh="l"><surface diffuse="0 0 0" emission="12 12 12"/></model>
<camera id="c" position="0 1.5 4" lookat="0 0.8 0" fov="50"><render width="48" height="32" supersample="SS" integrator="path" max-bounces="3" output="out.png"/></camera>
</scene>
"#;

fn scene(dir: &Dir, name: &str, ss: u32) -> std::path::PathBuf {
    dir.write(name, &SCENE.replace("SS", &ss.to_string()))
}

/// 8-bit RGB(A) pixels of a PNG file, as floats in [0, 1].
fn pixels(path: &Path) -> Vec<f64> {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut r = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .unwrap();
    let mut buf = vec![0; r.output_buffer_size().unwrap()];
    let info = r.next_frame(&mut buf).unwrap();
    let step = info.color_type.samples();
    buf[..info.buffer_size()]
        .chunks(step)
        .flat_map(|p| p[..3].iter().map(|&v| f64::from(v) / 255.0))
        .collect()
}

fn rmse(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    (a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / a.len() as f64).sqrt()
}

fn run(dir: &Dir, args: &[&str]) -> std::process::Output {
    let out = submit(dir, args);
    assert!(
        out.status.success(),
        "trevi-submit {args:?}: {}\n{}",
        String::from_utf8_lossy(&out.stderr),
        dir.logs()
    );
    out
}

#[test]
fn denoise_is_refused_before_rendering_without_a_denoiser_or_denoises_with_one() {
    let dir = Dir::new();
    let noisy_scene = scene(&dir, "s.xml", 2);
    let out = dir.path().join("d.png");
    let first = submit(
        &dir,
        &[
            noisy_scene.to_str().unwrap(),
            "--denoise",
            "--quiet",
            "--threads",
            "1",
            "-o",
            out.to_str().unwrap(),
        ],
    );
    let err = String::from_utf8_lossy(&first.stderr).into_owned();
    if err.contains("this build has no denoiser") {
        assert!(
            std::env::var("TREVI_REQUIRE_DENOISE").as_deref() != Ok("1"),
            "TREVI_REQUIRE_DENOISE=1 but trevi-submit was built without the denoise feature: {err}"
        );
        without_a_denoiser(&dir, &first, &out);
        return;
    }
    assert!(first.status.success(), "{err}\n{}", dir.logs());
    with_a_denoiser(&dir, &noisy_scene, &out);
}

/// Refused before anything renders, saying how to get one; nothing written,
/// also for a camera's `denoise="true"`.
fn without_a_denoiser(dir: &Dir, first: &std::process::Output, out: &Path) {
    let err = String::from_utf8_lossy(&first.stderr);
    assert_eq!(first.status.code(), Some(1), "{err}");
    assert!(
        err.contains("--denoise") && err.contains("`denoise` cargo feature"),
        "{err}"
    );
    assert!(!out.exists() && !dir.path().join("d.noisy.exr").exists());
    let flagged = dir.write(
        "flagged.xml",
        &SCENE
            .replace("SS", "2")
            .replace(r#"output="out.png""#, r#"output="out.png" denoise="true""#),
    );
    let o = submit(dir, &[flagged.to_str().unwrap(), "--quiet"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("denoise=\"true\""), "{err}");
    assert!(!dir.path().join("out.png").exists() && !dir.path().join("out.noisy.exr").exists());
    let seq = dir.path().join("seq_#.png");
    let o = submit(
        dir,
        &[
            flagged.to_str().unwrap(),
            "--quiet",
            "--frames",
            "1-2",
            "-o",
            seq.to_str().unwrap(),
        ],
    );
    assert_eq!(o.status.code(), Some(1), "a sequence is refused too");
    assert!(std::fs::read_dir(dir.path())
        .unwrap()
        .flatten()
        .all(|e| !e.file_name().to_string_lossy().starts_with("seq_")));
}

/// Closer to the reference than the noisy frame; the noisy frame kept; the
/// farm's denoised frame the local one's bytes.
fn with_a_denoiser(dir: &Dir, noisy_scene: &Path, out: &Path) {
    let noisy_exr = dir.path().join("d.noisy.exr");
    assert!(
        noisy_exr.exists(),
        "the noisy frame is kept beside the output"
    );
    // The same noisy render without denoising, and a converged reference
    // (1024 samples a pixel).
    let noisy_png = dir.path().join("noisy.png");
    run(
        dir,
        &[
            noisy_scene.to_str().unwrap(),
            "--quiet",
            "-o",
            noisy_png.to_str().unwrap(),
        ],
    );
    let reference = scene(dir, "ref.xml", 32);
    let ref_png = dir.path().join("ref.png");
    run(
        dir,
        &[
            reference.to_str().unwrap(),
            "--quiet",
            "-o",
            ref_png.to_str().unwrap(),
        ],
    );
    let (r, n, d) = (pixels(&ref_png), pixels(&noisy_png), pixels(out));
    let (noisy_err, denoised_err) = (rmse(&n, &r), rmse(&d, &r));
    eprintln!("RMSE against 1024 spp: noisy (4 spp) {noisy_err:.4}, denoised {denoised_err:.4}");
    assert!(
        denoised_err < 0.7 * noisy_err,
        "denoising did not bring 4 spp closer to the reference: {denoised_err} vs {noisy_err}"
    );

    // On a farm: the same noisy bytes, denoised here by the same code.
    let c = coordinator_with(dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let _w = worker_with(dir, &c.url, "worker", &[], &[]);
    let farm_out = dir.path().join("farm.png");
    run(
        dir,
        &[
            noisy_scene.to_str().unwrap(),
            "--denoise",
            "--quiet",
            "--threads",
            "1",
            "--coordinator",
            &c.url,
            "-o",
            farm_out.to_str().unwrap(),
        ],
    );
    assert_eq!(
        std::fs::read(dir.path().join("farm.noisy.exr")).unwrap(),
        std::fs::read(&noisy_exr).unwrap(),
        "the farm's noisy frame differs from the local one"
    );
    assert!(
        std::fs::read(&farm_out).unwrap() == std::fs::read(out).unwrap(),
        "the farm's denoised frame differs from the local one"
    );
    layers_of_a_denoised_exr(dir, noisy_scene, out);
    a_denoised_sequence(dir, noisy_scene, &r, &c.url);
    a_progressive_preview_denoised_after_each_pass(dir, noisy_scene, &r);
}

/// A progressive render's `--preview` with `--denoise`: the last pass's
/// preview, denoised (the 48×32 frame is its own preview, not scaled), closer
/// to the reference than the same render's preview without denoising; the
/// output denoised at the end.
fn a_progressive_preview_denoised_after_each_pass(
    dir: &Dir,
    noisy_scene: &Path,
    reference: &[f64],
) {
    let scene = noisy_scene.to_str().unwrap();
    let at = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let local = at("kept");
    let common = [
        "--quiet",
        "--threads",
        "1",
        "--samples",
        "8",
        "--pass",
        "4",
        "--local-dir",
        &local,
    ];
    run(
        dir,
        &[
            &[
                scene,
                "--denoise",
                "--preview",
                &at("dp.png"),
                "-o",
                &at("dprog.png"),
            ][..],
            &common,
        ]
        .concat(),
    );
    run(
        dir,
        &[
            &[scene, "--preview", &at("np.png"), "-o", &at("nprog.png")][..],
            &common,
        ]
        .concat(),
    );
    let (denoised, noisy) = (
        pixels(Path::new(&at("dp.png"))),
        pixels(Path::new(&at("np.png"))),
    );
    let (noisy_err, denoised_err) = (rmse(&noisy, reference), rmse(&denoised, reference));
    eprintln!("progressive preview, 8 spp: RMSE noisy {noisy_err:.4}, denoised {denoised_err:.4}");
    assert!(
        denoised_err < 0.7 * noisy_err,
        "the preview is not denoised: {denoised_err} vs {noisy_err}"
    );
    let out = pixels(Path::new(&at("nprog.png")));
    assert!(
        out.iter()
            .zip(&noisy)
            .all(|(a, b)| (a - b).abs() <= 1.0 / 255.0 + 1e-9),
        "the preview without denoising is not the output's image"
    );
    let out_err = rmse(&pixels(Path::new(&at("dprog.png"))), reference);
    assert!(
        out_err < 0.7 * noisy_err,
        "the output is not denoised: {out_err}"
    );
}

/// A sequence: every frame rendered noisy by the pattern beside the
/// output's, then denoised; each denoised frame closer to the reference than
/// its noisy frame (the scene does not move, so one reference serves every
/// frame), each noisy frame the beauty of the same sequence rendered without
/// denoising, the farm's frames the local ones' bytes. An EXR sequence holds
/// its noisy beauty as a layer and leaves no noisy file.
fn a_denoised_sequence(dir: &Dir, noisy_scene: &Path, reference: &[f64], farm: &str) {
    use trevi_core::output::read_exr_channels;
    let scene = noisy_scene.to_str().unwrap();
    let common = ["--quiet", "--threads", "1", "--frames", "3-4"];
    let at = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    run(
        dir,
        &[&[scene, "--denoise", "-o", &at("seq_#.png")][..], &common].concat(),
    );
    run(
        dir,
        &[&[scene, "-o", &at("plain_#.exr")][..], &common].concat(),
    );
    let farm_args = ["--coordinator", farm];
    run(
        dir,
        &[
            &[scene, "--denoise", "-o", &at("farm_#.png")][..],
            &common,
            &farm_args,
        ]
        .concat(),
    );
    run(
        dir,
        &[
            &[scene, "--denoise", "-o", &at("layered_#.exr")][..],
            &common,
        ]
        .concat(),
    );
    for f in [3, 4] {
        let denoised = dir.path().join(format!("seq_{f}.png"));
        let noisy = dir.path().join(format!("seq_{f}.noisy.exr"));
        let (_, _, noisy_layers) = read_exr_channels(&noisy).unwrap();
        let (_, _, plain) = read_exr_channels(&dir.path().join(format!("plain_{f}.exr"))).unwrap();
        for c in ["R", "G", "B"] {
            let get = |l: &[(String, Vec<f32>)]| l.iter().find(|(n, _)| n == c).unwrap().1.clone();
            assert!(
                get(&noisy_layers) == get(&plain),
                "frame {f}: the noisy frame's {c} is not the render's without denoising"
            );
        }
        let noisy_png: Vec<f64> = (0..noisy_layers[0].1.len())
            .flat_map(|i| {
                ["R", "G", "B"].map(|c| {
                    let v = noisy_layers.iter().find(|(n, _)| n == c).unwrap().1[i];
                    f64::from(trevi_core::output::linear_to_srgb8(v)) / 255.0
                })
            })
            .collect();
        let d = pixels(&denoised);
        let (noisy_err, denoised_err) = (rmse(&noisy_png, reference), rmse(&d, reference));
        eprintln!("frame {f}: RMSE noisy {noisy_err:.4}, denoised {denoised_err:.4}");
        assert!(denoised_err < 0.7 * noisy_err, "frame {f} is not denoised");
        assert!(
            std::fs::read(&denoised).unwrap()
                == std::fs::read(dir.path().join(format!("farm_{f}.png"))).unwrap(),
            "frame {f}: the farm's denoised frame differs from the local one"
        );
        assert!(!dir.path().join(format!("layered_{f}.noisy.exr")).exists());
        let (_, _, layered) =
            read_exr_channels(&dir.path().join(format!("layered_{f}.exr"))).unwrap();
        let noisy_r = &layered.iter().find(|(n, _)| n == "noisy.R").unwrap().1;
        assert!(
            *noisy_r == plain.iter().find(|(n, _)| n == "R").unwrap().1,
            "frame {f}: the EXR's noisy layer is not the render without denoising"
        );
    }
}

/// An EXR output holds the denoised beauty, the passes asked for (and not
/// the guides nobody asked for) and the noisy beauty as its layer `noisy`;
/// no noisy file is left beside it. Checked against renders without
/// denoising and against the PNG output's bytes (the same denoised floats
/// through the sRGB curve). A PNG output gets the passes asked for beside
/// it, the noisy frame too.
fn layers_of_a_denoised_exr(dir: &Dir, noisy_scene: &Path, png_out: &Path) {
    use trevi_core::output::{linear_to_srgb8, read_exr_channels};
    let scene = noisy_scene.to_str().unwrap();
    let exr = dir.path().join("layers.exr");
    let args = ["--quiet", "--threads", "1", "--aovs", "depth"];
    run(
        dir,
        &[
            &[scene, "--denoise", "-o", exr.to_str().unwrap()][..],
            &args,
        ]
        .concat(),
    );
    assert!(
        !dir.path().join("layers.noisy.exr").exists(),
        "the noisy frame is a layer of the EXR, not a file beside it"
    );
    let plain = dir.path().join("plain.exr");
    run(
        dir,
        &[&[scene, "-o", plain.to_str().unwrap()][..], &args].concat(),
    );
    let (_, _, got) = read_exr_channels(&exr).unwrap();
    let (_, _, want) = read_exr_channels(&plain).unwrap();
    let channel = |list: &[(String, Vec<f32>)], name: &str| -> Vec<f32> {
        list.iter()
            .find(|(n, _)| n == name)
            .unwrap_or_else(|| panic!("no channel {name}"))
            .1
            .clone()
    };
    let mut names: Vec<&str> = got.iter().map(|(n, _)| n.as_str()).collect();
    names.sort_unstable();
    assert_eq!(
        names,
        ["B", "G", "R", "Z", "noisy.B", "noisy.G", "noisy.R"],
        "the passes asked for and the noisy beauty, not the guides"
    );
    for (layer, plain) in [
        ("noisy.R", "R"),
        ("noisy.G", "G"),
        ("noisy.B", "B"),
        ("Z", "Z"),
    ] {
        assert!(
            channel(&got, layer) == channel(&want, plain),
            "{layer} is not the render's {plain} without denoising"
        );
    }
    assert!(channel(&got, "R") != channel(&want, "R"), "R is denoised");
    // The denoised floats are the PNG's pixels through the sRGB curve.
    let srgb: Vec<f64> = (0..channel(&got, "R").len())
        .flat_map(|i| ["R", "G", "B"].map(|c| channel(&got, c)[i]))
        .map(|v| f64::from(linear_to_srgb8(v)) / 255.0)
        .collect();
    assert!(
        srgb == pixels(png_out),
        "the EXR's denoised beauty is not the PNG's"
    );

    let png = dir.path().join("side.png");
    run(
        dir,
        &[
            &[scene, "--denoise", "-o", png.to_str().unwrap()][..],
            &args,
        ]
        .concat(),
    );
    for (file, there) in [
        ("side.depth.exr", true),
        ("side.noisy.exr", true),
        ("side.albedo.png", false),
        ("side.normal.png", false),
    ] {
        assert_eq!(dir.path().join(file).exists(), there, "{file}");
    }
}
