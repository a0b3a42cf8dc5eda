//! The requeue grammar (`trevi_proto::requeue`: the body of `POST
//! /api/jobs/{id}/requeue`, `--frames A-B`, `--rect X,Y,W,H`) on arbitrary
//! bytes: a requeue or an error, never a panic; what is read back is within
//! its bounds (frames first ≤ last), and a body over `MAX_BODY_BYTES` is
//! refused whatever it holds.
//!
//! The module is compiled here from its file, as `duration.rs` is: it needs
//! nothing but `std` and `thiserror`.
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "../../proto/src/requeue.rs"]
mod requeue;

fuzz_target!(|data: &[u8]| {
    match requeue::parse_body(data) {
        Ok(r) => {
            assert!(data.len() <= requeue::MAX_BODY_BYTES);
            if let Some((a, b)) = r.frames {
                assert!(a <= b, "{a}-{b}");
            }
        }
        Err(e) => {
            if data.len() > requeue::MAX_BODY_BYTES {
                assert!(matches!(e, requeue::BadRequeue::TooLong { .. }), "{e}");
            }
        }
    }
    let Ok(s) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok((a, b)) = requeue::parse_frames(s) {
        assert!(a <= b && s.chars().count() <= requeue::MAX_ARG_CHARS);
        let text = format!("{a}-{b}");
        assert_eq!(requeue::parse_frames(&text), Ok((a, b)));
    }
    if let Ok(r) = requeue::parse_rect(s) {
        let text = format!("{},{},{},{}", r[0], r[1], r[2], r[3]);
        assert_eq!(requeue::parse_rect(&text), Ok(r));
    }
});
