//! What the coordinator needs to know of a stored bundle's scene, parsed
//! once per bundle: each camera's id, frame size, supersampling and output.
//!
//! Submitting one job per camera of a scene asks the same bundle about each
//! camera in turn; without this cache every submission would decode and
//! read the whole bundle's scene again. With it, a submission
//! on a cached bundle still has the stored copy checked against its hash
//! (so a copy damaged on disk is refused), which reads it but parses
//! nothing. The cache is small
//! ([`Summaries::CAPACITY`] bundles, the least recently used dropped first)
//! because a summary is only worth keeping while its jobs are being
//! submitted, and it holds only what [`crate::Farm::job_spec`] reads, never
//! the meshes. A summary is made by the headers-only parse, within the
//! admission bounds of [`crate::admission`]. A local render hands the description it already parsed to
//! [`Summaries::prime`], so the embedded coordinator does not parse at all.

use crate::admission::{admission_cost, Admissions, Ticket};
use crate::bundles::BundleStore;
use crate::error::FarmError;
use crate::limits::Limits;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use trevi_core::scene::aisxml::SceneHeaders;
use trevi_core::SceneDesc;

/// One camera of a scene, as a job needs it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CameraSummary {
    /// The camera's id, unique in its scene.
    pub id: String,
    /// The frame's width in pixels.
    pub width: u32,
    /// The frame's height in pixels.
    pub height: u32,
    /// n: n×n samples per pixel.
    pub supersample: u32,
    /// Samples per pixel: `supersample²`, or `max-samples` with adaptive
    /// sampling (`trevi_core::integrator::samples_per_pixel`).
    pub samples_per_pixel: u32,
    /// Bundle-relative output path.
    pub output: String,
    /// The camera's render passes (`<render aovs>`): a job's unless its
    /// submission says otherwise.
    pub aovs: trevi_core::Aovs,
}

/// The cameras of a scene, in document order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SceneSummary {
    /// The scene file's name in its bundle.
    pub scene: String,
    /// The scene's cameras, in document order.
    pub cameras: Vec<CameraSummary>,
    /// What the scene needs once built, in bytes
    /// ([`trevi_core::scene::estimate`]): which workers can take its jobs.
    pub memory: u64,
}

impl SceneSummary {
    /// The summary of a fully parsed scene, `scene` its file's name.
    pub fn of(scene: &str, desc: &SceneDesc) -> SceneSummary {
        Self::with_memory(
            scene,
            desc,
            trevi_core::scene::estimate::estimate(desc).total(),
        )
    }

    /// The summary of a scene read by the headers-only parse (see
    /// [`crate::admission`]).
    pub fn of_headers(scene: &str, h: &SceneHeaders) -> SceneSummary {
        Self::with_memory(scene, &h.desc, h.estimate().total())
    }

    fn with_memory(scene: &str, desc: &SceneDesc, memory: u64) -> SceneSummary {
        SceneSummary {
            scene: scene.to_string(),
            cameras: desc
                .cameras
                .iter()
                .map(|c| CameraSummary {
                    id: c.id.clone(),
                    width: c.render.width,
                    height: c.render.height,
                    supersample: c.render.supersample,
                    samples_per_pixel: trevi_core::integrator::samples_per_pixel(&c.render),
                    output: c.render.output.clone(),
                    aovs: c.render.aovs,
                })
                .collect(),
            memory,
        }
    }
}

/// Summaries by bundle hash, most recently used last; and the gate the
/// parses that make them go through (see [`crate::admission`]).
pub struct Summaries {
    entries: Mutex<VecDeque<(String, Arc<SceneSummary>)>>,
    /// How many summaries were made by parsing a bundle (see
    /// [`Summaries::parses`]).
    parses: std::sync::atomic::AtomicU64,
    admissions: Admissions,
}

impl Default for Summaries {
    fn default() -> Self {
        Summaries::new(&Limits::default())
    }
}

