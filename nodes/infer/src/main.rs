//! dora node: reconstruction. Inputs, as the method declares ([`Method::inputs`]):
//! `representation` (Representation: `tfp`, `isi` or `stp`) and `events` (EventBatch: the `align`
//! node's event stream, cut at each window's `t_ref`). Output `frames` (Frame). Methods: `tfp`
//! (needs `tfp`), `tfi` (needs `isi`), `tfstp` (needs `stp`), `hf` (events), `cf` (events and
//! `tfp` or `isi`), `fusion` (events and `isi`). The two inputs of one window carry the window's sequence number; a window is
//! reconstructed when both have arrived, in order.
//!
//! `--method learned --model FILE` runs a NeuSpike-Net exported to ONNX (`neuspike_infer::learned`)
//! on the representations it reads, each its own input named as the represent output that makes
//! it: `spike_repr` (spike representation) and/or `event_integration`. The model is loaded, checked
//! against the graph's inputs and planned before the first message is read.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use dora_node_api::{DoraNode, Event, EventStream};
use ndarray::Axis;
use neuspike_infer::learned::{ConvPath, LearnedModel, LearnedOutput};
use neuspike_infer::{
    EventSlice, Method, Online, OnlineParams, SpikeInput, ThetaMode, Window,
    luminance_from_rate_into,
};
use neuspike_schemas::node::{self, output, send, send_end};
use neuspike_schemas::{
    EventBatch, Frame, FrameKind, Message, Representation, SeqStatus, SeqTracker, is_end_of_stream,
};

/// tract allocates every intermediate tensor afresh on each run; with the system allocator those
/// megabytes went back to the kernel and came back as page faults on every frame (measured with
/// `neuspike bench-model`: about a quarter of a base-8 network's time at 256x400). mimalloc keeps
/// them for the next frame.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Node arguments (the graph's `args:`).
#[derive(Debug, clap::Parser)]
#[command(
    name = "neuspike-infer",
    about = "Reconstructs frames from representations and events",
    args_override_self = true
)]
struct Args {
    /// Reconstruction method: tfp, tfi, tfstp, hf, cf, fusion, or learned (with `--model`).
    #[arg(long, default_value = "tfp", value_parser = parse_method)]
    method: NodeMethod,
    /// learned: the ONNX network (`models/*.onnx`).
    #[arg(long)]
    model: Option<PathBuf>,
    /// learned: how tract runs the convolutions: auto (time each path on the first frame of each
    /// size, keep the fastest), direct, im2col or blocked (neuspike's 3x3 kernel on wide rows).
    #[arg(long, default_value = "auto")]
    conv: ConvPath,
    /// Luminance per unit firing rate (overrides the calibration the spike source sends).
    #[arg(long)]
    lum_per_rate: Option<f64>,
    /// hf, cf: the DVS contrast threshold (log luminance per event).
    #[arg(long, default_value_t = 0.2)]
    contrast: f64,
    /// hf: cutoff of the high-pass filter, rad/s.
    #[arg(long, default_value_t = 5.0)]
    hf_cutoff_rad_s: f64,
    /// cf: gain of the complementary filter, rad/s.
    #[arg(long, default_value_t = 5.0)]
    cf_gain_rad_s: f64,
    /// fusion: where theta comes from: fixed, global or per-pixel.
    #[arg(long, default_value = "global", value_parser = parse_theta_mode)]
    theta_mode: ThetaMode,
    /// fusion: theta before any estimate.
    #[arg(long, default_value_t = 0.2)]
    theta_init: f64,
    /// cf, fusion: use the spike input of one window in this many; events carry the estimate in
    /// between.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    anchor_every: u32,
}

/// A classical method of the library, or the learned network.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum NodeMethod {
    Classical(Method),
    Learned,
}

impl std::fmt::Display for NodeMethod {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            NodeMethod::Classical(m) => m.fmt(f),
            NodeMethod::Learned => f.write_str("learned"),
        }
    }
}

fn parse_method(s: &str) -> Result<NodeMethod, String> {
    match s {
        "learned" => Ok(NodeMethod::Learned),
        _ => s
            .parse()
            .map(NodeMethod::Classical)
            .map_err(|e| format!("{e}, learned")),
    }
}

