//! The facts `shared/data/README.md` states about the real recordings, checked through our
//! readers. Each test skips, with a notice, when the shared folder is absent.
// Test code: a panic is how a failure is reported.
#![allow(clippy::unwrap_used)]

mod common;

use common::*;
use neuspike_formats::EventWriter;
use neuspike_formats::dat::{DatReader, DatWriter};
use neuspike_formats::pku::{self, PkuGeometry, PkuOptions, PkuReader, PkuWriter};
use neuspike_formats::raw::{Evt2Writer, Evt3Writer, RawReader};
use neuspike_formats::text::{TextReader, TextWriter};
use neuspike_formats::{
    Event, EventReader, EvtVersion, Format, FormatError, Info, ReadOptions, Resolution, info, sniff,
};

#[test]
fn vidar_dat_has_200_planes_and_7324316_spikes() {
    let Some(path) = real(VIDAR) else { return };
    assert_eq!(sniff(&path).unwrap(), Format::PkuSpikes);
    let opts = PkuOptions::default();
    assert_eq!(pku::plane_count(&path, &opts.geometry).unwrap(), 200);
    let mut planes = 0;
    let mut spikes = 0;
    let mut chunks = 0;
    for c in PkuReader::open(&path, &opts).unwrap().into_chunks(32) {
        let c = c.unwrap();
        assert_eq!((c.width, c.height), (400, 250));
        assert_eq!(c.bits.len(), c.n_planes * 12_500);
        assert_eq!(c.first_plane, planes);
        assert_eq!(c.t_first_ns, planes as i64 * 50_000);
        assert_eq!(c.seq, chunks);
        planes += c.n_planes as u64;
        spikes += c.spike_count();
        chunks += 1;
    }
    assert_eq!((planes, spikes, chunks), (200, 7_324_316, 7));

    let Info::Spikes(s) = info(&path, &opts, &ReadOptions::default()).unwrap() else {
        panic!("not spikes")
    };
    assert_eq!((s.planes, s.spikes, s.partial_tail), (200, 7_324_316, None));
    assert!((s.spikes_per_plane() - 36_621.58).abs() < 0.01);
    assert!((s.firing_probability() - 0.366).abs() < 0.001);
    assert_eq!(s.duration_ns(), 10_000_000);
    println!("{s}");
}

#[test]
fn vidar_dat_round_trips_byte_exact() {
    let Some(path) = real(VIDAR) else { return };
    let original = std::fs::read(&path).unwrap();
    let mut w = PkuWriter::new(Vec::new(), "mem", PkuGeometry::default()).unwrap();
    let mut r = PkuReader::open(&path, &PkuOptions::default()).unwrap();
    while let Some(c) = r.next_chunk(17).unwrap() {
        w.write_chunk(&c).unwrap();
    }
    let (bytes, summary) = w.finish().unwrap();
    assert_eq!(summary.items, 200);
    assert!(bytes == original, "written bytes differ from the file");
}

#[test]
fn vidar_dat_rows_are_flipped_top_down() {
    let Some(path) = real(VIDAR) else { return };
    let original = std::fs::read(&path).unwrap();
    let c = PkuReader::open(&path, &PkuOptions::default())
        .unwrap()
        .next_chunk(1)
        .unwrap()
        .unwrap();
    // Our top row is the file's last stored row of the plane (50 bytes a row).
    assert_eq!(&c.bits[..50], &original[249 * 50..250 * 50]);
    assert_eq!(&c.bits[249 * 50..250 * 50], &original[..50]);
}

#[test]
fn davis_text_has_20000_events_with_the_stated_ends_and_extent() {
    let Some(path) = real(DAVIS_TEXT) else { return };
    assert_eq!(sniff(&path).unwrap(), Format::EventText);
    let mut r = TextReader::open(&path, &ReadOptions::with_resolution(240, 180)).unwrap();
    let b = all(&mut r).unwrap();
    assert_eq!(b.len(), 20_000);
    // `2.097134001 162 27 0` and `2.195729 127 147 1`.
    assert_eq!(
        b.get(0),
        Event {
            t_ns: 2_097_134_001,
            x: 162,
            y: 27,
            polarity: -1
        }
    );
    assert_eq!(
        b.get(19_999),
        Event {
            t_ns: 2_195_729_000,
            x: 127,
            y: 147,
            polarity: 1
        }
    );
    assert_eq!(*b.x.iter().max().unwrap(), 236);
    assert_eq!(*b.y.iter().max().unwrap(), 179);
    // The line `2.1957200009999998 111 149 0` rounds to the nearest nanosecond.
    assert!(b.t_ns.contains(&2_195_720_001));
    b.validate("davis").unwrap();
    let s = r.stats();
    assert_eq!((s.clamped_timestamps, s.lines_skipped), (0, 0));

    // Without a size, info still summarises, reporting the extent seen.
    let i = neuspike_formats::event_info(
        &path,
        neuspike_formats::Format::EventText,
        &ReadOptions::default(),
    )
    .unwrap();
    assert_eq!(i.resolution, None);
    assert_eq!(
        (i.stats.events, i.stats.max_x, i.stats.max_y),
        (20_000, 236, 179)
    );
    assert_eq!(i.duration_ns(), 98_594_999);
    println!("{i}");
    // ... but a reader needs one.
    let e = TextReader::open(&path, &ReadOptions::default())
        .err()
        .unwrap();
    assert!(matches!(e, FormatError::MissingResolution { .. }), "{e}");
    assert!(e.to_string().contains(DAVIS_TEXT), "{e}");
}

