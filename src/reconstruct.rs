//! `neuspike reconstruct`: frames from a recorded spike file, through a graph written for the
//! run. The graph is saved in the output folder beside the frames (`graph.yml`, with a `types`
//! link to the message types), so the run can be repeated with the stock dora CLI too.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use eyre::WrapErr;

use crate::graph;
use neuspike_reconstruction::learned::{LearnedInput, LearnedModel};

/// Reconstructions a recording can go through: the infer node's methods.
pub use neuspike_reconstruction::Method;

/// What the graph needs to know of a learned model: its file and the representations it reads.
#[derive(Clone, Debug)]
pub struct Learned {
    /// The ONNX file (absolute: the graph lives in the output folder).
    pub model: PathBuf,
    /// Its inputs, in order, with their channel counts.
    pub inputs: Vec<(LearnedInput, usize)>,
}

impl Learned {
    /// Loads and checks the model (the infer node checks it again at start-up).
    ///
    /// # Errors
    /// The file is missing, unreadable or not a NeuSpike-Net.
    pub fn load(path: &Path) -> eyre::Result<Learned> {
        let model = std::fs::canonicalize(crate::models::or_shipped(path))
            .wrap_err_with(|| format!("--model {}: cannot open", path.display()))?;
        let net = LearnedModel::load(&model).map_err(|e| eyre::eyre!("--model: {e}"))?;
        let inputs = net
            .inputs()
            .iter()
            .copied()
            .zip(net.channels().iter().copied())
            .collect();
        Ok(Learned { model, inputs })
    }

    fn reads_events(&self) -> bool {
        self.inputs.iter().any(|(i, _)| *i == LearnedInput::Events)
    }
}

/// What the graph needs to know for [`Method::Auto`].
#[derive(Clone, Debug)]
pub struct AutoPlan {
    /// The policy file (absolute).
    pub policy: PathBuf,
    /// The folder of the networks it names (absolute).
    pub models: PathBuf,
    /// Planes of align's windows.
    pub window_planes: u32,
    /// Whether the windows are shorter than the policy's longest method reads.
    pub short: bool,
}

