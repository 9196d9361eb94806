//! The graphs' stages from Python, in one process: [`reconstruct`] runs align, represent and
//! infer over spikes and events the user holds, and [`run_graph`] runs a graph's nodes as the
//! in-process chain (`neuspike run --in-process`), handing the messages of the outputs asked for
//! back as Python values. Both are the stage interface's second driver: the same stages, the same
//! order and loss rules as the dora graph, no daemon.

use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::Mutex;

use ndarray::Array1;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use neuspike_pipeline::{GraphChain, make_stage};
use neuspike_reconstruction::Method;
use neuspike_reconstruction::learned::{LearnedInput, LearnedModel};
use neuspike_schemas::{EventBatch, Frame, SpikeChunk, bytes_per_plane};
use neuspike_stage::{Chain, Msg, MsgType, Replay};

use crate::values::{Events, Spikes, stack_on_pool, to_numpy};
use crate::{errors, threads};

/// The folder of the shipped networks and `auto`'s policy: `$NEUSPIKE_MODELS`, else the
/// `models/` of the checkout this package was built from, while it is there.
pub fn models_dir() -> Option<PathBuf> {
    if let Some(d) = std::env::var_os("NEUSPIKE_MODELS") {
        return Some(PathBuf::from(d));
    }
    let built = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models");
    built
        .join("policy.yml")
        .is_file()
        .then(|| built.canonicalize().unwrap_or(built))
}

/// The shipped networks' folder (``$NEUSPIKE_MODELS``, else the checkout's ``models/`` that
/// built the package), or ``None``.
#[pyfunction]
pub fn models() -> Option<PathBuf> {
    models_dir()
}

/// A model given as a path, or by a shipped network's name (`neuspike-spike-8-video`).
fn model_path(m: &Path) -> PathBuf {
    let bare = m.components().count() == 1 && m.extension().is_none();
    match (bare, models_dir()) {
        (true, Some(d)) => d.join(m).with_extension("onnx"),
        _ => m.to_path_buf(),
    }
}

/// Planes per spike message fed to align.
const CHUNK_PLANES: usize = 20;
/// The span of each event message fed to align, ns.
const BATCH_NS: i64 = 1_000_000;
/// The most event messages one call feeds align (2^22 ms: 70 minutes of recording).
const MAX_EVENT_BATCHES: i128 = 1 << 22;

/// The spikes as the camera's messages of [`CHUNK_PLANES`] planes.
fn chunks(bits: &[u8], n: usize, s: &Spikes, lum_per_rate: Option<f64>) -> Vec<Msg> {
    let c = s.clock();
    let per = bytes_per_plane(c.width, c.height);
    (0..n)
        .step_by(CHUNK_PLANES)
        .enumerate()
        .map(|(seq, first)| {
            let k = CHUNK_PLANES.min(n - first);
            Msg::from(SpikeChunk {
                width: c.width,
                height: c.height,
                first_plane: c.first_plane + first as u64,
                n_planes: k,
                t_first_ns: c.t_first_ns + first as i64 * c.plane_period_ns,
                plane_period_ns: c.plane_period_ns,
                seq: seq as u64,
                bits: bits[first * per..(first + k) * per].to_vec(),
                lum_per_rate,
            })
        })
        .collect()
}

/// The events as the camera's messages of [`BATCH_NS`] each, covering `[from_ns, to_ns)` and
/// every event.
fn batches(
    e: neuspike_representations::EventSlice<'_>,
    sensor: (usize, usize),
    (start, end): (i64, i64),
) -> Vec<Msg> {
    let (h, w) = sensor;
    let mut out = Vec::new();
    let mut i = 0;
    let mut t = start;
    while t < end {
        let t_end = t.saturating_add(BATCH_NS).min(end);
        let mut b = EventBatch::empty(w, h, t, t_end, out.len() as u64);
        while i < e.len() && e.t_ns[i] < t_end {
            b.t_ns.push(e.t_ns[i]);
            b.x.push(e.x[i]);
            b.y.push(e.y[i]);
            b.polarity.push(e.polarity[i]);
            i += 1;
        }
        out.push(Msg::from(b));
        t = t_end;
    }
    out
}

/// Stage `kind` made from its node's arguments and the ports the chain wires, as a graph makes it.
fn stage(
    kind: &str,
    args: &[String],
    inputs: &[&str],
    outputs: &[&str],
) -> PyResult<Box<dyn neuspike_stage::Stage>> {
    make_stage(kind, args, &strings(inputs), &strings(outputs))
        .map_err(|e| errors::config(format!("{e:#}")))
}

