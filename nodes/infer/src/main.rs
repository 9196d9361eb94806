//! dora node: reconstruction. Inputs, as the method declares (`Method::inputs`):
//! `representation` (Representation: `tfp`, `isi` or `stp`) and `events` (EventBatch: the `align`
//! node's event stream, cut at each window's `t_ref`). Output `frames` (Frame). The two inputs of
//! one window carry the window's sequence number; a window is reconstructed when both have
//! arrived, in order (`neuspike_reconstruction::Reconstructor`).
//!
//! `--method auto` reads align's windows on its input `windows` and chooses the method of each
//! window from `--policy` (`neuspike_reconstruction::auto`): its frames say which in their `chosen` key.
//!
//! `--method learned --model FILE` runs a NeuSpike-Net exported to ONNX (`neuspike_reconstruction::learned`)
//! on the representations it reads, each its own input named as the represent output that makes
//! it: `spike_repr` and/or `event_integration`. The model is loaded, checked against the graph's
//! inputs and planned before the first message is read.

use dora_node_api::{DoraNode, EventStream};
use neuspike_reconstruction::{InferConfig, InferStage, Reconstructor};
use neuspike_runtime::graph_inputs;

/// tract allocates every intermediate tensor afresh on each run; with the system allocator those
/// megabytes went back to the kernel and came back as page faults on every frame (measured with
/// `neuspike bench-model`: about a quarter of a base-8 network's time at 256x400). mimalloc keeps
/// them for the next frame.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Node arguments (the graph's `args:`).
#[derive(Debug, clap::Parser)]
#[command(
    name = "neuspike-infer",
    about = "Reconstructs frames from representations and events",
    args_override_self = true
)]
struct Args {
    #[command(flatten)]
    infer: InferConfig,
}

fn main() -> std::process::ExitCode {
    neuspike_runtime::exit_code(start())
}

/// Reads the settings, opens what the node needs, then runs its loop.
fn start() -> eyre::Result<()> {
    neuspike_runtime::init_logging();
    let args: Args = neuspike_runtime::parse_config("infer")?;
    let (node, events) = neuspike_runtime::init_node()?;
    let inputs: Vec<String> = graph_inputs(&node).into_iter().collect();
    let stage = args
        .infer
        .reconstructor(&inputs)
        .map_err(|e| eyre::eyre!("infer: {e}"))?;
    neuspike_runtime::run_on_rayon("infer", || run(node, events, stage))
}

/// Reconstructs every window whose inputs all came, in order, and sends its frame.
fn run(node: DoraNode, events: EventStream, stage: Reconstructor) -> eyre::Result<()> {
    neuspike_runtime::run_stage(node, events, &mut InferStage::new(stage))
}

#[cfg(test)]
mod node_tests;
