//! Per-frame cost of the sink at 400x250: writing a PNG and each metric, against copying the frame
//! (read the ratios, measured in the same run). At 1,000 frames/s (a 20 kHz camera reconstructed
//! every 20 planes) the sink has 1 ms per frame for all of it.
//!
//! `cargo bench -p neuspike-sink --bench bench_sink`

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ndarray::Array2;
use neuspike_image::{BitDepth, write_frame_png};
use neuspike_metrics::{entropy_2d, psnr, psnr_after_gain, ssim};
use std::hint::black_box;

fn frame(seed: u32) -> Array2<f32> {
    let mut s = seed;
    Array2::from_shape_fn((250, 400), |(r, c)| {
        s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        let noise = (s >> 8) as f32 / (1u32 << 24) as f32;
        (0.5 + 0.3 * ((r as f32 * 0.05).sin() * (c as f32 * 0.03).cos()) + 0.05 * noise)
            .clamp(0.0, 1.0)
    })
}

fn bench(c: &mut Criterion) {
    let x = frame(1);
    let gt = frame(2);
    let mut g = c.benchmark_group("sink_400x250");
    g.throughput(Throughput::Elements(1));
    let mut copy = x.clone();
    g.bench_function("baseline_copy_frame", |b| {
        b.iter(|| copy.assign(black_box(&x)))
    });
    let dir = tempfile::tempdir().expect("temp dir");
    for (name, depth) in [
        ("png_8bit", BitDepth::Eight),
        ("png_16bit", BitDepth::Sixteen),
    ] {
        let path = dir.path().join(format!("{name}.png"));
        g.bench_function(name, |b| {
            b.iter(|| write_frame_png(&path, x.view(), depth).expect("write"))
        });
    }
    g.bench_function("psnr", |b| b.iter(|| black_box(psnr(x.view(), gt.view()))));
    g.bench_function("psnr_after_gain", |b| {
        b.iter(|| black_box(psnr_after_gain(x.view(), gt.view())))
    });
    g.bench_function("ssim", |b| b.iter(|| black_box(ssim(x.view(), gt.view()))));
    g.bench_function("entropy_2d", |b| b.iter(|| black_box(entropy_2d(x.view()))));
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
