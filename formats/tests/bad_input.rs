//! Bad input, one named test a case: each asserts a clear error that names the file, the byte
//! offset or line, and the value, and that everything decoded before the fault was delivered
//! first. Never a panic, never a silently wrong image.
// Test code: a panic is how a failure is reported.
#![allow(clippy::unwrap_used)]

mod common;

use std::path::Path;

use common::*;
use neuspike_formats::dat::DatReader;
use neuspike_formats::pku::{self, PkuGeometry, PkuOptions, PkuReader};
use neuspike_formats::raw::RawReader;
use neuspike_formats::text::TextReader;
use neuspike_formats::{
    Disorder, Event, EventReader, Format, FormatError, Location, ReadOptions, UnknownWords, info,
    open_events, sniff,
};

fn text_reader<'a>(
    s: &'a str,
    opts: &ReadOptions,
) -> neuspike_formats::Result<TextReader<&'a [u8]>> {
    TextReader::from_reader(s.as_bytes(), "events.txt", opts)
}

fn raw_reader<'a>(
    bytes: &'a [u8],
    opts: &ReadOptions,
) -> neuspike_formats::Result<RawReader<&'a [u8]>> {
    RawReader::from_reader(bytes, "rec.raw", opts)
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

// ---------------------------------------------------------------- PKU spike planes

#[test]
fn pku_partial_plane_delivers_whole_planes_then_names_offset_and_size() {
    let dir = tempfile::tempdir().unwrap();
    // 2 whole 2x8 planes (2 bytes each) + 1 byte.
    let p = write(dir.path(), "cut.dat", &[1, 2, 3, 4, 5]);
    let opts = PkuOptions {
        geometry: PkuGeometry::new(8, 2),
        ..PkuOptions::default()
    };
    let mut r = PkuReader::open(&p, &opts).unwrap();
    let c = r.next_chunk(10).unwrap().unwrap();
    assert_eq!(c.n_planes, 2);
    // Rows flipped: stored [1, 2] -> [2, 1].
    assert_eq!(c.bits, vec![2, 1, 4, 3]);
    let e = r.next_chunk(10).unwrap_err();
    match &e {
        FormatError::PartialPlane {
            whole_planes,
            tail_offset,
            tail_bytes,
            size,
            plane_bytes,
            ..
        } => {
            assert_eq!(
                (
                    *whole_planes,
                    *tail_offset,
                    *tail_bytes,
                    *size,
                    *plane_bytes
                ),
                (2, 4, 1, 5, 2)
            );
        }
        other => panic!("{other}"),
    }
    let msg = e.to_string();
    assert!(
        msg.contains("cut.dat") && msg.contains("byte 4") && msg.contains("1 bytes remain"),
        "{msg}"
    );
    assert!(r.next_chunk(10).unwrap().is_none());

    // info keeps the whole planes and reports the tail as a warning value.
    let s = pku::info(&p, &opts).unwrap();
    assert_eq!((s.planes, s.partial_tail), (2, Some((4, 1))));
}

#[test]
fn pku_partial_plane_inside_a_chunk_still_delivers_the_chunk() {
    // 3 planes and a half, read 2 at a time: 2, then 1, then the error.
    let bytes = [0u8, 0, 0, 0, 0, 0, 9];
    let opts = PkuOptions {
        geometry: PkuGeometry::new(8, 2),
        ..PkuOptions::default()
    };
    let mut r = PkuReader::from_reader(&bytes[..], "mem.dat", &opts).unwrap();
    assert_eq!(r.next_chunk(2).unwrap().unwrap().n_planes, 2);
    assert_eq!(r.next_chunk(2).unwrap().unwrap().n_planes, 1);
    assert!(matches!(
        r.next_chunk(2),
        Err(FormatError::PartialPlane {
            tail_offset: 6,
            tail_bytes: 1,
            ..
        })
    ));
    assert_eq!(r.planes_read(), 3);
}

