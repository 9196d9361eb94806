//! Writers and readers against each other, on random data: what is written is read back.
// Test code: a panic is how a failure is reported.
#![allow(clippy::unwrap_used)]

mod common;

use common::*;
use neuspike_formats::EventWriter;
use neuspike_formats::dat::{DatReader, DatWriter};
use neuspike_formats::evt3::CLOCK_PERIOD_US;
use neuspike_formats::pku::{PkuGeometry, PkuOptions, PkuReader, PkuWriter};
use neuspike_formats::raw::{Evt2Writer, Evt3Writer, RawReader};
use neuspike_formats::text::{TextReader, TextWriter};
use neuspike_formats::{Event, EventBatch, EventReader, ReadOptions, ReadStats, Resolution};
use proptest::prelude::*;

/// Sorted events on a `w x h` sensor, the first at `t0_us`, then with gaps drawn from `gap_us`.
fn events_strategy(
    w: u16,
    h: u16,
    t0_us: std::ops::Range<u64>,
    gap_us: impl Strategy<Value = u64>,
) -> impl Strategy<Value = Vec<Event>> {
    (
        t0_us,
        prop::collection::vec((gap_us, 0..w, 0..h, any::<bool>()), 0..300),
    )
        .prop_map(|(t0, evs)| {
            let mut t = t0;
            evs.into_iter()
                .map(|(gap, x, y, on)| {
                    let e = Event {
                        t_ns: (t * 1000) as i64,
                        x,
                        y,
                        polarity: if on { 1 } else { -1 },
                    };
                    t += gap;
                    e
                })
                .collect()
        })
}

fn batch(events: &[Event], r: Resolution) -> EventBatch {
    let mut b = EventBatch::empty(r.width.into(), r.height.into(), 0, 0, 0);
    for e in events {
        b.push(*e);
    }
    b
}

/// Reads everything in chunks of `n`, failing on any error.
fn read_in_chunks(r: &mut dyn EventReader, n: usize) -> Vec<Event> {
    let (got, e) = drain(r, n);
    if let Some(e) = e {
        panic!("{e}");
    }
    got
}

/// The reader's statistics agree with a plain count over the events it delivered.
fn assert_stats_match(s: &ReadStats, got: &[Event]) {
    assert_eq!(s.events, got.len() as u64, "events");
    let on = got.iter().filter(|e| e.polarity > 0).count() as u64;
    assert_eq!(s.on_events, on, "on_events");
    assert_eq!(s.max_x, got.iter().map(|e| e.x).max().unwrap_or(0), "max_x");
    assert_eq!(s.max_y, got.iter().map(|e| e.y).max().unwrap_or(0), "max_y");
    assert_eq!(s.first_t_ns, got.first().map(|e| e.t_ns), "first_t_ns");
    assert_eq!(s.last_t_ns, got.last().map(|e| e.t_ns), "last_t_ns");
    let dups = got.windows(2).filter(|p| p[0] == p[1]).count() as u64;
    assert_eq!(s.duplicate_events, dups, "duplicate_events");
}

