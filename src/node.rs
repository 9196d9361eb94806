//! `neuspike node KIND ARGS...`: this program as one of neuspike's stage nodes, for a graph whose
//! node binaries are not installed beside it (`crate::graph::resolve_node_binaries` points such
//! nodes here). The stage is made as the in-process chain makes it (`neuspike_pipeline`), from
//! the node's arguments and the inputs and outputs its graph wires, and run as the node binary
//! runs it (`neuspike_runtime::run_stage`); `fused` runs a process of several stages.

use eyre::bail;
use neuspike_pipeline::{STAGES, make_stage};

/// The stage kinds this program serves as a node: every stage, and `fused`.
pub fn serves(kind: &str) -> bool {
    kind == "fused" || STAGES.contains(&kind)
}

/// Runs this process as the node of stage `kind` with `args`.
///
/// # Errors
/// Not a stage this program serves, arguments the stage refuses, or the stage's own failure.
pub fn run(kind: &str, args: &[String]) -> eyre::Result<()> {
    if kind == "fused" {
        return neuspike_fused::run();
    }
    if !serves(kind) {
        bail!(
            "neuspike node: `{kind}` is not a stage this program runs (it runs: {}, fused)",
            STAGES.join(", ")
        );
    }
    let (node, events) = neuspike_runtime::init_node()?;
    let inputs: Vec<String> = neuspike_runtime::graph_inputs(&node).into_iter().collect();
    let outputs: Vec<String> = neuspike_runtime::graph_outputs(&node).into_iter().collect();
    let mut stage = make_stage(kind, args, &inputs, &outputs)?;
    neuspike_runtime::run_stage(node, events, &mut stage)
}
