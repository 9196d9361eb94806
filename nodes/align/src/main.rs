//! dora node: aligns the spike and event streams. Inputs `spikes` (SpikeChunk) and, optionally,
//! `events` (EventBatch); output `windows` (AlignedWindow) and, when the graph declares it,
//! `events` (EventBatch): the event stream on the spike clock cut at every window's reference
//! instant, each event once (what the event filters of `infer` take).

use dora_node_api::{DoraNode, EventStream};
use neuspike_align::{AlignConfig, AlignStage};
use neuspike_runtime::{graph_inputs, graph_outputs};

/// Node arguments (the graph's `args:`).
#[derive(Debug, clap::Parser)]
#[command(
    name = "neuspike-align",
    about = "Aligns spikes and events into windows",
    args_override_self = true
)]
struct Args {
    #[command(flatten)]
    align: AlignConfig,
}

fn main() -> std::process::ExitCode {
    neuspike_runtime::exit_code(start())
}

/// Reads the settings, opens what the node needs, then runs its loop.
fn start() -> eyre::Result<()> {
    neuspike_runtime::init_logging();
    let args: Args = neuspike_runtime::parse_config("align")?;
    let (node, events) = neuspike_runtime::init_node()?;
    let stage = AlignStage::new(
        args.align,
        graph_inputs(&node).contains("events"),
        graph_outputs(&node).contains("events"),
    );
    run(node, events, stage)
}

/// The stage's loop on the node's links.
fn run(node: DoraNode, events: EventStream, mut stage: AlignStage) -> eyre::Result<()> {
    neuspike_runtime::run_stage(node, events, &mut stage)
}

#[cfg(test)]
mod node_tests;
