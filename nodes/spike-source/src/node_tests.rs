//! The node driven through its `run` loop with canned inputs.

use super::*;
use clap::Parser;
use dora_node_api::integration_testing::OutputJson;
use neuspike_formats::FormatError;
use neuspike_formats::pku::PkuGeometry;
use neuspike_formats::pku::PkuWriter;
use neuspike_runtime::testing::{CannedInputs, output_ids, payload_len};
use neuspike_schemas::bytes_per_plane;
use neuspike_spike_camera::playback::DEFAULT_FILE_LUM_PER_RATE;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

fn args(extra: &[&str]) -> Args {
    Args::try_parse_from(std::iter::once("spike-source").chain(extra.iter().copied())).unwrap()
}

/// Plays `args` through `run` on a testing node; returns what it sent.
fn play_args(args: &Args) -> Vec<OutputJson> {
    let source = open_source(args).unwrap();
    let dir = tempfile::tempdir().unwrap();
    CannedInputs::new(dir.path())
        .run(|node, events| run(node, events, source, args))
        .unwrap()
}

fn payload_bytes(o: &OutputJson) -> Vec<u8> {
    o["data"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| u8::try_from(v.as_u64().unwrap()).unwrap())
        .collect()
}

/// `n` planes of `w x h` in the pipeline layout: pseudo-random, padding bits clear.
fn planes(n: usize, w: usize, h: usize, mut s: u64) -> Vec<u8> {
    let per = bytes_per_plane(w, h);
    let mut bits: Vec<u8> = (0..n * per)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s as u8
        })
        .collect();
    let pad = per * 8 - w * h;
    if pad > 0 {
        for p in bits.chunks_exact_mut(per) {
            p[per - 1] &= 0xFF >> pad;
        }
    }
    bits
}

/// Writes `bits` as a PKU file (plus `extra` stray bytes) and returns its path.
fn write_dat(dir: &Path, g: PkuGeometry, bits: &[u8], extra: &[u8]) -> PathBuf {
    let path = dir.join("planes.dat");
    let mut w = PkuWriter::new(Vec::new(), &path, g).unwrap();
    w.write_planes(bits).unwrap();
    let (mut bytes, _) = w.finish().unwrap();
    bytes.extend_from_slice(extra);
    std::fs::write(&path, bytes).unwrap();
    path
}

#[test]
fn chunks_ground_truth_and_end_markers() {
    let args = args(&[
        "--scene",
        "bright-static",
        "--width",
        "40",
        "--height",
        "25",
        "--chunk-planes",
        "20",
        "--gt-every-planes",
        "20",
        "--max-planes",
        "50",
    ]);
    let out = play_args(&args);
    let ids = output_ids(&out);
    // 50 planes: chunks of 20, 20, 10; truth at planes 0, 20, 40.
    assert_eq!(ids.iter().filter(|i| *i == "spikes").count(), 4);
    assert_eq!(ids.iter().filter(|i| *i == "ground_truth").count(), 4);
    let spikes: Vec<usize> = out
        .iter()
        .filter(|o| o["id"] == "spikes")
        .map(payload_len)
        .collect();
    let per = bytes_per_plane(40, 25);
    assert_eq!(spikes, vec![20 * per, 20 * per, 10 * per, 0]);
}

