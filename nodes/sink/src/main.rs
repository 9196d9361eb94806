//! dora node: writes frames as PNG, scores them against ground truth, summarises the run.
//!
//! Inputs: `ground_truth` (Frame, optional) and any number of frame inputs under other ids (one per
//! method). Writes `<out>/<method>/<seq>.png`, `<out>/metrics.csv` (a row per frame, flushed as it
//! goes) and, at the end, `<out>/summary.md` with the mean metrics per method and the frames
//! expected, written and missing on every input.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::path::PathBuf;

use dora_node_api::{DoraNode, Event, EventStream};
use eyre::WrapErr;
use neuspike_schemas::node;
use neuspike_schemas::{Frame, Message, SeqStatus, SeqTracker, is_end_of_stream};
use neuspike_sink::metrics::{check_same_shape, entropy_2d, psnr, psnr_after_gain, ssim};
use neuspike_sink::png_out::{BitDepth, write_frame_png};
use neuspike_sink::report::{FrameMetrics, MetricsCsv, Summary};

/// Node arguments (the graph's `args:`).
#[derive(Debug, clap::Parser)]
#[command(
    name = "neuspike-sink",
    about = "Writes and scores frames",
    args_override_self = true
)]
struct Args {
    /// Output folder (relative paths are relative to the graph's folder).
    #[arg(long, default_value = "out")]
    out: PathBuf,
    /// PNG bit depth: 8 or 16.
    #[arg(long, default_value = "16")]
    bit_depth: BitDepth,
    /// Also write the ground-truth frames as PNG.
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    write_ground_truth: bool,
    /// Score a frame against the nearest ground truth within this many nanoseconds of its
    /// `t_ref_ns` (the earlier one on a tie); 0 asks for the same instant. Truth that is not taken
    /// on the reconstruction's grid, such as a DAVIS's APS frames, needs about half the time
    /// between two frames.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(i64).range(0..))]
    truth_within_ns: i64,
}

fn main() -> eyre::Result<()> {
    node::init_logging();
    let args: Args = node::parse_config("sink")?;
    let (node, events) = DoraNode::init_from_env()?;
    let has_gt = node
        .node_config()
        .inputs
        .keys()
        .any(|k| AsRef::<str>::as_ref(k) == "ground_truth");
    run(node, events, &args, has_gt)
}

/// Per-input bookkeeping.
#[derive(Default)]
struct InputState {
    seq: SeqTracker,
    written: u64,
    ended: bool,
}

struct Sink {
    out: PathBuf,
    depth: BitDepth,
    write_gt: bool,
    has_gt: bool,
    truth_within_ns: i64,
    csv: MetricsCsv,
    summary: Summary,
    inputs: BTreeMap<String, InputState>,
    /// Ground truth by time, kept until every frame input has passed it.
    truth: BTreeMap<i64, Frame>,
    truth_until_ns: i64,
    truth_closed: bool,
    /// Frames waiting for their ground truth.
    pending: VecDeque<(String, Frame)>,
    /// Per-method folders already created.
    made_dirs: BTreeSet<String>,
}

impl Sink {
    fn new(args: &Args, has_gt: bool) -> eyre::Result<Self> {
        std::fs::create_dir_all(&args.out).wrap_err_with(|| {
            format!(
                "sink: cannot create the output folder {}",
                args.out.display()
            )
        })?;
        let csv = MetricsCsv::create(&args.out.join("metrics.csv"))?;
        Ok(Sink {
            out: args.out.clone(),
            depth: args.bit_depth,
            write_gt: args.write_ground_truth,
            has_gt,
            truth_within_ns: args.truth_within_ns,
            csv,
            summary: Summary::default(),
            inputs: BTreeMap::new(),
            truth: BTreeMap::new(),
            truth_until_ns: i64::MIN,
            truth_closed: !has_gt,
            pending: VecDeque::new(),
            made_dirs: BTreeSet::new(),
        })
    }

    fn frame_path(&mut self, method: &str, seq: u64) -> eyre::Result<(PathBuf, String)> {
        if !self.made_dirs.contains(method) {
            let dir = self.out.join(method);
            std::fs::create_dir_all(&dir)
                .wrap_err_with(|| format!("sink: cannot create {}", dir.display()))?;
            self.made_dirs.insert(method.to_string());
        }
        let name = format!("{method}/{seq:06}.png");
        Ok((self.out.join(&name), name))
    }

    fn on_truth(&mut self, f: Frame) -> eyre::Result<()> {
        if self.write_gt {
            let (path, _) = self.frame_path("ground-truth", f.seq)?;
            write_frame_png(&path, f.data.view(), self.depth)?;
        }
        self.inputs
            .entry("ground_truth".to_string())
            .or_default()
            .written += 1;
        self.truth_until_ns = self.truth_until_ns.max(f.t_ref_ns);
        self.truth.insert(f.t_ref_ns, f);
        self.drain_pending()
    }

    fn on_frame(&mut self, input: &str, f: Frame) -> eyre::Result<()> {
        self.pending.push_back((input.to_string(), f));
        self.drain_pending()
    }

    /// Writes every pending frame whose ground truth has arrived or can no longer arrive.
    fn drain_pending(&mut self) -> eyre::Result<()> {
        while let Some((_, f)) = self.pending.front() {
            if !self.truth_closed
                && f.t_ref_ns.saturating_add(self.truth_within_ns) > self.truth_until_ns
            {
                break;
            }
            if let Some((input, f)) = self.pending.pop_front() {
                self.write(&input, f)?;
            }
        }
        Ok(())
    }

