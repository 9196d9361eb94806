//! `neuspike bench-live`: the spike-only live graph (`graphs/spike-tfp-live.yml`) paced to a
//! camera's clock, timed against the camera time it covers, with its losses and latency; its
//! infer stage runs TFP, or a spike-reading network (`--method`) on the spike representation.

use std::path::{Path, PathBuf};

use eyre::{WrapErr, bail};
use neuspike_sink::report::LatencyWindow;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use crate::{graph, soak};

/// The live graph, built into the program.
pub const LIVE_GRAPH: &str = include_str!("../graphs/spike-tfp-live.yml");

/// What to run (the `neuspike bench-live` arguments).
#[derive(Clone, Debug, clap::Args)]
pub struct LiveBenchOptions {
    /// Camera time to stream, seconds.
    #[arg(long, default_value_t = 30.0)]
    pub seconds: f64,
    /// Spike camera plane rate, Hz (a Vidar runs at 20,000 or 40,000).
    #[arg(long, default_value_t = 20_000)]
    pub rate_hz: u64,
    /// Frames a second: a frame every `rate_hz / fps` planes.
    #[arg(long, default_value_t = 1_000)]
    pub fps: u64,
    /// Planes a frame reads (TFP averages them; a network reads the spike representation of its
    /// last ones).
    #[arg(long, default_value_t = 33)]
    pub window_planes: u64,
    /// What the infer stage runs: `tfp`, or a network that reads spikes alone, by its name in
    /// the trade bench: `neuspike-spike-8` runs `<models>/neuspike-spike-8.onnx` in f32,
    /// `neuspike-spike-8-int8` the same file in 8 bits (the widest path this CPU has).
    #[arg(long, default_value = "tfp")]
    pub method: String,
    /// The folder of the networks `--method` names.
    #[arg(long, default_value = "models")]
    pub models: PathBuf,
    /// Where a network's spike representation is made: `windows`, in the infer stage of
    /// align's windows, its raw planes read as the window holds them (bit-packed; in 8 bits the
    /// network's first convolution reads the bits), one stage fewer; `represent`, by the
    /// represent stage, sent to infer as `f32` (32 bits a pixel and plane).
    #[arg(long, value_enum, default_value_t = NetworkInput::Windows)]
    pub network_input: NetworkInput,
    /// Threads a network's convolutions split each frame across (the infer stage's
    /// `--threads`), sharing the machine's cores with the other stages.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=64))]
    pub infer_threads: u16,
    /// Built-in scene the simulated camera sees.
    #[arg(long, default_value = "bright-static")]
    pub scene: String,
    /// The camera simulates its first N planes once and sends them again and again (the spike
    /// source's `--repeat-planes`): the graph then pays for the stages after the camera, as with
    /// a real camera, not for simulating one. 0: every plane simulated as it is sent.
    #[arg(long, default_value_t = 0)]
    pub repeat_planes: u64,
    /// The sink writes a PNG of one frame in N (every frame is received and counted).
    #[arg(long, default_value_t = 10)]
    pub write_every: u64,
    /// Runs of each layout, one after the other.
    #[arg(long, default_value_t = 1)]
    pub runs: usize,
    /// How the stages share processes, each layout run in turn (comma-separated): `nodes`, one
    /// process a stage; `core`, align, represent and infer in one; `one`, all five in one (the
    /// camera on a thread of its own). The first is the baseline of the `vs` column.
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [Layout::Nodes, Layout::One])]
    pub processes: Vec<Layout>,
    /// Folder of the graph and its frames.
    #[arg(long, default_value = "out/bench-live")]
    pub out: PathBuf,
    /// Soak: sample every process's resident memory each second (`rss.csv`), print it with the
    /// latency of each minute, and fail unless memory stays flat, nothing is lost and latency
    /// does not grow (see `scripts/soak.sh`).
    #[arg(long)]
    pub soak: bool,
}

/// Where a network's spike representation is made (`--network-input`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum NetworkInput {
    /// In the infer stage, of align's windows.
    Windows,
    /// By the represent stage.
    Represent,
}

