//! The learned reconstruction: a NeuSpike-Net exported to ONNX by `training/export.py`, run with
//! tract.
//!
//! A model reads one or both of the network's representations by input name: `spike` (the
//! spike representation, represent's `spike-repr`) and `events` (the event integration,
//! represent's `event-integration`), each `[1, C, H, W]` float32, and writes one image
//! `[1, 1, H, W]` whose name is its unit ([`LearnedOutput`]): `rate` (spikes per tick, for
//! networks that read spikes) or `luminance` (the event-only network: events carry no absolute
//! level, so it cannot use the camera's calibration). [`LearnedModel::load`] reads and checks the
//! file once; [`LearnedModel::run`] pins the input shapes to the frame's size padded up to
//! [`STRIDE`], optimises and keeps the plans of the last [`MAX_PLANS`] sizes, pads each input by repeating
//! its last row and column, runs, and crops the image back. (With neuspike's convolution, an
//! input's first convolution reads the representation where it lies, the padding included, and
//! the plan starts from its output: the input is never copied.) The plan runs on a thread of
//! tract's pool, the others spinning for work between its nodes. The infer node turns a rate
//! into luminance with the camera's calibration, as it does TFP's rate.
//!
//! Every failure is an [`InferError::Model`] naming the file and what is wrong: a missing,
//! unreadable or corrupt file, inputs the network does not know, a representation of the wrong
//! shape. Untrusted bytes go through tract's protobuf parser, which returns errors, not panics
//! (the fuzz target `onnx_model` feeds it arbitrary bytes).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use ndarray::{Array2, Array3, ArrayView3, Axis};
use neuspike_representations::{
    EventSlice, RepresentConfig, RepresentError, Representer, event_integration_into,
    integration_instants, spike_representation_parts,
};
use neuspike_schemas::{AlignedWindow, RepresentationKind};
use tract_onnx::prelude::*;
use tract_onnx::tract_hir::infer::Factoid;

use crate::InferError;
use neuspike_tract_ops::conv3x3::Conv3x3;
pub use neuspike_tract_ops::conv3x3::Precision;
pub use neuspike_tract_ops::{pad_edge, pad_edge_into};

/// Heights and widths the networks take are multiples of this (three stride-2 layers).
pub const STRIDE: usize = 8;

/// What a model input reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LearnedInput {
    /// The spike representation (1 ISI + raw planes): ONNX input `spike`.
    Spike,
    /// The event integration: ONNX input `events`.
    Events,
}

impl LearnedInput {
    /// The ONNX input name.
    pub fn onnx_name(self) -> &'static str {
        match self {
            LearnedInput::Spike => "spike",
            LearnedInput::Events => "events",
        }
    }

    /// The representation kind it reads: the represent node's output, and the infer node's
    /// input, of the same name.
    pub fn representation(self) -> RepresentationKind {
        match self {
            LearnedInput::Spike => RepresentationKind::SpikeRepr,
            LearnedInput::Events => RepresentationKind::EventIntegration,
        }
    }

    /// The infer node's input id for it: the representation's name.
    pub fn input_id(self) -> &'static str {
        self.representation().name()
    }
}

/// One input of a network as the caller holds it ([`LearnedModel::run_inputs`]).
#[derive(Clone, Copy, Debug)]
pub enum ModelInput<'a> {
    /// A representation `[C, H, W]`.
    Dense(ArrayView3<'a, f32>),
    /// A representation of dense channels `[D, H, W]` (each row contiguous) followed by
    /// `planes` binary channels, bit-packed in `bits` as a spike window holds its planes
    /// (`neuspike_tract_ops::conv3x3::packed_plane_bytes`): the spike representation as its
    /// ISI channel and raw planes (`neuspike_representations::spike_representation_parts`).
    Packed {
        /// The dense channels.
        dense: ArrayView3<'a, f32>,
        /// The binary channels' planes, one after the other.
        bits: &'a [u8],
        /// How many binary channels.
        planes: usize,
    },
    /// An event integration `[K, H, W]` not made yet: a window's events, the `K` instants,
    /// the window's start and the decay, as
    /// [`event_integration_into`](neuspike_representations::event_integration_into) takes them.
    /// Where the network's first convolution is its own and the events are at most
    /// [`SPARSE_EVENTS`] of the pixels, that convolution runs on the events themselves
    /// (`Conv3x3::run_edge_padded_events`); otherwise the integration is made first.
    Events {
        /// The events, sorted by time.
        events: EventSlice<'a>,
        /// The window's start: earlier events are not counted.
        t0_ns: i64,
        /// The instant of each channel.
        ts_ns: &'a [i64],
        /// The decay constant, nanoseconds.
        tau_ns: f64,
        /// The sensor's `(H, W)`.
        size: (usize, usize),
    },
}

/// The share of a frame's pixels up to which a network's first convolution of event
/// integration runs on the events themselves rather than on the integration made of them
/// ([`ModelInput::Events`]).
pub const SPARSE_EVENTS: f64 = 0.1;

impl ModelInput<'_> {
    /// `(channels, H, W)`.
    pub fn dim(&self) -> (usize, usize, usize) {
        match self {
            ModelInput::Dense(x) => x.dim(),
            ModelInput::Packed { dense, planes, .. } => {
                let (d, h, w) = dense.dim();
                (d.saturating_add(*planes), h, w)
            }
            ModelInput::Events { ts_ns, size, .. } => (ts_ns.len(), size.0, size.1),
        }
    }
}

/// What the network's one output is, by its ONNX name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LearnedOutput {
    /// `rate`: spikes per tick; luminance is `rate * lum_per_rate`.
    Rate,
    /// `luminance`: already in [0, 1] units of the scene.
    Luminance,
}

impl LearnedOutput {
    /// The ONNX output name.
    pub fn onnx_name(self) -> &'static str {
        match self {
            LearnedOutput::Rate => "rate",
            LearnedOutput::Luminance => "luminance",
        }
    }
}

