//! Scene rendering at 400x250 on one thread: the fast path against the scalar reference, on a
//! panning scene (the axis-aligned path) and on `bright-fast`, which turns (the general affine
//! path). The figure to read is the ratio to the reference, measured in the same run.
//!
//! `cargo bench -p neuspike-scene --bench bench_render`

use criterion::{Criterion, criterion_group, criterion_main};
use ndarray::Array2;
use neuspike_scene::{Scene, render_fast_with, render_reference};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("render_400x250");
    g.sample_size(20);
    let mut dst = Array2::<f32>::zeros((250, 400));
    for name in ["bright-slow", "bright-fast"] {
        let scene = Scene::load(name).expect("builtin scene");
        let mut t = 0i64;
        g.bench_function(format!("fast_{name}"), |b| {
            b.iter(|| {
                t += 100_000;
                render_fast_with(&scene, black_box(t), dst.view_mut(), false);
            })
        });
        g.bench_function(format!("reference_{name}"), |b| {
            b.iter(|| {
                t += 100_000;
                render_reference(&scene, black_box(t), dst.view_mut());
            })
        });
    }
    // Moving a rendered image by a fraction of a pixel (motion-compensated interpolation).
    let src = Scene::load("bright-fast")
        .expect("builtin scene")
        .render(0, 250 + 20, 400 + 20);
    let mut scratch = Vec::new();
    let mut k = 0.0;
    g.bench_function("shift_cubic", |b| {
        b.iter(|| {
            k += 0.37;
            neuspike_scene::shift::shift_into(
                src.view(),
                10,
                (black_box(k % 3.0), 1.3),
                dst.view_mut(),
                &mut scratch,
            );
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
