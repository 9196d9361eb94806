//! Test inputs shared by the operators' tests.

/// `n` values in [-1, 1] from a multiplicative hash of the index and `seed`: the kernels' tests'
/// inputs and weights, reproducible and not smooth.
pub(crate) fn pattern(n: usize, seed: u32) -> Vec<f32> {
    (0..n)
        .map(|i| {
            let k = (i as u32).wrapping_mul(2_654_435_761).wrapping_add(seed) >> 8;
            (k % 2001) as f32 / 1000.0 - 1.0
        })
        .collect()
}

/// `n` inputs of a layer as the networks' are, from [`pattern`] and `seed`: after a ReLU (0 and
/// above) for `kind % 3 == 0`, signed for 1, spikes (0 or 1) for 2.
pub(crate) fn layer_input(n: usize, seed: u32, kind: u32) -> Vec<f32> {
    let v = pattern(n, seed);
    match kind % 3 {
        0 => v.into_iter().map(|x| x.max(0.0) * 3.0).collect(),
        1 => v,
        _ => v.into_iter().map(|x| f32::from(x > 0.6)).collect(),
    }
}

/// The networks' 3x3 layers the convolution tests run at: `(c_in, c_out, stride, (h, w))`
/// (the head at full width, a half-width layer, the deepest at 50 wide, the stride-2 ones).
pub(crate) const NETWORK_LAYERS: [(usize, usize, usize, (usize, usize)); 5] = [
    (32, 8, 1, (16, 400)),
    (8, 16, 1, (9, 200)),
    (64, 64, 1, (5, 50)),
    (8, 16, 2, (16, 400)),
    (32, 64, 2, (9, 101)),
];

/// Runs the typed `model`, optimised, on `input`: its first output's shape and values in
/// logical order.
pub(crate) fn run_typed(
    model: tract_onnx::prelude::TypedModel,
    input: &tract_onnx::prelude::Tensor,
) -> (Vec<usize>, Vec<f32>) {
    use tract_onnx::prelude::*;
    let plan = model
        .into_optimized()
        .expect("optimised")
        .into_runnable()
        .expect("runnable");
    let out = plan.run(tvec![input.clone().into_tvalue()]).expect("runs");
    let out = out[0].clone().into_tensor();
    let values = out
        .to_plain_array_view::<f32>()
        .expect("f32")
        .iter()
        .copied()
        .collect();
    (out.shape().to_vec(), values)
}

/// A `c_in`-to-`c_out` [`Conv3x3`](crate::conv3x3::Conv3x3) of `stride` with [`pattern`]
/// weights and bias from `seed`.
pub(crate) fn conv(c_in: usize, c_out: usize, stride: usize, seed: u32) -> crate::conv3x3::Conv3x3 {
    let weights =
        ndarray::Array4::from_shape_vec((c_out, c_in, 3, 3), pattern(c_out * c_in * 9, seed))
            .expect("weights");
    let bias = pattern(c_out, seed + 1);
    crate::conv3x3::Conv3x3::new(weights.view(), &bias, stride).expect("a 3x3 convolution")
}

/// Runs `conv` on `input` (`[C, h, w]`) on every instruction set this CPU has, on this thread
/// and on a pool of three, and asserts each output is `want`, bit for bit (`what` names the case).
pub(crate) fn runs_give(
    conv: &crate::conv3x3::Conv3x3,
    input: &[f32],
    (h, w): (usize, usize),
    want: &[f32],
    what: &str,
) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(3)
        .build()
        .expect("a pool");
    for isa in neuspike_simd::Isa::ALL
        .into_iter()
        .filter(|i| i.is_supported())
    {
        for pool in [None, Some(&pool)] {
            let mut got = vec![f32::NAN; want.len()];
            conv.run_on(isa, input, (h, w), &mut got, pool)
                .expect("runs");
            assert_eq!(got, want, "{what}, {isa:?}, pool {}", pool.is_some());
        }
    }
}