/// The model optimised for one padded size, and the first convolutions it leaves to
/// [`LearnedModel`] (one per input, or `None`; see
/// [`take_first_convolutions`](neuspike_tract_ops::conv3x3::take_first_convolutions)).
#[derive(Debug)]
struct Planned {
    runnable: Arc<TypedRunnableModel>,
    first: Vec<Option<Arc<Conv3x3>>>,
}

type Plan = Arc<Planned>;

/// How tract computes the network's spatial convolutions. Measured at 256x400 on one thread
/// (`neuspike bench-model --conv`): the direct convolution was faster for base width 8 and im2col
/// with a matrix product faster for base 24 (563 against 757 ms); neuspike's own kernels beat
/// both on every 3x3 layer at least 40 points wide (all of them at 256x400). The default times
/// each path on the first frame of each size and keeps the fastest.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ConvPath {
    /// Plan each path, time each on the frame, keep the fastest (the default).
    #[default]
    Auto,
    /// tract's direct spatial convolution where it applies.
    Direct,
    /// im2col and a matrix product everywhere (`TRACT_DISABLE_DIRECT_SPATIAL`).
    Im2col,
    /// neuspike's register-blocked kernels: for the 3x3, stride-1 and 2 convolutions with output
    /// rows of at least [`neuspike_tract_ops::conv3x3::MIN_WIDTH`] points ([`neuspike_tract_ops::conv3x3`]) and the 2x2,
    /// stride-2 transposed ones ([`neuspike_tract_ops::deconv2x2`]); the skip connections' spatial attention
    /// as one operator ([`neuspike_tract_ops::attention`]); tract's direct convolution for the others.
    Blocked,
}

impl std::fmt::Display for ConvPath {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            ConvPath::Auto => "auto",
            ConvPath::Direct => "direct",
            ConvPath::Im2col => "im2col",
            ConvPath::Blocked => "blocked",
        })
    }
}

impl std::str::FromStr for ConvPath {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "auto" => Ok(ConvPath::Auto),
            "direct" => Ok(ConvPath::Direct),
            "im2col" => Ok(ConvPath::Im2col),
            "blocked" => Ok(ConvPath::Blocked),
            other => Err(format!(
                "convolution path `{other}`: expected auto, direct, im2col or blocked"
            )),
        }
    }
}

/// The suffix of a network method run in 8 bits: `neuspike-spike-8-int8` is
/// `neuspike-spike-8.onnx` with `--precision int8` (the trade bench's and `auto`'s name for it).
pub const INT8_SUFFIX: &str = "-int8";

/// The suffix of a network method run in `bf16`: `neuspike-spike-8-bf16` is
/// `neuspike-spike-8.onnx` with `--precision bf16`.
pub const BF16_SUFFIX: &str = "-bf16";

/// A network method's name as its file's stem and the precision it runs in (see
/// [`INT8_SUFFIX`], [`BF16_SUFFIX`]; the widest path of that precision this CPU has).
pub fn network_variant(name: &str) -> (&str, Precision) {
    for (suffix, precision) in [
        (INT8_SUFFIX, Precision::int8()),
        (BF16_SUFFIX, Precision::bf16()),
    ] {
        match name.strip_suffix(suffix) {
            Some(stem) if !stem.is_empty() => return (stem, precision),
            _ => {}
        }
    }
    (name, Precision::F32)
}

/// The precision a stage runs for the one asked: `f32` in place of a reduced precision this CPU
/// has only plain loops for (they are slower than `f32`: any CPU but an x86-64 with AVX-512
/// VNNI or AMX for 8 bits, AVX-512 BF16 for `bf16`); `bench-model` still times those loops.
pub fn effective_precision(asked: Precision) -> Precision {
    match asked {
        Precision::Int8(neuspike_simd::dot::DotPath::Portable)
        | Precision::Bf16(neuspike_simd::bf16::Bf16Path::Portable) => Precision::F32,
        p => p,
    }
}

/// Runs of each candidate plan [`ConvPath::Auto`] times (the fastest counts: the machines here
/// are noisy, and noise only ever adds time). Two runs each, one after the other, once kept
/// im2col for the large model at 2 threads, 1.5x slower than the blocked path.
const AUTO_RUNS: usize = 3;

/// Time one run spent in one node of the optimised plan ([`LearnedModel::profile`]).
#[derive(Clone, Debug, PartialEq)]
pub struct NodeTime {
    /// The node's name in the optimised plan (derived from the ONNX node it came from).
    pub node: String,
    /// tract's operator name (e.g. `DirectSpatialConv`, `OptMatMul`, `Reduce<Max>`).
    pub op: String,
    /// Milliseconds.
    pub ms: f64,
}

/// The most plans a model keeps, one per padded frame size (per-region choice runs a network on
/// regions of a few sizes); the oldest goes first.
pub const MAX_PLANS: usize = 8;

/// A loaded network, with its plans for the last frame sizes.
#[derive(Clone, Debug)]
pub struct LearnedModel {
    path: PathBuf,
    model: InferenceModel,
    inputs: Vec<LearnedInput>,
    channels: Vec<usize>,
    output: LearnedOutput,
    conv: ConvPath,
    precision: Precision,
    /// The plans for the last padded sizes, newest last, and the path they use (never `Auto`):
    /// under `Auto`, the path timed fastest at the first size is kept for the others.
    plans: Vec<((usize, usize), Plan)>,
    path_in_use: Option<ConvPath>,
    /// The last run's input tensors, refilled in place when nothing else holds them: a fresh
    /// 13 MB tensor per input and frame cost its page faults every time.
    buffers: Vec<Arc<Tensor>>,
}