/// The align stage cutting windows of `window` planes every `stride` planes, reading events when
/// `events`, sending `outputs`.
fn align_stage(
    window: u32,
    stride: u32,
    events: bool,
    outputs: &[&str],
) -> PyResult<Box<dyn neuspike_stage::Stage>> {
    let args = strings(&[
        "--window-planes",
        &window.to_string(),
        "--stride-planes",
        &stride.to_string(),
    ]);
    let inputs: &[&str] = if events {
        &["spikes", "events"]
    } else {
        &["spikes"]
    };
    stage("align", &args, inputs, outputs)
}

/// The recording as its cameras would send it: the spikes in chunks of [`CHUNK_PLANES`]
/// calibrated by `lum_per_rate`, and with `with_events` the events in batches covering the
/// planes' span. Made on the pool, the GIL released.
fn feed(
    py: Python<'_>,
    spikes: &Spikes,
    events: Option<&Bound<'_, Events>>,
    lum_per_rate: f64,
    with_events: bool,
) -> PyResult<(Vec<Msg>, Option<Vec<Msg>>)> {
    let n = spikes.planes(py);
    let bits = spikes.bits(py);
    let bits = bits.as_slice().map_err(errors::input)?;
    let columns = match events {
        Some(e) if with_events => Some((e.get().columns(py), e.get().sensor())),
        _ => None,
    };
    let events = match &columns {
        Some((cols, sensor)) => Some((cols.slice()?, *sensor)),
        None => None,
    };
    let c = spikes.clock();
    // The events' messages cover the planes' light and every event, a batch a millisecond.
    let mut span = (
        c.t_first_ns.saturating_sub(c.plane_period_ns),
        c.t_first_ns
            .saturating_add((n as i64).saturating_mul(c.plane_period_ns)),
    );
    if let Some((e, _)) = &events
        && let (Some(&first), Some(&last)) = (e.t_ns.first(), e.t_ns.last())
    {
        span = (span.0.min(first), span.1.max(last.saturating_add(1)));
    }
    let count = (i128::from(span.1) - i128::from(span.0)) / i128::from(BATCH_NS);
    if events.is_some() && count > MAX_EVENT_BATCHES {
        return Err(errors::input(format!(
            "events: the spikes and events span [{}, {}) ns together, more than {MAX_EVENT_BATCHES} ms: \
             are both on one clock (t_first_ns of the spikes, t_ns of the events)?",
            span.0, span.1
        )));
    }
    threads::run(py, || {
        (
            chunks(bits, n, spikes, Some(lum_per_rate)),
            events.map(|(slice, sensor)| batches(slice, sensor, span)),
        )
    })
}

/// The cameras of a [`feed`], as a source stage.
fn cameras(spikes: Vec<Msg>, events: Option<Vec<Msg>>) -> Replay<'static> {
    let source = Replay::new("cameras").output("spikes", MsgType::SpikeChunk, spikes);
    match events {
        Some(e) => source.output("events", MsgType::EventBatch, e),
        None => source,
    }
}

fn words(args: &str, what: &str) -> PyResult<Vec<String>> {
    shlex::split(args)
        .ok_or_else(|| errors::config(format!("{what}: `{args}` has an unclosed quote")))
}

fn strings(ids: &[&str]) -> Vec<String> {
    ids.iter().map(|s| s.to_string()).collect()
}

/// Frames collected from the infer stage, in order.
#[derive(Default)]
struct Collected {
    frames: Vec<Frame>,
}

/// The frames as arrays: ``frames [K, H, W]``, ``t_ref_ns [K]``, ``compute_ns [K]``, ``method``
/// and, for ``auto``, ``chosen`` (each frame's method).
fn frames_dict(py: Python<'_>, frames: Vec<Frame>) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    let t: Vec<i64> = frames.iter().map(|f| f.t_ref_ns).collect();
    let c: Vec<i64> = frames.iter().map(|f| f.compute_ns).collect();
    let chosen: Vec<Option<String>> = frames.iter().map(|f| f.chosen.clone()).collect();
    let method = frames.first().map(|f| f.method.clone());
    let views: Vec<_> = frames.iter().map(|f| f.data.view()).collect();
    d.set_item("frames", to_numpy(py, stack_on_pool(py, &views)?)?)?;
    d.set_item("t_ref_ns", to_numpy(py, Array1::from(t))?)?;
    d.set_item("compute_ns", to_numpy(py, Array1::from(c))?)?;
    d.set_item("method", method)?;
    if chosen.iter().any(Option::is_some) {
        d.set_item("chosen", chosen)?;
    }
    Ok(d)
}

