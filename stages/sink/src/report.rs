//! The run report: `metrics.csv`, one row a frame, and a per-method summary in Markdown.
//!
//! The summary is written as Markdown text (`summary.md`: the table plus the frame counts), not
//! JSON: the crate has no JSON dependency, and the per-frame figures a program would want are all
//! in `metrics.csv` already.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::SinkError;
use neuspike_image::write_atomically;

/// Header line of `metrics.csv` (without the newline).
pub const CSV_HEADER: &str =
    "seq,t_ref_ns,method,compute_ns,psnr_db,psnr_gain_db,ssim,entropy_2d,file";

/// One row of `metrics.csv`: the figures of one reconstructed frame.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameMetrics {
    /// Sequence number of the frame in the stream.
    pub seq: u64,
    /// Reference time of the frame, ns.
    pub t_ref_ns: i64,
    /// Reconstruction method that produced it (e.g. `tfp`, `tfi`, `neuspike`).
    pub method: String,
    /// Time the method took to compute it, ns.
    pub compute_ns: i64,
    /// PSNR against ground truth in dB (`inf` when exact); `None` without ground truth.
    pub psnr_db: Option<f64>,
    /// PSNR after the least-squares gain, dB; `None` without ground truth.
    pub psnr_gain_db: Option<f64>,
    /// SSIM against ground truth; `None` without ground truth.
    pub ssim: Option<f64>,
    /// 2D entropy of the frame in bits (no reference needed).
    pub entropy_2d: f64,
    /// The PNG file written for the frame, as the sink names it (may be empty).
    pub file: String,
}

/// A float as the CSV shows it: shortest round-trip decimal; `inf`, `-inf` and `nan` spelled so.
fn csv_float(v: f64) -> String {
    if v.is_nan() {
        "nan".to_owned()
    } else if v == f64::INFINITY {
        "inf".to_owned()
    } else if v == f64::NEG_INFINITY {
        "-inf".to_owned()
    } else {
        format!("{v}")
    }
}

fn csv_opt(v: Option<f64>) -> String {
    v.map(csv_float).unwrap_or_default()
}

/// A text field quoted as RFC 4180 asks when it holds a comma, a quote or a line break.
fn csv_text(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_owned()
    }
}

/// `row` as one CSV line, newline included.
pub fn csv_line(row: &FrameMetrics) -> String {
    format!(
        "{},{},{},{},{},{},{},{},{}\n",
        row.seq,
        row.t_ref_ns,
        csv_text(&row.method),
        row.compute_ns,
        csv_opt(row.psnr_db),
        csv_opt(row.psnr_gain_db),
        csv_opt(row.ssim),
        csv_float(row.entropy_2d),
        csv_text(&row.file),
    )
}

/// Writer of `metrics.csv`. Each row is flushed to the operating system as soon as it is appended,
/// so a crash or a kill of the node loses no row already produced (no fsync: power loss may).
#[derive(Debug)]
pub struct MetricsCsv {
    path: PathBuf,
    out: BufWriter<File>,
    rows: u64,
}

impl MetricsCsv {
    /// Creates (or truncates) `path` and writes the header ([`CSV_HEADER`]).
    pub fn create(path: &Path) -> Result<Self, SinkError> {
        let io_error = |source| SinkError::Io {
            path: path.to_owned(),
            source,
        };
        let file = File::create(path).map_err(io_error)?;
        let mut csv = Self {
            path: path.to_owned(),
            out: BufWriter::new(file),
            rows: 0,
        };
        csv.write_flushed(&format!("{CSV_HEADER}\n"))?;
        Ok(csv)
    }

    /// Appends one row and flushes it. `None` figures are empty fields; infinite PSNR is `inf`.
    pub fn append(&mut self, row: &FrameMetrics) -> Result<(), SinkError> {
        self.write_flushed(&csv_line(row))?;
        self.rows += 1;
        Ok(())
    }

    /// Rows appended whole so far (the header not counted).
    pub fn rows(&self) -> u64 {
        self.rows
    }

    /// The file being written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn write_flushed(&mut self, text: &str) -> Result<(), SinkError> {
        self.out
            .write_all(text.as_bytes())
            .and_then(|()| self.out.flush())
            .map_err(|source| SinkError::Io {
                path: self.path.clone(),
                source,
            })
    }
}

/// Running mean of the values added.
#[derive(Clone, Copy, Debug, Default)]
struct Mean {
    sum: f64,
    n: u64,
}

impl Mean {
    fn add(&mut self, v: f64) {
        self.sum += v;
        self.n += 1;
    }

    fn get(&self) -> Option<f64> {
        (self.n > 0).then(|| self.sum / self.n as f64)
    }
}

/// Accumulated figures of one method.
#[derive(Clone, Debug, Default)]
struct MethodAccumulator {
    frames: u64,
    psnr: Mean,
    psnr_exact: u64,
    psnr_gain: Mean,
    psnr_gain_exact: u64,
    ssim: Mean,
    entropy: Mean,
    compute_ns: Mean,
    nan_values: u64,
}

