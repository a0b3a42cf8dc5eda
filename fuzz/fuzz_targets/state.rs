//! The accumulation-state decoder on arbitrary bytes (what a coordinator
//! reads back from its disk between passes): a state or an error, never a
//! panic, never an allocation the input's length does not bound; a decoded
//! state encodes back to the input and finishes and estimates its noise
//! without panicking.
#![no_main]
use libfuzzer_sys::fuzz_target;
use trevi_core::passes::TileState;

fuzz_target!(|data: &[u8]| {
    if let Ok(state) = TileState::decode(data) {
        assert_eq!(state.encode(), data, "a decoded state re-encodes differently");
        let pixels = state.finish();
        assert_eq!(pixels.len(), state.rect().pixel_count());
        let _ = state.noise().relative_error();
    }
});
