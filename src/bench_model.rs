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

/// The median of `ms` (sorted in place); `ms` is not empty.
fn median(ms: &mut [f64]) -> f64 {
    ms.sort_by(f64::total_cmp);
    ms[ms.len() / 2]
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
            NodeTime {
                ms: median(&mut ms),
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
        out.push(Timing {
            threads: n,
            median_ms: median(&mut ms),
            min_ms: ms[0],
            runs: ms.len(),
            conv: model.conv_path_in_use().unwrap_or(conv),
            precision,
        });
    }
    set_threads(1);
    Ok(out)
}

/// A network's frame of an aligned window, two ways, per thread count: its representations made
/// as the represent stage makes them (`f32`, `[C, H, W]`) then the network run on them, and the
/// window read by the network itself (`LearnedModel::run_window`: the raw planes bit-packed, the
/// events themselves where few). `(threads, representation then network ms, from the window ms)`, medians
/// of `runs` runs each, the two alternated.
#[derive(Clone, Debug, PartialEq)]
pub struct FromWindow {
    /// Threads tract used.
    pub threads: usize,
    /// Median, the representation made then the network, milliseconds.
    pub represented_ms: f64,
    /// Median, the network reading the window, milliseconds.
    pub window_ms: f64,
}

/// Times [`FromWindow`] on a window of 33 planes of `height x width` with about a quarter of
/// the pixels set in each (a fixed pattern) and `events` events spread over its pixels and
/// time (a fixed pattern; read by a network with an event input).
///
/// # Errors
/// The model does not load or fails to run.
pub fn time_from_window(
    path: &Path,
    (height, width): (usize, usize),
    threads: &[usize],
    runs: usize,
    conv: ConvPath,
    precision: Precision,
    events: usize,
) -> eyre::Result<Vec<FromWindow>> {
    use neuspike_representations::Representer;
    use neuspike_schemas::{AlignedWindow, EventBatch, SpikeChunk};
    let loaded = LearnedModel::load(path).wrap_err("bench-model")?;
    const PLANES: usize = 33;
    const PERIOD_NS: i64 = 50_000;
    let per = (height * width).div_ceil(8);
    let bits: Vec<u8> = (0..PLANES * per)
        .map(|i| {
            // Two bytes of a multiplicative hash and-ed: each bit set with probability 1/4.
            let h = (i as u32).wrapping_mul(2_654_435_761);
            (h >> 8) as u8 & (h >> 16) as u8
        })
        .collect();
    let spikes = SpikeChunk {
        width,
        height,
        first_plane: 0,
        n_planes: PLANES,
        t_first_ns: 0,
        plane_period_ns: PERIOD_NS,
        seq: 0,
        bits,
        lum_per_rate: Some(1.0),
    };
    let span_ns = PERIOD_NS * PLANES as i64;
    let mut batch = EventBatch::empty(width, height, 0, span_ns, 0);
    for i in 0..events {
        let h = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 16;
        batch.t_ns.push(i as i64 * span_ns / events.max(1) as i64);
        batch.x.push((h % width.max(1) as u64) as u16);
        batch.y.push(((h >> 20) % height.max(1) as u64) as u16);
        batch.polarity.push(if h >> 40 & 1 == 1 { 1 } else { -1 });
    }
    let window = AlignedWindow {
        t_ref_ns: spikes.plane_time_ns(PLANES / 2),
        ref_plane: (PLANES / 2) as u64,
        spikes,
        events: batch,
    };
    let mut represent = Representer::new(loaded.represent_config())?;
    let mut out = Vec::new();
    for &n in threads {
        let mut model = loaded.clone();
        model.set_conv_path(conv);
        model.set_precision(precision);
        set_threads(n);
        let mut represented = |model: &mut LearnedModel| -> eyre::Result<f64> {
            let start = Instant::now();
            let reps = model
                .inputs()
                .iter()
                .map(|i| represent.represent(i.representation(), &window))
                .collect::<Result<Vec<_>, _>>()?;
            let views: Vec<_> = reps.iter().map(|r| r.data.view()).collect();
            model.run(&views)?;
            Ok(start.elapsed().as_secs_f64() * 1e3)
        };
        represented(&mut model).wrap_err("bench-model: warm-up run")?;
        let (mut a, mut b) = (Vec::new(), Vec::new());
        let mut win_represent = Representer::new(loaded.represent_config())?;
        for _ in 0..runs.max(1) {
            a.push(represented(&mut model)?);
            let start = Instant::now();
            model.run_window(&window, &mut win_represent)?;
            b.push(start.elapsed().as_secs_f64() * 1e3);
        }
        out.push(FromWindow {
            threads: n,
            represented_ms: median(&mut a),
            window_ms: median(&mut b),
        });
    }
    set_threads(1);
    Ok(out)
}
