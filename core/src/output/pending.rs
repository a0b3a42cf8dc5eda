//! The rows of a frame that have received some pixels but have not yet been
//! handed to the encoder, with a record of which pixels each one has.

use std::collections::BTreeMap;

/// One buffered row: its samples in the encoder's layout and a bit per pixel
/// saying whether it has been written.
struct Row<T> {
    samples: Vec<T>,
    written: Vec<u64>,
    count: u32,
}

/// Buffered rows of a `width`-pixel-wide frame, `samples_per_row` values of
/// type `T` each. A row is allocated when a tile first touches it and freed by
/// [`PendingRows::take`].
pub(super) struct PendingRows<T> {
    width: u32,
    samples_per_row: usize,
    rows: BTreeMap<u32, Row<T>>,
}

/// Calls `f(word index, mask)` for the 64-bit words covering bits `x0..x1`.
fn for_each_word(x0: u32, x1: u32, mut f: impl FnMut(usize, u64)) {
    let mut x = x0;
    while x < x1 {
        let word = x / 64;
        let lo = x % 64;
        let hi = (x1 - word * 64).min(64);
        let mask = if hi - lo == 64 {
            u64::MAX
        } else {
            ((1u64 << (hi - lo)) - 1) << lo
        };
        f(word as usize, mask);
        x = word * 64 + hi;
    }
}

impl<T: Copy + Default> PendingRows<T> {
    pub(super) fn new(width: u32, samples_per_row: usize) -> Self {
        PendingRows {
            width,
            samples_per_row,
            rows: BTreeMap::new(),
        }
    }

    /// Number of rows currently buffered.
    pub(super) fn len(&self) -> usize {
        self.rows.len()
    }

    /// Whether any of pixels `x0..x1` of row `y` has been written (rows not
    /// buffered have none).
    pub(super) fn any_written(&self, y: u32, x0: u32, x1: u32) -> bool {
        let Some(row) = self.rows.get(&y) else {
            return false;
        };
        let mut any = false;
        for_each_word(x0, x1, |w, mask| any |= row.written[w] & mask != 0);
        any
    }

    /// Marks pixels `x0..x1` of row `y` as written (allocating the row if
    /// needed) and returns the row's samples for the caller to fill. The caller
    /// must have checked [`PendingRows::any_written`] first.
    pub(super) fn claim(&mut self, y: u32, x0: u32, x1: u32) -> &mut [T] {
        let (width, samples_per_row) = (self.width, self.samples_per_row);
        let row = self.rows.entry(y).or_insert_with(|| Row {
            samples: vec![T::default(); samples_per_row],
            written: vec![0; (width as usize).div_ceil(64)],
            count: 0,
        });
        for_each_word(x0, x1, |w, mask| {
            debug_assert_eq!(row.written[w] & mask, 0, "claim of written pixels");
            row.written[w] |= mask;
        });
        row.count += x1 - x0;
        &mut row.samples
    }

    /// Whether row `y` is buffered and has all its pixels.
    pub(super) fn is_complete(&self, y: u32) -> bool {
        self.rows.get(&y).is_some_and(|r| r.count == self.width)
    }

    /// Number of buffered rows that have all their pixels.
    pub(super) fn complete_count(&self) -> usize {
        self.rows.values().filter(|r| r.count == self.width).count()
    }

    /// Removes row `y` and returns its samples.
    pub(super) fn take(&mut self, y: u32) -> Option<Vec<T>> {
        self.rows.remove(&y).map(|r| r.samples)
    }

    /// Removes and returns rows `y0..min(y0 + n, height)` (a PNG segment or
    /// an EXR block starting at `y0`) once all of them are complete; `None`
    /// while one is missing a pixel, or at the end of the image.
    pub(super) fn take_block(&mut self, y0: u32, n: u32, height: u32) -> Option<Vec<Vec<T>>> {
        let y1 = y0.saturating_add(n).min(height);
        if y0 >= y1 || !(y0..y1).all(|y| self.is_complete(y)) {
            return None;
        }
        Some((y0..y1).map(|y| self.take(y).unwrap_or_default()).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn word_masks_cover_exactly_the_range() {
        for &(x0, x1) in &[
            (0, 1),
            (0, 64),
            (0, 65),
            (3, 61),
            (63, 64),
            (63, 130),
            (64, 128),
            (5, 200),
        ] {
            let mut bits = [0u64; 4];
            for_each_word(x0, x1, |w, m| {
                assert_eq!(bits[w] & m, 0);
                bits[w] |= m;
            });
            for x in 0..256u32 {
                let set = bits[(x / 64) as usize] >> (x % 64) & 1 == 1;
                assert_eq!(set, (x0..x1).contains(&x), "{x0}..{x1} bit {x}");
            }
        }
    }

    #[test]
    fn rows_complete_when_every_pixel_is_claimed() {
        let mut rows = PendingRows::<u8>::new(130, 3 * 130);
        assert!(!rows.any_written(4, 0, 130));
        rows.claim(4, 0, 64)[0] = 7;
        assert!(rows.any_written(4, 63, 65));
        assert!(!rows.any_written(4, 64, 130));
        assert!(!rows.is_complete(4));
        rows.claim(4, 100, 130);
        rows.claim(4, 64, 100);
        assert!(rows.is_complete(4));
        assert_eq!((rows.len(), rows.complete_count()), (1, 1));
        let samples = rows.take(4).unwrap();
        assert_eq!((samples.len(), samples[0]), (390, 7));
        assert_eq!(rows.len(), 0);
    }

    #[test]
    fn a_block_is_taken_only_when_all_its_rows_are_complete() {
        let mut rows = PendingRows::<u8>::new(4, 4);
        for y in [0, 1, 2] {
            rows.claim(y, 0, 4)[0] = y as u8 + 10;
        }
        rows.claim(3, 0, 3);
        // Rows 0..4 of a 6-row image: row 3 lacks a pixel.
        assert!(rows.take_block(0, 4, 6).is_none());
        assert_eq!(rows.len(), 4, "nothing taken from an incomplete block");
        rows.claim(3, 3, 4);
        let block = rows.take_block(0, 4, 6).expect("complete");
        assert_eq!(
            block.iter().map(|r| r[0]).collect::<Vec<_>>(),
            [10, 11, 12, 0]
        );
        assert_eq!(rows.len(), 0);
        // The last block is cut at the image's height; past it, nothing.
        for y in [4, 5] {
            rows.claim(y, 0, 4);
        }
        assert_eq!(rows.take_block(4, 4, 6).map(|b| b.len()), Some(2));
        assert!(rows.take_block(6, 4, 6).is_none());
    }
}
