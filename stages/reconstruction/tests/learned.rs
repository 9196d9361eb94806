//! The shipped ONNX models under tract: each reproduces the PyTorch output `training/export.py`
//! saved beside it, and bad models and bad inputs give errors that name the file.

use std::path::{Path, PathBuf};

use ndarray::{Array3, Array4, ArrayView3, Axis, s};
use ndarray_npy::read_npy;
use neuspike_reconstruction::InferError;
use neuspike_reconstruction::learned::{
    ConvPath, LearnedInput, LearnedModel, LearnedOutput, Precision, STRIDE, network_variant,
    pad_edge,
};
use prost::Message;
use tract_onnx::prelude::Framework;

fn models_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models")
}

/// Every `models/*.onnx`, sorted.
fn shipped() -> Vec<PathBuf> {
    let mut out: Vec<PathBuf> = std::fs::read_dir(models_dir())
        .expect("models/")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "onnx"))
        .collect();
    out.sort();
    out
}

fn reference(model: &Path, name: &str) -> Array4<f32> {
    let path = model.with_extension("ref").join(format!("{name}.npy"));
    read_npy(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The reference input of each of the model's inputs, `[1, C, H, W]`.
fn reference_inputs(model: &LearnedModel, path: &Path) -> Vec<Array4<f32>> {
    model
        .inputs()
        .iter()
        .map(|i| reference(path, i.onnx_name()))
        .collect()
}

fn max_diff<'a>(a: impl IntoIterator<Item = &'a f32>, b: impl IntoIterator<Item = &'a f32>) -> f32 {
    a.into_iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0f32, f32::max)
}

#[test]
fn every_shipped_model_reproduces_its_pytorch_reference() {
    let models = shipped();
    assert!(
        !models.is_empty(),
        "no models in {}",
        models_dir().display()
    );
    for path in models {
        let mut model = LearnedModel::load(&path).expect("load");
        let inputs = reference_inputs(&model, &path);
        let views: Vec<ArrayView3<f32>> = inputs.iter().map(|a| a.index_axis(Axis(0), 0)).collect();
        let want = reference(&path, model.output().onnx_name());
        let got = model.run(&views).expect("run");
        assert_eq!(
            got.dim(),
            (want.shape()[2], want.shape()[3]),
            "{}",
            path.display()
        );
        let diff = max_diff(&got, &want);
        assert!(
            diff < 1e-4,
            "{}: tract differs from PyTorch by {diff}",
            path.display()
        );
        // Rates and luminances both come out of a sigmoid: in [0, 1], and not all the same.
        assert!(got.iter().all(|r| (0.0..=1.0).contains(r)));
        let (lo, hi) = got
            .iter()
            .fold((1.0f32, 0.0f32), |(l, h), &r| (l.min(r), h.max(r)));
        assert!(hi - lo > 1e-3, "{}: a flat output", path.display());
    }
}

#[test]
fn sizes_that_are_not_multiples_of_the_stride_are_padded_and_cropped() {
    let path = &shipped()[0];
    let mut model = LearnedModel::load(path).expect("load");
    let inputs = reference_inputs(&model, path);
    // 13 x 21 of the 16 x 24 reference: the network sees it padded back to 16 x 24 by repeating
    // the last row and column, so the output is that of the padded input, cropped.
    let cut: Vec<Array3<f32>> = inputs
        .iter()
        .map(|a| a.slice(s![0, .., ..13, ..21]).to_owned())
        .collect();
    let views: Vec<ArrayView3<f32>> = cut.iter().map(|a| a.view()).collect();
    let got = model.run(&views).expect("run 13x21");
    assert_eq!(got.dim(), (13, 21));
    let padded: Vec<Array3<f32>> = cut
        .iter()
        .map(|a| {
            let c = a.dim().0;
            Array3::from_shape_vec((c, 16, 24), pad_edge(a.view(), 16, 24)).expect("shape")
        })
        .collect();
    let views: Vec<ArrayView3<f32>> = padded.iter().map(|a| a.view()).collect();
    let full = model.run(&views).expect("run 16x24");
    let diff = full
        .slice(s![..13, ..21])
        .iter()
        .zip(got.iter())
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(diff < 1e-6, "crop differs by {diff}");
    // A second size replans, and going back still works.
    let small: Vec<Array3<f32>> = inputs
        .iter()
        .map(|a| a.slice(s![0, .., ..8, ..8]).to_owned())
        .collect();
    let views: Vec<ArrayView3<f32>> = small.iter().map(|a| a.view()).collect();
    assert_eq!(model.run(&views).expect("8x8").dim(), (8, 8));
    assert_eq!(STRIDE, 8);
}

