//! The node driven through its `run` loop with canned inputs.

use super::*;
use clap::Parser;
use dora_node_api::integration_testing::OutputJson;
use neuspike_formats::Event as Ev;
use neuspike_formats::Resolution;
use neuspike_formats::raw::Evt2Writer;
use neuspike_formats::text::TextWriter;
use neuspike_runtime::testing::{CannedInputs, output_ids, payload_len};
use neuspike_schemas::EventBatch;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

fn args(extra: &[&str]) -> Args {
    Args::try_parse_from(std::iter::once("event-source").chain(extra.iter().copied())).unwrap()
}

fn play_args(args: &Args) -> Vec<OutputJson> {
    let source = open_source(args).unwrap();
    let dir = tempfile::tempdir().unwrap();
    CannedInputs::new(dir.path())
        .run(|node, events| run(node, events, source, args))
        .unwrap()
}

/// The events of an output, from dora's testing JSON.
fn payload_events(o: &OutputJson) -> Vec<Ev> {
    o["data"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| Ev {
            t_ns: e["t_ns"].as_i64().unwrap(),
            x: u16::try_from(e["x"].as_u64().unwrap()).unwrap(),
            y: u16::try_from(e["y"].as_u64().unwrap()).unwrap(),
            polarity: i8::try_from(e["polarity"].as_i64().unwrap()).unwrap(),
        })
        .collect()
}

/// Every batch `EventFile` makes for `args` (the headers `run` sends).
fn batches(args: &Args) -> Vec<EventBatch> {
    let EventSource::File(mut f) = open_source(args).unwrap() else {
        panic!("a file source")
    };
    let mut out = Vec::new();
    while let Some(b) = f.next_batch().unwrap() {
        out.push(b);
    }
    out
}

/// Asserts consecutive half-open intervals numbered from 0, events inside their interval.
fn assert_contiguous(bs: &[EventBatch]) {
    for (i, b) in bs.iter().enumerate() {
        assert_eq!(b.seq, i as u64);
        assert!(b.t_start_ns < b.t_end_ns, "batch {i}");
        if i > 0 {
            assert_eq!(
                b.t_start_ns,
                bs[i - 1].t_end_ns,
                "batch {i} starts where {i}-1 ended"
            );
        }
        assert!(
            b.t_ns.iter().all(|&t| b.t_start_ns <= t && t < b.t_end_ns),
            "batch {i}"
        );
    }
}

fn ev(t_ns: i64, x: u16, y: u16, polarity: i8) -> Ev {
    Ev {
        t_ns,
        x,
        y,
        polarity,
    }
}

/// Ten events from 1.000 ms to 5.5 ms, two at the same time, one gap of 2 ms.
fn sample() -> Vec<Ev> {
    vec![
        ev(1_000_000, 0, 0, 1),
        ev(1_200_000, 3, 1, -1),
        ev(1_200_000, 4, 2, 1),
        ev(1_999_999, 5, 2, -1),
        ev(2_000_000, 6, 0, 1),
        ev(2_500_000, 7, 1, 1),
        ev(4_600_000, 1, 2, -1),
        ev(5_000_000, 2, 0, 1),
        ev(5_000_001, 2, 1, -1),
        ev(5_500_000, 9, 2, 1),
    ]
}

fn write_text(dir: &Path, events: &[Ev], size_line: bool) -> PathBuf {
    let path = dir.join("events.txt");
    let mut w = TextWriter::new(Vec::new(), &path, Resolution::new(10, 3), size_line).unwrap();
    for e in events {
        w.write_event(e).unwrap();
    }
    std::fs::write(&path, w.finish().unwrap().0).unwrap();
    path
}

#[test]
fn batches_cover_time_and_end() {
    let args = args(&[
        "--scene",
        "bright-fast",
        "--width",
        "34",
        "--height",
        "26",
        "--batch-ns",
        "1000000",
        "--end-ns",
        "3500000",
    ]);
    let out = play_args(&args);
    // 3.5 ms in 1 ms batches: 4 batches and the marker.
    assert_eq!(output_ids(&out), vec!["events"; 5]);
    assert!(
        out[..4].iter().map(payload_len).sum::<usize>() > 0,
        "a fast scene makes events"
    );
    assert_eq!(payload_len(&out[4]), 0);
}

