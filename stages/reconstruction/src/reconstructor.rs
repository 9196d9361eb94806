//! The infer node's stage: the settings, the check of what the graph connects, the join of a
//! window's inputs by sequence number, and the frame of each complete window, by a classical
//! method ([`Online`]) or the learned network ([`LearnedModel`]).

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use ndarray::{Array2, Array3, Axis};
use neuspike_schemas::{
    AlignedWindow, EventBatch, Frame, FrameKind, Representation, RepresentationKind,
};

use crate::auto::Auto;
use neuspike_representations::Representer;

use crate::learned::{ConvPath, LearnedModel, LearnedOutput};
use crate::{
    EventSlice, InferError, Method, Online, OnlineParams, SpikeInput, ThetaMode, Window,
    luminance_from_rate_into,
};

/// The infer stage's settings (the node's `args:`).
#[derive(Clone, Debug, clap::Args)]
pub struct InferConfig {
    /// Reconstruction method: tfp, tfi, tfstp, hf, cf, fusion, or learned (with `--model`).
    #[arg(long, default_value = "tfp")]
    pub method: Method,
    /// learned: the ONNX network (`models/*.onnx`).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// learned: how tract runs the convolutions: auto (time each path on the first frame of each
    /// size, keep the fastest), direct, im2col or blocked (neuspike's 3x3 kernel on wide rows).
    #[arg(long, default_value = "auto")]
    pub conv: ConvPath,
    /// learned: the precision of the 3x3 convolutions: f32; bf16 (inputs and weights rounded
    /// to bf16, sums in f32, on AVX-512 BF16 or plain loops; bf16-avx512 or bf16-portable names
    /// one); or int8 (each frame's input quantised per channel, on the widest 8-bit path this
    /// CPU has: AMX tiles, AVX-512 VNNI, or plain loops; int8-amx, int8-vnni or int8-portable
    /// names one). The other operators stay f32; neuspike's kernels only, so --conv auto or
    /// blocked.
    #[arg(long, default_value = "f32")]
    pub precision: crate::learned::Precision,
    /// learned and auto: the threads a network's convolutions split each frame across
    /// (tract's pool, one for the whole process; at most 64). Unset, the process's setting
    /// stands: one thread, the stage's own, unless a host set it.
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..=64))]
    pub threads: Option<u16>,
    /// Luminance per unit firing rate (overrides the calibration the spike source sends).
    #[arg(long)]
    pub lum_per_rate: Option<f64>,
    /// hf, cf: the DVS contrast threshold (log luminance per event).
    #[arg(long, default_value_t = 0.2)]
    pub contrast: f64,
    /// hf: cutoff of the high-pass filter, rad/s.
    #[arg(long, default_value_t = 5.0)]
    pub hf_cutoff_rad_s: f64,
    /// cf: gain of the complementary filter, rad/s.
    #[arg(long, default_value_t = 5.0)]
    pub cf_gain_rad_s: f64,
    /// fusion: where theta comes from: fixed, global or per-pixel.
    #[arg(long, default_value = "global")]
    pub theta_mode: ThetaMode,
    /// fusion: theta before any estimate.
    #[arg(long, default_value_t = 0.2)]
    pub theta_init: f64,
    /// cf, fusion: use the spike input of one window in this many; events carry the estimate in
    /// between.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub anchor_every: u32,
    /// auto: the policy (`neuspike bench --fit-policy`).
    #[arg(long, default_value = "models/policy.yml")]
    pub policy: PathBuf,
    /// auto: the folder of the networks the policy names (`<name>.onnx`).
    #[arg(long, default_value = "models")]
    pub models: PathBuf,
    /// auto: a deadline per frame, milliseconds: the most accurate method whose cost, measured
    /// on this machine as it runs, fits; cheaper ones under load.
    #[arg(long)]
    pub budget_ms: Option<f64>,
    /// auto: the stream has no events (a spike recording alone): choose among the methods that
    /// read spikes only.
    #[arg(long)]
    pub spikes_only: bool,
    /// auto: the planes of align's windows, when fewer than the policy's longest method reads
    /// (a short recording): the methods that need more are left out.
    #[arg(long)]
    pub window_planes: Option<usize>,
    /// auto: choose per region, in tiles of `WxH` pixels (e.g. `80x50`): each tile takes the
    /// method its own statistics choose, a tile without events reuses the last frame's pixels,
    /// and a network runs only over its tiles.
    #[arg(long, value_parser = parse_tiles)]
    pub regions: Option<(usize, usize)>,
}