fn parse_theta_mode(s: &str) -> Result<ThetaMode, String> {
    match s {
        "fixed" => Ok(ThetaMode::Fixed),
        "global" => Ok(ThetaMode::Global),
        "per-pixel" => Ok(ThetaMode::PerPixel),
        _ => Err(format!("{s:?} is not one of fixed, global, per-pixel")),
    }
}

impl Args {
    fn online(&self) -> OnlineParams {
        OnlineParams {
            contrast: self.contrast,
            hf_cutoff_rad_s: self.hf_cutoff_rad_s,
            cf_gain_rad_s: self.cf_gain_rad_s,
            theta_mode: self.theta_mode,
            theta_init: self.theta_init,
            anchor_every: self.anchor_every,
        }
    }

    /// Checks the settings and that the graph connects what the method reads; loads the learned
    /// model, checks it runs, and returns it.
    fn check(&self, inputs: &[String]) -> eyre::Result<Option<LearnedModel>> {
        if let Some(g) = self.lum_per_rate
            && !(g.is_finite() && g > 0.0)
        {
            eyre::bail!("infer: `lum-per-rate` = {g} is invalid: must be finite and > 0");
        }
        let has = |id: &str| inputs.iter().any(|i| i == id);
        let method = match self.method {
            NodeMethod::Learned => return self.load_model(&has).map(Some),
            NodeMethod::Classical(m) => m,
        };
        if self.model.is_some() {
            eyre::bail!("infer: `--model` is for `--method learned`, not `{method}`");
        }
        Online::new(method, self.online()).map_err(|e| eyre::eyre!("infer: {e}"))?;
        let needs = method.inputs();
        if !needs.representations.is_empty() && !has("representation") {
            eyre::bail!(
                "infer: method `{method}` needs an input `representation` ({} from the represent node)",
                needs.representations.join(" or ")
            );
        }
        if needs.events && !has("events") {
            eyre::bail!(
                "infer: method `{method}` needs an input `events` (the align node's `events` output)"
            );
        }
        Ok(None)
    }

    /// Loads `--model`, checks that the graph feeds every input it reads, and plans it once on a
    /// small frame so that a network tract cannot run fails now, not at the first window.
    fn load_model(&self, has: &dyn Fn(&str) -> bool) -> eyre::Result<LearnedModel> {
        let Some(path) = &self.model else {
            eyre::bail!(
                "infer: method `learned` needs `--model FILE` (an ONNX network, e.g. models/neuspike-fused-8.onnx)"
            );
        };
        let mut model = LearnedModel::load(path).map_err(|e| eyre::eyre!("infer: {e}"))?;
        model.set_conv_path(self.conv);
        for i in model.inputs() {
            if !has(i.input_id()) {
                eyre::bail!(
                    "infer: model {} reads `{}`: connect an input `{}` (represent's `{}` output)",
                    path.display(),
                    i.onnx_name(),
                    i.input_id(),
                    i.input_id()
                );
            }
        }
        let probes: Vec<ndarray::Array3<f32>> = model
            .channels()
            .iter()
            .map(|&c| ndarray::Array3::zeros((c, 8, 8)))
            .collect();
        let views: Vec<_> = probes.iter().map(|a| a.view()).collect();
        model.run(&views).map_err(|e| eyre::eyre!("infer: {e}"))?;
        Ok(model)
    }
}

fn main() -> eyre::Result<()> {
    node::init_logging();
    let args: Args = node::parse_config("infer")?;
    let (node, events) = DoraNode::init_from_env()?;
    let inputs: Vec<String> = node
        .node_config()
        .inputs
        .keys()
        .map(|k| k.to_string())
        .collect();
    let model = args.check(&inputs)?;
    node::run_on_rayon("infer", || run(node, events, &args, model))
}

/// The inputs of one window gathered so far: the representations by slot (see
/// [`Reconstructor::rep_ids`]) and the event batch.
#[derive(Default)]
struct Pending {
    reps: BTreeMap<usize, Representation>,
    events: Option<EventBatch>,
}

