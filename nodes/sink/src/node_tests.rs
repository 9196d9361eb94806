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

fn config(out: &std::path::Path) -> SinkConfig {
    SinkConfig {
        out: out.to_path_buf(),
        bit_depth: BitDepth::Eight,
        write_ground_truth: false,
        truth_within_ns: 0,
        write_every: 1,
        score_every: 1,
        delay_us: 0,
    }
}

/// `frames` small frames on each of `methods` and their ends, run through the node writing into
/// `out` (the canned inputs under `dir`).
fn run_frames(
    dir: &std::path::Path,
    out: &std::path::Path,
    methods: &[&str],
    frames: u64,
) -> eyre::Result<()> {
    let mut c = CannedInputs::new(dir);
    for seq in 0..frames {
        for m in methods {
            let mut f = frame(FrameKind::Reconstruction, m, seq, 1.0);
            f.data = Array2::from_elem((2, 2), 0.5);
            c.message(m, &f)?;
        }
    }
    for m in methods {
        c.end::<Frame>(m, frames)?;
    }
    c.run(|node, events| run(node, events, &config(out), &inputs(methods)))
        .map(|_| ())
}

#[test]
fn a_frame_that_cannot_be_written_fails_the_node_and_its_summary_says_why() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    std::fs::create_dir(&out).unwrap();
    // The folder of the method's PNGs is a file.
    std::fs::write(out.join("tfp"), "in the way").unwrap();
    let e = format!(
        "{:#}",
        run_frames(dir.path(), &out, &["tfp"], 3).unwrap_err()
    );
    assert!(!e.contains('\n') && e.contains("tfp"), "{e}");
    let summary = std::fs::read_to_string(out.join("summary.md")).expect("summary written");
    assert!(summary.contains("**The sink failed**"), "{summary}");
    let read = neuspike_sink::read_run(&out).unwrap_err().to_string();
    assert!(read.contains("the sink failed"), "{read}");
}

#[test]
fn a_whole_run_reads_back_whole_and_a_cut_one_does_not() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    run_frames(dir.path(), &out, &["tfp"], 5).unwrap();
    let run = neuspike_sink::read_run(&out).expect("whole");
    assert_eq!(run.metrics_rows, 5);
    assert_eq!(run.inputs["tfp"].counts.written, 5);
    // The file cut after the run: a row short.
    let csv = std::fs::read_to_string(out.join("metrics.csv")).unwrap();
    let cut = &csv[..csv.trim_end().rfind('\n').unwrap() + 1];
    std::fs::write(out.join("metrics.csv"), cut).unwrap();
    let e = neuspike_sink::read_run(&out).unwrap_err().to_string();
    assert!(e.contains("holds 4 rows but summary.yml counts 5"), "{e}");
    // A second run into the same folder: the first run's summary goes when it starts, so a run
    // that stops part-way is never vouched for by an earlier one's.
    let sink = neuspike_sink::Sink::new(&config(&out), false).expect("sink");
    assert!(!out.join("summary.yml").exists() && !out.join("summary.md").exists());
    drop(sink);
    let e = neuspike_sink::read_run(&out).unwrap_err().to_string();
    assert!(e.contains("no summary.yml: the run did not finish"), "{e}");
}

/// Set by [`under_a_file_size_limit_the_counts_and_the_failure_still_reach_the_user`] for its
/// child: the folder to write into.
const LIMIT_CHILD: &str = "NEUSPIKE_SINK_LIMIT_CHILD";

/// The child's side: the node writes 400 frames on each of the methods its parent named into
/// the folder it named, under the parent's file size limit, and says how it ended on stderr.
#[test]
fn file_size_limit_child() {
    let Some(dir) = std::env::var_os(LIMIT_CHILD) else {
        return;
    };
    let dir = std::path::PathBuf::from(dir);
    let methods = std::env::var("NEUSPIKE_SINK_LIMIT_METHODS").unwrap_or_default();
    let methods: Vec<&str> = methods.split(',').collect();
    match run_frames(&dir.join("inputs"), &dir.join("out"), &methods, 400) {
        Ok(()) => eprintln!("CHILD: finished"),
        Err(e) => eprintln!("CHILD: {e:#}"),
    }
}

/// The node in a child process whose files may hold at most `kib` KiB (`ulimit -f`, the shell
/// ignoring SIGXFSZ so that a write past it fails as on a full disk): its stderr.
fn under_limit(dir: &std::path::Path, kib: u32, methods: &str) -> String {
    std::fs::create_dir_all(dir.join("inputs")).unwrap();
    let exe = std::env::current_exe().unwrap();
    let out = std::process::Command::new("bash")
        .arg("-c")
        .arg(format!("trap '' XFSZ; ulimit -f {kib}; exec \"$0\" \"$@\""))
        .arg(exe)
        .args([
            "--exact",
            "node_tests::file_size_limit_child",
            "--nocapture",
        ])
        .env(LIMIT_CHILD, dir)
        .env("NEUSPIKE_SINK_LIMIT_METHODS", methods)
        .output()
        .expect("bash");
    String::from_utf8_lossy(&out.stderr)
        .lines()
        .find_map(|l| l.strip_prefix("CHILD: ").map(String::from))
        .unwrap_or_else(|| panic!("the child said nothing: {out:?}"))
}

#[test]
fn under_a_file_size_limit_the_counts_and_the_failure_still_reach_the_user() {
    // 8 KiB a file: every frame fits, metrics.csv does not (400 rows of about 40 bytes), the
    // summary does. The node fails naming the file; the summary gives the counts and why.
    let dir = tempfile::tempdir().unwrap();
    let e = under_limit(dir.path(), 8, "tfp");
    assert!(
        e.contains("metrics.csv") && e.contains("File too large"),
        "{e}"
    );
    let out = dir.path().join("out");
    let summary = std::fs::read_to_string(out.join("summary.md")).expect("summary written");
    assert!(
        summary.contains("**The sink failed**") && summary.contains("File too large"),
        "{summary}"
    );
    let read = neuspike_sink::read_run(&out).unwrap_err().to_string();
    assert!(read.contains("the sink failed"), "{read}");
    // The rows before the failure are all there, whole, and the summary counts them.
    let yml = std::fs::read_to_string(out.join("summary.yml")).unwrap();
    let file: neuspike_sink::SummaryFile = serde_yaml::from_str(&yml).unwrap();
    let csv = std::fs::read_to_string(out.join("metrics.csv")).unwrap();
    let whole = csv.matches('\n').count() as u64 - 1;
    assert!(
        file.metrics_rows > 50 && file.metrics_rows == whole,
        "{file:?}"
    );
    assert_eq!(file.inputs["tfp"].counts.written, file.metrics_rows + 1);

    // 1 KiB a file: nor does the summary of four methods fit. The counts come with the error
    // on stderr.
    let dir = tempfile::tempdir().unwrap();
    let e = under_limit(dir.path(), 1, "tfp,tfi,tfstp,spk");
    assert!(
        e.contains("File too large")
            && e.contains("cannot write the summary")
            && e.contains("tfp: "),
        "{e}"
    );
}