#[test]
fn file_arguments_are_checked() {
    let bad = |a: &[&str]| {
        Args::try_parse_from(std::iter::once("event-source").chain(a.iter().copied()))
            .unwrap_err()
            .to_string()
    };
    let e = bad(&["--file", "e.txt", "--scene", "bright-fast"]);
    assert!(e.contains("--scene") && e.contains("--file"), "{e}");
    let e = bad(&["--file", "e.txt", "--file-width", "240"]);
    assert!(e.contains("--file-height"), "{e}");
    let e = bad(&["--file", "e.txt", "--height", "180"]);
    assert!(e.contains("--height") && e.contains("--file"), "{e}");
    let e = bad(&["--start-ns", "5"]);
    assert!(e.contains("--file"), "{e}");
    let e = bad(&["--file", "e.txt", "--pace", "slow"]);
    assert!(e.contains("pace") && e.contains("slow"), "{e}");
    let a = args(&["--file", "e.txt", "--start-ns", "-5", "--end-ns", "-1"]);
    assert_eq!((a.source.start_ns, a.source.end_ns), (Some(-5), Some(-1)));
    let e = format!(
        "{:#}",
        open_source(&args(&[
            "--file",
            "e.txt",
            "--start-ns",
            "5",
            "--end-ns",
            "5"
        ]))
        .err()
        .unwrap()
    );
    assert!(e.contains("end-ns") && e.contains("start-ns"), "{e}");
}

#[test]
fn bad_files_are_named_before_any_message() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_text(dir.path(), &sample(), false);
    let p = path.to_str().unwrap();
    // No size line and no --file-width/--file-height.
    let e = format!("{:#}", open_source(&args(&["--file", p])).err().unwrap());
    assert!(e.contains("events.txt"), "{e}");
    // A size that disagrees with the file's.
    let path = write_text(dir.path(), &sample(), true);
    let p = path.to_str().unwrap();
    let e = format!(
        "{:#}",
        open_source(&args(&[
            "--file",
            p,
            "--file-width",
            "11",
            "--file-height",
            "3"
        ]))
        .err()
        .unwrap()
    );
    assert!(e.contains("events.txt"), "{e}");
}

#[test]
fn plays_a_written_text_file_in_contiguous_batches() {
    let dir = tempfile::tempdir().unwrap();
    let events = sample();
    let path = write_text(dir.path(), &events, false);
    let a = args(&[
        "--file",
        path.to_str().unwrap(),
        "--file-width",
        "10",
        "--file-height",
        "3",
    ]);
    let out = play_args(&a);
    // From the first event (1 ms) to the last + 1 ns (5.5 ms + 1 ns): five batches, the
    // fourth empty, the last shortened.
    assert_eq!(output_ids(&out), vec!["events"; 6]);
    let sent: Vec<Vec<Ev>> = out.iter().map(payload_events).collect();
    assert_eq!(
        sent.iter().map(Vec::len).collect::<Vec<_>>(),
        [4, 2, 0, 1, 3, 0]
    );
    assert_eq!(sent.concat(), events);

    let bs = batches(&a);
    assert_contiguous(&bs);
    let intervals: Vec<(i64, i64)> = bs.iter().map(|b| (b.t_start_ns, b.t_end_ns)).collect();
    assert_eq!(
        intervals,
        [
            (1_000_000, 2_000_000),
            (2_000_000, 3_000_000),
            (3_000_000, 4_000_000),
            (4_000_000, 5_000_000),
            (5_000_000, 5_500_001)
        ]
    );
    assert!(bs.iter().all(|b| (b.width, b.height) == (10, 3)));
}

#[test]
fn a_gap_in_a_recording_is_one_empty_batch_not_one_per_interval() {
    let dir = tempfile::tempdir().unwrap();
    // A day between two events, 1 ms batches: 86 million empty batches played one by one.
    let day = 86_400_000_000_000;
    let events = [ev(1_000_000, 0, 0, 1), ev(day + 1_500_000, 1, 1, -1)];
    let path = write_text(dir.path(), &events, false);
    let a = args(&[
        "--file",
        path.to_str().unwrap(),
        "--file-width",
        "10",
        "--file-height",
        "3",
    ]);
    let bs = batches(&a);
    assert_contiguous(&bs);
    let intervals: Vec<(i64, i64)> = bs.iter().map(|b| (b.t_start_ns, b.t_end_ns)).collect();
    assert_eq!(
        intervals,
        [
            (1_000_000, 2_000_000),
            (2_000_000, day + 1_000_000),
            (day + 1_000_000, day + 1_500_001)
        ]
    );
    assert_eq!(bs.iter().map(|b| b.len()).sum::<usize>(), 2);
}

#[test]
fn start_end_and_batch_length_cut_an_evt2_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("events.raw");
    let mut w = Evt2Writer::new(Vec::new(), &path, Resolution::new(10, 3)).unwrap();
    for e in sample() {
        w.write_event(&e).unwrap();
    }
    std::fs::write(&path, w.finish().unwrap().0).unwrap();
    let p = path.to_str().unwrap();

    let a = args(&[
        "--file",
        p,
        "--start-ns",
        "1500000",
        "--end-ns",
        "5000001",
        "--batch-ns",
        "1500000",
    ]);
    let bs = batches(&a);
    assert_contiguous(&bs);
    let intervals: Vec<(i64, i64)> = bs.iter().map(|b| (b.t_start_ns, b.t_end_ns)).collect();
    assert_eq!(
        intervals,
        [
            (1_500_000, 3_000_000),
            (3_000_000, 4_500_000),
            (4_500_000, 5_000_001)
        ]
    );
    let counts: Vec<usize> = bs.iter().map(EventBatch::len).collect();
    // EVT 2.0 keeps microseconds: 1,999,999 ns comes back as 1,999,000.
    assert_eq!(counts, [3, 0, 3]);
    assert_eq!(bs[0].t_ns, [1_999_000, 2_000_000, 2_500_000]);
    assert_eq!(bs[2].t_ns, [4_600_000, 5_000_000, 5_000_000]);

    let out = play_args(&a);
    assert_eq!(
        out.iter().map(payload_len).collect::<Vec<_>>(),
        [3, 0, 3, 0],
        "three batches and the marker"
    );

    // A window after the last event: nothing to play, just the marker.
    let a = args(&["--file", p, "--start-ns", "9000000"]);
    assert!(batches(&a).is_empty());
    assert_eq!(play_args(&a).len(), 1);
}

