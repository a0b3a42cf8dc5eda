//! Denoises a multi-layer EXR (R G B, albedo.*, N.*) band by band into an
//! RGB EXR: the tool bench/peers.py times for "Trevi denoised".
//! `denoise_exr IN.exr OUT.exr [--threads N]`
//! (holds the output frame in memory: a benchmark tool, not the farm's path).
use exr::prelude::*;
use trevi_denoise::{denoise_frame, BandPlan, Denoiser, ExrSource, Source};
use trevi_denoise::{DEFAULT_BAND_ROWS, DEFAULT_OVERLAP};

fn main() -> std::result::Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let (input, output) = match (args.get(1), args.get(2)) {
        (Some(i), Some(o)) => (i, o),
        _ => return Err("usage: denoise_exr IN.exr OUT.exr [--threads N]".into()),
    };
    let threads = match args.get(3).map(String::as_str) {
        Some("--threads") => args.get(4).ok_or("--threads takes a number")?.parse()?,
        _ => 0,
    };
    let mut src = ExrSource::open(std::path::Path::new(input))?;
    let (w, h) = (src.width(), src.height());
    let denoiser = Denoiser::new(threads)?;
    let plan = BandPlan::new(h, DEFAULT_BAND_ROWS, DEFAULT_OVERLAP)?;
    let mut pixels = Vec::with_capacity(w as usize * h as usize);
    denoise_frame(&denoiser, &mut src, plan, &mut |_, rows| {
        pixels.extend_from_slice(rows);
        Ok(())
    })?;
    let img = Image::from_channels(
        (w as usize, h as usize),
        SpecificChannels::rgb(|p: Vec2<usize>| {
            let [r, g, b] = pixels[p.y() * w as usize + p.x()];
            (r, g, b)
        }),
    );
    img.write().to_file(output)?;
    Ok(())
}