#[test]
fn pad_edge_repeats_the_last_row_and_column() {
    let x = Array3::from_shape_fn((2, 2, 3), |(c, y, x)| (c * 100 + y * 10 + x) as f32);
    let p = pad_edge(x.view(), 3, 4);
    let p = Array3::from_shape_vec((2, 3, 4), p).expect("shape");
    assert_eq!(p[[1, 0, 0]], 100.0);
    assert_eq!(p[[0, 1, 3]], 12.0);
    assert_eq!(p[[0, 2, 1]], 11.0);
    assert_eq!(p[[1, 2, 3]], 112.0);
}

fn model_error(e: InferError) -> (PathBuf, String) {
    match e {
        InferError::Model { path, reason } => (path, reason),
        other => panic!("expected a model error, got {other}"),
    }
}

#[test]
fn a_missing_or_corrupt_file_is_refused_by_name() {
    let dir = tempfile::tempdir().expect("tempdir");
    let missing = dir.path().join("nope.onnx");
    let (path, reason) = model_error(LearnedModel::load(&missing).expect_err("missing"));
    assert_eq!(path, missing);
    assert!(reason.contains("cannot read"), "{reason}");

    let bytes = std::fs::read(&shipped()[0]).expect("read");
    for (name, data) in [
        ("empty.onnx", Vec::new()),
        ("truncated.onnx", bytes[..bytes.len() / 3].to_vec()),
        ("text.onnx", b"not a model at all".to_vec()),
    ] {
        let p = dir.path().join(name);
        std::fs::write(&p, &data).expect("write");
        let err = LearnedModel::load(&p).expect_err(name);
        let msg = err.to_string();
        assert!(msg.contains(name), "{name}: {msg}");
    }
}

/// A model file is untrusted: a tensor that claims more bytes than it holds (here 4 TiB from none)
/// is refused by name before tract allocates it, and a file over the size limit is refused
/// before it is read whole.
#[test]
fn a_model_is_read_within_what_its_bytes_hold() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut proto = tract_onnx::onnx()
        .proto_model_for_path(&shipped()[0])
        .expect("proto");
    let graph = proto.graph.as_mut().expect("graph");
    let t = graph.initializer.first_mut().expect("an initializer");
    t.dims = vec![1 << 20, 1 << 20];
    let name = t.name.clone();
    let p = dir.path().join("claims.onnx");
    std::fs::write(&p, proto.encode_to_vec()).expect("write");
    let (path, reason) = model_error(LearnedModel::load(&p).expect_err("a forged tensor"));
    assert_eq!(path, p);
    assert!(
        reason.contains(&format!("tensor `{name}` claims [1048576, 1048576]"))
            && reason.contains("4398046511104 bytes"),
        "{reason}"
    );
    let size = std::fs::metadata(&shipped()[0]).expect("size").len();
    let (_, reason) = model_error(
        LearnedModel::load_at_most(&shipped()[0], size - 1).expect_err("one byte too many"),
    );
    assert!(
        reason.contains(&format!("larger than {} bytes", size - 1)),
        "{reason}"
    );
    LearnedModel::load_at_most(&shipped()[0], size).expect("exactly the limit");
}

