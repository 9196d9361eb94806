//! A graph as a user writes it (nodes, `path`, `args`, data edges) made into the graph dora runs:
//! the message types of every port, neuspike's credit edges (or dora's backpressure where a node
//! does not speak credits), the `build:` and `env:` of neuspike's nodes, and the nodes its
//! `processes:` groups made one process each ([`fuse`]); checked first, every fault one line
//! naming both ends of the edge.

use crate::{Side, data_inputs, port_type, stage_kind};
use eyre::{bail, eyre};
use neuspike_stage::MsgType;
use serde_yaml::{Mapping, Value};

mod credits;
pub mod fuse;

pub use credits::{CREDIT_WINDOW, wire_credits};

/// The output on which a consumer returns credits.
const CREDITS: &str = "credits";

/// What runs a node.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Runs {
    /// A neuspike stage binary: its ports' types are known.
    Stage(&'static str),
    /// Another binary on neuspike's runtime (`neuspike-publish`, a user's Rust node named
    /// `neuspike-*`): it speaks credits; its types are declared or come from its producers.
    Runtime,
    /// Anything else: it speaks credits when it declares an output `credits` (the Python `Link`).
    Foreign,
}

struct Node {
    id: String,
    runs: Runs,
    credits: bool,
}

/// One data edge: `from`'s output `output` feeds `to`'s input `input`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Edge {
    /// The producer's id.
    pub from: String,
    /// Its output.
    pub output: String,
    /// The consumer's id.
    pub to: String,
    /// Its input.
    pub input: String,
}

fn text<'v>(v: &'v Value, key: &str) -> Option<&'v str> {
    v.get(key).and_then(Value::as_str)
}

fn runs(path: &str) -> Runs {
    if let Some(kind) = stage_kind(path) {
        return Runs::Stage(kind);
    }
    let file = path.rsplit(['/', '\\']).next().unwrap_or(path);
    if file.starts_with("neuspike-") {
        Runs::Runtime
    } else {
        Runs::Foreign
    }
}

/// A type's name for messages: a neuspike type by its short name.
fn short(urn: &str) -> String {
    MsgType::from_urn(urn).map_or_else(|| urn.to_string(), |t| t.name().to_string())
}

/// The source of an input spec: `node/output` as a string or under `source:`.
fn source_of(spec: &Value) -> Option<&str> {
    match spec {
        Value::String(s) => Some(s.as_str()),
        other => text(other, "source"),
    }
}

/// The declared outputs of a node (credits left out).
fn outputs_of(node: &Value) -> Vec<String> {
    node.get("outputs")
        .and_then(Value::as_sequence)
        .into_iter()
        .flatten()
        .filter_map(Value::as_str)
        .map(String::from)
        .collect()
}

/// The data edges of `graph`: every input fed by a node's output (credit edges and dora's timers
/// left out), in the graph's order.
///
/// # Errors
/// A source that is not `node/output`.
pub fn edges(graph: &Value) -> eyre::Result<Vec<Edge>> {
    let mut out = Vec::new();
    for n in list(graph) {
        let id = text(n, "id").unwrap_or_default();
        for (input, source) in data_inputs(id, n)? {
            if let Some((from, output)) = source.split_once('/') {
                out.push(Edge {
                    from: from.to_string(),
                    output: output.to_string(),
                    to: id.to_string(),
                    input,
                });
            }
        }
    }
    Ok(out)
}

fn list(graph: &Value) -> impl Iterator<Item = &Value> {
    graph
        .get("nodes")
        .and_then(Value::as_sequence)
        .into_iter()
        .flatten()
}

/// The declared type of `port` in `node`'s `key` (`input_types`, `output_types`).
fn declared<'v>(node: &'v Value, key: &str, port: &str) -> Option<&'v str> {
    node.get(key)
        .and_then(|t| t.get(port))
        .and_then(Value::as_str)
}

