//! The fused node's body: several stages in one process. `neuspike run` makes such a node from a
//! graph's `processes:` (each entry a name and the nodes it holds) and hands it its stages as a
//! graph in the env variable `NEUSPIKE_STAGES` (`neuspike_pipeline::fused_stage`); its inputs
//! and outputs are its stages' links to nodes outside it, named `node.port`. At its end it
//! prints the time each of its stages took.

use eyre::{WrapErr, eyre};
use neuspike_pipeline::{FUSED_STAGES, fused_stage};

/// Reads the stages, opens the node, then runs them as one stage.
///
/// # Errors
/// `NEUSPIKE_STAGES` is missing or does not make a stage, the node cannot start, or a stage
/// failed (what was made before still went out, its streams ended cut short).
pub fn run() -> eyre::Result<()> {
    let spec = std::env::var(FUSED_STAGES).map_err(|_| {
        eyre!("neuspike-fused: {FUSED_STAGES} is not set: this node is made by `neuspike run` from a graph's `processes:`")
    })?;
    let (node, events) = neuspike_runtime::init_node()?;
    let name = node.id().to_string();
    let mut stage = fused_stage(&name, &spec)
        .wrap_err_with(|| format!("neuspike-fused `{name}`: {FUSED_STAGES}"))?;
    let result = neuspike_runtime::run_stage(node, events, &mut stage);
    if let Some(report) = stage.report() {
        println!("process `{name}`, stage by stage:\n{}", report.table());
    }
    result
}
