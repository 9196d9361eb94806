//! `neuspike`: runs neuspike graphs on an embedded dora daemon.

use std::path::PathBuf;

use clap::{Parser, Subcommand};
use eyre::WrapErr;
use neuspike::{graph, record};

/// Spike and event cameras to high-speed video, as a dora dataflow.
#[derive(Debug, Parser)]
#[command(name = "neuspike", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run a graph (YAML dataflow) on an embedded dora daemon, after running its nodes' `build:`
    /// commands. A graph whose nodes name machines (`deploy: { machine: ... }`, as in
    /// graphs/distributed.yml) runs on a dora cluster instead: a coordinator and one daemon per
    /// machine started here on loopback, or the cluster at `--coordinator`. That needs the dora
    /// CLI (`pip install dora-rs-cli==1.1.0`).
    Run {
        /// The graph file.
        graph: PathBuf,
        /// Append arguments to a node's `args:` (later ones win), e.g.
        /// `--set spike-source="--scene dark-slow"`. Repeatable.
        #[arg(long = "set", value_name = "NODE=ARGS")]
        set: Vec<String>,
        /// Skip the nodes' `build:` commands.
        #[arg(long)]
        no_build: bool,
        /// Stop the graph after this many seconds (one daemon only).
        #[arg(long)]
        stop_after_s: Option<f64>,
        /// Run every node on one embedded daemon, whatever machines the graph names.
        #[arg(long, conflicts_with = "coordinator")]
        one_daemon: bool,
        /// Run the graph on the dora cluster whose coordinator is at ADDR[:PORT] (port 6013 when
        /// left out), with a daemon registered for each machine the graph names. Node binaries
        /// must be at the same path on every machine.
        #[arg(long, value_name = "ADDR[:PORT]")]
        coordinator: Option<String>,
        /// Run every node's stage in this process, as one chain: no dora, no copies between
        /// stages; every node must be a neuspike stage. Prints each stage's time.
        #[arg(long, conflicts_with_all = ["coordinator", "one_daemon", "stop_after_s"])]
        in_process: bool,
    },
    /// Run the default graph (both simulated cameras, TFP and TFI) on a built-in scene and print
    /// where the frames and metrics are, with the mean PSNR/SSIM per method.
    Demo {
        /// Built-in scene name or scene YAML path (`neuspike scenes` lists the built-in ones).
        #[arg(long, default_value = "bright-slow")]
        scene: String,
        /// Skip the nodes' `build:` commands.
        #[arg(long)]
        no_build: bool,
    },
    /// Check a graph and draw it; with `--out`, write the whole dora graph it runs as (message
    /// types, credit edges, `build:`, node binaries), with the message types beside it, for the
    /// stock dora CLI (`dora run`, `dora validate --strict-types`).
    /// This program as a stage's node in a dora graph (`neuspike run` points a graph's
    /// `neuspike-<kind>` nodes here when their binaries are not installed beside it).
    #[command(hide = true)]
    Node {
        /// The stage: spike-source, event-source, align, represent, infer, sink, or fused.
        kind: String,
        /// The node's arguments (the graph's `args:`).
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<String>,
    },
    Graph {
        /// The graph file, as a user writes it (nodes, `path`, `args`, data edges).
        graph: PathBuf,
        /// Append arguments to a node's `args:`, as `run --set` does. Repeatable.
        #[arg(long = "set", value_name = "NODE=ARGS")]
        set: Vec<String>,
        /// Write the whole graph here (a `.yml` file; its folder gets `types/`).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// List the built-in scenes.
    Scenes,
    /// Simulate a scene with both cameras and write a recording: spikes.dat (PKU), events.txt,
    /// events.raw (EVT 2.0) and events.aedat4 (AEDAT 4), ground-truth PNGs with their time stamps, recording.yml.
    Simulate {
        /// Built-in scene name or scene YAML path.
        scene: String,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// Spike planes to simulate (default: the scene's duration).
        #[arg(long)]
        planes: Option<u64>,
        /// Ground truth at every plane whose index is a multiple of this (0 = none).
        #[arg(long, default_value_t = 20)]
        gt_every_planes: u64,
        /// Planes per simulation step.
        #[arg(long, default_value_t = 200)]
        chunk_planes: usize,
        /// Spike camera only.
        #[arg(long)]
        no_events: bool,
        /// Spike camera settings, as the spike-source node takes them, e.g.
        /// `--spike="--rate-hz 40000 --fpn-cap false"`.
        #[arg(long, default_value = "", allow_hyphen_values = true)]
        spike: String,
        /// Event camera settings, as the event-source node takes them, e.g.
        /// `--dvs="--theta-on 0.3"`.
        #[arg(long, default_value = "", allow_hyphen_values = true)]
        dvs: String,
    },
    /// Generate a training or held-out set for the learned reconstruction: 5 light scales x 5
    /// speeds of small simulated scenes, each with the spike representation and the event
    /// integration of one window, its ground truth and the TFP/TFI baselines, as .npy shards
    /// (see training/README.md).
    Dataset(neuspike_dataset::DatasetOptions),
    /// Score methods on a held-out `neuspike dataset` set as training/evaluate.py does (PSNR
    /// and SSIM, normal and complex scenes, per light scale), the networks run by tract as the
    /// infer node runs them, in 8 bits and bf16 too (`<name>-int8`, `<name>-bf16`): what a
    /// precision costs in accuracy.
    Evaluate(neuspike::held_out::EvaluateOptions),
    /// Run the DVS on a sequence of intensity frames (a float32 [T, H, W] .npy), as v2e runs
    /// its emulator on video frames: events as text, and a one-line JSON summary (counts and
    /// the emulation's time).
    FramesToEvents(neuspike::frames_to_events::FramesToEventsOptions),
    /// Run the spike camera's pixels (integrate-and-fire, no noise) on a sequence of intensity
    /// frames (a float32 [T, H, W] .npy), the light linear in time between frames: the planes
    /// as a PKU .dat, and a one-line JSON summary (planes, spikes, firing probability).
    FramesToSpikes(neuspike::frames_to_spikes::FramesToSpikesOptions),
    /// Check the DVS against a DAVIS recording (AEDAT 4 with APS frames): emulate the events
    /// of its own frames and compare them with the recorded events (counts, over time, over the
    /// pixels, what the frames cannot show); `--fit-threshold` fits the contrast threshold.
    ApsCheck(neuspike::aps_check::ApsCheckOptions),
    /// Stream the spike-only live graph paced to a camera's clock (default 30 s of a 20 kHz camera
    /// at 1,000 TFP frames/s) and report the wall time against the camera time, the frames lost
    /// and the latency, one Markdown row a run.
    BenchLive {
        #[command(flatten)]
        opts: neuspike::bench_live::LiveBenchOptions,
        /// Skip building the node binaries.
        #[arg(long)]
        no_build: bool,
    },
    /// The speed-accuracy trade: every reconstruction method over a grid of simulated scenes
    /// (5 light scales x 5 speeds at 400x250, and the extreme corners), several held-out textures
    /// each; PSNR, SSIM, 2D entropy and the cost of a frame on 1 and 2 threads; bench.csv
    /// (resumable), summary.md, pareto.png and winners.png in --out.
    Bench(neuspike::trade::BenchOptions),
    /// The spike camera's noise model against a real recording: inter-spike-interval histograms
    /// of its still pixels at matched rates, for the paper's model, each noise term, SCSim's
    /// values and the fitted model; calibration.md, isi.png and profile.yml (a `--profile` file)
    /// in --out.
    Calibrate(neuspike::calibrate::CalibrateOptions),
    /// The homography and clock offset of a rig of two cameras (a spike camera and a DVS behind
    /// a beam splitter), estimated from a stretch of both recordings; prints them as the event
    /// source's and align's arguments.
    CalibrateRig(neuspike::rig::RigOptions),
    /// Time a learned model (ONNX) under tract at a frame size, on 1 and 2 threads (as the infer
    /// node runs it: shapes pinned, optimised once, padded to the network's stride).
    BenchModel {
        /// The ONNX file.
        model: PathBuf,
        /// Frame height (padded up to a multiple of 8).
        #[arg(long, default_value_t = 250)]
        height: usize,
        /// Frame width.
        #[arg(long, default_value_t = 400)]
        width: usize,
        /// Thread counts to time, comma-separated.
        #[arg(long, value_delimiter = ',', default_value = "1,2")]
        threads: Vec<usize>,
        /// Timed runs per thread count.
        #[arg(long, default_value_t = 10)]
        runs: usize,
        /// Also print the time per operator kind (median of the runs, on the last thread count).
        #[arg(long)]
        profile: bool,
        /// How tract runs the convolutions: auto (as the infer node: time each path, keep the
        /// fastest), direct, im2col or blocked (neuspike's 3x3 kernel on wide rows).
        #[arg(long, default_value = "auto")]
        conv: neuspike_reconstruction::learned::ConvPath,
        /// Precisions of the 3x3 convolutions to time side by side, comma-separated: f32, bf16
        /// or int8 (the widest such path this CPU has, as the infer node runs it),
        /// bf16-portable, bf16-avx512, int8-portable, int8-vnni, int8-amx; by default every one
        /// this CPU runs. Ratios are against the first.
        #[arg(long, value_delimiter = ',')]
        precision: Vec<neuspike_reconstruction::learned::Precision>,
        /// Also time a frame from an aligned window both ways, in each precision and thread
        /// count, alternated: the representations made in `f32` (as the represent stage makes
        /// them) then the network, against the network reading the window itself (as the infer
        /// stage does when it reads align's windows: the spike planes bit-packed, the events
        /// themselves where they are few).
        #[arg(long)]
        from_window: bool,
        /// Events in the window of `--from-window`, spread over its pixels and time.
        #[arg(long, default_value_t = 10_000)]
        window_events: usize,
    },
    /// Reconstruct frames from a recorded spike file (PKU .dat) through a graph written to the
    /// output folder (`graph.yml`), e.g. `neuspike reconstruct --spikes car.dat --out out/car`.
    Reconstruct {
        /// The PKU spike .dat.
        #[arg(long)]
        spikes: PathBuf,
        /// An event recording of the same sensor size and clock, for the methods that read
        /// events (hf, cf, fusion), e.g. the `events.raw` of `neuspike simulate` (with
        /// `--dvs="--width 400 --height 250"`).
        #[arg(long)]
        events: Option<PathBuf>,
        /// Ground truth recorded with the spikes: a folder with `timestamps.txt` and PNGs, or an
        /// AEDAT 4 file whose APS frames are the truth (each frame scores the nearest
        /// reconstruction within half a stride); by default `ground-truth/` beside the spike file
        /// when it exists. The frames are then scored (metrics.csv, summary.md).
        #[arg(long)]
        truth: Option<PathBuf>,
        /// Reconstruction method.
        #[arg(long, default_value = "tfp")]
        method: neuspike::reconstruct::Method,
        /// The ONNX network for `--method learned`, e.g. models/neuspike-spike-8.onnx.
        #[arg(long)]
        model: Option<PathBuf>,
        /// The policy of `--method auto` (`neuspike bench --fit-policy`); the networks it names
        /// are read from its folder. Without `--events` auto chooses among the methods that read
        /// spikes alone.
        #[arg(long, default_value = "models/policy.yml")]
        policy: PathBuf,
        /// Output folder: frames, metrics, summary, and the graph that made them.
        #[arg(long)]
        out: PathBuf,
        /// Spike-source settings for the file, e.g. `--source="--file-width 416 --head-columns 16
        /// --rate-hz 40000 --start-plane 1000 --max-planes 4000 --lum-per-rate 2"`.
        #[arg(long, default_value = "", allow_hyphen_values = true)]
        source: String,
        /// Event-source settings for the event file, e.g. `--event-source="--file-width 400
        /// --file-height 250"` for a file that does not state its sensor size.
        #[arg(long, default_value = "", allow_hyphen_values = true)]
        event_source: String,
        /// Infer settings, e.g. `--infer="--contrast 0.25 --theta-mode per-pixel"`.
        #[arg(long, default_value = "", allow_hyphen_values = true)]
        infer: String,
        /// Planes per window: 33 by default; for `--method auto` the longest its policy's
        /// methods read (256), and a smaller value (a short recording) leaves out the methods
        /// that read more.
        #[arg(long)]
        window_planes: Option<u32>,
        /// Planes between two frames.
        #[arg(long, default_value_t = 10)]
        stride_planes: u32,
        /// PNG bit depth: 8 or 16.
        #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u8).range(8..=16))]
        bit_depth: u8,
        /// Skip the nodes' `build:` command.
        #[arg(long)]
        no_build: bool,
    },
    /// Play a recording onto zenoh as a camera machine sends it (Arrow IPC SpikeChunks or
    /// EventBatches, then the end-of-stream marker), for a graph elsewhere whose source reads
    /// the key: `spike-source --from-zenoh KEY`, `event-source --from-zenoh KEY`. Waits for
    /// that subscriber first.
    PublishFile(neuspike::publish_file::PublishFile),
    /// Describe a recording: format, resolution, duration, counts, rates, first and last times.
    Info {
        /// A PKU spike .dat, or an event file (ECD text, Prophesee RAW or DAT).
        file: PathBuf,
        /// Width of a spike .dat, or of an event file that does not state it.
        #[arg(long)]
        width: Option<u16>,
        /// Height, likewise.
        #[arg(long)]
        height: Option<u16>,
        /// Extra columns stored per row of a spike .dat (0 or 16).
        #[arg(long, default_value_t = 0)]
        head_columns: usize,
        /// Plane rate of a spike .dat.
        #[arg(long, default_value_t = 20_000.0)]
        rate_hz: f64,
    },
}

