//! Spike-camera simulation speed at 400x250 with noise on, against a memory-copy baseline of the
//! same per-plane data (the figure to read is the ratio, measured in the same run).
//!
//! `cargo bench -p neuspike-spike-camera --bench bench_simulate`

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use neuspike_scene::Scene;
use neuspike_spike_camera::{
    CameraConfig, FireNoise, Isa, KeyLight, Noise, NoiseArgs, PixelState, Reset, SpikeCamera,
    integrate_ticks_noisy_with, integrate_ticks_reference, integrate_ticks_with,
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
    let mut acc = vec![0.0f32; n];
    let mut since = vec![0u32; n];
    let cap = vec![180u32; n];
    let mut planes = vec![0u8; n / 8 * KEY_TICKS];
    let light = KeyLight {
        keys: &[&base, &base],
        step: KEY_TICKS as u32,
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

    // The noisy kernel (per-interval threshold draws and the reset delay) on the fastest
    // instruction set.
    let isa = Isa::ALL
        .into_iter()
        .rfind(|isa| isa.is_supported())
        .expect("an instruction set");
    let mut thr = vec![1.0f32; n];
    let mut rng: Vec<u32> = (0..n as u32)
        .map(|i| i.wrapping_mul(2_654_435_761) | 1)
        .collect();
    g.bench_function(format!("kernel_noisy_fast_{}", isa.name()), |b| {
        b.iter(|| {
            for _ in 0..PLANES / KEY_TICKS {
                planes.fill(0);
                let px = PixelState {
                    acc: &mut acc,
                    since: &mut since,
                    cap: &cap,
                };
                let fire = FireNoise {
                    sigma: 0.1,
                    reset_delay: 0.002,
                    thr: &mut thr,
                    rng: &mut rng,
                };
                integrate_ticks_noisy_with(
                    isa,
                    light,
                    0,
                    1.0,
                    Reset::Subtract,
                    px,
                    fire,
                    &mut planes,
                );
            }
            black_box(&planes);
        })
    });

    // The whole camera, rendering included: the paper's model on a still and two moving scenes,
    // and on the still scene each noise term alone and every term on (SCSim's values).
    let term = |name: &'static str, noise: Noise| (name, noise);
    let terms = [
        term(
            "shot",
            Noise {
                electrons_per_phi: Noise::SCSIM.electrons_per_phi,
                ..Noise::OFF
            },
        ),
        term(
            "jitter",
            Noise {
                threshold_jitter: 0.1,
                ..Noise::OFF
            },
        ),
        term(
            "offset",
            Noise {
                threshold_offset: Noise::SCSIM.threshold_offset,
                ..Noise::OFF
            },
        ),
        term(
            "prnu",
            Noise {
                prnu: Noise::SCSIM.prnu,
                ..Noise::OFF
            },
        ),
        term(
            "dark",
            Noise {
                dark_current_hz: 93.5,
                dark_current_spread: 0.38,
                ..Noise::OFF
            },
        ),
        term(
            "reset_delay",
            Noise {
                reset_delay_ticks: 0.002,
                ..Noise::OFF
            },
        ),
        term("all", Noise::SCSIM),
    ];
    // (label, scene, noise, (--render-step-ticks, --warp-step-ticks))
    let mut cases = vec![
        (
            "bright-static".to_string(),
            "bright-static",
            Noise::OFF,
            (0, 1),
        ),
        ("bright-slow".to_string(), "bright-slow", Noise::OFF, (0, 1)),
        ("bright-fast".to_string(), "bright-fast", Noise::OFF, (0, 1)),
        (
            "bright-fast_step32".to_string(),
            "bright-fast",
            Noise::OFF,
            (32, 1),
        ),
        (
            "bright-fast_warp64".to_string(),
            "bright-fast",
            Noise::OFF,
            (0, 64),
        ),
    ];
    for (name, noise) in terms {
        cases.push((
            format!("bright-static_noise_{name}"),
            "bright-static",
            noise,
            (0, 1),
        ));
    }
    for (label, scene, noise, (render_step_ticks, warp_step_ticks)) in cases {
        let s = Scene::load(scene).expect("builtin scene");
        let cfg = CameraConfig {
            noise: NoiseArgs::from(noise),
            render_step_ticks,
            warp_step_ticks,
            ..CameraConfig::default()
        };
        let mut cam = SpikeCamera::new(s, cfg).expect("camera");
        g.bench_function(format!("camera_{label}"), |b| {
            b.iter(|| black_box(cam.next_chunk(PLANES, 0)))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
