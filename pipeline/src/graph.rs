//! A dora graph's nodes as an in-process chain of stages.

use std::path::Path;

use eyre::{WrapErr, bail, eyre};
use neuspike_stage::{Chain, Fused};
use serde_yaml::Value;

use crate::registry::{make_stage, stage_kind};

/// The env variable that hands a fused node (`neuspike-fused`) its stages: a graph of them
/// ([`fused_stage`]).
pub const FUSED_STAGES: &str = "NEUSPIKE_STAGES";

/// The largest graph file read: 4 MiB (the shipped graphs are a few KiB each).
pub const MAX_GRAPH_BYTES: u64 = 4 << 20;

/// The graph file at `path` as YAML, read up to [`MAX_GRAPH_BYTES`].
///
/// # Errors
/// The file cannot be read, is longer than the limit, or is not YAML: one line naming the file.
pub fn read_graph(path: &Path) -> eyre::Result<Value> {
    let text = read_graph_text(path)?;
    serde_yaml::from_str(&text)
        .map_err(|e| eyre!("{}: not a valid YAML graph: {e}", path.display()))
}

/// The text of the graph file at `path`, read up to [`MAX_GRAPH_BYTES`].
///
/// # Errors
/// The file cannot be read, is not UTF-8, or is longer than the limit.
pub fn read_graph_text(path: &Path) -> eyre::Result<String> {
    use std::io::Read;
    let cannot = |e: std::io::Error| eyre!("cannot read the graph {}: {e}", path.display());
    let file = std::fs::File::open(path).map_err(cannot)?;
    let mut bytes = Vec::new();
    file.take(MAX_GRAPH_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(cannot)?;
    if bytes.len() as u64 > MAX_GRAPH_BYTES {
        bail!(
            "{}: longer than {MAX_GRAPH_BYTES} bytes, the most a graph file may hold",
            path.display()
        );
    }
    String::from_utf8(bytes).map_err(|e| {
        eyre!(
            "{}: not UTF-8 text (byte {})",
            path.display(),
            e.utf8_error().valid_up_to()
        )
    })
}

/// Checks a node's id: not empty, and without a `/` (an input names its source
/// `node/output`, so an id holding one could not be told from its output).
///
/// # Errors
/// One line naming the id.
pub(crate) fn check_id(id: &str) -> eyre::Result<()> {
    if id.is_empty() || id.contains('/') {
        bail!(
            "node id `{id}`: an id must not be empty nor hold a `/` (an input reads `node/output`)"
        );
    }
    Ok(())
}

/// The port of a fused node that stands for `node/port` inside it: `node.port`.
pub fn fused_port(address: &str) -> String {
    address.replacen('/', ".", 1)
}

/// The output a consumer returns credits on: its edges are the dora driver's flow control, not
/// data.
const CREDITS: &str = "credits";

/// One node of a graph: its stage, arguments and data edges.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GraphNode {
    /// Its id.
    pub id: String,
    /// The stage its binary runs ([`crate::STAGES`]).
    pub kind: &'static str,
    /// Its `args:`, split into words as dora splits them.
    pub args: Vec<String>,
    /// Its data inputs: `(input id, "node/output")`.
    pub inputs: Vec<(String, String)>,
    /// Its data outputs: those it declares and those other nodes read.
    pub outputs: Vec<String>,
}

/// A graph's neuspike nodes and their data edges (credit edges and `build:`, `env:`, types
/// left out: the chain needs none of them).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GraphChain {
    /// The nodes, in the graph's order.
    pub nodes: Vec<GraphNode>,
}

fn text<'v>(v: &'v Value, key: &str) -> Option<&'v str> {
    v.get(key).and_then(Value::as_str)
}

/// The data inputs of node `id` of a dora graph: `(input, "node/output")` in the graph's order,
/// the credit edges and dora's timers left out.
///
/// # Errors
/// An input without a source, or whose source is not `node/output`.
pub fn data_inputs(id: &str, node: &Value) -> eyre::Result<Vec<(String, String)>> {
    let mut inputs = Vec::new();
    let Some(map) = node.get("inputs").and_then(Value::as_mapping) else {
        return Ok(inputs);
    };
    for (k, spec) in map {
        let input = k.as_str().unwrap_or_default();
        let source = match spec {
            Value::String(s) => Some(s.as_str()),
            other => text(other, "source"),
        };
        let Some(source) = source else {
            bail!("input `{id}/{input}` names no source");
        };
        let Some((from, output)) = source.split_once('/') else {
            bail!("input `{id}/{input}`: source `{source}` is not `node/output`");
        };
        if output == CREDITS || from == "dora" {
            continue;
        }
        inputs.push((input.to_string(), source.to_string()));
    }
    Ok(inputs)
}