/// What makes the frames. A node holds one, so the variants' sizes do not matter.
#[allow(clippy::large_enum_variant)]
enum Engine {
    Online(Online),
    Learned(Box<LearnedModel>),
}

/// One input's stream state.
#[derive(Default)]
struct Input {
    seq: SeqTracker,
    ended: bool,
}

impl Input {
    fn observe(&mut self, name: &str, seq: u64) {
        if let SeqStatus::Gap { missing } = self.seq.observe(seq) {
            tracing::error!(input = name, seq, missing, "messages lost before this one");
        }
    }
}

struct Reconstructor {
    engine: Engine,
    args_lum_per_rate: Option<f64>,
    method: NodeMethod,
    /// The input ids that carry representations, one slot each.
    rep_ids: Vec<&'static str>,
    wants_events: bool,
    pending: BTreeMap<u64, Pending>,
    frames: u64,
    incomplete: u64,
}

impl Reconstructor {
    fn complete(&self, p: &Pending) -> bool {
        p.reps.len() == self.rep_ids.len() && (!self.wants_events || p.events.is_some())
    }

    /// Reconstructs every window whose inputs are all in, in order. A window that is still
    /// incomplete when a later one is complete lost a message (inputs arrive in order): it is
    /// dropped and counted.
    fn drain(&mut self, node: &mut DoraNode, flush: bool) -> eyre::Result<()> {
        let done: Vec<u64> = self
            .pending
            .iter()
            .filter(|(_, p)| self.complete(p))
            .map(|(&k, _)| k)
            .collect();
        let Some(&last_done) = done.last() else {
            if flush {
                self.incomplete += self.pending.len() as u64;
                self.pending.clear();
            }
            return Ok(());
        };
        let limit = if flush { u64::MAX } else { last_done };
        while let Some(entry) = self.pending.first_entry() {
            if *entry.key() > limit {
                break;
            }
            let (seq, p) = entry.remove_entry();
            if !self.complete(&p) {
                tracing::error!(seq, "window incomplete (a message was lost): no frame");
                self.incomplete += 1;
                continue;
            }
            self.reconstruct(node, seq, &p)?;
        }
        Ok(())
    }

    fn reconstruct(&mut self, node: &mut DoraNode, seq: u64, p: &Pending) -> eyre::Result<()> {
        let start = Instant::now();
        let (t_ref_ns, data) = match &mut self.engine {
            Engine::Online(online) => {
                let method = match self.method {
                    NodeMethod::Classical(m) => m,
                    NodeMethod::Learned => {
                        eyre::bail!("infer: internal: learned method without a model")
                    }
                };
                classical(online, method, self.args_lum_per_rate, seq, p)?
            }
            Engine::Learned(model) => learned(model, self.args_lum_per_rate, seq, p)?,
        };
        let frame = Frame {
            kind: FrameKind::Reconstruction,
            method: self.method.to_string(),
            t_ref_ns,
            compute_ns: i64::try_from(start.elapsed().as_nanos()).unwrap_or(i64::MAX),
            seq,
            data,
        };
        send(node, &output("frames"), &frame)?;
        self.frames = seq + 1;
        Ok(())
    }
}