#[test]
fn pku_resolution_not_dividing_names_file_size_and_plane_bytes() {
    let dir = tempfile::tempdir().unwrap();
    // Two 400x250 planes read as 416-wide rows (13,000-byte planes).
    let p = write(dir.path(), "car.dat", &vec![0u8; 25_000]);
    let g = PkuGeometry::with_head(400, 250);
    let e = pku::plane_count(&p, &g).unwrap_err();
    assert!(matches!(
        e,
        FormatError::ResolutionMismatch {
            size: 25_000,
            plane_bytes: 13_000,
            remainder: 12_000,
            ..
        }
    ));
    let msg = e.to_string();
    assert!(
        msg.contains("car.dat")
            && msg.contains("25000 bytes")
            && msg.contains("13000-byte")
            && msg.contains("400x250 + 16 head columns"),
        "{msg}"
    );
    // Smaller than one plane: refused when opening.
    let small = write(dir.path(), "small.dat", &[0u8; 100]);
    let e = PkuReader::open(&small, &PkuOptions::default())
        .err()
        .unwrap();
    assert!(
        matches!(
            e,
            FormatError::ResolutionMismatch {
                size: 100,
                plane_bytes: 12_500,
                ..
            }
        ),
        "{e}"
    );
}

#[test]
fn pku_head_columns_are_dropped() {
    // 416x2 stored rows; the head (last 16 columns) is all ones, the image all zeros but pixel 0
    // of the bottom row.
    let g = PkuGeometry::with_head(400, 2);
    let mut stored = vec![0u8; g.stored_plane_bytes()];
    stored[0] = 1;
    stored[50] = 0xFF;
    stored[51] = 0xFF;
    stored[102] = 0xFF;
    stored[103] = 0xFF;
    let opts = PkuOptions {
        geometry: g,
        ..PkuOptions::default()
    };
    let c = PkuReader::from_reader(&stored[..], "mem.dat", &opts)
        .unwrap()
        .next_chunk(1)
        .unwrap()
        .unwrap();
    assert_eq!(c.width, 400);
    assert_eq!(c.spike_count(), 1);
    // The bottom row is row 1 of the top-down image: pixel (1, 0) = bit 400.
    assert_eq!(c.bits[50], 1);
}

// ---------------------------------------------------------------- empty and missing files

#[test]
fn empty_file_is_named_by_every_reader() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "empty.bin", b"");
    let opts = ReadOptions::with_resolution(640, 480);
    let errors = [
        PkuReader::open(&p, &PkuOptions::default()).err().unwrap(),
        TextReader::open(&p, &opts).err().unwrap(),
        RawReader::open(&p, &opts).err().unwrap(),
        DatReader::open(&p, &opts).err().unwrap(),
        sniff(&p).unwrap_err(),
        pku::plane_count(&p, &PkuGeometry::default()).unwrap_err(),
    ];
    for e in errors {
        assert!(matches!(e, FormatError::Empty { .. }), "{e}");
        assert!(
            e.to_string().contains("empty.bin: the file is empty"),
            "{e}"
        );
    }
    // Empty in-memory sources too.
    let e = PkuReader::from_reader(&b""[..], "mem", &PkuOptions::default())
        .unwrap()
        .next_chunk(1)
        .unwrap_err();
    assert!(matches!(e, FormatError::Empty { .. }), "{e}");
}

#[test]
fn missing_file_is_named_by_every_reader() {
    let p = Path::new("/nonexistent/dir/recording.dat");
    let opts = ReadOptions::with_resolution(640, 480);
    let errors = [
        PkuReader::open(p, &PkuOptions::default()).err().unwrap(),
        TextReader::open(p, &opts).err().unwrap(),
        RawReader::open(p, &opts).err().unwrap(),
        DatReader::open(p, &opts).err().unwrap(),
        sniff(p).unwrap_err(),
        info(p, &PkuOptions::default(), &opts).unwrap_err(),
        open_events(p, &opts).err().unwrap(),
    ];
    for e in errors {
        assert!(matches!(e, FormatError::Open { .. }), "{e}");
        assert!(
            e.to_string()
                .starts_with("/nonexistent/dir/recording.dat: cannot open"),
            "{e}"
        );
    }
}

// ---------------------------------------------------------------- text

