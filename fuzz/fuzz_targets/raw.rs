//! Prophesee RAW (EVT 2.0 and EVT 3.0): header and words.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| neuspike_fuzz::formats::raw(data));
