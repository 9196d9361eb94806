//! Spike-camera simulation speed at 400x250 with noise on, against a memory-copy baseline of the
//! same per-plane data (the figure to read is the ratio, measured in the same run).
//!
//! `cargo bench -p neuspike-spike-source --bench bench_simulate`

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use neuspike_scene::Scene;
use neuspike_spike_source::{
    CameraConfig, Isa, KeyLight, PixelState, Reset, SpikeCamera, integrate_ticks_reference,
    integrate_ticks_with,
};
use std::hint::black_box;

const PLANES: usize = 200;

fn bench(c: &mut Criterion) {
    let (w, h) = (400usize, 250usize);
    let n = w * h;
    let mut g = c.benchmark_group("spike_source_400x250");
    g.throughput(Throughput::Elements(PLANES as u64));

    // Baseline: copy one plane of f32 luminance per tick (what any simulator must at least read).
    let src = vec![0.5f32; n];
    let mut dst = vec![0.0f32; n];
    g.bench_function("baseline_copy_luminance", |b| {
        b.iter(|| {
            for _ in 0..PLANES {
                dst.copy_from_slice(black_box(&src));
            }
            black_box(&dst);
        })
    });

    // The kernel alone (integrate, fire, reset, cap, pack) over 20-tick key intervals: the scalar
    // reference and the fast path on each instruction set this CPU has.
    const KEY_TICKS: usize = 20;
    let base: Vec<f32> = (0..n).map(|i| (i % 255) as f32 / 255.0).collect();
    let slope = vec![0.0f32; n];
    let mut acc = vec![0.0f32; n];
    let mut since = vec![0u32; n];
    let cap = vec![180u32; n];
    let mut planes = vec![0u8; n / 8 * KEY_TICKS];
    let light = KeyLight {
        base: &base,
        slope: &slope,
    };
    let mut variants = vec![("kernel_reference".to_string(), None)];
    for isa in Isa::ALL.into_iter().filter(|isa| isa.is_supported()) {
        variants.push((format!("kernel_fast_{}", isa.name()), Some(isa)));
    }
    for (name, isa) in variants {
        g.bench_function(name, |b| {
            b.iter(|| {
                for _ in 0..PLANES / KEY_TICKS {
                    planes.fill(0);
                    let px = PixelState {
                        acc: &mut acc,
                        since: &mut since,
                        cap: &cap,
                    };
                    match isa {
                        Some(isa) => integrate_ticks_with(
                            isa,
                            light,
                            0,
                            1.0,
                            Reset::Subtract,
                            px,
                            &mut planes,
                        ),
                        None => integrate_ticks_reference(
                            light,
                            0,
                            1.0,
                            Reset::Subtract,
                            px,
                            &mut planes,
                        ),
                    }
                }
                black_box(&planes);
            })
        });
    }

    // The whole camera on a moving scene, rendering included.
    for scene in ["bright-static", "bright-slow", "bright-fast"] {
        let s = Scene::load(scene).expect("builtin scene");
        let mut cam = SpikeCamera::new(s, CameraConfig::default()).expect("camera");
        g.bench_function(format!("camera_{scene}"), |b| {
            b.iter(|| black_box(cam.next_chunk(PLANES, 0)))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
