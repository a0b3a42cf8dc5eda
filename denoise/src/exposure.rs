//! One exposure for the whole frame.
//!
//! Open Image Denoise's HDR filter scales the colour by an exposure before
//! its network; left to itself it computes that exposure from the image it
//! is given, so two bands of one frame would each get their own and their
//! rows would not match at the cut. The exposure is computed here once, from
//! the whole frame streamed 16 rows at a time, by the library's own rule
//! (the key 0.18 over the geometric mean of the luminance of 16×16-pixel
//! bins, bins darker than 1e-8 left out), and every band is given it.

/// Pixels per bin side.
const BIN: u32 = 16;
/// Middle grey.
const KEY: f64 = 0.18;
/// Bins darker than this are left out.
const EPS: f64 = 1e-8;

/// Rec. 709 luminance, the weights the library uses.
fn luminance(c: [f32; 3]) -> f64 {
    0.212671 * c[0] as f64 + 0.715160 * c[1] as f64 + 0.072169 * c[2] as f64
}

/// Accumulates bins from blocks of up to 16 rows, top to bottom.
pub struct Exposure {
    width: u32,
    log_sum: f64,
    bins: u64,
}

impl Exposure {
    /// For a frame `width` pixels wide.
    pub fn new(width: u32) -> Exposure {
        Exposure {
            width,
            log_sum: 0.0,
            bins: 0,
        }
    }

    /// Adds one row of bins: `rows` (1 to 16) full rows of colour, the
    /// frame's rows from a multiple of 16 (the last block may be shorter).
    pub fn add_block(&mut self, rows: u32, color: &[[f32; 3]]) {
        let w = self.width as usize;
        debug_assert_eq!(color.len(), w * rows as usize);
        for x0 in (0..self.width).step_by(BIN as usize) {
            let x1 = (x0 + BIN).min(self.width);
            let mut sum = 0.0;
            for y in 0..rows as usize {
                let row = &color[y * w..(y + 1) * w];
                sum += row[x0 as usize..x1 as usize]
                    .iter()
                    .map(|&c| luminance(c))
                    .sum::<f64>();
            }
            let mean = sum / ((x1 - x0) as f64 * rows as f64);
            if mean > EPS {
                self.log_sum += libm::log2(mean);
                self.bins += 1;
            }
        }
    }

    /// The scale for the filter's input: 1 for a black frame.
    pub fn scale(&self) -> f32 {
        if self.bins == 0 {
            return 1.0;
        }
        (KEY / libm::exp2(self.log_sum / self.bins as f64)) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_uniform_frame_is_scaled_to_middle_grey() {
        let mut e = Exposure::new(40);
        e.add_block(16, &vec![[0.5; 3]; 40 * 16]);
        e.add_block(5, &vec![[0.5; 3]; 40 * 5]);
        // Luminance weights sum to 1, so every bin's mean is 0.5.
        let expected = 0.18 / 0.5;
        assert!((e.scale() as f64 - expected).abs() < 1e-6, "{}", e.scale());
    }

    #[test]
    fn the_geometric_mean_is_over_bins_and_black_bins_are_left_out() {
        // Two bins side by side: luminance 2 and 8 -> geometric mean 4;
        // a third, black, bin is left out.
        let mut row = vec![[2.0f32; 3]; 16];
        row.extend(vec![[8.0f32; 3]; 16]);
        row.extend(vec![[0.0f32; 3]; 16]);
        let block: Vec<[f32; 3]> = row.iter().cycle().take(48 * 16).copied().collect();
        let mut e = Exposure::new(48);
        e.add_block(16, &block);
        assert!((e.scale() as f64 - 0.18 / 4.0).abs() < 1e-6);
        assert_eq!(Exposure::new(8).scale(), 1.0);
    }
}