impl MethodAccumulator {
    fn add(&mut self, row: &FrameMetrics) {
        self.frames += 1;
        self.compute_ns.add(row.compute_ns as f64);
        Self::add_psnr(
            row.psnr_db,
            &mut self.psnr,
            &mut self.psnr_exact,
            &mut self.nan_values,
        );
        Self::add_psnr(
            row.psnr_gain_db,
            &mut self.psnr_gain,
            &mut self.psnr_gain_exact,
            &mut self.nan_values,
        );
        for (value, mean) in [
            (row.ssim, &mut self.ssim),
            (Some(row.entropy_2d), &mut self.entropy),
        ] {
            match value {
                Some(v) if v.is_finite() => mean.add(v),
                Some(_) => self.nan_values += 1,
                None => {}
            }
        }
    }

    /// Finite PSNR goes into the mean, `+inf` (exact frame) is counted, anything else is NaN-like.
    fn add_psnr(value: Option<f64>, mean: &mut Mean, exact: &mut u64, nan_values: &mut u64) {
        match value {
            Some(v) if v.is_finite() => mean.add(v),
            Some(v) if v == f64::INFINITY => *exact += 1,
            Some(_) => *nan_values += 1,
            None => {}
        }
    }

    fn summary(&self, method: &str) -> MethodSummary {
        MethodSummary {
            method: method.to_owned(),
            frames: self.frames,
            psnr_mean_db: self.psnr.get(),
            psnr_finite: self.psnr.n,
            psnr_exact: self.psnr_exact,
            psnr_gain_mean_db: self.psnr_gain.get(),
            psnr_gain_exact: self.psnr_gain_exact,
            ssim_mean: self.ssim.get(),
            entropy_mean: self.entropy.get(),
            compute_ms_mean: self.compute_ns.get().map(|ns| ns / 1e6),
            nan_values: self.nan_values,
        }
    }
}

/// Summary figures of one method, as [`Summary::methods`] gives them.
#[derive(Clone, Debug, PartialEq)]
pub struct MethodSummary {
    /// The method's name.
    pub method: String,
    /// Frames added for the method.
    pub frames: u64,
    /// Mean PSNR in dB over the frames with a finite PSNR; `None` if there are none.
    pub psnr_mean_db: Option<f64>,
    /// Frames whose PSNR is finite (those in the mean).
    pub psnr_finite: u64,
    /// Frames with an infinite PSNR (MSE 0): exact, counted and never averaged.
    pub psnr_exact: u64,
    /// Mean gain-corrected PSNR in dB over the frames where it is finite.
    pub psnr_gain_mean_db: Option<f64>,
    /// Frames whose gain-corrected PSNR is infinite.
    pub psnr_gain_exact: u64,
    /// Mean SSIM over the frames that have one (finite).
    pub ssim_mean: Option<f64>,
    /// Mean 2D entropy in bits over the frames where it is finite.
    pub entropy_mean: Option<f64>,
    /// Mean compute time in ms.
    pub compute_ms_mean: Option<f64>,
    /// Figures that were NaN (or `-inf`), left out of every mean: a sign of a broken frame.
    pub nan_values: u64,
}

/// How many frames one input was expected to carry, and what became of them (set by the node).
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct InputCounts {
    /// The input's id.
    pub input: String,
    /// Frames the input should have carried.
    pub expected: u64,
    /// Frames from it that reached the sink.
    pub received: u64,
    /// Frames from it written to disk as PNG.
    pub written: u64,
    /// Frames that never arrived.
    pub missing: u64,
    /// Whether the input closed with its end-of-stream marker.
    pub ended: bool,
    /// Whether the stream was cut short because a node upstream failed: the frames after the
    /// failure were never made, and are not counted as expected.
    #[serde(default)]
    pub cut: bool,
}

/// Per-method summary of a run, built row by row from what goes into `metrics.csv`, plus the frame
/// counts of every input.
#[derive(Clone, Debug, Default)]
pub struct Summary {
    methods: BTreeMap<String, MethodAccumulator>,
    counts: BTreeMap<String, InputCounts>,
    /// `(write_every, score_every)` when either is above 1.
    sampling: Option<(u64, u64)>,
    /// Latency by input.
    latency: BTreeMap<String, LatencyTrack>,
    /// `auto`'s choices, by method then chosen method.
    auto: BTreeMap<String, BTreeMap<String, Chosen>>,
    /// `auto`'s budget and late frames, by method.
    budget: BTreeMap<String, (i64, u64, u64)>,
    /// Why the sink failed, if it did: the figures above cover what came before.
    failure: Option<String>,
    /// Rows written whole to `metrics.csv`.
    metrics_rows: u64,
}

/// Frames one method of `auto` made.
#[derive(Clone, Debug, Default)]
struct Chosen {
    frames: u64,
    compute_ns: u128,
    psnr: Mean,
}

/// Length of one window of [`LatencyTrack::windows`]: a minute of wall time.
pub const LATENCY_WINDOW_NS: i64 = 60_000_000_000;

/// The latency of one stream: percentiles over the whole run and over each minute, in memory that
/// does not grow with the run (histograms of microseconds, 3 significant digits: a percentile is
/// within 0.1% of the exact one; the largest is exact).
#[derive(Clone, Debug)]
pub struct LatencyTrack {
    all: Histogram,
    max_ns: i64,
    window: Histogram,
    window_max_ns: i64,
    /// Wall time the current window started, ns since the epoch; `None` before the first frame.
    window_start_ns: Option<i64>,
    /// Wall time of the first frame.
    first_ns: i64,
    windows: Vec<LatencyWindow>,
}

