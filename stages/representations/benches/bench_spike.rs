//! Spike-side representations at 400x250 over a 33-plane window (firing probability 0.37, as the
//! real Vidar recording), and the event integration (Eq. 8, 32 channels, 1 million events at
//! 346x260); one thread, each against its scalar reference and a memory copy of the same bytes
//! measured in the same run (read the ratios). SpikeCV's TFP ran at 1,075-1,373 frames/s and its
//! TFI at 167-248 frames/s on one core here. TFSTP's synapses (`StpFilter`) are fed 33 planes and
//! read once per iteration (throughput in planes). The event integration is also timed at 10,000
//! and 100,000 events a window, against the copy of its output.
//!
//! `cargo bench -p neuspike-representations --bench bench_spike`

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ndarray::{Array2, Array3};
use neuspike_representations::{
    EventSlice, StpFilter, StpParams, event_integration_into, event_integration_reference,
    isi_packed_into, spike_representation_into, spike_representation_packed_into,
    spike_representation_reference, tfi_into, tfi_reference, tfp_into, tfp_packed_into,
    tfp_reference,
};
use neuspike_schemas::pack_planes;
use std::hint::black_box;

const W: usize = 400;
const H: usize = 250;
const N: usize = 33;
const C: usize = 16;
const CHANNELS: usize = 32;

fn xorshift(seed: u64) -> impl FnMut() -> u64 {
    let mut s = seed | 1;
    move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    }
}

fn bench(c: &mut Criterion) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    spike(c, &pool);
    stats(c);
    events(c, &pool);
}

/// `auto`'s window statistics over the same 33-plane window (with no events), against the
/// scalar reference and TFP from the packed planes.
fn stats(c: &mut Criterion) {
    let mut next = xorshift(11);
    let threshold = (0.37 * u64::MAX as f64) as u64;
    let planes = Array3::from_shape_fn((N, H, W), |_| u8::from(next() < threshold));
    let window = neuspike_schemas::AlignedWindow {
        t_ref_ns: 0,
        ref_plane: C as u64,
        spikes: neuspike_schemas::SpikeChunk {
            width: W,
            height: H,
            first_plane: 0,
            n_planes: N,
            t_first_ns: 0,
            plane_period_ns: 50_000,
            seq: 0,
            bits: pack_planes(planes.view()),
            lum_per_rate: None,
        },
        events: neuspike_schemas::EventBatch::empty(W, H, 0, 1, 0),
    };
    let mut g = c.benchmark_group("window_stats_400x250_33_planes");
    g.throughput(Throughput::Elements(1));
    let mut dst = Array2::<f32>::zeros((H, W));
    g.bench_function("baseline_tfp_packed", |b| {
        b.iter(|| tfp_packed_into(black_box(&window.spikes.bits), 0..N, dst.view_mut()))
    });
    g.bench_function("window_stats_reference", |b| {
        b.iter(|| neuspike_representations::window_stats_reference(black_box(&window)))
    });
    g.bench_function("window_stats", |b| {
        b.iter(|| neuspike_representations::window_stats(black_box(&window)))
    });
    g.finish();
}

fn spike(c: &mut Criterion, one: &rayon::ThreadPool) {
    let mut next = xorshift(7);
    let threshold = (0.37 * u64::MAX as f64) as u64;
    let planes = Array3::from_shape_fn((N, H, W), |_| u8::from(next() < threshold));
    let bits = pack_planes(planes.view());
    let mut g = c.benchmark_group("spike_400x250_33_planes");
    g.throughput(Throughput::Elements(1));
    let mut copy = planes.clone();
    g.bench_function("baseline_copy_unpacked_window", |b| {
        b.iter(|| copy.assign(black_box(&planes)))
    });
    let mut dst = Array2::<f32>::zeros((H, W));
    g.bench_function("tfp_reference", |b| {
        b.iter(|| one.install(|| tfp_reference(planes.view(), dst.view_mut()).expect("tfp")))
    });
    g.bench_function("tfp_into", |b| {
        b.iter(|| one.install(|| tfp_into(planes.view(), dst.view_mut()).expect("tfp")))
    });
    // The packed kernels are single-threaded: called directly (a hand-over to the pool would
    // add 55 us a call, a third of their time).
    g.bench_function("tfp_packed_into", |b| {
        b.iter(|| tfp_packed_into(&bits, 0..N, dst.view_mut()).expect("tfp"))
    });
    g.bench_function("tfi_reference", |b| {
        b.iter(|| one.install(|| tfi_reference(planes.view(), C, dst.view_mut()).expect("tfi")))
    });
    g.bench_function("tfi_into", |b| {
        b.iter(|| one.install(|| tfi_into(planes.view(), C, dst.view_mut()).expect("tfi")))
    });
    // The ISI map and its mask straight from the packed planes (what the node sends; TFI is
    // `1 / ISI` of it).
    let mut valid = Array2::<bool>::from_elem((H, W), false);
    g.bench_function("isi_packed_into", |b| {
        b.iter(|| isi_packed_into(&bits, N, C, dst.view_mut(), valid.view_mut()).expect("isi"))
    });
    let mut repr = Array3::<f32>::zeros((CHANNELS, H, W));
    let src = Array3::<f32>::from_elem((CHANNELS, H, W), 0.5);
    g.bench_function("baseline_copy_spike_representation_bytes", |b| {
        b.iter(|| repr.assign(black_box(&src)))
    });
    g.bench_function("spike_representation_reference", |b| {
        b.iter(|| {
            one.install(|| {
                spike_representation_reference(planes.view(), C, repr.view_mut()).expect("repr")
            })
        })
    });
    g.bench_function("spike_representation_into", |b| {
        b.iter(|| {
            one.install(|| {
                spike_representation_into(planes.view(), C, repr.view_mut()).expect("repr")
            })
        })
    });
    // Straight from the packed planes, as the node computes it (single-threaded).
    g.bench_function("spike_representation_packed_into", |b| {
        b.iter(|| spike_representation_packed_into(&bits, N, C, repr.view_mut()).expect("repr"))
    });
    g.finish();

    // TFSTP: the window's planes fed to the synapses (numbered on, so none is skipped as seen),
    // then the rates read; throughput in planes.
    let mut g = c.benchmark_group("stp_400x250_33_planes");
    g.throughput(Throughput::Elements(N as u64));
    let mut copy = planes.clone();
    g.bench_function("baseline_copy_unpacked_window", |b| {
        b.iter(|| copy.assign(black_box(&planes)))
    });
    let mut reference = StpFilter::new(H, W, StpParams::default()).expect("stp");
    let mut next_plane = 0u64;
    g.bench_function("stp_reference", |b| {
        b.iter(|| {
            reference
                .advance_reference(planes.view(), next_plane)
                .expect("stp");
            next_plane += N as u64;
            reference.rate_into(dst.view_mut()).expect("stp")
        })
    });
    let mut fast = StpFilter::new(H, W, StpParams::default()).expect("stp");
    let mut next_plane = 0u64;
    g.bench_function("stp_packed", |b| {
        b.iter(|| {
            let last = next_plane + N as u64 - 1;
            fast.advance_packed(&bits, next_plane, N, last)
                .expect("stp");
            next_plane += N as u64;
            fast.rate_into(dst.view_mut()).expect("stp")
        })
    });
    g.bench_function("stp_rate_into_only", |b| {
        b.iter(|| fast.rate_into(dst.view_mut()).expect("stp"))
    });
    g.finish();
}

