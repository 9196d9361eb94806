//! `neuspike bench-model`: latency of a learned model under tract at a chosen frame size and
//! thread counts, as the infer node runs it (shapes pinned, optimised once, padded to the
//! network's stride). The model cards' tract figures come from here; `training/bench_ort.py` times
//! the same file in onnxruntime for the ratio.

use std::path::Path;
use std::time::Instant;

use eyre::WrapErr;
use ndarray::Array3;
use neuspike_infer::learned::{LearnedModel, set_threads};

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
}

/// Times `runs` runs of the model on a `height x width` frame for each thread count. The inputs
/// are a fixed pattern in `[0, 1]` (dense convolutions cost the same whatever the values).
pub fn time_model(
    path: &Path,
    height: usize,
    width: usize,
    threads: &[usize],
    runs: usize,
) -> eyre::Result<Vec<Timing>> {
    let mut model = LearnedModel::load(path).wrap_err("bench-model")?;
    let inputs: Vec<Array3<f32>> = model
        .channels()
        .iter()
        .map(|&c| {
            Array3::from_shape_fn((c, height, width), |(k, y, x)| {
                (((k * 7 + y * 3 + x) % 17) as f32) / 16.0
            })
        })
        .collect();
    let views: Vec<_> = inputs.iter().map(|a| a.view()).collect();
    let mut out = Vec::new();
    for &n in threads {
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
        });
    }
    set_threads(1);
    Ok(out)
}
