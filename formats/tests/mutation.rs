//! Randomly damaged bytes of real recordings (or, without the shared folder, of files our writers
//! make) fed to every decoder and to the sniffer. Whatever the damage: no panic, and every event
//! that is delivered is inside the sensor, has polarity ±1 and is in time order, so a bad file
//! can stop a reader but never hand out a wrong image.
// Test code: a panic is how a failure is reported.
#![allow(clippy::unwrap_used)]

mod common;

use neuspike_formats::EventWriter;
use std::path::Path;
use std::sync::OnceLock;

use common::*;
use neuspike_formats::aedat4::{Aedat4Frames, Aedat4Reader, Aedat4Writer, Compression};
use neuspike_formats::dat::{DatReader, DatWriter};
use neuspike_formats::header::read_header;
use neuspike_formats::pku::{PkuGeometry, PkuOptions, PkuReader};
use neuspike_formats::raw::{Evt2Writer, Evt3Writer, RawReader};
use neuspike_formats::sniff::sniff_bytes;
use neuspike_formats::text::TextReader;
use neuspike_formats::{
    Disorder, Event, EventBatch, EventReader, ReadOptions, Resolution, UnknownWords, drain_checked,
};
use proptest::prelude::*;

/// Bytes of each format kept from a real file (its first part) or made by our writers.
struct Samples {
    pku: Vec<u8>,
    text: Vec<u8>,
    evt2: Vec<u8>,
    evt3: Vec<u8>,
    dat: Vec<u8>,
    /// Our writer's AEDAT 4, uncompressed and LZ4, and dv-processing's (Zstd) fixture.
    aedat: [Vec<u8>; 3],
}

const SAMPLE_BYTES: usize = 48 * 1024;

fn synthetic_events() -> Vec<Event> {
    let mut s = 0x9E37_79B9_7F4A_7C15u64;
    let mut t = 1_000_000i64;
    (0..4000)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            t += (s % 5) as i64 * 1000;
            Event {
                t_ns: t,
                x: ((s >> 8) % 640) as u16,
                y: ((s >> 20) % 480) as u16,
                polarity: if s & 1 == 1 { 1 } else { -1 },
            }
        })
        .collect()
}

fn samples() -> &'static Samples {
    static S: OnceLock<Samples> = OnceLock::new();
    S.get_or_init(|| {
        let head = |name: &str| {
            real(name).map(|p| {
                let mut b = std::fs::read(p).unwrap();
                b.truncate(SAMPLE_BYTES);
                b
            })
        };
        let r = Resolution::new(640, 480);
        // Events to re-encode: the real EVT 2.0 recording's first part, or synthetic ones.
        let evs: Vec<Event> = match real(PROPHESEE_EVT2) {
            Some(p) => {
                let mut reader =
                    RawReader::open(p, &ReadOptions::with_resolution(640, 480)).unwrap();
                let mut b = EventBatch::default();
                reader.read_into(&mut b, 6000).unwrap();
                events(&b)
            }
            None => synthetic_events(),
        };
        let mut batch = EventBatch::empty(640, 480, 0, 0, 0);
        for e in &evs {
            batch.push(*e);
        }
        let mut w = Evt2Writer::new(Vec::new(), "s", r).unwrap();
        w.write_batch(&batch).unwrap();
        let evt2_made = w.finish().unwrap().0;
        let mut w = Evt3Writer::new(Vec::new(), "s", r).unwrap();
        w.write_batch(&batch).unwrap();
        let evt3 = w.finish().unwrap().0;
        let mut w = DatWriter::new(Vec::new(), "s", r).unwrap();
        w.write_batch(&batch).unwrap();
        let dat = w.finish().unwrap().0;
        let aedat = |c| {
            let mut w = Aedat4Writer::new(Vec::new(), "s", r, c).unwrap();
            w.write_batch(&batch).unwrap();
            w.finish().unwrap().0
        };
        let dv = std::fs::read(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/data/dv-zstd.aedat4"
        ))
        .unwrap();
        let text = head(DAVIS_TEXT).unwrap_or_else(|| {
            let mut s = String::from("640 480\n");
            for e in &evs {
                s.push_str(&format!(
                    "{}.{:09} {} {} {}\n",
                    e.t_ns / 1_000_000_000,
                    e.t_ns % 1_000_000_000,
                    e.x,
                    e.y,
                    u8::from(e.polarity > 0)
                ));
            }
            s.into_bytes()
        });
        Samples {
            pku: head(VIDAR)
                .map(|mut b| {
                    b.truncate(2 * 12_500 + 100);
                    b
                })
                .unwrap_or_else(|| {
                    (0..25_100u32)
                        .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
                        .collect()
                }),
            text,
            evt2: head(PROPHESEE_EVT2)
                .map(|mut b| {
                    // Cut at a word boundary.
                    let (h, _) = read_header(&mut &b[..], Path::new("s")).unwrap();
                    let off = h.data_offset as usize;
                    b.truncate(off + (b.len() - off) / 4 * 4);
                    b
                })
                .unwrap_or(evt2_made),
            evt3,
            dat,
            aedat: [aedat(Compression::None), aedat(Compression::Lz4), dv],
        }
    })
}

