//! Speed of the event-based reconstructions at 346x260 (DAVIS346) with 1 million events per frame,
//! each against its scalar reference and a memcpy baseline measured in the same run.
//!
//! - `*_frame_1M_events`: one output frame's work: push 1 M events (uniform over the pixels, the
//!   worst case for caches; times evenly over 33 ms, a third OFF), push the frame or ISI map where
//!   the method takes one, read the frame. Throughput in events. Baseline: copying the four event
//!   columns (13 MB) once, the least any pass over the events costs.
//! - `read_346x260`: reading one frame from the state alone. Throughput in pixels. Baseline:
//!   copying one `f32` frame (360 KB).
//!
//! Everything runs on one thread (the event passes never use rayon; the frame maps only from
//! 4 M pixels). The filter states are cloned outside the timed part.
//!
//! `cargo bench -p neuspike-reconstruction --bench bench_fusion -- --warm-up-time 1 --measurement-time 3`

use criterion::{BatchSize, Criterion, Throughput, criterion_group, criterion_main};
use ndarray::Array2;
use neuspike_reconstruction::{
    ComplementaryFilter, Contrast, EventSlice, FusionParams, HighPassFilter, PhysicsFusion,
    ThetaMode,
};
use std::hint::black_box;

const WIDTH: usize = 346;
const HEIGHT: usize = 260;
const EVENTS: usize = 1_000_000;
const SPAN_NS: i64 = 33_333_333;
/// The cutoff of the high-pass filter and the gain of the complementary filter, rad/s.
const ALPHA_RAD_S: f64 = 2.0 * std::f64::consts::PI;
const CONTRAST: Contrast = Contrast { on: 0.2, off: 0.2 };

/// Owned events, uniform over the pixels (xorshift, fixed seed), times evenly over `SPAN_NS`
/// after `t0_ns`.
struct Events {
    t_ns: Vec<i64>,
    x: Vec<u16>,
    y: Vec<u16>,
    polarity: Vec<i8>,
}

