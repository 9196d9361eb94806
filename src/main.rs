//! `neuspike`: runs neuspike graphs on an embedded dora daemon.

use std::path::PathBuf;

use clap::{Parser, Subcommand};
use eyre::WrapErr;
use neuspike::{demo_graph, graph};

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
    /// commands.
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
        /// Stop the graph after this many seconds.
        #[arg(long)]
        stop_after_s: Option<f64>,
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
    /// List the built-in scenes.
    Scenes,
}

fn main() -> eyre::Result<()> {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn,neuspike=info"));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    match cli.command {
        Command::Run {
            graph,
            set,
            no_build,
            stop_after_s,
        } => {
            let overrides = set
                .iter()
                .map(|s| graph::parse_override(s))
                .collect::<eyre::Result<Vec<_>>>()?;
            let stop_after = stop_after_s.map(std::time::Duration::from_secs_f64);
            let report = graph::run(&graph, &overrides, !no_build, stop_after, None)?;
            report.print();
            report.into_result()
        }
        Command::Demo { scene, no_build } => demo(&scene, !no_build),
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

fn demo(scene: &str, build: bool) -> eyre::Result<()> {
    // Built-in names pass through; a path is made absolute, since nodes start in graphs/.
    let scene_arg = if neuspike_scene::Scene::builtin_names().contains(&scene) {
        scene.to_string()
    } else {
        std::fs::canonicalize(scene)
            .wrap_err_with(|| format!("scene `{scene}` is neither built in nor a readable file"))?
            .display()
            .to_string()
    };
    let set = format!("--scene {scene_arg}");
    let overrides = vec![
        ("spike-source".to_string(), set.clone()),
        ("event-source".to_string(), set),
    ];
    let graph = demo_graph();
    let out = graph::sink_out_dir(&graph)?;
    let report = graph::run(&graph, &overrides, build, None, out.clone())?;
    report.print();
    report.into_result()
}