/// One window of a classical method.
fn classical(
    online: &mut Online,
    method: Method,
    args_lum_per_rate: Option<f64>,
    seq: u64,
    p: &Pending,
) -> eyre::Result<(i64, ndarray::Array2<f32>)> {
    let rep = p.reps.get(&0);
    let spikes = rep.map(|r| -> eyre::Result<SpikeInput<'_>> {
        Ok(match r.kind.as_str() {
            "tfp" => SpikeInput::Rate(r.data.index_axis(Axis(0), 0)),
            "stp" => SpikeInput::StpRate(r.data.index_axis(Axis(0), 0)),
            "isi" if r.data.dim().0 >= 2 => SpikeInput::Isi {
                isi: r.data.index_axis(Axis(0), 0),
                valid: r.data.index_axis(Axis(0), 1),
            },
            other => eyre::bail!(
                "infer: method `{}` cannot use the `{other}` representation (seq {seq}); it takes {}",
                method,
                method.inputs().representations.join(" or ")
            ),
        })
    });
    let spikes = spikes.transpose()?;
    let lum_per_rate =
        args_lum_per_rate.or_else(|| rep.and_then(|r| r.params.get("lum_per_rate").copied()));
    let events = p.events.as_ref().map(|b| {
        (
            EventSlice {
                t_ns: &b.t_ns,
                x: &b.x,
                y: &b.y,
                polarity: &b.polarity,
            },
            (b.height, b.width),
        )
    });
    let t_ref_ns = match (rep, &p.events) {
        (Some(r), _) => r.t_ref_ns,
        (None, Some(b)) => b.t_end_ns,
        (None, None) => eyre::bail!("infer: window {seq} has no input"),
    };
    if let (Some(r), Some(b)) = (rep, &p.events)
        && b.t_end_ns != r.t_ref_ns
    {
        eyre::bail!(
            "infer: window {seq}: the event batch ends at {} ns but the representation is at t_ref {} ns (connect align's `events` output, which cuts the stream at each t_ref)",
            b.t_end_ns,
            r.t_ref_ns
        );
    }
    let window = Window {
        t_ref_ns,
        spikes,
        lum_per_rate,
        events,
    };
    let data = online.frame(&window).map_err(|e| {
        let hint = if lum_per_rate.is_none() && spikes.is_some() {
            " (the representation carries no `lum_per_rate` and the graph sets no `--lum-per-rate`)"
        } else {
            ""
        };
        eyre::eyre!("infer: window {seq} at {t_ref_ns} ns: {e}{hint}")
    })?;
    Ok((t_ref_ns, data))
}

/// One window of the learned method: the network's rate, calibrated to luminance as TFP's (or
/// the event-only network's luminance, clipped to [0, 1] the same way).
fn learned(
    model: &mut LearnedModel,
    args_lum_per_rate: Option<f64>,
    seq: u64,
    p: &Pending,
) -> eyre::Result<(i64, ndarray::Array2<f32>)> {
    let reps: Vec<&Representation> = p.reps.values().collect();
    for (r, i) in reps.iter().zip(model.inputs()) {
        if r.kind != i.representation() {
            eyre::bail!(
                "infer: input `{}` (seq {seq}) carries the `{}` representation; model {} reads `{}` there",
                i.input_id(),
                r.kind,
                model.path().display(),
                i.representation()
            );
        }
    }
    let t_ref_ns = reps[0].t_ref_ns;
    if let Some(r) = reps.iter().find(|r| r.t_ref_ns != t_ref_ns) {
        eyre::bail!(
            "infer: window {seq}: representations at t_ref {} ns and {} ns",
            t_ref_ns,
            r.t_ref_ns
        );
    }
    let views: Vec<_> = reps.iter().map(|r| r.data.view()).collect();
    let image = model
        .run(&views)
        .map_err(|e| eyre::eyre!("infer: window {seq} at {t_ref_ns} ns: {e}"))?;
    let gain = match model.output() {
        LearnedOutput::Luminance => 1.0,
        LearnedOutput::Rate => args_lum_per_rate
            .or_else(|| reps.iter().find_map(|r| r.params.get("lum_per_rate").copied()))
            .ok_or_else(|| {
                eyre::eyre!(
                    "infer: window {seq}: no calibration (the representations carry no `lum_per_rate` and the graph sets no `--lum-per-rate`)"
                )
            })?,
    };
    let mut data = ndarray::Array2::<f32>::zeros(image.dim());
    luminance_from_rate_into(image.view(), gain, 1.0, data.view_mut())
        .map_err(|e| eyre::eyre!("infer: window {seq}: {e}"))?;
    Ok((t_ref_ns, data))
}

