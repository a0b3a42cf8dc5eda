//! A job's band window: its tiles numbered in band order, which of them are
//! pending, leased or done, and how far ahead of the first band that is not
//! complete tiles may be leased. Only the tiles between the first one not
//! done and the first one never leased are stored; the window keeps that
//! span to a few bands, so neither the stitcher's rows nor this bookkeeping
//! grows with the image height.
//!
//! The window is a budget in bytes (`Limits::window_bytes` less
//! [`encoder_bytes`]), not a number of bands: every band from the first
//! one not complete to the last one with a tile leased is *held*, and costs
//! what the writer may hold of it. A band any of whose tiles went out as
//! floats costs [`band_bytes`] (12 bytes a pixel); a band leased only as
//! encoded PNG segments costs [`segment_band_bytes`] (at most about 4.5
//! bytes a pixel: what the segment encoder can emit at worst). A tile (or a
//! span) is leased only while the held bands, its own counted at its cost,
//! fit the budget, and the first band not complete is always allowed, so a
//! job whose one band fits always makes progress. Segment leases therefore
//! run up to 12 / 4.5 ≈ 2.7 times as many bands ahead as float leases, and
//! what one job holds stays within the one budget whatever the mix.
//!
//! [`band_bytes`]: band_bytes
//! [`segment_band_bytes`]: segment_band_bytes

use super::{JobSpec, LeaseId};
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use trevi_core::output::SEGMENT_ROWS;
use trevi_core::tile::Rect;

/// What the bookkeeping of one tile in a job's band window may cost, in
/// bytes: its state in the window, a lease, a re-queue entry (counted
/// generously; see [`band_bytes`]).
pub const TILE_BOOKKEEPING_BYTES: u64 = 96;

/// What one band of `spec`'s tiles costs the coordinator while it is in the
/// window and was leased (at least partly) as floats, in bytes: its rows in
/// the writer (12 bytes a pixel, the most any format holds) and the
/// bookkeeping of its tiles. A frame whose one band does not fit the window
/// is refused at submission.
pub fn band_bytes(spec: &JobSpec) -> u64 {
    let tile = spec.tile_size.max(1) as u64;
    let rows = tile.min(spec.height.max(1) as u64);
    let cols = (spec.width as u64).div_ceil(tile).max(1);
    // 12 bytes of beauty a pixel, and 4 for each render pass channel.
    let pixel = 12 + 4 * spec.aovs.channels() as u64;
    spec.width as u64 * rows * pixel + cols * TILE_BOOKKEEPING_BYTES
}

/// Bytes of one encoded segment beyond its filtered bytes' share, at most:
/// the block header (52 bytes), the end-of-block code, the sync flush (5
/// bytes), and the segment's own bookkeeping while it waits, rounded up.
pub const SEGMENT_FRAMING_BYTES: u64 = 128;

/// The most bytes the encoded segments of `rows` full rows of a
/// `width`-pixel frame can take (`trevi_core::output::encode_segment`):
/// every filtered byte (`1 + 3 × width` a row) coded in at most 12 bits
/// (the longest code of the encoder's fixed table; runs of zeros cost
/// less), so 1.5 bytes each, plus [`SEGMENT_FRAMING_BYTES`] for each of the
/// segments the rows touch. About 4.5 bytes a pixel; a cheap scene's
/// segments take about 0.55.
pub fn encoded_rows_bound(width: u32, rows: u32) -> u64 {
    let filtered = rows as u64 * (1 + 3 * width as u64);
    let segments = (rows as u64).div_ceil(SEGMENT_ROWS as u64) + 1;
    filtered.div_ceil(2) * 3 + segments * SEGMENT_FRAMING_BYTES
}