impl GraphChain {
    /// Reads the graph file at `path`.
    ///
    /// # Errors
    /// The file cannot be read, or is not a graph of neuspike stages (see [`Self::from_yaml`]).
    pub fn read(path: &Path) -> eyre::Result<Self> {
        let s = read_graph_text(path)?;
        Self::from_yaml(&s).wrap_err_with(|| format!("{}", path.display()))
    }

    /// The graph in `yaml` (a dora dataflow).
    ///
    /// # Errors
    /// Not YAML, no `nodes`, a node without an id or whose binary is not a neuspike stage, an id
    /// used twice, arguments that do not split into words, or an input whose source is not
    /// `node/output`.
    pub fn from_yaml(yaml: &str) -> eyre::Result<Self> {
        let v: Value = serde_yaml::from_str(yaml).map_err(|e| eyre!("not YAML: {e}"))?;
        let list = v
            .get("nodes")
            .and_then(Value::as_sequence)
            .ok_or_else(|| eyre!("no `nodes` list"))?;
        let mut nodes: Vec<GraphNode> = Vec::new();
        for (i, n) in list.iter().enumerate() {
            let id = text(n, "id").ok_or_else(|| eyre!("node {i}: no `id`"))?;
            check_id(id)?;
            if nodes.iter().any(|m| m.id == id) {
                bail!("node id `{id}` is used twice");
            }
            let path = text(n, "path").unwrap_or_default();
            let kind = stage_kind(path).ok_or_else(|| {
                eyre!("node `{id}`: `path: {path}` is not a neuspike stage's binary, so it cannot run in process")
            })?;
            let args = match n.get("args") {
                None | Some(Value::Null) => Vec::new(),
                Some(Value::String(s)) => shlex::split(s)
                    .ok_or_else(|| eyre!("node `{id}`: `args: {s}` has an unclosed quote"))?,
                Some(other) => bail!("node `{id}`: `args` is {other:?}, expected a string"),
            };
            let inputs = data_inputs(id, n)?;
            let outputs = n
                .get("outputs")
                .and_then(Value::as_sequence)
                .into_iter()
                .flatten()
                .filter_map(Value::as_str)
                .filter(|o| *o != CREDITS)
                .map(String::from)
                .collect();
            nodes.push(GraphNode {
                id: id.to_string(),
                kind,
                args,
                inputs,
                outputs,
            });
        }
        // An output another node reads is the node's, declared or not.
        let read: Vec<(String, String)> = nodes
            .iter()
            .flat_map(|n| n.inputs.iter())
            .filter_map(|(_, source)| source.split_once('/'))
            .map(|(from, output)| (from.to_string(), output.to_string()))
            .collect();
        for (from, output) in read {
            if let Some(n) = nodes.iter_mut().find(|n| n.id == from)
                && !n.outputs.contains(&output)
            {
                n.outputs.push(output);
            }
        }
        Ok(GraphChain { nodes })
    }

    /// Appends `extra` (words) to the arguments of node `id`: later arguments win.
    ///
    /// # Errors
    /// No node `id`.
    pub fn append_args(&mut self, id: &str, extra: &[String]) -> eyre::Result<()> {
        let n = self
            .nodes
            .iter_mut()
            .find(|n| n.id == id)
            .ok_or_else(|| eyre!("--set {id}: the graph has no node `{id}`"))?;
        n.args.extend_from_slice(extra);
        Ok(())
    }

    /// The nodes as one stage named `name` (a fused node, [`FUSED_STAGES`]): an input whose
    /// source is not one of the nodes reads the fused stage's input named for that source
    /// ([`fused_port`]: `spike-source.spikes`), and each output in `outlets` (`node/output`) is
    /// sent out under its own such name.
    ///
    /// # Errors
    /// A stage refused its settings, an edge or an outlet its ports, or the stages do not make
    /// one stage (see [`Chain::into_stage`]).
    pub fn fused(&self, name: &str, outlets: &[String]) -> eyre::Result<Fused> {
        let mut chain = self.stages()?;
        for n in &self.nodes {
            for (input, source) in &n.inputs {
                let to = format!("{}/{input}", n.id);
                let from = source.split_once('/').map_or("", |(f, _)| f);
                if self.nodes.iter().any(|m| m.id == from) {
                    chain.connect(source, &to)?;
                } else {
                    chain.inlet(&fused_port(source), &to)?;
                }
            }
        }
        for o in outlets {
            chain.outlet(&fused_port(o), o)?;
        }
        chain.into_stage(name)
    }

