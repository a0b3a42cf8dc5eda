//! Job control as `trevi-submit` shows and checks it: the state word of a
//! paused or waiting job, what it waits for, and the bound on `--after`
//! (the verbs themselves, `pause` and `resume`, are in `commands.rs`).

use trevi_coordinator::farm::MAX_AFTER;
use trevi_proto::pb;

/// The word for `s`'s state in `status` and `list`: `paused` or `waiting`
/// for an unfinished job held so, else the state's own label.
pub fn state_word(s: &pb::JobStatus) -> &'static str {
    if s.state().is_final() {
        s.state().label()
    } else if s.paused {
        "paused"
    } else if !s.waiting_for.is_empty() {
        "waiting"
    } else {
        s.state().label()
    }
}

/// `  waiting for 3, 4` for a job that waits for jobs, else nothing.
pub fn waiting_note(s: &pb::JobStatus) -> String {
    if s.waiting_for.is_empty() || s.state().is_final() {
        return String::new();
    }
    let ids: Vec<String> = s.waiting_for.iter().map(u64::to_string).collect();
    format!("  waiting for {}", ids.join(", "))
}

/// `--after`'s rules, checked before anything is read or uploaded: at most
/// [`MAX_AFTER`] ids, and a farm to wait on.
pub fn check_after(after: &[u64], farm: bool) -> Result<(), String> {
    if after.len() > MAX_AFTER {
        return Err(format!(
            "--after names {} jobs; a job may wait for at most {MAX_AFTER}",
            after.len()
        ));
    }
    if !after.is_empty() && !farm {
        return Err("--after waits for farm jobs: it needs --coordinator".into());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_held_job_says_why_and_an_ended_one_does_not() {
        let mut s = pb::JobStatus {
            state: pb::JobState::Running as i32,
            paused: true,
            waiting_for: vec![3, 4],
            ..Default::default()
        };
        assert_eq!(state_word(&s), "paused");
        assert_eq!(waiting_note(&s), "  waiting for 3, 4");
        s.paused = false;
        assert_eq!(state_word(&s), "waiting");
        s.waiting_for.clear();
        assert_eq!(state_word(&s), "running");
        assert_eq!(waiting_note(&s), "");
        s.state = pb::JobState::Failed as i32;
        s.paused = true;
        s.waiting_for = vec![3];
        assert_eq!(state_word(&s), "failed");
        assert_eq!(waiting_note(&s), "");
    }

    #[test]
    fn after_is_bounded_and_needs_a_farm() {
        assert!(check_after(&[1, 2], true).is_ok());
        assert!(check_after(&[], false).is_ok());
        let many: Vec<u64> = (1..=MAX_AFTER as u64 + 1).collect();
        let e = check_after(&many, true).unwrap_err();
        assert!(e.contains("at most 64"), "{e}");
        assert!(check_after(&many[..MAX_AFTER], true).is_ok());
        let e = check_after(&[1], false).unwrap_err();
        assert!(e.contains("--coordinator"), "{e}");
    }
}
