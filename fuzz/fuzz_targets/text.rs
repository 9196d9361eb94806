//! Event Camera Dataset text: optional `W H` line, then `t x y p` lines.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| neuspike_fuzz::formats::text(data));
