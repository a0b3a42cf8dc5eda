//! `<render>`: how a camera's frame is rendered and where it is written,
//! including Trevi's adaptive sampling (docs/aisxml-extensions.md).

use super::outputs::{Output, MAX_PATTERN_RUN};
use super::table::{attr, extension, Attribute, REQUIRED};
use super::values::{parse_uint, El};
use super::xml::{excerpt, is_xml_ws, Attr, Elem};
use super::{Resolver, Result};
use crate::aov::Aovs;
use crate::error::SceneErrorKind;
use crate::scene::animation::{Frames, DEFAULT_FPS, MAX_FRAME};
use crate::scene::source::normalize_rel_path;
use crate::scene::{
    Adaptive, AoDistance, IntegratorKind, RenderSettings, DEFAULT_MAX_BOUNCES,
    MAX_ADAPTIVE_SAMPLES, MAX_DEPTH, MAX_IMAGE_SIDE, MAX_RAY_SAMPLES, MAX_SUPERSAMPLE,
};

/// The attributes of `<render>`.
pub(super) const RENDER: &[Attribute] = &[
    attr(
        "width",
        "integer in [1, 65536]",
        REQUIRED,
        "the frame's width in pixels",
    ),
    attr(
        "height",
        "integer in [1, 65536]",
        REQUIRED,
        "the frame's height in pixels",
    ),
    attr(
        "supersample",
        "integer in [1, 65535]",
        "1",
        "n: n×n samples per pixel",
    ),
    attr(
        "jitter",
        "boolean",
        "false",
        "jitter samples inside their strata",
    ),
    attr(
        "max-depth",
        "integer in [0, 10000]",
        "5",
        "the reflection and refraction depth",
    ),
    attr(
        "shadow-samples",
        "integer in [1, 65536]",
        "1",
        "shadow rays per light per sample",
    ),
    attr(
        "ao-samples",
        "integer in [0, 65536]",
        "0",
        "ambient-occlusion rays per sample",
    ),
    attr(
        "ao-distance",
        "real > 0 | auto",
        "auto",
        "s_max; auto is half the diagonal of the scene's bounds",
    ),
    attr(
        "diffuse-samples",
        "integer in [0, 65536]",
        "0",
        "diffuse-interreflection rays per sample at the first level",
    ),
    attr(
        "diffuse-depth",
        "integer in [1, 10000]",
        "1",
        "diffuse bounce levels",
    ),
    attr("seed", "integer ≥ 0 (64 bits)", "0", "the random seed"),
    attr(
        "output",
        "path ending in .png or .exr",
        "<camera id>.png",
        "the output file, relative to the scene's directory",
    ),
    extension(
        "noise-threshold",
        "real > 0",
        "none (adaptive sampling off)",
        "the target standard error of a pixel's mean",
    ),
    extension(
        "min-samples",
        "integer ≥ 1",
        "4",
        "camera samples every pixel takes before it may stop",
    ),
    extension(
        "max-samples",
        "integer ≥ min-samples",
        "256",
        "camera samples after which a pixel stops",
    ),
    extension(
        "integrator",
        "whitted | path",
        "whitted",
        "the spec's Whitted model, or physically based path tracing",
    ),
    extension(
        "max-bounces",
        "integer in [0, 10000]",
        "16",
        "path mode: scattering events along a path (0: emitters and background only)",
    ),
    extension(
        "frames",
        "integer or range \"first-last\", in [0, 9999999]",
        "none (a still)",
        "the frames of a sequence, each at t = frame / fps",
    ),
    extension(
        "fps",
        "real ≥ 1.2e-38 (> 0 in 32 bits)",
        "24",
        "frames per second",
    ),
    extension(
        "aovs",
        "names among albedo, normal, depth",
        "none (no render passes)",
        "render passes written beside the beauty",
    ),
    extension(
        "denoise",
        "true or false",
        "false",
        "the frame denoised after it is rendered (trevi-submit --denoise)",
    ),
];