/// How the stages of the live graph share processes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Layout {
    /// One process a stage (five dora nodes).
    Nodes,
    /// Align, represent and infer in one process (three dora nodes).
    Core,
    /// Every stage in one process, the camera on a thread of its own (one dora node).
    One,
}

impl Layout {
    /// Its name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Layout::Nodes => "nodes",
            Layout::Core => "core",
            Layout::One => "one",
        }
    }

    /// The graph's `processes:` for it (none for `nodes`), its infer node named `infer`.
    /// The graph's `processes:` for it (none for `nodes`), its infer node named `infer`, with or
    /// without a represent node.
    fn processes(self, infer: &str, represent: bool) -> Option<String> {
        let represent = if represent { "represent, " } else { "" };
        match self {
            Layout::Nodes => None,
            Layout::Core => Some(format!("{{core: [align, {represent}{infer}]}}")),
            Layout::One => Some(format!(
                "{{pipeline: [spike-source, align, {represent}{infer}, sink]}}"
            )),
        }
    }
}

/// What the live graph's infer stage runs (`--method`).
#[derive(Clone, Debug, PartialEq)]
pub enum LiveMethod {
    /// TFP over the window.
    Tfp,
    /// A network reading the spike representation of `channels` channels.
    Network {
        /// The method's name (the sink's input).
        name: String,
        /// The ONNX file.
        model: PathBuf,
        /// How its convolutions compute.
        precision: neuspike_reconstruction::learned::Precision,
        /// Channels of its spike input.
        channels: usize,
    },
}

impl LiveMethod {
    /// `--method` of `opts` checked: a network's file exists, loads, and reads spikes alone.
    pub fn of(opts: &LiveBenchOptions) -> eyre::Result<LiveMethod> {
        use neuspike_reconstruction::learned::{LearnedInput, LearnedModel, network_variant};
        if opts.method == "tfp" {
            return Ok(LiveMethod::Tfp);
        }
        let (stem, precision) = network_variant(&opts.method);
        let model = opts.models.join(format!("{stem}.onnx"));
        if !model.is_file() {
            bail!(
                "bench-live: --method = {} is neither tfp nor a network in {} (no {})",
                opts.method,
                opts.models.display(),
                model.display()
            );
        }
        let loaded = LearnedModel::load(&model)?;
        let (&[LearnedInput::Spike], &[channels]) = (loaded.inputs(), loaded.channels()) else {
            bail!(
                "bench-live: --method = {} reads events ({}): the live graph has a spike camera only",
                opts.method,
                model.display()
            );
        };
        Ok(LiveMethod::Network {
            name: opts.method.clone(),
            model: model.canonicalize()?,
            precision,
            channels,
        })
    }

    /// The sink's input for its frames.
    pub fn input(&self) -> &str {
        match self {
            LiveMethod::Tfp => "tfp",
            LiveMethod::Network { name, .. } => name,
        }
    }

    /// The infer node's id.
    fn infer_id(&self) -> &'static str {
        match self {
            LiveMethod::Tfp => "infer-tfp",
            LiveMethod::Network { .. } => "infer",
        }
    }
}

/// One run's figures.
#[derive(Clone, Debug, PartialEq)]
pub struct LiveRun {
    /// Camera time streamed, seconds.
    pub camera_s: f64,
    /// Wall time of the dataflow, seconds (start-up included).
    pub wall_s: f64,
    /// Frames the graph should have made.
    pub expected: u64,
    /// Frames that reached the sink.
    pub received: u64,
    /// Frames lost on the way.
    pub missing: u64,
    /// Latency p50 and p99, milliseconds.
    pub latency_ms: Option<(f64, f64)>,
    /// Latency over each minute.
    pub minutes: Vec<LatencyWindow>,
}

impl LiveRun {
    /// Camera time over wall time: 1 or more keeps up.
    pub fn real_time(&self) -> f64 {
        if self.wall_s > 0.0 {
            self.camera_s / self.wall_s
        } else {
            0.0
        }
    }
}

