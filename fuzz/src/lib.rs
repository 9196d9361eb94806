//! What every fuzz target checks: a decoder fed arbitrary bytes may refuse them with an error,
//! but never panics, and every event it delivers is inside the sensor, has polarity ±1 and comes
//! in time order; its counts agree with what it delivered. A violated check panics, which
//! libFuzzer reports as a crash with the input that caused it.

use neuspike_formats::{Disorder, EventBatch, EventReader, ReadOptions, Resolution, UnknownWords};

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
    };
    let batch = [1, 7, 256, 4096][usize::from(b >> 4) & 3];
    (opts, batch, rest)
}

/// Drains `reader` in batches of `n`, checking every event and the reader's count.
pub fn drain(reader: &mut dyn EventReader, n: usize) {
    let r = reader.resolution();
    let mut last = i64::MIN;
    let mut total = 0u64;
    loop {
        let mut b = EventBatch::default();
        match reader.read_into(&mut b, n) {
            Ok(0) => break,
            Ok(k) => {
                assert!(
                    k <= n && k == b.len(),
                    "read {k} of at most {n}, batch {}",
                    b.len()
                );
                for i in 0..k {
                    let e = b.get(i);
                    assert!(e.x < r.width && e.y < r.height, "{e:?} outside {r}");
                    assert!(e.polarity == 1 || e.polarity == -1, "{e:?}");
                    assert!(e.t_ns >= last, "{e:?} before {last}");
                    last = e.t_ns;
                }
                total += k as u64;
            }
            Err(e) => {
                let _ = e.to_string();
                break;
            }
        }
    }
    assert_eq!(reader.stats().events, total, "counted vs delivered");
}