impl<'a> Resolver<'a> {
    pub(super) fn render(
        &mut self,
        e: &'a Elem,
        camera: &El<'a>,
        camera_id_attr: &'a Attr,
        camera_id: &str,
    ) -> Result<RenderSettings> {
        let el = self.el(e);
        el.check_attrs(RENDER)?;
        el.req("width")?;
        el.req("height")?;
        // Every count has a maximum (see the constants and the limits table
        // of docs/aisxml-extensions.md): past it, arithmetic on it would
        // overflow or lose precision, or memory would grow without bound.
        let width = el.u32_in("width", 1, MAX_IMAGE_SIDE)?.unwrap_or(1);
        let height = el.u32_in("height", 1, MAX_IMAGE_SIDE)?.unwrap_or(1);
        let supersample = el.u32_in("supersample", 1, MAX_SUPERSAMPLE)?.unwrap_or(1);
        let jitter = el.boolean("jitter")?.unwrap_or(false);
        let max_depth = el.u32_in("max-depth", 0, MAX_DEPTH)?.unwrap_or(5);
        let shadow_samples = el
            .u32_in("shadow-samples", 1, MAX_RAY_SAMPLES)?
            .unwrap_or(1);
        let ao_samples = el.u32_in("ao-samples", 0, MAX_RAY_SAMPLES)?.unwrap_or(0);
        let ao_distance = match el.get("ao-distance") {
            Some(a) if a.value.trim_matches(is_xml_ws) == "auto" => AoDistance::Auto,
            Some(_) => AoDistance::Fixed(
                el.real_in("ao-distance", "a number > 0 or \"auto\"", |v| v > 0.0)?
                    .unwrap_or(1.0) as f32,
            ),
            None => AoDistance::Auto,
        };
        let diffuse_samples = el
            .u32_in("diffuse-samples", 0, MAX_RAY_SAMPLES)?
            .unwrap_or(0);
        let diffuse_depth = el.u32_in("diffuse-depth", 1, MAX_DEPTH)?.unwrap_or(1);
        let seed = el.uint("seed", 0, u64::MAX)?.unwrap_or(0);

        let frames = self.frames(&el)?;
        let fps = self.fps(&el)?;
        let output_attr = el.get("output");
        let output = match output_attr {
            Some(a) => {
                let rel = Self::attr_path(&el, a)?;
                if !has_image_extension(&rel) {
                    return Err(el.expected(a, "a file name ending in .png or .exr"));
                }
                check_pattern(&el, a, &rel, frames.is_some())?;
                rel
            }
            None => {
                let default = if frames.is_some() {
                    format!("{camera_id}.####.png")
                } else {
                    format!("{camera_id}.png")
                };
                if camera_id.contains('#') {
                    // A # would make the name a frame-number pattern (or
                    // more than one), refused later and elsewhere without
                    // a place in the scene.
                    return Err(camera
                        .attr_err(
                            camera_id_attr,
                            format!(
                                "the camera id \"{}\" contains #, which would make its default output \"{}\" a frame-number pattern (expected an id without #, or an explicit output= on <render>)",
                                excerpt(camera_id),
                                excerpt(&default)
                            ),
                        )
                        .with_kind(SceneErrorKind::BadValue));
                }
                match normalize_rel_path(&default) {
                    Ok(rel) if has_image_extension(&rel) => rel,
                    _ => {
                        return Err(camera.attr_err(
                            camera_id_attr,
                            format!(
                                "the default output \"{}\" is not a usable file name (expected an id that makes one, or an explicit output= on <render>)",
                                excerpt(&default)
                            ),
                        ).with_kind(SceneErrorKind::BadValue))
                    }
                }
            }
        };
        let output = self.bundle_path(&output);
        let aovs = aovs(&el)?;
        // Compared with every earlier camera's by the names they write,
        // not only as patterns (see outputs.rs); the files a PNG's render
        // passes go to as well.
        let sidecars = aovs
            .iter()
            .filter_map(|a| crate::aov::aov_path(std::path::Path::new(&output), a))
            .map(|p| p.to_string_lossy().into_owned());
        for written in std::iter::once(output.clone()).chain(sidecars) {
            let Some((name, other, first)) = self.outputs.add(Output::new(&written, frames), e.pos)
            else {
                continue;
            };
            // The same output, or one of the names both write.
            let msg = if other == written && written == output {
                format!(
                    "output \"{}\" is already written by the <render> at {} (expected a distinct output per camera)",
                    excerpt(&output),
                    self.src.line_col(first)
                )
            } else {
                format!(
                    "output \"{}\" writes \"{}\", which the <render> at {} (output \"{}\") writes too (expected outputs that name distinct files for every frame, render passes beside a PNG included)",
                    excerpt(&output),
                    excerpt(&name),
                    self.src.line_col(first),
                    excerpt(&other)
                )
            };
            return Err(match output_attr {
                Some(a) => el.attr_err(a, msg),
                None => el.err(msg),
            }
            .with_kind(SceneErrorKind::Reference));
        }

        let threshold = el.real_in("noise-threshold", "a number > 0", |v| v > 0.0)?;
        let min_samples = el.u32_in("min-samples", 1, MAX_ADAPTIVE_SAMPLES)?;
        let max_samples = el.u32_in("max-samples", 1, MAX_ADAPTIVE_SAMPLES)?;
        let adaptive = match threshold {
            None => {
                if let Some(a) = el.get("min-samples").or_else(|| el.get("max-samples")) {
                    return Err(el.attr_err(
                        a,
                        "only allowed together with \"noise-threshold\" (expected noise-threshold= to enable adaptive sampling)",
                    ));
                }
                None
            }
            Some(t) => {
                let min_samples = min_samples.unwrap_or(4);
                let max_samples = max_samples.unwrap_or(256);
                if max_samples < min_samples {
                    let a = el
                        .get("max-samples")
                        .or_else(|| el.get("min-samples"))
                        .ok_or_else(|| el.err("max-samples < min-samples"))?;
                    return Err(el.expected(
                        a,
                        &format!(
                            "max-samples ≥ min-samples ({min_samples} ≤ {max_samples} is violated)"
                        ),
                    ));
                }
                Some(Adaptive {
                    threshold: t as f32,
                    min_samples,
                    max_samples,
                })
            }
        };
        let integrator = el
            .keyword(
                "integrator",
                &[
                    ("whitted", IntegratorKind::Whitted),
                    ("path", IntegratorKind::Path),
                ],
            )?
            .unwrap_or_default();
        let max_bounces = el
            .u32_in("max-bounces", 0, MAX_DEPTH)?
            .unwrap_or(DEFAULT_MAX_BOUNCES);
        Ok(RenderSettings {
            width,
            height,
            supersample,
            jitter,
            max_depth,
            shadow_samples,
            ao_samples,
            ao_distance,
            diffuse_samples,
            diffuse_depth,
            seed,
            output,
            adaptive,
            integrator,
            max_bounces,
            frames,
            fps,
            aovs,
            denoise: el.boolean("denoise")?.unwrap_or(false),
        })
    }

