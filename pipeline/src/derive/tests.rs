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
        // Found by the `graph` fuzz target: an id holding a `/` derived, but its credit edges
        // (`node/credits`) could not be read back.
        (
            HAND_WRITTEN.replace("- id: represent", "- id: repre/sent"),
            "node id `repre/sent`: an id must not be empty nor hold a `/` (an input reads `node/output`)",
        ),
    ];
    for (graph, expected) in cases {
        let e = derived(&graph).expect_err(expected).to_string();
        assert_eq!(e, expected);
    }
}

#[test]
fn the_shipped_graphs_derive_and_their_edges_are_all_credited_or_backpressured() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../graphs");
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

#[test]
fn a_process_makes_its_nodes_one_fused_node_wired_like_any_other() {
    let g = derived(&format!(
        "{HAND_WRITTEN}processes:\n  core: [align, represent, infer]\n"
    ))
    .expect("derived");
    assert!(g.get(fuse::PROCESSES).is_none());
    let ids: Vec<&str> = list(&g).filter_map(|n| text(n, "id")).collect();
    assert_eq!(ids, ["camera", "core", "sink", "viewer"]);
    let core = node(&g, "core");
    assert_eq!(text(core, "path"), Some(fuse::FUSED_NODE));
    assert_eq!(
        source_of(&core["inputs"]["camera.spikes"]),
        Some("camera/spikes")
    );
    assert_eq!(
        declared(core, "input_types", "camera.spikes"),
        Some("neuspike/messages/v1/SpikeChunk")
    );
    assert_eq!(outputs_of(core), ["infer.frames", "credits"]);
    assert_eq!(
        declared(core, "output_types", "infer.frames"),
        Some("neuspike/messages/v1/Frame")
    );
    assert_eq!(text(core, "build"), Some("cargo build"));
    // Its readers read it; credits flow to and from it as for any neuspike node.
    let sink = node(&g, "sink");
    assert_eq!(source_of(&sink["inputs"]["tfp"]), Some("core/infer.frames"));
    assert_eq!(
        source_of(&node(&g, "camera")["inputs"]["credits-core"]),
        Some("core/credits")
    );
    assert_eq!(
        source_of(&core["inputs"]["credits-sink"]),
        Some("sink/credits")
    );
    let viewer = node(&g, "viewer");
    assert_eq!(
        viewer["inputs"]["frames"]["queue_policy"],
        Value::from("backpressure")
    );
    // The stages it holds, with their arguments and the wiring between them.
    assert_eq!(
        fused_members(core),
        [
            ("align".to_string(), "align".to_string()),
            ("represent".to_string(), "represent".to_string()),
            ("infer".to_string(), "infer".to_string())
        ]
    );
    let stages = fused_nodes(core);
    assert_eq!(
        source_of(&stages[1]["inputs"]["windows"]),
        Some("align/windows")
    );
    assert_eq!(text(&stages[2], "args"), Some("--method tfp"));
    let spec: Value =
        serde_yaml::from_str(core["env"][crate::FUSED_STAGES].as_str().expect("spec"))
            .expect("yaml");
    assert_eq!(spec["outlets"], Value::from(vec!["infer/frames"]));
    // Derived twice, the same graph; drawn as one process.
    let mut again = g.clone();
    derive(&mut again, 8, Some("cargo build")).expect("again");
    assert_eq!(again, g);
    let picture = draw(&g).expect("draw");
    assert!(
        picture.contains("one process: align (align), represent (represent), infer (infer)"),
        "{picture}"
    );
}

#[test]
fn a_process_that_cannot_be_is_one_line_naming_it() {
    let with = |p: &str| format!("{HAND_WRITTEN}processes:\n{p}\n");
    let cases = [
        (
            with("  core: [align, aligner]"),
            "processes: `core` holds node `aligner`, which the graph does not have",
        ),
        (
            with("  a: [align]\n  b: [represent, align]"),
            "processes: node `align` is in `a` and in `b`",
        ),
        (
            with("  sink: [align]"),
            "processes: `sink` is also the id of a node: name the process otherwise",
        ),
        (
            with("  core: [infer, viewer]"),
            "processes: `core` holds `viewer`, which runs viewer.py, not a neuspike stage: only stages share a process",
        ),
        (
            with("  core: [camera, represent]"),
            "processes: `core` holds the source `camera` and reads `align/windows` from outside it: a process with a source takes no input from outside",
        ),
        (
            with("  core: align"),
            "processes: `core` is not a list of node ids",
        ),
        (
            with("  p: [camera, align]").replace(
                "    args: --scene bright-slow\n",
                "    args: --scene bright-slow\n    restart_policy: on-failure\n",
            ),
            "processes: `p` holds `camera`, which sets `restart_policy`, and `align`, which does not: one process has one",
        ),
        (
            with("  p: [camera, align]")
                .replace(
                    "    args: --scene bright-slow\n",
                    "    args: --scene bright-slow\n    restart_policy: on-failure\n",
                )
                .replace(
                    "    path: neuspike-align\n",
                    "    path: neuspike-align\n    restart_policy: on-failure\n",
                ),
            "processes: `p` holds the source `camera` and restarts (`restart_policy`): a source restarts only as a node of its own",
        ),
        // A fault of the graph itself names the nodes as written.
        (
            with("  core: [align, represent]")
                .replace("windows: align/windows", "windows: align/window"),
            "input `represent/windows` reads `align/window`, but align has no output `window`",
        ),
    ];
    for (graph, expected) in cases {
        let e = derived(&graph).expect_err(expected).to_string();
        assert_eq!(e, expected);
    }
}
