//! What the coordinator needs to know of a stored bundle's scene, parsed
//! once per bundle: each camera's id, frame size, supersampling and output.
//!
//! Submitting one job per camera of a scene asks the same bundle about each
//! camera in turn; without this cache every submission would decode and
//! parse the whole bundle (meshes included) again. With it, a submission
//! on a cached bundle still has the stored copy checked against its hash
//! (so a copy damaged on disk is refused), which reads it but parses
//! nothing. The cache is small
//! ([`Summaries::CAPACITY`] bundles, the least recently used dropped first)
//! because a summary is only worth keeping while its jobs are being
//! submitted, and it holds only what [`crate::Farm::job_spec`] reads, never
//! the meshes. A local render hands the description it already parsed to
//! [`Summaries::prime`], so the embedded coordinator does not parse at all.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use trevi_core::SceneDesc;

/// One camera of a scene, as a job needs it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CameraSummary {
    pub id: String,
    pub width: u32,
    pub height: u32,
    pub supersample: u32,
    /// Bundle-relative output path.
    pub output: String,
}

/// The cameras of a scene, in document order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SceneSummary {
    pub cameras: Vec<CameraSummary>,
    /// What the scene needs once built, in bytes
    /// ([`trevi_core::scene::estimate`]): which workers can take its jobs.
    pub memory: u64,
}

impl SceneSummary {
    pub fn of(desc: &SceneDesc) -> SceneSummary {
        SceneSummary {
            cameras: desc
                .cameras
                .iter()
                .map(|c| CameraSummary {
                    id: c.id.clone(),
                    width: c.render.width,
                    height: c.render.height,
                    supersample: c.render.supersample,
                    output: c.render.output.clone(),
                })
                .collect(),
            memory: trevi_core::scene::estimate::estimate(desc).total(),
        }
    }
}

/// Summaries by bundle hash, most recently used last.
#[derive(Default)]
pub struct Summaries {
    entries: Mutex<VecDeque<(String, Arc<SceneSummary>)>>,
    /// How many summaries were made by parsing a bundle (see
    /// [`Summaries::parses`]).
    parses: std::sync::atomic::AtomicU64,
}

impl Summaries {
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
    pub fn prime(&self, hash: &str, desc: &SceneDesc) {
        self.put(hash, Arc::new(SceneSummary::of(desc)));
    }

    /// How many summaries were made by parsing a bundle so far.
    pub fn parses(&self) -> u64 {
        self.parses.load(std::sync::atomic::Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn summary(n: u32) -> Arc<SceneSummary> {
        Arc::new(SceneSummary {
            cameras: vec![CameraSummary {
                id: format!("c{n}"),
                width: n,
                height: n,
                supersample: 1,
                output: "c.png".into(),
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

    #[test]
    fn a_primed_summary_spares_the_parse() {
        let (_tmp, farm, hash, bundle) = farm_with_the_scene();
        let parsed = trevi_core::ParsedBundle::parse(bundle).unwrap();
        farm.summaries().prime(&hash, &parsed.desc);
        assert_eq!(farm.job_spec(&hash, "b", 0, 0).unwrap().width, 4);
        assert_eq!(farm.summaries().parses(), 0);
    }
}
