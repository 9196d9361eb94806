//! Prophesee `.dat` events: `%` header, type and size bytes, fixed-size events.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| neuspike_fuzz::formats::prophesee_dat(data));