/// Histogram of latencies in microseconds, 1 us to an hour.
#[derive(Clone, Debug)]
struct Histogram(hdrhistogram::Histogram<u64>);

impl Histogram {
    const MAX_US: u64 = 3_600_000_000;

    fn new() -> Self {
        // Bounds and precision are constants in range: construction cannot fail.
        Histogram(
            hdrhistogram::Histogram::new_with_bounds(1, Self::MAX_US, 3)
                .unwrap_or_else(|_| unreachable!("valid histogram bounds")),
        )
    }

    /// Records `ns`, clamped to [1 us, 1 h] (a negative latency, from clocks that disagree, counts
    /// as 1 us).
    fn record(&mut self, ns: i64) {
        let us = (ns / 1000).clamp(1, Self::MAX_US as i64) as u64;
        self.0.saturating_record(us);
    }

    /// The figures, with `max_ns` as the largest; `None` when empty.
    fn figures(&self, max_ns: i64) -> Option<Latency> {
        let h = &self.0;
        let ms = |q: f64| h.value_at_quantile(q) as f64 * 1e-3;
        (!h.is_empty()).then(|| Latency {
            frames: h.len() as usize,
            p50_ms: ms(0.50),
            p99_ms: ms(0.99),
            max_ms: max_ns as f64 * 1e-6,
        })
    }
}

impl LatencyTrack {
    fn new() -> Self {
        LatencyTrack {
            all: Histogram::new(),
            max_ns: i64::MIN,
            window: Histogram::new(),
            window_max_ns: i64::MIN,
            window_start_ns: None,
            first_ns: 0,
            windows: Vec::new(),
        }
    }

    /// Records a frame's latency `ns`, received at wall time `at_ns`.
    fn add(&mut self, ns: i64, at_ns: i64) {
        let start = *self.window_start_ns.get_or_insert_with(|| {
            self.first_ns = at_ns;
            at_ns
        });
        if at_ns.saturating_sub(start) >= LATENCY_WINDOW_NS {
            self.close_window();
            // The next window starts on the minute grid of the first frame.
            let minutes = at_ns.saturating_sub(self.first_ns) / LATENCY_WINDOW_NS;
            self.window_start_ns = Some(self.first_ns + minutes * LATENCY_WINDOW_NS);
        }
        self.all.record(ns);
        self.max_ns = self.max_ns.max(ns);
        self.window.record(ns);
        self.window_max_ns = self.window_max_ns.max(ns);
    }

    /// The figures of the window being filled, if it holds a frame.
    fn current_window(&self) -> Option<LatencyWindow> {
        let start = self.window_start_ns?;
        Some(LatencyWindow {
            start_s: (start.saturating_sub(self.first_ns) / 1_000_000_000) as u64,
            latency: self.window.figures(self.window_max_ns)?,
        })
    }

    fn close_window(&mut self) {
        if let Some(w) = self.current_window() {
            self.windows.push(w);
        }
        self.window.0.reset();
        self.window_max_ns = i64::MIN;
    }

    /// The whole run's figures.
    pub fn overall(&self) -> Option<Latency> {
        self.all.figures(self.max_ns)
    }

    /// Each minute's figures, the current one included, oldest first.
    pub fn windows(&self) -> Vec<LatencyWindow> {
        let mut v = self.windows.clone();
        v.extend(self.current_window());
        v
    }
}

/// The latency of one minute of a stream.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LatencyWindow {
    /// Seconds from the stream's first frame to the window's start.
    pub start_s: u64,
    /// The window's figures.
    #[serde(flatten)]
    pub latency: Latency,
}

/// The latency of a stream, milliseconds.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Latency {
    /// Frames measured.
    pub frames: usize,
    /// Median.
    pub p50_ms: f64,
    /// 99th percentile.
    pub p99_ms: f64,
    /// Largest.
    pub max_ms: f64,
}

impl Summary {
    /// An empty summary.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds one frame's figures to its method.
    pub fn add(&mut self, row: &FrameMetrics) {
        self.methods.entry(row.method.clone()).or_default().add(row);
    }

    /// Records which method `auto` chose for a frame (its `chosen` key), and in budget mode
    /// whether the frame took longer than `budget_ns`.
    pub fn add_chosen(&mut self, row: &FrameMetrics, chosen: &str, budget_ns: Option<i64>) {
        let c = self
            .auto
            .entry(row.method.clone())
            .or_default()
            .entry(chosen.to_string())
            .or_default();
        c.frames += 1;
        c.compute_ns += u128::from(row.compute_ns.max(0).unsigned_abs());
        if let Some(p) = row.psnr_db.filter(|p| p.is_finite()) {
            c.psnr.add(p);
        }
        if let Some(b) = budget_ns {
            let e = self.budget.entry(row.method.clone()).or_insert((b, 0, 0));
            e.0 = b;
            e.1 += 1;
            e.2 += u64::from(row.compute_ns > b);
        }
    }

