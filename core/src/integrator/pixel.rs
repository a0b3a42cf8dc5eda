//! A pixel's estimate (the n×n box-filtered grid, or adaptive sampling),
//! over all its samples or over a range of them continuing a
//! [`PixelState`] (docs/progressive.md), and the two doors every ray goes
//! through, where a render is cancelled.
//!
//! One pixel may cost hours (`supersample="65535"` is 2³² camera samples,
//! `max-bounces="10000"` or `diffuse-samples="65536"` multiply that), so a
//! cancellation flag read only between pixels would leave a cancelled
//! render running for hours. [`Integrator::trace`] and
//! [`Integrator::trace_shadow`] read the flag (one relaxed load) every
//! [`CANCEL_EVERY`] rays; once it is set, every further ray of the pixel
//! misses at once, so loops of any size over samples, lights or gather
//! directions run out in a few cycles each, and the camera-sample loop stops
//! at the next sample. The pixel is then [`Cancelled`]: its half-made value
//! is never returned. An uncancelled pixel is computed by exactly the same
//! arithmetic as before the flag existed (the checks change no value).

use super::accumulate::PixelState;
use super::aov::{AovSums, MAX_AOV_CHANNELS};
use super::{Integrator, PixelContext, RayObserver, STREAM_PIXEL};
use crate::aov::Aovs;
use crate::sampling::{pixel_seed, PixelSampler};
use crate::scene::RenderSettings;
use crate::world::Hit;
use glam::Vec3;
use std::sync::atomic::{AtomicBool, Ordering};

/// The cancellation flag is read once per this many rays (a power of two).
/// A ray costs well under 10 µs even in a large, incoherent scene, so a
/// cancelled pixel stops within a few milliseconds of work per thread.
pub const CANCEL_EVERY: u64 = 256;

/// The flag of an integrator that is never cancelled.
pub(super) static NEVER: AtomicBool = AtomicBool::new(false);

/// The render of a pixel (and so of its tile) was stopped by its
/// cancellation flag; it has no value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("the render of the tile was cancelled")]
pub struct Cancelled;

/// How many samples a pixel of a camera with settings `r` takes at most:
/// supersample² on the grid, `max-samples` with adaptive sampling (which may
/// stop a pixel sooner).
pub fn samples_per_pixel(r: &RenderSettings) -> u32 {
    match r.adaptive {
        // n ≤ MAX_SUPERSAMPLE, so n² fits in a u32 (the parser's bound).
        None => r.supersample * r.supersample,
        Some(a) => a.max_samples,
    }
}

impl<'a, O: RayObserver> Integrator<'a, O> {
    /// This integrator, stopping any pixel soon after `cancel` turns true
    /// (see the module's documentation).
    pub fn cancelled_by(mut self, cancel: &'a AtomicBool) -> Self {
        self.cancel = cancel;
        self
    }

    /// The linear RGB value of pixel (column `x`, row `y`), and rays traced;
    /// [`Cancelled`] once the integrator's flag is set (see
    /// [`Integrator::cancelled_by`]; never without it). Every sample of the
    /// pixel in one range: [`Integrator::pixel_samples`] from no samples,
    /// finished.
    pub fn pixel(&self, x: u32, y: u32) -> Result<([f32; 3], u64), Cancelled> {
        let mut state = PixelState::default();
        let rays = self.pixel_samples(x, y, u32::MAX, &mut state)?;
        Ok((state.finish(), rays))
    }

    /// How many samples a pixel takes at most: supersample² on the grid,
    /// `max-samples` with adaptive sampling (which may stop a pixel
    /// sooner).
    pub fn samples_per_pixel(&self) -> u32 {
        samples_per_pixel(&self.desc.render)
    }

    /// Continues pixel (`x`, `y`) from `state` up to sample index `end`
    /// (exclusive; past [`Integrator::samples_per_pixel`] it stops there):
    /// samples `state.count()..end`, fewer if adaptive sampling stops the
    /// pixel. Returns the rays traced. Sample `i` is the same whatever
    /// range it falls in, and the sums go on exactly where they stopped, so
    /// any split of a pixel's samples into ranges finishes to the bytes of
    /// [`Integrator::pixel`]. On [`Cancelled`] `state` is left as it was.
    pub fn pixel_samples(
        &self,
        x: u32,
        y: u32,
        end: u32,
        state: &mut PixelState,
    ) -> Result<u64, Cancelled> {
        self.samples_with::<false>(x, y, end, state, None)
    }