fn events(c: &mut Criterion, one: &rayon::ThreadPool) {
    const EW: usize = 346;
    const EH: usize = 260;
    const EVENTS: usize = 1_000_000;
    const SPAN_NS: i64 = 10_000_000;
    let mut next = xorshift(11);
    let t_ns: Vec<i64> = (0..EVENTS)
        .map(|i| i as i64 * SPAN_NS / EVENTS as i64)
        .collect();
    let x: Vec<u16> = (0..EVENTS).map(|_| (next() % EW as u64) as u16).collect();
    let y: Vec<u16> = (0..EVENTS).map(|_| (next() % EH as u64) as u16).collect();
    let polarity: Vec<i8> = (0..EVENTS)
        .map(|_| if next().is_multiple_of(3) { -1 } else { 1 })
        .collect();
    let ev = EventSlice {
        t_ns: &t_ns,
        x: &x,
        y: &y,
        polarity: &polarity,
    };
    let ts: Vec<i64> = (1..=CHANNELS as i64)
        .map(|k| k * SPAN_NS / CHANNELS as i64)
        .collect();
    let mut g = c.benchmark_group("event_integration_346x260_32ch_1M_events");
    g.throughput(Throughput::Elements(EVENTS as u64));
    let mut dst = Array3::<f32>::zeros((CHANNELS, EH, EW));
    let src = Array3::<f32>::from_elem((CHANNELS, EH, EW), 0.5);
    g.bench_function("baseline_copy_output_bytes", |b| {
        b.iter(|| dst.assign(black_box(&src)))
    });
    // The input side: the four event columns (13 MB).
    let (mut t2, mut x2, mut y2, mut p2) = (t_ns.clone(), x.clone(), y.clone(), polarity.clone());
    g.bench_function("baseline_copy_input_events", |b| {
        b.iter(|| {
            t2.copy_from_slice(black_box(&t_ns));
            x2.copy_from_slice(black_box(&x));
            y2.copy_from_slice(black_box(&y));
            p2.copy_from_slice(black_box(&polarity));
        })
    });
    g.bench_function("event_integration_reference", |b| {
        b.iter(|| {
            one.install(|| {
                event_integration_reference(ev, 0, &ts, 5e5, dst.view_mut()).expect("ei")
            })
        })
    });
    g.bench_function("event_integration_into", |b| {
        b.iter(|| {
            one.install(|| event_integration_into(ev, 0, &ts, 5e5, dst.view_mut()).expect("ei"))
        })
    });
    // The same on two threads (below the four that split the sensor into bands: the bands were
    // slower here).
    let two = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .expect("pool");
    g.bench_function("event_integration_into_2_threads", |b| {
        b.iter(|| {
            two.install(|| event_integration_into(ev, 0, &ts, 5e5, dst.view_mut()).expect("ei"))
        })
    });
    g.finish();

    // Sparser windows: the first `n` events spread over the same span (every `1M / n`-th).
    for n in [10_000usize, 100_000] {
        let step = EVENTS / n;
        fn pick<T: Copy>(v: &[T], step: usize) -> Vec<T> {
            v.iter().step_by(step).copied().collect()
        }
        let (t_n, x_n, y_n, p_n) = (
            pick(&t_ns, step),
            pick(&x, step),
            pick(&y, step),
            pick(&polarity, step),
        );
        let ev = EventSlice {
            t_ns: &t_n,
            x: &x_n,
            y: &y_n,
            polarity: &p_n,
        };
        let mut g = c.benchmark_group(format!("event_integration_346x260_32ch_{n}_events"));
        g.throughput(Throughput::Elements(n as u64));
        g.bench_function("baseline_copy_output_bytes", |b| {
            b.iter(|| dst.assign(black_box(&src)))
        });
        g.bench_function("event_integration_into", |b| {
            b.iter(|| {
                one.install(|| event_integration_into(ev, 0, &ts, 5e5, dst.view_mut()).expect("ei"))
            })
        });
        g.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