#[test]
fn text_unsorted_timestamps_are_an_error_or_a_counted_clamp() {
    let s = "10 10\n0.000002 1 1 1\n0.000001 2 2 0\n0.000003 3 3 1\n";
    let mut r = text_reader(s, &ReadOptions::default()).unwrap();
    let (got, e) = drain(&mut r, 100);
    assert_eq!(got.len(), 1);
    let e = e.unwrap();
    assert!(
        matches!(
            e,
            FormatError::Unsorted {
                at: Location::Line(3),
                t_ns: 1_000,
                previous_t_ns: 2_000,
                ..
            }
        ),
        "{e}"
    );
    assert!(
        e.to_string()
            .contains("events.txt: line 3: timestamp 1000 ns"),
        "{e}"
    );

    let opts = ReadOptions {
        disorder: Disorder::Clamp,
        ..ReadOptions::default()
    };
    let mut r = text_reader(s, &opts).unwrap();
    let (got, e) = drain(&mut r, 100);
    assert!(e.is_none());
    assert_eq!(
        got.iter().map(|e| e.t_ns).collect::<Vec<_>>(),
        vec![2_000, 2_000, 3_000]
    );
    assert_eq!(r.stats().clamped_timestamps, 1);
}

#[test]
fn text_duplicate_timestamps_are_legal_and_identical_events_counted() {
    let s = "10 10\n1.5 1 1 1\n1.5 2 2 0\n1.5 2 2 0\n";
    let mut r = text_reader(s, &ReadOptions::default()).unwrap();
    let (got, e) = drain(&mut r, 100);
    assert!(e.is_none());
    assert_eq!(got.len(), 3);
    assert_eq!(r.stats().duplicate_events, 1);
    assert_eq!(r.stats().clamped_timestamps, 0);
}

#[test]
fn text_polarity_not_0_or_1_names_line_and_value() {
    for (line, value) in [
        ("0.5 1 1 -1", Some(-1)),
        ("0.5 1 1 2", Some(2)),
        ("0.5 1 1 on", None),
    ] {
        let s = format!("10 10\n0.1 0 0 1\n{line}\n");
        let mut r = text_reader(&s, &ReadOptions::default()).unwrap();
        let (got, e) = drain(&mut r, 100);
        assert_eq!(got.len(), 1, "the good line first");
        let e = e.unwrap();
        let msg = e.to_string();
        assert!(msg.contains("events.txt: line 3: polarity"), "{msg}");
        if let Some(v) = value {
            assert!(
                matches!(e, FormatError::Polarity { value, .. } if value == v),
                "{msg}"
            );
        } else {
            assert!(msg.contains("`on`"), "{msg}");
        }
    }
}

#[test]
fn text_coordinates_outside_the_sensor_name_line_and_value() {
    let mut r = text_reader(
        "240 180\n0.1 239 179 1\n0.2 240 5 0\n",
        &ReadOptions::default(),
    )
    .unwrap();
    let (got, e) = drain(&mut r, 100);
    assert_eq!(
        got,
        vec![Event {
            t_ns: 100_000_000,
            x: 239,
            y: 179,
            polarity: 1
        }]
    );
    let msg = e.unwrap().to_string();
    assert_eq!(
        msg,
        "events.txt: line 3: event at (240, 5) is outside the 240x180 sensor"
    );
    // A coordinate too large for any sensor is a text error, not a wrapped value.
    let mut r = text_reader("240 180\n0.2 99999999999 5 0\n", &ReadOptions::default()).unwrap();
    let msg = drain(&mut r, 100).1.unwrap().to_string();
    assert!(
        msg.contains("line 2") && msg.contains("99999999999"),
        "{msg}"
    );
}