    /// [`Integrator::pixel`] with the render passes `aovs` (see
    /// [`crate::aov`]): the beauty (the bytes of [`Integrator::pixel`]),
    /// the passes' means in the first `aovs.channels()` values, and the
    /// rays traced (the passes' own rays included).
    #[allow(clippy::type_complexity)]
    pub fn pixel_aovs(
        &self,
        x: u32,
        y: u32,
        aovs: Aovs,
    ) -> Result<([f32; 3], [f32; MAX_AOV_CHANNELS], u64), Cancelled> {
        let mut state = PixelState::default();
        let mut sums = AovSums::default();
        let rays = self.samples_with::<true>(x, y, u32::MAX, &mut state, Some(&mut sums))?;
        Ok((state.finish(), sums.finish(aovs), rays))
    }

    /// [`Integrator::pixel_samples`], adding every sample's passes to `aov`
    /// when `AOV` (a constant, so that a render without passes compiles to
    /// the loop it always was).
    fn samples_with<const AOV: bool>(
        &self,
        x: u32,
        y: u32,
        end: u32,
        state: &mut PixelState,
        mut aov: Option<&mut AovSums>,
    ) -> Result<u64, Cancelled> {
        let r = &self.desc.render;
        let mut ctx = PixelContext {
            sampler: PixelSampler {
                seed: pixel_seed(r.seed, self.camera_hash, x, y),
                kind: self.sampler,
            },
            sample: 0,
            rays: 0,
            stopped: false,
            pending: Vec::new(),
            links: Vec::new(),
        };
        let end = end.min(self.samples_per_pixel());
        let mut run = state.running();
        match r.adaptive {
            None => {
                let n = r.supersample;
                while run.count < end {
                    let s = run.count;
                    if ctx.stopped {
                        return Err(Cancelled);
                    }
                    let (sx, sy) = if r.jitter {
                        let [jx, jy] = ctx.sampler.get2(STREAM_PIXEL, s);
                        (
                            ((s % n) as f32 + jx) / n as f32,
                            ((s / n) as f32 + jy) / n as f32,
                        )
                    } else {
                        (
                            ((s % n) as f32 + 0.5) / n as f32,
                            ((s / n) as f32 + 0.5) / n as f32,
                        )
                    };
                    run.add_grid(self.camera_sample::<AOV>(
                        &mut ctx,
                        x,
                        y,
                        s,
                        sx,
                        sy,
                        aov.as_deref_mut(),
                    ));
                }
            }
            Some(a) => {
                // Sample until the standard error of the mean (largest over the
                // channels) is under the threshold, between min and max samples.
                // A pixel that stopped in an earlier range stops again at once:
                // the rule sees the same sums.
                while run.count < end && !run.converged(&a) {
                    let n = run.count;
                    if ctx.stopped {
                        return Err(Cancelled);
                    }
                    let [sx, sy] = ctx.sampler.get2(STREAM_PIXEL, n);
                    run.add_adaptive(self.camera_sample::<AOV>(
                        &mut ctx,
                        x,
                        y,
                        n,
                        sx,
                        sy,
                        aov.as_deref_mut(),
                    ));
                }
            }
        }
        // The last sample may have been cut short too.
        if ctx.stopped {
            return Err(Cancelled);
        }
        *state = run.state();
        Ok(ctx.rays)
    }

    /// Whether the pixel is to stop: set for good once the flag is seen.
    #[inline(always)]
    fn stopping(&self, ctx: &mut PixelContext) -> bool {
        if ctx.rays.is_multiple_of(CANCEL_EVERY) && self.cancel.load(Ordering::Relaxed) {
            ctx.stopped = true;
        }
        ctx.stopped
    }

    /// Every closest-hit ray goes through here: counted, observed, traced
    /// (or a miss, once the pixel is cancelled).
    #[inline(always)]
    pub(super) fn trace(
        &self,
        ctx: &mut PixelContext,
        origin: Vec3,
        dir: Vec3,
        t_max: f32,
    ) -> Option<Hit> {
        ctx.rays += 1;
        if self.stopping(ctx) {
            return None;
        }
        self.observer.closest(origin, dir, t_max);
        self.view.intersect(origin, dir, t_max)
    }

