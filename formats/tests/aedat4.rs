//! AEDAT 4: files written by iniVation's own dv-processing (LZ4 and Zstd) read with the facts its
//! reader gave (`tests/data/make_aedat4_fixtures.py`), our writer's files read back (events and
//! frames, both compressions), and one named test per kind of bad input.
// Test code: a panic is how a failure is reported.
#![allow(clippy::unwrap_used)]

mod common;

use std::path::PathBuf;

use common::*;
use neuspike_formats::aedat4::{
    Aedat4Frames, Aedat4Reader, Aedat4Writer, ApsFrame, Compression, EVENTS_PER_PACKET,
    FrameFormat, MAGIC,
};
use neuspike_formats::{
    Event, EventBatch, EventReader, EventWriter, Format, FormatError, ReadOptions, Resolution,
    open_events, sniff,
};
use proptest::prelude::*;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// `key -> values` of a `.facts` file.
fn facts(name: &str) -> Vec<(String, Vec<i64>)> {
    std::fs::read_to_string(fixture(name))
        .unwrap()
        .lines()
        .map(|l| {
            let mut f = l.split_whitespace();
            let key = f.next().unwrap().to_string();
            (key, f.map(|v| v.parse().unwrap()).collect())
        })
        .collect()
}

fn fact<'a>(f: &'a [(String, Vec<i64>)], key: &str) -> &'a [i64] {
    &f.iter().find(|(k, _)| k == key).unwrap().1
}

#[test]
fn files_written_by_dv_processing_read_as_its_reader_reads_them() {
    for name in ["dv-lz4", "dv-zstd"] {
        let path = fixture(&format!("{name}.aedat4"));
        let f = facts(&format!("{name}.facts"));
        assert_eq!(sniff(&path).unwrap(), Format::Aedat4);
        let mut r = open_events(&path, &ReadOptions::default()).unwrap();
        assert_eq!(r.resolution(), Resolution::new(346, 260));
        assert_eq!(fact(&f, "size"), [346, 260]);
        // Odd batch sizes: batches cross packets.
        let got = read_in(&mut *r, 777);
        assert_eq!(got.len() as i64, fact(&f, "events")[0], "{name}");
        let as_dv = |e: &Event| {
            [
                e.t_ns / 1000,
                e.x.into(),
                e.y.into(),
                (e.polarity > 0).into(),
            ]
        };
        assert_eq!(as_dv(&got[0]), fact(&f, "first"), "{name}");
        assert_eq!(as_dv(got.last().unwrap()), fact(&f, "last"), "{name}");
        let t0 = 1_600_000_000_000_000i64;
        let sums = [
            got.iter().map(|e| e.t_ns / 1000 - t0).sum::<i64>(),
            got.iter().map(|e| i64::from(e.x)).sum(),
            got.iter().map(|e| i64::from(e.y)).sum(),
        ];
        assert_eq!(sums, fact(&f, "sums"), "{name}");
        assert_eq!(
            got.iter().filter(|e| e.polarity > 0).count() as i64,
            fact(&f, "on")[0]
        );
        let s = r.stats();
        assert_eq!(s.events, got.len() as u64);
        // Three frame packets were skipped (not decompressed), and nothing else.
        assert_eq!(s.skipped_packets, 3, "{name}");

        let frames: Vec<ApsFrame> = Aedat4Frames::open(&path)
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap();
        let want: Vec<&Vec<i64>> = f
            .iter()
            .filter(|(k, _)| k == "frame")
            .map(|(_, v)| v)
            .collect();
        assert_eq!(frames.len(), want.len());
        // `info` reports them.
        let info =
            neuspike_formats::info::event_info(&path, Format::Aedat4, &ReadOptions::default())
                .unwrap();
        let aps = info.aps.clone().expect("APS frames");
        assert_eq!(aps.frames as usize, want.len());
        assert_eq!(
            (aps.width, aps.height, aps.format),
            (346, 260, FrameFormat::Gray)
        );
        assert_eq!(aps.first_t_ns, want[0][0] * 1000);
        assert_eq!(aps.last_t_ns, want[want.len() - 1][0] * 1000);
        let text = info.to_string();
        assert!(
            text.contains(&format!("{} APS frames, 346x260 grey", want.len())),
            "{text}"
        );
        for (fr, w) in frames.iter().zip(want) {
            assert_eq!(fr.t_ns, w[0] * 1000);
            assert_eq!(fr.pixels.iter().map(|&p| i64::from(p)).sum::<i64>(), w[1]);
            assert_eq!([i64::from(fr.width), i64::from(fr.height)], [w[2], w[3]]);
            assert_eq!(fr.format, FrameFormat::Gray);
            let lum = fr.luminance();
            assert_eq!(lum.len(), 346 * 260);
            assert!(lum.iter().all(|v| (0.0..=1.0).contains(v)));
        }
    }
}