/// `--regions`' parser: `WxH`, both at least 1.
fn parse_tiles(text: &str) -> Result<(usize, usize), String> {
    let bad = || format!("{text:?}: expected WIDTHxHEIGHT in pixels, e.g. 80x50");
    let (w, h) = text.split_once('x').ok_or_else(bad)?;
    let w: usize = w.trim().parse().map_err(|_| bad())?;
    let h: usize = h.trim().parse().map_err(|_| bad())?;
    if w == 0 || h == 0 {
        return Err(bad());
    }
    Ok((w, h))
}

impl Default for InferConfig {
    fn default() -> Self {
        let p = OnlineParams::default();
        InferConfig {
            method: Method::Tfp,
            model: None,
            conv: ConvPath::default(),
            precision: crate::learned::Precision::F32,
            threads: None,
            lum_per_rate: None,
            contrast: p.contrast,
            hf_cutoff_rad_s: p.hf_cutoff_rad_s,
            cf_gain_rad_s: p.cf_gain_rad_s,
            theta_mode: p.theta_mode,
            theta_init: p.theta_init,
            anchor_every: p.anchor_every,
            policy: PathBuf::from("models/policy.yml"),
            models: PathBuf::from("models"),
            budget_ms: None,
            spikes_only: false,
            window_planes: None,
            regions: None,
        }
    }
}

/// The input that carries a classical method's representation.
pub const REPRESENTATION: &str = "representation";
/// The input that carries align's event stream.
pub const EVENTS: &str = "events";
/// The input that carries align's windows (`auto`).
pub const WINDOWS: &str = "windows";

impl InferConfig {
    /// The settings of the classical methods.
    pub fn online(&self) -> OnlineParams {
        OnlineParams {
            contrast: self.contrast,
            hf_cutoff_rad_s: self.hf_cutoff_rad_s,
            cf_gain_rad_s: self.cf_gain_rad_s,
            theta_mode: self.theta_mode,
            theta_init: self.theta_init,
            anchor_every: self.anchor_every,
        }
    }

    /// Checks the settings and that the graph's `inputs` carry what the method reads; for the
    /// learned method, loads the model, checks the graph feeds every input it reads, and runs it
    /// once on a small frame so that a network tract cannot run fails now, not at the first
    /// window. Returns the stage, ready for the first window.
    pub fn reconstructor(&self, inputs: &[String]) -> Result<Reconstructor, InferError> {
        if let Some(g) = self.lum_per_rate
            && !(g.is_finite() && g > 0.0)
        {
            return Err(InferError::Param {
                name: "lum-per-rate",
                value: g,
                reason: "must be finite and > 0",
            });
        }
        let has = |id: &str| inputs.iter().any(|i| i == id);
        if let Some(n) = self.threads
            && matches!(self.method, Method::Auto | Method::Learned)
        {
            crate::learned::set_threads(usize::from(n));
        }
        if self.method == Method::Auto {
            if !has(WINDOWS) {
                return Err(InferError::Wiring(format!(
                    "method `auto` needs an input `{WINDOWS}` (the align node's `windows` output)"
                )));
            }
            let auto = Auto::new(
                &self.policy,
                &self.models,
                self.budget_ms,
                self.lum_per_rate,
                self.conv,
            )?
            .restrict(self.spikes_only, self.window_planes)?;
            let auto = match self.regions {
                Some((w, h)) => auto.with_regions(w, h)?,
                None => auto,
            };
            let mut r = Reconstructor::new(Engine::Auto(Box::new(auto)), self, vec![], false);
            r.wants_window = true;
            return Ok(r);
        }
        if self.method == Method::Learned {
            let from_windows = has(WINDOWS);
            let model = self.load_model(&has, from_windows)?;
            if from_windows {
                // Its representations made here of align's windows: the spike one read from
                // the window's packed planes (`LearnedModel::run_window`).
                let represent = Representer::new(model.represent_config())
                    .map_err(|e| InferError::Wiring(e.to_string()))?;
                let mut r =
                    Reconstructor::new(Engine::Learned(Box::new(model)), self, vec![], false);
                r.represent = Some(Box::new(represent));
                r.wants_window = true;
                return Ok(r);
            }
            let rep_ids = model.inputs().iter().map(|i| i.input_id()).collect();
            return Ok(Reconstructor::new(
                Engine::Learned(Box::new(model)),
                self,
                rep_ids,
                false,
            ));
        }
        let method = self.method;
        if self.model.is_some() {
            return Err(InferError::Wiring(format!(
                "`--model` is for `--method learned`, not `{method}`"
            )));
        }
        let online = Online::new(method, self.online())?;
        let needs = method.inputs();
        if !needs.representations.is_empty() && !has(REPRESENTATION) {
            let kinds: Vec<&str> = needs.representations.iter().map(|k| k.name()).collect();
            return Err(InferError::Wiring(format!(
                "method `{method}` needs an input `{REPRESENTATION}` ({} from the represent node)",
                kinds.join(" or ")
            )));
        }
        if needs.events && !has(EVENTS) {
            return Err(InferError::Wiring(format!(
                "method `{method}` needs an input `{EVENTS}` (the align node's `events` output)"
            )));
        }
        let rep_ids = if needs.representations.is_empty() {
            vec![]
        } else {
            vec![REPRESENTATION]
        };
        Ok(Reconstructor::new(
            Engine::Online(online),
            self,
            rep_ids,
            needs.events,
        ))
    }

