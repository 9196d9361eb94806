//! A whole `.npy` file as `frames-to-events` reads it (`NpyFrames`): header, size check and every
//! frame. Any bytes give frames or an error, never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| neuspike_fuzz::formats::npy_file(data));
