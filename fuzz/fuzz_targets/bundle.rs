//! The bundle codec on arbitrary bytes: `Bundle::decode` (what a worker
//! does with a downloaded bundle) and `check_encoding` (what the coordinator
//! does with an upload, streaming from its file) give a bundle or an error,
//! never a panic, and `check_encoding` accepts nothing `decode` refuses.
#![no_main]
use libfuzzer_sys::fuzz_target;
use trevi_core::bundle::{check_encoding, Bundle};

fuzz_target!(|data: &[u8]| {
    let decoded = Bundle::decode(data);
    if check_encoding(data).is_ok() {
        assert!(decoded.is_ok(), "check_encoding accepted what decode refuses");
    }
});
