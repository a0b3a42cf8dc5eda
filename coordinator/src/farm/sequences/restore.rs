//! Sequences after a restart: picked up from the database's rows (frames
//! or passes done, those in progress, failures) and moved on.

use super::super::Farm;
use super::*;

impl Farm {
    /// Picks up the sequences among `rows` (the database's jobs): each
    /// sequence with its count of frames done, its frames in progress and
    /// failures. Called before the jobs themselves are restored, so a frame
    /// that completes while it is restored moves its sequence on correctly.
    pub(in crate::farm) fn restore_sequences(&self, rows: &[StoredJob]) {
        let (now, wall) = (Instant::now(), wall_ms());
        let mut st = self.state.lock();
        for j in rows {
            let Some((first, last)) = j.seq.frames else {
                continue;
            };
            let ago = Duration::from_millis(wall.saturating_sub(j.submitted_ms));
            let submitted = now.checked_sub(ago).unwrap_or(now);
            let finished = j
                .elapsed
                .filter(|_| j.state.is_final())
                .map(|e| submitted + e);
            let seq = Sequence {
                spec: j.spec.clone(),
                first,
                last,
                done: j.seq.frames_done,
                next: first,
                running: BTreeMap::new(),
                again: BTreeSet::new(),
                state: j.state,
                submitted,
                started: finished
                    .zip(j.render)
                    .map(|(end, r)| end.checked_sub(r).unwrap_or(submitted)),
                finished,
                error: j.error.clone(),
                failed: None,
                rays: j.rays,
                latest: None,
                passes: j.seq.passes.as_ref().map(Passes::from_stored),
            };
            st.sched.skip_ids_through(j.id);
            if !seq.state.is_final() {
                st.submitters.insert(j.id, j.spec.submitter.clone());
            }
            st.seqs.insert(j.id, seq);
        }
        let mut rays: HashMap<JobId, u64> = HashMap::new();
        for j in rows {
            let (Some(p), Some(f)) = (j.seq.parent, run_index(&j.spec)) else {
                continue;
            };
            if j.state.is_final() {
                st.ended.frame(j.id, p, f);
            }
            let Some(s) = st.seqs.get_mut(&p) else {
                continue;
            };
            if j.state == JobState::Done && s.latest.is_none_or(|(l, _)| f >= l) {
                s.latest = Some((f, Some(j.id)));
            }
            if s.state.is_final() {
                continue;
            }
            if j.state == JobState::Done {
                *rays.entry(p).or_default() += j.rays;
            } else if j.state.is_final() {
                s.failed.get_or_insert_with(|| {
                    format!(
                        "{} {f}: {}",
                        if j.spec.frame.is_some() {
                            "frame"
                        } else {
                            "pass"
                        },
                        j.error.as_deref().unwrap_or(j.state.name())
                    )
                });
            } else {
                s.running.insert(f, j.id);
                st.parent_of.insert(j.id, p);
            }
        }
        let ids: Vec<JobId> = st.seqs.keys().copied().collect();
        for id in ids {
            let s = st.seqs.get_mut(&id).expect("listed");
            if !s.state.is_final() {
                // Frames started: a sequence in passes counts passes.
                let runs = s.done + s.running.len() as u32;
                s.next = s.first + runs.div_ceil(s.runs_per_frame());
                s.rays = rays.get(&id).copied().unwrap_or(0);
                // The frames before `next` not in progress are done.
                if s.latest.is_none() {
                    s.latest = (s.first..s.next)
                        .rev()
                        .find(|f| !s.running.contains_key(f))
                        .map(|f| (f, None));
                }
            } else if s.latest.is_none() && s.state == JobState::Done {
                s.latest = Some((s.last, None));
            }
            let info = st.info(id, now).expect("listed");
            st.watchers.insert(id, watch::channel(info).0);
        }
    }

    /// Moves every unfinished sequence on after a restart.
    pub(in crate::farm) fn resume_sequences(&self) {
        let ids: Vec<JobId> = self.state.lock().seqs.keys().copied().collect();
        for id in ids {
            self.advance(id);
        }
    }
}