/// Spike camera settings given as one string.
#[derive(Debug, Parser)]
#[command(name = "--spike", no_binary_name = true)]
struct SpikeSettings {
    #[command(flatten)]
    camera: neuspike_spike_camera::CameraConfig,
}

/// Event camera settings given as one string.
#[derive(Debug, Parser)]
#[command(name = "--dvs", no_binary_name = true)]
struct DvsSettings {
    #[command(flatten)]
    camera: neuspike_event_camera::DvsConfig,
}

/// Splits a settings string on whitespace and parses it.
fn settings<P: Parser>(what: &str, args: &str) -> eyre::Result<P> {
    P::try_parse_from(args.split_whitespace()).map_err(|e| eyre::eyre!("{what}: {e}"))
}

/// The infer node's allocator (see nodes/infer/src/main.rs), so that `bench-model` and `bench`
/// time the network as the node runs it; counted, for `bench`'s peak memory.
#[global_allocator]
static ALLOCATOR: neuspike::memory::Counting<mimalloc::MiMalloc> =
    neuspike::memory::Counting(mimalloc::MiMalloc);

/// The log filter when `RUST_LOG` is unset: warnings, the program's own progress, and not the
/// embedded daemon's transport chatter (zenoh's scouting).
const DEFAULT_LOG_FILTER: &str = "warn,neuspike=info,zenoh=error";

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    if matches!(cli.command, Command::Node { .. }) {
        // As a node, it logs as the node binaries do.
        neuspike_runtime::init_logging();
    } else {
        let filter = tracing_subscriber::EnvFilter::try_from_default_env()
            .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(DEFAULT_LOG_FILTER));
        tracing_subscriber::fmt()
            .with_env_filter(filter)
            .with_writer(std::io::stderr)
            .init();
    }
    // A failure is one line: what went wrong and its causes, no source locations or backtrace.
    match run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> eyre::Result<()> {
    match cli.command {
        Command::Run {
            graph,
            set,
            no_build,
            stop_after_s,
            one_daemon,
            coordinator,
            in_process,
        } => {
            let overrides = set
                .iter()
                .map(|s| graph::parse_override(s))
                .collect::<eyre::Result<Vec<_>>>()?;
            if in_process {
                let graph = neuspike::in_process::enter_graph_folder(&graph)?;
                let (report, chain) = neuspike::in_process::run(&graph, &overrides)?;
                neuspike::in_process::print_stages(&chain);
                report.print();
                return neuspike::in_process::check(&chain);
            }
            let cluster = match coordinator {
                Some(c) => Some(neuspike::cluster::parse_coordinator(&c)?),
                None if !one_daemon && neuspike::cluster::places_nodes(&graph)? => {
                    Some(neuspike::cluster::Cluster::loopback())
                }
                None => None,
            };
            let report = match cluster {
                Some(cluster) => {
                    if stop_after_s.is_some() {
                        eyre::bail!("--stop-after-s works on one daemon only (add --one-daemon)");
                    }
                    neuspike::cluster::run(&graph, &overrides, !no_build, &cluster)?
                }
                None => {
                    let stop_after = stop_after_s.map(std::time::Duration::from_secs_f64);
                    graph::run(&graph, &overrides, !no_build, stop_after, None)?
                }
            };
            report.print();
            report.into_result()
        }
        Command::Demo { scene, no_build } => demo(&scene, !no_build),
        Command::BenchLive { opts, no_build } => {
            if !no_build {
                graph::build_nodes()?;
            }
            let runs = neuspike::bench_live::run(&opts)?;
            let lost: u64 = runs.iter().map(|(_, r)| r.missing).sum();
            if lost > 0 {
                eyre::bail!("bench-live: {lost} frames lost");
            }
            Ok(())
        }
        Command::Simulate {
            scene,
            out,
            planes,
            gt_every_planes,
            chunk_planes,
            no_events,
            spike,
            dvs,
        } => {
            let spike: SpikeSettings = settings("--spike", &spike)?;
            let dvs: DvsSettings = settings("--dvs", &dvs)?;
            let opts = record::SimulateOptions {
                scene,
                out,
                planes,
                gt_every_planes,
                chunk_planes,
                events: !no_events,
                spike: spike.camera,
                dvs: dvs.camera,
                progress: true,
            };
            let rec = record::simulate(&opts)?;
            println!(
                "{}: {} planes ({} spikes), {} events, {} ground-truth frames",
                rec.out.display(),
                rec.planes,
                rec.spikes,
                rec.events,
                rec.ground_truth
            );
            Ok(())
        }
        Command::Calibrate(opts) => {
            let cal = neuspike::calibrate::run(&opts)?;
            for m in &cal.models {
                println!(
                    "{:<36} sigma {:.4}  mean W1 {:.3} ticks  mean KL {:.3}",
                    m.label,
                    m.noise.fire_sigma(),
                    m.score.mean_wasserstein,
                    m.score.mean_kl
                );
            }
            println!(
                "{}: calibration.md, isi.png, profile.yml (`--profile {}`)",
                opts.out.display(),
                opts.out.join("profile.yml").display()
            );
            Ok(())
        }
        Command::CalibrateRig(opts) => {
            let (est, size) = neuspike::rig::run(&opts)?;
            println!(
                "homography {} (event camera pixel -> spike camera pixel)\nclock offset {} ns (event camera minus spike camera), {}\nagreement {:.3} over {} events\n{}",
                est.homography,
                est.offset_ns,
                est.clock,
                est.score,
                est.events,
                neuspike::rig::arguments(&est, size)
            );
            Ok(())
        }
        Command::Bench(opts) => {
            let r = neuspike::trade::run(&opts, true)?;
            println!(
                "{}: {} rows ({} new, {} already there): bench.csv, summary.md, pareto.png, winners.png",
                r.out.display(),
                r.rows,
                r.new_rows,
                r.rows - r.new_rows
            );
            Ok(())
        }
        Command::ApsCheck(opts) => neuspike::aps_check::main(&opts),
        Command::FramesToEvents(opts) => {
            let s = neuspike::frames_to_events::run(&opts)?;
            println!("{}", s.json());
            Ok(())
        }
        Command::FramesToSpikes(opts) => {
            let s = neuspike::frames_to_spikes::run(&opts)?;
            println!("{}", s.json());
            Ok(())
        }
        Command::Evaluate(opts) => {
            let scores = neuspike::held_out::run(&opts)?;
            let n = scores
                .first()
                .and_then(|m| m.group("all"))
                .map_or(0, |g| g.n);
            println!("held-out: {} ({n} samples)\n", opts.test.display());
            print!("{}", neuspike::held_out::tables(&scores));
            Ok(())
        }
        Command::Dataset(opts) => {
            let sum = neuspike_dataset::generate(&opts, true)?;
            println!(
                "{}: {} samples ({} complex) in {} shards, {} photographs",
                opts.out.display(),
                sum.samples,
                sum.complex,
                sum.shards,
                sum.photos
            );
            Ok(())
        }
        Command::BenchModel {
            model,
            height,
            width,
            threads,
            runs,
            profile,
            conv,
            precision,
            from_window,
            window_events,
        } => {
            let precisions = if precision.is_empty() {
                neuspike::bench_model::every_precision()
            } else {
                precision
            };
            println!(
                "{}: {height}x{width}; this CPU: {}, bf16 on {}, int8 on {}",
                model.display(),
                neuspike_simd::detect().name(),
                neuspike_simd::bf16::detect().name(),
                neuspike_simd::dot::detect().name()
            );
            let mut first: Option<Vec<neuspike::bench_model::Timing>> = None;
            for &p in &precisions {
                let t = neuspike::bench_model::time_model(
                    &model, height, width, &threads, runs, conv, p,
                )?;
                for x in &t {
                    let base = first
                        .as_ref()
                        .and_then(|f| f.iter().find(|b| b.threads == x.threads));
                    let ratio = base.map_or(String::new(), |b| {
                        format!(
                            ", {:.2}x the time of {}",
                            x.median_ms / b.median_ms,
                            b.precision
                        )
                    });
                    println!(
                        "{:<16} threads {}: median {:.2} ms, min {:.2} ms ({} runs, {} convolutions{ratio})",
                        x.precision.to_string(),
                        x.threads,
                        x.median_ms,
                        x.min_ms,
                        x.runs,
                        x.conv
                    );
                }
                first.get_or_insert(t);
            }
            if from_window {
                for &p in &precisions {
                    let t = neuspike::bench_model::time_from_window(
                        &model,
                        (height, width),
                        &threads,
                        runs,
                        conv,
                        p,
                        window_events,
                    )?;
                    for x in t {
                        println!(
                            "{:<16} threads {}: from a window: represented then run {:.2} ms, \
                             read from the window {:.2} ms ({:.2}x)",
                            p.to_string(),
                            x.threads,
                            x.represented_ms,
                            x.window_ms,
                            x.window_ms / x.represented_ms
                        );
                    }
                }
            }
            if profile {
                let n = threads.last().copied().unwrap_or(1);
                let last = precisions.last().copied().unwrap_or_default();
                let p = neuspike::bench_model::profile_model(
                    &model, height, width, n, runs, conv, last,
                )?;
                let total = p.total_ms().max(f64::MIN_POSITIVE);
                println!(
                    "per operator, {last}, {n} thread(s), median of {runs} runs (sum {total:.2} ms):"
                );
                for (op, ms, k) in p.by_op() {
                    println!(
                        "  {op:<28} {ms:>9.2} ms {:>5.1}%  {k} nodes",
                        100.0 * ms / total
                    );
                }
                println!("slowest nodes:");
                for t in p.slowest(usize::MAX) {
                    println!("  {:<48} {:<22} {:>8.2} ms", t.node, t.op, t.ms);
                }
            }
            Ok(())
        }
        Command::Reconstruct {
            spikes,
            events,
            truth,
            method,
            model,
            policy,
            out,
            source,
            event_source,
            infer,
            window_planes,
            stride_planes,
            bit_depth,
            no_build,
        } => {
            if bit_depth != 8 && bit_depth != 16 {
                eyre::bail!("--bit-depth {bit_depth}: must be 8 or 16");
            }
            let opts = neuspike::reconstruct::ReconstructOptions {
                spikes,
                events,
                truth,
                method,
                model,
                policy,
                out,
                source_args: source,
                event_source_args: event_source,
                infer_args: infer,
                window_planes,
                stride_planes,
                bit_depth,
                build: !no_build,
            };
            let report = neuspike::reconstruct::reconstruct(&opts)?;
            report.print();
            report.into_result()
        }
        Command::PublishFile(opts) => {
            let p = neuspike::publish_file::run(&opts)?;
            println!(
                "published {} messages ({} {}) on {} in {:.2} s",
                p.messages,
                p.items,
                if p.spikes { "planes" } else { "events" },
                p.key,
                p.elapsed.as_secs_f64()
            );
            Ok(())
        }
        Command::Info {
            file,
            width,
            height,
            head_columns,
            rate_hz,
        } => {
            let mut spikes = neuspike_formats::pku::PkuOptions::default();
            if let (Some(w), Some(h)) = (width, height) {
                spikes.geometry.width = usize::from(w);
                spikes.geometry.height = usize::from(h);
            }
            spikes.geometry.head_columns = head_columns;
            if !(rate_hz.is_finite() && rate_hz > 0.0) {
                eyre::bail!("--rate-hz {rate_hz}: must be finite and > 0");
            }
            spikes.plane_period_ns = (1e9 / rate_hz).round() as i64;
            let mut events = neuspike_formats::ReadOptions::default();
            if let (Some(w), Some(h)) = (width, height) {
                events.resolution = Some(neuspike_formats::Resolution::new(w, h));
            }
            println!("{}", record::describe(&file, &spikes, &events)?);
            Ok(())
        }
        Command::Node { kind, args } => neuspike::node::run(&kind, &args),
        Command::Graph { graph, set, out } => {
            let overrides = set
                .iter()
                .map(|s| graph::parse_override(s))
                .collect::<eyre::Result<Vec<_>>>()?;
            let graph = graph
                .canonicalize()
                .wrap_err_with(|| format!("graph {} not found", graph.display()))?;
            let mut g = graph::prepare(&graph, &overrides, false)?;
            print!("{}", neuspike_pipeline::derive::draw(&g)?);
            if let Some(out) = out {
                graph::write_full(&mut g, &graph, &out)?;
                println!(
                    "\nwritten: {} (message types in its folder's types/)",
                    out.display()
                );
            }
            Ok(())
        }
        Command::Scenes => {
            for name in neuspike_scene::Scene::builtin_names() {
                let s = neuspike_scene::Scene::builtin(name)?;
                println!(
                    "{name:16} {}x{} {:>6} ms  light x{}",
                    s.width(),
                    s.height(),
                    s.duration_ns() / 1_000_000,
                    s.light_scale()
                );
            }
            Ok(())
        }
    }
}

/// The default graph on `scene`, written into `out/demo` under the current folder and run there.
fn demo(scene: &str, build: bool) -> eyre::Result<()> {
    if build {
        graph::build_nodes()?;
    }
    let out = std::path::Path::new("out/demo");
    let graph_path = neuspike::demo::prepare(out, scene)?;
    let out = graph_path.parent().map(std::path::Path::to_path_buf);
    let report = graph::run(&graph_path, &[], false, None, out)?;
    report.print();
    report.into_result()
}
