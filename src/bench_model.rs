//! `neuspike bench-model`: latency of a learned model under tract at a chosen frame size and
//! thread counts, as the infer node runs it (shapes pinned, optimised once, padded to the
//! network's stride). The model cards' tract figures come from here; `training/bench_ort.py` times
//! the same file in onnxruntime for the ratio.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

use eyre::WrapErr;
use ndarray::Array3;

use neuspike_reconstruction::learned::{ConvPath, LearnedModel, NodeTime, Precision, set_threads};
use neuspike_simd::bf16::Bf16Path;
use neuspike_simd::dot::DotPath;

/// Latency at one thread count.
#[derive(Clone, Debug, PartialEq)]
pub struct Timing {
    /// Threads tract used.
    pub threads: usize,
    /// Median over the timed runs, milliseconds.
    pub median_ms: f64,
    /// Fastest run, milliseconds.
    pub min_ms: f64,
    /// Timed runs (after one untimed warm-up run that also plans).
    pub runs: usize,
    /// The convolution path the plan used.
    pub conv: ConvPath,
    /// The precision of its 3x3 convolutions.
    pub precision: Precision,
}

/// Every precision and path this CPU runs, `f32` first, then `bf16`'s and the 8-bit ones,
/// narrowest first.
pub fn every_precision() -> Vec<Precision> {
    let bf16 = Bf16Path::ALL.into_iter().filter(|p| p.is_supported());
    let int8 = DotPath::ALL.into_iter().filter(|p| p.is_supported());
    std::iter::once(Precision::F32)
        .chain(bf16.map(Precision::Bf16))
        .chain(int8.map(Precision::Int8))
        .collect()
}

/// The input pattern every timing uses: `[0, 1]`, a fixed pattern per channel (dense convolutions
/// cost the same whatever the values).
fn pattern_inputs(model: &LearnedModel, height: usize, width: usize) -> Vec<Array3<f32>> {
    model
        .channels()
        .iter()
        .map(|&c| {
            Array3::from_shape_fn((c, height, width), |(k, y, x)| {
                (((k * 7 + y * 3 + x) % 17) as f32) / 16.0
            })
        })
        .collect()
}

/// Where one run's time goes.
#[derive(Clone, Debug, PartialEq)]
pub struct Profile {
    /// Per node, in evaluation order: the median over the profiled runs.
    pub nodes: Vec<NodeTime>,
}

impl Profile {
    /// Total per operator kind, slowest first: `(op, ms, nodes)`.
    pub fn by_op(&self) -> Vec<(String, f64, usize)> {
        let mut ops: BTreeMap<&str, (f64, usize)> = BTreeMap::new();
        for n in &self.nodes {
            let e = ops.entry(&n.op).or_default();
            e.0 += n.ms;
            e.1 += 1;
        }
        let mut out: Vec<_> = ops
            .into_iter()
            .map(|(op, (ms, k))| (op.to_string(), ms, k))
            .collect();
        out.sort_by(|a, b| b.1.total_cmp(&a.1));
        out
    }

    /// The `k` slowest nodes.
    pub fn slowest(&self, k: usize) -> Vec<&NodeTime> {
        let mut v: Vec<&NodeTime> = self.nodes.iter().collect();
        v.sort_by(|a, b| b.ms.total_cmp(&a.ms));
        v.truncate(k);
        v
    }

    /// Sum over the nodes, milliseconds.
    pub fn total_ms(&self) -> f64 {
        self.nodes.iter().map(|n| n.ms).sum()
    }
}

/// Profiles `runs` runs on `threads` threads (after a warm-up that plans): each node's median.
pub fn profile_model(
    path: &Path,
    height: usize,
    width: usize,
    threads: usize,
    runs: usize,
    conv: ConvPath,
    precision: Precision,
) -> eyre::Result<Profile> {
    let mut model = LearnedModel::load(path).wrap_err("bench-model")?;
    model.set_conv_path(conv);
    model.set_precision(precision);
    let inputs = pattern_inputs(&model, height, width);
    let views: Vec<_> = inputs.iter().map(|a| a.view()).collect();
    set_threads(threads);
    model.run(&views).wrap_err("bench-model: warm-up run")?;
    let mut all: Vec<Vec<NodeTime>> = Vec::new();
    for _ in 0..runs.max(1) {
        all.push(model.profile(&views)?);
    }
    set_threads(1);
    // The plan is the same every run, so node i is the same node in every run.
    let nodes = (0..all[0].len())
        .map(|i| {
            let mut ms: Vec<f64> = all.iter().map(|run| run[i].ms).collect();
            ms.sort_by(f64::total_cmp);
            NodeTime {
                ms: ms[ms.len() / 2],
                ..all[0][i].clone()
            }
        })
        .collect();
    Ok(Profile { nodes })
}

/// Times `runs` runs of the model on a `height x width` frame for each thread count, on
/// [`pattern_inputs`].
pub fn time_model(
    path: &Path,
    height: usize,
    width: usize,
    threads: &[usize],
    runs: usize,
    conv: ConvPath,
    precision: Precision,
) -> eyre::Result<Vec<Timing>> {
    let loaded = LearnedModel::load(path).wrap_err("bench-model")?;
    let inputs = pattern_inputs(&loaded, height, width);
    let views: Vec<_> = inputs.iter().map(|a| a.view()).collect();
    let mut out = Vec::new();
    for &n in threads {
        // A fresh plan per thread count, as a node started with that many threads makes: `auto`
        // may choose another convolution path (tract's direct convolution runs on one thread).
        let mut model = loaded.clone();
        model.set_conv_path(conv);
        model.set_precision(precision);
        set_threads(n);
        model.run(&views).wrap_err("bench-model: warm-up run")?;
        let mut ms = Vec::with_capacity(runs);
        for _ in 0..runs.max(1) {
            let start = Instant::now();
            model.run(&views)?;
            ms.push(start.elapsed().as_secs_f64() * 1e3);
        }
        ms.sort_by(f64::total_cmp);
        out.push(Timing {
            threads: n,
            median_ms: ms[ms.len() / 2],
            min_ms: ms[0],
            runs: ms.len(),
            conv: model.conv_path_in_use().unwrap_or(conv),
            precision,
        });
    }
    set_threads(1);
    Ok(out)
}
