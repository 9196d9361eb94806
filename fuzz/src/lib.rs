//! What every fuzz target checks: a decoder fed arbitrary bytes may refuse them with an error,
//! but never panics, and every event it delivers is inside the sensor, has polarity ±1 and comes
//! in time order; its counts agree with what it delivered. A violated check panics, which
//! libFuzzer reports as a crash with the input that caused it.

use neuspike_formats::{Disorder, EventReader, ReadOptions, Resolution, UnknownWords};

/// Reader options and a batch size chosen by the input's first byte, so the fuzzer explores
/// them too; returns them with the remaining bytes.
pub fn options(data: &[u8]) -> (ReadOptions, usize, &[u8]) {
    let Some((&b, rest)) = data.split_first() else {
        return (ReadOptions::default(), 1, data);
    };
    let resolution = match b & 3 {
        0 => None,
        1 => Some(Resolution::new(640, 480)),
        2 => Some(Resolution::new(240, 180)),
        _ => Some(Resolution::new(1, 1)),
    };
    let opts = ReadOptions {
        resolution,
        disorder: if b & 4 != 0 {
            Disorder::Clamp
        } else {
            Disorder::Error
        },
        unknown_words: if b & 8 != 0 {
            UnknownWords::Skip
        } else {
            UnknownWords::Error
        },
        allow_unknown_size: b & 64 != 0,
        ..ReadOptions::default()
    };
    let batch = [1, 7, 256, 4096][usize::from(b >> 4) & 3];
    (opts, batch, rest)
}

/// Drains `reader` in batches of `n`; a broken promise (see
/// [`neuspike_formats::drain_checked`]) is a crash.
pub fn drain(reader: &mut dyn EventReader, n: usize) {
    if let Err(bug) = neuspike_formats::drain_checked(reader, n) {
        panic!("{bug}");
    }
}
