//! DVS simulation speed at 346x260 over 10 ms of simulated time per iteration (throughput in
//! 100-us steps, i.e. 10 kHz samples), against a memory-copy baseline of the same frame data (read
//! the ratios, measured in the same run). Real time at 10 kHz = 10,000 elements/s. v2e ran at
//! 741-932 frames/s (clean) here.
//!
//! `cargo bench -p neuspike-event-source --bench bench_simulate`

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use neuspike_event_source::{DvsConfig, EventCamera};
use neuspike_scene::Scene;
use std::hint::black_box;

/// Simulated time per iteration: 10 ms at a forced 100 us step = 100 samples.
const SPAN_NS: i64 = 10_000_000;
const STEP_NS: i64 = 100_000;

fn bench(c: &mut Criterion) {
    let n = 346 * 260;
    let samples = (SPAN_NS / STEP_NS) as u64;
    let mut g = c.benchmark_group("event_source_346x260");
    g.throughput(Throughput::Elements(samples));
    let src = vec![0.5f32; n];
    let mut dst = vec![0.0f32; n];
    g.bench_function("baseline_copy_frame", |b| {
        b.iter(|| {
            for _ in 0..samples {
                dst.copy_from_slice(black_box(&src));
            }
            black_box(&dst);
        })
    });
    for scene in ["bright-slow", "bright-fast"] {
        let s = Scene::load(scene).expect("builtin scene");
        // max_shift_px large and max_step_ns = STEP_NS: sample exactly every 100 us (10 kHz).
        let cfg = DvsConfig {
            max_shift_px: 1e9,
            max_step_ns: STEP_NS,
            ..DvsConfig::default()
        };
        let mut cam = EventCamera::new(s, cfg, 0).expect("camera");
        g.bench_function(format!("camera_{scene}_10kHz"), |b| {
            b.iter(|| {
                let t = cam.time_ns() + SPAN_NS;
                black_box(cam.advance_to(t, 0))
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
