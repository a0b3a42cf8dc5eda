//! What the two speed/accuracy examples (`speed_accuracy.rs`,
//! `ground_truth.rs`) share: the error measure, the time a curve needs to
//! reach an error, the timed whole-frame render, and the log–log plot of
//! error against time.

use plotters::prelude::*;
use std::time::Instant;
use trevi_core::integrator::RenderOptions;
use trevi_core::sampling::SamplerKind;
use trevi_core::scene::SceneDesc;
use trevi_core::tile::render_tile_with;
use trevi_core::{Rect, Scene};

/// A whole frame of the scene's first camera, with the best of its render
/// times and the rays it traced.
pub struct Render {
    pub pixels: Vec<[f32; 3]>,
    pub seconds: f64,
    pub rays: u64,
}

/// Renders the first camera's whole frame `best_of` times at most (fewer once
/// a run takes over 2 s: the machine is shared) and keeps the best time.
pub fn render(desc: &SceneDesc, sampler: SamplerKind, best_of: u32) -> Render {
    let scene = Scene::build(desc.clone());
    let r = &scene.desc.cameras[0].render;
    let rect = Rect::new(0, 0, r.width, r.height);
    let mut best = f64::INFINITY;
    let mut runs = 0;
    loop {
        let t0 = Instant::now();
        let t = render_tile_with(&scene, 0, rect, RenderOptions { sampler });
        best = best.min(t0.elapsed().as_secs_f64());
        runs += 1;
        if runs >= best_of || best > 2.0 {
            return Render {
                seconds: best,
                pixels: t.pixels,
                rays: t.rays,
            };
        }
    }
}

/// Root-mean-square difference of two images, over every channel.
pub fn rmse(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let sum: f64 = a
        .iter()
        .zip(b)
        .flat_map(|(p, q)| (0..3).map(move |c| (p[c] as f64 - q[c] as f64).powi(2)))
        .sum();
    (sum / (3 * a.len()) as f64).sqrt()
}

/// The time at which a log–log piecewise-linear curve of (time, error),
/// sorted by time, crosses the error `e`; `None` when no segment of the
/// curve crosses it (the caller decides what a curve that starts below `e`
/// means).
pub fn time_at_rmse(curve: &[(f64, f64)], e: f64) -> Option<f64> {
    for w in curve.windows(2) {
        let ((t0, e0), (t1, e1)) = (w[0], w[1]);
        if (e0 >= e && e1 <= e) && e0 != e1 {
            let f = (e.ln() - e0.ln()) / (e1.ln() - e0.ln());
            return Some((t0.ln() + f * (t1.ln() - t0.ln())).exp());
        }
    }
    None
}

/// One panel of [`plot`]: its title and its points (strategy, seconds,
/// RMSE); a strategy's points are joined in order of time.
pub struct Panel<'a> {
    pub title: String,
    pub points: Vec<(&'a str, f64, f64)>,
}

/// How [`plot`] draws.
pub struct Style<'a> {
    pub caption_size: u32,
    pub x_desc: &'a str,
    pub legend: SeriesLabelPosition,
    /// Axis labels rounded to 3 decimals (no trailing float noise).
    pub round_ticks: bool,
}

/// Writes `path`: the panels side by side, 700×620 pixels each, RMSE
/// against time on log–log axes, one coloured line per strategy.
pub fn plot(path: &str, panels: &[Panel], style: &Style) -> Result<(), Box<dyn std::error::Error>> {
    plotters::style::register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular())
        .map_err(|_| "font registration failed")?;
    let root = BitMapBackend::new(path, (700 * panels.len() as u32, 620)).into_drawing_area();
    root.fill(&WHITE)?;
    let areas = root.split_evenly((1, panels.len()));
    let tick = |v: &f64| format!("{}", (v * 1e3).round() / 1e3);
    for (area, panel) in areas.iter().zip(panels) {
        let mut strategies: Vec<&str> = Vec::new();
        for &(s, _, _) in &panel.points {
            if !strategies.contains(&s) {
                strategies.push(s);
            }
        }
        let (t0, t1) = panel
            .points
            .iter()
            .fold((f64::MAX, 0f64), |(a, b), p| (a.min(p.1), b.max(p.1)));
        let (e0, e1) = panel
            .points
            .iter()
            .fold((f64::MAX, 0f64), |(a, b), p| (a.min(p.2), b.max(p.2)));
        let mut chart = ChartBuilder::on(area)
            .caption(&panel.title, ("sans-serif", style.caption_size))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d(
                (t0 / 1.5..t1 * 1.5).log_scale(),
                (e0 / 1.5..e1 * 1.5).log_scale(),
            )?;
        let mut mesh = chart.configure_mesh();
        mesh.x_desc(style.x_desc)
            .y_desc("RMSE (linear RGB)")
            .label_style(("sans-serif", 14));
        if style.round_ticks {
            mesh.x_label_formatter(&tick).y_label_formatter(&tick);
        }
        mesh.draw()?;
        for (i, s) in strategies.iter().enumerate() {
            let color = Palette99::pick(i).to_rgba();
            let mut pts: Vec<(f64, f64)> = panel
                .points
                .iter()
                .filter(|p| p.0 == *s)
                .map(|p| (p.1, p.2))
                .collect();
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            chart
                .draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))?
                .label(*s)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
                });
            chart.draw_series(pts.iter().map(|&p| Circle::new(p, 3, color.filled())))?;
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 13))
            .position(style.legend.clone())
            .draw()?;
    }
    root.present()?;
    Ok(())
}