    /// The network of `--model`, checked against what the graph connects: each of its
    /// representations, or (`from_windows`) align's windows and none of them.
    fn load_model(
        &self,
        has: &dyn Fn(&str) -> bool,
        from_windows: bool,
    ) -> Result<LearnedModel, InferError> {
        let Some(path) = &self.model else {
            return Err(InferError::NeedsModel);
        };
        let mut model = LearnedModel::load(path)?;
        model.set_conv_path(self.conv);
        let precision = crate::learned::effective_precision(self.precision);
        if precision != self.precision {
            tracing::warn!(
                model = %path.display(),
                "--precision {}: this CPU has no vector path for it (8 bits: AVX-512 VNNI or AMX; \
                 bf16: AVX-512 BF16), and plain loops are slower than f32: running f32",
                self.precision
            );
        }
        model.set_precision(precision);
        for i in model.inputs() {
            if from_windows && has(i.input_id()) {
                return Err(InferError::Wiring(format!(
                    "model {}: connect either `{WINDOWS}` (its representations made of align's \
                     windows) or `{}`, not both",
                    path.display(),
                    i.input_id()
                )));
            }
            if !from_windows && !has(i.input_id()) {
                return Err(InferError::Wiring(format!(
                    "model {} reads `{}`: connect an input `{}` (represent's `{}` output), or \
                     `{WINDOWS}` (align's) to make it here",
                    path.display(),
                    i.onnx_name(),
                    i.input_id(),
                    i.input_id()
                )));
            }
        }
        let probes: Vec<Array3<f32>> = model
            .channels()
            .iter()
            .map(|&c| Array3::zeros((c, 8, 8)))
            .collect();
        let views: Vec<_> = probes.iter().map(|a| a.view()).collect();
        model.run(&views)?;
        Ok(model)
    }
}

/// The inputs of one window gathered so far: the representations by slot and the event batch.
#[derive(Default)]
struct Pending {
    reps: BTreeMap<usize, Representation>,
    events: Option<EventBatch>,
    window: Option<AlignedWindow>,
}

/// What makes the frames. A node holds one, so the variants' sizes do not matter.
#[allow(clippy::large_enum_variant)]
enum Engine {
    Online(Online),
    Learned(Box<LearnedModel>),
    Auto(Box<Auto>),
}

impl std::fmt::Debug for Reconstructor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Reconstructor")
            .field("method", &self.method)
            .field("inputs", &self.input_ids())
            .field("pending", &self.pending.len())
            .finish()
    }
}