/// Checks the options and writes the graph with them, its stages in processes as `layout`
/// says, into `opts.out/<layout>/`; returns its path.
pub fn prepare(opts: &LiveBenchOptions, layout: Layout) -> eyre::Result<PathBuf> {
    let bad = |name: &str, v: String, why: &str| -> eyre::Result<PathBuf> {
        bail!("bench-live: --{name} = {v} is invalid: {why}")
    };
    if !(opts.seconds.is_finite() && opts.seconds > 0.0 && opts.seconds <= 3600.0) {
        return bad("seconds", opts.seconds.to_string(), "must be in (0, 3600]");
    }
    if opts.rate_hz == 0 || !opts.rate_hz.is_multiple_of(1000) {
        return bad(
            "rate-hz",
            opts.rate_hz.to_string(),
            "must be a positive multiple of 1000 (1-ms chunks)",
        );
    }
    if opts.fps == 0 || !opts.rate_hz.is_multiple_of(opts.fps) {
        return bad(
            "fps",
            opts.fps.to_string(),
            "must divide --rate-hz (a frame every whole number of planes)",
        );
    }
    let stride = opts.rate_hz / opts.fps;
    let planes = (opts.seconds * opts.rate_hz as f64).round() as u64;
    let method = LiveMethod::of(opts)?;
    if let LiveMethod::Network { channels, .. } = &method
        && opts.window_planes < *channels as u64
    {
        return bad(
            "window-planes",
            opts.window_planes.to_string(),
            &format!("{} reads {channels} planes a frame", opts.method),
        );
    }
    let out = opts.out.join(layout.name());
    std::fs::create_dir_all(&out).wrap_err_with(|| format!("cannot create {}", out.display()))?;
    let out = out.canonicalize()?;
    let frames = out.join("frames");
    if frames.exists() {
        std::fs::remove_dir_all(&frames)
            .wrap_err_with(|| format!("cannot clear {}", frames.display()))?;
    }
    let mut g: serde_yaml::Value = serde_yaml::from_str(LIVE_GRAPH)?;
    if let LiveMethod::Network { name, .. } = &method {
        // represent makes the spike representation, infer reads it, the sink its frames.
        let mut edit = |id: &str, key: &str, value: &str| -> eyre::Result<()> {
            let nodes = g["nodes"].as_sequence_mut();
            let node = nodes
                .into_iter()
                .flatten()
                .find(|n| n["id"].as_str() == Some(id))
                .ok_or_else(|| eyre::eyre!("the live graph has no node {id}"))?;
            node[key] = serde_yaml::from_str(value)?;
            Ok(())
        };
        match opts.network_input {
            NetworkInput::Represent => {
                edit("represent", "outputs", "[spike_repr]")?;
                edit("infer-tfp", "inputs", "{spike_repr: represent/spike_repr}")?;
            }
            NetworkInput::Windows => {
                edit("infer-tfp", "inputs", "{windows: align/windows}")?;
            }
        }
        edit("infer-tfp", "id", "infer")?;
        edit("sink", "inputs", &format!("{{{name}: infer/frames}}"))?;
        if opts.network_input == NetworkInput::Windows
            && let Some(nodes) = g["nodes"].as_sequence_mut()
        {
            nodes.retain(|n| n["id"].as_str() != Some("represent"));
        }
    }
    let represent = !matches!(
        (&method, opts.network_input),
        (LiveMethod::Network { .. }, NetworkInput::Windows)
    );
    if let Some(m) = g.as_mapping_mut() {
        m.remove("processes");
        if let Some(p) = layout.processes(method.infer_id(), represent) {
            m.insert("processes".into(), serde_yaml::from_str(&p)?);
        }
    }
    let text = serde_yaml::to_string(&g)?;
    graph::write_built_in(&text, &out, "neuspike bench-live", |id, _| match id {
        "spike-source" => Some(format!(
            "--scene {} --rate-hz {} --chunk-planes {} --max-planes {planes} --seed 1 --pace realtime{}",
            opts.scene,
            opts.rate_hz,
            opts.rate_hz / 1000,
            match opts.repeat_planes {
                0 => String::new(),
                n => format!(" --repeat-planes {n}"),
            }
        )),
        "align" => Some(format!(
            "--window-planes {} --stride-planes {stride}",
            opts.window_planes
        )),
        "represent" => Some(match &method {
            LiveMethod::Tfp => format!("--tfp-planes {}", opts.window_planes),
            LiveMethod::Network { channels, .. } => format!("--repr-channels {channels}"),
        }),
        "infer" => match &method {
            LiveMethod::Network {
                model, precision, ..
            } => Some(format!(
                "--method learned --model {} --precision {precision} --threads {}",
                model.display(),
                opts.infer_threads
            )),
            LiveMethod::Tfp => None,
        },
        "sink" => Some(format!(
            "--out {} --bit-depth 8 --write-every {}",
            frames.display(),
            opts.write_every
        )),
        _ => None,
    })
}