enum Io {
    Input,
    Output,
}

/// The first shipped model with its first input or output renamed to `name`, written into `dir`.
fn renamed(dir: &Path, io: Io, name: &str) -> PathBuf {
    let mut proto = tract_onnx::onnx()
        .proto_model_for_path(&shipped()[0])
        .expect("proto");
    let graph = proto.graph.as_mut().expect("graph");
    let slot = match io {
        Io::Input => &mut graph.input[0],
        Io::Output => &mut graph.output[0],
    };
    let old = std::mem::replace(&mut slot.name, name.into());
    for node in &mut graph.node {
        for wire in node.input.iter_mut().chain(node.output.iter_mut()) {
            if *wire == old {
                *wire = name.into();
            }
        }
    }
    let p = dir.join(format!("{name}.onnx"));
    std::fs::write(&p, proto.encode_to_vec()).expect("write");
    p
}

/// Loading the renamed model fails naming the file, the name, and `hint` (what it should be).
fn refused_when_renamed(io: Io, name: &str, hint: &str) {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = renamed(dir.path(), io, name);
    let (path, reason) = model_error(LearnedModel::load(&p).expect_err(name));
    assert_eq!(path, p);
    assert!(
        reason.contains(&format!("`{name}`")) && reason.contains(hint),
        "{reason}"
    );
}

#[test]
fn a_model_whose_inputs_are_not_the_representations_is_refused() {
    refused_when_renamed(Io::Input, "voxels", "spike");
}

#[test]
fn representations_of_the_wrong_shape_are_refused_before_running() {
    let path = &shipped()[0];
    let mut model = LearnedModel::load(path).expect("load");
    let n = model.inputs().len();
    let c = model.channels()[0];
    // Wrong channel count.
    let x = Array3::<f32>::zeros((c + 1, 16, 16));
    let views: Vec<ArrayView3<f32>> = (0..n).map(|_| x.view()).collect();
    let (_, reason) = model_error(model.run(&views).expect_err("channels"));
    assert!(
        reason.contains(&format!("[{}, 16, 16]", c + 1)) || reason.contains("shape"),
        "{reason}"
    );
    // Too few inputs.
    let ok = Array3::<f32>::zeros((c, 16, 16));
    if n > 1 {
        let (_, reason) = model_error(model.run(&[ok.view()]).expect_err("count"));
        assert!(reason.contains("1 representations given"), "{reason}");
    }
    // Inputs of different sizes.
    if n > 1 {
        let other = Array3::<f32>::zeros((model.channels()[1], 16, 24));
        let (_, reason) = model_error(model.run(&[ok.view(), other.view()]).expect_err("sizes"));
        assert!(
            reason.contains("[32, 16, 24]") || reason.contains("wants"),
            "{reason}"
        );
    }
    // The inputs name the representations the represent node makes.
    for i in model.inputs() {
        assert!(matches!(i, LearnedInput::Spike | LearnedInput::Events));
        assert_eq!(i.input_id(), i.representation().name());
        assert!(["spike_repr", "event_integration"].contains(&i.input_id()));
    }
}

#[test]
fn the_output_name_says_its_unit_and_an_unknown_one_is_refused() {
    // Networks that read spikes predict a rate; the event-only one predicts luminance.
    for path in shipped() {
        let model = LearnedModel::load(&path).expect("load");
        let want = if model.inputs().contains(&LearnedInput::Spike) {
            LearnedOutput::Rate
        } else {
            LearnedOutput::Luminance
        };
        assert_eq!(model.output(), want, "{}", path.display());
    }
    refused_when_renamed(Io::Output, "depth", "luminance");
}