/// Joins each window's inputs by sequence number and reconstructs every complete window, in
/// order. A window still incomplete when a later one is complete lost a message (each input
/// arrives in order): it is dropped and counted.
pub struct Reconstructor {
    engine: Engine,
    /// The learned network's representations made of align's windows, when it reads those.
    represent: Option<Box<Representer>>,
    method: Method,
    lum_per_rate: Option<f64>,
    /// The input ids that carry representations, one slot each.
    rep_ids: Vec<&'static str>,
    wants_events: bool,
    wants_window: bool,
    pending: BTreeMap<u64, Pending>,
    frames: u64,
    incomplete: u64,
}

impl Reconstructor {
    fn new(
        engine: Engine,
        cfg: &InferConfig,
        rep_ids: Vec<&'static str>,
        wants_events: bool,
    ) -> Self {
        Reconstructor {
            engine,
            represent: None,
            method: cfg.method,
            lum_per_rate: cfg.lum_per_rate,
            rep_ids,
            wants_events,
            wants_window: false,
            pending: BTreeMap::new(),
            frames: 0,
            incomplete: 0,
        }
    }

    /// The ids of the inputs the method reads.
    pub fn input_ids(&self) -> Vec<&'static str> {
        let mut ids = self.rep_ids.clone();
        if self.wants_events {
            ids.push(EVENTS);
        }
        if self.wants_window {
            ids.push(WINDOWS);
        }
        ids
    }

    /// Takes an aligned window (`auto`).
    pub fn push_window(&mut self, window: AlignedWindow) {
        let seq = window.seq();
        self.pending.entry(seq).or_default().window = Some(window);
    }

    /// `auto`'s stage, when the method is `auto`.
    pub fn auto(&self) -> Option<&Auto> {
        match &self.engine {
            Engine::Auto(a) => Some(a),
            _ => None,
        }
    }

    /// Takes a representation that came on `input`.
    pub fn push_representation(&mut self, input: &str, rep: Representation) {
        if let Some(slot) = self.rep_ids.iter().position(|&i| i == input) {
            self.pending
                .entry(rep.seq)
                .or_default()
                .reps
                .insert(slot, rep);
        }
    }

    /// Takes an event batch (align's stream, cut at the window's instant).
    pub fn push_events(&mut self, batch: EventBatch) {
        let seq = batch.seq;
        self.pending.entry(seq).or_default().events = Some(batch);
    }

    fn complete(&self, p: &Pending) -> bool {
        p.reps.len() == self.rep_ids.len()
            && (!self.wants_events || p.events.is_some())
            && (!self.wants_window || p.window.is_some())
    }

    /// The frames of every window whose inputs are all in, in order; with `flush` (no more input
    /// will come), the incomplete windows are dropped and counted too.
    pub fn ready(&mut self, flush: bool) -> Result<Vec<Frame>, InferError> {
        let last_done = self
            .pending
            .iter()
            .filter(|(_, p)| self.complete(p))
            .map(|(&k, _)| k)
            .next_back();
        let limit = match (last_done, flush) {
            (_, true) => u64::MAX,
            (Some(k), false) => k,
            (None, false) => return Ok(Vec::new()),
        };
        let mut frames = Vec::new();
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
            frames.push(self.reconstruct(seq, &p)?);
        }
        Ok(frames)
    }

    fn reconstruct(&mut self, seq: u64, p: &Pending) -> Result<Frame, InferError> {
        let start = Instant::now();
        let (t_ref_ns, data) = match &mut self.engine {
            Engine::Online(online) => classical(online, self.method, self.lum_per_rate, seq, p)?,
            Engine::Learned(model) => match (&mut self.represent, &p.window) {
                (Some(represent), Some(w)) => {
                    learned_window(model, represent, self.lum_per_rate, w)?
                }
                _ => learned(model, self.lum_per_rate, seq, p)?,
            },
            Engine::Auto(auto) => {
                let w = p
                    .window
                    .as_ref()
                    .ok_or_else(|| window_error(seq, "no window"))?;
                let f = auto.frame(w)?;
                self.frames = seq + 1;
                return Ok(Frame {
                    kind: FrameKind::Reconstruction,
                    method: self.method.to_string(),
                    t_ref_ns: w.t_ref_ns,
                    compute_ns: f.compute_ns,
                    chosen: Some(f.method),
                    budget_ns: auto.budget_ns(),
                    seq,
                    data: f.data,
                });
            }
        };
        self.frames = seq + 1;
        Ok(Frame {
            kind: FrameKind::Reconstruction,
            method: self.method.to_string(),
            t_ref_ns,
            compute_ns: i64::try_from(start.elapsed().as_nanos()).unwrap_or(i64::MAX),
            chosen: None,
            budget_ns: None,
            seq,
            data,
        })
    }

    /// The learned method's network.
    pub fn model(&self) -> Option<&LearnedModel> {
        match &self.engine {
            Engine::Learned(m) => Some(m),
            Engine::Online(_) | Engine::Auto(_) => None,
        }
    }

    /// Windows dropped because an input of theirs was lost.
    pub fn incomplete(&self) -> u64 {
        self.incomplete
    }

    /// Logs what was made.
    pub fn log_end(&self, announced: u64, lost: u64) {
        match &self.engine {
            Engine::Online(online) => {
                let s = online.stats();
                tracing::info!(
                    frames = s.frames,
                    announced,
                    incomplete = self.incomplete,
                    lost,
                    events = s.events,
                    method = %self.method,
                    clamped = s.frame.clamped,
                    exp_overflow = s.frame.exp_overflow,
                    "infer finished"
                );
            }
            Engine::Learned(model) => tracing::info!(
                frames = self.frames,
                announced,
                incomplete = self.incomplete,
                lost,
                model = %model.path().display(),
                conv = %model.conv_path_in_use().unwrap_or_default(),
                "infer finished"
            ),
            Engine::Auto(auto) => {
                let s = auto.stats();
                let mix: Vec<String> = s.frames.iter().map(|(m, n)| format!("{m} x{n}")).collect();
                let tiles: Vec<String> = s.tiles.iter().map(|(m, n)| format!("{m} x{n}")).collect();
                tracing::info!(
                    frames = self.frames,
                    announced,
                    incomplete = self.incomplete,
                    lost,
                    late = s.late,
                    mix = %mix.join(" "),
                    tiles = %tiles.join(" "),
                    "infer finished"
                );
            }
        }
    }
}