fn read_in(r: &mut dyn EventReader, n: usize) -> Vec<Event> {
    let mut b = EventBatch::default();
    while r.read_into(&mut b, n).unwrap() > 0 {}
    events(&b)
}

fn frame(t_ns: i64, w: u16, h: u16, format: FrameFormat, seed: u8) -> ApsFrame {
    let n = usize::from(w) * usize::from(h) * format.bytes_per_pixel();
    ApsFrame {
        t_ns,
        exposure_begin_ns: t_ns - 1000,
        exposure_end_ns: t_ns + 1000,
        format,
        width: w,
        height: h,
        pixels: (0..n).map(|i| (i as u8).wrapping_mul(seed)).collect(),
    }
}

/// Events (whole µs), then frames interleaved after every `every` events.
fn write(evs: &[Event], frames: &[ApsFrame], r: Resolution, c: Compression) -> Vec<u8> {
    let mut w = Aedat4Writer::new(Vec::new(), "mem", r, c).unwrap();
    let every = evs.len() / frames.len().max(1) + 1;
    let mut fi = frames.iter();
    for (i, e) in evs.iter().enumerate() {
        if i % every == 0
            && let Some(f) = fi.next()
        {
            w.write_frame(f).unwrap();
        }
        w.write_event(e).unwrap();
    }
    for f in fi {
        w.write_frame(f).unwrap();
    }
    let (bytes, summary) = w.finish().unwrap();
    assert_eq!(summary.items, evs.len() as u64);
    assert_eq!(summary.bytes, bytes.len() as u64);
    bytes
}

