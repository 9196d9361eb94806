//! The sink's stage: frames written as PNG as they come, each scored against the ground truth
//! nearest its instant, one metrics row a frame, and the run's summary at the end.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::path::{Path, PathBuf};

use neuspike_schemas::Frame;

use crate::SinkError;
use crate::report::{FrameMetrics, InputCounts, MetricsCsv, Summary};
use neuspike_image::{BitDepth, write_frame_png};
use neuspike_metrics::{check_same_shape, entropy_2d, psnr, psnr_after_gain, ssim};

/// The sink's settings (the node's `args:`).
#[derive(Clone, Debug, clap::Args)]
pub struct SinkConfig {
    /// Output folder (relative paths are relative to the graph's folder).
    #[arg(long, default_value = "out")]
    pub out: PathBuf,
    /// PNG bit depth: 8 or 16.
    #[arg(long, default_value = "16")]
    pub bit_depth: BitDepth,
    /// Also write the ground-truth frames as PNG.
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    pub write_ground_truth: bool,
    /// Score a frame against the nearest ground truth within this many nanoseconds of its
    /// `t_ref_ns` (the earlier one on a tie); 0 asks for the same instant. Truth that is not taken
    /// on the reconstruction's grid, such as a DAVIS's APS frames, needs about half the time
    /// between two frames.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(i64).range(0..))]
    pub truth_within_ns: i64,
    /// Write a PNG of one frame in N (those whose sequence number is a multiple of N, so that
    /// every method keeps the same instants); every frame is still received and counted. A live
    /// graph at 1,000 frames/s sets it so that the disk does not hold the camera back.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    pub write_every: u64,
    /// Score one frame in N (metrics and a `metrics.csv` row), chosen as `--write-every` does.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    pub score_every: u64,
    /// Sleep this many microseconds after each reconstructed frame: a deliberately slow consumer,
    /// to see what one does to a graph (credits hold its producers back; nothing queues up).
    #[arg(long, default_value_t = 0)]
    pub delay_us: u64,
}

/// How long ground truth is kept for frames that come late, nanoseconds.
const TRUTH_HISTORY_NS: i64 = 1_000_000_000;

/// One input's tally as the receive loop kept it, for the summary.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct InputTally {
    /// The count its end-of-stream marker announced, if it came.
    pub announced: Option<u64>,
    /// Messages received.
    pub received: u64,
    /// Messages known to be missing.
    pub missing: u64,
    /// Whether its end-of-stream marker came.
    pub ended: bool,
    /// Whether the stream was cut short by a node that failed upstream.
    pub cut: bool,
}

/// Writes and scores frames. Frames wait for the ground truth of their instant (or for the truth
/// stream to move past it, or to end); truth is kept until no frame still to come can use it.
pub struct Sink {
    out: PathBuf,
    depth: BitDepth,
    write_gt: bool,
    has_gt: bool,
    truth_within_ns: i64,
    write_every: u64,
    score_every: u64,
    delay: std::time::Duration,
    csv: MetricsCsv,
    summary: Summary,
    /// Frames received, by input.
    received: BTreeMap<String, u64>,
    /// Frames written, by input.
    written: BTreeMap<String, u64>,
    /// Ground truth by time, kept until every frame input has passed it.
    truth: BTreeMap<i64, Frame>,
    truth_until_ns: i64,
    truth_closed: bool,
    /// Frames waiting for their ground truth, with their input.
    pending: VecDeque<(String, Frame)>,
    /// Per-method folders already created.
    made_dirs: BTreeSet<String>,
}

/// The name of the input that carries ground truth.
pub const GROUND_TRUTH: &str = "ground_truth";