/// A way to damage bytes.
#[derive(Clone, Debug)]
enum Damage {
    /// Overwrite bytes at these (relative) positions.
    Flip(Vec<(f64, u8)>),
    /// Keep only the first fraction.
    Truncate(f64),
    /// Insert bytes at a (relative) position.
    Insert(f64, Vec<u8>),
    /// Delete a run of bytes.
    Delete(f64, usize),
}

fn damage() -> impl Strategy<Value = Vec<Damage>> {
    let one = prop_oneof![
        4 => prop::collection::vec((0.0f64..1.0, any::<u8>()), 1..12).prop_map(Damage::Flip),
        1 => (0.0f64..1.0).prop_map(Damage::Truncate),
        1 => (0.0f64..1.0, prop::collection::vec(any::<u8>(), 1..9)).prop_map(|(p, b)| Damage::Insert(p, b)),
        1 => (0.0f64..1.0, 1usize..9).prop_map(|(p, n)| Damage::Delete(p, n)),
    ];
    prop::collection::vec(one, 1..4)
}

/// Damage concentrated near the start (headers, first words) half the time.
fn apply(bytes: &[u8], damage: &[Damage], near_start: bool) -> Vec<u8> {
    let mut b = bytes.to_vec();
    let span = |b: &Vec<u8>| {
        if near_start {
            b.len().min(256)
        } else {
            b.len()
        }
    };
    for d in damage {
        let at = |p: f64, b: &Vec<u8>| ((p * span(b) as f64) as usize).min(b.len());
        match d {
            Damage::Flip(v) => {
                for &(p, val) in v {
                    let i = at(p, &b);
                    if i < b.len() {
                        b[i] = val;
                    }
                }
            }
            Damage::Truncate(p) => {
                let n = (p * b.len() as f64) as usize;
                b.truncate(n);
            }
            Damage::Insert(p, ins) => {
                let i = at(*p, &b);
                b.splice(i..i, ins.iter().copied());
            }
            Damage::Delete(p, n) => {
                let i = at(*p, &b);
                let j = (i + n).min(b.len());
                b.drain(i..j);
            }
        }
    }
    b
}

fn options(disorder: bool, skip: bool) -> ReadOptions {
    ReadOptions {
        resolution: None,
        disorder: if disorder {
            Disorder::Clamp
        } else {
            Disorder::Error
        },
        unknown_words: if skip {
            UnknownWords::Skip
        } else {
            UnknownWords::Error
        },
        allow_unknown_size: false,
        ..ReadOptions::default()
    }
}

/// Drains a reader, checking every delivered event; returns how many were delivered and whether
/// it ended in an error.
fn check(reader: &mut dyn EventReader, n: usize) -> (u64, bool) {
    let d = drain_checked(reader, n).unwrap_or_else(|bug| panic!("{bug}"));
    if let Some(e) = &d.error {
        let _ = e.to_string();
    }
    (d.events, d.error.is_some())
}

/// Every event decoder on the same bytes (each format's bytes are also fed to the others).
fn every_decoder(bytes: &[u8], opts: &ReadOptions, n: usize) {
    let name = Path::new("damaged");
    let _ = sniff_bytes(bytes, bytes.len() as u64, name);
    let sized = ReadOptions {
        resolution: Some(Resolution::new(640, 480)),
        ..opts.clone()
    };
    for o in [opts, &sized] {
        if let Ok(mut r) = RawReader::from_reader(bytes, name, o) {
            check(&mut r, n);
        }
        if let Ok(mut r) = DatReader::from_reader(bytes, name, o) {
            check(&mut r, n);
        }
        if let Ok(mut r) = TextReader::from_reader(bytes, name, o) {
            check(&mut r, n);
        }
        if let Ok(mut r) = Aedat4Reader::from_reader(bytes, name, o) {
            check(&mut r, n);
        }
    }
    if let Ok(frames) = Aedat4Frames::from_reader(bytes, name) {
        for f in frames {
            match f {
                Ok(f) => assert_eq!(
                    f.pixels.len(),
                    usize::from(f.width) * usize::from(f.height) * f.format.bytes_per_pixel()
                ),
                Err(e) => {
                    let _ = e.to_string();
                }
            }
        }
    }
    let davis = ReadOptions {
        resolution: Some(Resolution::new(240, 180)),
        ..opts.clone()
    };
    if let Ok(mut r) = TextReader::from_reader(bytes, name, &davis) {
        check(&mut r, n);
    }
}