#[test]
fn a_recording_played_from_its_middle_keeps_its_clock_and_its_truth() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (16, 4);
    let path = write_dat(dir.path(), PkuGeometry::new(w, h), &planes(9, w, h, 3), &[]);
    let truth = dir.path().join("gt");
    std::fs::create_dir(&truth).unwrap();
    let list = "0 0 a.png\n4 4000000 b.png\n8 8000000 c.png\n";
    std::fs::write(truth.join("timestamps.txt"), list).unwrap();
    for (name, v) in [("a.png", 0u16), ("b.png", 30_000), ("c.png", 60_000)] {
        image::ImageBuffer::<image::Luma<u16>, _>::from_pixel(16, 4, image::Luma([v]))
            .save(truth.join(name))
            .unwrap();
    }
    let a = args(&[
        "--file",
        path.to_str().unwrap(),
        "--file-width",
        "16",
        "--file-height",
        "4",
        "--start-plane",
        "2",
        "--chunk-planes",
        "4",
        "--rate-hz",
        "1000",
        "--truth",
        truth.to_str().unwrap(),
    ]);
    let out = play_args(&a);
    let gt: Vec<&OutputJson> = out.iter().filter(|o| o["id"] == "ground_truth").collect();
    // Planes 2..9 are played: the truth of planes 4 and 8, at their times, then the marker.
    assert_eq!(gt.len(), 3, "{out:?}");
    // Told apart by their levels: a.png (plane 0, before the start) is not sent.
    let level = |o: &OutputJson| o["data"][0].as_f64().unwrap();
    assert!(
        (level(gt[0]) - 30_000.0 / 65_535.0).abs() < 1e-6,
        "{:?}",
        gt[0]
    );
    assert!((level(gt[1]) - 60_000.0 / 65_535.0).abs() < 1e-6);
    assert_eq!(payload_len(gt[0]), 16 * 4);
    assert_eq!(payload_len(gt[2]), 0, "end-of-stream marker");
}

#[test]
fn a_wrong_key_is_named() {
    let e = Args::try_parse_from(["spike-source", "--rate-hz", "fast"])
        .unwrap_err()
        .to_string();
    assert!(e.contains("rate-hz") && e.contains("fast"), "{e}");
    let e = Args::try_parse_from(["spike-source", "--sceen", "x"])
        .unwrap_err()
        .to_string();
    assert!(e.contains("--sceen"), "{e}");
}

#[test]
fn file_arguments_are_checked() {
    let bad = |a: &[&str]| {
        Args::try_parse_from(std::iter::once("spike-source").chain(a.iter().copied()))
            .unwrap_err()
            .to_string()
    };
    let e = bad(&["--file", "a.dat", "--scene", "bright-slow"]);
    assert!(e.contains("--scene") && e.contains("--file"), "{e}");
    let e = bad(&["--file", "a.dat", "--gt-every-planes", "20"]);
    assert!(e.contains("--gt-every-planes"), "{e}");
    let e = bad(&["--file", "a.dat", "--width", "40"]);
    assert!(e.contains("--width") && e.contains("--file"), "{e}");
    let e = bad(&["--start-plane", "3"]);
    assert!(e.contains("--file"), "{e}");
    let e = bad(&["--file", "a.dat", "--head-columns", "8"]);
    assert!(e.contains("head-columns") && e.contains('8'), "{e}");
    let e = bad(&["--file", "a.dat", "--pace", "slow"]);
    assert!(e.contains("pace") && e.contains("slow"), "{e}");
    // Defaults alone do not need --file.
    let a = args(&[]);
    assert!(a.source.file.is_none());
    assert_eq!(
        (
            a.source.file_width,
            a.source.file_height,
            a.source.head_columns
        ),
        (400, 250, 0)
    );
    assert_eq!(a.pace, Pace::Fast);
}

#[test]
fn bad_files_are_named_before_any_message() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.dat");
    let a = args(&["--file", missing.to_str().unwrap()]);
    let e = format!("{:#}", open_source(&a).err().unwrap());
    assert!(e.contains("missing.dat"), "{e}");

    let g = PkuGeometry::new(16, 4);
    let path = write_dat(dir.path(), g, &planes(3, 16, 4, 1), &[]);
    let p = path.to_str().unwrap();
    // 24-byte file, 12,500-byte planes: not even one plane.
    let e = format!("{:#}", open_source(&args(&["--file", p])).err().unwrap());
    assert!(e.contains("planes.dat") && e.contains("24 bytes"), "{e}");
    let e = format!(
        "{:#}",
        open_source(&args(&[
            "--file",
            p,
            "--file-width",
            "16",
            "--file-height",
            "4",
            "--start-plane",
            "3"
        ]))
        .err()
        .unwrap()
    );
    assert!(
        e.contains("start plane 3") && e.contains("3 whole planes"),
        "{e}"
    );
    let e = format!(
        "{:#}",
        open_source(&args(&["--file", p, "--lum-per-rate", "0"]))
            .err()
            .unwrap()
    );
    assert!(e.contains("`lum-per-rate` = 0"), "{e}");
}

