//! The duration grammar of the farm's command lines (`--time-limit`,
//! `--keep-ended-for`: `trevi_proto::duration::parse`) on arbitrary text: a
//! duration or an error naming the (trimmed) input, never a panic or an
//! overflow; a duration is whole seconds and reads back from its own
//! `format`.
//!
//! The module is compiled here from its file rather than through the
//! `trevi-proto` crate, whose gRPC stack (tonic, rustls with ring, the
//! protox build) would multiply the instrumented build for a parser that
//! needs nothing but `std` and `thiserror`.
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "../../proto/src/duration.rs"]
mod duration;

fuzz_target!(|data: &[u8]| {
    let Ok(s) = std::str::from_utf8(data) else {
        return;
    };
    match duration::parse(s) {
        Ok(d) => {
            assert_eq!(d.subsec_nanos(), 0, "{s:?}: not whole seconds");
            let text = duration::format(d);
            assert_eq!(duration::parse(&text), Ok(d), "{s:?} -> {text:?}");
        }
        Err(e) => assert_eq!(e.0, s.trim(), "the error names another input"),
    }
});
