//! dora node: representations of aligned windows. Input `windows` (AlignedWindow); one output per
//! representation kind, computed only when the graph declares it: `tfp`, `isi`, `spike_repr`,
//! `event_integration`, `stp`, `voxel_grid`, `event_stack`, `time_surface` (all Representation).
//!
//! `stp` (TFSTP's rate, `StpFilter`) is the one with state across windows: each pixel's synapse
//! is fed every plane once, up to each window's reference plane (the planes after it wait for
//! the next window), and read there. Windows that leave planes out are gaps: the synapses forget
//! their last spike there, and the count travels as the `gaps` parameter.

use dora_node_api::{DoraNode, EventStream};
use neuspike_representations::{RepresentConfig, RepresentStage, Representer};
use neuspike_runtime::graph_outputs;
use neuspike_schemas::RepresentationKind;

/// Node arguments (the graph's `args:`).
#[derive(Clone, Debug, clap::Parser)]
#[command(
    name = "neuspike-represent",
    about = "Spike and event representations",
    args_override_self = true
)]
struct Args {
    #[command(flatten)]
    represent: RepresentConfig,
}

fn main() -> std::process::ExitCode {
    neuspike_runtime::exit_code(start())
}

/// Reads the settings, opens what the node needs, then runs its loop.
fn start() -> eyre::Result<()> {
    neuspike_runtime::init_logging();
    let args: Args = neuspike_runtime::parse_config("represent")?;
    let representer =
        Representer::new(args.represent).map_err(|e| eyre::eyre!("represent: {e}"))?;
    let (node, events) = neuspike_runtime::init_node()?;
    let outputs = graph_outputs(&node);
    let kinds: Vec<RepresentationKind> = RepresentationKind::ALL
        .into_iter()
        .filter(|k| outputs.contains(k.name()))
        .collect();
    neuspike_runtime::run_on_rayon("represent", || run(node, events, representer, &kinds))
}

/// Sends the representations `kinds` of every window, each on the output of its name.
fn run(
    node: DoraNode,
    events: EventStream,
    representer: Representer,
    kinds: &[RepresentationKind],
) -> eyre::Result<()> {
    tracing::info!(outputs = ?kinds.iter().map(|k| k.name()).collect::<Vec<_>>(), "represent started");
    let mut stage = RepresentStage::new(representer, kinds);
    neuspike_runtime::run_stage(node, events, &mut stage)
}

#[cfg(test)]
mod node_tests;