    fn stages(&self) -> eyre::Result<Chain<'static>> {
        let mut chain = Chain::new();
        for n in &self.nodes {
            let inputs: Vec<String> = n.inputs.iter().map(|(i, _)| i.clone()).collect();
            let stage = make_stage(n.kind, &n.args, &inputs, &n.outputs)
                .wrap_err_with(|| format!("node `{}`", n.id))?;
            chain.add(&n.id, stage)?;
        }
        Ok(chain)
    }

    /// The chain: every node's stage made from its arguments and wiring, every data edge
    /// connected. Paths in the arguments are taken from the current folder (a graph's nodes run
    /// in the graph's folder: run the chain there).
    ///
    /// # Errors
    /// A stage refused its settings, or an edge its ports (both ends named).
    pub fn chain(&self) -> eyre::Result<Chain<'static>> {
        let mut chain = self.stages()?;
        for n in &self.nodes {
            for (input, source) in &n.inputs {
                chain.connect(source, &format!("{}/{input}", n.id))?;
            }
        }
        Ok(chain)
    }
}

/// The stage a fused node runs, named `name`, from its [`FUSED_STAGES`] graph: its `nodes` (as
/// [`GraphChain::from_yaml`] reads them) and `outlets`, the outputs (`node/output`) it sends
/// out.
///
/// # Errors
/// Not such a graph, or its stages do not make one stage ([`GraphChain::fused`]).
pub fn fused_stage(name: &str, yaml: &str) -> eyre::Result<Fused> {
    let g = GraphChain::from_yaml(yaml)?;
    let v: Value = serde_yaml::from_str(yaml).map_err(|e| eyre!("not YAML: {e}"))?;
    let outlets: Vec<String> = v
        .get("outlets")
        .and_then(Value::as_sequence)
        .into_iter()
        .flatten()
        .filter_map(Value::as_str)
        .map(String::from)
        .collect();
    g.fused(name, &outlets)
}

#[cfg(test)]
mod tests {
    use super::*;

    const GRAPH: &str = "
nodes:
  - id: cam
    path: ../target/release/neuspike-spike-source
    args: --scene bright-static --chunk-planes 20 --gt-every-planes 20 --max-planes 200 --width 64 --height 48
    inputs:
      credits-align: { source: align/credits, queue_size: 100 }
    outputs: [spikes, ground_truth]
  - id: align
    path: neuspike-align
    args: --window-planes 9 --stride-planes 20
    inputs:
      spikes: cam/spikes
    outputs: [windows, credits]
  - id: represent
    path: neuspike-represent
    args: --tfp-planes 9
    inputs:
      windows: { source: align/windows }
    outputs: [tfp]
  - id: infer
    path: neuspike-infer
    args: --method tfp
    inputs:
      representation: represent/tfp
    outputs: [frames]
  - id: sink
    path: neuspike-sink
    args: --out OUT
    inputs:
      tfp: infer/frames
      ground_truth: cam/ground_truth
";

    #[test]
    fn a_graph_written_by_hand_runs_in_process_with_nothing_lost() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("out");
        let g = GraphChain::from_yaml(&GRAPH.replace("OUT", &out.display().to_string()))
            .expect("graph");
        assert_eq!(g.nodes[1].inputs, [("spikes".into(), "cam/spikes".into())]);
        assert_eq!(g.nodes[1].outputs, ["windows"]);
        let report = g.chain().expect("chain").run().expect("run");
        assert_eq!(report.missing(), 0);
        let sink = report.stage("sink").expect("sink");
        let tfp = sink.inputs.get("tfp").expect("tfp");
        assert!(tfp.ended && !tfp.cut && tfp.received >= 8, "{tfp:?}");
        assert_eq!(tfp.announced, Some(tfp.received));
        let summary = std::fs::read_to_string(out.join("summary.md")).expect("summary");
        assert!(summary.contains("| tfp"), "{summary}");
        let pngs = std::fs::read_dir(out.join("tfp")).expect("frames").count() as u64;
        assert_eq!(pngs, tfp.received);
    }

    #[test]
    fn a_node_that_is_not_a_stage_is_named() {
        let e = GraphChain::from_yaml("nodes:\n  - id: viewer\n    path: python3\n")
            .expect_err("refused")
            .to_string();
        assert!(
            e.contains("node `viewer`") && e.contains("not a neuspike stage"),
            "{e}"
        );
        let dir = tempfile::tempdir().expect("tempdir");
        let graph = GRAPH
            .replace("tfp: infer/frames", "tfp: infer/frame")
            .replace("OUT", &dir.path().display().to_string());
        let e = GraphChain::from_yaml(&graph)
            .expect("graph")
            .chain()
            .err()
            .expect("refused")
            .to_string();
        assert!(e.contains("stage `infer` has no output `frame`"), "{e}");
    }
}
