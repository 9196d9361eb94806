//! dora node: representations of aligned windows. Input `windows` (AlignedWindow); one output per
//! representation kind, computed only when the graph declares it: `tfp`, `isi`, `spike_repr`,
//! `event_integration`, `stp`, `voxel_grid`, `event_stack`, `time_surface` (all Representation).
//!
//! `stp` (TFSTP's rate, `StpFilter`) is the one with state across windows: each pixel's synapse
//! is fed every plane once, up to each window's reference plane (the planes after it wait for
//! the next window), and read there. Windows that leave planes out are gaps: the synapses forget
//! their last spike there, and the count travels as the `gaps` parameter.

use dora_node_api::{DoraNode, EventStream};
use neuspike_represent::{RepresentConfig, Representer};
use neuspike_runtime::{Flow, Inputs, Link, Received, graph_outputs, receive};
use neuspike_schemas::{AlignedWindow, Message, Representation, RepresentationKind};

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
    mut representer: Representer,
    kinds: &[RepresentationKind],
) -> eyre::Result<()> {
    tracing::info!(outputs = ?kinds.iter().map(|k| k.name()).collect::<Vec<_>>(), "represent started");
    let mut out = Link::new(node, events)?;
    for k in kinds {
        out.declare::<Representation>(k.name());
    }
    let mut inputs = Inputs::new(["windows"]);
    receive(&mut out, &mut inputs, |out, msg| {
        if let Received::Message { meta, data, .. } = msg {
            let w = AlignedWindow::from_arrow(meta, data)?;
            for &kind in kinds {
                let r = representer
                    .represent(kind, &w)
                    .map_err(|e| eyre::eyre!("represent: window {} ({kind}): {e}", w.seq()))?;
                // Sequence numbers follow the windows', so a lost window shows downstream too.
                out.send(kind.name(), &r)?;
            }
        }
        Ok(Flow::Continue)
    })?;
    // A window lost at the tail shows downstream too.
    let announced = inputs.announced();
    for k in kinds {
        out.at_least(k.name(), announced)?;
    }
    out.end_all()?;
    tracing::info!(
        windows = inputs.get("windows").map_or(0, |s| s.seq.received()),
        lost = inputs.missing(),
        "represent finished"
    );
    Ok(())
}

#[cfg(test)]
mod node_tests;
