//! A graph's `processes:`: nodes that share one process, made one `neuspike-fused` node.
//!
//! ```yaml
//! processes:
//!   core: [align, represent, infer]
//! ```
//!
//! makes the nodes `align`, `represent` and `infer` one dora node `core` that runs their stages
//! in one process ([`crate::fused_stage`]). Its inputs are its stages' inputs fed
//! from outside it, named for their source (`spike-source.spikes`); its outputs the outputs
//! read outside it (`infer.frames`), and the nodes reading them are pointed there. Everything
//! else (types, credits, `build:`) is derived for it as for any neuspike node.

use crate::{FUSED_STAGES, Side, data_inputs, fused_port, port_type, stage_kind};
use eyre::{bail, eyre};
use serde_yaml::{Mapping, Value};

use super::{CREDITS, Edge, edges, list, outputs_of, source_of, text};

/// The graph's key that lists its processes.
pub const PROCESSES: &str = "processes";

/// The binary of a fused node.
pub const FUSED_NODE: &str = "neuspike-fused";

/// The processes of `graph`: each name and the ids of the nodes it holds, in order.
///
/// # Errors
/// `processes` is not a mapping of names to lists of node ids.
pub fn processes(graph: &Value) -> eyre::Result<Vec<(String, Vec<String>)>> {
    let Some(v) = graph.get(PROCESSES) else {
        return Ok(Vec::new());
    };
    let Some(map) = v.as_mapping() else {
        bail!("`{PROCESSES}` is {v:?}: expected a mapping of names to lists of node ids");
    };
    let mut out = Vec::new();
    for (k, ids) in map {
        let name = k
            .as_str()
            .ok_or_else(|| eyre!("{PROCESSES}: the name {k:?} is not a string"))?;
        let ids: Option<Vec<String>> = ids.as_sequence().and_then(|s| {
            s.iter()
                .map(|i| i.as_str().map(String::from))
                .collect::<Option<Vec<_>>>()
        });
        match ids {
            Some(ids) if !ids.is_empty() => out.push((name.to_string(), ids)),
            _ => bail!("{PROCESSES}: `{name}` is not a list of node ids"),
        }
    }
    Ok(out)
}

/// Makes every process of `graph` one fused node (and removes `processes:`). The graph's nodes
/// and edges are checked before (`super::derive` on the graph as written).
///
/// # Errors
/// One line naming the process and the node: a node it names that the graph does not have, a
/// node in two processes, a name that is also a node's id, a node that is not a neuspike stage,
/// a source with an input from outside the process or a restart policy, members deployed on
/// different machines or with different restart policies or env values.
pub fn fuse(graph: &mut Value) -> eyre::Result<()> {
    let groups = processes(graph)?;
    if let Some(m) = graph.as_mapping_mut() {
        m.remove(PROCESSES);
    }
    let ids: Vec<String> = list(graph)
        .filter_map(|n| text(n, "id").map(String::from))
        .collect();
    for (i, (name, members)) in groups.iter().enumerate() {
        if ids.contains(name) {
            bail!("{PROCESSES}: `{name}` is also the id of a node: name the process otherwise");
        }
        for m in members {
            if !ids.contains(m) {
                bail!("{PROCESSES}: `{name}` holds node `{m}`, which the graph does not have");
            }
            if let Some((other, _)) = groups[..i].iter().find(|(_, ms)| ms.contains(m)) {
                bail!("{PROCESSES}: node `{m}` is in `{other}` and in `{name}`");
            }
        }
    }
    for (name, members) in &groups {
        let edges = edges(graph)?;
        fuse_one(graph, name, members, &edges)?;
    }
    Ok(())
}

/// The value of `key` shared by every member (none: absent); members that differ are refused.
fn shared(nodes: &[&Value], key: &str, name: &str) -> eyre::Result<Option<Value>> {
    let mut v: Option<(&str, &Value)> = None;
    for n in nodes {
        let id = text(n, "id").unwrap_or_default();
        let this = n.get(key).filter(|x| !x.is_null());
        match (v, this) {
            (None, Some(x)) => v = Some((id, x)),
            (Some((first, a)), Some(b)) if a != b => bail!(
                "{PROCESSES}: `{name}` holds `{first}` and `{id}`, whose `{key}` differ: one process has one"
            ),
            (Some((first, _)), None) => bail!(
                "{PROCESSES}: `{name}` holds `{first}`, which sets `{key}`, and `{id}`, which does not: one process has one"
            ),
            _ => {}
        }
    }
    Ok(v.map(|(_, x)| x.clone()))
}

