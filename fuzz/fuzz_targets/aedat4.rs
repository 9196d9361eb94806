//! AEDAT 4: header, XML description, packets (uncompressed, LZ4, Zstd) and FlatBuffers, for the
//! events (`Aedat4Reader`) and the APS frames (`Aedat4Frames`).
#![no_main]
use libfuzzer_sys::fuzz_target;
use neuspike_formats::aedat4::{Aedat4Frames, Aedat4Reader};

fuzz_target!(|data: &[u8]| {
    let (opts, n, bytes) = neuspike_fuzz::options(data);
    if let Ok(mut r) = Aedat4Reader::from_reader(bytes, "fuzz.aedat4", &opts) {
        neuspike_fuzz::drain(&mut r, n);
    }
    if let Ok(frames) = Aedat4Frames::from_reader(bytes, "fuzz.aedat4") {
        for f in frames.flatten() {
            let want = usize::from(f.width) * usize::from(f.height) * f.format.bytes_per_pixel();
            assert_eq!(f.pixels.len(), want);
        }
    }
});
