//! `neuspike reconstruct`: frames from a recorded spike file, through a graph written for the
//! run. The graph is saved in the output folder beside the frames (`graph.yml`, with a `types`
//! link to the message types), so the run can be repeated with the stock dora CLI too.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use eyre::WrapErr;

use crate::graph;

/// Classical reconstructions a recording can go through.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Method {
    /// Texture from playback: mean firing over the window.
    Tfp,
    /// Texture from inter-spike intervals at the reference plane.
    Tfi,
    /// Events alone: Scheerlinck's high-pass filter (needs `--events`).
    Hf,
    /// Events with the spike camera's TFI frames: the complementary filter (needs `--events`).
    Cf,
    /// Events with ISI maps: NeuSpike-Net's Eq. 5-7 (needs `--events`).
    Fusion,
}

impl Method {
    fn name(self) -> &'static str {
        match self {
            Method::Tfp => "tfp",
            Method::Tfi => "tfi",
            Method::Hf => "hf",
            Method::Cf => "cf",
            Method::Fusion => "fusion",
        }
    }

    /// The representation the method reads (the represent node's output), if any.
    fn representation(self) -> Option<&'static str> {
        match self {
            Method::Tfp => Some("tfp"),
            Method::Tfi | Method::Cf | Method::Fusion => Some("isi"),
            Method::Hf => None,
        }
    }

    /// Whether the method reads the event stream.
    fn needs_events(self) -> bool {
        matches!(self, Method::Hf | Method::Cf | Method::Fusion)
    }
}

/// What to reconstruct.
#[derive(Clone, Debug)]
pub struct ReconstructOptions {
    /// The PKU spike `.dat`.
    pub spikes: PathBuf,
    /// An event file of the same sensor size, on the same clock as the spikes (both counted
    /// from the recording's start, as `neuspike simulate` writes them), for `hf`, `cf` and
    /// `fusion`.
    pub events: Option<PathBuf>,
    /// Ground truth recorded with the spikes: a folder with `timestamps.txt` (`plane t_ns
    /// file`) and PNGs. `None` looks for `ground-truth/` beside the spike file, as `neuspike
    /// simulate` writes it; the sink scores the frames against it.
    pub truth: Option<PathBuf>,
    /// The method.
    pub method: Method,
    /// Output folder.
    pub out: PathBuf,
    /// Extra spike-source arguments (resolution, head columns, rate, start, calibration).
    pub source_args: String,
    /// Extra event-source arguments (the sensor size of files that do not state it, start, end).
    pub event_source_args: String,
    /// Extra infer arguments (contrast, filter gains, theta mode).
    pub infer_args: String,
    /// Planes per window and planes between frames.
    pub window_planes: u32,
    /// Planes between two frames.
    pub stride_planes: u32,
    /// PNG bit depth.
    pub bit_depth: u8,
    /// Run the graph's `build:` command first.
    pub build: bool,
}