    /// `auto`'s mix as Markdown: per chosen method its frames, share, mean cost and PSNR; the
    /// compute saved against running the costliest chosen method on every frame; the frames
    /// late in budget mode. Empty without `auto` frames.
    pub fn to_markdown_auto(&self) -> String {
        let mut out = String::new();
        for (method, mix) in &self.auto {
            let total: u64 = mix.values().map(|c| c.frames).sum();
            let spent: u128 = mix.values().map(|c| c.compute_ns).sum();
            let mean_ms = |c: &Chosen| c.compute_ns as f64 / c.frames.max(1) as f64 / 1e6;
            let _ = writeln!(
                out,
                "\n## `{method}`: the methods chosen\n\n| chosen | frames | share | mean ms | PSNR dB |\n|---|---:|---:|---:|---:|"
            );
            for (name, c) in mix {
                let _ = writeln!(
                    out,
                    "| {} | {} | {:.1}% | {:.3} | {} |",
                    name.replace('|', "\\|"),
                    c.frames,
                    100.0 * c.frames as f64 / total.max(1) as f64,
                    mean_ms(c),
                    c.psnr.get().map_or("-".to_string(), |p| format!("{p:.2}"))
                );
            }
            // Against the costliest method it chose, run on every frame at its mean cost here.
            if let Some((name, c)) = mix
                .iter()
                .max_by(|a, b| mean_ms(a.1).total_cmp(&mean_ms(b.1)))
            {
                let always = mean_ms(c) * total as f64;
                let spent_ms = spent as f64 / 1e6;
                if always > 0.0 {
                    let _ = writeln!(
                        out,
                        "\nCompute: {spent_ms:.1} ms for {total} frames; always `{name}` would have taken about {always:.1} ms: {:.1}% saved.",
                        100.0 * (1.0 - spent_ms / always)
                    );
                }
            }
            if let Some((b, n, late)) = self.budget.get(method) {
                let _ = writeln!(
                    out,
                    "\nBudget {:.3} ms a frame: {late} of {n} frames late ({:.2}%).",
                    *b as f64 / 1e6,
                    100.0 * *late as f64 / (*n).max(1) as f64
                );
            }
        }
        out
    }

    /// Records how many frames an input was expected to carry, received, written and missed, and
    /// whether it ended with its end-of-stream marker. A second call for the same input replaces
    /// the first.
    pub fn set_counts(&mut self, counts: InputCounts) {
        self.counts.insert(counts.input.clone(), counts);
    }

    /// Records one frame's latency on `input`, nanoseconds, received at wall time `at_ns` (ns
    /// since the epoch; it places the frame in its minute).
    pub fn add_latency(&mut self, input: &str, ns: i64, at_ns: i64) {
        if !self.latency.contains_key(input) {
            self.latency.insert(input.to_string(), LatencyTrack::new());
        }
        if let Some(t) = self.latency.get_mut(input) {
            t.add(ns, at_ns);
        }
    }

    /// The latency of each input that had any, sorted by input.
    pub fn latencies(&self) -> Vec<(String, Latency)> {
        self.latency
            .iter()
            .filter_map(|(k, t)| t.overall().map(|l| (k.clone(), l)))
            .collect()
    }

    /// Records that one frame in `write_every` was written and one in `score_every` scored (the
    /// summary says so when either is above 1).
    pub fn set_sampling(&mut self, write_every: u64, score_every: u64) {
        self.sampling = (write_every > 1 || score_every > 1).then_some((write_every, score_every));
    }

    /// The counts set with [`Summary::set_counts`], sorted by input.
    pub fn counts(&self) -> Vec<InputCounts> {
        self.counts.values().cloned().collect()
    }

    /// One summary a method, sorted by method name.
    pub fn methods(&self) -> Vec<MethodSummary> {
        self.methods
            .iter()
            .map(|(name, acc)| acc.summary(name))
            .collect()
    }

    /// The per-method Markdown table, one row a method sorted by name. Missing figures are `-`.
    ///
    /// `PSNR dB` is the mean over the finite frames only and `exact` counts the frames with an
    /// infinite PSNR (MSE 0); likewise for the gain-corrected PSNR.
    pub fn to_markdown_table(&self) -> String {
        fn fixed(v: Option<f64>, decimals: usize) -> String {
            v.map_or_else(|| "-".to_owned(), |v| format!("{v:.decimals$}"))
        }
        let mut table = String::from(
            "| method | frames | PSNR dB | exact | PSNR after gain dB | exact after gain | SSIM | 2D entropy bits | compute ms | NaN |\n\
             |---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
        );
        for m in self.methods() {
            let _ = writeln!(
                table,
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                m.method.replace('|', "\\|"),
                m.frames,
                fixed(m.psnr_mean_db, 2),
                m.psnr_exact,
                fixed(m.psnr_gain_mean_db, 2),
                m.psnr_gain_exact,
                fixed(m.ssim_mean, 4),
                fixed(m.entropy_mean, 3),
                fixed(m.compute_ms_mean, 3),
                m.nan_values,
            );
        }
        table
    }

