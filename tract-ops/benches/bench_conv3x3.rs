//! Speed of [`Conv3x3`], neuspike's 3x3 convolution, against tract's own convolution on the same
//! weights and input, measured in the same run, at the shapes that take most of a NeuSpike-Net's
//! time (base width 16 at 256x400):
//!
//! - `head_32to16_256x400`: an encoder's head (32 representation channels in), and the last merge;
//! - `down_16to32_256x400_stride2`: an encoder's first, stride-2 layer;
//! - `residual_128to128_32x50`: a residual block at an eighth of the resolution;
//! - `spike_head_1+31to4_250x400_int8`: the base-4 networks' head in 8 bits on the spike
//!   representation, its raw planes as `f32` against the same planes bit-packed.
//!
//! Throughput in multiply-adds. `tract-direct` is tract's direct convolution, `tract-im2col`
//! im2col and a matrix product (`TRACT_DISABLE_DIRECT_SPATIAL`), both planned as the infer node
//! plans them; everything runs on one thread but `neuspike-2-threads`, ours on two.
//!
//! `cargo bench -p neuspike-tract-ops --bench bench_conv3x3 -- --warm-up-time 1 --measurement-time 3`

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ndarray::{Array1, Array4};
use neuspike_tract_ops::conv3x3::{Conv3x3, Precision};
use std::hint::black_box;
use tract_onnx::prelude::*;

/// Values in [-1, 1], a fixed pattern.
fn pattern(n: usize, seed: u32) -> Vec<f32> {
    (0..n)
        .map(|i| {
            let k = (i as u32).wrapping_mul(2_654_435_761).wrapping_add(seed) >> 8;
            (k % 2001) as f32 / 1000.0 - 1.0
        })
        .collect()
}

fn bench_shape(
    c: &mut Criterion,
    name: &str,
    (c_in, c_out, stride): (usize, usize, usize),
    (h, w): (usize, usize),
) {
    let weights =
        Array4::from_shape_vec((c_out, c_in, 3, 3), pattern(c_out * c_in * 9, 1)).expect("weights");
    let bias = Array1::from(pattern(c_out, 2));
    let conv = Conv3x3::new(weights.view(), bias.as_slice().expect("contiguous"), stride)
        .expect("a 3x3 convolution");
    let input = pattern(c_in * h * w, 3);
    let (ho, wo) = (conv.out_len(h), conv.out_len(w));
    let mut output = vec![0f32; c_out * ho * wo];
    let mut group = c.benchmark_group(name);
    group.throughput(Throughput::Elements((c_out * ho * wo * c_in * 9) as u64));
    group.bench_function("neuspike", |b| {
        b.iter(|| {
            conv.run(black_box(&input), (h, w), &mut output, None)
                .expect("runs")
        })
    });
    // In 8 bits, on each path this CPU runs (the input quantised afresh every run).
    for path in neuspike_simd::dot::DotPath::ALL
        .into_iter()
        .filter(|p| p.is_supported())
    {
        let int8 = conv.clone().with_precision(Precision::Int8(path));
        group.bench_function(format!("neuspike-int8-{}", path.name()), |b| {
            b.iter(|| {
                int8.run(black_box(&input), (h, w), &mut output, None)
                    .expect("runs")
            })
        });
    }
    // In `bf16`, on each path this CPU runs (the input converted as it is read).
    for path in neuspike_simd::bf16::Bf16Path::ALL
        .into_iter()
        .filter(|p| p.is_supported())
    {
        let bf16 = conv.clone().with_precision(Precision::Bf16(path));
        group.bench_function(format!("neuspike-bf16-{}", path.name()), |b| {
            b.iter(|| {
                bf16.run(black_box(&input), (h, w), &mut output, None)
                    .expect("runs")
            })
        });
    }
    // The same into the same output on two threads: how well the bands scale, page faults apart.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .expect("a pool of two threads");
    group.bench_function("neuspike-2-threads", |b| {
        b.iter(|| {
            conv.run(black_box(&input), (h, w), &mut output, Some(&pool))
                .expect("runs")
        })
    });
    let tensor = Tensor::from_shape(&[1, c_in, h, w], &input).expect("input tensor");
    for (label, im2col) in [("tract-direct", false), ("tract-im2col", true)] {
        let model = conv.tract_model(h, w).expect("a one-convolution model");
        let scope = tract_onnx::tract_core::knobs::KnobScope::new([(
            "TRACT_DISABLE_DIRECT_SPATIAL",
            if im2col { "true" } else { "false" },
        )])
        .expect("a knob scope");
        let plan = scope
            .enter(|| model.into_optimized()?.into_runnable())
            .expect("a runnable plan");
        group.bench_function(label, |b| {
            b.iter(|| {
                plan.run(tvec![black_box(tensor.clone()).into_tvalue()])
                    .expect("runs")
            })
        });
    }
    group.finish();
}