impl Sink {
    /// A sink writing under `cfg.out` (created); `has_gt` says whether ground truth will come.
    pub fn new(cfg: &SinkConfig, has_gt: bool) -> Result<Self, SinkError> {
        create_dir(&cfg.out)?;
        // An earlier run's summary would vouch for this run's metrics.csv: it goes first (the
        // summary is written again when this run ends).
        for name in ["summary.yml", "summary.md"] {
            let path = cfg.out.join(name);
            match std::fs::remove_file(&path) {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                    return Err(SinkError::Io { path, source: e });
                }
                _ => {}
            }
        }
        let csv = MetricsCsv::create(&cfg.out.join("metrics.csv"))?;
        Ok(Sink {
            out: cfg.out.clone(),
            depth: cfg.bit_depth,
            write_gt: cfg.write_ground_truth,
            has_gt,
            truth_within_ns: cfg.truth_within_ns,
            write_every: cfg.write_every.max(1),
            score_every: cfg.score_every.max(1),
            delay: std::time::Duration::from_micros(cfg.delay_us),
            csv,
            summary: Summary::default(),
            received: BTreeMap::new(),
            written: BTreeMap::new(),
            truth: BTreeMap::new(),
            truth_until_ns: i64::MIN,
            truth_closed: !has_gt,
            pending: VecDeque::new(),
            made_dirs: BTreeSet::new(),
        })
    }

    fn frame_path(&mut self, method: &str, seq: u64) -> Result<(PathBuf, String), SinkError> {
        if !self.made_dirs.contains(method) {
            create_dir(&self.out.join(method))?;
            self.made_dirs.insert(method.to_string());
        }
        let name = format!("{method}/{seq:06}.png");
        Ok((self.out.join(&name), name))
    }

    /// Takes a ground-truth frame; writes the frames that waited for it.
    pub fn on_truth(&mut self, f: Frame) -> Result<(), SinkError> {
        *self.received.entry(GROUND_TRUTH.to_string()).or_default() += 1;
        if self.write_gt && f.seq.is_multiple_of(self.write_every) {
            let (path, _) = self.frame_path("ground-truth", f.seq)?;
            write_frame_png(&path, f.data.view(), self.depth)?;
            *self.written.entry(GROUND_TRUTH.to_string()).or_default() += 1;
        }
        self.truth_until_ns = self.truth_until_ns.max(f.t_ref_ns);
        self.truth.insert(f.t_ref_ns, f);
        self.drain_pending()
    }

    /// No more ground truth will come: the frames waiting for it are written.
    pub fn truth_ended(&mut self) -> Result<(), SinkError> {
        self.truth_closed = true;
        self.drain_pending()
    }

    /// Records that a frame of `input` reached the sink `latency_ns` after the newest camera
    /// data it derives from left its source, at wall time `at_unix_ns` (ns since the epoch).
    pub fn on_latency(&mut self, input: &str, latency_ns: i64, at_unix_ns: i64) {
        self.summary.add_latency(input, latency_ns, at_unix_ns);
    }

    /// Takes a reconstructed frame from `input`.
    pub fn on_frame(&mut self, input: &str, f: Frame) -> Result<(), SinkError> {
        self.pending.push_back((input.to_string(), f));
        self.drain_pending()?;
        if !self.delay.is_zero() {
            std::thread::sleep(self.delay);
        }
        Ok(())
    }

    /// Writes every pending frame whose ground truth has arrived or can no longer arrive.
    fn drain_pending(&mut self) -> Result<(), SinkError> {
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

    fn write(&mut self, input: &str, f: Frame) -> Result<(), SinkError> {
        *self.received.entry(input.to_string()).or_default() += 1;
        let name = if f.seq.is_multiple_of(self.write_every) {
            let (path, name) = self.frame_path(&f.method, f.seq)?;
            write_frame_png(&path, f.data.view(), self.depth)?;
            *self.written.entry(input.to_string()).or_default() += 1;
            name
        } else {
            String::new()
        };
        if !f.seq.is_multiple_of(self.score_every) {
            self.evict_truth();
            return Ok(());
        }
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
        if let Some(c) = &f.chosen {
            self.summary.add_chosen(&row, c, f.budget_ns);
        }
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

    /// Writes the frames still waiting, then `summary.md` with the mean metrics per method and,
    /// for each input of `tallies`, the frames expected, written and missing; returns its path.
    pub fn finish<'a>(
        mut self,
        tallies: impl IntoIterator<Item = (&'a str, InputTally)>,
    ) -> Result<PathBuf, SinkError> {
        self.truth_closed = true;
        // What is still waiting may not fit (a full disk): the summary is written all the same,
        // with the counts so far and the failure.
        let drained = self.drain_pending();
        if let Err(e) = &drained {
            self.summary.set_failure(&one_line(e));
        }
        for (name, t) in tallies {
            self.summary.set_counts(InputCounts {
                input: name.to_string(),
                expected: t.announced.unwrap_or(t.received + t.missing),
                received: self.received.get(name).copied().unwrap_or(0),
                written: self.written.get(name).copied().unwrap_or(0),
                missing: t.missing,
                ended: t.ended,
                cut: t.cut,
            });
        }
        self.summary
            .set_sampling(self.write_every, self.score_every);
        self.summary.set_metrics_rows(self.csv.rows());
        let path = self.out.join("summary.md");
        if let Err(e) = self.summary.write(&path) {
            return Err(SinkError::SummaryLost {
                what: format!("cannot write the summary: {}", one_line(&e)),
                counts: self.summary.counts_line(),
            });
        }
        drained.map(|()| path)
    }

    /// Records why the sink failed (a frame it could not write): the summary says so.
    pub fn note_failure(&mut self, why: &str) {
        self.summary.set_failure(why);
    }
}

/// An error and its causes on one line.
fn one_line(e: &SinkError) -> String {
    let mut text = e.to_string();
    let mut source = std::error::Error::source(e);
    while let Some(s) = source {
        text.push_str(": ");
        text.push_str(&s.to_string());
        source = s.source();
    }
    text
}

fn create_dir(dir: &Path) -> Result<(), SinkError> {
    std::fs::create_dir_all(dir).map_err(|source| SinkError::Io {
        path: dir.to_path_buf(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;
    use neuspike_schemas::FrameKind;

    fn frame(kind: FrameKind, method: &str, seq: u64, t_ref_ns: i64, value: f32) -> Frame {
        Frame {
            kind,
            method: method.into(),
            t_ref_ns,
            compute_ns: 1,
            chosen: None,
            budget_ns: None,
            seq,
            data: Array2::from_elem((4, 5), value),
        }
    }

    fn config(out: &Path, within_ns: i64) -> SinkConfig {
        SinkConfig {
            out: out.to_path_buf(),
            bit_depth: BitDepth::Eight,
            write_ground_truth: false,
            truth_within_ns: within_ns,
            write_every: 1,
            score_every: 1,
            delay_us: 0,
        }
    }

    /// A tmpfs mounted on `dir` with `opts` (root only), unmounted when dropped.
    struct Mount(PathBuf);

    impl Mount {
        fn tmpfs(dir: &Path, opts: &str) -> Option<Mount> {
            let ok = std::process::Command::new("mount")
                .args(["-t", "tmpfs", "-o", opts, "neuspike-test"])
                .arg(dir)
                .stderr(std::process::Stdio::null())
                .status()
                .is_ok_and(|s| s.success());
            if !ok {
                eprintln!("SKIPPED: cannot mount a tmpfs here (root is needed)");
            }
            ok.then(|| Mount(dir.to_path_buf()))
        }
    }

    impl Drop for Mount {
        fn drop(&mut self) {
            let _ = std::process::Command::new("umount").arg(&self.0).status();
        }
    }

    /// `e` and its causes on one line, as the node prints it.
    fn chain(e: &dyn std::error::Error) -> String {
        let mut s = e.to_string();
        let mut cause = e.source();
        while let Some(c) = cause {
            s = format!("{s}: {c}");
            cause = c.source();
        }
        s
    }

    /// A frame of noise (PNG cannot shrink it): about 64 KiB as an 8-bit PNG.
    fn noise(seq: u64) -> Frame {
        let mut x = seq.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let data = Array2::from_shape_fn((256, 256), |_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x % 256) as f32 / 255.0
        });
        Frame {
            kind: FrameKind::Reconstruction,
            method: "tfp".into(),
            t_ref_ns: seq as i64,
            compute_ns: 1,
            chosen: None,
            budget_ns: None,
            seq,
            data,
        }
    }

    #[test]
    fn a_full_disk_is_a_one_line_error_naming_the_file_with_nothing_half_written() {
        let dir = tempfile::tempdir().expect("tempdir");
        let Some(_mount) = Mount::tmpfs(dir.path(), "size=256k") else {
            return;
        };
        let mut sink = Sink::new(&config(dir.path(), 0), false).expect("sink");
        let e = (0..64)
            .find_map(|seq| sink.on_frame("tfp", noise(seq)).err())
            .map(|e| chain(&e))
            .expect("256 KiB fill up");
        assert!(!e.contains('\n'), "one line: {e}");
        assert!(e.contains(".png") && e.contains("No space left"), "{e}");
        // Every PNG there is whole; no temporary file is left.
        let mut pngs = 0;
        for entry in std::fs::read_dir(dir.path().join("tfp")).expect("tfp") {
            let path = entry.expect("entry").path();
            assert!(
                path.extension().is_some_and(|x| x == "png"),
                "left behind: {}",
                path.display()
            );
            neuspike_image::read_frame_png(&path).expect("a whole PNG");
            pngs += 1;
        }
        assert!(pngs >= 1, "no PNG fitted");
    }

    #[test]
    fn a_read_only_folder_is_a_one_line_error_naming_it() {
        let dir = tempfile::tempdir().expect("tempdir");
        let Some(_mount) = Mount::tmpfs(dir.path(), "ro,size=64k") else {
            return;
        };
        let out = dir.path().join("frames");
        let e = Sink::new(&config(&out, 0), false)
            .err()
            .map(|e| chain(&e))
            .expect("a read-only folder");
        assert!(!e.contains('\n'), "one line: {e}");
        assert!(
            e.contains(&out.display().to_string()) && e.contains("Read-only"),
            "{e}"
        );
    }

    #[test]
    fn one_frame_in_n_is_written_or_scored_and_every_frame_is_counted() {
        let dir = tempfile::tempdir().expect("tempdir");
        let cfg = SinkConfig {
            write_every: 3,
            score_every: 2,
            ..config(dir.path(), 0)
        };
        let mut sink = Sink::new(&cfg, false).expect("sink");
        for seq in 0..7 {
            sink.on_frame(
                "tfp",
                frame(FrameKind::Reconstruction, "tfp", seq, seq as i64, 0.5),
            )
            .expect("frame");
        }
        let pngs: Vec<bool> = (0..7)
            .map(|s| dir.path().join(format!("tfp/{s:06}.png")).is_file())
            .collect();
        assert_eq!(pngs, [true, false, false, true, false, false, true]);
        let csv = std::fs::read_to_string(dir.path().join("metrics.csv")).expect("csv");
        let seqs: Vec<&str> = csv
            .lines()
            .skip(1)
            .map(|r| r.split(',').next().unwrap_or(""))
            .collect();
        assert_eq!(seqs, ["0", "2", "4", "6"], "{csv}");
        // Seq 2 and 4 were scored, not written: their rows name no file.
        assert!(
            csv.lines().nth(2).is_some_and(|r| !r.contains(".png")),
            "{csv}"
        );
        let tally = InputTally {
            announced: Some(7),
            received: 7,
            missing: 0,
            ended: true,
            cut: false,
        };
        let text = std::fs::read_to_string(sink.finish([("tfp", tally)]).expect("summary"))
            .expect("summary");
        assert!(text.contains("| tfp | 7 | 7 | 3 | 0 | yes |"), "{text}");
        assert!(
            text.contains("one frame in 3 (`--write-every 3`)"),
            "{text}"
        );
    }

    #[test]
    fn a_frame_waits_for_its_truth_and_is_scored_against_it() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut sink = Sink::new(&config(dir.path(), 0), true).expect("sink");
        sink.on_frame("tfp", frame(FrameKind::Reconstruction, "tfp", 0, 100, 0.5))
            .expect("frame");
        // Not written yet: its truth may still come.
        let csv = || std::fs::read_to_string(dir.path().join("metrics.csv")).expect("csv");
        assert_eq!(csv().lines().count(), 1, "header only");
        sink.on_truth(frame(FrameKind::GroundTruth, "ground-truth", 0, 100, 0.5))
            .expect("truth");
        let rows = csv();
        assert_eq!(rows.lines().count(), 2, "{rows}");
        assert!(
            rows.lines().nth(1).is_some_and(|r| r.contains(",inf,")),
            "{rows}"
        );
        // A frame past the last truth waits until the truth stream ends, then goes unscored.
        sink.on_frame("tfp", frame(FrameKind::Reconstruction, "tfp", 1, 200, 0.5))
            .expect("frame");
        assert_eq!(csv().lines().count(), 2);
        sink.truth_ended().expect("end");
        assert_eq!(csv().lines().count(), 3);
        let tally = InputTally {
            announced: Some(3),
            received: 2,
            missing: 1,
            ended: true,
            cut: false,
        };
        let summary = sink.finish([("tfp", tally)]).expect("summary");
        let text = std::fs::read_to_string(summary).expect("summary");
        assert!(text.contains("| tfp | 3 | 2 | 2 | 1 | yes |"), "{text}");
    }

    #[test]
    fn the_nearest_truth_within_the_tolerance_scores_a_frame() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut sink = Sink::new(&config(dir.path(), 30), true).expect("sink");
        sink.on_truth(frame(FrameKind::GroundTruth, "ground-truth", 0, 80, 0.5))
            .expect("truth");
        sink.on_truth(frame(FrameKind::GroundTruth, "ground-truth", 1, 125, 0.25))
            .expect("truth");
        // 100 is 20 from the first truth and 25 from the second: the first scores it.
        sink.on_frame("tfp", frame(FrameKind::Reconstruction, "tfp", 0, 100, 0.5))
            .expect("frame");
        sink.truth_ended().expect("end");
        let rows = std::fs::read_to_string(dir.path().join("metrics.csv")).expect("csv");
        assert!(
            rows.lines().nth(1).is_some_and(|r| r.contains(",inf,")),
            "{rows}"
        );
    }
}