#[test]
fn both_convolution_paths_reproduce_the_reference_and_auto_keeps_one() {
    for path in shipped() {
        let inputs = reference_inputs(&LearnedModel::load(&path).expect("load"), &path);
        let views: Vec<ArrayView3<f32>> = inputs.iter().map(|a| a.index_axis(Axis(0), 0)).collect();
        for conv in [
            ConvPath::Direct,
            ConvPath::Im2col,
            ConvPath::Blocked,
            ConvPath::Auto,
        ] {
            let mut model = LearnedModel::load(&path).expect("load");
            model.set_conv_path(conv);
            assert_eq!(model.conv_path_in_use(), None);
            let want = reference(&path, model.output().onnx_name());
            let got = model.run(&views).expect("run");
            let diff = max_diff(&got, &want);
            assert!(
                diff < 1e-4,
                "{} ({conv}): differs by {diff}",
                path.display()
            );
            let used = model.conv_path_in_use().expect("planned");
            if conv == ConvPath::Auto {
                assert_ne!(used, ConvPath::Auto);
            } else {
                assert_eq!(used, conv);
            }
        }
    }
    assert_eq!("im2col".parse::<ConvPath>(), Ok(ConvPath::Im2col));
    assert_eq!("blocked".parse::<ConvPath>(), Ok(ConvPath::Blocked));
    assert_eq!(ConvPath::default().to_string(), "auto");
    let err = "fast".parse::<ConvPath>().unwrap_err();
    assert!(err.contains("`fast`") && err.contains("im2col"), "{err}");
}

#[test]
fn neuspikes_convolution_computes_what_tracts_does_on_wide_frames() {
    // The reference frames are 24 wide, narrower than the rows `conv3x3` takes over: repeat
    // them to 336 so the full- and half-resolution layers run on it.
    for path in shipped() {
        let wide = wide_reference_inputs(&path);
        // Also 13x333, neither a multiple of the stride: the first convolution, which reads the
        // representation in place (not a padded copy), pads it.
        for (h, w) in [(16, 336), (13, 333)] {
            let views: Vec<ArrayView3<f32>> =
                wide.iter().map(|a| a.slice(s![.., ..h, ..w])).collect();
            same_on_both_paths(&path, &views);
        }
    }
}

/// The reference inputs of `path`, 24 points wide, repeated side by side to 336: wide enough for
/// neuspike's convolutions to take every full- and half-resolution layer.
fn wide_reference_inputs(path: &Path) -> Vec<Array3<f32>> {
    reference_inputs(&LearnedModel::load(path).expect("load"), path)
        .iter()
        .map(|a| {
            let a = a.index_axis(Axis(0), 0);
            let tiles: Vec<_> = (0..14).map(|_| a.view()).collect();
            ndarray::concatenate(Axis(2), &tiles).expect("tiles")
        })
        .collect()
}