fn fuse_one(graph: &mut Value, name: &str, members: &[String], edges: &[Edge]) -> eyre::Result<()> {
    let inside = |id: &str| members.iter().any(|m| m == id);
    let nodes: Vec<&Value> = members
        .iter()
        .filter_map(|m| list(graph).find(|n| text(n, "id") == Some(m.as_str())))
        .collect();
    let mut spec_nodes = Vec::new();
    let mut inputs = Mapping::new();
    let mut input_types = Mapping::new();
    let mut env = Mapping::new();
    let mut source: Option<&str> = None;
    let mut outside: Option<String> = None;
    for n in &nodes {
        let id = text(n, "id").unwrap_or_default();
        let path = text(n, "path").unwrap_or_default();
        let Some(kind) = stage_kind(path) else {
            bail!(
                "{PROCESSES}: `{name}` holds `{id}`, which runs {path}, not a neuspike stage: only stages share a process"
            );
        };
        if kind.ends_with("-source") {
            source = Some(id);
        }
        let mut ins = Mapping::new();
        for (input, from) in data_inputs(id, n)? {
            ins.insert(input.clone().into(), from.clone().into());
            let producer = from.split_once('/').map_or("", |(p, _)| p);
            if inside(producer) {
                continue;
            }
            outside.get_or_insert_with(|| from.clone());
            let port = fused_port(&from);
            inputs.insert(port.clone().into(), from.clone().into());
            if let Some(t) = port_type(kind, Side::Input, &input) {
                input_types.insert(port.into(), t.urn().into());
            }
        }
        let mut outs: Vec<String> = outputs_of(n).into_iter().filter(|o| o != CREDITS).collect();
        for e in edges.iter().filter(|e| e.from == id) {
            if !outs.contains(&e.output) {
                outs.push(e.output.clone());
            }
        }
        let mut spec = Mapping::new();
        spec.insert("id".into(), id.into());
        spec.insert("path".into(), path.into());
        if let Some(args) = n.get("args").filter(|a| !a.is_null()) {
            spec.insert("args".into(), args.clone());
        }
        spec.insert("inputs".into(), Value::Mapping(ins));
        spec.insert(
            "outputs".into(),
            Value::Sequence(outs.into_iter().map(Value::from).collect()),
        );
        spec_nodes.push(Value::Mapping(spec));
        for (k, v) in n
            .get("env")
            .and_then(Value::as_mapping)
            .into_iter()
            .flatten()
        {
            match env.get(k) {
                Some(old) if old != v => bail!(
                    "{PROCESSES}: `{name}` holds nodes whose env `{}` differ: one process has one",
                    k.as_str().unwrap_or_default()
                ),
                _ => {
                    env.insert(k.clone(), v.clone());
                }
            }
        }
    }
    if let (Some(src), Some(from)) = (source, &outside) {
        bail!(
            "{PROCESSES}: `{name}` holds the source `{src}` and reads `{from}` from outside it: a process with a source takes no input from outside"
        );
    }
    let deploy = shared(&nodes, "deploy", name)?;
    let restart = shared(&nodes, "restart_policy", name)?;
    // A source node restarted by dora resumes on its first start's clock; inside a process it
    // would start its stream over.
    if let (Some(src), Some(policy)) = (source, &restart)
        && policy.as_str() != Some("never")
    {
        bail!(
            "{PROCESSES}: `{name}` holds the source `{src}` and restarts (`restart_policy`): a source restarts only as a node of its own"
        );
    }
    // The outputs read outside the process.
    let mut outlets: Vec<String> = Vec::new();
    let mut output_types = Mapping::new();
    for e in edges
        .iter()
        .filter(|e| inside(&e.from) && !inside(&e.to) && e.output != CREDITS)
    {
        let address = format!("{}/{}", e.from, e.output);
        if outlets.contains(&address) {
            continue;
        }
        let kind = nodes
            .iter()
            .find(|n| text(n, "id") == Some(e.from.as_str()))
            .and_then(|n| text(n, "path"))
            .and_then(stage_kind);
        if let Some(t) = kind.and_then(|k| port_type(k, Side::Output, &e.output)) {
            output_types.insert(fused_port(&address).into(), t.urn().into());
        }
        outlets.push(address);
    }
    let mut spec = Mapping::new();
    spec.insert("nodes".into(), Value::Sequence(spec_nodes));
    spec.insert(
        "outlets".into(),
        Value::Sequence(outlets.iter().cloned().map(Value::from).collect()),
    );
    let spec = serde_yaml::to_string(&Value::Mapping(spec))
        .map_err(|e| eyre!("{PROCESSES}: `{name}`: {e}"))?;
    env.insert(FUSED_STAGES.into(), spec.into());

    let mut fused = Mapping::new();
    fused.insert("id".into(), name.into());
    fused.insert("path".into(), FUSED_NODE.into());
    if let Some(d) = deploy {
        fused.insert("deploy".into(), d);
    }
    if let Some(r) = restart {
        fused.insert("restart_policy".into(), r);
    }
    if !inputs.is_empty() {
        fused.insert("inputs".into(), Value::Mapping(inputs));
        fused.insert("input_types".into(), Value::Mapping(input_types));
    }
    if !outlets.is_empty() {
        fused.insert(
            "outputs".into(),
            Value::Sequence(outlets.iter().map(|o| fused_port(o).into()).collect()),
        );
        fused.insert("output_types".into(), Value::Mapping(output_types));
    }
    fused.insert("env".into(), Value::Mapping(env));

    let Some(seq) = graph.get_mut("nodes").and_then(Value::as_sequence_mut) else {
        bail!("the graph has no `nodes` list");
    };
    // The nodes outside read the fused node; their credits to a member go (derived again).
    for n in seq.iter_mut() {
        if text(n, "id").is_some_and(inside) {
            continue;
        }
        let Some(ins) = n.get_mut("inputs").and_then(Value::as_mapping_mut) else {
            continue;
        };
        ins.retain(|_, spec| {
            source_of(spec)
                .and_then(|s| s.split_once('/'))
                .is_none_or(|(from, output)| !(inside(from) && output == CREDITS))
        });
        for (_, spec) in ins.iter_mut() {
            let Some(from) = source_of(spec).map(String::from) else {
                continue;
            };
            if !from.split_once('/').is_some_and(|(p, _)| inside(p)) {
                continue;
            }
            let to = Value::from(format!("{name}/{}", fused_port(&from)));
            match spec {
                Value::Mapping(m) => {
                    m.insert("source".into(), to);
                }
                other => *other = to,
            }
        }
    }
    let at = seq
        .iter()
        .position(|n| text(n, "id").is_some_and(inside))
        .unwrap_or(seq.len());
    seq.retain(|n| !text(n, "id").is_some_and(inside));
    seq.insert(at.min(seq.len()), Value::Mapping(fused));
    Ok(())
}