impl Events {
    fn uniform(n: usize, t0_ns: i64) -> Self {
        let mut s = 0x9E37_79B9_7F4A_7C15u64;
        let mut e = Events {
            t_ns: Vec::with_capacity(n),
            x: Vec::with_capacity(n),
            y: Vec::with_capacity(n),
            polarity: Vec::with_capacity(n),
        };
        for i in 0..n {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            e.t_ns.push(t0_ns + SPAN_NS * i as i64 / n as i64);
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

    fn empty_like(&self) -> Self {
        let n = self.t_ns.len();
        Events {
            t_ns: vec![0; n],
            x: vec![0; n],
            y: vec![0; n],
            polarity: vec![0; n],
        }
    }
}

/// A luminance frame and an ISI map with its validity: a smooth ramp, a few invalid pixels.
fn frame_and_isi() -> (Array2<f32>, Array2<f32>, Array2<bool>) {
    let lum = Array2::from_shape_fn((HEIGHT, WIDTH), |(y, x)| {
        0.05 + 0.9 * ((x + y) % 97) as f32 / 97.0
    });
    let isi = lum.mapv(|l| (1.0 / l).round().max(1.0));
    let valid = Array2::from_shape_fn((HEIGHT, WIDTH), |(y, x)| (x * 7 + y) % 50 != 0);
    (lum, isi, valid)
}

fn bench(c: &mut Criterion) {
    let first = Events::uniform(EVENTS, 0);
    let next = Events::uniform(EVENTS, SPAN_NS);
    let (ev0, ev) = (first.slice(), next.slice());
    let t_frame = 2 * SPAN_NS;
    let (lum, isi, valid) = frame_and_isi();

    // States after one frame of events, so the timed frame meets warm, non-trivial pixels.
    let mut hf0 = HighPassFilter::new(HEIGHT, WIDTH, ALPHA_RAD_S, 0).expect("hf");
    hf0.push_events(ev0, CONTRAST).expect("hf events");
    let mut cf0 = ComplementaryFilter::new(HEIGHT, WIDTH, ALPHA_RAD_S, 0).expect("cf");
    cf0.push_frame(0, lum.view()).expect("cf frame");
    cf0.push_events(ev0, CONTRAST).expect("cf events");
    let params = FusionParams {
        mode: ThetaMode::PerPixel,
        ..FusionParams::new(1.0, 1.0)
    };
    let mut fu0 = PhysicsFusion::new(HEIGHT, WIDTH, params, 0).expect("fusion");
    fu0.push_isi(0, isi.view(), valid.view()).expect("isi");
    fu0.push_events(ev0).expect("fusion events");

    let mut out = Array2::<f32>::zeros((HEIGHT, WIDTH));
    let mut out_valid = Array2::from_elem((HEIGHT, WIDTH), false);
    let mut copy = next.empty_like();

    let mut g = c.benchmark_group("frame_1M_events_346x260");
    g.sample_size(10);
    g.throughput(Throughput::Elements(EVENTS as u64));
    g.bench_function("baseline_memcpy_events", |b| {
        b.iter(|| {
            copy.t_ns.copy_from_slice(black_box(&next.t_ns));
            copy.x.copy_from_slice(black_box(&next.x));
            copy.y.copy_from_slice(black_box(&next.y));
            copy.polarity.copy_from_slice(black_box(&next.polarity));
            black_box(&copy);
        })
    });
    g.bench_function("hf_fast", |b| {
        b.iter_batched_ref(
            || hf0.clone(),
            |f| {
                f.push_events(ev, CONTRAST).expect("events");
                f.frame_into(t_frame, out.view_mut()).expect("read");
            },
            BatchSize::LargeInput,
        )
    });
    g.bench_function("hf_reference", |b| {
        b.iter_batched_ref(
            || hf0.clone(),
            |f| {
                f.push_events_reference(ev, CONTRAST).expect("events");
                f.frame_into_reference(t_frame, out.view_mut())
                    .expect("read");
            },
            BatchSize::LargeInput,
        )
    });
    g.bench_function("cf_fast", |b| {
        b.iter_batched_ref(
            || cf0.clone(),
            |f| {
                f.push_events(ev, CONTRAST).expect("events");
                f.push_frame(t_frame, lum.view()).expect("frame");
                f.frame_into(t_frame, out.view_mut()).expect("read");
            },
            BatchSize::LargeInput,
        )
    });
    g.bench_function("cf_reference", |b| {
        b.iter_batched_ref(
            || cf0.clone(),
            |f| {
                f.push_events_reference(ev, CONTRAST).expect("events");
                f.push_frame_reference(t_frame, lum.view()).expect("frame");
                f.frame_into_reference(t_frame, out.view_mut())
                    .expect("read");
            },
            BatchSize::LargeInput,
        )
    });
    g.bench_function("fusion_fast", |b| {
        b.iter_batched_ref(
            || fu0.clone(),
            |f| {
                f.push_events(ev).expect("events");
                f.push_isi(t_frame, isi.view(), valid.view()).expect("isi");
                f.frame_into(t_frame, out.view_mut(), out_valid.view_mut())
                    .expect("read");
            },
            BatchSize::LargeInput,
        )
    });
    g.bench_function("fusion_reference", |b| {
        b.iter_batched_ref(
            || fu0.clone(),
            |f| {
                f.push_events_reference(ev).expect("events");
                f.push_isi_reference(t_frame, isi.view(), valid.view())
                    .expect("isi");
                f.frame_into_reference(t_frame, out.view_mut(), out_valid.view_mut())
                    .expect("read");
            },
            BatchSize::LargeInput,
        )
    });
    g.finish();

    let mut g = c.benchmark_group("read_346x260");
    g.throughput(Throughput::Elements((WIDTH * HEIGHT) as u64));
    let src = lum.clone();
    g.bench_function("baseline_memcpy_frame", |b| {
        b.iter(|| out.assign(black_box(&src)))
    });
    g.bench_function("hf_fast", |b| {
        b.iter(|| hf0.frame_into(t_frame, out.view_mut()).expect("read"))
    });
    g.bench_function("hf_reference", |b| {
        b.iter(|| {
            hf0.frame_into_reference(t_frame, out.view_mut())
                .expect("read")
        })
    });
    g.bench_function("cf_fast", |b| {
        b.iter(|| cf0.frame_into(t_frame, out.view_mut()).expect("read"))
    });
    g.bench_function("cf_reference", |b| {
        b.iter(|| {
            cf0.frame_into_reference(t_frame, out.view_mut())
                .expect("read")
        })
    });
    g.bench_function("fusion_fast", |b| {
        b.iter(|| {
            fu0.frame_into(t_frame, out.view_mut(), out_valid.view_mut())
                .expect("read")
        })
    });
    g.bench_function("fusion_reference", |b| {
        b.iter(|| {
            fu0.frame_into_reference(t_frame, out.view_mut(), out_valid.view_mut())
                .expect("read")
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
