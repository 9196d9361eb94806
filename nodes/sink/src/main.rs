//! dora node: writes frames as PNG, scores them against ground truth, summarises the run.
//!
//! Inputs: `ground_truth` (Frame, optional) and any number of frame inputs under other ids (one per
//! method). Writes `<out>/<method>/<seq>.png`, `<out>/metrics.csv` (a row per frame, flushed as it
//! goes) and, at the end, `<out>/summary.md` with the mean metrics per method and the frames
//! expected, written and missing on every input.

use dora_node_api::{DoraNode, EventStream};
use eyre::WrapErr;
use neuspike_runtime::graph_inputs;
use neuspike_sink::{SinkConfig, SinkStage};

/// Node arguments (the graph's `args:`).
#[derive(Debug, clap::Parser)]
#[command(
    name = "neuspike-sink",
    about = "Writes and scores frames",
    args_override_self = true
)]
struct Args {
    #[command(flatten)]
    sink: SinkConfig,
}

fn main() -> std::process::ExitCode {
    neuspike_runtime::exit_code(start())
}

/// Reads the settings, opens what the node needs, then runs its loop.
fn start() -> eyre::Result<()> {
    neuspike_runtime::init_logging();
    let args: Args = neuspike_runtime::parse_config("sink")?;
    let (node, events) = neuspike_runtime::init_node()?;
    let inputs: Vec<String> = graph_inputs(&node).into_iter().collect();
    run(node, events, &args.sink, &inputs)
}

/// Writes and scores every frame of `inputs` (`ground_truth` among them, when the graph has it).
fn run(
    node: DoraNode,
    events: EventStream,
    cfg: &SinkConfig,
    inputs: &[String],
) -> eyre::Result<()> {
    let mut stage = SinkStage::new(cfg, inputs).wrap_err("sink")?;
    neuspike_runtime::run_stage(node, events, &mut stage)
}

#[cfg(test)]
mod node_tests;