/// Reads a run's figures for the sink's `input` from its `summary.yml` in `frames`.
pub fn figures(frames: &Path, input: &str, camera_s: f64, wall_s: f64) -> eyre::Result<LiveRun> {
    let path = frames.join("summary.yml");
    let file = neuspike_sink::read_run(frames)?;
    let Some(counted) = file.inputs.get(input) else {
        bail!("{}: no input `{input}`", path.display());
    };
    Ok(LiveRun {
        camera_s,
        wall_s,
        expected: counted.counts.expected,
        received: counted.counts.received,
        missing: counted.counts.missing,
        latency_ms: counted.latency.map(|l| (l.p50_ms, l.p99_ms)),
        minutes: counted.latency_by_minute.clone(),
    })
}

/// Runs the benchmark and prints one Markdown row a run: each layout in turn, `--runs` times,
/// its wall time also as a ratio to the first layout's in the same round.
pub fn run(opts: &LiveBenchOptions) -> eyre::Result<Vec<(Layout, LiveRun)>> {
    if opts.processes.is_empty() {
        bail!("bench-live: --processes names no layout");
    }
    let input = LiveMethod::of(opts)?.input().to_string();
    let mut graphs = Vec::new();
    for &layout in &opts.processes {
        let path = prepare(opts, layout)?;
        let frames = path.parent().unwrap_or(Path::new(".")).join("frames");
        graphs.push((layout, path, frames));
    }
    println!(
        "| method | processes | camera | frames/s | camera s | wall s | vs {} | real time | frames | lost | latency p50 ms | latency p99 ms |\n\
         |---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        opts.processes[0].name()
    );
    let mut runs = Vec::new();
    for _ in 0..opts.runs {
        let mut baseline = None;
        for (layout, path, frames) in &graphs {
            let (r, samples) = run_one(opts, path, frames, &input)?;
            let base = *baseline.get_or_insert(r.wall_s);
            let (p50, p99) = r.latency_ms.map_or(("-".into(), "-".into()), |(a, b)| {
                (format!("{a:.1}"), format!("{b:.1}"))
            });
            // A baseline of zero seconds cannot be: the ratio is then left out.
            let vs = if base > 0.0 {
                format!("{:.2}x", r.wall_s / base)
            } else {
                "-".into()
            };
            println!(
                "| {} | {} | {} kHz{} | {} | {:.1} | {:.2} | {vs} | {:.3}x | {}/{} | {} | {p50} | {p99} |",
                opts.method,
                layout.name(),
                opts.rate_hz / 1000,
                if opts.repeat_planes > 0 {
                    ", repeated"
                } else {
                    ""
                },
                opts.fps,
                r.camera_s,
                r.wall_s,
                r.real_time(),
                r.received,
                r.expected,
                r.missing
            );
            if opts.soak {
                let rss_csv = path.parent().unwrap_or(Path::new(".")).join("rss.csv");
                soak::report(&samples, &r.minutes, r.missing, &rss_csv)?;
            }
            runs.push((*layout, r));
        }
    }
    Ok(runs)
}

