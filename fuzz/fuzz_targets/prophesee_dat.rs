//! Prophesee `.dat` events: `%` header, type and size bytes, fixed-size events.
#![no_main]
use libfuzzer_sys::fuzz_target;
use neuspike_formats::dat::DatReader;

fuzz_target!(|data: &[u8]| {
    let (opts, n, bytes) = neuspike_fuzz::options(data);
    if let Ok(mut r) = DatReader::from_reader(bytes, "fuzz.dat", &opts) {
        neuspike_fuzz::drain(&mut r, n);
    }
});
