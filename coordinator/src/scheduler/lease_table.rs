//! The farm's live leases, one entry a span.
//!
//! A lease covers one tile, and a worker gets a span of adjacent tiles at
//! once, under consecutive lease ids: on a farm of a thousand workers that
//! is over a million tile leases, granted and taken hundreds at a time. So
//! the table keeps one entry per span (its first lease id, first tile,
//! worker, deadline, and which of its tiles are still out under it), and
//! answers for single leases from that: a span's tiles are consecutive
//! indices, so lease `first + i` is tile `first_tile + i`. Granting or
//! taking a span of 768 tiles is then one B-tree insert or removal, not
//! 768, under the farm's one lock (docs/benchmarks.md, "Stage 7").

use super::{JobId, LeaseId, WorkerId};
use std::collections::BTreeMap;
use std::time::Instant;

/// One tile's lease, as the table gives it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct LeaseEntry {
    pub job: JobId,
    pub tile: u32,
    pub worker: WorkerId,
    pub deadline: Instant,
    /// When it was granted, and the pixels of the span it came in: a
    /// result measures the job's cost (see [`super::lease_size`]). The
    /// pixels are given for the span's first tile only (0 for the others):
    /// a span's result is one measurement, not one for each of its tiles,
    /// which would replace the smoothed cost with the last span's.
    pub granted: Instant,
    pub span_pixels: u64,
}

/// Consecutive leases out of one span: tiles `first_tile..first_tile +
/// len` of `job`, held by `worker` ([`LeaseTable::runs`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct LeaseRun {
    pub job: JobId,
    pub worker: WorkerId,
    pub first_tile: u32,
    pub len: u32,
}

/// A span's leases: ids `first..first + count` for tiles
/// `first_tile..first_tile + count`.
#[derive(Debug)]
struct SpanLease {
    job: JobId,
    first_tile: u32,
    count: u32,
    worker: WorkerId,
    deadline: Instant,
    granted: Instant,
    span_pixels: u64,
    /// Bit `i`: tile `first_tile + i` is still out under lease `first + i`.
    out: Box<[u64]>,
}

impl SpanLease {
    fn is_out(&self, i: u64) -> bool {
        i < u64::from(self.count) && self.out[(i / 64) as usize] & (1 << (i % 64)) != 0
    }

    fn entry(&self, i: u64) -> LeaseEntry {
        LeaseEntry {
            job: self.job,
            tile: self.first_tile + i as u32,
            worker: self.worker,
            deadline: self.deadline,
            granted: self.granted,
            span_pixels: if i == 0 { self.span_pixels } else { 0 },
        }
    }

    /// The leases still out, with their offsets in the span, in id order.
    fn out_offsets(&self) -> impl Iterator<Item = u64> + '_ {
        (0..u64::from(self.count)).filter(|&i| self.is_out(i))
    }
}

/// The live leases: see the module's doc.
#[derive(Debug, Default)]
pub(super) struct LeaseTable {
    /// Spans by their first lease id.
    spans: BTreeMap<LeaseId, SpanLease>,
}

/// What one span is granted as: [`LeaseTable::insert_span`].
pub(super) struct NewSpan {
    pub first: LeaseId,
    pub job: JobId,
    pub first_tile: u32,
    pub count: u32,
    pub worker: WorkerId,
    pub deadline: Instant,
    pub granted: Instant,
    pub span_pixels: u64,
}

impl LeaseTable {
    /// Adds a span's `count` leases (none when `count` is 0). Its ids must
    /// not overlap a live span's: lease ids are never reused.
    pub fn insert_span(&mut self, s: NewSpan) {
        let count = s.count;
        if count == 0 {
            return;
        }
        // Every tile out: whole words of ones, the last word's tail clear.
        let mut out = vec![u64::MAX; count.div_ceil(64) as usize].into_boxed_slice();
        if count % 64 != 0 {
            out[out.len() - 1] = (1 << (count % 64)) - 1;
        }
        self.spans.insert(
            s.first,
            SpanLease {
                job: s.job,
                first_tile: s.first_tile,
                count,
                worker: s.worker,
                deadline: s.deadline,
                granted: s.granted,
                span_pixels: s.span_pixels,
                out,
            },
        );
    }