/// Runs `conv` (8 input channels) on an input of each stride's size, `(9, 37)` at stride 1 and
/// `(8, 20)` at stride 2: as the parts of a concatenation of 3 and 5 channels (an odd split) on
/// this thread and on a pool of two, and read in place as if padded to `(h + 3, w + 5)` by
/// repeating the last row and column; asserts each gives `definition`'s bits on the whole
/// input (the padded copy for the second).
pub(crate) fn parts_and_edge_give(
    conv: &crate::conv3x3::Conv3x3,
    definition: impl Fn(&crate::conv3x3::Conv3x3, ndarray::ArrayView3<f32>) -> ndarray::Array3<f32>,
) {
    use ndarray::ArrayView3;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .expect("a pool");
    let (h, w) = if conv.stride() == 1 { (9, 37) } else { (8, 20) };
    let x = layer_input(8 * h * w, 3, 0);
    let view = ArrayView3::from_shape((8, h, w), &x).expect("a view");
    let want = definition(conv, view).into_raw_vec_and_offset().0;
    let (a, b) = x.split_at(3 * h * w);
    for pool in [None, Some(&pool)] {
        let mut got = vec![f32::NAN; want.len()];
        conv.run_concat(&[(a, 3), (b, 5)], (h, w), &mut got, pool)
            .expect("runs");
        assert_eq!(got, want, "stride {}", conv.stride());
    }
    let (hp, wp) = (h + 3, w + 5);
    let padded = crate::pad_edge(view, hp, wp);
    let padded = ArrayView3::from_shape((8, hp, wp), &padded).expect("a view");
    let want = definition(conv, padded).into_raw_vec_and_offset().0;
    let mut got = vec![f32::NAN; want.len()];
    conv.run_edge_padded(view, (hp, wp), &mut got, Some(&pool))
        .expect("runs");
    assert_eq!(got, want, "edge, stride {}", conv.stride());
}

/// `planes` binary planes of `h x w` pixels, about `density` of them set (plane `k` empty
/// when `empty` holds `k`), packed as a window holds them, and the same unpacked to 0.0/1.0
/// after `dense` (`[D, h, w]`).
pub(crate) fn packed(
    dense: &[f32],
    planes: usize,
    (h, w): (usize, usize),
    seed: u32,
    empty: &[usize],
) -> (Vec<u8>, ndarray::Array3<f32>) {
    let per = crate::conv3x3::packed_plane_bytes(h, w);
    let d = dense.len() / (h * w).max(1);
    let mut bits = vec![0u8; planes * per];
    let mut all = ndarray::Array3::<f32>::zeros((d + planes, h, w));
    all.slice_mut(ndarray::s![..d, .., ..])
        .assign(&ndarray::ArrayView3::from_shape((d, h, w), dense).unwrap());
    let values = pattern(planes * h * w, seed);
    for k in 0..planes {
        for i in 0..h * w {
            let set = values[k * h * w + i] > 0.4 && !empty.contains(&k);
            if set {
                bits[k * per + i / 8] |= 1 << (i % 8);
                all[[d + k, i / w, i % w]] = 1.0;
            }
        }
    }
    (bits, all)
}

/// A convolution of `d` dense and `planes` binary input channels to `c_out` (a ReLU after it for
/// odd seeds), a dense input `[d, h, w]` of [`layer_input`], and the planes bit-packed and the
/// whole input unpacked as [`packed`] makes them.
pub(crate) fn bits_case(
    (d, planes, c_out, stride): (usize, usize, usize, usize),
    (h, w): (usize, usize),
    seed: u32,
    empty: &[usize],
) -> (
    crate::conv3x3::Conv3x3,
    Vec<f32>,
    Vec<u8>,
    ndarray::Array3<f32>,
) {
    let base = conv(d + planes, c_out, stride, seed);
    let base = if seed % 2 == 1 {
        base.with_relu()
    } else {
        base
    };
    let dense = layer_input(d * h * w, seed + 3, seed);
    let (bits, all) = packed(&dense, planes, (h, w), seed + 5, empty);
    (base, dense, bits, all)
}