/// The repository the program was built from (node binaries and message types live there).
fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The graph for `opts`, with absolute paths (it lives in the output folder). `events` is the
/// event file, when the method reads one.
pub fn graph_yaml(
    opts: &ReconstructOptions,
    spikes: &Path,
    events: Option<&Path>,
    truth: Option<&Path>,
    out: &Path,
) -> String {
    let repo = repo();
    let bin = |name: &str| repo.join("target/release").join(format!("neuspike-{name}"));
    let build = format!(
        "cargo build --release --manifest-path {} --workspace --bins",
        repo.join("Cargo.toml").display()
    );
    let queue = "queue_size: 1000, queue_policy: backpressure";
    let m = opts.method.name();
    let mut y = String::new();
    let _ = writeln!(
        y,
        "# Written by `neuspike reconstruct`: {m} frames of {}{}.\nnodes:",
        spikes.display(),
        events.map_or(String::new(), |e| format!(" and {}", e.display()))
    );
    // One node: id, binary, args, then its inputs, outputs and their types as YAML lines.
    let mut node = |id: &str, binary: &str, args: &str, rest: &[String]| {
        let _ = writeln!(
            y,
            "  - id: {id}\n    build: {build}\n    path: {}\n    args: {args}\n    env: {{ DORA_RUNTIME_TYPE_CHECK: error }}",
            bin(binary).display()
        );
        for line in rest {
            let _ = writeln!(y, "    {line}");
        }
    };
    let t = |name: &str| format!("neuspike/messages/v1/{name}");
    let truth_args = truth.map_or(String::new(), |d| format!("--truth {} ", d.display()));
    let (source_outputs, source_types) = match truth {
        Some(_) => (
            "outputs: [spikes, ground_truth]".to_string(),
            format!(
                "output_types: {{ spikes: {}, ground_truth: {} }}",
                t("SpikeChunk"),
                t("Frame")
            ),
        ),
        None => (
            "outputs: [spikes]".to_string(),
            format!("output_types: {{ spikes: {} }}", t("SpikeChunk")),
        ),
    };
    node(
        "spike-source",
        "spike-source",
        &format!(
            "--file {} {truth_args}--chunk-planes 20 {}",
            spikes.display(),
            opts.source_args
        ),
        &[source_outputs, source_types],
    );
    if let Some(events) = events {
        node(
            "event-source",
            "event-source",
            &format!(
                "--file {} --batch-ns 1000000 {}",
                events.display(),
                opts.event_source_args
            ),
            &[
                "outputs: [events]".into(),
                format!("output_types: {{ events: {} }}", t("EventBatch")),
            ],
        );
    }
    let window_args = format!(
        "--window-planes {} --stride-planes {}",
        opts.window_planes, opts.stride_planes
    );
    if events.is_some() {
        node(
            "align",
            "align",
            &window_args,
            &[
                format!(
                    "inputs: {{ spikes: {{ source: spike-source/spikes, {queue} }}, events: {{ source: event-source/events, {queue} }} }}"
                ),
                format!(
                    "input_types: {{ spikes: {}, events: {} }}",
                    t("SpikeChunk"),
                    t("EventBatch")
                ),
                "outputs: [windows, events]".into(),
                format!(
                    "output_types: {{ windows: {}, events: {} }}",
                    t("AlignedWindow"),
                    t("EventBatch")
                ),
            ],
        );
    } else {
        node(
            "align",
            "align",
            &window_args,
            &[
                format!("inputs: {{ spikes: {{ source: spike-source/spikes, {queue} }} }}"),
                format!("input_types: {{ spikes: {} }}", t("SpikeChunk")),
                "outputs: [windows]".into(),
                format!("output_types: {{ windows: {} }}", t("AlignedWindow")),
            ],
        );
    }
    let repr = opts.method.representation();
    if let Some(r) = repr {
        node(
            "represent",
            "represent",
            &format!("--tfp-planes {}", opts.window_planes),
            &[
                format!("inputs: {{ windows: {{ source: align/windows, {queue} }} }}"),
                format!("input_types: {{ windows: {} }}", t("AlignedWindow")),
                format!("outputs: [{r}]"),
                format!("output_types: {{ {r}: {} }}", t("Representation")),
            ],
        );
    }
    let mut inputs = Vec::new();
    let mut types = Vec::new();
    if let Some(r) = repr {
        inputs.push(format!(
            "representation: {{ source: represent/{r}, {queue} }}"
        ));
        types.push(format!("representation: {}", t("Representation")));
    }
    if opts.method.needs_events() {
        inputs.push(format!("events: {{ source: align/events, {queue} }}"));
        types.push(format!("events: {}", t("EventBatch")));
    }
    node(
        &format!("infer-{m}"),
        "infer",
        &format!("--method {m} {}", opts.infer_args),
        &[
            format!("inputs: {{ {} }}", inputs.join(", ")),
            format!("input_types: {{ {} }}", types.join(", ")),
            "outputs: [frames]".into(),
            format!("output_types: {{ frames: {} }}", t("Frame")),
        ],
    );
    let (truth_in, truth_type) = match truth {
        Some(_) => (
            format!(", ground_truth: {{ source: spike-source/ground_truth, {queue} }}"),
            format!(", ground_truth: {}", t("Frame")),
        ),
        None => (String::new(), String::new()),
    };
    node(
        "sink",
        "sink",
        &format!("--out {} --bit-depth {}", out.display(), opts.bit_depth),
        &[
            format!("inputs: {{ {m}: {{ source: infer-{m}/frames, {queue} }}{truth_in} }}"),
            format!("input_types: {{ {m}: {}{truth_type} }}", t("Frame")),
        ],
    );
    y
}

