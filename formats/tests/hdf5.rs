//! HDF5 event files (built with `--features hdf5`, which needs libhdf5): our writer read back,
//! the layouts of other sets (datasets at the root, float seconds, -1/+1 polarity, DSEC's
//! `t_offset`), and one named test per kind of bad input.
#![cfg(feature = "hdf5")]
// Test code: a panic is how a failure is reported.
#![allow(clippy::unwrap_used)]

mod common;

use std::path::Path;

use common::*;
use neuspike_formats::hdf5::{Hdf5Reader, Hdf5Writer, lib as h5};
use neuspike_formats::{
    Event, EventBatch, EventReader, EventWriter, Format, FormatError, ReadOptions, Resolution,
    open_events, sniff,
};
use proptest::prelude::*;

fn read(path: &Path, opts: &ReadOptions, n: usize) -> (Vec<Event>, Option<FormatError>) {
    let mut r = match Hdf5Reader::open(path, opts) {
        Ok(r) => r,
        Err(e) => return (Vec::new(), Some(e)),
    };
    let mut b = EventBatch::default();
    loop {
        match r.read_into(&mut b, n) {
            Ok(0) => return (events(&b), None),
            Ok(_) => {}
            Err(e) => return (events(&b), Some(e)),
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn our_files_round_trip_at_microseconds(
        raw in prop::collection::vec((0i64..5_000, 0u16..346, 0u16..260, any::<bool>()), 0..150_000),
        n in 1usize..100_000,
    ) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("e.h5");
        let r = Resolution::new(346, 260);
        let mut t = 0i64;
        let evs: Vec<Event> = raw.iter().map(|&(dt, x, y, on)| {
            t += dt;
            Event { t_ns: t, x, y, polarity: if on { 1 } else { -1 } }
        }).collect();
        let mut w = Hdf5Writer::create(&path, r).unwrap();
        for e in &evs {
            w.write_event(e).unwrap();
        }
        let s = w.finish().unwrap();
        prop_assert_eq!(s.items, evs.len() as u64);
        prop_assert_eq!(sniff(&path).unwrap(), Format::Hdf5);
        let mut reader = open_events(&path, &ReadOptions::default()).unwrap();
        prop_assert_eq!(reader.resolution(), r);
        let mut b = EventBatch::default();
        while reader.read_into(&mut b, n).unwrap() > 0 {}
        let want: Vec<Event> = evs.iter().map(|e| Event { t_ns: e.t_ns / 1000 * 1000, ..*e }).collect();
        assert_same_events(&events(&b), &want);
        prop_assert_eq!(reader.stats().events, evs.len() as u64);
    }
}

/// A one-dimensional dataset `name` in `g` holding `data`.
fn put<T: h5::H5Type>(g: &h5::Group, name: &str, data: &[T]) -> h5::Dataset {
    g.new_dataset_builder()
        .with_data(data)
        .create(name)
        .unwrap()
}

fn root_file(path: &Path, t: &[f64], x: &[i32], y: &[i32], p: &[i8]) {
    let f = h5::File::create(path).unwrap();
    put(&f, "t", t);
    put(&f, "x", x);
    put(&f, "y", y);
    put(&f, "p", p);
}

#[test]
fn root_datasets_float_seconds_and_signed_polarity() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("root.h5");
    root_file(
        &path,
        &[0.5, 0.500_001_5, 2.0],
        &[1, 2, 3],
        &[4, 5, 6],
        &[1, -1, 1],
    );
    // No width/height: the size must come from the options.
    let e = Hdf5Reader::open(&path, &ReadOptions::default())
        .err()
        .unwrap();
    assert!(matches!(e, FormatError::MissingResolution { .. }), "{e}");
    let (got, err) = read(&path, &ReadOptions::with_resolution(10, 10), 2);
    assert!(err.is_none(), "{err:?}");
    assert_eq!(
        got,
        [
            Event {
                t_ns: 500_000_000,
                x: 1,
                y: 4,
                polarity: 1
            },
            Event {
                t_ns: 500_001_500,
                x: 2,
                y: 5,
                polarity: -1
            },
            Event {
                t_ns: 2_000_000_000,
                x: 3,
                y: 6,
                polarity: 1
            },
        ]
    );
}

#[test]
fn dsec_layout_with_t_offset_in_microseconds() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dsec.h5");
    let f = h5::File::create(&path).unwrap();
    let g = f.create_group("events").unwrap();
    put(&g, "t", &[0u32, 7, 9]);
    put(&g, "x", &[0u16, 639, 5]);
    put(&g, "y", &[0u16, 479, 5]);
    put(&g, "p", &[0u8, 1, 0]);
    f.new_dataset::<i64>()
        .create("events/t_offset")
        .unwrap()
        .write_scalar(&1_000_000i64)
        .unwrap();
    drop(f);
    let (got, err) = read(&path, &ReadOptions::with_resolution(640, 480), 100);
    assert!(err.is_none(), "{err:?}");
    let t: Vec<i64> = got.iter().map(|e| e.t_ns).collect();
    assert_eq!(t, [1_000_000_000, 1_000_007_000, 1_000_009_000]);
    assert_eq!((got[1].x, got[1].y, got[1].polarity), (639, 479, 1));
}

