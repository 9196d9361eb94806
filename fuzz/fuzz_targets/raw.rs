//! Prophesee RAW (EVT 2.0 and EVT 3.0): header and words.
#![no_main]
use libfuzzer_sys::fuzz_target;
use neuspike_formats::raw::RawReader;

fuzz_target!(|data: &[u8]| {
    let (opts, n, bytes) = neuspike_fuzz::options(data);
    if let Ok(mut r) = RawReader::from_reader(bytes, "fuzz.raw", &opts) {
        neuspike_fuzz::drain(&mut r, n);
    }
});