/// Gaps: mostly small, some of 0 (equal times), some up to `long` (exclusive), long enough to
/// wrap the clocks.
fn gaps(long: u64) -> impl Strategy<Value = u64> {
    prop_oneof![8 => 0u64..3, 4 => 0u64..200, 1 => 0u64..long]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, failure_persistence: None, ..ProptestConfig::default() })]

    /// The file starts inside the first period of the 34-bit clock (later wraps are undone).
    #[test]
    fn evt2_round_trip(
        evs in events_strategy(640, 480, 0..(1u64 << 34), 0u64..4),
        long in prop::collection::vec(gaps(1 << 35), 300),
        n in 1usize..500,
    ) {
        // Spread the events with the long gaps too, then repeat every seventh (duplicates).
        let mut evs = evs;
        let mut shift = 0i64;
        for (e, g) in evs.iter_mut().zip(&long) {
            e.t_ns += shift;
            shift += *g as i64 * 1000;
        }
        let evs: Vec<Event> = evs
            .into_iter()
            .enumerate()
            .flat_map(|(i, e)| std::iter::repeat_n(e, 1 + usize::from(i % 7 == 3)))
            .collect();
        let r = Resolution::new(640, 480);
        let mut w = Evt2Writer::new(Vec::new(), "mem", r).unwrap();
        w.write_batch(&batch(&evs, r)).unwrap();
        let (bytes, s) = w.finish().unwrap();
        prop_assert_eq!(s.items, evs.len() as u64);
        prop_assert_eq!(s.bytes, bytes.len() as u64);
        let mut reader = RawReader::from_reader(&bytes[..], "mem", &ReadOptions::default()).unwrap();
        let got = read_in_chunks(&mut reader, n);
        assert_stats_match(reader.stats(), &got);
        assert_same_events(&got, &evs);
    }

    #[test]
    fn evt3_round_trip_modulo_the_24_bit_clock(
        evs in events_strategy(1280, 720, 0..(1u64 << 30), gaps(1 << 27)),
        runs in prop::collection::vec((0u16..1280, prop::collection::vec(1usize..15, 1..40)), 0..20),
        full_groups in any::<bool>(),
        n in 1usize..64,
    ) {
        // Add runs of neighbours at one time and row, which the writer vectorises: columns
        // from dense to 14 apart, so vectors start, go on and stop.
        let mut evs = evs;
        for (x0, steps) in runs {
            if let Some(&e) = evs.last() {
                let mut x = usize::from(x0);
                for step in steps {
                    if x < 1280 {
                        evs.push(Event { x: x as u16, ..e });
                    }
                    x += step;
                }
            }
        }
        let r = Resolution::new(1280, 720);
        let mut w = Evt3Writer::new(Vec::new(), "mem", r).unwrap();
        if full_groups {
            w = w.with_full_vector_groups();
        }
        w.write_batch(&batch(&evs, r)).unwrap();
        let (bytes, s) = w.finish().unwrap();
        prop_assert_eq!(s.items, evs.len() as u64);
        // Never more words than one `EVT_ADDR_X` per event.
        let mut singles = Evt3Writer::new(Vec::new(), "mem", r).unwrap();
        for e in &evs {
            singles.write_event(e).unwrap();
        }
        let singles = singles.finish().unwrap().0;
        prop_assert!(full_groups || bytes.len() <= singles.len(), "{} > {}", bytes.len(), singles.len());
        let mut reader = RawReader::from_reader(&bytes[..], "mem", &ReadOptions::default()).unwrap();
        let got = read_in_chunks(&mut reader, n);
        assert_stats_match(reader.stats(), &got);
        let period_ns = (CLOCK_PERIOD_US * 1000) as i64;
        let shift = evs.first().map_or(0, |e| e.t_ns / period_ns * period_ns);
        let want: Vec<Event> = evs.iter().map(|e| Event { t_ns: e.t_ns - shift, ..*e }).collect();
        assert_same_events(&got, &want);
    }

    /// The file starts inside the first period of the 32-bit clock (later wraps are undone).
    #[test]
    fn dat_round_trip(
        evs in events_strategy(16384, 300, 0..(1u64 << 32), gaps(1 << 31)),
        n in 1usize..500,
    ) {
        let r = Resolution::new(16384, 300);
        let mut w = DatWriter::new(Vec::new(), "mem", r).unwrap();
        w.write_batch(&batch(&evs, r)).unwrap();
        let (bytes, _) = w.finish().unwrap();
        let mut reader = DatReader::from_reader(&bytes[..], "mem", &ReadOptions::default()).unwrap();
        prop_assert_eq!(reader.resolution(), r);
        assert_same_events(&read_in_chunks(&mut reader, n), &evs);
    }

    #[test]
    fn text_round_trip_keeps_nanoseconds(
        evs in events_strategy(346, 260, 0..(1u64 << 40), 0u64..1000),
        ns in prop::collection::vec(0i64..1000, 300),
        n in 1usize..500,
    ) {
        let mut evs = evs;
        for (e, d) in evs.iter_mut().zip(&ns) {
            e.t_ns += d;
        }
        evs.sort_by_key(|e| e.t_ns);
        let r = Resolution::new(346, 260);
        let mut w = TextWriter::new(Vec::new(), "mem", r, true).unwrap();
        w.write_batch(&batch(&evs, r)).unwrap();
        let (bytes, _) = w.finish().unwrap();
        let mut reader = TextReader::from_reader(&bytes[..], "mem", &ReadOptions::default()).unwrap();
        assert_same_events(&read_in_chunks(&mut reader, n), &evs);
    }

    #[test]
    fn pku_file_round_trips_byte_exact(
        w8 in 1usize..8, h in 1usize..12, planes in 1usize..6, head in any::<bool>(),
        seed in any::<u64>(), n in 1usize..4,
    ) {
        // Byte-aligned rows (as the real 400- and 416-pixel rows are) and zero head columns
        // keep every stored bit, so file -> read -> write is byte-exact.
        let g = if head { PkuGeometry::with_head(8 * w8, h) } else { PkuGeometry::new(8 * w8, h) };
        let mut s = seed | 1;
        let mut stored: Vec<u8> = (0..planes * g.stored_plane_bytes()).map(|_| {
            s ^= s << 13; s ^= s >> 7; s ^= s << 17; s as u8
        }).collect();
        if head {
            let rb = g.stored_width() / 8;
            for row in stored.chunks_exact_mut(rb) {
                row[rb - 2..].fill(0);
            }
        }
        let opts = PkuOptions { geometry: g, ..PkuOptions::default() };
        let mut reader = PkuReader::from_reader(&stored[..], "mem", &opts).unwrap();
        let mut writer = PkuWriter::new(Vec::new(), "mem", g).unwrap();
        let mut count = 0;
        while let Some(c) = reader.next_chunk(n).unwrap() {
            prop_assert_eq!(c.first_plane, count as u64);
            count += c.n_planes;
            writer.write_chunk(&c).unwrap();
        }
        prop_assert_eq!(count, planes);
        let (bytes, _) = writer.finish().unwrap();
        prop_assert_eq!(bytes, stored);
    }
}