/// `path`'s image on `views` is the same whether tract or neuspike computes the convolutions.
fn same_on_both_paths(path: &Path, views: &[ArrayView3<f32>]) {
    let mut outputs = Vec::new();
    for conv in [ConvPath::Direct, ConvPath::Blocked] {
        let mut model = LearnedModel::load(path).expect("load");
        model.set_conv_path(conv);
        let ops: Vec<String> = model
            .profile(views)
            .expect("profile")
            .into_iter()
            .map(|t| t.op)
            .collect();
        let ours = ops.iter().filter(|op| *op == "NeuspikeConv3x3").count();
        let blocked = usize::from(conv == ConvPath::Blocked);
        // A `-lite` network's decoder stops at half resolution (models/README.md): one scale
        // fewer, and a sub-pixel output in place of the depthwise one.
        let lite = path
            .file_stem()
            .is_some_and(|s| s.to_string_lossy().ends_with("-lite"));
        let scales = if lite { 2 } else { 3 };
        // The decoder's upsamplings and the attention of its skip connections, whatever the
        // width.
        let count = |name: &str| ops.iter().filter(|op| *op == name).count();
        for name in ["NeuspikeDeconv2x2", "NeuspikeSpatialAttention"] {
            assert_eq!(
                count(name),
                scales * blocked,
                "{name} in {} ({conv})",
                path.display()
            );
        }
        // The channel attention of each fusion (one path or two, summed): those of the skips
        // formed inside their spatial attention, the deepest (which the residual blocks read)
        // as an operator of its own.
        assert_eq!(count("NeuspikeScaledSum"), blocked, "{}", path.display());
        // The depthwise convolution, the 1x1 convolution and the sigmoid at the end (or the
        // sub-pixel shuffle, the heads' 1x1 convolutions and the sigmoid): one pass.
        let (depthwise, subpixel) = if lite { (0, blocked) } else { (blocked, 0) };
        assert_eq!(
            count("NeuspikeDepthwiseOut"),
            depthwise,
            "{}",
            path.display()
        );
        assert_eq!(count("NeuspikeSubpixelOut"), subpixel, "{}", path.display());
        // The merges read their two inputs in place; the attention's maps are its own: no
        // concatenation is left.
        if conv == ConvPath::Blocked {
            assert_eq!(count("Concat"), 0, "{}", path.display());
        } else {
            assert!(count("Concat") >= 2 * scales, "{}", path.display());
        }
        if conv == ConvPath::Blocked {
            assert!(
                ours >= 3,
                "{}: {ours} convolutions of neuspike's",
                path.display()
            );
        } else {
            assert_eq!(ours, 0);
        }
        outputs.push(model.run(views).expect("run"));
    }
    let diff = max_diff(&outputs[0], &outputs[1]);
    assert!(
        diff < 1e-4,
        "{} at {:?}: blocked differs from direct by {diff}",
        path.display(),
        views[0].shape()
    );
}

#[test]
fn a_profile_times_every_node_of_the_plan_and_the_padding() {
    let path = &shipped()[0];
    let mut model = LearnedModel::load(path).expect("load");
    let inputs = reference_inputs(&model, path);
    let views: Vec<ArrayView3<f32>> = inputs.iter().map(|a| a.index_axis(Axis(0), 0)).collect();
    let nodes = model.profile(&views).expect("profile");
    assert_eq!(nodes[0].op, "(inputs)");
    assert!(nodes.iter().all(|n| n.ms >= 0.0 && n.ms.is_finite()));
    // A network of convolutions: most of the plan is convolution or matrix product nodes.
    let convs = nodes
        .iter()
        .filter(|n| n.op.contains("Conv") || n.op.contains("MatMul"))
        .count();
    assert!(convs >= 10, "{convs} convolution nodes of {}", nodes.len());
}

#[test]
fn reused_input_tensors_never_leak_one_frame_into_the_next() {
    let path = &shipped()[0];
    let mut model = LearnedModel::load(path).expect("load");
    let a = reference_inputs(&model, path);
    let b: Vec<Array4<f32>> = a.iter().map(|x| x.mapv(|v| 1.0 - v)).collect();
    let view = |xs: &[Array4<f32>]| -> Vec<Array3<f32>> {
        xs.iter()
            .map(|x| x.index_axis(Axis(0), 0).to_owned())
            .collect()
    };
    let (a3, b3) = (view(&a), view(&b));
    let run = |m: &mut LearnedModel, xs: &[Array3<f32>]| {
        let v: Vec<ArrayView3<f32>> = xs.iter().map(|x| x.view()).collect();
        m.run(&v).expect("run")
    };
    let first = run(&mut model, &a3);
    let other = run(&mut model, &b3);
    let again = run(&mut model, &a3);
    assert_eq!(first, again);
    assert_ne!(first, other);
    // A clone shares nothing it could overwrite under the original.
    let mut copy = model.clone();
    assert_eq!(run(&mut copy, &b3), other);
    assert_eq!(run(&mut model, &a3), first);
}

