//! Scene rendering at 400x250 on one thread: the fast path against the scalar reference, on a
//! panning scene (the axis-aligned path) and on `bright-fast`, which turns (the general affine
//! path). The figure to read is the ratio to the reference, measured in the same run; for the
//! moved images, `move_blended` against `move_each_then_blend`.
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
    // Two renders of one moving grid blended, then moved once (what the interpolator does),
    // against moving each and blending the two (twice the taps), in the same run.
    let other =
        Scene::load("bright-fast")
            .expect("builtin scene")
            .render(3_200_000, 250 + 20, 400 + 20);
    let mut moved_b = Array2::<f32>::zeros((250, 400));
    g.bench_function("move_blended", |b| {
        b.iter(|| {
            k += 0.37;
            let a = neuspike_scene::shift::Moved {
                src: src.view(),
                shift: (black_box(k % 3.0), 1.3),
            };
            let blended = neuspike_scene::shift::Blended {
                src: other.view(),
                offset: [0, 6],
                weight: 0.4,
            };
            neuspike_scene::shift::shift_rows(
                10,
                (250, 400),
                a,
                Some(blended),
                &mut scratch,
                |r, row| dst.row_mut(r).assign(&ndarray::ArrayView1::from(row)),
            );
        })
    });
    g.bench_function("move_each_then_blend", |b| {
        b.iter(|| {
            k += 0.37;
            let shift = (black_box(k % 3.0), 1.3);
            neuspike_scene::shift::shift_into(src.view(), 10, shift, dst.view_mut(), &mut scratch);
            let other_shift = (shift.0 - 6.0, shift.1);
            neuspike_scene::shift::shift_into(
                other.view(),
                10,
                other_shift,
                moved_b.view_mut(),
                &mut scratch,
            );
            dst.zip_mut_with(&moved_b, |x, &y| *x += 0.4 * (y - *x));
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