/// Writes the graph into the output folder and runs it.
pub fn reconstruct(opts: &ReconstructOptions) -> eyre::Result<graph::Report> {
    let m = opts.method.name();
    let events = match (&opts.events, opts.method.needs_events()) {
        (Some(e), true) => Some(
            std::fs::canonicalize(e)
                .wrap_err_with(|| format!("--events {}: cannot open", e.display()))?,
        ),
        (None, true) => eyre::bail!(
            "--method {m} reconstructs from events: give the event recording with --events FILE"
        ),
        (Some(e), false) => eyre::bail!(
            "--events {}: --method {m} reads the spikes only; the methods that read events are \
             hf, cf and fusion",
            e.display()
        ),
        (None, false) => None,
    };
    let spikes = std::fs::canonicalize(&opts.spikes)
        .wrap_err_with(|| format!("--spikes {}: cannot open", opts.spikes.display()))?;
    let truth = match &opts.truth {
        Some(dir) => Some(
            std::fs::canonicalize(dir)
                .wrap_err_with(|| format!("--truth {}: cannot open", dir.display()))?,
        ),
        None => spikes
            .parent()
            .map(|d| d.join("ground-truth"))
            .filter(|d| d.join("timestamps.txt").is_file()),
    };
    if let Some(dir) = &truth {
        tracing::info!(truth = %dir.display(), "scoring against the recorded ground truth");
    }
    std::fs::create_dir_all(&opts.out)
        .wrap_err_with(|| format!("cannot create {}", opts.out.display()))?;
    let out = std::fs::canonicalize(&opts.out)?;
    let types = out.join("types");
    if !types.exists() {
        link_dir(&repo().join("schemas/types"), &types)?;
    }
    let graph_path = out.join("graph.yml");
    std::fs::write(
        &graph_path,
        graph_yaml(opts, &spikes, events.as_deref(), truth.as_deref(), &out),
    )
    .wrap_err_with(|| format!("cannot write {}", graph_path.display()))?;
    graph::run(&graph_path, &[], opts.build, None, Some(out))
}

#[cfg(unix)]
fn link_dir(target: &Path, link: &Path) -> eyre::Result<()> {
    std::os::unix::fs::symlink(target, link)
        .wrap_err_with(|| format!("cannot link {} to {}", link.display(), target.display()))
}

