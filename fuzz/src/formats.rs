//! What every format fuzz target checks, as plain functions: the fuzz targets call them on what
//! libFuzzer makes, and `formats/tests/corpus.rs` on the committed corpus (`fuzz/corpus-min/`),
//! without libFuzzer. What they check: a decoder fed arbitrary bytes may refuse them with an error,
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

/// The `raw` target: Prophesee RAW (EVT 2.0 and EVT 3.0): header and words.
pub fn raw(data: &[u8]) {
    use neuspike_formats::raw::RawReader;
    let (opts, n, bytes) = options(data);
    if let Ok(mut r) = RawReader::from_reader(bytes, "fuzz.raw", &opts) {
        drain(&mut r, n);
    }
}

/// The `prophesee_dat` target: Prophesee `.dat` events: `%` header, type and size bytes, fixed-size events.
pub fn prophesee_dat(data: &[u8]) {
    use neuspike_formats::dat::DatReader;
    let (opts, n, bytes) = options(data);
    if let Ok(mut r) = DatReader::from_reader(bytes, "fuzz.dat", &opts) {
        drain(&mut r, n);
    }
}

/// The `text` target: Event Camera Dataset text: optional `W H` line, then `t x y p` lines.
pub fn text(data: &[u8]) {
    use neuspike_formats::text::TextReader;
    let (opts, n, bytes) = options(data);
    if let Ok(mut r) = TextReader::from_reader(bytes, "fuzz.txt", &opts) {
        drain(&mut r, n);
    }
}

/// The `aedat4` target: AEDAT 4: header, XML description, packets (uncompressed, LZ4, Zstd) and FlatBuffers, for the events (`Aedat4Reader`) and the APS frames (`Aedat4Frames`).
pub fn aedat4(data: &[u8]) {
    use neuspike_formats::aedat4::{Aedat4Frames, Aedat4Reader};
    let (opts, n, bytes) = options(data);
    if let Ok(mut r) = Aedat4Reader::from_reader(bytes, "fuzz.aedat4", &opts) {
        drain(&mut r, n);
    }
    if let Ok(frames) = Aedat4Frames::from_reader(bytes, "fuzz.aedat4") {
        for f in frames.flatten() {
            let want = usize::from(f.width) * usize::from(f.height) * f.format.bytes_per_pixel();
            assert_eq!(f.pixels.len(), want);
        }
    }
}

/// The `pku` target: PKU spike `.dat`: whole planes are delivered in order, a partial last plane is reported, and nothing panics, for small geometries chosen by the first bytes (head columns included).
pub fn pku(data: &[u8]) {
    use neuspike_formats::pku::{PkuGeometry, PkuOptions, PkuReader};
    let [w, h, flags, rest @ ..] = data else {
        return;
    };
    let g = PkuGeometry {
        width: usize::from(*w % 64) + 1,
        height: usize::from(*h % 16) + 1,
        head_columns: if flags & 1 != 0 { 16 } else { 0 },
    };
    let opts = PkuOptions {
        geometry: g,
        ..PkuOptions::default()
    };
    let Ok(mut r) = PkuReader::from_reader(rest, "fuzz.dat", &opts) else {
        return;
    };
    let n = usize::from(flags >> 1) + 1;
    let mut planes = 0u64;
    loop {
        match r.next_chunk(n) {
            Ok(Some(c)) => {
                assert_eq!(c.bits.len(), c.n_planes * g.plane_bytes());
                assert_eq!(c.first_plane, planes);
                planes += c.n_planes as u64;
            }
            Ok(None) => break,
            Err(e) => {
                let _ = e.to_string();
                break;
            }
        }
    }
    assert_eq!(planes, (rest.len() / g.stored_plane_bytes()) as u64);
}

/// The `sniff` target: The format sniffer: any prefix and length gives a format or an error, never a panic.
pub fn sniff(data: &[u8]) {
    use neuspike_formats::sniff::sniff_bytes;
    let len = data.len() as u64;
    if let Err(e) = sniff_bytes(data, len, std::path::Path::new("fuzz")) {
        let _ = e.to_string();
    }
    // A prefix of a longer file.
    let _ = sniff_bytes(
        data,
        len.saturating_mul(3).saturating_add(7),
        std::path::Path::new("fuzz"),
    );
}

/// The `npy` target: NumPy `.npy` headers (`npy::parse_header`): any bytes give a header or an error, never a panic, and a parsed header's data offset is where its bytes end.
pub fn npy(data: &[u8]) {
    use neuspike_formats::npy::parse_header;
    let mut reader = data;
    match parse_header(&mut reader, std::path::Path::new("fuzz.npy")) {
        Ok(h) => assert_eq!(h.data_offset as usize, data.len() - reader.len()),
        Err(e) => {
            let _ = e.to_string();
        }
    }
}

/// The `npy_file` target: a whole `.npy` file as `frames-to-events` reads it (`NpyFrames`):
/// header, size check and every frame; never more memory than one frame of the shape the file's
/// size holds.
pub fn npy_file(data: &[u8]) {
    use neuspike_formats::npy::NpyFrames;
    let dir = std::env::temp_dir().join(format!("neuspike-fuzz-npy-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join(format!("{:?}.npy", std::thread::current().id()).replace(['(', ')'], ""));
    if std::fs::write(&path, data).is_err() {
        return;
    }
    let Ok(mut frames) = NpyFrames::open(&path) else {
        return;
    };
    let (t, h, w) = frames.shape();
    assert!(t.saturating_mul(h).saturating_mul(w).saturating_mul(4) <= data.len());
    let mut frame = Vec::new();
    let mut n = 0;
    while let Ok(true) = frames.read_frame(&mut frame) {
        assert_eq!(frame.len(), h * w);
        n += 1;
    }
    assert!(n <= t);
}