/// Reconstructs frames from spikes (and events) with ``method`` (``tfp``, ``tfi``, ``tfstp``,
/// ``hf``, ``cf``, ``fusion``, ``learned``, ``auto``), through the graph's align, represent and
/// infer stages in one process: a frame every ``stride_planes`` planes, each from the
/// ``window_planes`` planes around it (``auto``: its policy's longest window unless given).
///
/// ``model`` is the network for ``learned`` (an ONNX file); ``policy`` the policy of ``auto``
/// (its networks are read from the policy's folder). ``infer`` adds the infer node's arguments
/// (``"--contrast 0.25"``). ``lum_per_rate`` calibrates spikes that do not carry it (default
/// 1). Returns a dict: ``frames`` ``float32 [K, H, W]`` (luminance in ``[0, 1]``), ``t_ref_ns``,
/// ``compute_ns``, ``method``, and for ``auto`` ``chosen`` (each frame's method).
#[pyfunction]
#[pyo3(signature = (spikes, events = None, *, method = "tfp", model = None, policy = None, window_planes = None, stride_planes = 20, infer = "", lum_per_rate = None))]
pub fn reconstruct<'py>(
    py: Python<'py>,
    spikes: &Bound<'py, Spikes>,
    events: Option<&Bound<'py, Events>>,
    method: &str,
    model: Option<PathBuf>,
    policy: Option<PathBuf>,
    window_planes: Option<u32>,
    stride_planes: u32,
    infer: &str,
    lum_per_rate: Option<f64>,
) -> PyResult<Bound<'py, PyDict>> {
    let m = Method::from_str(method).map_err(errors::config)?;
    let model = model.as_deref().map(model_path);
    let policy = policy.or_else(|| models_dir().map(|d| d.join("policy.yml")));
    let s = spikes.get();
    let n = s.planes(py);
    if n == 0 {
        return Err(errors::input("spikes: no planes"));
    }
    let needs = m.inputs();
    if needs.events && events.is_none() {
        return Err(errors::config(format!(
            "method {method}: reads events; pass events="
        )));
    }
    // What the network reads, for learned.
    let learned: Vec<(LearnedInput, usize)> = match (m, &model) {
        (Method::Learned, Some(path)) => {
            let net =
                LearnedModel::load(path).map_err(|e| errors::config(format!("model: {e}")))?;
            net.inputs()
                .iter()
                .copied()
                .zip(net.channels().iter().copied())
                .collect()
        }
        (Method::Learned, None) => {
            return Err(errors::config(
                "method learned: pass model= (an ONNX file, or a shipped network's name such as neuspike-spike-8-video)",
            ));
        }
        _ => Vec::new(),
    };
    let reads_events = needs.events
        || learned.iter().any(|(i, _)| *i == LearnedInput::Events)
        || (m == Method::Auto && events.is_some());
    if learned.iter().any(|(i, _)| *i == LearnedInput::Events) && events.is_none() {
        return Err(errors::config("model: reads events; pass events="));
    }
    // Auto's window is its policy's longest, or the recording where that is shorter (the
    // methods that read more are then left out).
    let window = match (m, window_planes) {
        (_, Some(w)) => w,
        (Method::Auto, None) => {
            let p = policy.as_deref().ok_or_else(|| {
                errors::config("method auto: pass policy= (models/policy.yml in the repository)")
            })?;
            auto_window(p)?.min(u32::try_from(n).unwrap_or(u32::MAX))
        }
        _ => 33,
    };
    let lum = lum_per_rate.or(s.clock().lum_per_rate).unwrap_or(1.0);

    // The stages, as a graph wires them.
    let mut align_out = vec!["windows"];
    if needs.events {
        align_out.push("events");
    }
    let reprs: Vec<&str> = if learned.is_empty() {
        m.graph_representation()
            .map(|k| k.name())
            .into_iter()
            .collect()
    } else {
        learned.iter().map(|(i, _)| i.input_id()).collect()
    };
    let mut represent_args = vec!["--tfp-planes".to_string(), window.to_string()];
    for (i, c) in &learned {
        match i {
            LearnedInput::Spike => {
                represent_args.extend(strings(&["--repr-channels", &c.to_string()]))
            }
            LearnedInput::Events => represent_args.extend(strings(&[
                "--ei-channels",
                &c.to_string(),
                "--tau-ns",
                "500000",
            ])),
        }
    }
    let mut infer_args = vec!["--method".to_string(), m.as_str().to_string()];
    if let Some(path) = &model {
        infer_args.extend(["--model".to_string(), path.display().to_string()]);
    }
    if m == Method::Auto {
        let p = policy.as_deref().unwrap_or(Path::new("models/policy.yml"));
        let models = p.parent().unwrap_or(Path::new("."));
        infer_args.extend(strings(&[
            "--policy",
            &p.display().to_string(),
            "--models",
            &models.display().to_string(),
        ]));
        if events.is_none() {
            infer_args.push("--spikes-only".into());
        }
        infer_args.extend(strings(&["--window-planes", &window.to_string()]));
    }
    infer_args.extend(words(infer, "infer")?);
    let mut infer_in: Vec<String> = Vec::new();
    let mut edges: Vec<(String, String)> = Vec::new();
    if learned.is_empty() {
        if let Some(r) = reprs.first() {
            infer_in.push("representation".into());
            edges.push((format!("represent/{r}"), "infer/representation".into()));
        }
    } else {
        for r in &reprs {
            infer_in.push((*r).into());
            edges.push((format!("represent/{r}"), format!("infer/{r}")));
        }
    }
    if needs.events {
        infer_in.push("events".into());
        edges.push(("align/events".into(), "infer/events".into()));
    }
    if m == Method::Auto {
        infer_in.push("windows".into());
        edges.push(("align/windows".into(), "infer/windows".into()));
    }

    let align = align_stage(window, stride_planes, reads_events, &align_out)?;
    let represent = if reprs.is_empty() {
        None
    } else {
        Some(stage("represent", &represent_args, &["windows"], &reprs)?)
    };
    let infer_ins: Vec<&str> = infer_in.iter().map(String::as_str).collect();
    let infer_stage = stage("infer", &infer_args, &infer_ins, &["frames"])?;
    let (spike_msgs, event_msgs) = feed(py, s, events, lum, reads_events)?;
    let collected = Mutex::new(Collected::default());
    let run = threads::run(py, || -> eyre::Result<()> {
        let source = cameras(spike_msgs, event_msgs);
        let mut chain = Chain::new();
        chain
            .add("cameras", source)?
            .add("align", align)?
            .connect("cameras/spikes", "align/spikes")?;
        if reads_events {
            chain.connect("cameras/events", "align/events")?;
        }
        if let Some(r) = represent {
            chain
                .add("represent", r)?
                .connect("align/windows", "represent/windows")?;
        }
        chain.add("infer", infer_stage)?;
        for (from, to) in &edges {
            chain.connect(from, to)?;
        }
        chain.tap("infer/frames", |msg| {
            let f = Frame::try_from(msg)?;
            collected
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .frames
                .push(f);
            Ok(())
        })?;
        chain.run().map(drop)
    })?;
    run.map_err(|e| errors::config(format!("{e:#}")))?;
    let frames = collected
        .into_inner()
        .unwrap_or_else(|p| p.into_inner())
        .frames;
    frames_dict(py, frames)
}