#[test]
fn davis_text_round_trips_through_the_writer() {
    let Some(path) = real(DAVIS_TEXT) else { return };
    let opts = ReadOptions::with_resolution(240, 180);
    let b = all(&mut TextReader::open(&path, &opts).unwrap()).unwrap();
    let mut w = TextWriter::new(Vec::new(), "mem", Resolution::new(240, 180), true).unwrap();
    w.write_batch(&b).unwrap();
    let (bytes, _) = w.finish().unwrap();
    let back =
        all(&mut TextReader::from_reader(&bytes[..], "mem", &ReadOptions::default()).unwrap())
            .unwrap();
    assert_same_events(&events(&back), &events(&b));
}

#[test]
fn prophesee_evt2_has_521252_events_in_the_stated_time_range() {
    let Some(path) = real(PROPHESEE_EVT2) else {
        return;
    };
    assert_eq!(
        sniff(&path).unwrap(),
        Format::PropheseeRaw(EvtVersion::Evt2)
    );
    // The header says `% evt 2.0` but no geometry: the size comes from the options.
    let e = RawReader::open(&path, &ReadOptions::default())
        .err()
        .unwrap();
    assert!(matches!(e, FormatError::MissingResolution { .. }), "{e}");
    let mut r = RawReader::open(&path, &ReadOptions::with_resolution(640, 480)).unwrap();
    assert_eq!(r.header().value("plugin_name"), Some("hal_plugin_gen3_fx3"));
    let mut n = 0u64;
    let mut chunks = 0u64;
    let mut last_end: Option<i64> = None;
    while let Some(b) = r.next_chunk(50_000).unwrap() {
        assert!(b.len() <= 50_000);
        b.validate("evt2").unwrap();
        // Neighbouring chunks share at most their boundary nanosecond.
        assert!(last_end.is_none_or(|end| b.t_start_ns >= end - 1));
        last_end = Some(b.t_end_ns);
        n += b.len() as u64;
        chunks += 1;
    }
    assert_eq!((n, chunks), (521_252, 11));
    let s = r.stats();
    assert_eq!(s.first_t_ns, Some(913_716_224_000));
    assert_eq!(s.last_t_ns, Some(913_812_095_000));
    assert!(s.max_x <= 639 && s.max_y <= 479);
    assert_eq!(
        (
            s.clamped_timestamps,
            s.unknown_words,
            s.events_without_time_base
        ),
        (0, 0, 0)
    );

    let i = neuspike_formats::info::event_info(
        &path,
        neuspike_formats::sniff(&path).unwrap(),
        &ReadOptions::default(),
    )
    .unwrap();
    assert_eq!(i.stats.events, 521_252);
    assert_eq!(i.duration_ns(), 95_871_000);
    println!("{i}");
}

#[test]
fn prophesee_evt2_events_round_trip_through_evt2_evt3_and_dat() {
    let Some(path) = real(PROPHESEE_EVT2) else {
        return;
    };
    let res = Resolution::new(640, 480);
    let opts = ReadOptions::with_resolution(640, 480);
    let original = all(&mut RawReader::open(&path, &opts).unwrap()).unwrap();

    let mut w = Evt2Writer::new(Vec::new(), "mem.raw", res).unwrap();
    w.write_batch(&original).unwrap();
    let (evt2, s2) = w.finish().unwrap();
    assert_eq!(s2.floored_timestamps, 0);
    let back =
        all(&mut RawReader::from_reader(&evt2[..], "mem.raw", &ReadOptions::default()).unwrap())
            .unwrap();
    assert_same_events(&events(&back), &events(&original));

    // EVT 3.0 carries a 24-bit µs clock: times come back modulo 2^24 µs at the start of the file
    // (913.7 s is 54 periods of 16.8 s and 7.75 s), then unwrapped.
    let mut w = Evt3Writer::new(Vec::new(), "mem3.raw", res).unwrap();
    w.write_batch(&original).unwrap();
    let (evt3, _) = w.finish().unwrap();
    let back =
        all(&mut RawReader::from_reader(&evt3[..], "mem3.raw", &ReadOptions::default()).unwrap())
            .unwrap();
    let period_ns = neuspike_formats::evt3::CLOCK_PERIOD_US as i64 * 1000;
    let shift = original.t_ns[0] / period_ns * period_ns;
    assert_eq!(shift, 54 * period_ns);
    let mut expected = events(&original);
    for e in &mut expected {
        e.t_ns -= shift;
    }
    assert_same_events(&events(&back), &expected);
    println!(
        "EVT 2.0 {} bytes, EVT 3.0 {} bytes for {} events",
        evt2.len(),
        evt3.len(),
        original.len()
    );

    let mut w = DatWriter::new(Vec::new(), "mem.dat", res).unwrap();
    w.write_batch(&original).unwrap();
    let (dat, _) = w.finish().unwrap();
    let back =
        all(&mut DatReader::from_reader(&dat[..], "mem.dat", &ReadOptions::default()).unwrap())
            .unwrap();
    assert_same_events(&events(&back), &events(&original));
}