    /// Every shadow ray goes through here: counted, observed, traced (or
    /// blocked, once the pixel is cancelled).
    #[inline(always)]
    pub(super) fn trace_shadow(
        &self,
        ctx: &mut PixelContext,
        origin: Vec3,
        dir: Vec3,
        t_max: f32,
    ) -> f32 {
        ctx.rays += 1;
        if self.stopping(ctx) {
            return 0.0;
        }
        self.observer.shadow(origin, dir, t_max);
        self.view.transmittance(origin, dir, t_max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::integrator::RenderOptions;
    use crate::testing::scene;
    use std::sync::atomic::AtomicU64;
    use std::sync::{mpsc, Arc};
    use std::time::{Duration, Instant};

    /// Counts the rays it is shown: how a test knows a pixel has started.
    #[derive(Default)]
    struct Count(AtomicU64);

    impl RayObserver for Count {
        fn closest(&self, _: Vec3, _: Vec3, _: f32) {
            self.0.fetch_add(1, Ordering::Relaxed);
        }
        fn shadow(&self, _: Vec3, _: Vec3, _: f32) {
            self.0.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Renders the one pixel of `xml` on its own thread, sets the flag once
    /// the pixel has traced its first rays, and returns how long the pixel
    /// took to stop after that (panicking if it did not within a minute:
    /// uncancelled, each of these pixels takes hours).
    fn cancelled_mid_pixel(xml: &str) -> Duration {
        let scene = Arc::new(scene(xml));
        let flag = Arc::new(AtomicBool::new(false));
        let seen = Arc::new(Count::default());
        let (tx, rx) = mpsc::channel();
        {
            let (scene, flag, seen) = (scene.clone(), flag.clone(), seen.clone());
            std::thread::spawn(move || {
                let it = Integrator::observed(&scene, 0, RenderOptions::default(), &*seen)
                    .cancelled_by(&flag);
                let _ = tx.send(it.pixel(0, 0));
            });
        }
        // Wait for the state "inside the pixel", not for a time.
        let started = Instant::now();
        while seen.0.load(Ordering::Relaxed) < 10 * CANCEL_EVERY {
            assert!(
                started.elapsed() < Duration::from_secs(60),
                "the pixel never started"
            );
            std::thread::yield_now();
        }
        flag.store(true, Ordering::Relaxed);
        let t0 = Instant::now();
        let r = rx
            .recv_timeout(Duration::from_secs(60))
            .expect("the pixel went on after it was cancelled");
        assert_eq!(r, Err(Cancelled));
        t0.elapsed()
    }

    /// Path tracing at the largest supersample and max-bounces: 2³² camera
    /// samples in one pixel, hours of work, stopped within a second.
    #[test]
    fn a_path_traced_pixel_of_hours_stops_soon_after_its_flag_is_set() {
        let took = cancelled_mid_pixel(
            r#"<scene version="1">
  <sphere id="s" center="0 0 0" radius="1"> <surface diffuse="0.8 0.8 0.8"/> </sphere>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1"/>
  <camera id="c" position="0 0 5" lookat="0 0 0" up="0 1 0" fov="10">
    <render width="1" height="1" supersample="65535" integrator="path"
            max-bounces="10000" output="o.png"/>
  </camera>
</scene>"#,
        );
        assert!(took < Duration::from_secs(5), "took {took:?}");
    }

    /// One Whitted camera sample that alone is hours of work: a gather of
    /// 65536 directions, each a chain 10000 levels deep, in a closed
    /// diffuse sphere. The flag is read inside the sample, not only
    /// between samples.
    #[test]
    fn a_single_camera_sample_of_hours_stops_soon_after_its_flag_is_set() {
        let took = cancelled_mid_pixel(
            r#"<scene version="1">
  <sphere id="m" center="0 0 0" radius="5"><surface diffuse="0.5 0.5 0.5"/></sphere>
  <light position="0 4 0"/>
  <camera id="c" position="0 0 0" direction="0 0 -1" fov="30">
    <render width="1" height="1" max-depth="0" diffuse-samples="65536"
            ao-distance="1000" diffuse-depth="10000" output="o.png"/>
  </camera>
</scene>"#,
        );
        assert!(took < Duration::from_secs(5), "took {took:?}");
    }

    /// The flag read every CANCEL_EVERY rays changes nothing while it is
    /// clear: the same pixel, the same ray count, with or without it.
    #[test]
    fn an_uncancelled_pixel_is_the_pixel_without_a_flag() {
        let s = scene(
            r#"<scene version="1">
  <sphere id="s" center="0 0 0" radius="1"> <surface diffuse="0.8 0.3 0.2" reflectivity="0.3"/> </sphere>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1"/>
  <camera id="c" position="0 0 5" lookat="0 0 0" up="0 1 0" fov="30">
    <render width="4" height="4" supersample="20" output="o.png"/>
  </camera>
</scene>"#,
        );
        let flag = AtomicBool::new(false);
        let plain = Integrator::observed(&s, 0, RenderOptions::default(), &());
        let flagged =
            Integrator::observed(&s, 0, RenderOptions::default(), &()).cancelled_by(&flag);
        for (x, y) in [(0, 0), (1, 2), (2, 1), (3, 3)] {
            let p = plain.pixel(x, y).unwrap();
            assert!(p.1 > CANCEL_EVERY, "too few rays to read the flag");
            assert_eq!(flagged.pixel(x, y), Ok(p));
        }
        flag.store(true, Ordering::Relaxed);
        assert_eq!(flagged.pixel(0, 0), Err(Cancelled));
    }
}