/// `f()`, with a panic inside it (tract on a file it does not expect) turned into an
/// [`InferError::Model`] naming the file, what was being done and the panic's message.
fn caught<T>(
    path: &Path,
    doing: &str,
    f: impl FnOnce() -> Result<T, InferError>,
) -> Result<T, InferError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).unwrap_or_else(|panic| {
        let why = panic
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "no message".into());
        Err(model_error(path, format!("tract failed {doing}: {why}")))
    })
}

fn model_error(path: &Path, reason: impl std::fmt::Display) -> InferError {
    InferError::Model {
        path: path.to_path_buf(),
        reason: reason.to_string(),
    }
}

/// The largest model file read: 512 MiB (the shipped networks take 1 to 10 MB). A larger file is
/// refused before it is read whole.
pub const MAX_MODEL_BYTES: u64 = 512 << 20;

/// Bytes of one element of an ONNX tensor type: FLOAT16/BFLOAT16 2, the 8-bit types 1, the rest
/// up to 16 (COMPLEX128); an unknown type counts 1, the least, so that no genuine tensor is
/// refused.
fn element_bytes(data_type: i32) -> u128 {
    match data_type {
        11 | 7 | 13 | 14 => 8, // DOUBLE, INT64, UINT64, COMPLEX64
        1 | 6 | 12 => 4,       // FLOAT, INT32, UINT32
        10 | 16 | 5 | 4 => 2,  // FLOAT16, BFLOAT16, INT16, UINT16
        15 => 16,              // COMPLEX128
        _ => 1,
    }
}

/// Checks that every tensor stored in `graph` (initializers, and tensors in node attributes,
/// subgraphs included) holds the bytes its dimensions claim, and that none is stored outside
/// the file or sparse: what tract would otherwise allocate from a claim (a few bytes claiming a
/// tensor of terabytes) is refused first, naming the tensor.
fn check_tensors(graph: &tract_onnx::pb::GraphProto) -> Result<(), String> {
    let check = |t: &tract_onnx::pb::TensorProto| -> Result<(), String> {
        let name = if t.name.is_empty() {
            "(unnamed)"
        } else {
            t.name.as_str()
        };
        if !t.external_data.is_empty() || t.data_location == Some(1) {
            return Err(format!(
                "tensor `{name}` is stored outside the file; neuspike reads one file"
            ));
        }
        let mut elements: u128 = 1;
        for &d in &t.dims {
            let d = u128::try_from(d).map_err(|_| format!("tensor `{name}` has dimension {d}"))?;
            elements = elements.saturating_mul(d);
        }
        let held = t.raw_data.len() as u128
            + 4 * (t.float_data.len() + t.int32_data.len()) as u128
            + 8 * (t.int64_data.len() + t.double_data.len() + t.uint64_data.len()) as u128
            + t.string_data
                .iter()
                .map(|s| s.len() as u128 + 1)
                .sum::<u128>();
        let claimed = elements.saturating_mul(element_bytes(t.data_type));
        // int32_data packs the 1- and 2-byte types one element to 4 bytes: never fewer bytes
        // held than claimed for a genuine tensor.
        if claimed > held {
            return Err(format!(
                "tensor `{name}` claims {:?} ({claimed} bytes) but holds {held} bytes",
                t.dims
            ));
        }
        Ok(())
    };
    if !graph.sparse_initializer.is_empty() {
        return Err("sparse initializers are not read".into());
    }
    for t in &graph.initializer {
        check(t)?;
    }
    for node in &graph.node {
        for a in &node.attribute {
            if a.sparse_tensor.is_some() || !a.sparse_tensors.is_empty() {
                return Err(format!("node `{}`: sparse tensors are not read", node.name));
            }
            for t in a.t.iter().chain(&a.tensors) {
                check(t)?;
            }
            for g in a.g.iter().chain(&a.graphs) {
                check_tensors(g)?;
            }
        }
    }
    Ok(())
}

/// `f` of an error chain, one line.
fn chain(e: &TractError) -> String {
    format!("{e:#}").replace('\n', " ")
}

impl LearnedModel {
    /// Reads and checks `path`: every input is `spike` or `events` with a known channel count,
    /// the output is one image named `rate` or `luminance`.
    ///
    /// # Errors
    /// [`InferError::Model`] naming the file and the problem.
    pub fn load(path: &Path) -> Result<LearnedModel, InferError> {
        Self::load_at_most(path, MAX_MODEL_BYTES)
    }