#[test]
fn plays_a_written_file_byte_exact() {
    let dir = tempfile::tempdir().unwrap();
    // Odd width: the reader's bit-by-bit path; 7 planes in chunks of 3.
    let (w, h) = (13, 5);
    let bits = planes(7, w, h, 42);
    let path = write_dat(dir.path(), PkuGeometry::new(w, h), &bits, &[]);
    let a = args(&[
        "--file",
        path.to_str().unwrap(),
        "--file-width",
        "13",
        "--file-height",
        "5",
        "--chunk-planes",
        "3",
    ]);
    let out = play_args(&a);
    assert_eq!(output_ids(&out), vec!["spikes"; 4]);
    let per = bytes_per_plane(w, h);
    let sent: Vec<Vec<u8>> = out.iter().map(payload_bytes).collect();
    assert_eq!(sent[0], bits[..3 * per]);
    assert_eq!(sent[1], bits[3 * per..6 * per]);
    assert_eq!(sent[2], bits[6 * per..]);
    assert!(sent[3].is_empty(), "end-of-stream marker");

    // The headers `run` sends: the same numbering as the simulator's.
    let SpikeSource::File(mut playback) = open_source(&a).unwrap() else {
        panic!("a file source")
    };
    let f = playback.file();
    let mut seq = 0;
    let mut first = 0;
    while let Some(c) = f.next_chunk(3, seq).unwrap() {
        assert_eq!(
            (c.seq, c.first_plane, c.width, c.height),
            (seq, first, w, h)
        );
        assert_eq!(c.t_first_ns, first as i64 * 50_000);
        assert_eq!(c.plane_period_ns, 50_000);
        assert_eq!(c.lum_per_rate, Some(DEFAULT_FILE_LUM_PER_RATE));
        seq += 1;
        first += c.n_planes as u64;
    }
    assert_eq!((seq, first), (3, 7));
}

#[test]
fn start_max_rate_head_columns_and_calibration() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (400, 2);
    let bits = planes(9, w, h, 5);
    let path = write_dat(dir.path(), PkuGeometry::with_head(w, h), &bits, &[]);
    let a = args(&[
        "--file",
        path.to_str().unwrap(),
        "--file-height",
        "2",
        "--head-columns",
        "16",
        "--start-plane",
        "2",
        "--max-planes",
        "5",
        "--chunk-planes",
        "4",
        "--rate-hz",
        "1000",
        "--lum-per-rate",
        "2.5",
    ]);
    let out = play_args(&a);
    let per = bytes_per_plane(w, h);
    let sent: Vec<Vec<u8>> = out.iter().map(payload_bytes).collect();
    assert_eq!(sent.len(), 3);
    assert_eq!(sent[0], bits[2 * per..6 * per]);
    assert_eq!(sent[1], bits[6 * per..7 * per]);
    assert!(sent[2].is_empty());

    let SpikeSource::File(mut playback) = open_source(&a).unwrap() else {
        panic!("a file source")
    };
    let f = playback.file();
    let c = f.next_chunk(4, 0).unwrap().unwrap();
    // Planes keep their number and time in the file, so that events and ground truth
    // recorded with it still line up.
    assert_eq!(
        (c.first_plane, c.t_first_ns, c.plane_period_ns),
        (2, 2_000_000, 1_000_000)
    );
    assert_eq!(f.start_time_ns(), 2_000_000);
    assert_eq!(c.lum_per_rate, Some(2.5));
    let c = f.next_chunk(4, 1).unwrap().unwrap();
    assert_eq!((c.seq, c.first_plane, c.t_first_ns), (1, 6, 6_000_000));
}

