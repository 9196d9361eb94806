//! neuspike's credit flow control wired into a graph: the edges each consumer returns credits on
//! (see `neuspike_runtime::credit`).

use serde_yaml::Value;

/// The window a consumer grants each input in the graphs neuspike writes: large messages in
/// flight per link (8 frames of 400 x 250 are 3.2 MB, within a node's 8 MB shared-memory pool).
pub const CREDIT_WINDOW: u64 = 8;

/// Wires neuspike's credit flow control into `graph` (see `neuspike_runtime::credit`): every input
/// fed by another node of the graph gets `queue_size: window` and dora's default queue policy
/// (the zero-copy path), its node an output `credits`, and the producer an input
/// `credits-<consumer>` reading it (through the daemon: credits are small and must not be lost).
/// Inputs already reading `credits`, inputs under dora's backpressure, timers and unknown sources
/// are left alone.
pub fn wire_credits(graph: &mut Value, window: u64) {
    use serde_yaml::Mapping;
    let Some(list) = graph.get_mut("nodes").and_then(Value::as_sequence_mut) else {
        return;
    };
    let ids: Vec<String> = list
        .iter()
        .filter_map(|n| n.get("id").and_then(Value::as_str).map(str::to_string))
        .collect();
    let credit_type = Value::from("neuspike/messages/v1/Credit");
    // (producer, consumer) pairs, in order.
    let mut links: Vec<(String, String)> = Vec::new();
    for node in list.iter_mut() {
        let Some(id) = node.get("id").and_then(Value::as_str).map(str::to_string) else {
            continue;
        };
        let Some(inputs) = node.get_mut("inputs").and_then(Value::as_mapping_mut) else {
            continue;
        };
        for (_, spec) in inputs.iter_mut() {
            let source = match &*spec {
                Value::String(s) => s.clone(),
                other => match other.get("source").and_then(Value::as_str) {
                    Some(s) => s.to_string(),
                    None => continue,
                },
            };
            let Some((producer, output)) = source.split_once('/') else {
                continue;
            };
            // Not flow controlled by credits: a credit edge itself, a source outside the graph,
            // or an edge left to dora's backpressure (a node that does not speak credits).
            let backpressure =
                spec.get("queue_policy").and_then(Value::as_str) == Some("backpressure");
            if output == "credits" || backpressure || !ids.iter().any(|i| i == producer) {
                continue;
            }
            let mut m = Mapping::new();
            m.insert("source".into(), Value::from(source.clone()));
            m.insert("queue_size".into(), Value::from(window));
            *spec = Value::Mapping(m);
            let link = (producer.to_string(), id.clone());
            if !links.contains(&link) {
                links.push(link);
            }
        }
    }
    // The node's `key` mapping (a missing or empty key, `inputs:` with nothing under it, is a new
    // one).
    let entry = |node: &mut Value, key: &str| -> Option<Value> {
        let map = node.as_mapping_mut()?;
        let v = map
            .entry(Value::from(key))
            .or_insert_with(|| Value::Mapping(Mapping::new()));
        if v.is_null() {
            *v = Value::Mapping(Mapping::new());
        }
        Some(v.clone())
    };
    for node in list.iter_mut() {
        let Some(id) = node.get("id").and_then(Value::as_str).map(str::to_string) else {
            continue;
        };
        if links.iter().any(|(_, c)| *c == id) {
            let mut outputs = node
                .get("outputs")
                .and_then(Value::as_sequence)
                .cloned()
                .unwrap_or_default();
            if !outputs.iter().any(|o| o.as_str() == Some("credits")) {
                outputs.push(Value::from("credits"));
            }
            let mut types = entry(node, "output_types").unwrap_or_default();
            if let Some(t) = types.as_mapping_mut() {
                t.insert("credits".into(), credit_type.clone());
            }
            if let Some(map) = node.as_mapping_mut() {
                map.insert("outputs".into(), Value::Sequence(outputs));
                map.insert("output_types".into(), types);
            }
        }
        let consumers: Vec<&String> = links
            .iter()
            .filter(|(p, _)| *p == id)
            .map(|(_, c)| c)
            .collect();
        if consumers.is_empty() {
            continue;
        }
        let mut inputs = entry(node, "inputs").unwrap_or_default();
        let mut types = entry(node, "input_types").unwrap_or_default();
        for c in consumers {
            let mut m = Mapping::new();
            m.insert("source".into(), Value::from(format!("{c}/credits")));
            m.insert("queue_size".into(), Value::from(100));
            m.insert("queue_policy".into(), Value::from("backpressure"));
            if let Some(i) = inputs.as_mapping_mut() {
                i.insert(Value::from(format!("credits-{c}")), Value::Mapping(m));
            }
            if let Some(t) = types.as_mapping_mut() {
                t.insert(Value::from(format!("credits-{c}")), credit_type.clone());
            }
        }
        if let Some(map) = node.as_mapping_mut() {
            map.insert("inputs".into(), inputs);
            map.insert("input_types".into(), types);
        }
    }
}