    /// [`LearnedModel::load`] with a limit on the file's size other than [`MAX_MODEL_BYTES`].
    /// The file is untrusted: it is read up to the limit, every stored tensor must hold the bytes
    /// its dimensions claim, and a panic inside tract while it is read is an error naming the
    /// file, not the end of the program.
    ///
    /// # Errors
    /// [`InferError::Model`] naming the file and the problem.
    pub fn load_at_most(path: &Path, max_bytes: u64) -> Result<LearnedModel, InferError> {
        use std::io::Read;
        let mut bytes = Vec::new();
        std::fs::File::open(path)
            .and_then(|f| f.take(max_bytes.saturating_add(1)).read_to_end(&mut bytes))
            .map_err(|e| model_error(path, format!("cannot read: {e}")))?;
        if bytes.len() as u64 > max_bytes {
            return Err(model_error(
                path,
                format!("larger than {max_bytes} bytes, the most a model file may be"),
            ));
        }
        let model = caught(path, "reading it", || {
            let onnx = tract_onnx::onnx();
            let unreadable = |e: TractError| {
                model_error(path, format!("not a readable ONNX model: {}", chain(&e)))
            };
            let proto = onnx
                .proto_model_for_read(&mut bytes.as_slice())
                .map_err(unreadable)?;
            if let Some(graph) = &proto.graph {
                check_tensors(graph).map_err(|r| model_error(path, r))?;
            }
            onnx.model_for_proto_model(&proto).map_err(unreadable)
        })?;
        let mut inputs = Vec::new();
        let mut channels = Vec::new();
        for (i, outlet) in model
            .input_outlets()
            .map_err(|e| model_error(path, chain(&e)))?
            .iter()
            .enumerate()
        {
            let name = &model.node(outlet.node).name;
            let input = match name.as_str() {
                "spike" => LearnedInput::Spike,
                "events" => LearnedInput::Events,
                other => {
                    return Err(model_error(
                        path,
                        format!(
                            "input {i} is `{other}`; a NeuSpike-Net reads `spike` and/or `events`"
                        ),
                    ));
                }
            };
            let fact = model
                .input_fact(i)
                .map_err(|e| model_error(path, chain(&e)))?;
            let c = fact
                .shape
                .dims()
                .nth(1)
                .and_then(|d| d.concretize())
                .and_then(|d| d.as_i64())
                .and_then(|d| usize::try_from(d).ok())
                .filter(|_| fact.shape.rank().concretize() == Some(4))
                .ok_or_else(|| {
                    model_error(
                        path,
                        format!("input `{name}` is {fact:?}, not [1, C, H, W] with a fixed C"),
                    )
                })?;
            if inputs.contains(&input) {
                return Err(model_error(path, format!("input `{name}` appears twice")));
            }
            inputs.push(input);
            channels.push(c);
        }
        if inputs.is_empty() {
            return Err(model_error(path, "the model has no inputs"));
        }
        let outlets = model
            .output_outlets()
            .map_err(|e| model_error(path, chain(&e)))?;
        let [outlet] = outlets else {
            return Err(model_error(
                path,
                format!(
                    "{} outputs; a NeuSpike-Net has one (`rate` or `luminance`)",
                    outlets.len()
                ),
            ));
        };
        let name = model
            .outlet_label(*outlet)
            .unwrap_or(&model.node(outlet.node).name);
        let output = match name {
            "rate" => LearnedOutput::Rate,
            "luminance" => LearnedOutput::Luminance,
            other => {
                return Err(model_error(
                    path,
                    format!("the output is `{other}`; a NeuSpike-Net writes `rate` or `luminance`"),
                ));
            }
        };
        Ok(LearnedModel {
            path: path.to_path_buf(),
            model,
            inputs,
            channels,
            output,
            conv: ConvPath::Auto,
            precision: Precision::F32,
            plans: Vec::new(),
            path_in_use: None,
            buffers: Vec::new(),
        })
    }

    /// The inputs, in the order [`run`](Self::run) takes them.
    pub fn inputs(&self) -> &[LearnedInput] {
        &self.inputs
    }

    /// Whether it reads the events (an event integration input).
    pub fn reads_events(&self) -> bool {
        self.inputs.contains(&LearnedInput::Events)
    }

    /// What [`run`](Self::run) returns: a rate or luminance.
    pub fn output(&self) -> LearnedOutput {
        self.output
    }

    /// Chooses how the convolutions run (the next plan uses it).
    pub fn set_conv_path(&mut self, conv: ConvPath) {
        if conv != self.conv {
            self.conv = conv;
            self.plans.clear();
            self.path_in_use = None;
        }
    }

    /// Chooses the precision of the 3x3 convolutions (the next plan uses it). Any precision
    /// but `f32` runs on neuspike's kernels: [`ConvPath::Auto`] then plans
    /// [`ConvPath::Blocked`] alone, and [`ConvPath::Direct`] or [`ConvPath::Im2col`] refuse to
    /// plan.
    pub fn set_precision(&mut self, precision: Precision) {
        if precision != self.precision {
            self.precision = precision;
            self.plans.clear();
            self.path_in_use = None;
        }
    }

    /// The precision of the 3x3 convolutions.
    pub fn precision(&self) -> Precision {
        self.precision
    }

    /// The path the current plan uses (`None` before the first run).
    pub fn conv_path_in_use(&self) -> Option<ConvPath> {
        self.path_in_use
    }