/// Representations of a whole recording through the graph's align and represent stages in one
/// process: for every window of ``window_planes`` planes, a window every ``stride_planes``, each
/// kind of ``kinds`` (``tfp``, ``isi``, ``stp``, ``spike_repr``, ``event_integration``,
/// ``voxel_grid``, ``event_stack``, ``time_surface``; the event kinds need ``events``), as the
/// represent node makes them. ``represent`` adds the represent node's arguments
/// (``"--voxel-bins 10 --tau-ns 250000"``). Returns a dict: each kind's ``float32 [K, C, H, W]``,
/// and ``t_ref_ns``.
#[pyfunction]
#[pyo3(signature = (spikes, events = None, *, kinds = vec!["tfp".to_string()], window_planes = 33, stride_planes = 20, represent = ""))]
pub fn represent<'py>(
    py: Python<'py>,
    spikes: &Bound<'py, Spikes>,
    events: Option<&Bound<'py, Events>>,
    kinds: Vec<String>,
    window_planes: u32,
    stride_planes: u32,
    represent: &str,
) -> PyResult<Bound<'py, PyDict>> {
    use neuspike_schemas::{Representation, RepresentationKind};
    let s = spikes.get();
    let n = s.planes(py);
    if n == 0 {
        return Err(errors::input("spikes: no planes"));
    }
    let mut wanted: Vec<RepresentationKind> = Vec::new();
    for k in &kinds {
        let kind = RepresentationKind::ALL
            .into_iter()
            .find(|r| r.name() == k)
            .ok_or_else(|| {
                let names: Vec<&str> = RepresentationKind::ALL.iter().map(|r| r.name()).collect();
                errors::config(format!("kinds: {k:?} is not one of {}", names.join(", ")))
            })?;
        if !wanted.contains(&kind) {
            wanted.push(kind);
        }
    }
    if wanted.is_empty() {
        return Err(errors::config("kinds: none asked for"));
    }
    let mut represent_args = vec!["--tfp-planes".to_string(), window_planes.to_string()];
    represent_args.extend(words(represent, "represent")?);
    let names: Vec<String> = wanted.iter().map(|k| k.name().to_string()).collect();
    let name_refs: Vec<&str> = names.iter().map(String::as_str).collect();
    let align = align_stage(window_planes, stride_planes, events.is_some(), &["windows"])?;
    let represent_stage = stage("represent", &represent_args, &["windows"], &name_refs)?;
    let lum = s.clock().lum_per_rate.unwrap_or(1.0);
    let (spike_msgs, event_msgs) = feed(py, s, events, lum, true)?;
    let with_events = event_msgs.is_some();
    let made: Vec<Mutex<Vec<Representation>>> =
        names.iter().map(|_| Mutex::new(Vec::new())).collect();
    let run = threads::run(py, || -> eyre::Result<()> {
        let source = cameras(spike_msgs, event_msgs);
        let mut chain = Chain::new();
        chain
            .add("cameras", source)?
            .add("align", align)?
            .add("represent", represent_stage)?
            .connect("cameras/spikes", "align/spikes")?
            .connect("align/windows", "represent/windows")?;
        if with_events {
            chain.connect("cameras/events", "align/events")?;
        }
        for (name, slot) in names.iter().zip(&made) {
            chain.tap(&format!("represent/{name}"), move |m| {
                let r = Representation::try_from(m)?;
                slot.lock().unwrap_or_else(|p| p.into_inner()).push(r);
                Ok(())
            })?;
        }
        chain.run().map(drop)
    })?;
    run.map_err(|e| errors::config(format!("{e:#}")))?;
    let d = PyDict::new(py);
    let mut times: Option<Vec<i64>> = None;
    for (name, slot) in names.iter().zip(made) {
        let reps = slot.into_inner().unwrap_or_else(|p| p.into_inner());
        times.get_or_insert_with(|| reps.iter().map(|r| r.t_ref_ns).collect());
        let views: Vec<_> = reps.iter().map(|r| r.data.view()).collect();
        d.set_item(name, to_numpy(py, stack_on_pool(py, &views)?)?)?;
    }
    d.set_item(
        "t_ref_ns",
        to_numpy(py, Array1::from(times.unwrap_or_default()))?,
    )?;
    Ok(d)
}

