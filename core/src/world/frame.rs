//! A sequence's frames from one built scene: moving to a frame re-evaluates
//! the keyed channels and rebuilds only what depends on them (instance
//! transforms, the top-level trees, cameras, lights, bounds); the meshes and
//! their BVHs, the bulk of a scene's build, are kept.

use super::Scene;
use crate::scene::animation::{frame_time, FrameError};

impl Scene {
    /// The scene has keyed channels (`<animate>`).
    pub fn animated(&self) -> bool {
        !self.desc.animation.is_empty()
    }

    /// Moves the scene to frame `frame` of camera `camera`'s sequence: every
    /// keyed channel at `t = frame / fps` (the camera's `fps`), and the
    /// frame number in every camera's sample hash, so that noise changes
    /// from frame to frame. The mesh BVHs are not rebuilt; the views are
    /// rebuilt when next asked for. A frame depends only on the scene and
    /// `frame`, not on the frames set before.
    pub fn set_frame(&mut self, camera: usize, frame: u32) -> Result<(), FrameError> {
        let t = frame_time(frame, self.desc.cameras[camera].render.fps);
        let animation = std::mem::take(&mut self.desc.animation);
        let applied = animation.apply(&mut self.desc, t);
        self.desc.animation = animation;
        applied?;
        self.place(Some(frame));
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use crate::scene::aisxml::parse_scene_str;
    use crate::tile::{render_tile, Rect};
    use crate::Bundle;
    use crate::Scene;

    const MESH: &str = r#"<mesh id="box">
      <vertices>-1 -1 -1  1 -1 -1  1 1 -1  -1 1 -1  -1 -1 1  1 -1 1  1 1 1  -1 1 1</vertices>
      <triangles>0 2 1 0 3 2 4 5 6 4 6 7 0 1 5 0 5 4 3 6 2 3 7 6 0 4 7 0 7 3 1 2 6 1 6 5</triangles>
    </mesh>
    <light position="3 5 4" intensity="1"/>"#;

    fn scene(body: &str) -> Scene {
        let text = format!("<scene version=\"1\">{MESH}{body}</scene>");
        let desc = parse_scene_str(
            "s.xml",
            &text,
            &Bundle {
                scene: "s.xml".into(),
                files: Default::default(),
            },
        )
        .unwrap();
        Scene::build(desc)
    }

    fn pixels(s: &Scene) -> Vec<[f32; 3]> {
        render_tile(s, 0, Rect::new(0, 0, 24, 16)).pixels
    }

    /// An animated scene at frame 12 (t = 0.5 s at 24 fps) renders like the
    /// same scene written without keys, with the keyed values at 0.5 s
    /// worked out by hand (deterministic sampling, so the frame's sample
    /// hash does not show).
    #[test]
    fn a_frame_renders_like_the_scene_written_at_its_time() {
        let mut animated = scene(
            r#"<model id="m" mesh="box">
                 <transform><scale v="0.5"/></transform>
                 <animate channel="rotate" times="0 1" values="0 1 0 0  0 1 0 90"/>
                 <animate channel="translate" times="0 1" values="0 0 0  2 0 0"/>
               </model>
               <camera id="c" position="0 1 6" lookat="0 0 0" fov="40">
                 <animate channel="position" times="0 1" values="0 1 6  0 3 6"/>
                 <render width="24" height="16" frames="0-24" fps="24"/>
               </camera>"#,
        );
        let fixed = scene(
            r#"<model id="m" mesh="box">
                 <transform><scale v="0.5"/><rotate axis="0 1 0" angle="45"/><translate v="1 0 0"/></transform>
               </model>
               <camera id="c" position="0 2 6" lookat="0 0 0" fov="40">
                 <render width="24" height="16"/>
               </camera>"#,
        );
        let blas = animated.blas.as_ptr();
        animated.set_frame(0, 12).unwrap();
        assert_eq!(pixels(&animated), pixels(&fixed));
        // The mesh BVHs were kept, not rebuilt.
        assert_eq!(animated.blas.as_ptr(), blas);
        // Frames do not depend on the frames before: 3 then 12 is 12.
        let first = pixels(&animated);
        animated.set_frame(0, 3).unwrap();
        assert_ne!(pixels(&animated), first);
        animated.set_frame(0, 12).unwrap();
        assert_eq!(pixels(&animated), first);
    }

    /// The frame number enters the sample hash: a jittered scene without
    /// keys gives different noise in two frames, and the same noise in the
    /// same frame; a still (no frame set) keeps the hash of a scene without
    /// frames.
    #[test]
    fn the_frame_number_moves_the_noise() {
        let body = r#"<model id="m" mesh="box"/>
               <camera id="c" position="0 1 6" lookat="0 0 0" fov="40">
                 <render width="24" height="16" jitter="true" supersample="2"/>
               </camera>"#;
        let still = pixels(&scene(body));
        let mut s = scene(body);
        assert_eq!(pixels(&s), still);
        s.set_frame(0, 1).unwrap();
        let one = pixels(&s);
        s.set_frame(0, 2).unwrap();
        let two = pixels(&s);
        assert_ne!(one, two);
        assert_ne!(one, still);
        s.set_frame(0, 1).unwrap();
        assert_eq!(pixels(&s), one);
    }

    #[test]
    fn a_camera_that_degenerates_between_keys_is_an_error_at_that_frame() {
        // Looking along +z at t = 0 and −z at t = 1: halfway the linear
        // direction is zero.
        let mut s = scene(
            r#"<camera id="c" position="0 0 0" direction="0 0 1" fov="40">
                 <animate channel="direction" times="0 1" values="0 0 1  0 0 -1"/>
                 <render width="4" height="4" frames="0-2" fps="2"/>
               </camera>"#,
        );
        let e = s.set_frame(0, 1).unwrap_err();
        assert_eq!(e.camera, "c");
        assert_eq!(e.t, 0.5);
        assert!(s.set_frame(0, 2).is_ok());
    }
}