/// In 8 bits and in `bf16`, every shipped network gives nearly the `f32` image on its reference
/// input widened so that every layer runs neuspike's kernels: the PSNR of the image against the
/// `f32` one, peak the `f32` image's largest value, at least 45 dB in 8 bits and
/// `BF16_PSNR_DB` in `bf16`. The accuracy that counts (against the ground truth, on the held-out
/// scenes) is in each model's card.
#[test]
fn in_8_bits_and_bf16_every_shipped_network_stays_close_to_its_f32_image() {
    /// The least PSNR of an 8-bit image against the `f32` one.
    const INT8_PSNR_DB: f64 = 45.0;
    /// The least PSNR of a `bf16` image against the `f32` one.
    const BF16_PSNR_DB: f64 = 55.0;
    for path in shipped() {
        let wide = wide_reference_inputs(&path);
        let views: Vec<ArrayView3<f32>> = wide.iter().map(|a| a.view()).collect();
        let mut model = LearnedModel::load(&path).expect("load");
        let exact = model.run(&views).expect("f32 run");
        for (precision, least) in [
            (Precision::int8(), INT8_PSNR_DB),
            (Precision::bf16(), BF16_PSNR_DB),
        ] {
            model.set_precision(precision);
            let ops: Vec<String> = model
                .profile(&views)
                .expect("profile")
                .into_iter()
                .map(|t| t.op)
                .collect();
            assert!(
                ops.iter().filter(|op| *op == "NeuspikeConv3x3").count() >= 3,
                "{}: {ops:?}",
                path.display()
            );
            let got = model.run(&views).expect("run");
            let peak = exact.iter().fold(0f32, |m, &v| m.max(v.abs())) as f64;
            let mse = exact
                .iter()
                .zip(&got)
                .map(|(&a, &b)| (a as f64 - b as f64).powi(2))
                .sum::<f64>()
                / exact.len() as f64;
            let psnr = 10.0 * (peak * peak / mse.max(f64::MIN_POSITIVE)).log10();
            eprintln!("{}: {precision} against f32 {psnr:.2} dB", path.display());
            assert!(
                psnr >= least,
                "{}: {precision} against f32 {psnr:.2} dB",
                path.display()
            );
        }
    }
}

#[test]
fn eight_bits_refuse_tracts_own_convolutions_by_name() {
    let path = models_dir().join("neuspike-spike-8.onnx");
    let mut model = LearnedModel::load(&path).expect("load");
    let inputs = reference_inputs(&model, &path);
    let views: Vec<ArrayView3<f32>> = inputs.iter().map(|a| a.index_axis(Axis(0), 0)).collect();
    model.set_precision(Precision::int8());
    model.set_conv_path(ConvPath::Direct);
    let err = model
        .run(&views)
        .expect_err("int8 on tract's convolution")
        .to_string();
    assert!(
        err.contains("neuspike-spike-8.onnx") && err.contains("int8") && err.contains("direct"),
        "{err}"
    );
    model.set_conv_path(ConvPath::Auto);
    model
        .run(&views)
        .expect("int8 on auto plans neuspike's kernels");
    assert_eq!(model.conv_path_in_use(), Some(ConvPath::Blocked));
}

#[test]
fn an_8_bit_method_is_its_networks_file_in_8_bits() {
    assert_eq!(
        network_variant("neuspike-spike-8-int8"),
        ("neuspike-spike-8", Precision::int8())
    );
    assert_eq!(
        network_variant("neuspike-spike-8"),
        ("neuspike-spike-8", Precision::F32)
    );
    assert_eq!(
        network_variant("neuspike-fused-8-bf16"),
        ("neuspike-fused-8", Precision::bf16())
    );
    // The suffix alone names no network.
    assert_eq!(network_variant("-int8"), ("-int8", Precision::F32));
    assert_eq!(network_variant("-bf16"), ("-bf16", Precision::F32));
}