fn events_strategy(r: Resolution) -> impl Strategy<Value = Vec<Event>> {
    prop::collection::vec(
        (0i64..3_000, 0..r.width, 0..r.height, any::<bool>()),
        0..(3 * EVENTS_PER_PACKET),
    )
    .prop_map(|v| {
        let mut t = 1_600_000_000_000_000_000i64;
        v.into_iter()
            .map(|(dt, x, y, on)| {
                t += dt * 1000;
                Event {
                    t_ns: t,
                    x,
                    y,
                    polarity: if on { 1 } else { -1 },
                }
            })
            .collect()
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn events_and_frames_round_trip(
        evs in events_strategy(Resolution::new(346, 260)),
        lz4 in any::<bool>(),
        n in 1usize..20_000,
        n_frames in 0usize..4,
    ) {
        let r = Resolution::new(346, 260);
        let c = if lz4 { Compression::Lz4 } else { Compression::None };
        let formats = [FrameFormat::Gray, FrameFormat::Gray16, FrameFormat::Bgr, FrameFormat::Bgra];
        let frames: Vec<ApsFrame> = (0..n_frames)
            .map(|i| frame(1_000_000 * (i as i64 + 1), 34, 26, formats[i], 3 + i as u8))
            .collect();
        let bytes = write(&evs, &frames, r, c);
        let mut reader = Aedat4Reader::from_reader(&bytes[..], "mem", &ReadOptions::default()).unwrap();
        prop_assert_eq!(reader.header().compression, c);
        let got = read_in(&mut reader, n);
        assert_same_events(&got, &evs);
        prop_assert_eq!(reader.stats().skipped_packets, n_frames as u64);
        let back: Vec<ApsFrame> = Aedat4Frames::from_reader(&bytes[..], "mem").unwrap().collect::<Result<_, _>>().unwrap();
        // Exposure times and the frame time go through whole µs.
        prop_assert_eq!(back, frames);
    }
}

#[test]
fn our_files_are_what_dv_processing_expects_on_disk() {
    // What dv-processing's reader checks, in our writer's output: the magic, the header's
    // identifier, every packet's size prefix and identifier, 8-aligned event structs.
    let evs: Vec<Event> = (0..10_000)
        .map(|i| Event {
            t_ns: 1000 * i,
            x: (i % 346) as u16,
            y: (i % 260) as u16,
            polarity: if i % 3 == 0 { -1 } else { 1 },
        })
        .collect();
    let bytes = write(
        &evs,
        &[frame(5_000_000, 346, 260, FrameFormat::Gray, 1)],
        Resolution::new(346, 260),
        Compression::None,
    );
    assert_eq!(&bytes[..14], MAGIC);
    let hlen = u32::from_le_bytes(bytes[14..18].try_into().unwrap()) as usize;
    assert_eq!(&bytes[22..26], b"IOHE");
    let mut at = 18 + hlen;
    let mut kinds = Vec::new();
    while at < bytes.len() {
        let stream = i32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
        let size = u32::from_le_bytes(bytes[at + 4..at + 8].try_into().unwrap()) as usize;
        let p = &bytes[at + 8..at + 8 + size];
        assert_eq!(
            u32::from_le_bytes(p[..4].try_into().unwrap()) as usize,
            size - 4
        );
        let kind = std::str::from_utf8(&p[8..12]).unwrap().to_string();
        if kind == "EVTS" {
            assert_eq!(stream, 0);
            // The vector's length at 28 (with the prefix), the structs from 32: 8-aligned.
            let n = u32::from_le_bytes(p[28..32].try_into().unwrap()) as usize;
            assert_eq!(size, 32 + 16 * n);
        } else {
            assert_eq!((stream, kind.as_str()), (1, "FRME"));
        }
        kinds.push(kind);
        at += 8 + size;
    }
    assert_eq!(at, bytes.len());
    // The frame (written first), 8,192 events, then the rest.
    assert_eq!(kinds, ["FRME", "EVTS", "EVTS"]);
}

// ---------------------------------------------------------------------------------------------
// Bad input
// ---------------------------------------------------------------------------------------------

fn sample(c: Compression) -> Vec<u8> {
    let evs: Vec<Event> = (0..100)
        .map(|i| Event {
            t_ns: 1_000 * i,
            x: (i % 30) as u16,
            y: (i % 20) as u16,
            polarity: 1,
        })
        .collect();
    write(&evs, &[], Resolution::new(30, 20), c)
}

fn read_err(bytes: &[u8]) -> (usize, FormatError) {
    let mut r = match Aedat4Reader::from_reader(bytes, "bad.aedat4", &ReadOptions::default()) {
        Ok(r) => r,
        Err(e) => return (0, e),
    };
    let mut b = EventBatch::default();
    loop {
        match r.read_into(&mut b, 7) {
            Ok(0) => panic!("no error after {} events", b.len()),
            Ok(_) => {}
            Err(e) => return (b.len(), e),
        }
    }
}

/// Offset of the first packet of our writer's files.
fn first_packet(bytes: &[u8]) -> usize {
    18 + u32::from_le_bytes(bytes[14..18].try_into().unwrap()) as usize
}

#[test]
fn empty_and_missing_files() {
    assert!(matches!(read_err(b"").1, FormatError::Empty { .. }));
    let e = Aedat4Reader::open("/nonexistent/x.aedat4", &ReadOptions::default())
        .err()
        .unwrap();
    assert!(e.to_string().contains("/nonexistent/x.aedat4"), "{e}");
}

#[test]
fn wrong_magic_names_what_was_found() {
    let mut b = sample(Compression::None);
    b[9] = b'5';
    let e = read_err(&b).1.to_string();
    assert!(e.contains("bad.aedat4") && e.contains("AER-DAT5"), "{e}");
}

#[test]
fn truncated_header_and_packets() {
    let b = sample(Compression::None);
    let e = read_err(&b[..30]).1.to_string();
    assert!(e.contains("truncated") && e.contains("IOHeader"), "{e}");
    // Cut inside the (only) packet: a packet is decoded whole or not at all.
    let p = first_packet(&b);
    let cut = p + 8 + 32 + 16 * 10;
    let (got, e) = read_err(&b[..cut]);
    assert_eq!(got, 0, "a packet is all or nothing");
    let e = e.to_string();
    assert!(
        e.contains("truncated") && e.contains(&format!("byte {p}")),
        "{e}"
    );
}

#[test]
fn unknown_compression_and_stream() {
    let mut b = sample(Compression::None);
    // compression at IOHeader offset 28 (file offset 18 + 28).
    b[46] = 9;
    let e = read_err(&b).1.to_string();
    assert!(e.contains("compression code 9"), "{e}");
    let mut b = sample(Compression::None);
    let p = first_packet(&b);
    b[p] = 7;
    let e = read_err(&b).1.to_string();
    assert!(
        e.contains(&format!("byte {p}")) && e.contains("stream 7") && e.contains("0 EVTS"),
        "{e}"
    );
}

#[test]
fn identifier_that_does_not_match_the_stream() {
    let mut b = sample(Compression::None);
    let p = first_packet(&b);
    b[p + 8 + 8..p + 8 + 12].copy_from_slice(b"FRME");
    let e = read_err(&b).1.to_string();
    assert!(e.contains("identifier \"FRME\""), "{e}");
}

#[test]
fn corrupt_lz4_payload() {
    let mut b = sample(Compression::Lz4);
    let p = first_packet(&b);
    // Inside the LZ4 frame's block data.
    for v in &mut b[p + 8 + 12..p + 8 + 40] {
        *v ^= 0x5a;
    }
    // Our LZ4 frames carry a content checksum, so the damage is caught in decompression.
    let e = read_err(&b).1.to_string();
    assert!(
        e.contains(&format!("byte {p}")) && e.contains("decompress"),
        "{e}"
    );
}

#[test]
fn polarity_byte_other_than_0_or_1_and_events_outside_the_sensor() {
    let b0 = sample(Compression::None);
    let p = first_packet(&b0);
    let event = |i: usize| p + 8 + 32 + 16 * i;
    let mut b = b0.clone();
    b[event(20) + 12] = 2;
    let (got, e) = read_err(&b);
    assert_eq!(got, 20, "the 20 events before the bad one are delivered");
    assert!(e.to_string().contains("polarity byte 2"), "{e}");
    let mut b = b0.clone();
    b[event(5) + 8..event(5) + 10].copy_from_slice(&31i16.to_le_bytes());
    let (got, e) = read_err(&b);
    assert_eq!(got, 5);
    assert!(matches!(e, FormatError::OutOfBounds { x: 31, .. }), "{e}");
    let mut b = b0;
    b[event(5) + 10..event(5) + 12].copy_from_slice(&(-3i16).to_le_bytes());
    assert!(read_err(&b).1.to_string().contains("(5, -3)"));
}

#[test]
fn events_out_of_order() {
    let mut b = sample(Compression::None);
    let p = first_packet(&b);
    let at = p + 8 + 32 + 16 * 50;
    b[at..at + 8].copy_from_slice(&1i64.to_le_bytes());
    let (got, e) = read_err(&b);
    assert_eq!(got, 50);
    assert!(matches!(e, FormatError::Unsorted { .. }), "{e}");
}

#[test]
fn vector_running_past_its_packet() {
    let mut b = sample(Compression::None);
    let p = first_packet(&b);
    b[p + 8 + 28..p + 8 + 32].copy_from_slice(&1_000_000u32.to_le_bytes());
    let e = read_err(&b).1.to_string();
    assert!(e.contains("runs past the packet"), "{e}");
}

#[test]
fn frames_with_the_wrong_pixel_count_are_refused_both_ways() {
    let mut f = frame(1000, 10, 10, FrameFormat::Bgr, 1);
    f.pixels.pop();
    let mut w =
        Aedat4Writer::new(Vec::new(), "w", Resolution::new(10, 10), Compression::None).unwrap();
    let e = w.write_frame(&f).unwrap_err().to_string();
    assert!(e.contains("299 pixel bytes (300 expected)"), "{e}");
    // A frame packet whose height says 11.
    let good = write(
        &[],
        &[frame(1000, 10, 10, FrameFormat::Gray, 1)],
        Resolution::new(10, 10),
        Compression::None,
    );
    let mut bad = good.clone();
    let p = first_packet(&bad);
    // height at table + 50: the table is at 36 after the prefix, so packet byte 8 + 4 + 86.
    let at = p + 8 + 4 + 36 + 50;
    assert_eq!(i16::from_le_bytes([bad[at], bad[at + 1]]), 10);
    bad[at] = 11;
    let e = Aedat4Frames::from_reader(&bad[..], "f")
        .unwrap()
        .next()
        .unwrap()
        .unwrap_err()
        .to_string();
    assert!(e.contains("100 pixel bytes for a 10x11"), "{e}");
}

#[test]
fn writer_refuses_what_the_format_cannot_hold() {
    assert!(
        Aedat4Writer::new(Vec::new(), "w", Resolution::new(10, 10), Compression::Zstd).is_err()
    );
    assert!(
        Aedat4Writer::new(
            Vec::new(),
            "w",
            Resolution::new(40_000, 10),
            Compression::None
        )
        .is_err()
    );
    let mut w =
        Aedat4Writer::new(Vec::new(), "w", Resolution::new(10, 10), Compression::None).unwrap();
    let e = |t_ns, x| Event {
        t_ns,
        x,
        y: 0,
        polarity: 1,
    };
    assert!(w.write_event(&e(-1, 0)).is_err());
    w.write_event(&e(5_500, 0)).unwrap();
    assert!(w.write_event(&e(5_000, 0)).is_err());
    assert!(w.write_event(&e(6_000, 10)).is_err());
    let (_, s) = w.finish().unwrap();
    assert_eq!((s.items, s.floored_timestamps), (1, 1));
}

#[test]
fn resolution_option_must_agree_with_the_file() {
    let b = sample(Compression::None);
    let e = Aedat4Reader::from_reader(&b[..], "r", &ReadOptions::with_resolution(31, 20))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("30x20") && e.contains("31x20"), "{e}");
}
