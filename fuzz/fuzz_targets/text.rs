//! Event Camera Dataset text: optional `W H` line, then `t x y p` lines.
#![no_main]
use libfuzzer_sys::fuzz_target;
use neuspike_formats::text::TextReader;

fuzz_target!(|data: &[u8]| {
    let (opts, n, bytes) = neuspike_fuzz::options(data);
    if let Ok(mut r) = TextReader::from_reader(bytes, "fuzz.txt", &opts) {
        neuspike_fuzz::drain(&mut r, n);
    }
});
