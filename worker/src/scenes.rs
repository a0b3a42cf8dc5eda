//! Scenes moved to a frame of a sequence, kept across the frames of a job.
//!
//! A lease of a frame (`Lease.frame`) needs the scene at that frame. Scenes
//! are built once per bundle (download, parse, every mesh's BVH) and then
//! moved from frame to frame with `Scene::set_frame`, which rebuilds only
//! what a frame changes (instance transforms, the top-level trees, cameras,
//! lights). An entry not in use by a render is moved to the next frame in
//! place; one in use (another lease of the same bundle rendering
//! meanwhile) is left alone and another copy is built. At most `cap`
//! scenes are kept, the least recently used going first, so the memory is
//! `cap` scenes whatever the number of frames.

use std::num::NonZeroUsize;
use std::sync::Arc;
use trevi_core::Scene;

/// What [`FrameScenes::take`] found.
pub enum Found {
    /// The scene at that very frame.
    Ready(Arc<Scene>),
    /// A scene of that bundle at another frame, no longer in use: move it
    /// with `Scene::set_frame` and [`FrameScenes::put`] it back.
    Reuse(Box<Scene>),
    /// Nothing to reuse: build the scene.
    Miss,
}

struct Entry {
    hash: String,
    camera: String,
    frame: u32,
    scene: Arc<Scene>,
}

/// The frame scenes, most recently used last.
pub struct FrameScenes {
    cap: NonZeroUsize,
    entries: Vec<Entry>,
}

impl FrameScenes {
    pub fn new(cap: NonZeroUsize) -> Self {
        FrameScenes {
            cap,
            entries: Vec::new(),
        }
    }

    /// The scene of bundle `hash` at frame `frame` of camera `camera`, or
    /// one to move there, or [`Found::Miss`].
    pub fn take(&mut self, hash: &str, camera: &str, frame: u32) -> Found {
        if let Some(i) = self
            .entries
            .iter()
            .position(|e| e.hash == hash && e.camera == camera && e.frame == frame)
        {
            let e = self.entries.remove(i);
            let s = e.scene.clone();
            self.entries.push(e);
            return Found::Ready(s);
        }
        let free = self
            .entries
            .iter()
            .position(|e| e.hash == hash && Arc::strong_count(&e.scene) == 1);
        if let Some(i) = free {
            let e = self.entries.remove(i);
            if let Ok(scene) = Arc::try_unwrap(e.scene) {
                return Found::Reuse(Box::new(scene));
            }
        }
        Found::Miss
    }

    /// Keeps `scene`, at frame `frame` of camera `camera`.
    pub fn put(&mut self, hash: &str, camera: &str, frame: u32, scene: Arc<Scene>) {
        if self.entries.len() >= self.cap.get() {
            self.entries.remove(0);
        }
        self.entries.push(Entry {
            hash: hash.to_string(),
            camera: camera.to_string(),
            frame,
            scene,
        });
    }

    #[cfg(test)]
    fn len(&self) -> usize {
        self.entries.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use trevi_core::scene::aisxml::parse_scene_str;
    use trevi_core::tile::{render_tile, Rect};
    use trevi_core::Bundle;

    const SCENE: &str = r#"<scene version="1">
      <mesh id="box">
        <vertices>-1 -1 -1  1 -1 -1  1 1 -1  -1 1 -1  -1 -1 1  1 -1 1  1 1 1  -1 1 1</vertices>
        <triangles>0 2 1 0 3 2 4 5 6 4 6 7 0 1 5 0 5 4 3 6 2 3 7 6 0 4 7 0 7 3 1 2 6 1 6 5</triangles>
      </mesh>
      <light position="3 5 4" intensity="1"/>
      <model id="m" mesh="box">
        <animate channel="rotate" times="0 1" values="0 1 0 0  0 1 0 90"/>
      </model>
      <camera id="c" position="0 1 6" lookat="0 0 0" fov="40">
        <render width="16" height="12" frames="0-24" fps="24"/>
      </camera>
    </scene>"#;

    fn built() -> Scene {
        let b = Bundle {
            scene: "s.xml".into(),
            files: Default::default(),
        };
        Scene::build(parse_scene_str("s.xml", SCENE, &b).unwrap())
    }

    fn at(frame: u32) -> Vec<[f32; 3]> {
        let mut s = built();
        s.set_frame(0, frame).unwrap();
        render_tile(&s, 0, Rect::new(0, 0, 16, 12)).pixels
    }

    /// A scene moved through frames renders each like one built for it,
    /// an entry in use is never handed out to be moved, and the cache keeps
    /// at most its capacity.
    #[test]
    fn reused_scenes_render_like_fresh_ones_and_stay_bounded() {
        let mut c = FrameScenes::new(NonZeroUsize::new(2).unwrap());
        assert!(matches!(c.take("h", "c", 3), Found::Miss));
        let mut s = built();
        s.set_frame(0, 3).unwrap();
        c.put("h", "c", 3, Arc::new(s));
        let held = match c.take("h", "c", 3) {
            Found::Ready(s) => s,
            _ => panic!("frame 3 is cached"),
        };
        // In use: another frame of the bundle must be built afresh.
        assert!(matches!(c.take("h", "c", 12), Found::Miss));
        drop(held);
        let mut s = match c.take("h", "c", 12) {
            Found::Reuse(s) => *s,
            _ => panic!("the free scene is reused"),
        };
        s.set_frame(0, 12).unwrap();
        let moved = render_tile(&s, 0, Rect::new(0, 0, 16, 12)).pixels;
        assert_eq!(moved, at(12));
        assert_ne!(moved, at(3), "frame 12 differs from frame 3");
        c.put("h", "c", 12, Arc::new(s));
        c.put("g", "c", 1, Arc::new(built()));
        c.put("k", "c", 1, Arc::new(built()));
        assert_eq!(c.len(), 2);
        assert!(
            matches!(c.take("h", "c", 12), Found::Miss),
            "the oldest went"
        );
    }
}