/// The spike representation's head in 8 bits, 1 dense channel and 31 binary planes to 4 (the
/// base-4 networks') at 250x400 padded to 256x400: the planes as `f32` 0.0/1.0
/// (`unpacked-f32`) against the same planes bit-packed as the window holds them (`packed`).
fn bench_packed(c: &mut Criterion) {
    let (d, planes, c_out, (h, w), (hp, wp)) = (1, 31, 4, (250, 400), (256, 400));
    let c_in = d + planes;
    let weights =
        Array4::from_shape_vec((c_out, c_in, 3, 3), pattern(c_out * c_in * 9, 1)).expect("weights");
    let bias = Array1::from(pattern(c_out, 2));
    let conv = Conv3x3::new(weights.view(), bias.as_slice().expect("contiguous"), 1)
        .expect("a 3x3 convolution")
        .with_relu()
        .with_precision(Precision::int8());
    let per = neuspike_tract_ops::conv3x3::packed_plane_bytes(h, w);
    let values = pattern(planes * h * w, 3);
    let mut all = ndarray::Array3::<f32>::zeros((c_in, h, w));
    let mut bits = vec![0u8; planes * per];
    for (i, v) in pattern(h * w, 4).into_iter().enumerate() {
        all[[0, i / w, i % w]] = v.abs();
    }
    for k in 0..planes {
        for i in 0..h * w {
            if values[k * h * w + i] > 0.6 {
                bits[k * per + i / 8] |= 1 << (i % 8);
                all[[d + k, i / w, i % w]] = 1.0;
            }
        }
    }
    let dense = all.slice(ndarray::s![..d, .., ..]);
    let mut output = vec![0f32; c_out * hp * wp];
    let mut group = c.benchmark_group("spike_head_1+31to4_250x400_int8");
    group.throughput(Throughput::Elements((c_out * hp * wp * c_in * 9) as u64));
    group.bench_function("unpacked-f32", |b| {
        b.iter(|| {
            conv.run_edge_padded(black_box(all.view()), (hp, wp), &mut output, None)
                .expect("runs")
        })
    });
    group.bench_function("packed", |b| {
        b.iter(|| {
            conv.run_edge_padded_bits(dense, black_box(&bits), planes, (hp, wp), &mut output, None)
                .expect("runs")
        })
    });
    group.bench_function("packed-without-tables", |b| {
        b.iter(|| {
            conv.run_edge_padded_bits_by(
                false,
                dense,
                black_box(&bits),
                planes,
                (hp, wp),
                &mut output,
                None,
            )
            .expect("runs")
        })
    });
    group.finish();
}

fn convolutions(c: &mut Criterion) {
    bench_packed(c);
    bench_shape(c, "head_32to16_256x400", (32, 16, 1), (256, 400));
    bench_shape(c, "down_16to32_256x400_stride2", (16, 32, 2), (256, 400));
    bench_shape(c, "residual_128to128_32x50", (128, 128, 1), (32, 50));
}

criterion_group!(benches, convolutions);
criterion_main!(benches);