fn spike_decoder(bytes: &[u8], g: PkuGeometry, n: usize) {
    let opts = PkuOptions {
        geometry: g,
        ..PkuOptions::default()
    };
    let mut r = PkuReader::from_reader(bytes, "damaged", &opts).unwrap();
    let mut planes = 0;
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
                assert!(r.next_chunk(n).unwrap().is_none());
                break;
            }
        }
    }
    assert_eq!(planes, (bytes.len() / g.stored_plane_bytes()) as u64);
}

#[test]
fn undamaged_samples_decode_whole() {
    let s = samples();
    let sized = ReadOptions::with_resolution(640, 480);
    let (n, err) = check(
        &mut RawReader::from_reader(&s.evt2[..], "evt2", &sized).unwrap(),
        777,
    );
    assert!(n > 1000 && !err, "{n} {err}");
    let (n, err) = check(
        &mut RawReader::from_reader(&s.evt3[..], "evt3", &sized).unwrap(),
        777,
    );
    assert!(n > 1000 && !err, "{n} {err}");
    let (n, err) = check(
        &mut DatReader::from_reader(&s.dat[..], "dat", &sized).unwrap(),
        777,
    );
    assert!(n > 1000 && !err, "{n} {err}");
    for (i, a) in s.aedat.iter().enumerate() {
        let (n, err) = check(
            &mut Aedat4Reader::from_reader(&a[..], "aedat4", &ReadOptions::default()).unwrap(),
            777,
        );
        assert!(n >= 3000 && !err, "aedat {i}: {n} {err}");
    }
    let davis = ReadOptions::with_resolution(240, 180);
    let text = TextReader::from_reader(&s.text[..], "text", &davis)
        .or_else(|_| TextReader::from_reader(&s.text[..], "text", &ReadOptions::default()));
    // A real sample may end mid-line; everything before is delivered.
    let (n, _) = check(&mut text.unwrap(), 777);
    assert!(n > 1000, "{n}");
}

proptest! {
    // PROPTEST_CASES=5000 for a longer hunt.
    #![proptest_config(ProptestConfig {
        cases: std::env::var("PROPTEST_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(48),
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    #[test]
    fn damaged_evt2_never_panics(d in damage(), near in any::<bool>(), c in any::<bool>(), s in any::<bool>(), n in 1usize..5000) {
        every_decoder(&apply(&samples().evt2, &d, near), &options(c, s), n);
    }

    #[test]
    fn damaged_evt3_never_panics(d in damage(), near in any::<bool>(), c in any::<bool>(), s in any::<bool>(), n in 1usize..5000) {
        every_decoder(&apply(&samples().evt3, &d, near), &options(c, s), n);
    }

    #[test]
    fn damaged_dat_never_panics(d in damage(), near in any::<bool>(), c in any::<bool>(), s in any::<bool>(), n in 1usize..5000) {
        every_decoder(&apply(&samples().dat, &d, near), &options(c, s), n);
    }

    #[test]
    fn damaged_aedat4_never_panics(d in damage(), near in any::<bool>(), which in 0usize..3, c in any::<bool>(), n in 1usize..5000) {
        every_decoder(&apply(&samples().aedat[which], &d, near), &options(c, false), n);
    }

    #[test]
    fn damaged_text_never_panics(d in damage(), near in any::<bool>(), c in any::<bool>(), n in 1usize..5000) {
        every_decoder(&apply(&samples().text, &d, near), &options(c, false), n);
    }

    #[test]
    fn damaged_spikes_never_panic(d in damage(), near in any::<bool>(), n in 1usize..4, head in any::<bool>()) {
        let bytes = apply(&samples().pku, &d, near);
        let g = if head { PkuGeometry::with_head(400, 250) } else { PkuGeometry::new(400, 250) };
        spike_decoder(&bytes, g, n);
        spike_decoder(&bytes, PkuGeometry::new(13, 7), n);
        every_decoder(&bytes, &options(true, true), 1000);
    }

    #[test]
    fn random_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..2000), prefix in 0usize..5, n in 1usize..50) {
        // Random bytes behind each kind of header, so that the decoders' bodies are reached.
        let aedat = &samples().aedat[0];
        let aedat_head = &aedat[..aedat.len().min(18 + u32::from_le_bytes([aedat[14], aedat[15], aedat[16], aedat[17]]) as usize)];
        let heads: [&[u8]; 5] = [b"", EVT2_HEADER.as_bytes(), EVT3_HEADER.as_bytes(), b"% Width 64\n% Height 64\n\x0c\x08", aedat_head];
        let mut b = heads[prefix].to_vec();
        b.extend_from_slice(&bytes);
        every_decoder(&b, &options(true, true), n);
        every_decoder(&b, &options(false, false), n);
        spike_decoder(&b, PkuGeometry::new(8, 3), n);
    }
}