impl AutoPlan {
    /// Reads and checks the policy; the window is the longest any of its methods reads (TFP over
    /// its planes, 33 for the others), or `window_planes` when given.
    ///
    /// # Errors
    /// The policy does not load (the error names the file and field).
    pub fn new(policy: &Path, window_planes: Option<u32>) -> eyre::Result<AutoPlan> {
        use neuspike_reconstruction::policy::Policy;
        let policy = std::fs::canonicalize(crate::models::or_shipped(policy))
            .wrap_err_with(|| format!("--policy {}: cannot open", policy.display()))?;
        let longest = neuspike_reconstruction::auto::longest_window(&Policy::read(&policy)?);
        let models = policy
            .parent()
            .map_or_else(|| PathBuf::from("."), Path::to_path_buf);
        let window_planes = window_planes.unwrap_or(longest);
        Ok(AutoPlan {
            policy,
            models,
            window_planes,
            short: window_planes < longest,
        })
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
    /// file`) and PNGs, or an AEDAT 4 file whose APS frames (at their own times, on the spikes'
    /// clock) are the truth, each scoring the nearest frame within half a stride. `None` looks
    /// for `ground-truth/` beside the spike file, as `neuspike simulate` writes it; the sink
    /// scores the frames against it.
    pub truth: Option<PathBuf>,
    /// The method.
    pub method: Method,
    /// The ONNX network, for [`Method::Learned`].
    pub model: Option<PathBuf>,
    /// The policy, for [`Method::Auto`]; the networks it names are read from its folder.
    pub policy: PathBuf,
    /// Output folder.
    pub out: PathBuf,
    /// Extra spike-source arguments (resolution, head columns, rate, start, calibration).
    pub source_args: String,
    /// Extra event-source arguments (the sensor size of files that do not state it, start, end).
    pub event_source_args: String,
    /// Extra infer arguments (contrast, filter gains, theta mode).
    pub infer_args: String,
    /// Planes per window: `None` gives 33, or for [`Method::Auto`] the longest window its
    /// policy's methods read. For auto a smaller value (a short recording) leaves out the methods
    /// that read more.
    pub window_planes: Option<u32>,
    /// Planes between two frames.
    pub stride_planes: u32,
    /// PNG bit depth.
    pub bit_depth: u8,
    /// Run the graph's `build:` command first.
    pub build: bool,
}

/// The graph for `opts`, with absolute paths (it lives in the output folder). `events` is the
/// event file, when the method reads one.
pub fn graph_yaml(
    opts: &ReconstructOptions,
    spikes: &Path,
    events: Option<&Path>,
    truth: Option<&Path>,
    learned: Option<&Learned>,
    auto: Option<&AutoPlan>,
    out: &Path,
) -> String {
    // The node binaries beside this program; built from its sources when it runs from them.
    let bins = graph::node_dir().unwrap_or_default();
    let bin = |name: &str| bins.join(format!("neuspike-{name}"));
    let build = graph::build_command().map_or(String::new(), |cmd| format!("\n    build: {cmd}"));
    let queue = format!("queue_size: {}", neuspike_pipeline::derive::CREDIT_WINDOW);
    let m = opts.method.as_str();
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
            "  - id: {id}{build}\n    path: {}\n    args: {args}\n    env: {{ DORA_RUNTIME_TYPE_CHECK: error }}",
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
    let window_planes = auto.map_or(opts.window_planes.unwrap_or(DEFAULT_WINDOW_PLANES), |a| {
        a.window_planes
    });
    let window_args = format!(
        "--window-planes {window_planes} --stride-planes {}",
        opts.stride_planes
    );
    if events.is_some() {
        // A classical event method reads align's event stream; the learned one reads the events
        // inside the windows (represent's event integration).
        let (outputs, types) = if opts.method.inputs().events {
            (
                "outputs: [windows, events]".to_string(),
                format!(
                    "output_types: {{ windows: {}, events: {} }}",
                    t("AlignedWindow"),
                    t("EventBatch")
                ),
            )
        } else {
            (
                "outputs: [windows]".to_string(),
                format!("output_types: {{ windows: {} }}", t("AlignedWindow")),
            )
        };
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
                outputs,
                types,
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
    // A network that reads spikes alone reads align's windows itself (its raw planes as the
    // window holds them, bit-packed): no represent node.
    let from_windows =
        learned.is_some_and(|l| l.inputs.iter().all(|(i, _)| *i == LearnedInput::Spike));
    // The represent outputs the infer node reads, each the input of the same name.
    let reprs: Vec<&str> = match learned {
        Some(_) if from_windows => Vec::new(),
        Some(l) => l.inputs.iter().map(|(i, _)| i.input_id()).collect(),
        None => opts
            .method
            .graph_representation()
            .map(|k| k.name())
            .into_iter()
            .collect(),
    };
    if !reprs.is_empty() {
        let mut args = format!("--tfp-planes {window_planes}");
        if let Some(l) = learned {
            for (i, c) in &l.inputs {
                let _ = match i {
                    LearnedInput::Spike => write!(args, " --repr-channels {c}"),
                    LearnedInput::Events => write!(args, " --ei-channels {c} --tau-ns 500000"),
                };
            }
        }
        let list = reprs.join(", ");
        let kinds: Vec<String> = reprs
            .iter()
            .map(|r| format!("{r}: {}", t("Representation")))
            .collect();
        node(
            "represent",
            "represent",
            &args,
            &[
                format!("inputs: {{ windows: {{ source: align/windows, {queue} }} }}"),
                format!("input_types: {{ windows: {} }}", t("AlignedWindow")),
                format!("outputs: [{list}]"),
                format!("output_types: {{ {} }}", kinds.join(", ")),
            ],
        );
    }
    let mut inputs = Vec::new();
    let mut types = Vec::new();
    match learned {
        Some(_) => {
            for r in &reprs {
                inputs.push(format!("{r}: {{ source: represent/{r}, {queue} }}"));
                types.push(format!("{r}: {}", t("Representation")));
            }
        }
        None => {
            if let Some(r) = reprs.first() {
                inputs.push(format!(
                    "representation: {{ source: represent/{r}, {queue} }}"
                ));
                types.push(format!("representation: {}", t("Representation")));
            }
        }
    }
    if opts.method.inputs().events {
        inputs.push(format!("events: {{ source: align/events, {queue} }}"));
        types.push(format!("events: {}", t("EventBatch")));
    }
    if auto.is_some() || from_windows {
        inputs.push(format!("windows: {{ source: align/windows, {queue} }}"));
        types.push(format!("windows: {}", t("AlignedWindow")));
    }
    let infer_args = match (learned, auto) {
        (Some(l), _) => format!(
            "--method {m} --model {} {}",
            l.model.display(),
            opts.infer_args
        ),
        (None, Some(a)) => format!(
            "--method {m} --policy {} --models {}{}{} {}",
            a.policy.display(),
            a.models.display(),
            if events.is_none() {
                " --spikes-only"
            } else {
                ""
            },
            if a.short {
                format!(" --window-planes {}", a.window_planes)
            } else {
                String::new()
            },
            opts.infer_args
        ),
        (None, None) => format!("--method {m} {}", opts.infer_args),
    };
    node(
        &format!("infer-{m}"),
        "infer",
        &infer_args,
        &[
            format!("inputs: {{ {} }}", inputs.join(", ")),
            format!("input_types: {{ {} }}", types.join(", ")),
            "outputs: [frames]".into(),
            format!("output_types: {{ frames: {} }}", t("Frame")),
        ],
    );
    // Truth off the frames' grid (APS frames at their own times) scores the nearest frame within
    // half a stride; truth listed by plane must fall on a frame's instant.
    let within_ns = match truth {
        Some(t) if t.is_file() => {
            let stride_ns =
                i64::from(opts.stride_planes).saturating_mul(plane_period_ns(&opts.source_args));
            format!(" --truth-within-ns {}", stride_ns / 2)
        }
        _ => String::new(),
    };
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
        &format!(
            "--out {} --bit-depth {}{within_ns}",
            out.display(),
            opts.bit_depth
        ),
        &[
            format!("inputs: {{ {m}: {{ source: infer-{m}/frames, {queue} }}{truth_in} }}"),
            format!("input_types: {{ {m}: {}{truth_type} }}", t("Frame")),
        ],
    );
    with_credits(&y)
}

/// The luminance per unit firing rate that `neuspike simulate` wrote in `recording.yml` beside
/// `spikes`, when that manifest describes this file; `None` otherwise (no manifest, another
/// file, or a value that is not finite and `> 0`).
pub fn recorded_lum_per_rate(spikes: &Path) -> Option<f64> {
    let manifest = spikes.parent()?.join("recording.yml");
    let meta = std::fs::metadata(&manifest).ok()?;
    if meta.len() > 1 << 20 {
        return None;
    }
    let text = std::fs::read_to_string(&manifest).ok()?;
    let y: serde_yaml::Value = serde_yaml::from_str(&text).ok()?;
    let s = &y["spikes"];
    let named = s["file"].as_str()?;
    if spikes.file_name()?.to_str()? != named {
        return None;
    }
    s["lum_per_rate"]
        .as_f64()
        .filter(|v| v.is_finite() && *v > 0.0)
}

/// Planes per window of the methods that do not choose their own.
pub const DEFAULT_WINDOW_PLANES: u32 = 33;

/// `yaml` with neuspike's credit flow control wired in ([`neuspike_pipeline::derive::wire_credits`]), its first
/// comment line kept.
fn with_credits(yaml: &str) -> String {
    let Ok(mut g) = serde_yaml::from_str::<serde_yaml::Value>(yaml) else {
        return yaml.to_string();
    };
    neuspike_pipeline::derive::wire_credits(&mut g, neuspike_pipeline::derive::CREDIT_WINDOW);
    let comment: String = yaml
        .lines()
        .take_while(|l| l.starts_with('#'))
        .map(|l| format!("{l}\n"))
        .collect();
    match serde_yaml::to_string(&g) {
        Ok(body) => format!("{comment}{body}"),
        Err(_) => yaml.to_string(),
    }
}

/// The spike source's plane period: its `--rate-hz` among `source_args` (the other arguments are
/// the node's to check), else the camera's default; rounded as the camera rounds it. A rate the
/// node will refuse gives the default here, and the node's error names it.
fn plane_period_ns(source_args: &str) -> i64 {
    let mut rate = None;
    let mut words = source_args.split_whitespace();
    // The last one counts, as the node parses it (`args_override_self`).
    while let Some(w) = words.next() {
        if w == "--rate-hz" {
            rate = words.next();
        } else if let Some(v) = w.strip_prefix("--rate-hz=") {
            rate = Some(v);
        }
    }
    let rate = rate
        .and_then(|r| r.parse::<f64>().ok())
        .filter(|r| r.is_finite() && *r > 0.0 && *r <= 1e9)
        .unwrap_or(neuspike_spike_camera::CameraConfig::default().rate_hz);
    (1e9 / rate).round() as i64
}

/// Writes the graph into the output folder and runs it.
pub fn reconstruct(opts: &ReconstructOptions) -> eyre::Result<graph::Report> {
    let m = opts.method.as_str();
    let auto = match opts.method {
        Method::Auto => Some(AutoPlan::new(&opts.policy, opts.window_planes)?),
        _ => None,
    };
    let learned = match (opts.method, &opts.model) {
        (Method::Learned, Some(path)) => Some(Learned::load(path)?),
        (Method::Learned, None) => eyre::bail!(
            "--method learned needs --model FILE (an ONNX network, e.g. models/neuspike-spike-8.onnx)"
        ),
        (_, Some(path)) => eyre::bail!(
            "--model {}: --model is for --method learned, not {m}",
            path.display()
        ),
        (_, None) => None,
    };
    let needs_events = match &learned {
        Some(l) => l.reads_events(),
        None => opts.method.inputs().events,
    };
    // auto takes events when given (its policy then may choose the methods that read them),
    // and chooses among the methods that read spikes alone when not.
    let events = match (&opts.events, needs_events || auto.is_some()) {
        (Some(e), true) => Some(
            std::fs::canonicalize(e)
                .wrap_err_with(|| format!("--events {}: cannot open", e.display()))?,
        ),
        (None, _) if auto.is_some() => None,
        (None, true) => eyre::bail!(
            "--method {m}{} reconstructs from events: give the event recording with --events FILE",
            learned
                .as_ref()
                .map_or(String::new(), |l| format!(" with {}", l.model.display()))
        ),
        (Some(e), false) => eyre::bail!(
            "--events {}: --method {m} reads the spikes only; the methods that read events are \
             hf, cf, fusion, auto, and learned with a model that reads events",
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
    // `neuspike simulate` writes its recording.yml last: a folder of its files without it is a
    // simulation that did not finish.
    if let Some(folder) = spikes.parent()
        && folder.join("ground-truth").join("timestamps.txt").is_file()
        && !folder.join("recording.yml").exists()
    {
        tracing::warn!(
            "{}: no recording.yml beside the spikes and their ground truth: if `neuspike \
             simulate` made this folder, it did not finish, and its files may stop short",
            folder.display()
        );
    }
    // The calibration `neuspike simulate` recorded beside the spikes, unless given.
    let mut opts = opts.clone();
    if !opts.source_args.contains("--lum-per-rate")
        && let Some(lpr) = recorded_lum_per_rate(&spikes)
    {
        tracing::info!(
            lum_per_rate = lpr,
            "calibration from the recording's recording.yml"
        );
        opts.source_args = format!("{} --lum-per-rate {lpr}", opts.source_args);
    }
    let opts = &opts;
    std::fs::create_dir_all(&opts.out)
        .wrap_err_with(|| format!("cannot create {}", opts.out.display()))?;
    let out = std::fs::canonicalize(&opts.out)?;
    graph::write_types(&out)?;
    let graph_path = out.join("graph.yml");
    std::fs::write(
        &graph_path,
        graph_yaml(
            opts,
            &spikes,
            events.as_deref(),
            truth.as_deref(),
            learned.as_ref(),
            auto.as_ref(),
            &out,
        ),
    )
    .wrap_err_with(|| format!("cannot write {}", graph_path.display()))?;
    graph::run(&graph_path, &[], opts.build, None, Some(out))
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
            model: None,
            policy: "models/policy.yml".into(),
            out: "out".into(),
            source_args: "--file-width 40 --file-height 25".into(),
            event_source_args: String::new(),
            infer_args: String::new(),
            window_planes: Some(33),
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
        for (method, repr) in [
            (Method::Tfp, "tfp"),
            (Method::Tfi, "isi"),
            (Method::Tfstp, "stp"),
        ] {
            let y = graph_yaml(
                &opts(method),
                Path::new("/d/x.dat"),
                None,
                None,
                None,
                None,
                Path::new("/o"),
            );
            let nodes = nodes(&y);
            assert_eq!(nodes.len(), 5);
            let m = method.as_str();
            let infer = find(&nodes, &format!("infer-{m}"));
            assert_eq!(
                infer["inputs"]["representation"]["source"].as_str(),
                Some(format!("represent/{repr}").as_str())
            );
            assert!(infer["inputs"]["events"].is_null());
            assert_eq!(find(&nodes, "represent")["outputs"][0].as_str(), Some(repr));
            let src_args = find(&nodes, "spike-source")["args"].as_str().expect("args");
            assert!(src_args.contains("--file /d/x.dat") && src_args.contains("--file-width 40"));
            let sink = find(&nodes, "sink");
            assert_eq!(
                sink["inputs"][m]["queue_size"].as_u64(),
                Some(neuspike_pipeline::derive::CREDIT_WINDOW)
            );
            assert_eq!(sink["outputs"][0].as_str(), Some("credits"));
            assert_eq!(
                infer["inputs"]["credits-sink"]["source"].as_str(),
                Some("sink/credits")
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
                None,
                None,
                Path::new("/o"),
            );
            let nodes = nodes(&y);
            let m = method.as_str();
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
            assert!(infer["inputs"]["events"]["queue_policy"].is_null());
            assert_eq!(
                align["inputs"][format!("credits-infer-{m}").as_str()]["source"].as_str(),
                Some(format!("infer-{m}/credits").as_str())
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
        assert!(e.contains("e.raw") && e.contains("hf, cf, fusion"), "{e}");
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

    #[test]
    fn auto_reads_align_windows_and_takes_events_only_when_given() {
        let plan = AutoPlan {
            policy: "/m/policy.yml".into(),
            models: "/m".into(),
            window_planes: 256,
            short: false,
        };
        let infer_args = |events: Option<&Path>, plan: &AutoPlan| {
            let y = graph_yaml(
                &opts(Method::Auto),
                Path::new("/d/x.dat"),
                events,
                None,
                None,
                Some(plan),
                Path::new("/o"),
            );
            let graph = nodes(&y);
            assert!(graph.iter().all(|n| n["id"].as_str() != Some("represent")));
            let align = find(&graph, "align");
            assert!(
                align["args"]
                    .as_str()
                    .is_some_and(|a| a.contains("--window-planes 256")),
                "{align:?}"
            );
            let infer = find(&graph, "infer-auto");
            assert_eq!(
                infer["inputs"]["windows"]["source"].as_str(),
                Some("align/windows")
            );
            assert_eq!(graph.len(), 4 + usize::from(events.is_some()));
            infer["args"].as_str().expect("args").to_string()
        };
        let alone = infer_args(None, &plan);
        assert!(
            alone.contains("--method auto --policy /m/policy.yml --models /m --spikes-only"),
            "{alone}"
        );
        assert!(!alone.contains("--window-planes"), "{alone}");
        let both = infer_args(Some(Path::new("/d/e.raw")), &plan);
        assert!(!both.contains("--spikes-only"), "{both}");
        let short = AutoPlan {
            window_planes: 128,
            short: true,
            ..plan.clone()
        };
        let y = graph_yaml(
            &opts(Method::Auto),
            Path::new("/d/x.dat"),
            None,
            None,
            None,
            Some(&short),
            Path::new("/o"),
        );
        let graph = nodes(&y);
        assert!(
            find(&graph, "infer-auto")["args"]
                .as_str()
                .is_some_and(|a| a.contains("--window-planes 128")),
            "{y}"
        );
    }

    #[test]
    fn the_calibration_comes_from_the_recordings_manifest_when_it_names_the_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let spikes = dir.path().join("spikes.dat");
        assert_eq!(recorded_lum_per_rate(&spikes), None, "no manifest");
        let write = |text: &str| {
            std::fs::write(dir.path().join("recording.yml"), text).expect("write");
        };
        write("spikes:\n  file: spikes.dat\n  lum_per_rate: 20\n");
        assert_eq!(recorded_lum_per_rate(&spikes), Some(20.0));
        assert_eq!(recorded_lum_per_rate(&dir.path().join("other.dat")), None);
        write("spikes:\n  file: spikes.dat\n  lum_per_rate: -1\n");
        assert_eq!(recorded_lum_per_rate(&spikes), None);
        write("not: [yaml");
        assert_eq!(recorded_lum_per_rate(&spikes), None);
    }

    #[test]
    fn the_shipped_policy_sets_auto_windows_to_its_longest_method() {
        let policy = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/policy.yml");
        let plan = AutoPlan::new(&policy, None).expect("the shipped policy");
        assert_eq!(plan.window_planes, 256);
        assert!(!plan.short);
        assert!(plan.models.join("neuspike-fused-16.onnx").is_file());
        let short = AutoPlan::new(&policy, Some(128)).expect("the shipped policy");
        assert!(short.short);
        let e = AutoPlan::new(Path::new("/no/policy.yml"), None)
            .expect_err("missing")
            .to_string();
        assert!(e.contains("/no/policy.yml"), "{e}");
    }

    #[test]
    fn the_learned_method_wires_what_its_model_reads() {
        let spike_only = Learned {
            model: "/m/spike.onnx".into(),
            inputs: vec![(LearnedInput::Spike, 32)],
        };
        let y = graph_yaml(
            &opts(Method::Learned),
            Path::new("/d/x.dat"),
            None,
            None,
            Some(&spike_only),
            None,
            Path::new("/o"),
        );
        let graph = nodes(&y);
        // A spike network reads align's windows: no represent node.
        assert_eq!(graph.len(), 4);
        assert!(graph.iter().all(|n| n["id"].as_str() != Some("represent")));
        let infer = find(&graph, "infer-learned");
        assert_eq!(
            infer["inputs"]["windows"]["source"].as_str(),
            Some("align/windows")
        );
        assert!(infer["inputs"]["spike_repr"].is_null());
        let args = infer["args"].as_str().expect("args");
        assert!(
            args.contains("--method learned --model /m/spike.onnx"),
            "{args}"
        );

        let fused = Learned {
            model: "/m/fused.onnx".into(),
            inputs: vec![(LearnedInput::Spike, 32), (LearnedInput::Events, 32)],
        };
        let y = graph_yaml(
            &opts(Method::Learned),
            Path::new("/d/x.dat"),
            Some(Path::new("/d/e.raw")),
            None,
            Some(&fused),
            None,
            Path::new("/o"),
        );
        let graph = nodes(&y);
        assert_eq!(graph.len(), 6);
        // The events reach represent inside align's windows: align sends no event stream.
        let align = find(&graph, "align");
        assert_eq!(
            align["inputs"]["events"]["source"].as_str(),
            Some("event-source/events")
        );
        let outputs: Vec<&str> = align["outputs"]
            .as_sequence()
            .expect("outputs")
            .iter()
            .filter_map(serde_yaml::Value::as_str)
            .collect();
        assert_eq!(outputs, ["windows", "credits"]);
        let represent = find(&graph, "represent");
        assert_eq!(represent["outputs"][1].as_str(), Some("event_integration"));
        let args = represent["args"].as_str().expect("args");
        assert!(args.contains("--ei-channels 32"), "{args}");
        let infer = find(&graph, "infer-learned");
        assert_eq!(
            infer["inputs"]["event_integration"]["source"].as_str(),
            Some("represent/event_integration")
        );
        assert!(infer["inputs"]["events"].is_null());
    }

    #[test]
    fn the_learned_method_needs_a_model_and_the_events_it_reads() {
        let e = refused(&opts(Method::Learned));
        assert!(e.contains("--model"), "{e}");
        let mut o = opts(Method::Tfp);
        o.model = Some("m.onnx".into());
        let e = refused(&o);
        assert!(e.contains("m.onnx") && e.contains("learned"), "{e}");
        let mut o = opts(Method::Learned);
        o.model = Some("/no/such/model.onnx".into());
        let e = refused(&o);
        assert!(e.contains("/no/such/model.onnx"), "{e}");
        let mut o = opts(Method::Learned);
        o.model =
            Some(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models/neuspike-fused-8.onnx"));
        let e = refused(&o);
        assert!(e.contains("--events") && e.contains("fused-8"), "{e}");
    }

    #[test]
    fn the_plane_period_comes_from_the_source_arguments() {
        assert_eq!(plane_period_ns(""), 50_000);
        assert_eq!(
            plane_period_ns("--start-plane 1000 --rate-hz 40000 --max-planes 4"),
            25_000
        );
        assert_eq!(plane_period_ns("--rate-hz=1000"), 1_000_000);
        assert_eq!(plane_period_ns("--rate-hz -5"), 50_000);
    }

    #[test]
    fn aps_truth_is_matched_within_half_a_stride() {
        let dir = tempfile::tempdir().expect("tempdir");
        let aps = dir.path().join("davis.aedat4");
        std::fs::write(&aps, b"").expect("write");
        let mut o = opts(Method::Tfp);
        o.source_args = "--rate-hz 40000".into();
        let sink_args = |truth: &Path| {
            let y = graph_yaml(
                &o,
                Path::new("/d/x.dat"),
                None,
                Some(truth),
                None,
                None,
                Path::new("/o"),
            );
            let nodes = nodes(&y);
            let src = find(&nodes, "spike-source")["args"]
                .as_str()
                .expect("args")
                .to_string();
            assert!(
                src.contains(&format!("--truth {}", truth.display())),
                "{src}"
            );
            find(&nodes, "sink")["args"]
                .as_str()
                .expect("args")
                .to_string()
        };
        // 10 planes at 40 kHz: 250 us between frames.
        let a = sink_args(&aps);
        assert!(a.ends_with("--truth-within-ns 125000"), "{a}");
        let a = sink_args(dir.path());
        assert!(
            !a.contains("--truth-within-ns"),
            "a folder is listed by plane: {a}"
        );
    }
}