    /// The span holding lease `id` (out or not), and `id`'s offset in it.
    fn span_of(&self, id: LeaseId) -> Option<(LeaseId, &SpanLease, u64)> {
        let (&first, span) = self.spans.range(..=id).next_back()?;
        let i = id - first;
        (i < u64::from(span.count)).then_some((first, span, i))
    }

    /// As [`Self::span_of`], to change the span.
    fn span_of_mut(&mut self, id: LeaseId) -> Option<(LeaseId, &mut SpanLease, u64)> {
        let (&first, span) = self.spans.range_mut(..=id).next_back()?;
        let i = id - first;
        (i < u64::from(span.count)).then_some((first, span, i))
    }

    /// The span whose first lease is `first`, while any of its leases is
    /// out: its run of tiles (`len` is all of the span's tiles).
    pub fn span(&self, first: LeaseId) -> Option<LeaseRun> {
        let span = self.spans.get(&first)?;
        Some(LeaseRun {
            job: span.job,
            worker: span.worker,
            first_tile: span.first_tile,
            len: span.count,
        })
    }

    /// Lease `id`, if it is out.
    pub fn get(&self, id: LeaseId) -> Option<LeaseEntry> {
        let (_, span, i) = self.span_of(id)?;
        span.is_out(i).then(|| span.entry(i))
    }

    /// Ends lease `id` (its tile is done, re-queued or dropped) and gives
    /// what it was; `None` if it is not out.
    pub fn remove(&mut self, id: LeaseId) -> Option<LeaseEntry> {
        let (first, span, i) = self.span_of_mut(id)?;
        if !span.is_out(i) {
            return None;
        }
        let entry = span.entry(i);
        span.out[(i / 64) as usize] &= !(1 << (i % 64));
        if span.out.iter().all(|&w| w == 0) {
            self.spans.remove(&first);
        }
        Some(entry)
    }

    /// Renews lease `id` (and with it the rest of its span, which were
    /// granted together) to `deadline` if it is out, is `worker`'s and has
    /// not run out at `now`. Says whether it did.
    pub fn renew(
        &mut self,
        id: LeaseId,
        worker: WorkerId,
        now: Instant,
        deadline: Instant,
    ) -> bool {
        match self.span_of_mut(id) {
            Some((_, span, i))
                if span.is_out(i) && span.worker == worker && span.deadline >= now =>
            {
                span.deadline = deadline;
                true
            }
            _ => false,
        }
    }

