//! Voxel grid speed at 346x260, 5 bins, 10 million events in one window (throughput in events),
//! against the scalar reference and a plain baseline measured in the same run: summing
//! polarities into an `f64` histogram by pixel index (what NumPy's `bincount(y * W + x,
//! weights=p)` does; 58-82 M events/s there, tonic's voxel grid 26-32 M/s). The voxel grid is
//! single-threaded; the stacking (rayon over bins) is pinned to one thread here too. Events are
//! spread uniformly over the pixels (the worst case for caches), times evenly over 50 ms, a
//! third OFF. The kernels' figures include their validation pass over the events.
//!
//! `cargo bench -p neuspike-representations --bench bench_voxel`

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ndarray::Array3;
use neuspike_representations::{
    EventSlice, VoxelNorm, event_stack_into, voxel_grid_into, voxel_grid_reference,
};
use std::hint::black_box;

const WIDTH: usize = 346;
const HEIGHT: usize = 260;
const BINS: usize = 5;
const EVENTS: usize = 10_000_000;
const SPAN_NS: i64 = 50_000_000;

/// Owned events, uniform over the pixels (xorshift, fixed seed), sorted times.
struct Events {
    t_ns: Vec<i64>,
    x: Vec<u16>,
    y: Vec<u16>,
    polarity: Vec<i8>,
}

impl Events {
    fn uniform(n: usize) -> Self {
        let mut s = 0x9E37_79B9_7F4A_7C15u64;
        let mut e = Self {
            t_ns: Vec::with_capacity(n),
            x: Vec::with_capacity(n),
            y: Vec::with_capacity(n),
            polarity: Vec::with_capacity(n),
        };
        for i in 0..n {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            e.t_ns.push(SPAN_NS * i as i64 / n as i64);
            e.x.push(((s >> 8) % WIDTH as u64) as u16);
            e.y.push(((s >> 24) % HEIGHT as u64) as u16);
            e.polarity
                .push(if (s >> 40).is_multiple_of(3) { -1 } else { 1 });
        }
        e
    }

    fn slice(&self) -> EventSlice<'_> {
        EventSlice {
            t_ns: &self.t_ns,
            x: &self.x,
            y: &self.y,
            polarity: &self.polarity,
        }
    }
}

fn bench(c: &mut Criterion) {
    let events = Events::uniform(EVENTS);
    let ev = events.slice();
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("one-thread pool");
    let mut dst = Array3::<f32>::zeros((BINS, HEIGHT, WIDTH));
    let mut g = c.benchmark_group("voxel_346x260_5bins_10M_events");
    g.sample_size(10);
    g.throughput(Throughput::Elements(EVENTS as u64));
    let mut hist = vec![0.0f64; WIDTH * HEIGHT];
    g.bench_function("baseline_histogram_by_pixel", |b| {
        b.iter(|| {
            hist.fill(0.0);
            for ((&x, &y), &p) in ev.x.iter().zip(ev.y).zip(ev.polarity) {
                hist[usize::from(y) * WIDTH + usize::from(x)] += f64::from(p);
            }
            black_box(&hist);
        })
    });
    g.bench_function("voxel_grid_into", |b| {
        b.iter(|| voxel_grid_into(ev, VoxelNorm::Raw, dst.view_mut()))
    });
    g.bench_function("voxel_grid_into_normalised", |b| {
        b.iter(|| voxel_grid_into(ev, VoxelNorm::NonZeroStandard, dst.view_mut()))
    });
    g.bench_function("voxel_grid_reference", |b| {
        b.iter(|| voxel_grid_reference(ev, VoxelNorm::Raw, dst.view_mut()))
    });
    g.bench_function("event_stack_into_1_thread", |b| {
        b.iter(|| one.install(|| event_stack_into(ev, dst.view_mut())))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