fn run(
    mut node: DoraNode,
    mut events: EventStream,
    args: &Args,
    model: Option<LearnedModel>,
) -> eyre::Result<()> {
    let (engine, rep_ids, wants_events) = match (args.method, model) {
        (NodeMethod::Classical(m), _) => {
            let needs = m.inputs();
            let ids = if needs.representations.is_empty() {
                vec![]
            } else {
                vec!["representation"]
            };
            (
                Engine::Online(Online::new(m, args.online())?),
                ids,
                needs.events,
            )
        }
        (NodeMethod::Learned, Some(model)) => {
            let ids = model.inputs().iter().map(|i| i.input_id()).collect();
            (Engine::Learned(Box::new(model)), ids, false)
        }
        (NodeMethod::Learned, None) => eyre::bail!("infer: method `learned` needs `--model FILE`"),
    };
    let mut r = Reconstructor {
        engine,
        args_lum_per_rate: args.lum_per_rate,
        method: args.method,
        rep_ids,
        wants_events,
        pending: BTreeMap::new(),
        frames: 0,
        incomplete: 0,
    };
    // One stream state per representation slot, then the event stream's.
    let mut inputs: Vec<Input> = (0..=r.rep_ids.len()).map(|_| Input::default()).collect();
    let ev_slot = r.rep_ids.len();
    let mut announced = 0u64;
    while let Some(event) = events.recv() {
        match event {
            Event::Input { id, metadata, data } => {
                let meta = &metadata.parameters;
                let id: &str = id.as_ref();
                let slot = match r.rep_ids.iter().position(|&i| i == id) {
                    Some(slot) => slot,
                    None if id == "events" && r.wants_events => ev_slot,
                    None => {
                        tracing::warn!(input = id, method = %args.method, "input not used by the method");
                        continue;
                    }
                };
                let input = &mut inputs[slot];
                if let Some(n) = is_end_of_stream(meta) {
                    let lost = input.seq.end(n);
                    if lost > 0 {
                        tracing::error!(input = id, lost, "messages lost at the end of the stream");
                    }
                    input.ended = true;
                    announced = announced.max(n);
                } else if slot < ev_slot {
                    let rep = Representation::from_arrow(meta, data.as_array())?;
                    let seq = rep.seq;
                    input.observe(id, seq);
                    r.pending.entry(seq).or_default().reps.insert(slot, rep);
                } else {
                    let batch = EventBatch::from_arrow(meta, data.as_array())?;
                    let seq = batch.seq;
                    input.observe(id, seq);
                    r.pending.entry(seq).or_default().events = Some(batch);
                }
                r.drain(&mut node, false)?;
                let ended = |slot: usize| inputs[slot].ended;
                if (0..ev_slot).all(ended) && (!r.wants_events || ended(ev_slot)) {
                    break;
                }
            }
            // dora's scheduler may yield `InputClosed` and `Stop` before the last inputs: only the
            // end-of-stream markers, or the end of the event stream, end the loop.
            Event::InputClosed { id } => tracing::debug!(input = %id, "input closed"),
            Event::Stop(cause) => tracing::debug!(?cause, "stop received; draining the input"),
            _ => {}
        }
    }
    r.drain(&mut node, true)?;
    let count = r.frames.max(announced);
    send_end::<Frame>(&mut node, &output("frames"), count)?;
    let lost: u64 = inputs.iter().map(|i| i.seq.missing()).sum();
    match &r.engine {
        Engine::Online(online) => {
            let s = online.stats();
            tracing::info!(
                frames = s.frames,
                announced = count,
                incomplete = r.incomplete,
                lost,
                events = s.events,
                method = %args.method,
                clamped = s.frame.clamped,
                exp_overflow = s.frame.exp_overflow,
                "infer finished"
            );
        }
        Engine::Learned(model) => tracing::info!(
            frames = r.frames,
            announced = count,
            incomplete = r.incomplete,
            lost,
            model = %model.path().display(),
            conv = %model.conv_path_in_use().unwrap_or_default(),
            "infer finished"
        ),
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array3;
    use neuspike_infer::learned::LearnedInput;
    use neuspike_schemas::testing::{CannedInputs, output_ids};

    fn rep(kind: &str, value: f32, seq: u64) -> Representation {
        let mut data = Array3::from_elem((if kind == "isi" { 2 } else { 1 }, 3, 4), value);
        if kind == "isi" {
            data.index_axis_mut(Axis(0), 1).fill(1.0); // every ISI measured
        }
        Representation {
            kind: kind.into(),
            t_ref_ns: 1_000_000 * (seq as i64 + 1),
            seq,
            params: [("lum_per_rate".to_string(), 2.0)].into_iter().collect(),
            data,
        }
    }

    /// The event stream's batch of window `seq`: `[seq ms, seq + 1 ms)`, with `n` ON events at
    /// pixel (1, 2).
    fn batch(seq: u64, n: usize, (h, w): (usize, usize)) -> EventBatch {
        let t0 = 1_000_000 * seq as i64;
        let mut b = EventBatch::empty(w, h, t0, t0 + 1_000_000, seq);
        for k in 0..n {
            b.push(neuspike_schemas::Event {
                t_ns: t0 + 1_000 * k as i64,
                x: 1,
                y: 2,
                polarity: 1,
            });
        }
        b
    }

    fn args(method: Method) -> Args {
        Args {
            method: NodeMethod::Classical(method),
            model: None,
            conv: ConvPath::Auto,
            lum_per_rate: None,
            contrast: 0.2,
            hf_cutoff_rad_s: 5.0,
            cf_gain_rad_s: 5.0,
            theta_mode: ThetaMode::Global,
            theta_init: 0.2,
            anchor_every: 1,
        }
    }

    fn values(frame: &neuspike_schemas::testing::OutputJson) -> Vec<f64> {
        frame["data"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect()
    }

    #[test]
    fn tfp_frames_use_the_calibration() {
        let dir = tempfile::tempdir().unwrap();
        let mut c = CannedInputs::new(dir.path());
        c.message("representation", &rep("tfp", 0.25, 0)).unwrap();
        c.message("representation", &rep("tfp", 0.25, 1)).unwrap();
        c.end::<Representation>("representation", 2).unwrap();
        let out = c
            .run(|node, events| run(node, events, &args(Method::Tfp), None))
            .unwrap();
        assert_eq!(output_ids(&out), vec!["frames"; 3]);
        let v = values(&out[0]);
        assert_eq!(v.len(), 12);
        assert!(v.iter().all(|v| (v - 0.5).abs() < 1e-6), "{v:?}");
    }

    #[test]
    fn wrong_representation_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let mut c = CannedInputs::new(dir.path());
        c.message("representation", &rep("tfp", 0.25, 0)).unwrap();
        let err = c
            .run(|node, events| run(node, events, &args(Method::Tfi), None))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("`tfi` needs the `isi`") && err.contains("got `tfp`"),
            "{err}"
        );
    }

    #[test]
    fn hf_reconstructs_from_the_event_stream_alone() {
        let dir = tempfile::tempdir().unwrap();
        let mut c = CannedInputs::new(dir.path());
        c.message("events", &batch(0, 0, (3, 4))).unwrap();
        c.message("events", &batch(1, 3, (3, 4))).unwrap();
        c.end::<EventBatch>("events", 2).unwrap();
        let out = c
            .run(|node, events| run(node, events, &args(Method::Hf), None))
            .unwrap();
        assert_eq!(output_ids(&out), vec!["frames"; 3]);
        let (first, second) = (values(&out[0]), values(&out[1]));
        // No events: every pixel at rest. Three ON events at (x 1, y 2): brighter there only.
        assert!(first.iter().all(|&v| v == first[0]), "{first:?}");
        let hit = 2 * 4 + 1;
        assert!(second[hit] > first[hit] * 1.5, "{second:?}");
        assert!(
            second
                .iter()
                .enumerate()
                .all(|(i, &v)| i == hit || v == first[0])
        );
    }

    #[test]
    fn fusion_pairs_windows_by_sequence_whatever_the_arrival_order() {
        let dir = tempfile::tempdir().unwrap();
        let mut c = CannedInputs::new(dir.path());
        c.message("events", &batch(0, 0, (3, 4))).unwrap();
        c.message("events", &batch(1, 2, (3, 4))).unwrap();
        c.message("representation", &rep("isi", 8.0, 0)).unwrap();
        c.end::<EventBatch>("events", 2).unwrap();
        // Window 1's ISI says invalid nowhere but is a bound-free measurement of the same light:
        // the anchor is re-measured; the two events in between count into theta's estimate.
        c.message("representation", &rep("isi", 8.0, 1)).unwrap();
        c.end::<Representation>("representation", 2).unwrap();
        let out = c
            .run(|node, events| run(node, events, &args(Method::Fusion), None))
            .unwrap();
        assert_eq!(output_ids(&out), vec!["frames"; 3]);
        for f in &out[..2] {
            let v = values(f);
            // TFI of an 8-tick ISI at lum_per_rate 2: 0.25.
            assert!(v.iter().all(|v| (v - 0.25).abs() < 1e-6), "{v:?}");
        }
    }

    #[test]
    fn event_sensor_of_another_size_is_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let mut c = CannedInputs::new(dir.path());
        c.message("events", &batch(0, 0, (260, 346))).unwrap();
        c.message("representation", &rep("isi", 8.0, 0)).unwrap();
        let err = c
            .run(|node, events| run(node, events, &args(Method::Fusion), None))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("event sensor") && err.contains("[260, 346]"),
            "{err}"
        );
    }

    #[test]
    fn a_graph_without_the_inputs_a_method_reads_is_refused_at_start_up() {
        let only_rep = ["representation".to_string()];
        let err = args(Method::Fusion)
            .check(&only_rep)
            .unwrap_err()
            .to_string();
        assert!(err.contains("`fusion` needs an input `events`"), "{err}");
        let only_events = ["events".to_string()];
        let err = args(Method::Cf)
            .check(&only_events)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("`representation`") && err.contains("tfp or isi"),
            "{err}"
        );
        assert!(args(Method::Hf).check(&only_events).is_ok());
        let mut bad = args(Method::Hf);
        bad.contrast = -1.0;
        let err = bad.check(&only_events).unwrap_err().to_string();
        assert!(err.contains("contrast") && err.contains("-1"), "{err}");
    }

    fn models_dir() -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../models")
    }

    /// The smallest shipped model whose inputs are `inputs`.
    fn shipped_model(inputs: &[LearnedInput]) -> PathBuf {
        let mut models: Vec<PathBuf> = std::fs::read_dir(models_dir())
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "onnx"))
            .collect();
        models.sort_by_key(|p| (std::fs::metadata(p).unwrap().len(), p.clone()));
        models
            .into_iter()
            .find(|p| LearnedModel::load(p).unwrap().inputs() == inputs)
            .unwrap_or_else(|| panic!("a model reading {inputs:?} in models/"))
    }

    fn fused_model() -> PathBuf {
        shipped_model(&[LearnedInput::Spike, LearnedInput::Events])
    }

    fn learned_args(model: PathBuf) -> Args {
        Args {
            method: NodeMethod::Learned,
            model: Some(model),
            ..args(Method::Tfp)
        }
    }

    /// A representation of `kind` whose values are a fixed pattern (16 x 24, 32 channels).
    fn pattern(kind: &str, seq: u64) -> Representation {
        let data = Array3::from_shape_fn((32, 16, 24), |(c, y, x)| {
            ((c * 5 + y * 3 + x) % 7) as f32 / 6.0
        });
        Representation {
            kind: kind.into(),
            t_ref_ns: 1_000_000 * (seq as i64 + 1),
            seq,
            params: [("lum_per_rate".to_string(), 2.0)].into_iter().collect(),
            data,
        }
    }

    #[test]
    fn learned_frames_are_the_network_rate_calibrated() {
        let path = fused_model();
        let dir = tempfile::tempdir().unwrap();
        let mut c = CannedInputs::new(dir.path());
        // Window 0's two representations arrive in either order; window 1 is spike first.
        c.message("event_integration", &pattern("event-integration", 0))
            .unwrap();
        c.message("spike_repr", &pattern("spike-repr", 0)).unwrap();
        c.message("spike_repr", &pattern("spike-repr", 1)).unwrap();
        c.message("event_integration", &pattern("event-integration", 1))
            .unwrap();
        c.end::<Representation>("spike_repr", 2).unwrap();
        c.end::<Representation>("event_integration", 2).unwrap();
        let inputs = ["spike_repr".to_string(), "event_integration".to_string()];
        let a = learned_args(path.clone());
        let model = a.check(&inputs).unwrap();
        let out = c.run(|node, events| run(node, events, &a, model)).unwrap();
        assert_eq!(output_ids(&out), vec!["frames"; 3]);
        let mut direct = LearnedModel::load(&path).unwrap();
        let (s, e) = (pattern("spike-repr", 0), pattern("event-integration", 0));
        let rate = direct.run(&[s.data.view(), e.data.view()]).unwrap();
        for f in &out[..2] {
            let v = values(f);
            assert_eq!(v.len(), 16 * 24);
            for (got, r) in v.iter().zip(rate.iter()) {
                let want = (f64::from(*r) * 2.0).clamp(0.0, 1.0);
                assert!((got - want).abs() < 1e-6, "{got} vs {want}");
            }
        }
    }

    #[test]
    fn the_event_only_network_gives_luminance_without_the_spike_calibration() {
        let path = shipped_model(&[LearnedInput::Events]);
        let dir = tempfile::tempdir().unwrap();
        let mut c = CannedInputs::new(dir.path());
        c.message("event_integration", &pattern("event-integration", 0))
            .unwrap();
        c.end::<Representation>("event_integration", 1).unwrap();
        let inputs = ["event_integration".to_string()];
        let a = learned_args(path.clone());
        let model = a.check(&inputs).unwrap();
        assert_eq!(model.as_ref().unwrap().output(), LearnedOutput::Luminance);
        let out = c.run(|node, events| run(node, events, &a, model)).unwrap();
        assert_eq!(output_ids(&out), vec!["frames"; 2]);
        let e = pattern("event-integration", 0);
        let lum = LearnedModel::load(&path)
            .unwrap()
            .run(&[e.data.view()])
            .unwrap();
        let v = values(&out[0]);
        assert_eq!(v.len(), lum.len());
        // The pattern says lum_per_rate 2; a luminance output must not be doubled.
        for (got, l) in v.iter().zip(lum.iter()) {
            assert!((got - f64::from(*l)).abs() < 1e-6, "{got} vs {l}");
        }
    }

    #[test]
    fn learned_refuses_a_representation_on_the_wrong_input() {
        let dir = tempfile::tempdir().unwrap();
        let mut c = CannedInputs::new(dir.path());
        c.message("spike_repr", &pattern("event-integration", 0))
            .unwrap();
        c.message("event_integration", &pattern("event-integration", 0))
            .unwrap();
        let inputs = ["spike_repr".to_string(), "event_integration".to_string()];
        let a = learned_args(fused_model());
        let model = a.check(&inputs).unwrap();
        let err = c
            .run(|node, events| run(node, events, &a, model))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("`spike_repr`")
                && err.contains("`event-integration`")
                && err.contains("reads `spike-repr`"),
            "{err}"
        );
    }

    #[test]
    fn learned_is_checked_at_start_up() {
        let both = ["spike_repr".to_string(), "event_integration".to_string()];
        // No model.
        let mut a = learned_args(fused_model());
        a.model = None;
        let err = a.check(&both).unwrap_err().to_string();
        assert!(err.contains("--model"), "{err}");
        // A missing file, named.
        let err = learned_args(PathBuf::from("/nonexistent/net.onnx"))
            .check(&both)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("/nonexistent/net.onnx") && err.contains("cannot read"),
            "{err}"
        );
        // A graph that does not feed an input the model reads.
        let err = learned_args(fused_model())
            .check(&["spike_repr".to_string()])
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("connect an input `event_integration`"),
            "{err}"
        );
        // --model with a classical method.
        let mut a = args(Method::Tfp);
        a.model = Some(fused_model());
        let err = a
            .check(&["representation".to_string()])
            .unwrap_err()
            .to_string();
        assert!(err.contains("`--model` is for `--method learned`"), "{err}");
        // And the method names: learned is accepted, the list of names says so.
        assert_eq!(parse_method("learned"), Ok(NodeMethod::Learned));
        assert!(parse_method("nope").unwrap_err().contains("learned"));
    }
}