/// Checks `graph` and fills in what the runtime needs beyond nodes, arguments and data edges:
///
/// - each of its `processes:` becomes one `neuspike-fused` node holding those nodes' stages
///   ([`fuse::fuse`]);
/// - every data output a consumer reads is declared; every port of a neuspike stage gets its
///   message type, other nodes' ports the type they declare or (inputs) their producer's;
/// - an edge between two nodes that speak credits (neuspike's nodes, and nodes that declare an
///   output `credits`) gets neuspike's credit flow control; any other edge dora's backpressure
///   (lossless: the daemon holds what the consumer has not taken), unless the graph sets that
///   input's queue itself (a viewer that keeps only the newest frames);
/// - neuspike's nodes get `env: DORA_RUNTIME_TYPE_CHECK: error` and, when `build` is given,
///   that `build:` command.
///
/// A graph written the long way (credit edges, types, `build:`) comes out the same.
///
/// # Errors
/// One line naming the fault and both ends where there are two: a node id used twice, a node
/// without an id or a path, an input whose node or output does not exist, an edge whose two
/// ends carry different types.
pub fn derive(graph: &mut Value, window: u64, build: Option<&str>) -> eyre::Result<()> {
    if graph.get(fuse::PROCESSES).is_some() {
        // The graph as written is checked first, so that a fault names the nodes the user wrote.
        let mut written = graph.clone();
        if let Some(m) = written.as_mapping_mut() {
            m.remove(fuse::PROCESSES);
        }
        derive(&mut written, window, build)?;
        fuse::fuse(graph)?;
    }
    let mut nodes: Vec<Node> = Vec::new();
    for (i, n) in list(graph).enumerate() {
        let id = text(n, "id").ok_or_else(|| eyre!("node {} has no `id`", i + 1))?;
        crate::graph::check_id(id)?;
        if nodes.iter().any(|m| m.id == id) {
            bail!("node id `{id}` is used twice");
        }
        let path = text(n, "path").ok_or_else(|| eyre!("node `{id}` has no `path`"))?;
        let runs = runs(path);
        let credits = runs != Runs::Foreign || outputs_of(n).iter().any(|o| o == CREDITS);
        nodes.push(Node {
            id: id.to_string(),
            runs,
            credits,
        });
    }
    let edges = edges(graph)?;
    let node = |id: &str| nodes.iter().find(|n| n.id == id);
    let value = |id: &str| list(graph).find(|n| text(n, "id") == Some(id));
    // Every edge's producer exists and has the output; the types of both ends.
    let mut out_types: Vec<(String, String, Option<String>)> = Vec::new();
    let mut in_types: Vec<(String, String, Option<String>)> = Vec::new();
    let output_type = |from: &str, output: &str| -> Option<String> {
        let n = node(from)?;
        match n.runs {
            Runs::Stage(kind) => port_type(kind, Side::Output, output).map(|t| t.urn().to_string()),
            _ => declared(value(from)?, "output_types", output).map(String::from),
        }
    };
    for e in &edges {
        let Some(p) = node(&e.from) else {
            bail!(
                "input `{}/{}` reads `{}/{}`, but the graph has no node `{}`",
                e.to,
                e.input,
                e.from,
                e.output,
                e.from
            );
        };
        if let Runs::Stage(kind) = p.runs
            && port_type(kind, Side::Output, &e.output).is_none()
        {
            bail!(
                "input `{}/{}` reads `{}/{}`, but {kind} has no output `{}`",
                e.to,
                e.input,
                e.from,
                e.output,
                e.output
            );
        }
        if let Some(c) = node(&e.to)
            && let Runs::Stage(kind) = c.runs
            && port_type(kind, Side::Input, &e.input).is_none()
        {
            bail!(
                "`{}/{}` feeds `{}/{}`, but {kind} has no input `{}`",
                e.from,
                e.output,
                e.to,
                e.input,
                e.input
            );
        }
        let out_t = output_type(&e.from, &e.output);
        let in_t = match node(&e.to).map(|n| n.runs) {
            Some(Runs::Stage(kind)) => {
                port_type(kind, Side::Input, &e.input).map(|t| t.urn().to_string())
            }
            _ => value(&e.to)
                .and_then(|v| declared(v, "input_types", &e.input))
                .map(String::from)
                .or_else(|| out_t.clone()),
        };
        if let (Some(a), Some(b)) = (&out_t, &in_t)
            && a != b
        {
            bail!(
                "`{}/{}` sends {} but `{}/{}` reads {}",
                e.from,
                e.output,
                short(a),
                e.to,
                e.input,
                short(b)
            );
        }
        out_types.push((e.from.clone(), e.output.clone(), out_t));
        in_types.push((e.to.clone(), e.input.clone(), in_t));
    }
    // A type declared on a stage's port that is not the stage's.
    for (i, n) in list(graph).enumerate() {
        let Runs::Stage(kind) = nodes[i].runs else {
            continue;
        };
        for (key, side) in [("input_types", Side::Input), ("output_types", Side::Output)] {
            let Some(map) = n.get(key).and_then(Value::as_mapping) else {
                continue;
            };
            for (port, t) in map {
                let (Some(port), Some(t)) = (port.as_str(), t.as_str()) else {
                    continue;
                };
                if let Some(known) = port_type(kind, side, port)
                    && known.urn() != t
                {
                    bail!(
                        "node `{}`: {key} says `{port}` carries {}, but {kind}'s `{port}` carries {}",
                        nodes[i].id,
                        short(t),
                        known.name()
                    );
                }
            }
        }
    }
    let speaks = |id: &str| node(id).is_some_and(|n| n.credits);
    let credited: Vec<(String, String)> = edges
        .iter()
        .filter(|e| speaks(&e.from) && speaks(&e.to))
        .map(|e| (e.to.clone(), e.input.clone()))
        .collect();
    let Some(list) = graph.get_mut("nodes").and_then(Value::as_sequence_mut) else {
        bail!("the graph has no `nodes` list");
    };
    for (i, n) in list.iter_mut().enumerate() {
        let id = nodes[i].id.clone();
        let Some(map) = n.as_mapping_mut() else {
            continue;
        };
        // Outputs its consumers read, declared.
        let mut outputs: Vec<Value> = map
            .get("outputs")
            .and_then(Value::as_sequence)
            .cloned()
            .unwrap_or_default();
        for e in edges.iter().filter(|e| e.from == id) {
            if !outputs
                .iter()
                .any(|o| o.as_str() == Some(e.output.as_str()))
            {
                outputs.push(Value::from(e.output.clone()));
            }
        }
        if !outputs.is_empty() {
            map.insert("outputs".into(), Value::Sequence(outputs.clone()));
        }
        // Types.
        let mut put = |key: &str, port: &str, t: &str| {
            let types = map
                .entry(Value::from(key))
                .or_insert_with(|| Value::Mapping(Mapping::new()));
            if types.is_null() {
                *types = Value::Mapping(Mapping::new());
            }
            if let Some(t_map) = types.as_mapping_mut() {
                t_map
                    .entry(Value::from(port))
                    .or_insert_with(|| Value::from(t));
            }
        };
        for (_, port, t) in out_types.iter().filter(|(n, _, _)| *n == id) {
            if let Some(t) = t {
                put("output_types", port, t);
            }
        }
        if let Runs::Stage(kind) = nodes[i].runs {
            for o in outputs.iter().filter_map(Value::as_str) {
                if let Some(t) = port_type(kind, Side::Output, o) {
                    put("output_types", o, t.urn());
                }
            }
        }
        for (_, port, t) in in_types.iter().filter(|(n, _, _)| *n == id) {
            if let Some(t) = t {
                put("input_types", port, t);
            }
        }
        // Edges that are not flow controlled by credits: dora's backpressure.
        if let Some(inputs) = map.get_mut("inputs").and_then(Value::as_mapping_mut) {
            for (k, spec) in inputs.iter_mut() {
                let input = k.as_str().unwrap_or_default();
                let Some(source) = source_of(spec).map(String::from) else {
                    continue;
                };
                let data = edges.iter().any(|e| e.to == id && e.input == input);
                // A queue the user set (a viewer that keeps the newest frames) is theirs.
                let set = spec.get("queue_size").is_some() || spec.get("queue_policy").is_some();
                if !data || set || credited.iter().any(|(c, i)| *c == id && i == input) {
                    continue;
                }
                let mut m = match spec {
                    Value::Mapping(m) => m.clone(),
                    _ => Mapping::new(),
                };
                m.insert("source".into(), Value::from(source));
                m.insert("queue_policy".into(), Value::from("backpressure"));
                *spec = Value::Mapping(m);
            }
        }
        if nodes[i].runs != Runs::Foreign {
            if let Some(cmd) = build
                && !map.contains_key("build")
            {
                map.insert("build".into(), Value::from(cmd));
            }
            let env = map
                .entry(Value::from("env"))
                .or_insert_with(|| Value::Mapping(Mapping::new()));
            if env.is_null() {
                *env = Value::Mapping(Mapping::new());
            }
            if let Some(env) = env.as_mapping_mut()
                && !env.contains_key("DORA_RUNTIME_TYPE_CHECK")
            {
                env.insert("DORA_RUNTIME_TYPE_CHECK".into(), Value::from("error"));
            }
        }
    }
    wire_credits(graph, window);
    Ok(())
}