    /// The frame counts as a Markdown table, one row an input sorted by input.
    pub fn to_markdown_counts(&self) -> String {
        let mut table = String::from(
            "| input | expected | received | written | missing | ended |\n|---|---:|---:|---:|---:|---|\n",
        );
        for c in self.counts.values() {
            let _ = writeln!(
                table,
                "| {} | {} | {} | {} | {} | {} |",
                c.input.replace('|', "\\|"),
                c.expected,
                c.received,
                c.written,
                c.missing,
                if c.cut {
                    "cut short: a node upstream failed"
                } else if c.ended {
                    "yes"
                } else {
                    "no (no end-of-stream marker)"
                },
            );
        }
        table
    }

    /// The whole summary as Markdown: the metrics table, the frame counts and how to read them.
    pub fn to_markdown(&self) -> String {
        let mut latency = String::new();
        let lat = self.latencies();
        if !lat.is_empty() {
            latency.push_str(
                "\n## Latency\n\nFrom the newest camera data of a frame leaving its source to the \
                 frame reaching the sink (wall clock).\n\n| input | frames | p50 ms | p99 ms | max ms |\n\
                 |---|---:|---:|---:|---:|\n",
            );
            for (input, l) in lat {
                let _ = writeln!(
                    latency,
                    "| {} | {} | {:.2} | {:.2} | {:.2} |",
                    input.replace('|', "\\|"),
                    l.frames,
                    l.p50_ms,
                    l.p99_ms,
                    l.max_ms
                );
            }
            let minutes: Vec<(&String, Vec<LatencyWindow>)> = self
                .latency
                .iter()
                .map(|(k, t)| (k, t.windows()))
                .filter(|(_, w)| w.len() > 1)
                .collect();
            if !minutes.is_empty() {
                latency.push_str(
                    "\nBy minute of the run:\n\n| input | from s | frames | p50 ms | p99 ms | max ms |\n\
                     |---|---:|---:|---:|---:|---:|\n",
                );
                for (input, windows) in minutes {
                    for w in windows {
                        let l = w.latency;
                        let _ = writeln!(
                            latency,
                            "| {} | {} | {} | {:.2} | {:.2} | {:.2} |",
                            input.replace('|', "\\|"),
                            w.start_s,
                            l.frames,
                            l.p50_ms,
                            l.p99_ms,
                            l.max_ms
                        );
                    }
                }
            }
        }
        let sampling = match self.sampling {
            Some((w, s)) => format!(
                "\nSampled: a PNG of one frame in {w} (`--write-every {w}`), one frame in {s} \
                 scored (`--score-every {s}`), by sequence number; every frame was received and \
                 counted.\n"
            ),
            None => String::new(),
        };
        let failure = match &self.failure {
            Some(why) => format!(
                "**The sink failed**: {why}. The figures below cover the frames before it.\n\n"
            ),
            None => String::new(),
        };
        format!(
            "# neuspike run summary\n\n{failure}## Metrics per method\n\n{}\n\
             PSNR dB: mean over frames with a finite PSNR; exact: frames with MSE 0 (PSNR inf), \
             counted, never averaged. PSNR after gain: least-squares gain, clipped to [0, 1]. \
             NaN: figures that were NaN, left out of the means.\n{}\n## Frames per input\n\n{}{sampling}{latency}",
            self.to_markdown_table(),
            self.to_markdown_auto(),
            self.to_markdown_counts(),
        )
    }

    /// Records how many rows `metrics.csv` holds whole (`summary.yml` says so).
    pub fn set_metrics_rows(&mut self, rows: u64) {
        self.metrics_rows = rows;
    }

    /// Records why the sink failed (the first reason is kept).
    pub fn set_failure(&mut self, why: &str) {
        self.failure.get_or_insert_with(|| why.to_string());
    }

    /// Every input's counts on one line: `tfp: 120 expected, 118 received, 118 written, 2
    /// missing; ...`.
    pub fn counts_line(&self) -> String {
        let line: Vec<String> = self
            .counts
            .values()
            .map(|c| {
                format!(
                    "{}: {} expected, {} received, {} written, {} missing{}",
                    c.input,
                    c.expected,
                    c.received,
                    c.written,
                    c.missing,
                    if c.cut { " (cut short)" } else { "" }
                )
            })
            .collect();
        if line.is_empty() {
            "no input".into()
        } else {
            line.join("; ")
        }
    }

    /// The machine-readable summary (`summary.yml`): every input's counts and latency.
    pub fn to_file(&self) -> SummaryFile {
        let latency: BTreeMap<String, Latency> = self.latencies().into_iter().collect();
        SummaryFile {
            metrics_rows: self.metrics_rows,
            failure: self.failure.clone(),
            inputs: self
                .counts
                .values()
                .map(|c| {
                    (
                        c.input.clone(),
                        InputFigures {
                            counts: c.clone(),
                            latency: latency.get(&c.input).copied(),
                            latency_by_minute: self
                                .latency
                                .get(&c.input)
                                .map(LatencyTrack::windows)
                                .unwrap_or_default(),
                        },
                    )
                })
                .collect(),
        }
    }

    /// Writes [`Summary::to_markdown`] to `path` (e.g. `summary.md`) atomically, through
    /// `<path>.tmp` and a rename.
    pub fn write(&self, path: &Path) -> Result<(), SinkError> {
        let text = self.to_markdown();
        write_atomically(path, |out, tmp| {
            out.write_all(text.as_bytes())
                .map_err(|source| SinkError::Io {
                    path: tmp.to_owned(),
                    source,
                })
        })?;
        let yml = serde_yaml::to_string(&self.to_file()).unwrap_or_default();
        let yml_path = path.with_extension("yml");
        write_atomically(&yml_path, |out, tmp| {
            out.write_all(yml.as_bytes())
                .map_err(|source| SinkError::Io {
                    path: tmp.to_owned(),
                    source,
                })
        })
    }
}

