//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

use neuspike_formats::{Event, EventBatch, EventReader, Result, read_all};

/// The shared real recordings, beside the repository (`/work/shared/data/real` when the repo is
/// `/work/main`).
pub const REAL_DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/real");
pub const VIDAR: &str = "vidar-car-400x250.dat";
pub const DAVIS_TEXT: &str = "davis240c-shapes-rotation-events.txt";
pub const PROPHESEE_EVT2: &str = "prophesee-evt2-640x480.raw";

/// The path of a real recording, or `None` (after printing a notice) when the shared folder is
/// absent, as in a fresh clone.
pub fn real(name: &str) -> Option<PathBuf> {
    let p = PathBuf::from(REAL_DIR).join(name);
    if p.is_file() {
        Some(p)
    } else {
        eprintln!(
            "NOTICE: {} not found; skipping this real-data check",
            p.display()
        );
        None
    }
}

/// All events of a reader, in one batch.
pub fn all(reader: &mut dyn EventReader) -> Result<EventBatch> {
    read_all(reader)
}

/// The events of a batch as a vector.
pub fn events(b: &EventBatch) -> Vec<Event> {
    (0..b.len()).map(|i| b.get(i)).collect()
}

/// Asserts two event lists are equal, naming the first difference (never dumping the lists).
pub fn assert_same_events(got: &[Event], want: &[Event]) {
    if let Some(i) = (0..got.len().min(want.len())).find(|&i| got[i] != want[i]) {
        panic!("event {i} differs: got {:?}, want {:?}", got[i], want[i]);
    }
    assert_eq!(got.len(), want.len(), "event counts differ");
}

/// Reads everything, delivering events in chunks of `n`, until the end or the first error;
/// returns the events delivered and the error, if any.
pub fn drain(
    reader: &mut dyn EventReader,
    n: usize,
) -> (Vec<Event>, Option<neuspike_formats::FormatError>) {
    let mut out = Vec::new();
    loop {
        let mut b = EventBatch::default();
        match reader.read_into(&mut b, n) {
            Ok(0) => return (out, None),
            Ok(k) => {
                assert_eq!(k, b.len());
                assert!(k <= n, "read_into returned {k} > {n}");
                out.extend(events(&b));
            }
            Err(e) => {
                // After an error the reader is finished.
                let mut b = EventBatch::default();
                assert_eq!(reader.read_into(&mut b, n).ok(), Some(0));
                return (out, Some(e));
            }
        }
    }
}

// EVT 2.0 words.
pub fn evt2_time_high(high: u32) -> u32 {
    (0x8 << 28) | (high & 0x0FFF_FFFF)
}
pub fn evt2_cd(on: bool, t_low: u32, x: u32, y: u32) -> u32 {
    (u32::from(on) << 28) | ((t_low & 0x3F) << 22) | ((x & 0x7FF) << 11) | (y & 0x7FF)
}
pub fn evt2_file(header: &str, words: &[u32]) -> Vec<u8> {
    let mut v = header.as_bytes().to_vec();
    for w in words {
        v.extend_from_slice(&w.to_le_bytes());
    }
    v
}

// EVT 3.0 words.
pub fn evt3(kind: u16, payload: u16) -> u16 {
    (kind << 12) | (payload & 0xFFF)
}
pub fn evt3_file(header: &str, words: &[u16]) -> Vec<u8> {
    let mut v = header.as_bytes().to_vec();
    for w in words {
        v.extend_from_slice(&w.to_le_bytes());
    }
    v
}

// DAT records.
pub fn dat_record(t_us: u32, x: u32, y: u32, p: u32) -> [u8; 8] {
    let w = x | (y << 14) | (p << 28);
    let mut r = [0u8; 8];
    r[..4].copy_from_slice(&t_us.to_le_bytes());
    r[4..].copy_from_slice(&w.to_le_bytes());
    r
}
pub fn dat_file(header: &str, records: &[[u8; 8]]) -> Vec<u8> {
    let mut v = header.as_bytes().to_vec();
    v.extend_from_slice(&[0x0C, 0x08]);
    for r in records {
        v.extend_from_slice(r);
    }
    v
}

pub const EVT2_HEADER: &str = "% evt 2.0\n% format EVT2;height=480;width=640\n% end\n";
pub const EVT3_HEADER: &str = "% evt 3.0\n% format EVT3;height=480;width=640\n% end\n";
pub const DAT_HEADER: &str =
    "% Data file containing CD events\n% Version 2\n% Width 640\n% Height 480\n";