/// The graph drawn as text: a line per node (what runs it and its arguments) and a line per
/// data edge with its message type and how it is flow controlled.
pub fn draw(graph: &Value) -> eyre::Result<String> {
    use std::fmt::Write;
    let mut s = String::new();
    for n in list(graph) {
        let id = text(n, "id").unwrap_or_default();
        let path = text(n, "path").unwrap_or_default();
        let what = match runs(path) {
            Runs::Stage(kind) => format!("stage {kind}"),
            _ if path.ends_with(fuse::FUSED_NODE) => {
                let stages = fused_members(n)
                    .iter()
                    .map(|(id, kind)| format!("{id} ({kind})"))
                    .collect::<Vec<_>>()
                    .join(", ");
                format!("one process: {stages}")
            }
            Runs::Runtime | Runs::Foreign => {
                let file = path.rsplit(['/', '\\']).next().unwrap_or(path);
                format!("node {file}")
            }
        };
        let args = text(n, "args").unwrap_or_default();
        let _ = writeln!(s, "{id:<16} {what} {args}");
    }
    s.push('\n');
    for e in edges(graph)? {
        let consumer = list(graph).find(|n| text(n, "id") == Some(e.to.as_str()));
        let spec = consumer
            .and_then(|n| n.get("inputs"))
            .and_then(|i| i.get(&e.input));
        let t = consumer
            .and_then(|n| declared(n, "input_types", &e.input))
            .map_or_else(|| "?".to_string(), short);
        let flow = match spec.and_then(|s| text(s, "queue_policy")) {
            Some("backpressure") => "backpressure",
            _ => "credits",
        };
        let _ = writeln!(
            s,
            "{:>28} --{t}--> {:<28} ({flow})",
            format!("{}/{}", e.from, e.output),
            format!("{}/{}", e.to, e.input)
        );
    }
    Ok(s)
}

/// The stages a fused node holds: each node's id and kind, from its `env:`.
pub fn fused_members(node: &Value) -> Vec<(String, String)> {
    fused_nodes(node)
        .iter()
        .filter_map(|n| {
            let id = text(n, "id")?;
            let kind = stage_kind(text(n, "path")?)?;
            Some((id.to_string(), kind.to_string()))
        })
        .collect()
}

/// The nodes a fused node holds, as graph nodes (id, path, args, inputs), from its `env:`.
pub fn fused_nodes(node: &Value) -> Vec<Value> {
    node.get("env")
        .and_then(|e| e.get(crate::FUSED_STAGES))
        .and_then(Value::as_str)
        .and_then(|s| serde_yaml::from_str::<Value>(s).ok())
        .map(|spec| list(&spec).cloned().collect())
        .unwrap_or_default()
}

#[cfg(test)]
mod tests;