/// The window auto's policy needs: the longest any of its methods reads.
fn auto_window(policy: &Path) -> PyResult<u32> {
    neuspike_reconstruction::policy::Policy::read(policy)
        .map(|p| neuspike_reconstruction::auto::longest_window(&p))
        .map_err(|e| errors::config(format!("{e:#}")))
}

/// A message as a Python value: spikes as :class:`Spikes`, events as :class:`Events`, frames
/// and representations as dicts (``data`` and the header), windows as dicts of both.
fn message(py: Python<'_>, msg: Msg) -> PyResult<Bound<'_, PyAny>> {
    Ok(match msg {
        Msg::Spikes(c) => Bound::new(py, Spikes::from_chunk(py, c)?)?.into_any(),
        Msg::Events(b) => Bound::new(py, Events::from_batch(py, b))?.into_any(),
        Msg::Window(w) => {
            let d = PyDict::new(py);
            d.set_item("t_ref_ns", w.t_ref_ns)?;
            d.set_item("ref_plane", w.ref_plane)?;
            d.set_item("spikes", Bound::new(py, Spikes::from_chunk(py, w.spikes)?)?)?;
            d.set_item("events", Bound::new(py, Events::from_batch(py, w.events))?)?;
            d.into_any()
        }
        Msg::Representation(r) => {
            let d = PyDict::new(py);
            d.set_item("kind", r.kind.name())?;
            d.set_item("t_ref_ns", r.t_ref_ns)?;
            d.set_item("seq", r.seq)?;
            d.set_item("params", r.params.into_iter().collect::<Vec<_>>())?;
            d.set_item("data", to_numpy(py, r.data)?)?;
            d.into_any()
        }
        Msg::Frame(f) => {
            let d = PyDict::new(py);
            d.set_item("method", f.method)?;
            d.set_item("t_ref_ns", f.t_ref_ns)?;
            d.set_item("compute_ns", f.compute_ns)?;
            d.set_item("seq", f.seq)?;
            d.set_item("chosen", f.chosen)?;
            d.set_item("data", to_numpy(py, f.data)?)?;
            d.into_any()
        }
    })
}

/// Runs a graph's nodes as one in-process chain (``neuspike run --in-process``): the same stages
/// and wiring as the dora graph, no daemon. ``graph`` is a YAML file, or the graph as a dict.
/// ``set`` appends arguments to nodes (``{"spike-source": "--max-planes 200"}``). Relative paths
/// in the nodes' arguments are taken from ``cwd`` (default: the graph file's folder, where dora
/// runs its nodes; the current folder for a dict), the process's working folder for the run.
/// Returns, for each ``node/output`` of ``collect``, the list of its messages in order, and under
/// ``"stages"`` the run's table of stages (time, messages, losses).
#[pyfunction]
#[pyo3(signature = (graph, *, set = None, collect = Vec::new(), cwd = None))]
pub fn run_graph<'py>(
    py: Python<'py>,
    graph: &Bound<'py, PyAny>,
    set: Option<&Bound<'py, PyDict>>,
    collect: Vec<String>,
    cwd: Option<PathBuf>,
) -> PyResult<Bound<'py, PyDict>> {
    let (mut g, dir) = if graph.is_instance_of::<PyDict>() {
        let text = py
            .import("json")?
            .call_method1("dumps", (graph,))?
            .extract::<String>()?;
        (
            GraphChain::from_yaml(&text).map_err(|e| errors::config(format!("graph: {e:#}")))?,
            None,
        )
    } else {
        let path: PathBuf = graph.extract()?;
        let g = GraphChain::read(&path).map_err(|e| errors::config(format!("{e:#}")))?;
        (
            g,
            path.canonicalize()
                .ok()
                .and_then(|p| p.parent().map(Path::to_path_buf)),
        )
    };
    if let Some(set) = set {
        for (id, extra) in set.iter() {
            let id: String = id.extract()?;
            let extra: String = extra.extract()?;
            g.append_args(&id, &words(&extra, &id)?)
                .map_err(|e| errors::config(format!("{e:#}")))?;
        }
    }
    let dir = cwd.or(dir);
    let collected: Vec<Mutex<Vec<Msg>>> = collect.iter().map(|_| Mutex::new(Vec::new())).collect();
    let here = std::env::current_dir().ok();
    if let Some(d) = &dir {
        std::env::set_current_dir(d)
            .map_err(|e| errors::config(format!("cwd {}: {e}", d.display())))?;
    }
    let outcome = threads::run(py, || -> eyre::Result<String> {
        let mut chain = g.chain()?;
        for (name, slot) in collect.iter().zip(&collected) {
            chain.tap(name, move |m| {
                slot.lock().unwrap_or_else(|p| p.into_inner()).push(m);
                Ok(())
            })?;
        }
        Ok(chain.run()?.table())
    });
    if let (Some(_), Some(h)) = (&dir, &here) {
        let _ = std::env::set_current_dir(h);
    }
    let table = outcome?.map_err(|e| errors::config(format!("{e:#}")))?;
    let d = PyDict::new(py);
    for (name, slot) in collect.iter().zip(collected) {
        let list = PyList::empty(py);
        for m in slot.into_inner().unwrap_or_else(|p| p.into_inner()) {
            list.append(message(py, m)?)?;
        }
        d.set_item(name, list)?;
    }
    d.set_item("stages", table)?;
    Ok(d)
}
