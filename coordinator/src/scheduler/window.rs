//! A job's band window: its tiles numbered in band order, which of them are
//! pending, leased or done, and how far ahead of the first band that is not
//! complete tiles may be leased. Only the tiles between the first one not
//! done and the first one never leased are stored; the window keeps that
//! span to a few bands, so neither the stitcher's rows nor this bookkeeping
//! grows with the image height. What a band costs ([`band_bytes`],
//! [`encoder_bytes`]) sets how many bands the window holds.

use super::{JobSpec, LeaseId};
use std::collections::{BTreeMap, BTreeSet};
use trevi_core::tile::Rect;

/// What the bookkeeping of one tile in a job's band window may cost, in
/// bytes: its state in the window, a lease, a re-queue entry (counted
/// generously; see [`band_bytes`]).
pub const TILE_BOOKKEEPING_BYTES: u64 = 96;

/// What one band of `spec`'s tiles costs the coordinator while it is in the
/// window, in bytes: its rows in the writer (12 bytes a pixel, the most any
/// format holds) and the bookkeeping of its tiles. The band window holds
/// `window_bytes / band_bytes` bands, at least one.
pub fn band_bytes(spec: &JobSpec) -> u64 {
    let tile = spec.tile_size.max(1) as u64;
    let rows = tile.min(spec.height.max(1) as u64);
    let cols = (spec.width as u64).div_ceil(tile).max(1);
    spec.width as u64 * rows * 12 + cols * TILE_BOOKKEEPING_BYTES
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
    window_bands: u32,
    /// Every tile before this one is done.
    first_undone: u32,
    /// Every tile from this one on is pending and was never leased.
    next_fresh: u32,
    /// States of tiles `first_undone..next_fresh`.
    active: BTreeMap<u32, TileState>,
    /// Pending tiles before `next_fresh` (re-queued), smallest first.
    requeued: BTreeSet<u32>,
}

impl BandWindow {
    /// The window of a job in `spec.tile_size` tiles (≥ 1) with a budget of
    /// `window_bytes`.
    pub(super) fn new(spec: &JobSpec, window_bytes: u64) -> BandWindow {
        let tile = spec.tile_size.max(1);
        let cols = spec.width.div_ceil(tile).max(1);
        let rows = spec.height.div_ceil(tile);
        let room = window_bytes.saturating_sub(encoder_bytes(spec));
        let window_bands = (room / band_bytes(spec).max(1)).clamp(1, u32::MAX as u64);
        BandWindow {
            tile,
            width: spec.width,
            height: spec.height,
            cols,
            tiles_total: u32::try_from(cols as u64 * rows as u64).unwrap_or(u32::MAX),
            window_bands: window_bands as u32,
            first_undone: 0,
            next_fresh: 0,
            active: BTreeMap::new(),
            requeued: BTreeSet::new(),
        }
    }

    pub(super) fn tiles_total(&self) -> u32 {
        self.tiles_total
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
            self.active[&idx]
        }
    }

    /// Whether tile `idx` was never handed out.
    pub(super) fn is_fresh(&self, idx: u32) -> bool {
        idx >= self.next_fresh
    }

    /// The pending tile to hand out next, if the window allows one.
    pub(super) fn next_tile(&self) -> Option<u32> {
        let idx = match self.requeued.first() {
            Some(&i) => i,
            None if self.next_fresh < self.tiles_total => self.next_fresh,
            None => return None,
        };
        let limit = (self.first_undone / self.cols) as u64 + self.window_bands as u64;
        (((idx / self.cols) as u64) < limit).then_some(idx)
    }

    pub(super) fn set_leased(&mut self, idx: u32, lease: LeaseId) {
        if idx == self.next_fresh {
            self.next_fresh += 1;
        } else {
            self.requeued.remove(&idx);
        }
        self.active.insert(idx, TileState::Leased(lease));
    }

    /// Puts a handed-out tile back, ahead of the fresh ones.
    pub(super) fn requeue(&mut self, idx: u32) {
        self.active.insert(idx, TileState::Pending);
        self.requeued.insert(idx);
    }

    /// Marks a tile done and moves `first_undone` past the done prefix.
    pub(super) fn set_done(&mut self, idx: u32) {
        self.requeued.remove(&idx);
        self.active.insert(idx, TileState::Done);
        while self.first_undone < self.next_fresh
            && self.active.get(&self.first_undone) == Some(&TileState::Done)
        {
            self.active.remove(&self.first_undone);
            self.first_undone += 1;
        }
    }

    /// Restores the window of a job of an earlier run whose tiles `done`
    /// (sorted, unique, in the frame) are done: the done prefix needs no
    /// entries, the span after it up to the last done tile is pending or
    /// done (a window's worth, as when the tiles were leased).
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
        for i in prefix..self.next_fresh {
            self.requeue(i);
        }
        for &i in &done[prefix as usize..] {
            self.set_done(i);
        }
    }

    /// Drops the bookkeeping only a running job needs.
    pub(super) fn retire(&mut self) {
        self.active = BTreeMap::new();
        self.requeued = BTreeSet::new();
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
        JobSpec {
            frame: None,
            bundle_hash: "0".repeat(64),
            camera: "cam".into(),
            priority: 0,
            width: w,
            height: h,
            tile_size: tile,
            output_name: "out.png".into(),
        }
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
        assert_eq!(w.next_tile(), Some(1), "the gap first");
        w.set_leased(1, 7);
        assert_eq!(w.next_tile(), Some(3), "then the fresh tiles");
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
}