#[test]
fn a_corrupt_file_delivers_what_came_before_the_fault() {
    let dir = tempfile::tempdir().unwrap();
    let events = sample();
    let path = write_text(dir.path(), &events, true);
    let mut text = std::fs::read_to_string(&path).unwrap();
    text.push_str("6.000000000 99 1 1\n7.000000000 1 1 1\n");
    std::fs::write(&path, text).unwrap();
    let a = args(&["--file", path.to_str().unwrap()]);
    let EventSource::File(mut f) = open_source(&a).unwrap() else {
        panic!("a file source")
    };
    let mut good = Vec::new();
    let e = loop {
        match f.next_batch() {
            Ok(Some(b)) => good.push(b),
            Ok(None) => panic!("the fault must be reported"),
            Err(e) => break e,
        }
    };
    assert_contiguous(&good);
    assert_eq!(
        good.iter().map(EventBatch::len).sum::<usize>(),
        events.len()
    );
    assert_eq!(good.last().unwrap().t_end_ns, 5_500_001);
    let msg = e.to_string();
    assert!(
        msg.contains("events.txt") && msg.contains("line 12"),
        "{msg}"
    );
    assert!(f.next_batch().unwrap().is_none());

    // Through the node: the batches, the marker, then the node fails naming the fault.
    let source = open_source(&a).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let e = CannedInputs::new(tmp.path())
        .run(|node, events| run(node, events, source, &a))
        .unwrap_err();
    assert!(format!("{e:#}").contains("line 12"), "{e:#}");
}

#[test]
fn realtime_pace_follows_the_recording_clock() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_text(dir.path(), &sample(), true);
    let a = args(&["--file", path.to_str().unwrap(), "--pace", "realtime"]);
    let start = Instant::now();
    let out = play_args(&a);
    // The stream covers 4.5 ms of the recording.
    assert!(start.elapsed() >= Duration::from_micros(4_500));
    assert_eq!(out.len(), 6);
}

#[test]
fn plays_the_real_davis_text() {
    let Some(path) =
        neuspike_runtime::testing::real_recording("davis240c-shapes-rotation-events.txt")
    else {
        return;
    };
    let a = args(&[
        "--file",
        path.to_str().unwrap(),
        "--file-width",
        "240",
        "--file-height",
        "180",
    ]);
    let out = play_args(&a);
    // 2.097134001 s to 2.195729 s in 1 ms batches: 99 batches and the marker.
    assert_eq!(out.len(), 100);
    let sent: Vec<Vec<Ev>> = out.iter().map(payload_events).collect();
    let all = sent.concat();
    assert_eq!(all.len(), 20_000);
    assert_eq!(all[0], ev(2_097_134_001, 162, 27, -1));
    assert_eq!(all[19_999], ev(2_195_729_000, 127, 147, 1));
    let bs = batches(&a);
    assert_contiguous(&bs);
    assert_eq!(bs[0].t_start_ns, 2_097_134_001);
    assert_eq!(bs[98].t_end_ns, 2_195_729_001);
}

#[test]
fn plays_the_real_prophesee_raw() {
    let Some(path) = neuspike_runtime::testing::real_recording("prophesee-evt2-640x480.raw") else {
        return;
    };
    // Its header states no geometry: the README gives 640x480.
    let a = args(&[
        "--file",
        path.to_str().unwrap(),
        "--file-width",
        "640",
        "--file-height",
        "480",
        "--batch-ns",
        "10000000",
    ]);
    let bs = batches(&a);
    assert_contiguous(&bs);
    assert_eq!(bs.iter().map(EventBatch::len).sum::<usize>(), 521_252);
    assert_eq!(bs[0].t_start_ns, 913_716_224_000);
    assert_eq!(bs.last().unwrap().t_end_ns, 913_812_095_001);
    assert_eq!(bs.len(), 10);
    assert!(bs.iter().all(|b| (b.width, b.height) == (640, 480)));
    let out = play_args(&a);
    assert_eq!(out.len(), 11);
    assert_eq!(out.iter().map(payload_len).sum::<usize>(), 521_252);
}