#[test]
fn evt3_writer_vectorises_runs() {
    let r = Resolution::new(640, 480);
    let row: Vec<Event> = (0..32)
        .map(|x| Event {
            t_ns: 5_000,
            x: 100 + x,
            y: 7,
            polarity: 1,
        })
        .collect();
    // Words after the header, and the events read back.
    let write = |events: &[Event], full_groups: bool| {
        let mut w = Evt3Writer::new(Vec::new(), "mem", r).unwrap();
        if full_groups {
            w = w.with_full_vector_groups();
        }
        w.write_batch(&batch(events, r)).unwrap();
        let (bytes, s) = w.finish().unwrap();
        assert_eq!(s.items, events.len() as u64);
        let header = bytes.iter().rposition(|&b| b == b'\n').unwrap() + 1;
        // The type of each word: the top 4 bits of its second (little-endian) byte.
        let words: Vec<u8> = bytes[header..].chunks_exact(2).map(|w| w[1] >> 4).collect();
        let got = drain(
            &mut RawReader::from_reader(&bytes[..], "mem", &ReadOptions::default()).unwrap(),
            5,
        )
        .0;
        assert_same_events(&got, events);
        words
    };
    // TIME_HIGH, TIME_LOW, ADDR_Y, then one VECT_BASE_X + VECT_12 + VECT_12 + VECT_8 group,
    // either way.
    for full_groups in [false, true] {
        assert_eq!(
            write(&row, full_groups),
            [8, 6, 0, 3, 4, 4, 5],
            "{full_groups}"
        );
    }
    // Two events 31 columns apart: two EVT_ADDR_X words, or a whole group of four.
    let at = |xs: &[u16]| -> Vec<Event> { xs.iter().map(|&x| Event { x, ..row[0] }).collect() };
    let pair = at(&[100, 131]);
    assert_eq!(write(&pair, false), [8, 6, 0, 2, 2]);
    assert_eq!(write(&pair, true), [8, 6, 0, 3, 4, 4, 5]);
    // Three within 12 columns start a vector (100: a VECT_12 for 100, 103, 107 and 109), a
    // stretch of 12 columns with two events goes on with it (112: 119 and 121), one with fewer
    // stops it; 140 is alone; 200, 201 and 202 are a vector again, a VECT_8 as they lie within 8.
    let spread = at(&[100, 103, 107, 109, 119, 121, 140, 200, 201, 202]);
    assert_eq!(write(&spread, false), [8, 6, 0, 3, 4, 4, 2, 3, 5]);
    assert_eq!(write(&spread, true), [8, 6, 0, 3, 4, 4, 5, 2, 3, 4, 4, 5]);
}