#[test]
fn text_malformed_numbers_and_lines_name_the_line() {
    for (line, needle) in [
        ("1e-3 1 1 1", "`1e-3` is not a decimal number"),
        ("-0.5 1 1 1", "`-0.5` is not a decimal"),
        ("0.5 1 1", "expected 4 fields"),
        ("0.5 1 1 1 7", "found 5"),
        ("0..5 1 1 1", "`0..5`"),
        ("99999999999.0 1 1 1", "overflows"),
    ] {
        let s = format!("10 10\n{line}\n");
        let e = drain(&mut text_reader(&s, &ReadOptions::default()).unwrap(), 10)
            .1
            .unwrap();
        let msg = e.to_string();
        assert!(
            msg.starts_with("events.txt: line 2: ") && msg.contains(needle),
            "{msg}"
        );
    }
}

#[test]
fn text_size_line_conflicting_with_options_is_named() {
    let e = text_reader(
        "240 180\n0.1 1 1 1\n",
        &ReadOptions::with_resolution(346, 260),
    )
    .err()
    .unwrap();
    let msg = e.to_string();
    assert!(msg.contains("240x180") && msg.contains("346x260"), "{msg}");
}

#[test]
fn text_comments_and_blank_lines_are_skipped_and_counted() {
    let mut r = text_reader(
        "# DAVIS\n\n240 180\n0.1 1 1 1\n\n# end\n",
        &ReadOptions::default(),
    )
    .unwrap();
    let (got, e) = drain(&mut r, 10);
    assert!(e.is_none());
    assert_eq!(got.len(), 1);
    assert_eq!(r.stats().lines_skipped, 4);
}

// ---------------------------------------------------------------- EVT 2.0

#[test]
fn evt2_unknown_word_type_names_offset_and_value() {
    let bytes = evt2_file(
        EVT2_HEADER,
        &[evt2_time_high(1), evt2_cd(true, 3, 5, 6), 0x3000_0042],
    );
    let off = EVT2_HEADER.len() as u64 + 8;
    let (got, e) = drain(
        &mut raw_reader(&bytes, &ReadOptions::default()).unwrap(),
        10,
    );
    assert_eq!(
        got,
        vec![Event {
            t_ns: 67_000,
            x: 5,
            y: 6,
            polarity: 1
        }]
    );
    let e = e.unwrap();
    assert!(
        matches!(e, FormatError::UnknownWord { offset, word_type: 3, value: 0x3000_0042, .. } if offset == off),
        "{e}"
    );
    let msg = e.to_string();
    assert!(
        msg.contains(&format!(
            "rec.raw: byte {off}: unknown EVT 2.0 word type 0x3 (word 0x30000042)"
        )),
        "{msg}"
    );

    let opts = ReadOptions {
        unknown_words: UnknownWords::Skip,
        ..ReadOptions::default()
    };
    let mut r = raw_reader(&bytes, &opts).unwrap();
    let (got, e) = drain(&mut r, 10);
    assert!(e.is_none());
    assert_eq!(got.len(), 1);
    assert_eq!(r.stats().unknown_words, 1);
}

#[test]
fn evt2_truncated_word_delivers_events_then_names_offset() {
    let mut bytes = evt2_file(EVT2_HEADER, &[evt2_time_high(0), evt2_cd(false, 1, 2, 3)]);
    bytes.extend_from_slice(&[0xAA, 0xBB]);
    let (got, e) = drain(
        &mut raw_reader(&bytes, &ReadOptions::default()).unwrap(),
        10,
    );
    assert_eq!(
        got,
        vec![Event {
            t_ns: 1_000,
            x: 2,
            y: 3,
            polarity: -1
        }]
    );
    let msg = e.unwrap().to_string();
    let off = EVT2_HEADER.len() + 8;
    assert!(
        msg.contains(&format!(
            "rec.raw: truncated at byte {off}: 2 byte(s) of a 4-byte EVT 2.0 word"
        )),
        "{msg}"
    );
}

#[test]
fn evt2_time_high_wrap_is_unwrapped_past_34_bits() {
    let top = (1 << 28) - 1;
    let bytes = evt2_file(
        EVT2_HEADER,
        &[
            evt2_time_high(top),
            evt2_cd(true, 63, 1, 1),
            evt2_time_high(0),
            evt2_cd(true, 0, 1, 1),
        ],
    );
    let mut r = raw_reader(&bytes, &ReadOptions::default()).unwrap();
    let (got, e) = drain(&mut r, 10);
    assert!(e.is_none());
    let last_before = ((1u64 << 34) - 1) as i64 * 1000;
    assert_eq!(got[0].t_ns, last_before);
    assert_eq!(got[1].t_ns, (1i64 << 34) * 1000);
    assert_eq!(r.stats().time_wraps, 1);
}

