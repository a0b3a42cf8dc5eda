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
    let mut c = SceneCache::new(NonZeroUsize::new(2).unwrap());
    assert!(matches!(c.take(&Key::frame("h", "c", 3)), Found::Miss));
    let mut s = built();
    s.set_frame(0, 3).unwrap();
    c.put(Key::frame("h", "c", 3), Arc::new(s));
    let held = match c.take(&Key::frame("h", "c", 3)) {
        Found::Ready(s) => s,
        _ => panic!("frame 3 is cached"),
    };
    // In use: another frame of the bundle must be built afresh.
    assert!(matches!(c.take(&Key::frame("h", "c", 12)), Found::Miss));
    drop(held);
    let mut s = match c.take(&Key::frame("h", "c", 12)) {
        Found::Reuse(s) => *s,
        _ => panic!("the free scene is reused"),
    };
    s.set_frame(0, 12).unwrap();
    let moved = render_tile(&s, 0, Rect::new(0, 0, 16, 12)).pixels;
    assert_eq!(moved, at(12));
    assert_ne!(moved, at(3), "frame 12 differs from frame 3");
    c.put(Key::frame("h", "c", 12), Arc::new(s));
    c.put(Key::frame("g", "c", 1), Arc::new(built()));
    c.put(Key::frame("k", "c", 1), Arc::new(built()));
    assert_eq!(c.len(), 2);
    assert!(
        matches!(c.take(&Key::frame("h", "c", 12)), Found::Miss),
        "the oldest went"
    );
}

/// Stills' scenes and frames' scenes are kept apart: a still's scene is
/// never handed out to be moved to a frame, and each kind keeps `cap`
/// entries, the oldest of its own kind going first.
#[test]
fn stills_and_frames_keep_their_own_room() {
    let mut c = SceneCache::new(NonZeroUsize::new(2).unwrap());
    c.put(Key::still("h"), Arc::new(built()));
    assert!(
        matches!(c.take(&Key::frame("h", "c", 3)), Found::Miss),
        "a still's scene is not moved to a frame"
    );
    assert!(matches!(c.take(&Key::still("h")), Found::Ready(_)));
    assert!(matches!(c.take(&Key::still("g")), Found::Miss));
    // Frames fill their own room: the still stays.
    for f in 0..3 {
        c.put(Key::frame("h", "c", f), Arc::new(built()));
    }
    assert_eq!(c.len(), 3);
    assert!(matches!(c.take(&Key::still("h")), Found::Ready(_)));
    assert!(matches!(c.take(&Key::frame("h", "c", 0)), Found::Reuse(_)));
    // Stills fill theirs: the oldest still goes, the frames stay.
    c.put(Key::still("g"), Arc::new(built()));
    c.put(Key::still("k"), Arc::new(built()));
    assert!(matches!(c.take(&Key::still("h")), Found::Miss));
    assert!(matches!(c.take(&Key::still("g")), Found::Ready(_)));
    assert!(matches!(c.take(&Key::frame("h", "c", 2)), Found::Ready(_)));
}

/// A pass's scene (`set_samples`) is kept under a key of its own: a lease
/// without samples, or with another total or camera, never gets it, and a
/// frame scene is reused only for the same samples.
#[test]
fn samples_are_part_of_the_key() {
    let mut c = SceneCache::new(NonZeroUsize::new(4).unwrap());
    let eight = Key::still("h").with_samples("c", 8);
    assert_eq!(Key::still("h").with_samples("c", 0), Key::still("h"));
    c.put(eight.clone(), Arc::new(built()));
    assert!(matches!(c.take(&Key::still("h")), Found::Miss));
    assert!(matches!(
        c.take(&Key::still("h").with_samples("c", 9)),
        Found::Miss
    ));
    assert!(matches!(
        c.take(&Key::still("h").with_samples("d", 8)),
        Found::Miss
    ));
    assert!(matches!(c.take(&eight), Found::Ready(_)));
    // Frames combine with samples.
    c.put(
        Key::frame("h", "c", 3).with_samples("c", 8),
        Arc::new(built()),
    );
    assert!(matches!(c.take(&Key::frame("h", "c", 4)), Found::Miss));
    assert!(matches!(
        c.take(&Key::frame("h", "c", 4).with_samples("c", 16)),
        Found::Miss
    ));
    assert!(matches!(
        c.take(&Key::frame("h", "c", 4).with_samples("c", 8)),
        Found::Reuse(_)
    ));
}
