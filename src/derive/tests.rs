use super::*;

/// The five nodes a dora user writes: paths, arguments, data edges, nothing else.
const HAND_WRITTEN: &str = "
nodes:
  - id: camera
    path: neuspike-spike-source
    args: --scene bright-slow
    inputs:
    env:
  - id: align
    path: neuspike-align
    inputs:
      spikes: camera/spikes
  - id: represent
    path: neuspike-represent
    inputs:
      windows: align/windows
  - id: infer
    path: neuspike-infer
    args: --method tfp
    inputs:
      representation: represent/tfp
  - id: sink
    path: neuspike-sink
    inputs:
      tfp: infer/frames
      ground_truth: camera/ground_truth
  - id: viewer
    path: viewer.py
    inputs:
      frames: infer/frames
";

fn derived(text: &str) -> eyre::Result<Value> {
    let mut g: Value = serde_yaml::from_str(text).expect("yaml");
    derive(&mut g, 8, Some("cargo build"))?;
    Ok(g)
}

fn node<'v>(g: &'v Value, id: &str) -> &'v Value {
    list(g).find(|n| text(n, "id") == Some(id)).expect("node")
}

#[test]
fn a_hand_written_graph_gets_types_credits_build_and_env() {
    let g = derived(HAND_WRITTEN).expect("derived");
    let camera = node(&g, "camera");
    assert_eq!(outputs_of(camera), ["spikes", "ground_truth"]);
    assert_eq!(
        declared(camera, "output_types", "spikes"),
        Some("neuspike/messages/v1/SpikeChunk")
    );
    // Credits back from both consumers, through the daemon.
    let credits = camera.get("inputs").expect("inputs");
    assert_eq!(source_of(&credits["credits-align"]), Some("align/credits"));
    assert_eq!(source_of(&credits["credits-sink"]), Some("sink/credits"));
    let sink = node(&g, "sink");
    assert_eq!(sink["inputs"]["tfp"]["queue_size"], Value::from(8));
    assert!(outputs_of(sink).contains(&"credits".to_string()));
    assert_eq!(
        declared(sink, "input_types", "tfp"),
        Some("neuspike/messages/v1/Frame")
    );
    assert_eq!(text(sink, "build"), Some("cargo build"));
    assert_eq!(sink["env"]["DORA_RUNTIME_TYPE_CHECK"], Value::from("error"));
    // A node that does not speak credits: dora's backpressure, its type from its producer, and
    // its producer does not wait for credits from it.
    let viewer = node(&g, "viewer");
    assert_eq!(
        viewer["inputs"]["frames"]["queue_policy"],
        Value::from("backpressure")
    );
    assert_eq!(
        declared(viewer, "input_types", "frames"),
        Some("neuspike/messages/v1/Frame")
    );
    assert!(viewer.get("build").is_none() && viewer.get("env").is_none());
    let infer = node(&g, "infer");
    let inputs = infer["inputs"].as_mapping().expect("inputs");
    assert!(!inputs.contains_key("credits-viewer"), "{inputs:?}");
    assert!(inputs.contains_key("credits-sink"));
    // Derived twice, the same graph.
    let mut again = g.clone();
    derive(&mut again, 8, Some("cargo build")).expect("again");
    assert_eq!(again, g);
    let picture = draw(&g).expect("draw");
    assert!(
        picture.contains("infer/frames --Frame--> viewer/frames"),
        "{picture}"
    );
    assert!(
        picture.contains("(backpressure)") && picture.contains("(credits)"),
        "{picture}"
    );
}

#[test]
fn every_fault_is_one_line_naming_both_ends() {
    let cases = [
        (
            HAND_WRITTEN.replace("tfp: infer/frames", "tfp: represent/tfp"),
            "`represent/tfp` sends Representation but `sink/tfp` reads Frame",
        ),
        (
            HAND_WRITTEN.replace("windows: align/windows", "windows: aligner/windows"),
            "input `represent/windows` reads `aligner/windows`, but the graph has no node `aligner`",
        ),
        (
            HAND_WRITTEN.replace("tfp: infer/frames", "tfp: infer/frame"),
            "input `sink/tfp` reads `infer/frame`, but infer has no output `frame`",
        ),
        (
            HAND_WRITTEN.replace("- id: viewer", "- id: sink"),
            "node id `sink` is used twice",
        ),
        (
            HAND_WRITTEN.replace("spikes: camera/spikes", "spike: camera/spikes"),
            "`camera/spikes` feeds `align/spike`, but align has no input `spike`",
        ),
    ];
    for (graph, expected) in cases {
        let e = derived(&graph).expect_err(expected).to_string();
        assert_eq!(e, expected);
    }
}

#[test]
fn the_shipped_graphs_derive_and_their_edges_are_all_credited_or_backpressured() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/graphs");
    for f in std::fs::read_dir(dir).expect("graphs").flatten() {
        let p = f.path();
        if p.extension().is_none_or(|x| x != "yml") {
            continue;
        }
        let text = std::fs::read_to_string(&p).expect("read");
        let g = derived(&text).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        for e in edges(&g).expect("edges") {
            let spec = &node(&g, &e.to)["inputs"][e.input.as_str()];
            let credited = spec.get("queue_size").is_some();
            let backpressure = text_of(spec, "queue_policy") == Some("backpressure");
            assert!(credited || backpressure, "{}: {e:?}", p.display());
        }
    }
}

fn text_of<'v>(v: &'v Value, key: &str) -> Option<&'v str> {
    text(v, key)
}