#[test]
fn evt2_small_time_high_step_back_is_disorder_not_a_wrap() {
    let bytes = evt2_file(
        EVT2_HEADER,
        &[
            evt2_time_high(100),
            evt2_cd(true, 0, 1, 1),
            evt2_time_high(99),
            evt2_cd(true, 0, 2, 2),
        ],
    );
    let mut r = raw_reader(&bytes, &ReadOptions::default()).unwrap();
    let (got, e) = drain(&mut r, 10);
    assert_eq!(got.len(), 1);
    let e = e.unwrap();
    let off = EVT2_HEADER.len() as u64 + 12;
    assert!(
        matches!(e, FormatError::Unsorted { at: Location::Byte(o), t_ns: 6_336_000, previous_t_ns: 6_400_000, .. } if o == off),
        "{e}"
    );
    assert_eq!(r.stats().time_wraps, 0);
}

#[test]
fn evt2_events_before_the_first_time_high_are_dropped_and_counted() {
    let bytes = evt2_file(
        EVT2_HEADER,
        &[
            evt2_cd(true, 0, 1, 1),
            evt2_time_high(2),
            evt2_cd(true, 1, 1, 1),
        ],
    );
    let mut r = raw_reader(&bytes, &ReadOptions::default()).unwrap();
    let (got, e) = drain(&mut r, 10);
    assert!(e.is_none());
    assert_eq!(
        got,
        vec![Event {
            t_ns: 129_000,
            x: 1,
            y: 1,
            polarity: 1
        }]
    );
    assert_eq!(r.stats().events_without_time_base, 1);
}

#[test]
fn evt2_coordinates_outside_the_sensor_name_offset() {
    let bytes = evt2_file(EVT2_HEADER, &[evt2_time_high(0), evt2_cd(true, 0, 640, 10)]);
    let msg = drain(
        &mut raw_reader(&bytes, &ReadOptions::default()).unwrap(),
        10,
    )
    .1
    .unwrap()
    .to_string();
    let off = EVT2_HEADER.len() + 4;
    assert_eq!(
        msg,
        format!("rec.raw: byte {off}: event at (640, 10) is outside the 640x480 sensor")
    );
}

#[test]
fn evt2_triggers_others_and_continued_are_counted_not_delivered() {
    let bytes = evt2_file(
        EVT2_HEADER,
        &[
            evt2_time_high(0),
            0xA000_0101,
            0xE000_0000,
            0xF000_0000,
            evt2_cd(false, 0, 0, 0),
        ],
    );
    let mut r = raw_reader(&bytes, &ReadOptions::default()).unwrap();
    let (got, e) = drain(&mut r, 10);
    assert!(e.is_none());
    assert_eq!(got.len(), 1);
    assert_eq!((r.stats().triggers, r.stats().skipped_words), (1, 2));
}

// ---------------------------------------------------------------- RAW headers

#[test]
fn raw_header_problems_are_named() {
    let opts = ReadOptions::with_resolution(640, 480);
    let e = raw_reader(&[0x00, 0x00, 0x00, 0x80], &opts)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("rec.raw: header: no `%` header"), "{e}");
    let e = raw_reader(b"% date today\n\x00\x00\x00\x80", &opts)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("names no event encoding"), "{e}");
    let e = raw_reader(b"% evt 2.1\n", &opts).err().unwrap().to_string();
    assert!(e.contains("unsupported: EVT 2.1"), "{e}");
    let e = raw_reader(b"% evt 4.0\n", &opts).err().unwrap().to_string();
    assert!(e.contains("unknown `% evt 4.0`"), "{e}");
    let e = raw_reader(
        EVT2_HEADER.as_bytes(),
        &ReadOptions::with_resolution(320, 320),
    )
    .err()
    .unwrap()
    .to_string();
    assert!(
        e.contains("the file says 640x480, ReadOptions::resolution says 320x320"),
        "{e}"
    );
}