/// What one band of `spec`'s tiles costs the coordinator while it is in the
/// window, when every lease of it asked for encoded PNG segments: the
/// segments the writer may hold until those before them arrive
/// ([`encoded_rows_bound`]) and the bookkeeping of its tiles. Never more
/// than [`band_bytes`].
pub fn segment_band_bytes(spec: &JobSpec) -> u64 {
    let tile = spec.tile_size.max(1);
    let rows = tile.min(spec.height.max(1));
    let cols = (spec.width as u64).div_ceil(tile as u64).max(1);
    let encoded = encoded_rows_bound(spec.width, rows) + cols * TILE_BOOKKEEPING_BYTES;
    encoded.min(band_bytes(spec))
}

/// Rows a job's encoder holds beyond those in the band window: EXR
/// compresses one 16-row block while the next one waits (PNG needs two).
pub const ENCODER_ROWS: u64 = 32;

/// What a job's encoder holds whatever the window: [`ENCODER_ROWS`] rows at
/// 12 bytes a pixel. Taken from the window before it is divided into bands.
pub fn encoder_bytes(spec: &JobSpec) -> u64 {
    spec.width as u64 * ENCODER_ROWS * 12
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum TileState {
    Pending,
    Leased(LeaseId),
    Done,
}

/// A job's tiles and the span of them in flight.
pub(super) struct BandWindow {
    tile: u32,
    width: u32,
    height: u32,
    cols: u32,
    tiles_total: u32,
    /// The budget the held bands share: `window_bytes` less the encoder's.
    room: u64,
    /// What a held band costs leased as floats, and only as segments.
    float_band: u64,
    segment_band: u64,
    /// Every tile before this one is done.
    first_undone: u32,
    /// Every tile from this one on is pending and was never leased.
    next_fresh: u32,
    /// States of tiles `first_undone..next_fresh`, in order: a tile's
    /// state is at `idx - first_undone` (a deque, not a map: every tile of
    /// a span of hundreds is looked up, leased and done in turn under the
    /// farm's lock, and a deque needs no search; docs/benchmarks.md,
    /// "Stage 6").
    active: VecDeque<TileState>,
    /// How many of `active` are leased (the queue's depth without a scan
    /// of the farm's leases).
    leased: u32,
    /// Pending tiles before `next_fresh` (re-queued), smallest first.
    requeued: BTreeSet<u32>,
    /// The held bands (from the first one not complete to the last one
    /// with a tile leased) and what each costs.
    held: BTreeMap<u32, u64>,
    /// The sum of `held`'s costs.
    held_bytes: u64,
}

impl BandWindow {
    /// The window of a job in `spec.tile_size` tiles (≥ 1) with a budget of
    /// `window_bytes`.
    pub(super) fn new(spec: &JobSpec, window_bytes: u64) -> BandWindow {
        let tile = spec.tile_size.max(1);
        let cols = spec.width.div_ceil(tile).max(1);
        let rows = spec.height.div_ceil(tile);
        BandWindow {
            tile,
            width: spec.width,
            height: spec.height,
            cols,
            tiles_total: u32::try_from(cols as u64 * rows as u64).unwrap_or(u32::MAX),
            room: window_bytes.saturating_sub(encoder_bytes(spec)),
            float_band: band_bytes(spec),
            segment_band: segment_band_bytes(spec),
            first_undone: 0,
            next_fresh: 0,
            active: VecDeque::new(),
            leased: 0,
            requeued: BTreeSet::new(),
            held: BTreeMap::new(),
            held_bytes: 0,
        }
    }

    pub(super) fn tiles_total(&self) -> u32 {
        self.tiles_total
    }

    /// Tiles in a band (every band has as many).
    pub(super) fn cols(&self) -> u32 {
        self.cols
    }

    /// The frame's width and height.
    pub(super) fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    pub(super) fn rect(&self, idx: u32) -> Rect {
        let t = self.tile;
        let (x, y) = ((idx % self.cols) * t, (idx / self.cols) * t);
        Rect::new(x, y, t.min(self.width - x), t.min(self.height - y))
    }

    pub(super) fn tile_index(&self, rect: Rect) -> Option<u32> {
        let t = self.tile;
        if rect.x % t != 0 || rect.y % t != 0 || rect.x >= self.width {
            return None;
        }
        let idx = (rect.y / t) as u64 * self.cols as u64 + (rect.x / t) as u64;
        let idx = u32::try_from(idx).ok().filter(|&i| i < self.tiles_total)?;
        (self.rect(idx) == rect).then_some(idx)
    }

    pub(super) fn tile_state(&self, idx: u32) -> TileState {
        if idx < self.first_undone {
            TileState::Done
        } else if idx >= self.next_fresh {
            TileState::Pending
        } else {
            // Retired windows keep no states: their tiles count as done.
            let at = (idx - self.first_undone) as usize;
            self.active.get(at).copied().unwrap_or(TileState::Done)
        }
    }

    /// Whether tile `idx` was never handed out.
    pub(super) fn is_fresh(&self, idx: u32) -> bool {
        idx >= self.next_fresh
    }

    /// What a band costs held, leased as segments or as floats.
    fn band_cost(&self, segments: bool) -> u64 {
        if segments {
            self.segment_band
        } else {
            self.float_band
        }
    }

    /// Whether band `band` may be leased (as segments or as floats): it is
    /// the first band not complete, or the held bands with it, at its cost
    /// once leased so, fit the budget.
    pub(super) fn band_fits(&self, band: u32, segments: bool) -> bool {
        if band <= self.first_undone / self.cols {
            return true;
        }
        let now = self.held.get(&band).copied().unwrap_or(0);
        let after = now.max(self.band_cost(segments));
        self.held_bytes - now + after <= self.room
    }

    /// The pending tile to hand out next, if the window allows it to go
    /// out as floats (`segments` false) or in a segment lease.
    pub(super) fn next_tile(&self, segments: bool) -> Option<u32> {
        let idx = match self.requeued.first() {
            Some(&i) => i,
            None if self.next_fresh < self.tiles_total => self.next_fresh,
            None => return None,
        };
        self.band_fits(idx / self.cols, segments).then_some(idx)
    }

    /// Whether every tile of band `band` is pending (fresh or re-queued).
    fn band_pending(&self, band: u32) -> bool {
        let start = band as u64 * self.cols as u64;
        if start >= self.tiles_total as u64 {
            return false;
        }
        let start = start as u32;
        let end = start + self.cols;
        start >= self.first_undone
            && (start..end.min(self.next_fresh)).all(|i| self.tile_state(i) == TileState::Pending)
    }

    /// How many whole bands, from band `band` on, may go out in one lease
    /// (as segments or as floats), at most `most`: consecutive bands every
    /// tile of which is pending, while the held bands with them fit the
    /// budget (the first band not complete always fits).
    pub(super) fn whole_bands(&self, band: u32, most: u32, segments: bool) -> u32 {
        let cost = self.band_cost(segments);
        let first = self.first_undone / self.cols;
        let mut total = self.held_bytes;
        let mut n = 0;
        while n < most {
            let b = band + n;
            if !self.band_pending(b) {
                break;
            }
            let now = self.held.get(&b).copied().unwrap_or(0);
            total = total - now + now.max(cost);
            if b > first && total > self.room {
                break;
            }
            n += 1;
        }
        n
    }

    /// Hands tile `idx` out under `lease`, as part of a segment lease or
    /// not. Tiles go out in order: a re-queued one, or the next fresh one.
    pub(super) fn set_leased(&mut self, idx: u32, lease: LeaseId, segments: bool) {
        if idx == self.next_fresh {
            self.next_fresh += 1;
            self.active.push_back(TileState::Leased(lease));
            self.leased += 1;
        } else {
            debug_assert!(self.requeued.contains(&idx), "tile {idx} is not pending");
            self.requeued.remove(&idx);
            self.set_state(idx, TileState::Leased(lease));
        }
        let cost = self.band_cost(segments);
        let held = self.held.entry(idx / self.cols).or_insert(0);
        if cost > *held {
            self.held_bytes += cost - *held;
            *held = cost;
        }
    }

    /// What the held bands cost, in bytes (never more than the budget, or
    /// one band's cost when the first band alone is larger).
    #[cfg(test)]
    pub(super) fn held_bytes(&self) -> u64 {
        self.held_bytes
    }

    /// The budget the held bands share.
    #[cfg(test)]
    pub(super) fn room(&self) -> u64 {
        self.room
    }

    /// Sets the state of tile `idx`, one of `first_undone..next_fresh`.
    fn set_state(&mut self, idx: u32, state: TileState) {
        let at = idx.checked_sub(self.first_undone).map(|i| i as usize);
        match at.and_then(|i| self.active.get_mut(i)) {
            Some(s) => {
                let was = matches!(*s, TileState::Leased(_));
                let is = matches!(state, TileState::Leased(_));
                self.leased = self.leased + u32::from(is) - u32::from(was);
                *s = state;
            }
            None => debug_assert!(false, "tile {idx} is not in flight"),
        }
    }

    /// Puts a handed-out tile back, ahead of the fresh ones.
    pub(super) fn requeue(&mut self, idx: u32) {
        debug_assert!((self.first_undone..self.next_fresh).contains(&idx));
        self.set_state(idx, TileState::Pending);
        self.requeued.insert(idx);
    }

    /// Marks a tile done and moves `first_undone` past the done prefix;
    /// bands before it are no longer held.
    pub(super) fn set_done(&mut self, idx: u32) {
        if !(self.first_undone..self.next_fresh).contains(&idx) {
            // Done already, or never handed out: the callers take neither.
            debug_assert!(idx < self.first_undone, "tile {idx} was never leased");
            return;
        }
        self.requeued.remove(&idx);
        self.set_state(idx, TileState::Done);
        while self.active.front() == Some(&TileState::Done) {
            self.active.pop_front();
            self.first_undone += 1;
        }
        let first = self.first_undone / self.cols;
        while let Some(entry) = self.held.first_entry() {
            if *entry.key() >= first {
                break;
            }
            self.held_bytes -= entry.remove();
        }
    }

    /// Restores the window of a job of an earlier run whose tiles `done`
    /// (sorted, unique, in the frame) are done: the done prefix needs no
    /// entries, the span after it up to the last done tile is pending or
    /// done (a window's worth, as when the tiles were leased), and its
    /// bands are held at the float cost (what a replay may hold at most).
    pub(super) fn restore(&mut self, done: &[u32]) {
        let Some(&last) = done.last() else {
            return;
        };
        let prefix = done
            .iter()
            .enumerate()
            .take_while(|&(i, &t)| i as u32 == t)
            .count() as u32;
        self.first_undone = prefix;
        self.next_fresh = last + 1;
        self.active = VecDeque::from(vec![TileState::Pending; (last + 1 - prefix) as usize]);
        self.leased = 0;
        self.requeued = (prefix..self.next_fresh).collect();
        for band in prefix / self.cols..=last / self.cols {
            self.held.insert(band, self.float_band);
            self.held_bytes += self.float_band;
        }
        for &i in &done[prefix as usize..] {
            self.set_done(i);
        }
    }

    /// The leases its tiles are out under, one for each leased tile.
    pub(super) fn leases(&self) -> impl Iterator<Item = LeaseId> + '_ {
        self.active.iter().filter_map(|s| match *s {
            TileState::Leased(l) => Some(l),
            _ => None,
        })
    }

    /// Drops the bookkeeping only a running job needs.
    pub(super) fn retire(&mut self) {
        self.active = VecDeque::new();
        self.leased = 0;
        self.requeued = BTreeSet::new();
        self.held = BTreeMap::new();
        self.held_bytes = 0;
    }

    /// How many tiles are leased now.
    pub(super) fn leased(&self) -> u32 {
        self.leased
    }

    /// Tiles whose state is stored (for tests of the bound).
    #[cfg(test)]
    pub(super) fn tracked(&self) -> usize {
        self.active.len()
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Lease, Scheduler};
    use super::*;
    use crate::limits::Limits;
    use std::time::{Duration, Instant};

    fn spec(w: u32, h: u32, tile: u32) -> JobSpec {
        crate::scheduler::test_spec(w, h, tile, "out.png")
    }

    #[test]
    fn tiles_are_numbered_in_band_order_and_edge_tiles_are_clipped() {
        let w = BandWindow::new(&spec(10, 7, 4), 1 << 30);
        assert_eq!(w.tiles_total(), 3 * 2);
        assert_eq!(w.rect(2), Rect::new(8, 0, 2, 4));
        assert_eq!(w.rect(5), Rect::new(8, 4, 2, 3));
        assert_eq!(w.tile_index(Rect::new(8, 4, 2, 3)), Some(5));
        assert_eq!(w.tile_index(Rect::new(8, 4, 4, 4)), None, "not clipped");
        assert_eq!(w.tile_index(Rect::new(2, 0, 4, 4)), None, "not on the grid");
    }

    #[test]
    fn a_restored_window_leases_only_what_is_not_done() {
        let mut w = BandWindow::new(&spec(8, 8, 4), 1 << 30);
        w.restore(&[0, 2]);
        assert_eq!(w.tile_state(0), TileState::Done);
        assert_eq!(w.tile_state(1), TileState::Pending);
        assert_eq!(w.tile_state(2), TileState::Done);
        assert_eq!(w.next_tile(false), Some(1), "the gap first");
        w.set_leased(1, 7, false);
        assert_eq!(w.next_tile(false), Some(3), "then the fresh tiles");
        w.set_done(1);
        assert_eq!(w.tracked(), 0, "the done prefix needs no entries");
    }

    #[test]
    fn leasing_stays_within_the_band_window() {
        let now = Instant::now();
        // One band of a 16-wide frame with 4-pixel tiles is 16*4*12 bytes.
        let mut s = Scheduler::new(
            Limits {
                lease_ttl: Duration::from_secs(5),
                window_bytes: 2 * (16 * 4 * 12 + 4 * TILE_BOOKKEEPING_BYTES)
                    + 16 * 12 * ENCODER_ROWS,
                ..Limits::default()
            },
            1,
        );
        let w = s.register_worker(now, None);
        let j = s.submit(spec(16, 64, 4), now);
        let mut leased = Vec::new();
        while let Some(l) = s.lease(w, now).unwrap() {
            leased.push(l);
        }
        assert_eq!(leased.len(), 8, "two bands of four tiles");
        // Completing the first band opens the third.
        for l in &leased[..4] {
            s.accept_tile(j, l.rect, 1, now).unwrap();
        }
        let more: Vec<Lease> = std::iter::from_fn(|| s.lease(w, now).unwrap()).collect();
        assert_eq!(more.len(), 4);
        assert!(more.iter().all(|l| l.rect.y == 8));
    }

    #[test]
    fn bookkeeping_stays_within_the_window_whatever_the_height() {
        let now = Instant::now();
        let mut s = Scheduler::new(
            Limits {
                lease_ttl: Duration::from_secs(5),
                window_bytes: 2 * (16 * 4 * 12 + 4 * TILE_BOOKKEEPING_BYTES)
                    + 16 * 12 * ENCODER_ROWS,
                ..Limits::default()
            },
            1,
        );
        let w = s.register_worker(now, None);
        let j = s.submit(spec(16, 4000, 4), now);
        let mut peak = 0;
        loop {
            let leased: Vec<Lease> = std::iter::from_fn(|| s.lease(w, now).unwrap()).collect();
            if leased.is_empty() {
                break;
            }
            for l in leased.iter().rev() {
                s.accept_tile(j, l.rect, 1, now).unwrap();
                peak = peak.max(s.jobs[&j].window.tracked());
            }
        }
        assert_eq!(s.info(j, now).unwrap().tiles_done, 4000);
        assert!(peak <= 8, "tracked {peak} tiles at once");
    }

    /// The encoder's output never exceeds [`encoded_rows_bound`]: noise
    /// (the hardest input to compress), encoded by `encode_segment`.
    #[test]
    fn encoded_segments_stay_within_their_bound() {
        let mut x = 0x2545_f491_4f6c_dd1d_u64;
        let mut noise = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 40) as f32 / (1u64 << 24) as f32
        };
        for width in [1, 2, 7, 64, 301] {
            for rows in [1, 5, 16] {
                let pixels: Vec<[f32; 3]> = (0..width * rows)
                    .map(|_| [noise(), noise(), noise()])
                    .collect();
                let seg = trevi_core::output::encode_segment(width, &pixels);
                let bound = encoded_rows_bound(width, rows);
                let len = seg.deflate.len() as u64;
                assert!(len <= bound, "{width}x{rows}: {len} > {bound}");
                // Noise is nearly incompressible: the bound is not loose
                // by more than its 12-bit codes and framing.
                assert!(len * 2 >= seg.filtered_len, "{width}x{rows}: {len}");
            }
        }
        // A segment band costs less than a float band, never more.
        let wide = spec(4096, 64, 64);
        assert!(segment_band_bytes(&wide) * 2 < band_bytes(&wide));
        let narrow = spec(1, 1, 1);
        assert!(segment_band_bytes(&narrow) <= band_bytes(&narrow));
    }

    /// Limits whose window holds four float bands of a 64-wide frame of
    /// 16-pixel tiles (nine segment bands).
    fn four_float_bands() -> Limits {
        let s = spec(64, 16 * 40, 16);
        Limits {
            lease_ttl: Duration::from_secs(5),
            window_bytes: encoder_bytes(&s) + 4 * band_bytes(&s),
            ..Limits::default()
        }
    }

    #[test]
    fn segment_leases_run_further_ahead_within_the_same_budget() {
        let now = Instant::now();
        let sp = spec(64, 16 * 40, 16);
        let (float_band, segment_band) = (band_bytes(&sp), segment_band_bytes(&sp));
        let room = 4 * float_band;
        let segment_bands = (room / segment_band) as u32;
        assert_eq!(segment_bands, 9);
        for encodes in [false, true] {
            let mut s = Scheduler::new(four_float_bands(), 1);
            let w = s.register_worker(now, None);
            s.describe_worker(w, "w", 16);
            s.allow_spans(w);
            if encodes {
                s.allow_segments(w);
            }
            let j = s.submit(sp.clone(), now);
            s.sizer.seed(j, 1e-12);
            let leases: Vec<Lease> = std::iter::from_fn(|| s.lease(w, now).unwrap()).collect();
            let rows: u32 = leases.iter().map(|l| l.rect.h).sum();
            let want = if encodes { segment_bands } else { 4 };
            assert_eq!(rows, 16 * want, "encodes: {encodes}");
            assert!(leases.iter().all(|l| l.png_segments == encodes));
            let held = s.jobs[&j].window.held_bytes();
            let cost = if encodes { segment_band } else { float_band };
            assert_eq!(held, want as u64 * cost);
            assert!(held <= s.jobs[&j].window.room());
        }
    }

    /// Workers that encode and workers that do not take bands of the same
    /// frame, and leases complete out of order: what the
    /// held bands cost, computed here from the leases alone (12 bytes a
    /// pixel for a band any of whose tiles went out as floats, the
    /// encoder's worst case for the others), is the window's own figure,
    /// never over the budget unless one band alone is held, and the frame
    /// completes.
    #[test]
    fn mixed_leases_stay_within_the_budget() {
        use std::collections::{HashMap, VecDeque};
        let now = Instant::now();
        let sp = spec(64, 16 * 40, 16);
        let (float_band, segment_band) = (band_bytes(&sp), segment_band_bytes(&sp));
        let mut s = Scheduler::new(four_float_bands(), 1);
        let room = 4 * float_band;
        let mut workers = Vec::new();
        for encodes in [true, false, true] {
            let w = s.register_worker(now, None);
            s.describe_worker(w, "w", 1);
            s.allow_spans(w);
            if encodes {
                s.allow_segments(w);
            }
            workers.push(w);
        }
        let j = s.submit(sp.clone(), now);
        // 4.5 tiles a second of one thread: one band a lease at first
        // (results measure the cost again: later leases grow).
        s.sizer.seed(j, 1.0 / (4.5 * 256.0));
        let mut out: VecDeque<Lease> = VecDeque::new();
        let mut floats: BTreeMap<u32, bool> = BTreeMap::new();
        let mut done: HashMap<u32, u32> = HashMap::new();
        let (mut tiles_done, mut step, mut most_ahead) = (0, 0u32, 0);
        while tiles_done < 160 {
            step += 1;
            let who = workers[step as usize % 3];
            match s.lease(who, now).unwrap() {
                Some(l) => {
                    for band in l.rect.y / 16..(l.rect.y + l.rect.h) / 16 {
                        *floats.entry(band).or_default() |= !l.png_segments;
                    }
                    out.push_back(l);
                }
                None => {
                    let l = if step % 3 == 0 {
                        out.pop_back()
                    } else {
                        out.pop_front()
                    };
                    let l = l.expect("nothing out, and nothing given");
                    for p in s.span_tiles(j, l.rect).unwrap() {
                        s.accept_tile(j, p, 1, now).unwrap();
                        *done.entry(p.y / 16).or_default() += 1;
                        tiles_done += 1;
                    }
                }
            }
            let first = (0..40).find(|b| done.get(b).copied().unwrap_or(0) < 4);
            let Some(first) = first else { break };
            let held: u64 = floats
                .range(first..)
                .map(|(_, &f)| if f { float_band } else { segment_band })
                .sum();
            assert_eq!(held, s.jobs[&j].window.held_bytes(), "step {step}");
            // The count of leased tiles is the farm's leases of the job.
            let leases = s.leases.iter().filter(|(_, e)| e.job == j).count();
            assert_eq!(s.jobs[&j].window.leased() as usize, leases, "step {step}");
            let last = floats.keys().next_back().copied().unwrap_or(0);
            assert!(held <= room || last == first, "step {step}: {held}");
            most_ahead = most_ahead.max(last.saturating_sub(first) + 1);
        }
        assert_eq!(s.info(j, now).unwrap().tiles_done, 160);
        assert!(floats.values().any(|&f| f) && floats.values().any(|&f| !f));
        assert!(most_ahead > 4, "segment bands ran ahead: {most_ahead}");
    }

    /// The figures docs/farm.md gives: a 1920 × 4096 frame in 64-pixel
    /// tiles under the default 32 MiB window holds 22 bands leased as
    /// floats, 58 leased as segments.
    #[test]
    fn the_default_window_holds_22_float_or_58_segment_bands_of_a_1920_frame() {
        let now = Instant::now();
        for (encodes, bands) in [(false, 22), (true, 58)] {
            let mut s = Scheduler::new(Limits::default(), 1);
            let w = s.register_worker(now, None);
            s.describe_worker(w, "w", 16);
            s.allow_spans(w);
            if encodes {
                s.allow_segments(w);
            }
            let mut sp = spec(1920, 4096, 64);
            sp.output_name = "o.png".into();
            let j = s.submit(sp, now);
            s.sizer.seed(j, 1e-12);
            let rows: u32 = std::iter::from_fn(|| s.lease(w, now).unwrap())
                .map(|l| l.rect.h)
                .sum();
            assert_eq!(rows, 64 * bands, "encodes: {encodes}");
        }
    }
}