#[test]
fn writers_floor_to_microseconds_and_count() {
    let r = Resolution::new(10, 10);
    let e = Event {
        t_ns: 1_999,
        x: 1,
        y: 1,
        polarity: 1,
    };
    let mut w = Evt2Writer::new(Vec::new(), "mem", r).unwrap();
    w.write_event(&e).unwrap();
    let (bytes, s) = w.finish().unwrap();
    assert_eq!(s.floored_timestamps, 1);
    let got = drain(
        &mut RawReader::from_reader(&bytes[..], "mem", &ReadOptions::default()).unwrap(),
        5,
    )
    .0;
    assert_eq!(got[0].t_ns, 1_000);
}

#[test]
fn writers_refuse_what_their_format_cannot_hold() {
    let r = Resolution::new(10, 10);
    let ok = Event {
        t_ns: 5_000,
        x: 1,
        y: 1,
        polarity: 1,
    };
    let cases: [(Event, &str); 4] = [
        (Event { x: 10, ..ok }, "outside the 10x10 sensor"),
        (Event { polarity: 0, ..ok }, "polarity 0"),
        (Event { t_ns: -1, ..ok }, "negative"),
        (Event { t_ns: 4_000, ..ok }, "earlier"),
    ];
    for (bad, needle) in cases {
        let mut w = Evt2Writer::new(Vec::new(), "out.raw", r).unwrap();
        w.write_event(&ok).unwrap();
        let e = w.write_event(&bad).unwrap_err().to_string();
        assert!(
            e.starts_with("out.raw: cannot write event 1: ") && e.contains(needle),
            "{e}"
        );
        let mut w = TextWriter::new(Vec::new(), "out.txt", r, false).unwrap();
        w.write_event(&ok).unwrap();
        let e = w.write_event(&bad).unwrap_err().to_string();
        assert!(e.starts_with("out.txt: cannot write event 1: "), "{e}");
    }
    assert!(Evt3Writer::new(Vec::new(), "big", Resolution::new(4096, 10)).is_err());
    let mut w = DatWriter::new(Vec::new(), "out.dat", r).unwrap();
    w.write_event(&ok).unwrap();
    let e = w
        .write_event(&Event {
            t_ns: ok.t_ns + (1i64 << 31) * 1000,
            ..ok
        })
        .unwrap_err()
        .to_string();
    assert!(e.contains("too long for a 32-bit clock"), "{e}");
}

#[test]
fn evt3_writer_names_the_event_outside_the_sensor_inside_a_vector() {
    let r = Resolution::new(20, 10);
    // One run: a vector of 0, 1, 2 and then of 13, 14 and 20, the sixth event (index 5).
    let mut b = EventBatch::empty(20, 10, 0, 0, 0);
    for x in [0, 1, 2, 13, 14, 20] {
        b.push(Event {
            t_ns: 7_000,
            x,
            y: 3,
            polarity: -1,
        });
    }
    for full_groups in [false, true] {
        let mut w = Evt3Writer::new(Vec::new(), "out.raw", r).unwrap();
        if full_groups {
            w = w.with_full_vector_groups();
        }
        let e = w.write_batch(&b).unwrap_err().to_string();
        assert!(
            e.starts_with("out.raw: cannot write event 5: ") && e.contains("(20, 3) is outside"),
            "{full_groups}: {e}"
        );
    }
}

/// An `evt3` event packet (the words without a file header) decodes on its own to the events,
/// once a reader is given the header it lacks.
#[test]
fn an_evt3_packet_holds_its_events_without_the_file_header() {
    let r = Resolution::new(346, 260);
    let evs: Vec<Event> = (0..50)
        .map(|i| Event {
            t_ns: 1_000_000 + 7_000 * i,
            x: (i * 7 % 346) as u16,
            y: (i * 3 % 260) as u16,
            polarity: if i % 3 == 0 { -1 } else { 1 },
        })
        .collect();
    let words = neuspike_formats::evt3::packet_words(&batch(&evs, r), r).unwrap();
    assert!(!words.starts_with(b"%"), "no header in a packet");
    let mut file = Evt3Writer::new(Vec::new(), "mem", r).unwrap();
    file.write_batch(&batch(&[], r)).unwrap();
    let mut bytes = file.finish().unwrap().0;
    bytes.extend_from_slice(&words);
    let mut reader = RawReader::from_reader(&bytes[..], "mem", &ReadOptions::default()).unwrap();
    let got = read_in_chunks(&mut reader, 16);
    assert_eq!(got.len(), evs.len());
    assert_same_events(&got, &evs);
}