impl Summaries {
    /// An empty cache whose parses are bounded by `limits`'
    /// `max_admissions` and `admission_bytes`.
    pub fn new(limits: &Limits) -> Summaries {
        Summaries {
            entries: Mutex::default(),
            parses: Default::default(),
            admissions: Admissions::new(limits),
        }
    }

    /// The admissions in progress.
    pub fn admissions(&self) -> &Admissions {
        &self.admissions
    }

    /// The summary of `hash`, from the cache or made by `parse` within an
    /// admission (refused when the admissions are full; see
    /// [`Admissions::enter`]).
    pub fn get_or_admit(
        &self,
        hash: &str,
        parse: impl FnOnce(&mut Ticket) -> Result<SceneSummary, crate::error::FarmError>,
    ) -> Result<Arc<SceneSummary>, crate::error::FarmError> {
        self.get_or_parse(hash, || {
            let mut ticket = self.admissions.enter()?;
            parse(&mut ticket)
        })
    }

    /// How many bundles' summaries are kept.
    pub const CAPACITY: usize = 16;

    /// The summary of `hash`, if it is cached.
    pub fn get(&self, hash: &str) -> Option<Arc<SceneSummary>> {
        let mut entries = self.entries.lock().unwrap_or_else(|p| p.into_inner());
        let i = entries.iter().position(|(h, _)| h == hash)?;
        let e = entries.remove(i)?;
        let s = e.1.clone();
        entries.push_back(e);
        Some(s)
    }

    /// Keeps `summary` as the one of `hash`.
    pub fn put(&self, hash: &str, summary: Arc<SceneSummary>) {
        let mut entries = self.entries.lock().unwrap_or_else(|p| p.into_inner());
        entries.retain(|(h, _)| h != hash);
        if entries.len() >= Self::CAPACITY {
            entries.pop_front();
        }
        entries.push_back((hash.to_string(), summary));
    }

    /// The summary of `hash`, from the cache or made by `parse` (and then
    /// kept). Two callers missing at once may both parse; the result is the
    /// same.
    pub fn get_or_parse<E>(
        &self,
        hash: &str,
        parse: impl FnOnce() -> Result<SceneSummary, E>,
    ) -> Result<Arc<SceneSummary>, E> {
        if let Some(s) = self.get(hash) {
            return Ok(s);
        }
        let s = Arc::new(parse()?);
        self.parses
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.put(hash, s.clone());
        Ok(s)
    }

    /// Keeps the summary of a scene already parsed elsewhere (the
    /// submitter's own parse, in a local render), so that no job of
    /// bundle `hash` parses it again.
    /// `scene` is the scene file's name in the bundle.
    pub fn prime(&self, hash: &str, scene: &str, desc: &SceneDesc) {
        self.put(hash, Arc::new(SceneSummary::of(scene, desc)));
    }

    /// How many summaries were made by parsing a bundle so far.
    pub fn parses(&self) -> u64 {
        self.parses.load(std::sync::atomic::Ordering::Relaxed)
    }
}