// ---------------------------------------------------------------- EVT 3.0

const Y: u16 = 0x0;
const X: u16 = 0x2;
const BASE: u16 = 0x3;
const V12: u16 = 0x4;
const V8: u16 = 0x5;
const LOW: u16 = 0x6;
const HIGH: u16 = 0x8;

#[test]
fn evt3_time_low_step_back_is_taken_literally_then_disorder_decides() {
    // Convention (Prophesee's): a TIME_LOW below the previous one under the same TIME_HIGH is the
    // time it says, with no implied carry into TIME_HIGH; the event after it is earlier.
    let words = [
        evt3(HIGH, 1),
        evt3(LOW, 100),
        evt3(Y, 7),
        evt3(X, 3),
        evt3(LOW, 50),
        evt3(X, 4),
    ];
    let bytes = evt3_file(EVT3_HEADER, &words);
    let (got, e) = drain(
        &mut raw_reader(&bytes, &ReadOptions::default()).unwrap(),
        10,
    );
    assert_eq!(
        got,
        vec![Event {
            t_ns: (4096 + 100) * 1000,
            x: 3,
            y: 7,
            polarity: -1
        }]
    );
    let e = e.unwrap();
    assert!(
        matches!(
            e,
            FormatError::Unsorted {
                t_ns: 4_146_000,
                previous_t_ns: 4_196_000,
                ..
            }
        ),
        "{e}"
    );

    let opts = ReadOptions {
        disorder: Disorder::Clamp,
        ..ReadOptions::default()
    };
    let mut r = raw_reader(&bytes, &opts).unwrap();
    let (got, e) = drain(&mut r, 10);
    assert!(e.is_none());
    assert_eq!(got[1].t_ns, 4_196_000);
    assert_eq!((r.stats().clamped_timestamps, r.stats().time_wraps), (1, 0));
}

#[test]
fn evt3_time_high_wrap_adds_2_pow_24_us() {
    let words = [
        evt3(HIGH, 0xFFF),
        evt3(LOW, 0xFFF),
        evt3(Y, 0),
        evt3(X, 1),
        evt3(HIGH, 0),
        evt3(LOW, 1),
        evt3(X, 2),
    ];
    let bytes = evt3_file(EVT3_HEADER, &words);
    let mut r = raw_reader(&bytes, &ReadOptions::default()).unwrap();
    let (got, e) = drain(&mut r, 10);
    assert!(e.is_none());
    assert_eq!(got[0].t_ns, ((1i64 << 24) - 1) * 1000);
    assert_eq!(got[1].t_ns, ((1i64 << 24) + 1) * 1000);
    assert_eq!(r.stats().time_wraps, 1);
}

#[test]
fn evt3_time_high_change_resets_time_low() {
    let words = [
        evt3(HIGH, 1),
        evt3(LOW, 500),
        evt3(Y, 0),
        evt3(X, 0),
        evt3(HIGH, 2),
        evt3(X, 1),
    ];
    let (got, _) = drain(
        &mut raw_reader(&evt3_file(EVT3_HEADER, &words), &ReadOptions::default()).unwrap(),
        10,
    );
    assert_eq!(got[1].t_ns, 8192 * 1000);
}

#[test]
fn evt3_vectors_decode_from_their_base_and_advance_it() {
    let words = [
        evt3(HIGH, 0),
        evt3(Y, 9),
        evt3(BASE, 0x800 | 100),
        evt3(V12, 0b1000_0000_0001),
        evt3(V8, 0b1000_0001),
        evt3(X, 5),
    ];
    let (got, e) = drain(
        &mut raw_reader(&evt3_file(EVT3_HEADER, &words), &ReadOptions::default()).unwrap(),
        2,
    );
    assert!(e.is_none());
    let xs: Vec<(u16, i8)> = got.iter().map(|e| (e.x, e.polarity)).collect();
    assert_eq!(xs, vec![(100, 1), (111, 1), (112, 1), (119, 1), (5, -1)]);
}