    /// Channels each input expects.
    pub fn channels(&self) -> &[usize] {
        &self.channels
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Optimises the model for padded size `(h, w)` with convolutions on `path` (not `Auto`).
    fn build_plan(&self, h: usize, w: usize, path: ConvPath) -> Result<Plan, InferError> {
        let mut model = self.model.clone();
        for (i, &c) in self.channels.iter().enumerate() {
            model
                .set_input_fact(i, f32::fact([1, c, h, w]).into())
                .map_err(|e| model_error(&self.path, chain(&e)))?;
        }
        let disable = if path == ConvPath::Im2col {
            "true"
        } else {
            "false"
        };
        let scope = tract_onnx::tract_core::knobs::KnobScope::new([(
            "TRACT_DISABLE_DIRECT_SPATIAL",
            disable,
        )])
        .map_err(|e| model_error(&self.path, chain(&e)))?;
        let n_inputs = self.inputs.len();
        let precision = self.precision;
        if precision != Precision::F32 && path != ConvPath::Blocked {
            return Err(model_error(
                &self.path,
                format!(
                    "{precision} convolutions run on neuspike's kernels: --conv blocked or auto, not {path}"
                ),
            ));
        }
        let doing = format!("planning it at {h}x{w}");
        let (runnable, first) = caught(&self.path, &doing, || {
            scope
                .enter(|| {
                    let mut model = model.into_typed()?;
                    if path == ConvPath::Blocked {
                        // Before decluttering, which makes the 1x1 convolutions products.
                        neuspike_tract_ops::depthwise::use_depthwise_out(&mut model)?;
                        neuspike_tract_ops::subpixel::use_subpixel_out(&mut model)?;
                    }
                    let mut model = model.into_decluttered()?;
                    let mut first = vec![None; n_inputs];
                    if path == ConvPath::Blocked {
                        neuspike_tract_ops::conv3x3::use_conv3x3(
                            &mut model,
                            neuspike_tract_ops::conv3x3::MIN_WIDTH,
                            precision,
                        )?;
                        neuspike_tract_ops::deconv2x2::use_deconv2x2(&mut model)?;
                        neuspike_tract_ops::attention::use_spatial_attention(&mut model)?;
                        neuspike_tract_ops::attention::use_scaled_sums(&mut model)?;
                        first = neuspike_tract_ops::conv3x3::take_first_convolutions(&mut model)?;
                    }
                    Ok((model.into_optimized()?.into_runnable()?, first))
                })
                .map_err(|e: TractError| {
                    model_error(
                        &self.path,
                        format!("cannot be planned at {h}x{w} ({path}): {}", chain(&e)),
                    )
                })
        })?;
        Ok(Arc::new(Planned { runnable, first }))
    }

    /// The time of one run of `plan` on `xs` padded to `(hp, wp)`, seconds.
    fn time_run(
        &mut self,
        plan: &Plan,
        xs: &[ModelInput],
        (hp, wp): (usize, usize),
    ) -> Result<f64, InferError> {
        let start = std::time::Instant::now();
        self.run_plan(plan, xs, hp, wp)?;
        Ok(start.elapsed().as_secs_f64())
    }

    /// Runs `plan` on `xs` padded to `(hp, wp)` (its inputs prepared by [`plan_inputs`]), on
    /// tract's pool ([`in_pool`]); returns the output image, `hp * wp` values.
    fn run_plan(
        &mut self,
        plan: &Plan,
        xs: &[ModelInput],
        hp: usize,
        wp: usize,
    ) -> Result<Arc<Tensor>, InferError> {
        let (path, buffers) = (&self.path, &mut self.buffers);
        in_pool(|| {
            let values = plan_inputs(path, buffers, &plan.first, xs, hp, wp)?;
            let mut out = plan
                .runnable
                .run(values)
                .map_err(|e| model_error(path, format!("run at {hp}x{wp}: {}", chain(&e))))?;
            let image = out.pop().ok_or_else(|| model_error(path, "no output"))?;
            Ok(image.into_arc_tensor())
        })
    }

    /// The plan for padded size `(h, w)`: the kept one, or a new one (for [`ConvPath::Auto`],
    /// the fastest path on `values`).
    fn plan_for(&mut self, h: usize, w: usize, xs: &[ModelInput]) -> Result<Plan, InferError> {
        if let Some((_, plan)) = self.plans.iter().find(|(size, _)| *size == (h, w)) {
            return Ok(plan.clone());
        }
        let (plan, path) = match (self.conv, self.path_in_use) {
            (ConvPath::Auto, Some(path)) => (self.build_plan(h, w, path)?, path),
            (ConvPath::Auto, None) if self.precision != Precision::F32 => {
                (self.build_plan(h, w, ConvPath::Blocked)?, ConvPath::Blocked)
            }
            (ConvPath::Auto, None) => {
                let mut candidates = Vec::new();
                for path in [ConvPath::Direct, ConvPath::Im2col, ConvPath::Blocked] {
                    candidates.push((f64::INFINITY, self.build_plan(h, w, path)?, path));
                }
                // In rounds, one run of each plan per round, so a slow spell of the machine
                // falls on all of them rather than on one plan's every run.
                for _ in 0..AUTO_RUNS {
                    for (fastest, plan, _) in &mut candidates {
                        *fastest = fastest.min(self.time_run(plan, xs, (h, w))?);
                    }
                }
                let best = candidates
                    .into_iter()
                    .min_by(|a, b| a.0.total_cmp(&b.0))
                    .ok_or_else(|| model_error(&self.path, "internal: no plan to choose"))?;
                (best.1, best.2)
            }
            (path, _) => (self.build_plan(h, w, path)?, path),
        };
        if self.plans.len() == MAX_PLANS {
            self.plans.remove(0);
        }
        self.plans.push(((h, w), plan.clone()));
        self.path_in_use = Some(path);
        Ok(plan)
    }

    /// Checks `xs` against the network's inputs; returns the frame's `(h, w)`.
    fn check_inputs(&self, xs: &[ModelInput]) -> Result<(usize, usize), InferError> {
        if xs.len() != self.inputs.len() {
            return Err(model_error(
                &self.path,
                format!(
                    "{} representations given, the network reads {}",
                    xs.len(),
                    self.inputs.len()
                ),
            ));
        }
        let (_, h, w) = xs[0].dim();
        for ((x, input), &c) in xs.iter().zip(&self.inputs).zip(&self.channels) {
            if x.dim() != (c, h, w) {
                return Err(model_error(
                    &self.path,
                    format!(
                        "input `{}` ({}) has shape {:?}; the network wants [{c}, {h}, {w}]",
                        input.onnx_name(),
                        input.representation(),
                        <[usize; 3]>::from(x.dim())
                    ),
                ));
            }
            if let ModelInput::Packed {
                dense,
                bits,
                planes,
            } = x
            {
                let per = neuspike_tract_ops::conv3x3::packed_plane_bytes(h, w);
                if planes.checked_mul(per).is_none_or(|n| n > bits.len()) {
                    return Err(model_error(
                        &self.path,
                        format!(
                            "input `{}`: {planes} packed planes of {h}x{w} take {} bytes, {} given",
                            input.onnx_name(),
                            planes.saturating_mul(per),
                            bits.len()
                        ),
                    ));
                }
                if dense.dim().0 > 0 && w > 1 && dense.strides()[2] != 1 {
                    return Err(model_error(
                        &self.path,
                        format!(
                            "input `{}`: its dense channels' rows are not contiguous",
                            input.onnx_name()
                        ),
                    ));
                }
            }
        }
        if h == 0 || w == 0 {
            return Err(model_error(&self.path, format!("empty frame {h}x{w}")));
        }
        Ok((h, w))
    }

    /// Runs the network once on `xs` (as [`run`](Self::run)) and returns the time each node of
    /// the plan took, in evaluation order, after two pseudo-nodes for the work around it
    /// (`(inputs)`: the padded inputs, or the first convolutions run on the representations
    /// in place; `(plan state)`): what to look at when tract is slower than it should be
    /// (`neuspike bench-model --profile`).
    ///
    /// # Errors
    /// As [`run`](Self::run).
    pub fn profile(&mut self, xs: &[ArrayView3<f32>]) -> Result<Vec<NodeTime>, InferError> {
        let xs: Vec<ModelInput> = xs.iter().map(|x| ModelInput::Dense(x.view())).collect();
        let xs = &xs[..];
        let (h, w) = self.check_inputs(xs)?;
        let (hp, wp) = (h.next_multiple_of(STRIDE), w.next_multiple_of(STRIDE));
        let plan = self.plan_for(hp, wp, xs)?;
        let (path, buffers) = (&self.path, &mut self.buffers);
        in_pool(|| {
            let mut times = Vec::new();
            let step = |name: &str, start: std::time::Instant, times: &mut Vec<NodeTime>| {
                times.push(NodeTime {
                    node: name.to_string(),
                    op: name.to_string(),
                    ms: start.elapsed().as_secs_f64() * 1e3,
                })
            };
            let start = std::time::Instant::now();
            let values = plan_inputs(path, buffers, &plan.first, xs, hp, wp)?;
            step("(inputs)", start, &mut times);
            let start = std::time::Instant::now();
            let mut state =
                TypedSimpleState::new(&plan.runnable).map_err(|e| model_error(path, chain(&e)))?;
            step("(plan state)", start, &mut times);
            state
                .run_plan_with_eval(values, |ctx, st, node, input| {
                    let start = std::time::Instant::now();
                    let out = tract_onnx::tract_core::plan::eval(ctx, st, node, input);
                    times.push(NodeTime {
                        node: node.name.clone(),
                        op: node.op().name().into_owned(),
                        ms: start.elapsed().as_secs_f64() * 1e3,
                    });
                    out
                })
                .map_err(|e| model_error(path, format!("run at {hp}x{wp}: {}", chain(&e))))?;
            Ok(times)
        })
    }

    /// The represent settings that make this network's inputs: its channel counts.
    pub fn represent_config(&self) -> RepresentConfig {
        let mut cfg = RepresentConfig::default();
        for (i, &c) in self.inputs.iter().zip(&self.channels) {
            let c = u32::try_from(c).unwrap_or(u32::MAX);
            match i.representation() {
                RepresentationKind::SpikeRepr => cfg.repr_channels = c,
                _ => cfg.ei_channels = c,
            }
        }
        cfg
    }

    /// The network's frame of an aligned window: its spike input as the spike representation's
    /// ISI channel and the window's packed planes ([`ModelInput::Packed`], read by tables on
    /// AVX-512 and as bits where the first convolution runs in 8 bits, unpacked before it
    /// otherwise), its event input as the window's events with `represent`'s decay
    /// ([`ModelInput::Events`]: the first convolution adds them one by one where they are few).
    /// The frame of [`run`](Self::run) on the represent stage's representations of the window,
    /// up to the order of the first convolutions' sums (and their precision: `f32` where the
    /// planes are read by tables or the events one by one).
    ///
    /// # Errors
    /// [`InferError::Window`] when a representation cannot be made of the window (too few
    /// planes), and as [`run_inputs`](Self::run_inputs).
    pub fn run_window(
        &mut self,
        win: &AlignedWindow,
        represent: &mut Representer,
    ) -> Result<Array2<f32>, InferError> {
        let window_error = |e: RepresentError| InferError::Window {
            seq: win.seq(),
            what: e.to_string(),
        };
        let spikes = &win.spikes;
        let (n, h, w) = (spikes.n_planes, spikes.height, spikes.width);
        /// An input as made here.
        enum Made {
            /// The ISI channel, and the range of the window's bytes holding the raw planes.
            Spike(Array3<f32>, std::ops::Range<usize>, usize),
            /// The event integration's instants; it is made by `run_inputs` (from the events
            /// themselves where they are few).
            Events(Vec<i64>),
        }
        let mut made = Vec::with_capacity(self.inputs.len());
        for (i, &channels) in self.inputs.iter().zip(&self.channels) {
            made.push(match i {
                LearnedInput::Spike => {
                    let mut isi = Array3::<f32>::zeros((1, h, w));
                    let raw = spike_representation_parts(
                        &spikes.bits,
                        n,
                        win.ref_index(),
                        channels,
                        isi.index_axis_mut(Axis(0), 0),
                    )
                    .map_err(window_error)?;
                    Made::Spike(isi, raw, channels - 1)
                }
                LearnedInput::Events => Made::Events(integration_instants(
                    win.events.t_start_ns,
                    win.events.t_end_ns,
                    channels,
                )),
            });
        }
        let ev = &win.events;
        let events = EventSlice {
            t_ns: &ev.t_ns,
            x: &ev.x,
            y: &ev.y,
            polarity: &ev.polarity,
        };
        let inputs: Vec<ModelInput> = made
            .iter()
            .map(|m| match m {
                Made::Spike(isi, raw, planes) => ModelInput::Packed {
                    dense: isi.view(),
                    bits: spikes.bits.get(raw.clone()).unwrap_or(&[]),
                    planes: *planes,
                },
                Made::Events(ts_ns) => ModelInput::Events {
                    events,
                    t0_ns: ev.t_start_ns,
                    ts_ns,
                    tau_ns: represent.config().tau_ns,
                    size: (ev.height.max(1), ev.width.max(1)),
                },
            })
            .collect();
        self.run_inputs(&inputs)
    }

    /// Runs the network on one frame's representations, in [`inputs`](Self::inputs) order, each
    /// `[C, H, W]`; returns the [`output`](Self::output) image `[H, W]`.
    ///
    /// # Errors
    /// [`InferError::Model`] for a wrong number of inputs, a wrong channel count, inputs of
    /// different sizes, or a failure inside the network.
    pub fn run(&mut self, xs: &[ArrayView3<f32>]) -> Result<Array2<f32>, InferError> {
        let xs: Vec<ModelInput> = xs.iter().map(|x| ModelInput::Dense(x.view())).collect();
        self.run_inputs(&xs)
    }

    /// [`run`](Self::run) on inputs as the caller holds them ([`ModelInput`]): a spike
    /// representation whose raw planes are still bit-packed (as a window holds them) is read so
    /// by the network's first convolution, its planes never unpacked
    /// (`Conv3x3::run_edge_padded_bits`: by tables in `f32` on AVX-512, as bits in 8 bits
    /// elsewhere, unpacked for other precisions). The frame of `run` on the unpacked
    /// representation: bit for bit without the tables; with them, the first convolution's planes
    /// in `f32` whatever the precision (tested: no further from the `f32` frame).
    ///
    /// # Errors
    /// As [`run`](Self::run), and [`InferError::Model`] when `bits` holds fewer planes than
    /// said or the dense channels' rows are not contiguous.
    pub fn run_inputs(&mut self, xs: &[ModelInput]) -> Result<Array2<f32>, InferError> {
        let (h, w) = self.check_inputs(xs)?;
        let (hp, wp) = (h.next_multiple_of(STRIDE), w.next_multiple_of(STRIDE));
        let plan = self.plan_for(hp, wp, xs)?;
        let out = self.run_plan(&plan, xs, hp, wp)?;
        let plain = out
            .try_as_plain_ram()
            .map_err(|e| model_error(&self.path, chain(&e)))?;
        let image = plain
            .as_slice::<f32>()
            .map_err(|e| model_error(&self.path, chain(&e)))?;
        if image.len() != hp * wp {
            return Err(model_error(
                &self.path,
                format!("output has {} values, expected {hp}x{wp}", image.len()),
            ));
        }
        Ok(Array2::from_shape_fn((h, w), |(y, x)| image[y * wp + x]))
    }
}

/// The plan's input tensors for `xs` padded to `(hp, wp)`: for an input the plan reads through
/// a first convolution of its own (`first`), that convolution computed straight from the
/// representation, its padding read in place; for the others the representation padded by
/// repeating its last row and column ([`pad_edge`]). Each is written into `buffers`' tensor of
/// that slot when its shape matches and nothing else holds it (a fresh 13 MB tensor per input
/// and frame cost its page faults every time).
fn plan_inputs(
    path: &Path,
    buffers: &mut Vec<Arc<Tensor>>,
    first: &[Option<Arc<Conv3x3>>],
    xs: &[ModelInput],
    hp: usize,
    wp: usize,
) -> Result<TVec<TValue>, InferError> {
    let pool = neuspike_tract_ops::bands::tract_pool();
    let mut values = TVec::new();
    for (i, x) in xs.iter().enumerate() {
        let conv = first.get(i).and_then(Option::as_ref);
        // Packed planes: read by the first convolution (as bits in 8 bits), else unpacked here.
        let owned;
        let x = match (x, conv) {
            (ModelInput::Dense(x), _) => x.view(),
            (
                &ModelInput::Packed {
                    dense,
                    bits,
                    planes,
                },
                Some(conv),
            ) => {
                let shape = [1, conv.c_out(), conv.out_len(hp), conv.out_len(wp)];
                fill_input(path, buffers, i, shape, |dst| {
                    conv.run_edge_padded_bits(dense, bits, planes, (hp, wp), dst, pool.as_deref())
                        .map_err(|e| model_error(path, format!("first convolution: {e}")))
                })?;
                values.push(TValue::from_const(buffers[i].clone()));
                continue;
            }
            (
                &ModelInput::Packed {
                    dense,
                    bits,
                    planes,
                },
                None,
            ) => {
                owned = neuspike_tract_ops::conv3x3::unpacked(dense, bits, planes)
                    .ok_or_else(|| model_error(path, "packed planes: too few bytes"))?;
                owned.view()
            }
            (
                &ModelInput::Events {
                    events,
                    t0_ns,
                    ts_ns,
                    tau_ns,
                    size,
                },
                conv,
            ) => {
                let few = (events.len() as f64) <= SPARSE_EVENTS * (hp * wp) as f64;
                if let Some(conv) = conv.filter(|c| few && c.stride() == 1) {
                    let shape = [1, conv.c_out(), hp, wp];
                    let ev = neuspike_tract_ops::conv3x3::events::Events {
                        t_ns: events.t_ns,
                        x: events.x,
                        y: events.y,
                        polarity: events.polarity,
                    };
                    fill_input(path, buffers, i, shape, |dst| {
                        conv.run_edge_padded_events(ev, t0_ns, ts_ns, tau_ns, size, (hp, wp), dst)
                            .map_err(|e| model_error(path, format!("first convolution: {e}")))
                    })?;
                    values.push(TValue::from_const(buffers[i].clone()));
                    continue;
                }
                let mut made = Array3::<f32>::zeros((ts_ns.len(), size.0, size.1));
                event_integration_into(events, t0_ns, ts_ns, tau_ns, made.view_mut())
                    .map_err(|e| model_error(path, format!("event integration: {e}")))?;
                owned = made;
                owned.view()
            }
        };
        let shape = match conv {
            Some(conv) => [1, conv.c_out(), conv.out_len(hp), conv.out_len(wp)],
            None => [1, x.dim().0, hp, wp],
        };
        fill_input(path, buffers, i, shape, |dst| {
            write_input(path, conv, x, (hp, wp), dst, pool.as_deref())
        })?;
        values.push(TValue::from_const(buffers[i].clone()));
    }
    Ok(values)
}

/// Input `x` as the plan reads it, into `dst`: through its first convolution `conv` when it has
/// one, else padded to `(hp, wp)` by repeating its last row and column.
fn write_input(
    path: &Path,
    conv: Option<&Arc<Conv3x3>>,
    x: ArrayView3<f32>,
    (hp, wp): (usize, usize),
    dst: &mut [f32],
    pool: Option<&rayon::ThreadPool>,
) -> Result<(), InferError> {
    match conv {
        Some(conv) => {
            // Rows not contiguous in memory (a view taken across): a standard copy first.
            let copy;
            let x = if x.dim().2 <= 1 || x.strides()[2] == 1 {
                x.view()
            } else {
                copy = x.as_standard_layout().into_owned();
                copy.view()
            };
            conv.run_edge_padded(x, (hp, wp), dst, pool)
                .map_err(|e| model_error(path, format!("first convolution: {e}")))?;
        }
        None => {
            // Channel by channel across the pool: a copy of megabytes, memory-bound, that
            // one core alone does at half the speed of two.
            let planes = dst.chunks_mut((hp * wp).max(1));
            let copy = |(ch, dst): (usize, &mut [f32])| {
                pad_edge_into(x.slice(ndarray::s![ch..ch + 1, .., ..]), hp, wp, dst)
            };
            match pool {
                Some(pool) => {
                    use rayon::prelude::*;
                    pool.install(|| planes.enumerate().par_bridge().for_each(copy))
                }
                None => planes.enumerate().for_each(copy),
            }
        }
    }
    Ok(())
}

/// Writes slot `i` of `buffers`, a tensor of `shape`, with `fill`: the tensor there when it has
/// that shape and nothing else holds it, else a new one put there.
fn fill_input(
    path: &Path,
    buffers: &mut Vec<Arc<Tensor>>,
    i: usize,
    shape: [usize; 4],
    fill: impl FnOnce(&mut [f32]) -> Result<(), InferError>,
) -> Result<(), InferError> {
    let reusable = buffers
        .get_mut(i)
        .and_then(Arc::get_mut)
        .is_some_and(|t| t.shape() == shape);
    if !reusable {
        let t = Tensor::zero::<f32>(&shape).map_err(|e| model_error(path, chain(&e)))?;
        if i < buffers.len() {
            buffers[i] = Arc::new(t);
        } else if i == buffers.len() {
            buffers.push(Arc::new(t));
        } else {
            return Err(model_error(path, "internal: input buffers out of order"));
        }
    }
    let buffer = Arc::get_mut(&mut buffers[i])
        .ok_or_else(|| model_error(path, "internal: an input tensor is still shared"))?;
    let mut plain = buffer
        .try_as_plain_ram_mut()
        .map_err(|e| model_error(path, chain(&e)))?;
    let dst = plain
        .as_slice_mut::<f32>()
        .map_err(|e| model_error(path, chain(&e)))?;
    fill(dst)
}

/// How long a pool thread waits for work, spinning, before it goes to sleep (see [`in_pool`]).
const SPIN_LIMIT: std::time::Duration = std::time::Duration::from_millis(2);

/// Runs `f` (a plan's run) on a thread of tract's pool when it has more than one, the other
/// threads spinning for work meanwhile; else on this thread.
///
/// A plan runs its nodes one after the other; only some (matrix products, our convolutions)
/// split their work across the pool. Called from outside the pool, each such node hands its work
/// to the pool and sleeps until it is done, and between them the pool's threads go to sleep:
/// two wake-ups a node, which a virtual machine makes slow (tens of microseconds each). Run on a
/// pool thread, a node splits its work in place; and the other threads, instead of sleeping
/// between nodes, take work as soon as there is some (`rayon::yield_now`), as onnxruntime's
/// threads spin between its operators. Measured on 2 cores at 256x400 (`neuspike bench-model`,
/// alternating runs): 5-12% less time than the plan run from outside the pool.
///
/// A spinning thread stops when `f` returns, when it finds itself on `f`'s thread (it was taken
/// up there while `f` waited for other work: spinning there would wait for `f` forever), and
/// after [`SPIN_LIMIT`] without work.
fn in_pool<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    use std::sync::atomic::{AtomicBool, Ordering};
    let pool = match tract_linalg::multithread::current_tract_executor() {
        tract_linalg::multithread::Executor::MultiThread(pool)
            if pool.current_num_threads() > 1 =>
        {
            pool
        }
        _ => return f(),
    };
    pool.install(|| {
        let done = AtomicBool::new(false);
        let owner = rayon::current_thread_index();
        rayon::scope(|s| {
            for _ in 1..rayon::current_num_threads() {
                s.spawn(|_| {
                    if rayon::current_thread_index() == owner {
                        return;
                    }
                    let mut idle_since = None;
                    while !done.load(Ordering::Acquire) {
                        match rayon::yield_now() {
                            Some(rayon::Yield::Executed) => idle_since = None,
                            _ => {
                                let since = *idle_since.get_or_insert_with(std::time::Instant::now);
                                if since.elapsed() > SPIN_LIMIT {
                                    return;
                                }
                                std::hint::spin_loop();
                            }
                        }
                    }
                });
            }
            let out = f();
            done.store(true, Ordering::Release);
            out
        })
    })
}

/// The threads tract's matrix products and neuspike's convolutions split a frame across in this
/// process ([`set_threads`]): 1 when they run on the calling thread.
pub fn threads() -> usize {
    match tract_linalg::multithread::current_tract_executor() {
        tract_linalg::multithread::Executor::MultiThread(pool) => pool.current_num_threads(),
        _ => 1,
    }
}

/// Sets the number of threads tract's matrix products use, for every model of the process
/// (tract keeps one default executor): 1 runs on the calling thread; more use a private rayon
/// pool of that size. 0 is taken as 1.
pub fn set_threads(n: usize) {
    let executor = if n <= 1 {
        tract_linalg::multithread::Executor::SingleThread
    } else {
        tract_linalg::multithread::Executor::multithread(n)
    };
    tract_linalg::multithread::set_default_executor(executor);
}