fn window_error(seq: u64, what: impl std::fmt::Display) -> InferError {
    InferError::Window {
        seq,
        what: what.to_string(),
    }
}

/// One window of a classical method.
fn classical(
    online: &mut Online,
    method: Method,
    lum_per_rate: Option<f64>,
    seq: u64,
    p: &Pending,
) -> Result<(i64, Array2<f32>), InferError> {
    let rep = p.reps.get(&0);
    let spikes = rep
        .map(|r| -> Result<SpikeInput<'_>, InferError> {
            Ok(match r.kind {
                RepresentationKind::Tfp => SpikeInput::Rate(r.data.index_axis(Axis(0), 0)),
                RepresentationKind::Stp => SpikeInput::StpRate(r.data.index_axis(Axis(0), 0)),
                RepresentationKind::Isi if r.data.dim().0 >= 2 => SpikeInput::Isi {
                    isi: r.data.index_axis(Axis(0), 0),
                    valid: r.data.index_axis(Axis(0), 1),
                },
                other => {
                    let kinds: Vec<&str> =
                        method.inputs().representations.iter().map(|k| k.name()).collect();
                    return Err(window_error(
                        seq,
                        format!(
                            "method `{method}` cannot use the `{other}` representation; it takes {}",
                            kinds.join(" or ")
                        ),
                    ));
                }
            })
        })
        .transpose()?;
    let lum_per_rate =
        lum_per_rate.or_else(|| rep.and_then(|r| r.params.get("lum_per_rate").copied()));
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
        (None, None) => return Err(window_error(seq, "no input")),
    };
    if let (Some(r), Some(b)) = (rep, &p.events)
        && b.t_end_ns != r.t_ref_ns
    {
        return Err(window_error(
            seq,
            format!(
                "the event batch ends at {} ns but the representation is at t_ref {} ns (connect align's `events` output, which cuts the stream at each t_ref)",
                b.t_end_ns, r.t_ref_ns
            ),
        ));
    }
    let planes = rep
        .and_then(|r| r.params.get("window"))
        .filter(|w| w.is_finite() && **w >= 1.0 && **w <= 1e6)
        .map(|w| *w as usize);
    let window = Window {
        t_ref_ns,
        spikes,
        lum_per_rate,
        events,
        planes,
    };
    let data = online.frame(&window).map_err(|e| {
        let hint = if lum_per_rate.is_none() && spikes.is_some() {
            " (the representation carries no `lum_per_rate` and the graph sets no `--lum-per-rate`)"
        } else {
            ""
        };
        window_error(seq, format!("at {t_ref_ns} ns: {e}{hint}"))
    })?;
    Ok((t_ref_ns, data))
}

