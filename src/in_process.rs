//! `neuspike run --in-process`: a graph's stages in this process, as one chain, no dora.

use std::path::Path;

use eyre::{WrapErr, eyre};
use neuspike_pipeline::GraphChain;
use neuspike_stage::ChainReport;

use crate::graph::{Report, sink_out_dirs};

/// Runs the graph at `graph_path` as an in-process chain of its stages, `overrides` appended to
/// its nodes' arguments. Relative paths in the arguments are taken from the current folder: a
/// graph's nodes run in the graph's folder, so a program runs this there
/// ([`enter_graph_folder`]). Returns the run's report (for the sinks' summaries) and the
/// chain's, stage by stage.
///
/// # Errors
/// The graph cannot be read, holds a node that is not a neuspike stage, a stage refused its
/// settings, or a stage failed (after the run ended: the sinks wrote what they received).
pub fn run(
    graph_path: &Path,
    overrides: &[(String, String)],
) -> eyre::Result<(Report, ChainReport)> {
    let graph_path = graph_path
        .canonicalize()
        .wrap_err_with(|| format!("graph {} not found", graph_path.display()))?;
    let mut g = GraphChain::read(&graph_path)?;
    for (id, extra) in overrides {
        let words = shlex::split(extra)
            .ok_or_else(|| eyre!("--set {id}: `{extra}` has an unclosed quote"))?;
        g.append_args(id, &words)?;
    }
    let yaml = neuspike_pipeline::read_graph(&graph_path)?;
    let out_dirs = sink_out_dirs(&graph_path, &yaml);
    let started_at = std::time::SystemTime::now();
    let chain = g
        .chain()
        .and_then(|c| c.run())
        .wrap_err_with(|| format!("{}", graph_path.display()))?;
    let report = Report {
        failures: Vec::new(),
        out_dirs,
        elapsed: chain.wall,
        started_at,
        logs: None,
    };
    Ok((report, chain))
}

/// Makes the graph's folder this process's current folder (where its nodes would run); returns
/// the graph's path as seen from there.
///
/// # Errors
/// The graph is not found, or its folder cannot be entered.
pub fn enter_graph_folder(graph_path: &Path) -> eyre::Result<std::path::PathBuf> {
    let graph_path = graph_path
        .canonicalize()
        .wrap_err_with(|| format!("graph {} not found", graph_path.display()))?;
    let dir = graph_path.parent().unwrap_or(Path::new("/"));
    std::env::set_current_dir(dir)
        .wrap_err_with(|| format!("cannot enter the graph's folder {}", dir.display()))?;
    Ok(graph_path)
}

/// Prints the time each stage took and what its inputs lost.
pub fn print_stages(chain: &ChainReport) {
    print!("{}", chain.table());
}

/// An error when the run lost or cut data: what, and where.
///
/// # Errors
/// A stage's inputs missed messages or were cut short.
pub fn check(chain: &ChainReport) -> eyre::Result<()> {
    let lossy: Vec<String> = chain
        .stages
        .iter()
        .flat_map(|s| {
            s.inputs
                .iter()
                .filter(|(_, t)| t.missing > 0 || t.cut || (!t.ended && !s.stopped))
                .map(move |(i, t)| {
                    format!(
                        "{}/{i}: {} missing{}{}",
                        s.id,
                        t.missing,
                        if t.cut { ", cut short" } else { "" },
                        if t.ended { "" } else { ", never ended" }
                    )
                })
        })
        .collect();
    if lossy.is_empty() {
        Ok(())
    } else {
        Err(eyre!("the run lost data: {}", lossy.join("; ")))
    }
}