/// The summary of the stored bundle `hash`, from the headers-only parse of
/// its scene, counted against `ticket` before the bundle is decoded.
pub fn summarize(
    bundles: &BundleStore,
    hash: &str,
    ticket: &mut Ticket,
) -> Result<SceneSummary, FarmError> {
    let bytes = bundles.get_bytes(hash)?;
    ticket.reserve(admission_cost(bytes.len() as u64))?;
    let bundle =
        trevi_core::Bundle::decode(&bytes).map_err(|e| FarmError::BadBundle(e.to_string()))?;
    drop(bytes);
    let headers = trevi_core::scene::aisxml::parse_scene_headers(&bundle.scene, &bundle)
        .map_err(FarmError::from)?;
    Ok(SceneSummary::of_headers(&bundle.scene, &headers))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn summary(n: u32) -> Arc<SceneSummary> {
        Arc::new(SceneSummary {
            scene: "s.xml".into(),
            cameras: vec![CameraSummary {
                id: format!("c{n}"),
                width: n,
                height: n,
                supersample: 1,
                samples_per_pixel: 1,
                output: "c.png".into(),
                aovs: trevi_core::Aovs::NONE,
            }],
            memory: 0,
        })
    }

    #[test]
    fn parses_once_per_bundle_and_keeps_the_most_recently_used() {
        let s = Summaries::default();
        for _ in 0..3 {
            let got = s
                .get_or_parse::<()>("a", || Ok((*summary(1)).clone()))
                .unwrap();
            assert_eq!(got.cameras[0].width, 1);
        }
        assert_eq!(s.parses(), 1);
        for n in 0..Summaries::CAPACITY as u32 - 1 {
            s.put(&format!("h{n}"), summary(n));
        }
        // "a" was used least recently but still fits; one more pushes it out.
        assert!(s.get("a").is_some());
        s.put("x", summary(7));
        assert!(s.get("h0").is_none());
        assert!(s.get("a").is_some());
        // An error is not kept.
        assert_eq!(s.get_or_parse("bad", || Err("no")), Err("no"));
        assert!(s.get("bad").is_none());
    }

    const TWO_CAMERAS: &str = r#"<scene version="1">
  <sphere id="s" center="0 0 0" radius="1"/>
  <camera id="a" position="0 0 5" lookat="0 0 0" fov="40"><render width="8" height="6"/></camera>
  <camera id="b" position="0 0 5" lookat="0 0 0" fov="40"><render width="4" height="2"/></camera>
</scene>"#;

    fn farm_with_the_scene() -> (tempfile::TempDir, crate::Farm, String, trevi_core::Bundle) {
        let tmp = tempfile::tempdir().unwrap();
        let mut cfg = crate::FarmConfig::new(tmp.path());
        cfg.durable = false;
        let farm = crate::Farm::new(cfg).unwrap();
        let bundle = trevi_core::Bundle {
            scene: "scene.xml".into(),
            files: [("scene.xml".to_string(), TWO_CAMERAS.as_bytes().to_vec())].into(),
        };
        let mut up = farm.bundles().begin_upload().unwrap();
        up.write(&bundle.encode()).unwrap();
        let hash = farm.bundles().finish_upload(up, usize::MAX).unwrap();
        (tmp, farm, hash, bundle)
    }

    #[test]
    fn a_farm_parses_a_bundle_once_for_all_its_cameras() {
        let (tmp, farm, hash, _) = farm_with_the_scene();
        let a = farm.job_spec(&hash, "a", 0, 0).unwrap();
        let b = farm.job_spec(&hash, "b", 0, 0).unwrap();
        let first = farm.job_spec(&hash, "", 0, 0).unwrap();
        assert_eq!((a.width, a.height, b.width, b.height), (8, 6, 4, 2));
        assert_eq!(first.camera, "a");
        assert_eq!(farm.summaries().parses(), 1);
        assert!(farm.job_spec(&hash, "c", 0, 0).is_err());
        // A bundle not stored is refused even if a summary were cached; so
        // is a stored copy damaged since it was parsed.
        farm.summaries().put("0".repeat(64).as_str(), summary(1));
        assert!(farm.job_spec(&"0".repeat(64), "c1", 0, 0).is_err());
        let stored = tmp.path().join("bundles").join(&hash);
        let mut bytes = std::fs::read(&stored).unwrap();
        let last = bytes.len() - 1;
        bytes[last] ^= 1;
        std::fs::write(&stored, bytes).unwrap();
        assert!(matches!(
            farm.job_spec(&hash, "a", 0, 0),
            Err(crate::FarmError::BadBundle(m)) if m.contains("damaged")
        ));
        assert_eq!(farm.summaries().parses(), 1);
    }

    /// A stored bundle of `files`, its scene `s.xml`, on a farm with
    /// `limits`.
    fn farm_with(
        limits: Limits,
        files: &[(&str, &[u8])],
    ) -> (tempfile::TempDir, crate::Farm, String) {
        let tmp = tempfile::tempdir().unwrap();
        let mut cfg = crate::FarmConfig::new(tmp.path());
        cfg.durable = false;
        cfg.limits = limits;
        let farm = crate::Farm::new(cfg).unwrap();
        let bundle = trevi_core::Bundle {
            scene: "s.xml".into(),
            files: files
                .iter()
                .map(|(n, b)| (n.to_string(), b.to_vec()))
                .collect(),
        };
        let mut up = farm.bundles().begin_upload().unwrap();
        up.write(&bundle.encode()).unwrap();
        let hash = farm.bundles().finish_upload(up, usize::MAX).unwrap();
        (tmp, farm, hash)
    }

    #[test]
    fn an_admission_beyond_the_limit_is_refused_naming_the_flag() {
        let limits = Limits {
            max_admissions: 1,
            ..Limits::default()
        };
        let (_tmp, farm, hash) = farm_with(limits, &[("s.xml", TWO_CAMERAS.as_bytes())]);
        // Another admission in progress (held here; a barrier in effect).
        let other = farm.summaries().admissions().enter().unwrap();
        let e = farm.job_spec(&hash, "a", 0, 0).unwrap_err();
        assert!(
            matches!(&e, crate::FarmError::Limit(l) if l.flag() == Some("--max-admissions")),
            "{e}"
        );
        assert_eq!(farm.summaries().parses(), 0);
        drop(other);
        assert_eq!(farm.job_spec(&hash, "a", 0, 0).unwrap().width, 8);
        assert_eq!(farm.summaries().admissions().in_progress(), (0, 0));
    }

    /// A PNG signature and an IHDR claiming `side²` RGB, and no pixel data:
    /// only a reader of headers can take it.
    fn png_header(side: u32) -> Vec<u8> {
        let mut b = b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR".to_vec();
        b.extend_from_slice(&side.to_be_bytes());
        b.extend_from_slice(&side.to_be_bytes());
        b.extend_from_slice(&[8, 2, 0, 0, 0, 0, 0, 0, 0]);
        b
    }

    #[test]
    fn a_job_is_admitted_from_its_textures_headers() {
        let scene = r#"<scene version="1">
  <mesh id="q"><vertices>0 0 0 1 0 0 0 1 0</vertices><uvs>0 0 1 0 0 1</uvs><triangles>0 1 2</triangles></mesh>
  <model id="m" mesh="q"><surface diffuse-texture="t.png"/></model>
  <camera id="a" position="0 0 5" lookat="0 0 0" fov="40"><render width="8" height="6"/></camera>
</scene>"#;
        let png = png_header(4096);
        let (_tmp, farm, hash) = farm_with(
            Limits::default(),
            &[("s.xml", scene.as_bytes()), ("t.png", &png)],
        );
        // Decoding would fail (there are no pixels); the header is enough.
        farm.job_spec(&hash, "a", 0, 0).unwrap();
        let s = farm.summaries().get(&hash).unwrap();
        assert!(s.memory >= 4096 * 4096 * 12, "{}", s.memory);
        // A claim beyond the texture bounds is refused from the header.
        let (_tmp, farm, hash) = farm_with(
            Limits::default(),
            &[("s.xml", scene.as_bytes()), ("t.png", &png_header(20_000))],
        );
        let e = farm.job_spec(&hash, "a", 0, 0).unwrap_err();
        assert!(
            matches!(&e, crate::FarmError::BadScene(crate::error::BadScene::Scene(s)) if s.location.line == 3 && s.to_string().contains("s.xml:3:") && s.message.contains("20000 x 20000")),
            "{e}"
        );
    }

    #[test]
    fn a_primed_summary_spares_the_parse() {
        let (_tmp, farm, hash, bundle) = farm_with_the_scene();
        let parsed = trevi_core::ParsedBundle::parse(bundle).unwrap();
        farm.summaries()
            .prime(&hash, &parsed.bundle.scene, &parsed.desc);
        assert_eq!(farm.job_spec(&hash, "b", 0, 0).unwrap().width, 4);
        assert_eq!(farm.summaries().parses(), 0);
    }
}
