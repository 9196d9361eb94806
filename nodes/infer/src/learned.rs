//! The learned reconstruction: a NeuSpike-Net exported to ONNX by `training/export.py`, run with
//! tract.
//!
//! A model reads one or both of the network's representations by input name: `spike` (the
//! spike representation, represent's `spike-repr`) and `events` (the event integration,
//! represent's `event-integration`), each `[1, C, H, W]` float32, and writes `rate`
//! (`[1, 1, H, W]`, spikes per tick). [`LearnedModel::load`] reads and checks the file once;
//! [`LearnedModel::run`] pins the input shapes to the frame's size padded up to [`STRIDE`],
//! optimises and keeps that plan until the size changes, pads each input by repeating its last
//! row and column, runs, and crops the rate back. The infer node turns the rate into luminance
//! with the camera's calibration, as it does TFP's rate.
//!
//! Every failure is an [`InferError::Model`] naming the file and what is wrong: a missing,
//! unreadable or corrupt file, inputs the network does not know, a representation of the wrong
//! shape. Untrusted bytes go through tract's protobuf parser, which returns errors, not panics
//! (the fuzz target `onnx_model` feeds it arbitrary bytes).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use ndarray::{Array2, ArrayView3};
use tract_onnx::prelude::*;
use tract_onnx::tract_hir::infer::Factoid;

use crate::InferError;

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

    /// The representation kind the represent node sends for it.
    pub fn representation(self) -> &'static str {
        match self {
            LearnedInput::Spike => "spike-repr",
            LearnedInput::Events => "event-integration",
        }
    }

    /// The infer node's input id for it: the represent node's output of the same name.
    pub fn input_id(self) -> &'static str {
        match self {
            LearnedInput::Spike => "spike_repr",
            LearnedInput::Events => "event_integration",
        }
    }
}

type Plan = Arc<TypedRunnableModel>;

/// A loaded network, with its plan for the last frame size.
#[derive(Debug)]
pub struct LearnedModel {
    path: PathBuf,
    model: InferenceModel,
    inputs: Vec<LearnedInput>,
    channels: Vec<usize>,
    plan: Option<((usize, usize), Plan)>,
}

fn model_error(path: &Path, reason: impl std::fmt::Display) -> InferError {
    InferError::Model {
        path: path.to_path_buf(),
        reason: reason.to_string(),
    }
}

/// `f` of an error chain, one line.
fn chain(e: &TractError) -> String {
    format!("{e:#}").replace('\n', " ")
}

impl LearnedModel {
    /// Reads and checks `path`: every input is `spike` or `events` with a known channel count,
    /// the output is one image.
    ///
    /// # Errors
    /// [`InferError::Model`] naming the file and the problem.
    pub fn load(path: &Path) -> Result<LearnedModel, InferError> {
        let bytes =
            std::fs::read(path).map_err(|e| model_error(path, format!("cannot read: {e}")))?;
        let model = tract_onnx::onnx()
            .model_for_read(&mut bytes.as_slice())
            .map_err(|e| model_error(path, format!("not a readable ONNX model: {}", chain(&e))))?;
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
        let outputs = model
            .output_outlets()
            .map_err(|e| model_error(path, chain(&e)))?
            .len();
        if outputs != 1 {
            return Err(model_error(
                path,
                format!("{outputs} outputs; a NeuSpike-Net has one (`rate`)"),
            ));
        }
        Ok(LearnedModel {
            path: path.to_path_buf(),
            model,
            inputs,
            channels,
            plan: None,
        })
    }

    /// The inputs, in the order [`run`](Self::run) takes them.
    pub fn inputs(&self) -> &[LearnedInput] {
        &self.inputs
    }

    /// Channels each input expects.
    pub fn channels(&self) -> &[usize] {
        &self.channels
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Builds (or reuses) the plan for padded size `(h, w)`.
    fn plan_for(&mut self, h: usize, w: usize) -> Result<Plan, InferError> {
        if let Some((size, plan)) = &self.plan
            && *size == (h, w)
        {
            return Ok(plan.clone());
        }
        let mut model = self.model.clone();
        for (i, &c) in self.channels.iter().enumerate() {
            model
                .set_input_fact(i, f32::fact([1, c, h, w]).into())
                .map_err(|e| model_error(&self.path, chain(&e)))?;
        }
        let plan = model
            .into_optimized()
            .and_then(|m| m.into_runnable())
            .map_err(|e| {
                model_error(
                    &self.path,
                    format!("cannot be planned at {h}x{w}: {}", chain(&e)),
                )
            })?;
        self.plan = Some(((h, w), plan.clone()));
        Ok(plan)
    }

    /// Runs the network on one frame's representations, in [`inputs`](Self::inputs) order, each
    /// `[C, H, W]`; returns the rate `[H, W]`.
    ///
    /// # Errors
    /// [`InferError::Model`] for a wrong number of inputs, a wrong channel count, inputs of
    /// different sizes, or a failure inside the network.
    pub fn run(&mut self, xs: &[ArrayView3<f32>]) -> Result<Array2<f32>, InferError> {
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
                        x.shape()
                    ),
                ));
            }
        }
        if h == 0 || w == 0 {
            return Err(model_error(&self.path, format!("empty frame {h}x{w}")));
        }
        let (hp, wp) = (h.next_multiple_of(STRIDE), w.next_multiple_of(STRIDE));
        let plan = self.plan_for(hp, wp)?;
        let mut values = TVec::new();
        for x in xs {
            let padded = pad_edge(*x, hp, wp);
            let c = x.dim().0;
            // The padded buffer becomes the tensor's storage: no second copy.
            let t = tract_ndarray::Array4::from_shape_vec((1, c, hp, wp), padded)
                .map_err(|e| model_error(&self.path, e))?
                .into_tensor();
            values.push(t.into_tvalue());
        }
        let out = plan
            .run(values)
            .map_err(|e| model_error(&self.path, format!("run at {hp}x{wp}: {}", chain(&e))))?;
        let plain = out[0]
            .try_as_plain_ram()
            .map_err(|e| model_error(&self.path, chain(&e)))?;
        let rate = plain
            .as_slice::<f32>()
            .map_err(|e| model_error(&self.path, chain(&e)))?;
        if rate.len() != hp * wp {
            return Err(model_error(
                &self.path,
                format!("output has {} values, expected {hp}x{wp}", rate.len()),
            ));
        }
        Ok(Array2::from_shape_fn((h, w), |(y, x)| rate[y * wp + x]))
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

/// `x` (`[C, H, W]`) padded to `[C, hp, wp]` by repeating its last row and column, row-major.
pub fn pad_edge(x: ArrayView3<f32>, hp: usize, wp: usize) -> Vec<f32> {
    let (c, h, w) = x.dim();
    let mut out = Vec::with_capacity(c * hp * wp);
    for ch in 0..c {
        for y in 0..hp {
            let row = x.slice(ndarray::s![ch, y.min(h.saturating_sub(1)), ..]);
            out.extend(row.iter().copied());
            let last = row.last().copied().unwrap_or(0.0);
            out.extend(std::iter::repeat_n(last, wp - w));
        }
    }
    out
}
