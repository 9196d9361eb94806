//! DVS simulation speed at 346x260 over 10 ms of simulated time per iteration (throughput in
//! 100-us steps, i.e. 10 kHz samples), against a memory-copy baseline of the same frame data (read
//! the ratios, measured in the same run). Real time at 10 kHz = 10,000 elements/s. v2e ran at
//! 741-932 frames/s (clean) here.
//!
//! `dvs_core_*` is the job v2e does: luminance frames in (rendered beforehand), log conversion,
//! threshold crossings with interpolated time stamps, events out in time order. The fast path
//! takes logs only where a pixel may cross; the reference takes the log of every pixel. The
//! `dvs_core_hot_*` runs hand each frame over in cache, as the camera does right after rendering it
//! (and v2e right after decoding it); the plain runs stream 36 MB of frames from memory, whose
//! floor is `baseline_read_frames_*`. `camera_*` adds rendering the scene.
//!
//! `cargo bench -p neuspike-event-camera --bench bench_simulate`

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use neuspike_event_camera::{DvsConfig, DvsPixels, EventCamera};
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
    // The pixel array alone on 100 frames of each scene sampled at 10 kHz (bright-fast's
    // high-contrast strokes give about 11,500 events a frame, 115 million a second; bright-slow
    // about 170 a frame).
    let cfg = DvsConfig::default();
    for scene in ["bright-slow", "bright-fast"] {
        let s = Scene::load(scene).expect("scene");
        let frames: Vec<Vec<f32>> = (0..=samples as i64)
            .map(|k| s.render(k * STEP_NS, 260, 346).into_raw_vec_and_offset().0)
            .collect();
        // The mismatch draw is set-up, outside the timed loop: each iteration starts from a
        // copy of the same fresh pixel array.
        let fresh = DvsPixels::new(&cfg, 1.0, &frames[0]).expect("pixels");
        // The floor of the cold runs below: reading each of the 100 frames once from memory
        // (36 MB of frames do not stay in cache).
        g.bench_function(format!("baseline_read_frames_{scene}"), |b| {
            b.iter(|| {
                let mut top = 0.0f32;
                for f in &frames[1..] {
                    top = f.iter().fold(top, |a, &v| a.max(v));
                }
                black_box(top)
            })
        });
        // With v2e's noise as its emulator's example sets it (cutoff 200 Hz, leak 1 Hz, shot
        // noise 10 Hz, threshold mismatch 0.03).
        let noisy = DvsConfig {
            cutoff_hz: 200.0,
            leak_rate_hz: 1.0,
            shot_noise_rate_hz: 10.0,
            ..cfg.clone()
        };
        let fresh_noisy = DvsPixels::new(&noisy, 1.0, &frames[0]).expect("pixels");
        // As the camera runs it: each frame was just written (by the renderer), so it is in
        // cache. The copy into the two hot buffers is outside the timing.
        for (label, fresh) in [("", &fresh), ("_noisy", &fresh_noisy)] {
            g.bench_function(format!("dvs_core_hot_{scene}_10kHz{label}"), |b| {
                b.iter_custom(|iters| {
                    let mut took = std::time::Duration::ZERO;
                    let (mut fa, mut fb) = (frames[0].clone(), frames[0].clone());
                    let mut events = Vec::new();
                    for _ in 0..iters {
                        let mut px = fresh.clone();
                        let mut count = 0;
                        fa.copy_from_slice(&frames[0]);
                        for k in 0..samples as usize {
                            fb.copy_from_slice(&frames[k + 1]);
                            let (t_a, t_b) = (k as i64 * STEP_NS, (k as i64 + 1) * STEP_NS);
                            let start = std::time::Instant::now();
                            events.clear();
                            px.step(&fa, &fb, t_a, t_b, &mut events);
                            neuspike_event_camera::sort_by_time(&mut events);
                            count += events.len();
                            took += start.elapsed();
                            std::mem::swap(&mut fa, &mut fb);
                        }
                        black_box(count);
                    }
                    took
                })
            });
        }
        // The fast path against the plain loop over every pixel, with and without the noise.
        let runs = [false, true].map(|r| (r, "", &fresh));
        let noisy_runs = [false, true].map(|r| (r, "_noisy", &fresh_noisy));
        for (reference, label, fresh) in runs.into_iter().chain(noisy_runs) {
            let name = if reference {
                format!("dvs_core_reference_{scene}_10kHz{label}")
            } else {
                format!("dvs_core_{scene}_10kHz{label}")
            };
            g.bench_function(name, |b| {
                b.iter(|| {
                    let mut px = fresh.clone();
                    let mut events = Vec::new();
                    let mut count = 0;
                    for (k, pair) in frames.windows(2).enumerate() {
                        let k = k as i64;
                        events.clear();
                        let (t_a, t_b) = (k * STEP_NS, (k + 1) * STEP_NS);
                        if reference {
                            px.step_reference(&pair[0], &pair[1], t_a, t_b, &mut events);
                        } else {
                            px.step(&pair[0], &pair[1], t_a, t_b, &mut events);
                        }
                        neuspike_event_camera::sort_by_time(&mut events);
                        count += events.len();
                    }
                    black_box(count)
                })
            });
        }
    }
    for scene in ["bright-slow", "bright-fast"] {
        // Forced: render the scene every 100 us (10 kHz), as v2e samples its frames.
        let cfg = DvsConfig {
            max_shift_px: 1e9,
            max_step_ns: STEP_NS,
            ..DvsConfig::default()
        };
        let mut cam = EventCamera::new(Scene::load(scene).expect("scene"), cfg, 0).expect("camera");
        g.bench_function(format!("camera_{scene}_forced_10kHz"), |b| {
            b.iter(|| {
                let t = cam.time_ns() + SPAN_NS;
                black_box(cam.advance_to(t, 0))
            })
        });
        // Default: render only as often as a quarter pixel of motion (or 1 ms) needs, over the
        // same 10 ms of simulated time: the ratio of the two is the gain of adaptive sampling.
        let mut cam = EventCamera::new(Scene::load(scene).expect("scene"), DvsConfig::default(), 0)
            .expect("camera");
        g.bench_function(format!("camera_{scene}_adaptive"), |b| {
            b.iter(|| {
                let t = cam.time_ns() + SPAN_NS;
                black_box(cam.advance_to(t, 0))
            })
        });
        // The same samples, the scene rendered every 3.2 ms and moved along its motion between.
        let warped = DvsConfig {
            warp_step_ns: 3_200_000,
            ..DvsConfig::default()
        };
        let mut cam =
            EventCamera::new(Scene::load(scene).expect("scene"), warped, 0).expect("camera");
        g.bench_function(format!("camera_{scene}_adaptive_warp3200us"), |b| {
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