/// One window of the learned method: the network's rate, calibrated to luminance as TFP's (or
/// the event-only network's luminance, clipped to [0, 1] the same way).
fn learned(
    model: &mut LearnedModel,
    lum_per_rate: Option<f64>,
    seq: u64,
    p: &Pending,
) -> Result<(i64, Array2<f32>), InferError> {
    let reps: Vec<&Representation> = p.reps.values().collect();
    for (r, i) in reps.iter().zip(model.inputs()) {
        if r.kind != i.representation() {
            return Err(window_error(
                seq,
                format!(
                    "input `{}` carries the `{}` representation; model {} reads `{}` there",
                    i.input_id(),
                    r.kind,
                    model.path().display(),
                    i.representation()
                ),
            ));
        }
    }
    let Some(first) = reps.first() else {
        return Err(window_error(seq, "no input"));
    };
    let t_ref_ns = first.t_ref_ns;
    if let Some(r) = reps.iter().find(|r| r.t_ref_ns != t_ref_ns) {
        return Err(window_error(
            seq,
            format!(
                "representations at t_ref {t_ref_ns} ns and {} ns",
                r.t_ref_ns
            ),
        ));
    }
    let views: Vec<_> = reps.iter().map(|r| r.data.view()).collect();
    let image = model
        .run(&views)
        .map_err(|e| window_error(seq, format!("at {t_ref_ns} ns: {e}")))?;
    let gain = || {
        lum_per_rate.or_else(|| {
            reps.iter()
                .find_map(|r| r.params.get("lum_per_rate").copied())
        })
    };
    let data = luminance(model, &image, seq, gain, "the representations carry")?;
    Ok((t_ref_ns, data))
}

/// A network's `image` as luminance: a `rate` output times the calibration (`gain`, asked for
/// only then; `carrier` says what did not carry one), a `luminance` output as it is (clamped to
/// `[0, 1]` both ways).
fn luminance(
    model: &LearnedModel,
    image: &Array2<f32>,
    seq: u64,
    gain: impl FnOnce() -> Option<f64>,
    carrier: &str,
) -> Result<Array2<f32>, InferError> {
    let gain = match model.output() {
        LearnedOutput::Luminance => 1.0,
        LearnedOutput::Rate => gain().ok_or_else(|| {
            window_error(
                seq,
                format!(
                    "no calibration ({carrier} no `lum_per_rate` and the graph sets no `--lum-per-rate`)"
                ),
            )
        })?,
    };
    let mut data = Array2::<f32>::zeros(image.dim());
    luminance_from_rate_into(image.view(), gain, 1.0, data.view_mut())
        .map_err(|e| window_error(seq, e))?;
    Ok(data)
}

