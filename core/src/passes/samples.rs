//! A progressive job's own sample count (`trevi-submit --samples N`): the
//! camera's sampling replaced by adaptive sampling with `min-samples` =
//! `max-samples` = N, which never stops a pixel before N and whose sample
//! sequence is the same whatever N (docs/progressive.md, "Which totals
//! extend"), so a render of N samples continues into one of any larger
//! count.

use crate::scene::Adaptive;
use crate::world::Scene;

/// Most samples per pixel a job may ask for of its own (`--samples`, and
/// a job's total after `extend`): 2²⁰. The farm's admission bounds the
/// job's cost with it as with the scene's own count.
pub const MAX_SAMPLES: u32 = 1 << 20;

impl Scene {
    /// Renders camera `camera` with exactly `total` samples per pixel
    /// (at least 1) on the extendable sequence: the scene's grid or
    /// adaptive settings give way to `min-samples = max-samples = total`.
    /// Only the camera's render settings change; nothing is rebuilt.
    pub fn set_samples(&mut self, camera: usize, total: u32) {
        let total = total.max(1);
        self.desc.cameras[camera].render.adaptive = Some(Adaptive {
            // Never consulted before `max_samples`, where the pixel stops
            // anyway (integrator/accumulate.rs).
            threshold: 0.0,
            min_samples: total,
            max_samples: total,
        });
    }
}

#[cfg(test)]
mod tests {
    use crate::passes::TileState;
    use crate::testing::scene;
    use crate::tile::{render_tile, Rect};
    use std::sync::atomic::AtomicBool;

    /// A grid scene given 24 samples renders, in passes and at once, what
    /// the same scene written with `min-samples = max-samples = 24`
    /// renders.
    #[test]
    fn set_samples_is_the_scene_written_with_min_equal_max() {
        let grid = |render: &str| {
            format!(
                r#"<scene version="1">
  <sphere id="s" center="0 0 0" radius="1"><surface diffuse="0.8 0.3 0.2"/></sphere>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1" radius="1"/>
  <camera id="c" position="0 0 5" lookat="0 0 0" up="0 1 0" fov="30">
    <render width="5" height="4" {render} shadow-samples="1" output="o.png"/>
  </camera>
</scene>"#
            )
        };
        let mut set = scene(&grid(r#"supersample="3" jitter="true""#));
        let written = scene(&grid(
            r#"noise-threshold="0.5" min-samples="24" max-samples="24""#,
        ));
        let bits =
            |p: Vec<[f32; 3]>| -> Vec<[u32; 3]> { p.iter().map(|v| v.map(f32::to_bits)).collect() };
        let rect = Rect::new(0, 0, 5, 4);
        let before = bits(render_tile(&set, 0, rect).pixels);
        set.set_samples(0, 24);
        let once = bits(render_tile(&written, 0, rect).pixels);
        assert_eq!(bits(render_tile(&set, 0, rect).pixels), once);
        assert_ne!(before, once, "the grid's own samples differ");
        let never = AtomicBool::new(false);
        let mut state = TileState::new(rect);
        for r in [0..5, 5..6, 6..24] {
            state.render(&set, 0, r, &never).unwrap();
        }
        assert_eq!(bits(state.finish()), once);
    }
}
