//! NumPy `.npy` headers (`npy::parse_header`): any bytes give a header or an error, never a panic,
//! and a parsed header's data offset is where its bytes end.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| neuspike_fuzz::formats::npy(data));