#[test]
fn evt3_vector_bits_past_the_sensor_edge_are_errors() {
    let words = [
        evt3(HIGH, 0),
        evt3(Y, 0),
        evt3(BASE, 636),
        evt3(V8, 0b0001_0001),
    ];
    let bytes = evt3_file(EVT3_HEADER, &words);
    let (got, e) = drain(
        &mut raw_reader(&bytes, &ReadOptions::default()).unwrap(),
        10,
    );
    assert_eq!(got.len(), 1);
    let off = EVT3_HEADER.len() + 6;
    assert_eq!(
        e.unwrap().to_string(),
        format!("rec.raw: byte {off}: event at (640, 0) is outside the 640x480 sensor")
    );
}

#[test]
fn evt3_unknown_word_type_names_offset_and_value() {
    let words = [evt3(HIGH, 0), 0x9123];
    let bytes = evt3_file(EVT3_HEADER, &words);
    let e = drain(
        &mut raw_reader(&bytes, &ReadOptions::default()).unwrap(),
        10,
    )
    .1
    .unwrap();
    let off = EVT3_HEADER.len() + 2;
    assert_eq!(
        e.to_string(),
        format!(
            "rec.raw: byte {off}: unknown EVT 3.0 word type 0x9 (word 0x9123); \
             ReadOptions::unknown_words = UnknownWords::Skip skips and counts such words"
        )
    );
}

#[test]
fn evt3_odd_byte_count_is_truncated() {
    let mut bytes = evt3_file(EVT3_HEADER, &[evt3(HIGH, 0), evt3(Y, 1), evt3(X, 1)]);
    bytes.push(0x42);
    let (got, e) = drain(
        &mut raw_reader(&bytes, &ReadOptions::default()).unwrap(),
        10,
    );
    assert_eq!(got.len(), 1);
    assert!(matches!(e, Some(FormatError::Truncated { .. })));
}

#[test]
fn evt3_events_before_time_or_row_are_dropped_and_counted() {
    let words = [
        evt3(X, 1),
        evt3(HIGH, 0),
        evt3(X, 2),
        evt3(BASE, 0),
        evt3(V8, 0b11),
        evt3(Y, 3),
        evt3(X, 3),
    ];
    let bytes = evt3_file(EVT3_HEADER, &words);
    let mut r = raw_reader(&bytes, &ReadOptions::default()).unwrap();
    let (got, e) = drain(&mut r, 10);
    assert!(e.is_none());
    assert_eq!(got.len(), 1);
    assert_eq!(r.stats().events_without_time_base, 4);
}

// ---------------------------------------------------------------- DAT

fn dat_reader(bytes: &[u8]) -> neuspike_formats::Result<DatReader<&[u8]>> {
    DatReader::from_reader(bytes, "cars.dat", &ReadOptions::default())
}

#[test]
fn dat_polarity_not_0_or_1_names_offset_and_value() {
    let bytes = dat_file(
        DAT_HEADER,
        &[dat_record(5, 1, 2, 1), dat_record(6, 1, 2, 3)],
    );
    let (got, e) = drain(&mut dat_reader(&bytes).unwrap(), 10);
    assert_eq!(
        got,
        vec![Event {
            t_ns: 5_000,
            x: 1,
            y: 2,
            polarity: 1
        }]
    );
    let off = DAT_HEADER.len() + 2 + 8;
    assert_eq!(
        e.unwrap().to_string(),
        format!("cars.dat: byte {off}: polarity 3 is not 0 or 1")
    );
}

#[test]
fn dat_truncated_record_delivers_events_then_names_offset() {
    let mut bytes = dat_file(DAT_HEADER, &[dat_record(5, 1, 2, 0)]);
    bytes.extend_from_slice(&[1, 2, 3]);
    let (got, e) = drain(&mut dat_reader(&bytes).unwrap(), 10);
    assert_eq!(got.len(), 1);
    let off = DAT_HEADER.len() + 2 + 8;
    assert_eq!(
        e.unwrap().to_string(),
        format!("cars.dat: truncated at byte {off}: 3 byte(s) of an 8-byte DAT record")
    );
}