    fn write(&mut self, input: &str, f: Frame) -> eyre::Result<()> {
        let (path, name) = self.frame_path(&f.method, f.seq)?;
        write_frame_png(&path, f.data.view(), self.depth)?;
        let gt = self.nearest_truth(f.t_ref_ns);
        let (p, pg, ss) = match gt {
            Some(g) => {
                check_same_shape(f.data.view(), g.data.view())?;
                (
                    Some(psnr(f.data.view(), g.data.view())),
                    Some(psnr_after_gain(f.data.view(), g.data.view())),
                    Some(ssim(f.data.view(), g.data.view())),
                )
            }
            None => {
                if self.has_gt {
                    tracing::warn!(t_ref_ns = f.t_ref_ns, method = %f.method, "no ground truth at this instant");
                }
                (None, None, None)
            }
        };
        let row = FrameMetrics {
            seq: f.seq,
            t_ref_ns: f.t_ref_ns,
            method: f.method.clone(),
            compute_ns: f.compute_ns,
            psnr_db: p,
            psnr_gain_db: pg,
            ssim: ss,
            entropy_2d: entropy_2d(f.data.view()),
            file: name,
        };
        self.csv.append(&row)?;
        self.summary.add(&row);
        self.inputs.entry(input.to_string()).or_default().written += 1;
        self.evict_truth();
        Ok(())
    }

    /// The ground truth nearest `t_ns` within `truth_within_ns` (the earlier one on a tie).
    fn nearest_truth(&self, t_ns: i64) -> Option<&Frame> {
        let tol = self.truth_within_ns;
        let before = self.truth.range(..=t_ns).next_back();
        let after = self.truth.range(t_ns.saturating_add(1)..).next();
        let dist = |t: i64| t.abs_diff(t_ns);
        let best = match (before, after) {
            (Some(b), Some(a)) if dist(*a.0) < dist(*b.0) => a,
            (Some(b), _) => b,
            (None, Some(a)) => a,
            (None, None) => return None,
        };
        (dist(*best.0) <= tol.unsigned_abs()).then_some(best.1)
    }

    /// Forgets ground truth older than every frame still to come.
    fn evict_truth(&mut self) {
        let oldest_pending = self
            .pending
            .iter()
            .map(|(_, f)| f.t_ref_ns)
            .min()
            .unwrap_or(i64::MAX);
        let keep_from = oldest_pending
            .saturating_sub(self.truth_within_ns)
            .min(self.truth_until_ns.saturating_sub(TRUTH_HISTORY_NS));
        self.truth = self.truth.split_off(&keep_from);
    }

    fn finish(mut self) -> eyre::Result<()> {
        self.truth_closed = true;
        self.drain_pending()?;
        for (name, st) in &mut self.inputs {
            let expected = st.seq.announced();
            if !st.ended {
                tracing::error!(input = %name, "input ended without its end-of-stream marker");
            }
            self.summary.set_counts(
                name,
                expected.unwrap_or(st.seq.received() + st.seq.missing()),
                st.written,
                st.seq.missing(),
                st.ended,
            );
        }
        let table = self.summary.to_markdown_table();
        let path = self.out.join("summary.md");
        self.summary.write(&path)?;
        tracing::info!("summary written to {}", path.display());
        tracing::debug!("\n{table}");
        Ok(())
    }
}

/// How long ground truth is kept for frames that come late, nanoseconds.
const TRUTH_HISTORY_NS: i64 = 1_000_000_000;

fn run(_node: DoraNode, mut events: EventStream, args: &Args, has_gt: bool) -> eyre::Result<()> {
    let mut sink = Sink::new(args, has_gt)?;
    while let Some(event) = events.recv() {
        match event {
            Event::Input { id, metadata, data } => {
                let meta = &metadata.parameters;
                let id = id.to_string();
                let st = sink.inputs.entry(id.clone()).or_default();
                if let Some(n) = is_end_of_stream(meta) {
                    let lost = st.seq.end(n);
                    st.ended = true;
                    if lost > 0 {
                        tracing::error!(input = %id, lost, "frames lost at the end of the stream");
                    }
                    if id == "ground_truth" {
                        sink.truth_closed = true;
                        sink.drain_pending()?;
                    }
                } else {
                    let f = Frame::from_arrow(meta, data.as_array())
                        .wrap_err_with(|| format!("sink: bad frame on input `{id}`"))?;
                    if let SeqStatus::Gap { missing } = st.seq.observe(f.seq) {
                        tracing::error!(input = %id, seq = f.seq, missing, "frames lost before this one");
                    }
                    if id == "ground_truth" {
                        sink.on_truth(f)?;
                    } else {
                        sink.on_frame(&id, f)?;
                    }
                }
            }
            // dora's scheduler may yield `InputClosed` and `Stop` before the last inputs: only the
            // end-of-stream markers, or the end of the event stream, end an input.
            Event::InputClosed { id } => tracing::debug!(input = %id, "input closed"),
            Event::Stop(cause) => tracing::debug!(?cause, "stop received; draining the inputs"),
            _ => {}
        }
    }
    sink.finish()
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;
    use neuspike_schemas::FrameKind;
    use neuspike_schemas::testing::CannedInputs;

    fn frame(kind: FrameKind, method: &str, seq: u64, value: f32) -> Frame {
        Frame {
            kind,
            method: method.into(),
            t_ref_ns: 1_000 * seq as i64,
            compute_ns: 5,
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
        let args = Args {
            out: out.clone(),
            bit_depth: BitDepth::Eight,
            write_ground_truth: true,
            truth_within_ns: 0,
        };
        c.run(|node, events| run(node, events, &args, true))
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
        let args = Args {
            out: out.clone(),
            bit_depth: BitDepth::Eight,
            write_ground_truth: false,
            truth_within_ns: within_ns,
        };
        c.run(|node, events| run(node, events, &args, true))
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
}
