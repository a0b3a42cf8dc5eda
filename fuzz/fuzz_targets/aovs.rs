//! The render passes a submission names (`trevi-submit --aovs`,
//! `SubmitJobRequest.aovs`, a camera's `aovs=`), on arbitrary text: the
//! farm's check (`trevi_coordinator::farm::aovs_from`, the 64-byte bound
//! before the names are read) and the grammar under it
//! (`trevi_core::Aovs::parse`). A set reads back from its own display; an
//! error names at most 64 bytes of the input; past the bound the check
//! refuses without parsing; a progressive job refuses any pass. The wire's
//! byte (`Aovs::from_bits`) takes only the three passes' bits.
#![no_main]
use libfuzzer_sys::fuzz_target;
use trevi_coordinator::farm::{aovs_from, MAX_AOVS_BYTES};
use trevi_core::Aovs;

fuzz_target!(|data: &[u8]| {
    if let Some(&bits) = data.first() {
        match Aovs::from_bits(bits) {
            Some(a) => assert_eq!(a.bits(), bits),
            None => assert_ne!(bits & !Aovs::ALL.bits(), 0, "{bits:#b} refused"),
        }
    }
    let Ok(s) = std::str::from_utf8(data) else {
        return;
    };
    let parsed = Aovs::parse(s);
    match &parsed {
        Ok(set) => {
            assert!(set.channels() <= 7);
            assert_eq!(Aovs::parse(&set.to_string()).as_ref(), Ok(set), "{s:?}");
        }
        Err(e) => {
            assert!(e.name.len() <= 64, "{s:?}: the error holds {} bytes", e.name.len());
            assert!(s.contains(&e.name), "{s:?}: the error names {:?}", e.name);
        }
    }
    for progressive in [false, true] {
        match aovs_from(Some(s), progressive) {
            Ok(Some(set)) => {
                assert!(s.len() <= MAX_AOVS_BYTES, "{} bytes admitted", s.len());
                assert_eq!(parsed.as_ref(), Ok(&set));
                assert!(!progressive || set.is_empty(), "passes for a progressive job");
            }
            Ok(None) => panic!("{s:?}: a name given reads as none given"),
            Err(_) => assert!(
                s.len() > MAX_AOVS_BYTES
                    || parsed.is_err()
                    || (progressive && !parsed.as_ref().is_ok_and(|a| a.is_empty())),
                "{s:?} refused (progressive: {progressive})"
            ),
        }
    }
});