/// One input's figures in `summary.yml`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct InputFigures {
    /// Frames expected, received, written, missing; whether the input ended.
    #[serde(flatten)]
    pub counts: InputCounts,
    /// Latency, when the frames carried their origin.
    pub latency: Option<Latency>,
    /// Latency over each minute of the run (wall clock, from the first frame).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub latency_by_minute: Vec<LatencyWindow>,
}

/// `summary.yml`: what a program reads of a run (the Markdown summary is for people). The sink
/// writes it last, when the run ends, and removes an earlier run's when it starts: a folder whose
/// `metrics.csv` has no `summary.yml` beside it holds a run that did not finish.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SummaryFile {
    /// Rows written whole to `metrics.csv` (the header not counted).
    #[serde(default)]
    pub metrics_rows: u64,
    /// Why the sink failed, if it did: the figures cover what came before.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub failure: Option<String>,
    /// By input.
    pub inputs: BTreeMap<String, InputFigures>,
}

/// The largest `summary.yml` [`read_run`] reads: 16 MiB (a run's is a few KiB).
pub const MAX_SUMMARY_BYTES: u64 = 16 << 20;

/// A run's figures from the sink's folder `dir`, only when the run is whole: its `summary.yml`
/// was written (the run finished), says no failure, and `metrics.csv` holds exactly the rows it
/// counts, the last one ended.
///
/// # Errors
/// [`SinkError::NotWhole`] saying what is missing or cut (no summary: the run did not finish;
/// a failure: the summary's reason; rows missing or a row cut: the file was cut after the run),
/// or [`SinkError::Io`] when a file cannot be read.
pub fn read_run(dir: &Path) -> Result<SummaryFile, SinkError> {
    use std::io::{BufRead, BufReader, Read};
    let not_whole = |what: String| SinkError::NotWhole {
        dir: dir.to_owned(),
        what,
    };
    let io = |path: &Path| {
        let path = path.to_owned();
        move |source| SinkError::Io { path, source }
    };
    let csv_path = dir.join("metrics.csv");
    // Rows in metrics.csv, and whether the last one ended with its newline.
    let (lines, ended) = {
        let mut reader = BufReader::new(File::open(&csv_path).map_err(io(&csv_path))?);
        let (mut lines, mut ended) = (0u64, true);
        loop {
            let buf = reader.fill_buf().map_err(io(&csv_path))?;
            let Some(&last) = buf.last() else {
                break;
            };
            lines += buf.iter().filter(|&&b| b == b'\n').count() as u64;
            ended = last == b'\n';
            let n = buf.len();
            reader.consume(n);
        }
        (lines, ended)
    };
    let rows = lines.saturating_sub(1);
    let yml_path = dir.join("summary.yml");
    let mut text = String::new();
    match File::open(&yml_path) {
        Ok(f) => f
            .take(MAX_SUMMARY_BYTES)
            .read_to_string(&mut text)
            .map_err(io(&yml_path))?,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(not_whole(format!(
                "no summary.yml: the run did not finish, so metrics.csv ({rows} rows) may stop \
                 short of it"
            )));
        }
        Err(e) => return Err(io(&yml_path)(e)),
    };
    let file: SummaryFile = serde_yaml::from_str(&text)
        .map_err(|e| not_whole(format!("summary.yml: not a run's summary: {e}")))?;
    if let Some(why) = &file.failure {
        return Err(not_whole(format!(
            "the sink failed ({why}); metrics.csv holds the {} rows before it",
            file.metrics_rows
        )));
    }
    if !ended {
        return Err(not_whole(format!(
            "metrics.csv: its last row is cut (no newline after row {rows})"
        )));
    }
    if rows != file.metrics_rows {
        return Err(not_whole(format!(
            "metrics.csv holds {rows} rows but summary.yml counts {}: the file was cut or \
             changed after the run",
            file.metrics_rows
        )));
    }
    Ok(file)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(seq: u64, method: &str, psnr: Option<f64>, ssim: Option<f64>) -> FrameMetrics {
        FrameMetrics {
            seq,
            t_ref_ns: 1_000_000 * seq as i64,
            method: method.to_owned(),
            compute_ns: 2_000_000,
            psnr_db: psnr,
            psnr_gain_db: psnr.map(|p| p + 1.0),
            ssim,
            entropy_2d: 7.5,
            file: format!("frames/{method}_{seq:06}.png"),
        }
    }

    #[test]
    fn autos_mix_compute_saved_and_late_frames_are_summarised() {
        let mut s = Summary::new();
        let row = |seq: u64, ms: i64, psnr: f64| FrameMetrics {
            seq,
            t_ref_ns: 0,
            method: "auto".into(),
            compute_ns: ms * 1_000_000,
            psnr_db: Some(psnr),
            psnr_gain_db: None,
            ssim: None,
            entropy_2d: 1.0,
            file: String::new(),
        };
        // Three cheap frames (1 ms) and one network frame (10 ms, over a 5 ms budget).
        for (seq, (ms, method)) in [(1, "tfp-33"), (1, "tfp-33"), (1, "tfp-33"), (10, "net")]
            .into_iter()
            .enumerate()
        {
            let r = row(seq as u64, ms, 30.0 + seq as f64);
            s.add(&r);
            s.add_chosen(&r, method, Some(5_000_000));
        }
        let md = s.to_markdown_auto();
        assert!(
            md.contains("| tfp-33 | 3 | 75.0% | 1.000 | 31.00 |"),
            "{md}"
        );
        assert!(md.contains("| net | 1 | 25.0% | 10.000 | 33.00 |"), "{md}");
        // 13 ms spent; always the network: 40 ms; 67.5% saved.
        assert!(
            md.contains("13.0 ms for 4 frames") && md.contains("67.5% saved"),
            "{md}"
        );
        assert!(
            md.contains("Budget 5.000 ms a frame: 1 of 4 frames late (25.00%)."),
            "{md}"
        );
        assert!(s.to_markdown().contains(&md));
        assert_eq!(Summary::new().to_markdown_auto(), "");
    }

    #[test]
    fn csv_has_header_and_rows_with_inf_and_empty_fields() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("metrics.csv");
        let mut csv = MetricsCsv::create(&path).expect("create");
        csv.append(&row(0, "tfp", Some(25.5), Some(0.75)))
            .expect("row 0");
        // Read while the writer is still open: each row is already flushed.
        let text = std::fs::read_to_string(&path).expect("read");
        assert_eq!(
            text,
            "seq,t_ref_ns,method,compute_ns,psnr_db,psnr_gain_db,ssim,entropy_2d,file\n\
             0,0,tfp,2000000,25.5,26.5,0.75,7.5,frames/tfp_000000.png\n"
        );
        csv.append(&row(1, "tfi", Some(f64::INFINITY), Some(1.0)))
            .expect("row 1");
        csv.append(&row(2, "neuspike", None, None)).expect("row 2");
        let text = std::fs::read_to_string(&path).expect("read");
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 4);
        assert_eq!(
            lines[2],
            "1,1000000,tfi,2000000,inf,inf,1,7.5,frames/tfi_000001.png"
        );
        assert_eq!(
            lines[3],
            "2,2000000,neuspike,2000000,,,,7.5,frames/neuspike_000002.png"
        );
        assert_eq!(csv.path(), path);
    }

    #[test]
    fn csv_quotes_text_with_commas_and_quotes() {
        let mut r = row(3, "a,b", Some(f64::NAN), None);
        r.file = "say \"hi\".png".to_owned();
        assert_eq!(
            csv_line(&r),
            "3,3000000,\"a,b\",2000000,nan,nan,,7.5,\"say \"\"hi\"\".png\"\n"
        );
    }

    #[test]
    fn csv_floats_round_trip() {
        for v in [0.1, 1e-9, 123_456.789_012_345, -3.25] {
            let back: f64 = csv_float(v).parse().expect("parse");
            assert_eq!(back, v);
        }
    }

    #[test]
    fn csv_create_in_missing_folder_names_the_path() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("nowhere").join("metrics.csv");
        let err = MetricsCsv::create(&path).expect_err("missing folder");
        assert!(err.to_string().contains("nowhere"), "{err}");
    }

    fn counts(input: &str, expected: u64, written: u64, missing: u64, ended: bool) -> InputCounts {
        InputCounts {
            input: input.to_owned(),
            expected,
            received: expected - missing,
            written,
            missing,
            ended,
            cut: false,
        }
    }

    #[test]
    fn summary_mean_skips_inf_and_counts_it() {
        let mut s = Summary::new();
        s.add(&row(0, "tfp", Some(20.0), Some(0.5)));
        s.add(&row(1, "tfp", Some(f64::INFINITY), Some(1.0)));
        s.add(&row(2, "tfp", Some(30.0), Some(0.9)));
        s.add(&row(0, "neuspike", None, None));
        s.add(&row(1, "neuspike", Some(f64::NAN), Some(0.8)));
        s.set_counts(counts("tfp", 4, 3, 1, true));
        s.set_counts(counts("neuspike", 2, 1, 0, false));

        let methods = s.methods();
        assert_eq!(methods.len(), 2);
        // sorted by name
        assert_eq!(methods[0].method, "neuspike");
        let tfp = &methods[1];
        assert_eq!(tfp.frames, 3);
        assert_eq!(tfp.psnr_mean_db, Some(25.0));
        assert_eq!(tfp.psnr_finite, 2);
        assert_eq!(tfp.psnr_exact, 1);
        assert_eq!(tfp.psnr_gain_mean_db, Some(26.0));
        assert_eq!(tfp.psnr_gain_exact, 1);
        assert!((tfp.ssim_mean.expect("ssim") - 0.8).abs() < 1e-12);
        assert_eq!(tfp.entropy_mean, Some(7.5));
        assert_eq!(tfp.compute_ms_mean, Some(2.0));
        assert_eq!(tfp.nan_values, 0);
        let ns = &methods[0];
        assert_eq!(ns.psnr_mean_db, None);
        assert_eq!(ns.psnr_exact, 0);
        assert_eq!(ns.nan_values, 2); // plain and gain-corrected PSNR
        assert_eq!(ns.ssim_mean, Some(0.8));

        let table = s.to_markdown_table();
        let lines: Vec<&str> = table.lines().collect();
        assert_eq!(lines.len(), 4, "{table}");
        assert_eq!(
            lines[2],
            "| neuspike | 2 | - | 0 | - | 0 | 0.8000 | 7.500 | 2.000 | 2 |"
        );
        assert_eq!(
            lines[3],
            "| tfp | 3 | 25.00 | 1 | 26.00 | 1 | 0.8000 | 7.500 | 2.000 | 0 |"
        );
        let all = s.counts();
        assert_eq!(all.len(), 2);
        assert_eq!(
            all[1],
            InputCounts {
                input: "tfp".to_owned(),
                expected: 4,
                received: 3,
                written: 3,
                missing: 1,
                ended: true,
                cut: false,
            }
        );
        let md = s.to_markdown();
        assert!(md.contains("| tfp | 4 | 3 | 3 | 1 | yes |"), "{md}");
        assert!(
            md.contains("| neuspike | 2 | 2 | 1 | 0 | no (no end-of-stream marker) |"),
            "{md}"
        );
        assert!(!md.contains("Sampled"), "{md}");
        s.set_sampling(10, 1);
        assert!(
            s.to_markdown()
                .contains("a PNG of one frame in 10 (`--write-every 10`), one frame in 1 scored")
        );
        assert!(md.contains(&table), "{md}");
        // a stream cut short upstream says so
        let mut cut = counts("tfi", 3, 3, 0, true);
        cut.cut = true;
        let mut t = Summary::new();
        t.set_counts(cut);
        assert!(
            t.to_markdown_counts()
                .contains("| tfi | 3 | 3 | 3 | 0 | cut short: a node upstream failed |"),
            "{}",
            t.to_markdown_counts()
        );
        // a second call replaces the first
        s.set_counts(counts("tfp", 5, 5, 0, true));
        assert_eq!(s.counts()[1].expected, 5);
        assert_eq!(s.counts().len(), 2);
    }

    #[test]
    fn latency_percentiles_are_within_a_thousandth_and_reported_per_input_and_minute() {
        let mut s = Summary::new();
        assert!(s.latencies().is_empty());
        assert!(!s.to_markdown().contains("## Latency"));
        // 1..=200 ms, one frame a second: p50 100 ms, p99 198 ms (nearest rank), max 200 ms.
        for i in (1..=200i64).rev() {
            s.add_latency("tfp", i * 1_000_000, (200 - i) * 1_000_000_000);
        }
        let (_, l) = s.latencies().remove(0);
        let near = |a: f64, b: f64| (a - b).abs() <= b * 1e-3;
        assert_eq!(l.frames, 200);
        assert!(near(l.p50_ms, 100.0) && near(l.p99_ms, 198.0), "{l:?}");
        assert_eq!(l.max_ms, 200.0);
        // 200 s: windows from 0, 60, 120 and 180 s; the last holds 20 frames, the first 60.
        let w = s.latency["tfp"].windows();
        assert_eq!(
            w.iter().map(|w| w.start_s).collect::<Vec<_>>(),
            [0, 60, 120, 180]
        );
        assert_eq!(
            w.iter().map(|w| w.latency.frames).collect::<Vec<_>>(),
            [60, 60, 60, 20]
        );
        assert_eq!(w[0].latency.max_ms, 200.0);
        assert_eq!(w[3].latency.max_ms, 20.0);
        let md = s.to_markdown();
        assert!(md.contains("| tfp | 200 | "), "{md}");
        assert!(md.contains("| tfp | 180 | 20 | "), "{md}");
        s.set_counts(counts("tfp", 200, 200, 0, true));
        let file = s.to_file();
        let back: SummaryFile =
            serde_yaml::from_str(&serde_yaml::to_string(&file).expect("yaml")).expect("read");
        assert_eq!(back, file);
        let tfp = &back.inputs["tfp"];
        assert_eq!(tfp.counts.received, 200);
        assert_eq!(tfp.latency_by_minute.len(), 4);
        // Out-of-range latencies are clamped, never lost.
        let mut t = Summary::new();
        t.add_latency("x", -5, 0);
        t.add_latency("x", i64::MAX, 1);
        let (_, l) = t.latencies().remove(0);
        assert_eq!(l.frames, 2);
        assert!(l.p50_ms > 0.0 && l.p99_ms <= 3.6e6 * 1.001, "{l:?}");
    }

    #[test]
    fn summary_is_written_atomically() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("summary.md");
        let mut s = Summary::new();
        s.add(&row(0, "tfi", Some(31.0), Some(0.9)));
        s.set_counts(counts("tfi", 1, 1, 0, true));
        s.write(&path).expect("write");
        assert_eq!(
            std::fs::read_to_string(&path).expect("read"),
            s.to_markdown()
        );
        assert!(!dir.path().join("summary.md.tmp").exists());
        let bad = dir.path().join("absent").join("summary.md");
        let err = s.write(&bad).expect_err("missing folder");
        assert!(err.to_string().contains("absent"), "{err}");
    }
}