#[test]
fn plain_loops_in_a_reduced_precision_run_f32() {
    use neuspike_reconstruction::learned::effective_precision;
    use neuspike_simd::{bf16::Bf16Path, dot::DotPath};
    assert_eq!(
        effective_precision(Precision::Int8(DotPath::Portable)),
        Precision::F32
    );
    assert_eq!(
        effective_precision(Precision::Bf16(Bf16Path::Portable)),
        Precision::F32
    );
    for p in [
        Precision::F32,
        Precision::Int8(DotPath::Vnni),
        Precision::Int8(DotPath::Amx),
        Precision::Bf16(Bf16Path::Avx512),
    ] {
        assert_eq!(effective_precision(p), p);
    }
}

/// A spike network given its raw planes bit-packed, as a window holds them
/// (`LearnedModel::run_inputs`), makes the frame it makes on the same planes unpacked to
/// 0.0/1.0, bit for bit, in every precision (in 8 bits the first convolution reads the bits).
#[test]
fn packed_spike_planes_give_the_unpacked_frame() {
    use neuspike_reconstruction::learned::ModelInput;
    use neuspike_tract_ops::conv3x3::packed_plane_bytes;
    let spike_only = shipped().into_iter().filter(|p| {
        let model = LearnedModel::load(p).expect("load");
        model.inputs() == [LearnedInput::Spike]
    });
    let mut tested = 0;
    for path in spike_only {
        let wide = wide_reference_inputs(&path).remove(0);
        // Rows a size that is padded, planes of the reference's values thresholded.
        let (c, h, w) = wide.dim();
        let h = h - 3;
        let mut dense = wide.slice(s![..1, ..h, ..]).to_owned();
        dense.mapv_inplace(|v| v.abs());
        let per = packed_plane_bytes(h, w);
        let mut bits = vec![0u8; (c - 1) * per];
        let mut all = Array3::<f32>::zeros((c, h, w));
        all.slice_mut(s![..1, .., ..]).assign(&dense);
        for k in 0..c - 1 {
            for i in 0..h * w {
                if wide[[k + 1, i / w, i % w]] > 0.5 {
                    bits[k * per + i / 8] |= 1 << (i % 8);
                    all[[k + 1, i / w, i % w]] = 1.0;
                }
            }
        }
        let mut model = LearnedModel::load(&path).expect("load");
        let exact = model.run(&[all.view()]).expect("unpacked, f32");
        // Off the `f32` frame: the largest and the mean difference.
        let off = |a: &ndarray::Array2<f32>| {
            let d: Vec<f32> = a.iter().zip(&exact).map(|(a, b)| (a - b).abs()).collect();
            let max = d.iter().copied().fold(0.0f32, f32::max);
            (max, d.iter().sum::<f32>() / d.len() as f32)
        };
        for precision in [Precision::F32, Precision::int8(), Precision::bf16()] {
            model.set_precision(precision);
            let want = model.run(&[all.view()]).expect("unpacked");
            let packed = ModelInput::Packed {
                dense: dense.view(),
                bits: &bits,
                planes: c - 1,
            };
            let got = model.run_inputs(&[packed]).expect("packed");
            // Read by tables (AVX-512) the first convolution is the `f32` one, whatever the
            // precision: the frame stays as near the `f32` frame as the precision's own error,
            // or within `tol` of it (in `f32`, the same up to the order of the sums); elsewhere
            // it is the unpacked planes' frame.
            let ((got_max, got_mean), (want_max, want_mean)) = (off(&got), off(&want));
            let tol = if precision == Precision::F32 {
                1e-4
            } else {
                1e-3
            };
            assert!(
                got_max <= want_max.max(tol) && got_mean <= want_mean.max(tol / 10.0),
                "{} in {precision}: off the f32 frame by {got_max} (mean {got_mean}) read \
                 packed, {want_max} (mean {want_mean}) unpacked",
                path.display()
            );
            // Too few bytes: an error naming the file, nothing run.
            let short = ModelInput::Packed {
                dense: dense.view(),
                bits: &bits[..bits.len() - 1],
                planes: c - 1,
            };
            let (file, reason) = model_error(model.run_inputs(&[short]).expect_err("short"));
            assert_eq!(file, path);
            assert!(reason.contains("packed planes"), "{reason}");
        }
        tested += 1;
    }
    assert!(tested >= 2, "{tested} spike-only networks");
}

