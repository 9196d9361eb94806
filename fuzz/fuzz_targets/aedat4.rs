//! AEDAT 4: header, XML description, packets (uncompressed, LZ4, Zstd) and FlatBuffers, for the
//! events (`Aedat4Reader`) and the APS frames (`Aedat4Frames`).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| neuspike_fuzz::formats::aedat4(data));