    /// `fps=`: a number > 0, kept at 32-bit precision; one too small for
    /// 32 bits (`1e-300`) is refused as that, not as "not > 0".
    fn fps(&self, el: &El<'a>) -> Result<f64> {
        let Some(a) = el.get("fps") else {
            return Ok(DEFAULT_FPS);
        };
        let v = el.reals(a, &[1], "a number > 0")?[0];
        if !(v > 0.0) {
            return Err(el.expected(a, "a number > 0"));
        }
        if v < MIN_FPS {
            return Err(el
                .attr_err(
                    a,
                    format!(
                        "fps {} is too small (expected at least {:e}, the smallest normal 32-bit number)",
                        excerpt(&a.value),
                        f32::MIN_POSITIVE
                    ),
                )
                .with_kind(SceneErrorKind::BadValue));
        }
        Ok(f64::from(v as f32))
    }

    /// `frames="first-last"` (or one frame number).
    fn frames(&self, el: &El<'a>) -> Result<Option<Frames>> {
        let Some(a) = el.get("frames") else {
            return Ok(None);
        };
        let expected = format!(
            "a frame number or a range \"first-last\" of frame numbers in [0, {MAX_FRAME}]"
        );
        let v = a.value.trim_matches(is_xml_ws);
        let (lo, hi) = match v.split_once('-') {
            Some((l, h)) => (parse_uint(l), parse_uint(h)),
            None => (parse_uint(v), parse_uint(v)),
        };
        let (Some(first), Some(last)) = (lo, hi) else {
            return Err(el.expected(a, &expected));
        };
        if first > last || last > u64::from(MAX_FRAME) {
            return Err(el.expected(a, &expected));
        }
        Ok(Some(Frames {
            first: first as u32,
            last: last as u32,
        }))
    }
}

/// The smallest `fps=`: the smallest normal 32-bit number (fps is kept
/// in 32 bits, where a smaller one is 0 or loses its precision).
pub const MIN_FPS: f64 = f32::MIN_POSITIVE as f64;

/// An output with `#` is a sequence's pattern: one run of `#`, in the file
/// name, and only with `frames=`; a sequence's output needs one.
fn check_pattern(el: &El, a: &Attr, rel: &str, sequence: bool) -> Result<()> {
    let Some(runs) = crate::scene::animation::frame_runs(rel) else {
        return Err(el.expected(
            a,
            "a file name with one run of # for the frame number (like \"shot.####.png\")",
        ));
    };
    let name = rel.rsplit('/').next().unwrap_or(rel);
    if name.bytes().filter(|&b| b == b'#').count() > MAX_PATTERN_RUN {
        return Err(el.expected(
            a,
            &format!("a run of at most {MAX_PATTERN_RUN} # for the frame number"),
        ));
    }
    match (runs == 1, sequence) {
        (true, false) => Err(el.attr_err(
            a,
            "a frame-number pattern (#) is only for a sequence (expected frames= on this <render>, or a name without #)",
        )),
        (false, true) => Err(el.expected(
            a,
            "a file name with a run of # for the frame number, like \"shot.####.png\" (this <render> has frames=)",
        )),
        _ => Ok(()),
    }
}

/// `aovs=`: render passes by name, separated by whitespace or commas, in
/// any order; an unknown name is refused at the attribute.
fn aovs(el: &El) -> Result<Aovs> {
    let Some(a) = el.get("aovs") else {
        return Ok(Aovs::NONE);
    };
    Aovs::parse(&a.value).map_err(|e| {
        el.attr_err(
            a,
            format!(
                "unknown render pass \"{}\" (expected names among albedo, normal, depth)",
                excerpt(&e.name)
            ),
        )
        .with_kind(SceneErrorKind::BadValue)
    })
}

fn has_image_extension(path: &str) -> bool {
    let lower = path.to_ascii_lowercase();
    lower.ends_with(".png") || lower.ends_with(".exr")
}
