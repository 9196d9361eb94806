//! Read throughput of each format, from memory, with a plain copy of the same bytes as the
//! baseline in the same group (so the figure to read is the ratio). Uses the shared real
//! recordings when present, otherwise files made by our writers.
//!
//! `cargo bench -p neuspike-formats --bench bench_read -- --warm-up-time 1 --measurement-time 3`
//!
//! `NEUSPIKE_BENCH_DUMP=DIR` also writes the AEDAT 4 files it reads there, for
//! `benches/aedat4_dv_processing.py` (iniVation's reader on the same bytes).

use neuspike_formats::EventWriter;
use std::hint::black_box;
use std::path::PathBuf;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use neuspike_formats::aedat4::{Aedat4Reader, Aedat4Writer, Compression};
use neuspike_formats::dat::{DatReader, DatWriter};
use neuspike_formats::pku::{PkuOptions, PkuReader};
use neuspike_formats::raw::{Evt3Writer, RawReader};
use neuspike_formats::text::TextReader;
use neuspike_formats::{Event, EventBatch, EventReader, ReadOptions, Resolution, read_all};

const REAL_DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/real");

fn real(name: &str) -> Option<Vec<u8>> {
    let p = PathBuf::from(REAL_DIR).join(name);
    match std::fs::read(&p) {
        Ok(b) => Some(b),
        Err(_) => {
            eprintln!(
                "NOTICE: {} not found; benchmarking synthetic data",
                p.display()
            );
            None
        }
    }
}

fn synthetic_events(n: usize) -> EventBatch {
    let mut b = EventBatch::empty(640, 480, 0, 0, 0);
    let mut s = 0x2545_F491_4F6C_DD1Du64;
    let mut t = 0i64;
    for _ in 0..n {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        t += (s % 3) as i64 * 1000;
        b.push(Event {
            t_ns: t,
            x: ((s >> 8) % 640) as u16,
            y: ((s >> 24) % 480) as u16,
            polarity: if s & 1 == 1 { 1 } else { -1 },
        });
    }
    b
}

fn text_of(b: &EventBatch) -> Vec<u8> {
    let mut w =
        neuspike_formats::text::TextWriter::new(Vec::new(), "mem", Resolution::new(640, 480), true)
            .expect("writer");
    w.write_batch(b).expect("write");
    w.finish().expect("finish").0
}

fn evt2_of(b: &EventBatch) -> Vec<u8> {
    let mut w =
        neuspike_formats::raw::Evt2Writer::new(Vec::new(), "mem", Resolution::new(640, 480))
            .expect("writer");
    w.write_batch(b).expect("write");
    w.finish().expect("finish").0
}

/// Decodes `bytes` with `open` in chunks of `chunk` events; returns the count.
fn drain(mut r: impl EventReader, chunk: usize) -> usize {
    let mut b = EventBatch::default();
    let mut n = 0;
    loop {
        b.t_ns.clear();
        b.x.clear();
        b.y.clear();
        b.polarity.clear();
        match r.read_into(&mut b, chunk) {
            Ok(0) => return n,
            Ok(k) => n += k,
            Err(e) => panic!("{e}"),
        }
    }
}

fn event_group<F>(c: &mut Criterion, name: &str, bytes: &[u8], events: u64, open: F)
where
    F: Fn(&[u8], usize) -> usize,
{
    let mut g = c.benchmark_group(name);
    g.throughput(Throughput::Elements(events));
    let mut dst = vec![0u8; bytes.len()];
    g.bench_function("copy_bytes", |bch| {
        bch.iter(|| {
            dst.copy_from_slice(black_box(bytes));
            black_box(&dst);
        })
    });
    for chunk in [1024usize, 65_536] {
        g.bench_with_input(BenchmarkId::new("decode", chunk), &chunk, |bch, &chunk| {
            bch.iter(|| assert_eq!(open(black_box(bytes), chunk) as u64, events))
        });
    }
    g.finish();
}

