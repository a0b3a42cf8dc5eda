use crate::integrator::{Integrator, RenderOptions};
use crate::{Bundle, Scene};
use std::collections::BTreeMap;

pub(super) fn scene(xml: &str) -> Scene {
    let mut files = BTreeMap::new();
    files.insert("s.xml".to_string(), xml.as_bytes().to_vec());
    Scene::from_bundle(&Bundle {
        scene: "s.xml".into(),
        files,
    })
    .unwrap()
}

/// Every pixel of camera 0, row by row.
pub(super) fn pixels(s: &Scene) -> Vec<[f32; 3]> {
    let r = &s.desc.cameras[0].render;
    let it = Integrator::observed(s, 0, RenderOptions::default(), &());
    (0..r.height)
        .flat_map(|y| (0..r.width).map(move |x| (x, y)))
        .map(|(x, y)| it.pixel(x, y).0)
        .collect()
}
