//! PKU spike `.dat`: whole planes are delivered in order, a partial last plane is reported, and
//! nothing panics, for small geometries chosen by the first bytes (head columns included).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| neuspike_fuzz::formats::pku(data));