/// Runs the graph at `path` once: its figures for the sink's `input` from the summary in
/// `frames`, and the memory samples taken during it (with `--soak`).
fn run_one(
    opts: &LiveBenchOptions,
    path: &Path,
    frames: &Path,
    input: &str,
) -> eyre::Result<(LiveRun, Vec<soak::RssSample>)> {
    let done = Arc::new(AtomicBool::new(false));
    let rss_csv = path.parent().unwrap_or(Path::new(".")).join("rss.csv");
    let sampler = opts
        .soak
        .then(|| soak::spawn_sampler(rss_csv.clone(), done.clone()));
    let report = graph::run(path, &[], false, None, None);
    done.store(true, Ordering::Relaxed);
    let samples = match sampler.map(|s| s.join()) {
        Some(Ok(samples)) => samples?,
        Some(Err(_)) => bail!("bench-live: the memory sampler panicked"),
        None => Vec::new(),
    };
    let report = report?;
    let wall_s = report.elapsed.as_secs_f64();
    report.into_result()?;
    Ok((figures(frames, input, opts.seconds, wall_s)?, samples))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opts(out: PathBuf) -> LiveBenchOptions {
        LiveBenchOptions {
            seconds: 0.5,
            rate_hz: 40_000,
            fps: 200,
            window_planes: 33,
            scene: "bright-static".into(),
            repeat_planes: 0,
            write_every: 10,
            runs: 1,
            processes: vec![Layout::Nodes, Layout::One],
            out,
            soak: false,
            method: "tfp".into(),
            models: PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/models")),
            network_input: NetworkInput::Windows,
            infer_threads: 1,
        }
    }

    #[test]
    fn the_graph_is_the_shipped_one_with_the_camera_and_rate_set() {
        let shipped = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/graphs/spike-tfp-live.yml"
        ))
        .expect("graphs/spike-tfp-live.yml");
        assert_eq!(LIVE_GRAPH, shipped);
        let dir = tempfile::tempdir().expect("tempdir");
        let o = opts(dir.path().join("b"));
        // Without node binaries beside the test program the graph cannot be resolved, but the
        // options are checked first.
        for (bad, name) in [
            (
                LiveBenchOptions {
                    fps: 300,
                    ..o.clone()
                },
                "--fps",
            ),
            (
                LiveBenchOptions {
                    rate_hz: 20_500,
                    ..o.clone()
                },
                "--rate-hz",
            ),
            (
                LiveBenchOptions {
                    seconds: 0.0,
                    ..o.clone()
                },
                "--seconds",
            ),
        ] {
            let e = prepare(&bad, Layout::Nodes).expect_err(name).to_string();
            assert!(e.contains(name), "{e}");
        }
        if let Ok(path) = prepare(&o, Layout::Nodes) {
            let text = std::fs::read_to_string(path).expect("graph");
            assert!(text.contains("--rate-hz 40000 --chunk-planes 40 --max-planes 20000"));
            assert!(text.contains("--stride-planes 200") && text.contains("--write-every 10"));
        }
        if let Ok(path) = prepare(&o, Layout::One) {
            // One node, every stage in it, with the same arguments.
            let text = std::fs::read_to_string(path).expect("graph");
            let g: serde_yaml::Value = serde_yaml::from_str(&text).expect("yaml");
            let nodes = g["nodes"].as_sequence().expect("nodes");
            assert_eq!(nodes.len(), 1, "{text}");
            assert!(text.contains("--rate-hz 40000 --chunk-planes 40 --max-planes 20000"));
            assert!(text.contains("--stride-planes 200") && text.contains("--write-every 10"));
        }
    }

    #[test]
    fn a_network_reads_the_spike_representation_and_one_that_reads_events_is_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        let o = LiveBenchOptions {
            method: "neuspike-spike-8-int8".into(),
            fps: 100,
            ..opts(dir.path().join("b"))
        };
        let m = LiveMethod::of(&o).expect("spike-8");
        let LiveMethod::Network {
            precision,
            channels,
            ..
        } = &m
        else {
            panic!("{m:?}")
        };
        assert_eq!(
            (precision.to_string().starts_with("int8"), *channels),
            (true, 32)
        );
        assert_eq!(m.input(), "neuspike-spike-8-int8");
        for (method, why) in [
            ("neuspike-fused-8", "reads events"),
            ("neuspike-nothing", "neither tfp nor a network"),
        ] {
            let bad = LiveBenchOptions {
                method: method.into(),
                ..o.clone()
            };
            let e = prepare(&bad, Layout::Nodes).expect_err(method).to_string();
            assert!(e.contains(why) && e.contains(method), "{e}");
        }
        let short = LiveBenchOptions {
            window_planes: 20,
            ..o.clone()
        };
        let e = prepare(&short, Layout::Nodes)
            .expect_err("20 planes")
            .to_string();
        assert!(
            e.contains("--window-planes = 20") && e.contains("32 planes"),
            "{e}"
        );
        // Without node binaries beside the test program the graph cannot be resolved.
        let inputs = [NetworkInput::Windows, NetworkInput::Represent];
        for (layout, input) in [Layout::Nodes, Layout::One]
            .into_iter()
            .flat_map(|l| inputs.map(|i| (l, i)))
        {
            let o = LiveBenchOptions {
                network_input: input,
                ..o.clone()
            };
            if let Ok(path) = prepare(&o, layout) {
                let text = std::fs::read_to_string(path).expect("graph");
                // Of the windows: no represent stage, infer reads align's windows.
                let represent = input == NetworkInput::Represent;
                assert_eq!(text.contains("--repr-channels 32"), represent, "{text}");
                assert_eq!(text.contains("represent"), represent, "{text}");
                if layout == Layout::Nodes {
                    assert!(text.contains("align/windows"), "{text}");
                }
                assert!(
                    text.contains("--method learned --model") && text.contains("--precision int8")
                );
                assert!(
                    !text.contains("infer-tfp") && !text.contains("--tfp-planes"),
                    "{text}"
                );
                if layout == Layout::Nodes {
                    let g: serde_yaml::Value = serde_yaml::from_str(&text).expect("yaml");
                    let sink = g["nodes"]
                        .as_sequence()
                        .and_then(|n| n.iter().find(|n| n["id"].as_str() == Some("sink")))
                        .expect("sink");
                    assert_eq!(
                        sink["inputs"]["neuspike-spike-8-int8"]["source"].as_str(),
                        Some("infer/frames"),
                        "{text}"
                    );
                }
            }
        }
    }

    #[test]
    fn figures_come_from_the_sinks_summary_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        std::fs::write(dir.path().join("metrics.csv"), "header\nrow\n").expect("write");
        std::fs::write(
            dir.path().join("summary.yml"),
            "metrics_rows: 1\ninputs:\n  tfp:\n    input: tfp\n    expected: 10\n    received: 9\n    written: 1\n    missing: 1\n    ended: true\n    latency:\n      frames: 9\n      p50_ms: 2.0\n      p99_ms: 5.5\n      max_ms: 6.0\n",
        )
        .expect("write");
        let r = figures(dir.path(), "tfp", 1.0, 1.25).expect("figures");
        let e = figures(dir.path(), "neuspike-spike-8", 1.0, 1.25)
            .expect_err("no such input")
            .to_string();
        assert!(e.contains("no input `neuspike-spike-8`"), "{e}");
        assert_eq!((r.expected, r.received, r.missing), (10, 9, 1));
        assert_eq!(r.latency_ms, Some((2.0, 5.5)));
        assert_eq!(r.real_time(), 0.8);
        std::fs::remove_file(dir.path().join("summary.yml")).expect("remove");
        let e = figures(dir.path(), "tfp", 1.0, 1.0)
            .expect_err("no summary")
            .to_string();
        assert!(e.contains("no summary.yml: the run did not finish"), "{e}");
    }
}