/// A window of 33 planes of 250x400 (about a quarter of the pixels set in each, a fixed pattern)
/// and `events` events over its pixels and time (some on the edge row and column).
fn window_with_events(events: usize) -> neuspike_schemas::AlignedWindow {
    use neuspike_schemas::{AlignedWindow, EventBatch, SpikeChunk};
    let (planes, h, w, period) = (33usize, 250usize, 400usize, 50_000i64);
    let per = (h * w).div_ceil(8);
    let bits = (0..planes * per)
        .map(|i| {
            let k = (i as u32).wrapping_mul(2_654_435_761);
            (k >> 8) as u8 & (k >> 16) as u8
        })
        .collect();
    let spikes = SpikeChunk {
        width: w,
        height: h,
        first_plane: 0,
        n_planes: planes,
        t_first_ns: 0,
        plane_period_ns: period,
        seq: 0,
        bits,
        lum_per_rate: Some(1.0),
    };
    let span = period * planes as i64;
    let mut batch = EventBatch::empty(w, h, 0, span, 0);
    for i in 0..events {
        let k = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 16;
        batch.t_ns.push(i as i64 * span / events as i64);
        batch.x.push(if i % 11 == 0 {
            w as u16 - 1
        } else {
            (k % w as u64) as u16
        });
        batch.y.push(if i % 13 == 0 {
            h as u16 - 1
        } else {
            ((k >> 20) % h as u64) as u16
        });
        batch.polarity.push(if k >> 40 & 1 == 1 { 1 } else { -1 });
    }
    AlignedWindow {
        t_ref_ns: spikes.plane_time_ns(planes / 2),
        ref_plane: (planes / 2) as u64,
        spikes,
        events: batch,
    }
}

/// A network reading spikes and events from the window itself (its spike planes by tables or as
/// bits, its events' convolution added event by event while they are few, the integration made
/// first when they are many) gives the frame of the representations made then run, in `f32`
/// within 1e-3 (the first convolutions' sums in another order).
#[test]
fn a_fused_network_reads_the_windows_events_themselves() {
    use neuspike_representations::Representer;
    let path = models_dir().join("neuspike-fused-8-lite.onnx");
    let mut model = LearnedModel::load(&path).expect("load");
    let mut represent = Representer::new(model.represent_config()).expect("represent");
    // 4,000 events (few: from the events) and 30,000 (many: the integration made first).
    for events in [4_000, 30_000] {
        let win = window_with_events(events);
        let reps: Vec<_> = model
            .inputs()
            .iter()
            .map(|i| {
                represent
                    .represent(i.representation(), &win)
                    .expect("represented")
            })
            .collect();
        let views: Vec<_> = reps.iter().map(|r| r.data.view()).collect();
        let want = model.run(&views).expect("represented run");
        let got = model
            .run_window(&win, &mut represent)
            .expect("from the window");
        assert_eq!(got.dim(), want.dim());
        let off = got
            .iter()
            .zip(&want)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(off <= 1e-3, "{events} events: off by {off}");
        // The events matter: without them the frame is another.
        let mut quiet = win.clone();
        quiet.events = neuspike_schemas::EventBatch::empty(400, 250, 0, win.events.t_end_ns, 0);
        let silent = model.run_window(&quiet, &mut represent).expect("no events");
        let moved = silent
            .iter()
            .zip(&want)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(
            moved > 1e-2,
            "{events} events change the frame by only {moved}"
        );
    }
}