#[test]
fn missing_dataset_and_unequal_lengths_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.h5");
    let f = h5::File::create(&path).unwrap();
    put(&f, "t", &[1i64, 2]);
    put(&f, "x", &[1i64, 2]);
    put(&f, "y", &[1i64]);
    drop(f);
    let e = read(&path, &ReadOptions::with_resolution(9, 9), 9)
        .1
        .unwrap()
        .to_string();
    assert!(
        e.contains("m.h5") && e.contains("no dataset `/p`") && e.contains("t, x, y"),
        "{e}"
    );
    let f = h5::File::open_rw(&path).unwrap();
    put(&f, "p", &[1i64, 0]);
    drop(f);
    let e = read(&path, &ReadOptions::with_resolution(9, 9), 9)
        .1
        .unwrap()
        .to_string();
    assert!(e.contains("`/y` holds 1 values, `/t` 2"), "{e}");
}

#[test]
fn bad_values_stop_after_the_good_events() {
    let dir = tempfile::tempdir().unwrap();
    let opts = ReadOptions::with_resolution(10, 10);
    let p = dir.path().join("pol.h5");
    root_file(&p, &[1.0, 2.0, 3.0], &[1, 1, 1], &[1, 1, 1], &[1, 2, 0]);
    let (got, e) = read(&p, &opts, 100);
    assert_eq!(got.len(), 1);
    let e = e.unwrap().to_string();
    assert!(e.contains("byte 1") && e.contains("polarity 2"), "{e}");
    let p = dir.path().join("x.h5");
    root_file(&p, &[1.0, 2.0], &[1, 10], &[1, 1], &[1, 0]);
    let (got, e) = read(&p, &opts, 100);
    assert_eq!(got.len(), 1);
    assert!(
        matches!(e, Some(FormatError::OutOfBounds { x: 10, .. })),
        "{e:?}"
    );
    let p = dir.path().join("neg.h5");
    root_file(&p, &[1.0, 2.0], &[1, -1], &[1, 1], &[1, 0]);
    assert!(matches!(
        read(&p, &opts, 100).1,
        Some(FormatError::OutOfBounds { .. })
    ));
    let p = dir.path().join("order.h5");
    root_file(&p, &[2.0, 1.0], &[1, 1], &[1, 1], &[1, 0]);
    let (got, e) = read(&p, &opts, 100);
    assert_eq!(got.len(), 1);
    assert!(matches!(e, Some(FormatError::Unsorted { .. })), "{e:?}");
    let p = dir.path().join("nan.h5");
    root_file(&p, &[1.0, f64::NAN], &[1, 1], &[1, 1], &[1, 0]);
    let e = read(&p, &opts, 100).1.unwrap().to_string();
    assert!(e.contains("NaN is not a time"), "{e}");
}

#[test]
fn two_dimensional_datasets_and_unknown_units_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("2d.h5");
    let f = h5::File::create(&path).unwrap();
    f.new_dataset::<i64>().shape((2, 2)).create("t").unwrap();
    for n in ["x", "y", "p"] {
        put(&f, n, &[1i64, 0]);
    }
    drop(f);
    let e = read(&path, &ReadOptions::with_resolution(9, 9), 9)
        .1
        .unwrap()
        .to_string();
    assert!(e.contains("`/t` has shape [2, 2]"), "{e}");
    let path = dir.path().join("unit.h5");
    let f = h5::File::create(&path).unwrap();
    let t = put(&f, "t", &[1i64, 2]);
    let unit: h5::types::VarLenUnicode = "fortnights".parse().unwrap();
    t.new_attr::<h5::types::VarLenUnicode>()
        .create("unit")
        .unwrap()
        .write_scalar(&unit)
        .unwrap();
    for n in ["x", "y", "p"] {
        put(&f, n, &[1i64, 0]);
    }
    drop(f);
    let e = read(&path, &ReadOptions::with_resolution(9, 9), 9)
        .1
        .unwrap()
        .to_string();
    assert!(e.contains("unit `fortnights`"), "{e}");
}

#[test]
fn empty_and_missing_files() {
    let e = Hdf5Reader::open("/no/such.h5", &ReadOptions::default())
        .err()
        .unwrap();
    assert!(matches!(e, FormatError::Open { .. }) && e.to_string().contains("/no/such.h5"));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("none.h5");
    Hdf5Writer::create(&path, Resolution::new(4, 4))
        .unwrap()
        .finish()
        .unwrap();
    let (got, e) = read(&path, &ReadOptions::default(), 9);
    assert!(got.is_empty() && e.is_none(), "{e:?}");
}