/// One window of the learned method, its representations made of align's window.
fn learned_window(
    model: &mut LearnedModel,
    represent: &mut Representer,
    lum_per_rate: Option<f64>,
    w: &AlignedWindow,
) -> Result<(i64, Array2<f32>), InferError> {
    let seq = w.seq();
    let image = model
        .run_window(w, represent)
        .map_err(|e| window_error(seq, format!("at {} ns: {e}", w.t_ref_ns)))?;
    let gain = || lum_per_rate.or(w.spikes.lum_per_rate);
    let data = luminance(model, &image, seq, gain, "the window carries")?;
    Ok((w.t_ref_ns, data))
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array3;

    fn rep(kind: RepresentationKind, seq: u64, value: f32) -> Representation {
        let channels = if kind == RepresentationKind::Isi {
            2
        } else {
            1
        };
        let mut data = Array3::from_elem((channels, 2, 3), value);
        if kind == RepresentationKind::Isi {
            data.index_axis_mut(Axis(0), 1).fill(1.0); // every interval measured
        }
        Representation {
            kind,
            t_ref_ns: 1_000_000 * (seq as i64 + 1),
            seq,
            params: [("lum_per_rate".to_string(), 2.0)].into_iter().collect(),
            data,
        }
    }

    fn batch(seq: u64) -> EventBatch {
        let t0 = 1_000_000 * seq as i64;
        EventBatch::empty(3, 2, t0, t0 + 1_000_000, seq)
    }

    fn stage(method: Method) -> Reconstructor {
        InferConfig {
            method,
            ..InferConfig::default()
        }
        .reconstructor(&[REPRESENTATION.to_string(), EVENTS.to_string()])
        .expect("stage")
    }

    #[test]
    fn regions_parse_as_width_by_height_and_bad_ones_are_named() {
        assert_eq!(parse_tiles("80x50"), Ok((80, 50)));
        for bad in ["80", "0x50", "80x", "ax50", "80x-1"] {
            let e = parse_tiles(bad).expect_err(bad);
            assert!(e.contains(bad) && e.contains("80x50"), "{e}");
        }
    }

    #[test]
    fn windows_are_joined_by_sequence_whatever_the_arrival_order() {
        let mut r = stage(Method::Fusion);
        assert_eq!(r.input_ids(), [REPRESENTATION, EVENTS]);
        r.push_events(batch(1));
        r.push_events(batch(0));
        assert!(r.ready(false).expect("none complete").is_empty());
        r.push_representation(REPRESENTATION, rep(RepresentationKind::Isi, 1, 8.0));
        r.push_representation(REPRESENTATION, rep(RepresentationKind::Isi, 0, 8.0));
        let frames = r.ready(false).expect("frames");
        let seqs: Vec<u64> = frames.iter().map(|f| f.seq).collect();
        assert_eq!(seqs, [0, 1]);
        // TFI of an 8-tick interval at lum_per_rate 2.
        assert!(frames[0].data.iter().all(|&v| (v - 0.25).abs() < 1e-6));
        assert_eq!(frames[0].method, "fusion");
    }

    #[test]
    fn a_window_that_lost_an_input_is_dropped_and_counted() {
        let mut r = stage(Method::Fusion);
        // Window 0 lost its representation; window 1 is whole.
        r.push_events(batch(0));
        r.push_events(batch(1));
        r.push_representation(REPRESENTATION, rep(RepresentationKind::Isi, 1, 8.0));
        let frames = r.ready(false).expect("frames");
        assert_eq!(frames.iter().map(|f| f.seq).collect::<Vec<_>>(), [1]);
        assert_eq!(r.incomplete(), 1);
        // At the end, a window still waiting is dropped too.
        r.push_events(batch(2));
        assert!(r.ready(true).expect("flush").is_empty());
        assert_eq!(r.incomplete(), 2);
    }

    #[test]
    fn the_graph_must_carry_what_the_method_reads() {
        let cfg = InferConfig {
            method: Method::Hf,
            ..InferConfig::default()
        };
        let e = cfg.reconstructor(&[]).expect_err("no events").to_string();
        assert!(e.contains("`events`"), "{e}");
        let e = InferConfig::default()
            .reconstructor(&[EVENTS.to_string()])
            .expect_err("no representation")
            .to_string();
        assert!(e.contains("`representation`") && e.contains("tfp"), "{e}");
        let e = InferConfig {
            method: Method::Tfp,
            lum_per_rate: Some(0.0),
            ..InferConfig::default()
        }
        .reconstructor(&[REPRESENTATION.to_string()])
        .expect_err("bad calibration")
        .to_string();
        assert!(e.contains("lum-per-rate"), "{e}");
    }
}
