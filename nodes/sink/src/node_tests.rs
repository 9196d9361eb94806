//! The node driven through its `run` loop with canned inputs.

use super::*;
use ndarray::Array2;
use neuspike_schemas::{Frame, FrameKind};
use neuspike_sink::BitDepth;

fn inputs(ids: &[&str]) -> Vec<String> {
    ids.iter().map(|s| s.to_string()).collect()
}
use neuspike_runtime::testing::CannedInputs;

fn frame(kind: FrameKind, method: &str, seq: u64, value: f32) -> Frame {
    Frame {
        kind,
        method: method.into(),
        t_ref_ns: 1_000 * seq as i64,
        compute_ns: 5,
        chosen: None,
        budget_ns: None,
        seq,
        data: Array2::from_shape_fn((16, 16), |(y, x)| value * (x + y) as f32 / 30.0),
    }
}

#[test]
fn writes_scores_and_summarises() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let mut c = CannedInputs::new(dir.path());
    // Frames arrive before their ground truth: the sink must wait for it.
    c.message("tfp", &frame(FrameKind::Reconstruction, "tfp", 0, 1.0))
        .unwrap();
    c.message(
        "ground_truth",
        &frame(FrameKind::GroundTruth, "ground-truth", 0, 1.0),
    )
    .unwrap();
    c.message(
        "ground_truth",
        &frame(FrameKind::GroundTruth, "ground-truth", 1, 1.0),
    )
    .unwrap();
    // seq 1 of tfp is lost; seq 2 has no truth.
    c.message("tfp", &frame(FrameKind::Reconstruction, "tfp", 2, 0.9))
        .unwrap();
    c.end::<Frame>("tfp", 3).unwrap();
    c.end::<Frame>("ground_truth", 2).unwrap();
    let cfg = SinkConfig {
        out: out.clone(),
        bit_depth: BitDepth::Eight,
        write_ground_truth: true,
        truth_within_ns: 0,
        write_every: 1,
        score_every: 1,
        delay_us: 0,
    };
    c.run(|node, events| run(node, events, &cfg, &inputs(&["tfp", "ground_truth"])))
        .unwrap();
    let csv = std::fs::read_to_string(out.join("metrics.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().skip(1).collect();
    assert_eq!(rows.len(), 2, "{csv}");
    assert!(
        rows[0].contains(",inf,"),
        "identical frame is exact: {}",
        rows[0]
    );
    assert!(out.join("tfp/000000.png").is_file() && out.join("tfp/000002.png").is_file());
    assert!(out.join("ground-truth/000001.png").is_file());
    let summary = std::fs::read_to_string(out.join("summary.md")).unwrap();
    assert!(summary.contains("tfp"), "{summary}");
}

/// Scores of a run whose truth lies `offset_ns` after each frame, matched within `within_ns`.
fn scores_with_offset_truth(offset_ns: i64, within_ns: i64) -> Vec<String> {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let mut c = CannedInputs::new(dir.path());
    for seq in 0..3 {
        let mut gt = frame(FrameKind::GroundTruth, "ground-truth", seq, 1.0);
        gt.t_ref_ns += offset_ns;
        // Truth 1 is dimmer, so which truth scored a frame shows in its PSNR.
        if seq == 1 {
            gt.data *= 0.5;
        }
        c.message("tfp", &frame(FrameKind::Reconstruction, "tfp", seq, 1.0))
            .unwrap();
        c.message("ground_truth", &gt).unwrap();
    }
    c.end::<Frame>("tfp", 3).unwrap();
    c.end::<Frame>("ground_truth", 3).unwrap();
    let cfg = SinkConfig {
        out: out.clone(),
        bit_depth: BitDepth::Eight,
        write_ground_truth: false,
        truth_within_ns: within_ns,
        write_every: 1,
        score_every: 1,
        delay_us: 0,
    };
    c.run(|node, events| run(node, events, &cfg, &inputs(&["tfp", "ground_truth"])))
        .unwrap();
    let csv = std::fs::read_to_string(out.join("metrics.csv")).unwrap();
    // The PSNR column.
    csv.lines()
        .skip(1)
        .map(|r| r.split(',').nth(4).unwrap().to_string())
        .collect()
}

#[test]
fn truth_off_the_frame_grid_is_matched_to_the_nearest_within_the_tolerance() {
    // Truth 300 ns after each frame (frames are 1,000 ns apart).
    let exact = scores_with_offset_truth(300, 0);
    assert!(exact.iter().all(String::is_empty), "{exact:?}");
    let near = scores_with_offset_truth(300, 400);
    assert_eq!(near[0], "inf");
    assert_ne!(
        near[1], "inf",
        "frame 1 is scored against the dimmer truth 1"
    );
    assert_eq!(near[2], "inf");
    // Truth 700 ns after each frame is nearer the next frame: frame 1 takes truth 0 (300 ns
    // before it) and frame 2 truth 1; frame 0 has none within 400 ns.
    let next = scores_with_offset_truth(700, 400);
    assert_eq!(next[0], "");
    assert_eq!(next[1], "inf");
    assert_ne!(next[2], "inf");
    assert_ne!(next[2], "");
}
