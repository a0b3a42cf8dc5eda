//! A sequence's outputs: where a frame's file is, which frame a result
//! must name, and whose preview stands for the sequence.

use super::super::{Farm, State};
use super::*;

impl Farm {
    /// The output file of frame `frame` of a sequence, once that frame is
    /// done; without a frame, its highest frame done. Looks at the disk
    /// at most [`FRAME_SCAN`] times, whatever the sequence's length: the
    /// highest frame done is kept in memory (see `Sequence::latest`).
    /// Call off the async threads: it stats files.
    pub fn frame_file(&self, seq: JobId, frame: Option<u32>) -> Result<PathBuf, FarmError> {
        let (pattern, first, last, latest, done) = {
            let st = self.state.lock();
            let Some(s) = st.seqs.get(&seq) else {
                return Err(self.not_a_sequence(&st, seq, frame));
            };
            if !s.frames() {
                // A progressive still: the output of its last pass done.
                let path = self.output_path(seq, &s.spec.output_name);
                return match frame {
                    Some(f) => Err(FarmError::NoOutput(
                        seq,
                        format!("it is a still rendered in passes: it has no frame {f}"),
                    )),
                    None if s.done == 0 => {
                        Err(FarmError::NoOutput(seq, "no pass is done yet".into()))
                    }
                    None => Ok(path),
                };
            }
            let latest = s.latest.map(|l| l.0);
            (s.spec.output_name.clone(), s.first, s.last, latest, s.done)
        };
        let path = |f: u32| self.output_path(seq, &frame_output(&pattern, f));
        match frame {
            Some(f) if f < first || f > last => Err(FarmError::NoOutput(
                seq,
                format!("frame {f} is not in its frames {first}-{last}"),
            )),
            Some(f) if path(f).is_file() => Ok(path(f)),
            Some(f) => Err(FarmError::NoOutput(seq, format!("frame {f} is not done"))),
            None if done == 0 => Err(FarmError::NoOutput(seq, "no frame is done yet".into())),
            None => {
                // Frames start in order: none done is past `first + done`
                // plus the frames in progress (at most the maximum).
                let top = latest.unwrap_or_else(|| {
                    let most = u64::from(first) + u64::from(done) + MAX_FRAMES_IN_PROGRESS as u64;
                    most.min(u64::from(last)) as u32
                });
                (first..=top)
                    .rev()
                    .take(FRAME_SCAN)
                    .map(path)
                    .find(|p| p.is_file())
                    .ok_or_else(|| {
                        FarmError::NoOutput(seq, "its latest frame's file is missing".into())
                    })
            }
        }
    }

    /// Why `job`, which is not a sequence, has no frame `frame` to
    /// download: unknown, a still, or a frame of a sequence.
    fn not_a_sequence(&self, st: &State, job: JobId, frame: Option<u32>) -> FarmError {
        let Some(info) = st.info(job, Instant::now()) else {
            return FarmError::UnknownJob(job);
        };
        let seq = st
            .parent_of
            .get(&job)
            .copied()
            .or_else(|| st.ended.frame_of(job).map(|(s, _)| s));
        match (info.spec.frame, seq) {
            (Some(f), Some(seq)) => FarmError::NoOutput(
                job,
                format!("it is frame {f} of sequence {seq}: fetch that sequence's frame {f}"),
            ),
            _ => FarmError::NoOutput(
                job,
                format!(
                    "it is a still, not a sequence: it has no frame {}; fetch it without one",
                    frame.unwrap_or_default()
                ),
            ),
        }
    }

    /// Whether a result for `frame` fits `job` (a frame of a sequence must
    /// say its frame; a still's result says none).
    pub fn check_frame(&self, job: JobId, frame: Option<u32>) -> Result<(), FarmError> {
        let st = self.state.lock();
        let Some(info) = st.sched.info(job, Instant::now()) else {
            return Ok(()); // Unknown jobs are refused further on.
        };
        if info.spec.frame != frame {
            return Err(FarmError::BadTile(format!(
                "the result is for frame {frame:?}, job {job} renders frame {:?}",
                info.spec.frame
            )));
        }
        Ok(())
    }

    /// The job whose preview stands for `job`: a sequence's earliest frame
    /// in progress, or else its latest frame done; a progressive job's
    /// latest pass done (the whole frame after each pass), or else its first
    /// pass in progress; any other job itself.
    pub(in crate::farm) fn preview_job(&self, job: JobId) -> JobId {
        let st = self.state.lock();
        st.seqs
            .get(&job)
            .and_then(|s| {
                if !s.frames() {
                    if let Some(done) = s.latest.and_then(|l| l.1) {
                        return Some(done);
                    }
                }
                s.running
                    .values()
                    .next()
                    .copied()
                    .or(s.latest.and_then(|l| l.1))
            })
            .unwrap_or(job)
    }
}