#[cfg(not(unix))]
fn link_dir(target: &Path, link: &Path) -> eyre::Result<()> {
    eyre::bail!(
        "cannot link {} to {}: only supported on unix",
        link.display(),
        target.display()
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opts(method: Method) -> ReconstructOptions {
        ReconstructOptions {
            spikes: "x.dat".into(),
            events: None,
            truth: None,
            method,
            out: "out".into(),
            source_args: "--file-width 40 --file-height 25".into(),
            event_source_args: String::new(),
            infer_args: String::new(),
            window_planes: 33,
            stride_planes: 10,
            bit_depth: 8,
            build: false,
        }
    }

    fn nodes(y: &str) -> Vec<serde_yaml::Value> {
        let g: serde_yaml::Value = serde_yaml::from_str(y).expect("valid YAML");
        g["nodes"].as_sequence().expect("nodes").clone()
    }

    fn find<'a>(nodes: &'a [serde_yaml::Value], id: &str) -> &'a serde_yaml::Value {
        nodes
            .iter()
            .find(|n| n["id"].as_str() == Some(id))
            .unwrap_or_else(|| panic!("no node {id}"))
    }

    #[test]
    fn the_graph_wires_the_method_to_its_representation() {
        for (method, repr) in [(Method::Tfp, "tfp"), (Method::Tfi, "isi")] {
            let y = graph_yaml(
                &opts(method),
                Path::new("/d/x.dat"),
                None,
                None,
                Path::new("/o"),
            );
            let nodes = nodes(&y);
            assert_eq!(nodes.len(), 5);
            let m = method.name();
            let infer = find(&nodes, &format!("infer-{m}"));
            assert_eq!(
                infer["inputs"]["representation"]["source"].as_str(),
                Some(format!("represent/{repr}").as_str())
            );
            assert!(infer["inputs"]["events"].is_null());
            assert_eq!(find(&nodes, "represent")["outputs"][0].as_str(), Some(repr));
            let src_args = find(&nodes, "spike-source")["args"].as_str().expect("args");
            assert!(src_args.contains("--file /d/x.dat") && src_args.contains("--file-width 40"));
            assert_eq!(
                find(&nodes, "sink")["inputs"][m]["queue_policy"].as_str(),
                Some("backpressure")
            );
        }
    }

    #[test]
    fn event_methods_add_the_event_source_and_read_align_events() {
        for (method, repr) in [
            (Method::Hf, None),
            (Method::Cf, Some("isi")),
            (Method::Fusion, Some("isi")),
        ] {
            let mut o = opts(method);
            o.event_source_args = "--file-width 40 --file-height 25".into();
            o.infer_args = "--contrast 0.25".into();
            let y = graph_yaml(
                &o,
                Path::new("/d/x.dat"),
                Some(Path::new("/d/e.raw")),
                Some(Path::new("/d/ground-truth")),
                Path::new("/o"),
            );
            let nodes = nodes(&y);
            let m = method.name();
            let ev = find(&nodes, "event-source");
            let args = ev["args"].as_str().expect("args");
            assert!(
                args.contains("--file /d/e.raw") && args.contains("--file-width 40"),
                "{args}"
            );
            let align = find(&nodes, "align");
            assert_eq!(
                align["inputs"]["events"]["source"].as_str(),
                Some("event-source/events")
            );
            assert_eq!(align["outputs"][1].as_str(), Some("events"));
            let source = find(&nodes, "spike-source");
            let src_args = source["args"].as_str().expect("args");
            assert!(src_args.contains("--truth /d/ground-truth"), "{src_args}");
            assert_eq!(source["outputs"][1].as_str(), Some("ground_truth"));
            assert_eq!(
                find(&nodes, "sink")["inputs"]["ground_truth"]["source"].as_str(),
                Some("spike-source/ground_truth")
            );
            let infer = find(&nodes, &format!("infer-{m}"));
            assert_eq!(
                infer["inputs"]["events"]["source"].as_str(),
                Some("align/events")
            );
            assert_eq!(
                infer["inputs"]["events"]["queue_policy"].as_str(),
                Some("backpressure")
            );
            assert!(
                infer["args"]
                    .as_str()
                    .expect("args")
                    .contains("--contrast 0.25")
            );
            match repr {
                Some(r) => assert_eq!(
                    infer["inputs"]["representation"]["source"].as_str(),
                    Some(format!("represent/{r}").as_str())
                ),
                None => {
                    assert!(infer["inputs"]["representation"].is_null());
                    assert!(nodes.iter().all(|n| n["id"].as_str() != Some("represent")));
                }
            }
        }
    }

    fn refused(o: &ReconstructOptions) -> String {
        match reconstruct(o) {
            Ok(_) => panic!("{o:?} was accepted"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn events_and_methods_must_agree() {
        let mut o = opts(Method::Tfp);
        o.events = Some("e.raw".into());
        let e = refused(&o);
        assert!(
            e.contains("e.raw") && e.contains("hf, cf and fusion"),
            "{e}"
        );
        let e = refused(&opts(Method::Fusion));
        assert!(
            e.contains("--method fusion") && e.contains("--events"),
            "{e}"
        );
        let mut o = opts(Method::Hf);
        o.events = Some("/no/such/events.raw".into());
        let e = refused(&o);
        assert!(e.contains("/no/such/events.raw"), "{e}");
    }
}