#[test]
fn a_truncated_file_delivers_its_whole_planes_then_ends() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (16, 4);
    let g = PkuGeometry::new(w, h);
    let per = bytes_per_plane(w, h);
    let bits = planes(5, w, h, 9);
    let path = write_dat(dir.path(), g, &bits, &[0xAB; 3]);
    let a = args(&[
        "--file",
        path.to_str().unwrap(),
        "--file-width",
        "16",
        "--file-height",
        "4",
        "--chunk-planes",
        "2",
    ]);
    let out = play_args(&a);
    let sent: Vec<Vec<u8>> = out.iter().map(payload_bytes).collect();
    assert_eq!(sent.len(), 4, "chunks of 2, 2, 1 planes and the marker");
    assert_eq!(sent[..3].concat(), bits);
    assert!(sent[3].is_empty());

    // The error names the file and the partial plane's offset from the start of the file,
    // also when playing starts past the first plane.
    let a = args(&[
        "--file",
        path.to_str().unwrap(),
        "--file-width",
        "16",
        "--file-height",
        "4",
        "--start-plane",
        "1",
    ]);
    let SpikeSource::File(mut playback) = open_source(&a).unwrap() else {
        panic!("a file source")
    };
    let f = playback.file();
    let c = f.next_chunk(10, 0).unwrap().unwrap();
    assert_eq!(c.bits, bits[per..]);
    let e = f.next_chunk(10, 1).unwrap_err();
    let msg = e.to_string();
    assert!(
        matches!(
            e,
            FormatError::PartialPlane {
                tail_offset: 40,
                tail_bytes: 3,
                whole_planes: 5,
                size: 43,
                ..
            }
        ),
        "{msg}"
    );
    assert!(
        msg.contains("planes.dat") && msg.contains("at byte 40"),
        "{msg}"
    );
}

#[test]
fn realtime_pace_follows_the_plane_rate() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_dat(
        dir.path(),
        PkuGeometry::new(8, 2),
        &planes(20, 8, 2, 3),
        &[],
    );
    let a = args(&[
        "--file",
        path.to_str().unwrap(),
        "--file-width",
        "8",
        "--file-height",
        "2",
        "--chunk-planes",
        "5",
        "--rate-hz",
        "1000",
        "--pace",
        "realtime",
    ]);
    let start = Instant::now();
    let out = play_args(&a);
    // 20 planes at 1 kHz: the last chunk is due 20 ms after the start.
    assert!(start.elapsed() >= Duration::from_millis(20));
    assert_eq!(out.len(), 5);
}

#[test]
fn plays_the_real_vidar_recording() {
    let Some(path) = neuspike_runtime::testing::real_recording("vidar-car-400x250.dat") else {
        return;
    };
    let a = args(&["--file", path.to_str().unwrap(), "--chunk-planes", "32"]);
    let out = play_args(&a);
    // 200 planes of 12,500 bytes: six chunks of 32, one of 8, and the marker.
    let lens: Vec<usize> = out.iter().map(payload_len).collect();
    assert_eq!(lens, [&[32 * 12_500; 6][..], &[8 * 12_500, 0]].concat());
    let sent: Vec<u8> = out.iter().flat_map(payload_bytes).collect();
    let spikes: u64 = sent.iter().map(|b| u64::from(b.count_ones())).sum();
    assert_eq!(spikes, 7_324_316, "the README's spike count");
    // Byte-exact against the file, rows flipped upright (400 pixels = 50 bytes a row).
    let raw = std::fs::read(&path).unwrap();
    for (stored, plane) in raw.chunks_exact(12_500).zip(sent.chunks_exact(12_500)) {
        for y in 0..250 {
            let src = (249 - y) * 50;
            assert_eq!(plane[y * 50..y * 50 + 50], stored[src..src + 50]);
        }
    }
}