#[test]
fn dat_bad_type_size_pair_and_other_kinds_are_named() {
    let mut bytes = DAT_HEADER.as_bytes().to_vec();
    bytes.extend_from_slice(&[0x0C, 0x10]);
    let e = dat_reader(&bytes).err().unwrap().to_string();
    assert!(
        e.contains(&format!(
            "cars.dat: byte {}: event type 0x0c and size 16",
            DAT_HEADER.len()
        )),
        "{e}"
    );
    let mut bytes = DAT_HEADER.as_bytes().to_vec();
    bytes.extend_from_slice(&[0x0E, 0x08]);
    assert!(
        dat_reader(&bytes)
            .err()
            .unwrap()
            .to_string()
            .contains("external triggers")
    );
    let e = dat_reader(b"% Version 1\n\x0c\x08")
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("Version 1"), "{e}");
    let e = dat_reader(DAT_HEADER.as_bytes()).err().unwrap().to_string();
    assert!(
        e.contains("type and size bytes after the header are missing"),
        "{e}"
    );
    let e = DatReader::from_reader(
        &b"% Data file containing CD events\n\x0c\x08"[..],
        "n.dat",
        &ReadOptions::default(),
    )
    .err()
    .unwrap();
    assert!(matches!(e, FormatError::MissingResolution { .. }), "{e}");
}

#[test]
fn dat_32_bit_clock_wrap_is_unwrapped_and_small_steps_back_are_disorder() {
    let bytes = dat_file(
        DAT_HEADER,
        &[dat_record(u32::MAX, 0, 0, 1), dat_record(3, 0, 0, 1)],
    );
    let mut r = dat_reader(&bytes).unwrap();
    let (got, e) = drain(&mut r, 10);
    assert!(e.is_none());
    assert_eq!(got[1].t_ns, ((1i64 << 32) + 3) * 1000);
    assert_eq!(r.stats().time_wraps, 1);

    let bytes = dat_file(
        DAT_HEADER,
        &[dat_record(10, 0, 0, 1), dat_record(9, 0, 0, 1)],
    );
    let e = drain(&mut dat_reader(&bytes).unwrap(), 10).1.unwrap();
    assert!(
        matches!(
            e,
            FormatError::Unsorted {
                t_ns: 9_000,
                previous_t_ns: 10_000,
                ..
            }
        ),
        "{e}"
    );
}

#[test]
fn dat_coordinates_outside_the_sensor_name_offset() {
    let bytes = dat_file(DAT_HEADER, &[dat_record(1, 0, 480, 0)]);
    let e = drain(&mut dat_reader(&bytes).unwrap(), 10)
        .1
        .unwrap()
        .to_string();
    assert!(
        e.contains("event at (0, 480) is outside the 640x480 sensor"),
        "{e}"
    );
}

// ---------------------------------------------------------------- sniffing .dat files

#[test]
fn dat_path_is_told_apart_by_content() {
    let dir = tempfile::tempdir().unwrap();
    let spikes = write(dir.path(), "a.dat", &[0x25, 0x00, 0x13, 0x0A, 0x80]);
    let events = write(
        dir.path(),
        "b.dat",
        &dat_file(DAT_HEADER, &[dat_record(1, 1, 1, 1)]),
    );
    assert_eq!(sniff(&spikes).unwrap(), Format::PkuSpikes);
    assert_eq!(sniff(&events).unwrap(), Format::PropheseeDat);
    let amb = write(dir.path(), "c.dat", b"% some text\n\x07\x07\x07\x07");
    let e = sniff(&amb).unwrap_err();
    assert!(matches!(e, FormatError::Ambiguous { .. }), "{e}");
    assert!(
        e.to_string().contains("c.dat: cannot tell the format"),
        "{e}"
    );
    // open_events refuses spike files with a pointer to the spike reader.
    let e = open_events(&spikes, &ReadOptions::default())
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("pku::PkuReader"), "{e}");
    assert_eq!(
        open_events(&events, &ReadOptions::default())
            .unwrap()
            .stats()
            .events,
        0
    );
}