fn bench_read(c: &mut Criterion) {
    let opts640 = ReadOptions::with_resolution(640, 480);

    // PKU spike planes: throughput in planes.
    let pku = real("vidar-car-400x250.dat").unwrap_or_else(|| {
        (0..200 * 12_500u32)
            .map(|i| (i.wrapping_mul(2_654_435_761) >> 11) as u8)
            .collect()
    });
    let planes = (pku.len() / 12_500) as u64;
    let mut g = c.benchmark_group("pku_planes");
    g.throughput(Throughput::Elements(planes));
    let mut dst = vec![0u8; pku.len()];
    g.bench_function("copy_bytes", |b| {
        b.iter(|| {
            dst.copy_from_slice(black_box(&pku));
            black_box(&dst);
        })
    });
    for chunk in [1usize, 32] {
        g.bench_with_input(BenchmarkId::new("decode", chunk), &chunk, |b, &chunk| {
            b.iter(|| {
                let mut r =
                    PkuReader::from_reader(black_box(&pku[..]), "mem", &PkuOptions::default())
                        .expect("reader");
                let mut n = 0;
                while let Some(c) = r.next_chunk(chunk).expect("chunk") {
                    n += c.n_planes as u64;
                }
                assert_eq!(n, planes);
            })
        });
    }
    g.finish();

    // Event formats: throughput in events.
    let (evt2, evt2_events) = match real("prophesee-evt2-640x480.raw") {
        Some(b) => (b, 521_252u64),
        None => {
            let b = synthetic_events(500_000);
            (evt2_of(&b), b.len() as u64)
        }
    };
    let events = read_all(&mut RawReader::from_reader(&evt2[..], "mem", &opts640).expect("raw"))
        .expect("events");
    event_group(c, "evt2_events", &evt2, evt2_events, |b, chunk| {
        drain(
            RawReader::from_reader(b, "mem", &opts640).expect("raw"),
            chunk,
        )
    });

    // The same events in EVT 3.0 as our writer encodes them, and with a whole 32-column vector
    // group for every run of two or more (a stream heavy with vectors).
    for (name, full_groups) in [("evt3_events", false), ("evt3_groups_events", true)] {
        let mut w = Evt3Writer::new(Vec::new(), "mem", Resolution::new(640, 480)).expect("writer");
        if full_groups {
            w = w.with_full_vector_groups();
        }
        w.write_batch(&events).expect("write");
        let evt3 = w.finish().expect("finish").0;
        event_group(c, name, &evt3, events.len() as u64, |b, chunk| {
            drain(
                RawReader::from_reader(b, "mem", &opts640).expect("raw"),
                chunk,
            )
        });
    }

    let mut w = DatWriter::new(Vec::new(), "mem", Resolution::new(640, 480)).expect("writer");
    w.write_batch(&events).expect("write");
    let dat = w.finish().expect("finish").0;
    event_group(c, "dat_events", &dat, events.len() as u64, |b, chunk| {
        drain(
            DatReader::from_reader(b, "mem", &opts640).expect("dat"),
            chunk,
        )
    });

    // AEDAT 4 of the same events, as our writer makes it: uncompressed and LZ4 (dv-processing's
    // streaming read of the same files is the comparison: `aedat4_dv_processing.py`).
    for (name, compression) in [
        ("aedat4_none_events", Compression::None),
        ("aedat4_lz4_events", Compression::Lz4),
    ] {
        let mut w = Aedat4Writer::new(Vec::new(), "mem", Resolution::new(640, 480), compression)
            .expect("writer");
        w.write_batch(&events).expect("write");
        let bytes = w.finish().expect("finish").0;
        if let Ok(dir) = std::env::var("NEUSPIKE_BENCH_DUMP") {
            let path = PathBuf::from(dir).join(format!("{name}.aedat4"));
            std::fs::write(&path, &bytes).expect("dump");
        }
        event_group(c, name, &bytes, events.len() as u64, |b, chunk| {
            drain(
                Aedat4Reader::from_reader(b, "mem", &ReadOptions::default()).expect("aedat4"),
                chunk,
            )
        });
    }

    let (text, text_events, text_opts) = match real("davis240c-shapes-rotation-events.txt") {
        Some(b) => (b, 20_000u64, ReadOptions::with_resolution(240, 180)),
        None => (
            text_of(&events),
            events.len() as u64,
            ReadOptions::default(),
        ),
    };
    event_group(c, "text_events", &text, text_events, |b, chunk| {
        drain(
            TextReader::from_reader(b, "mem", &text_opts).expect("text"),
            chunk,
        )
    });
}

criterion_group!(benches, bench_read);
criterion_main!(benches);
