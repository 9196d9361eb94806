//! A learned model gives the same image on one thread and on two. Its own test binary (its own
//! process): the thread count is tract's, one for the whole process.

use std::path::{Path, PathBuf};

use ndarray::{Array3, Array4, ArrayView3, Axis};
use ndarray_npy::read_npy;
use neuspike_reconstruction::learned::{ConvPath, LearnedModel, set_threads};

fn model_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../../models/{name}.onnx"))
}

/// The model's reference inputs tiled 14 times across, so the full- and half-resolution layers
/// are wide enough for neuspike's convolution, `[C, H, W]` each.
fn wide_inputs(model: &LearnedModel, path: &Path) -> Vec<Array3<f32>> {
    model
        .inputs()
        .iter()
        .map(|i| {
            let file = path
                .with_extension("ref")
                .join(format!("{}.npy", i.onnx_name()));
            let a: Array4<f32> =
                read_npy(&file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
            let a = a.index_axis(Axis(0), 0);
            let tiles: Vec<_> = (0..14).map(|_| a.view()).collect();
            ndarray::concatenate(Axis(2), &tiles).expect("tiles")
        })
        .collect()
}

#[test]
fn two_threads_give_the_bits_of_one() {
    for name in ["neuspike-spike-8", "neuspike-fused-8"] {
        let path = model_path(name);
        let mut model = LearnedModel::load(&path).expect("load");
        model.set_conv_path(ConvPath::Blocked);
        let inputs = wide_inputs(&model, &path);
        let views: Vec<ArrayView3<f32>> = inputs.iter().map(|a| a.view()).collect();
        set_threads(1);
        let one = model.run(&views).expect("one thread");
        set_threads(2);
        // Several runs: the pool's threads spin between the nodes of a run and stop after it.
        for run in 0..3 {
            let two = model.run(&views).expect("two threads");
            let same = one
                .iter()
                .zip(&two)
                .all(|(a, b)| a.to_bits() == b.to_bits());
            assert!(same, "{name}, run {run}: two threads differ from one");
        }
        // The profile runs the plan the same way.
        let nodes = model.profile(&views).expect("profile");
        assert!(nodes.iter().any(|n| n.op == "NeuspikeConv3x3"), "{name}");
        set_threads(1);
    }
}