    /// The leases out with ids in `from..from + n`, in id order. Ids past
    /// `u64::MAX` are not there.
    pub fn in_range(
        &self,
        from: LeaseId,
        n: u64,
    ) -> impl Iterator<Item = (LeaseId, LeaseEntry)> + '_ {
        let end = from.saturating_add(n);
        // The span reaching into the range from before it, then those
        // starting in it.
        let before = self.spans.range(..from).next_back();
        before
            .into_iter()
            .chain(self.spans.range(from..end))
            .flat_map(|(&first, span)| span.out_offsets().map(move |i| (first + i, span.entry(i))))
            .filter(move |&(id, _)| id >= from && id < end)
    }

    /// Every lease out, in id order.
    #[cfg(test)]
    pub fn iter(&self) -> impl Iterator<Item = (LeaseId, LeaseEntry)> + '_ {
        self.spans
            .iter()
            .flat_map(|(&first, span)| span.out_offsets().map(move |i| (first + i, span.entry(i))))
    }

    /// Every lease out, as runs of consecutive tiles, in id order: what a
    /// worker holds without a step per tile (a whole span is one run).
    pub fn runs(&self) -> impl Iterator<Item = LeaseRun> + '_ {
        self.spans.values().flat_map(|span| {
            let count = u64::from(span.count);
            let mut i = 0u64;
            std::iter::from_fn(move || {
                while i < count && !span.is_out(i) {
                    i += 1;
                }
                let start = i;
                while i < count && span.is_out(i) {
                    i += 1;
                }
                (i > start).then(|| LeaseRun {
                    job: span.job,
                    worker: span.worker,
                    first_tile: span.first_tile + start as u32,
                    len: (i - start) as u32,
                })
            })
        })
    }

    /// Whether any lease of `job` is out.
    pub fn holds_job(&self, job: JobId) -> bool {
        self.spans.values().any(|s| s.job == job)
    }

    /// The leases out whose deadline is before `now`, in id order, and the
    /// earliest deadline of the others (`None`: there are none).
    pub fn expired(&self, now: Instant) -> (Vec<LeaseId>, Option<Instant>) {
        let mut expired = Vec::new();
        let mut rest: Option<Instant> = None;
        for (&first, span) in &self.spans {
            if span.deadline < now {
                expired.extend(span.out_offsets().map(|i| first + i));
            } else {
                rest = Some(rest.map_or(span.deadline, |d| d.min(span.deadline)));
            }
        }
        (expired, rest)
    }

    /// How many tile leases are out.
    #[cfg(test)]
    pub fn len(&self) -> usize {
        self.spans
            .values()
            .map(|s| s.out.iter().map(|w| w.count_ones() as usize).sum::<usize>())
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;
    use std::time::Duration;

    /// A lease id for a step: with `live` 1, one of the model's (any,
    /// when it has none); else any id up to a little past the last granted.
    fn pick(model: &BTreeMap<LeaseId, LeaseEntry>, live: u64, r: u64, next: LeaseId) -> LeaseId {
        match model.keys().nth((r % model.len().max(1) as u64) as usize) {
            Some(&id) if live == 1 => id,
            _ => 990 + r % (next - 980),
        }
    }

    /// The table against a map of one entry per tile lease (what it
    /// replaced), through spans granted, tiles taken one by one and spans
    /// expired, with a seeded generator.
    #[test]
    fn the_table_answers_as_a_map_of_tile_leases_does() {
        let t0 = Instant::now();
        let mut table = LeaseTable::default();
        let mut model: BTreeMap<LeaseId, LeaseEntry> = BTreeMap::new();
        let mut state = 7u64;
        let mut rnd = |n: u64| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) % n
        };
        let mut next: LeaseId = 1000;
        // The spans granted: (first id, count).
        let mut spans: Vec<(LeaseId, u32)> = Vec::new();
        let mut next_tile = 0u32;
        for step in 0..3000u64 {
            match rnd(20) {
                0..=5 => {
                    // A span of 1 to 200 tiles, sometimes more than 64.
                    let count = 1 + rnd(200) as u32;
                    let s = NewSpan {
                        first: next,
                        job: 1 + rnd(3),
                        first_tile: next_tile,
                        count,
                        worker: 1 + rnd(5),
                        deadline: t0 + Duration::from_millis(step + rnd(500)),
                        granted: t0,
                        span_pixels: 4096 * u64::from(count),
                    };
                    for i in 0..count {
                        model.insert(
                            next + u64::from(i),
                            LeaseEntry {
                                job: s.job,
                                tile: next_tile + i,
                                worker: s.worker,
                                deadline: s.deadline,
                                granted: s.granted,
                                span_pixels: if i == 0 { s.span_pixels } else { 0 },
                            },
                        );
                    }
                    spans.push((next, count));
                    table.insert_span(s);
                    next += u64::from(count) + rnd(3);
                    next_tile += count;
                }
                6..=13 => {
                    // A lease taken: live, gone already, or never granted.
                    let id = pick(&model, rnd(2), rnd(1 << 20), next);
                    assert_eq!(table.remove(id), model.remove(&id), "step {step}");
                }
                14 => {
                    let now = t0 + Duration::from_millis(step);
                    let (expired, rest) = table.expired(now);
                    let want: Vec<LeaseId> = model
                        .iter()
                        .filter(|(_, e)| e.deadline < now)
                        .map(|(&id, _)| id)
                        .collect();
                    assert_eq!(expired, want, "step {step}");
                    let rest_want = model
                        .values()
                        .filter(|e| e.deadline >= now)
                        .map(|e| e.deadline)
                        .min();
                    assert_eq!(rest, rest_want, "step {step}");
                    for id in expired {
                        assert_eq!(table.remove(id), model.remove(&id));
                    }
                }
                _ => {
                    // A heartbeat renews the lease's whole span, if it
                    // has not run out.
                    let id = pick(&model, rnd(2), rnd(1 << 20), next);
                    let w = match model.get(&id) {
                        Some(e) if rnd(2) == 0 => e.worker,
                        _ => 1 + rnd(5),
                    };
                    let now = t0 + Duration::from_millis(step);
                    let later = now + Duration::from_millis(300);
                    let renewed = table.renew(id, w, now, later);
                    let expect = model
                        .get(&id)
                        .is_some_and(|e| e.worker == w && e.deadline >= now);
                    assert_eq!(renewed, expect, "step {step}");
                    if renewed {
                        let &(first, count) = spans
                            .iter()
                            .find(|&&(f, c)| f <= id && id < f + u64::from(c))
                            .expect("a renewed lease is in a span");
                        for (_, o) in model.range_mut(first..first + u64::from(count)) {
                            o.deadline = later;
                        }
                    }
                }
            }
            assert_eq!(table.len(), model.len(), "step {step}");
            let all: Vec<(LeaseId, LeaseEntry)> = table.iter().collect();
            let want: Vec<(LeaseId, LeaseEntry)> = model.iter().map(|(&k, &v)| (k, v)).collect();
            assert_eq!(all, want, "step {step}");
            // The runs, tile by tile, are the leases; no two runs of one
            // span touch.
            let by_runs: Vec<(u32, JobId, WorkerId)> = table
                .runs()
                .flat_map(|r| {
                    (r.first_tile..r.first_tile + r.len).map(move |t| (t, r.job, r.worker))
                })
                .collect();
            let want: Vec<(u32, JobId, WorkerId)> =
                model.values().map(|e| (e.tile, e.job, e.worker)).collect();
            assert_eq!(by_runs, want, "step {step}");
            assert!(table.runs().all(|r| r.len > 0));
            let (from, n) = (990 + rnd(next - 980), rnd(300));
            let got: Vec<LeaseId> = table.in_range(from, n).map(|(id, _)| id).collect();
            let want: Vec<LeaseId> = model.range(from..from + n).map(|(&id, _)| id).collect();
            assert_eq!(got, want, "step {step}");
            for job in 1..=3 {
                assert_eq!(
                    table.holds_job(job),
                    model.values().any(|e| e.job == job),
                    "step {step}"
                );
            }
        }
    }

    #[test]
    fn a_hostile_lease_id_finds_nothing() {
        let t0 = Instant::now();
        let mut table = LeaseTable::default();
        table.insert_span(NewSpan {
            first: 5,
            job: 1,
            first_tile: 0,
            count: 3,
            worker: 1,
            deadline: t0,
            granted: t0,
            span_pixels: 3,
        });
        for id in [0, 4, 8, u64::MAX] {
            assert_eq!(table.get(id), None);
            assert_eq!(table.remove(id), None);
        }
        // A span of no tiles holds nothing.
        table.insert_span(NewSpan {
            first: 100,
            job: 1,
            first_tile: 9,
            count: 0,
            worker: 1,
            deadline: t0,
            granted: t0,
            span_pixels: 0,
        });
        assert_eq!(table.get(100), None);
        assert_eq!(table.in_range(u64::MAX, 5).count(), 0);
        assert_eq!(table.in_range(6, 5).count(), 2);
        assert_eq!(table.len(), 3);
    }
}
