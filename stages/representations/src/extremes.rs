//! Numerical extremes for every event kernel, named for the case: empty windows, one timestamp,
//! timestamps at the ends of `i64`, decay constants towards 0 and infinity, one-pixel and one-row
//! sensors, a flood of ten million events, and never a NaN or an infinity.

use ndarray::{Array2, Array3, Axis, s};
use proptest::prelude::*;

use crate::testing::{Events, any_events};
use crate::{
    RepresentError, VoxelNorm, event_count_into, event_integration_into,
    event_integration_reference, event_stack_into, event_stack_reference, time_surface_into,
    voxel_grid_into, voxel_grid_reference,
};

/// Every event kernel's output for one set of events on an `h x w` sensor.
struct All {
    integration: Array3<f32>,
    count: Array2<f32>,
    voxel: Array3<f32>,
    voxel_norm: Array3<f32>,
    stack: Array3<f32>,
    surface: Array3<f32>,
}

/// Runs every event kernel (destinations filled with NaN first, so that an element left unwritten
/// shows): integration at `ts` with `tau`, `bins` bins, the time surface at `t_ref` with `tau`
/// (or 1 ns where `tau` is not allowed there).
fn all(e: &Events, h: usize, w: usize, ts: &[i64], tau: f64, bins: usize, t_ref: i64) -> All {
    let ev = e.slice();
    let t0 = e.t_ns.first().copied().unwrap_or(0);
    let mut integration = Array3::from_elem((ts.len(), h, w), f32::NAN);
    event_integration_into(ev, t0, ts, tau, integration.view_mut()).expect("integration");
    let mut count = Array2::from_elem((h, w), f32::NAN);
    event_count_into(ev, count.view_mut()).expect("count");
    let mut voxel = Array3::from_elem((bins, h, w), f32::NAN);
    voxel_grid_into(ev, VoxelNorm::Raw, voxel.view_mut()).expect("voxel");
    let mut voxel_norm = Array3::from_elem((bins, h, w), f32::NAN);
    voxel_grid_into(ev, VoxelNorm::NonZeroStandard, voxel_norm.view_mut()).expect("voxel norm");
    let mut stack = Array3::from_elem((bins, h, w), f32::NAN);
    event_stack_into(ev, stack.view_mut()).expect("stack");
    let mut surface = Array3::from_elem((2, h, w), f32::NAN);
    let surface_tau = if tau > 0.0 { tau } else { 1.0 };
    time_surface_into(ev, t_ref, surface_tau, surface.view_mut()).expect("surface");
    All {
        integration,
        count,
        voxel,
        voxel_norm,
        stack,
        surface,
    }
}

impl All {
    fn assert_finite(&self) {
        for (name, values) in [
            ("integration", self.integration.as_slice()),
            ("count", self.count.as_slice()),
            ("voxel", self.voxel.as_slice()),
            ("voxel_norm", self.voxel_norm.as_slice()),
            ("stack", self.stack.as_slice()),
            ("surface", self.surface.as_slice()),
        ] {
            let values = values.expect("standard layout");
            assert!(values.iter().all(|v| v.is_finite()), "{name} not finite");
        }
        assert!(self.surface.iter().all(|v| (0.0..=1.0).contains(v)));
    }

    fn assert_zero(&self) {
        self.assert_finite();
        assert!(self.integration.iter().all(|&v| v == 0.0));
        assert!(self.count.iter().all(|&v| v == 0.0));
        assert!(self.voxel.iter().all(|&v| v == 0.0));
        assert!(self.voxel_norm.iter().all(|&v| v == 0.0));
        assert!(self.stack.iter().all(|&v| v == 0.0));
        assert!(self.surface.iter().all(|&v| v == 0.0));
    }
}

#[test]
fn no_events_in_a_window_give_zeros_everywhere() {
    let none = Events::default();
    for (h, w) in [(1, 1), (1, 7), (4, 3)] {
        for tau in [0.0, 1.0, f64::INFINITY] {
            all(&none, h, w, &[0, 10], tau, 5, 10).assert_zero();
            all(&none, h, w, &[i64::MIN, i64::MAX], tau, 1, i64::MAX).assert_zero();
        }
    }
    // Events exist but none in the integration's window nor before the surface's instant.
    let late = Events::from(&[(1_000, 0, 0, 1), (2_000, 1, 0, -1)]);
    let mut v = Array3::from_elem((1, 1, 2), f32::NAN);
    event_integration_into(late.slice(), 0, &[999], 10.0, v.view_mut()).expect("integration");
    assert!(v.iter().all(|&x| x == 0.0));
    let mut ts = Array3::from_elem((2, 1, 2), f32::NAN);
    time_surface_into(late.slice(), 999, 10.0, ts.view_mut()).expect("surface");
    assert!(ts.iter().all(|&x| x == 0.0));
}

#[test]
fn all_events_at_one_timestamp() {
    let t = 1_234_567;
    let e = Events::from(&[
        (t, 0, 0, 1),
        (t, 0, 0, 1),
        (t, 1, 0, -1),
        (t, 2, 1, 1),
        (t, 2, 1, -1),
    ]);
    let a = all(&e, 2, 3, &[t - 1, t], 100.0, 4, t);
    a.assert_finite();
    let count = ndarray::array![[2.0, -1.0, 0.0], [0.0, 0.0, 0.0]];
    assert_eq!(a.count, count);
    // dt = 1: every event has t* = 0, all in bin 0 with weight 1; the stack agrees.
    assert_eq!(a.voxel.index_axis(Axis(0), 0), count);
    assert!(a.voxel.slice(s![1.., .., ..]).iter().all(|&v| v == 0.0));
    assert_eq!(a.stack, a.voxel);
    // Two non-zero voxels (2 and -1): mean 0.5, std 1.5, so +1 and -1.
    assert_eq!(
        a.voxel_norm.index_axis(Axis(0), 0),
        ndarray::array![[1.0, -1.0, 0.0], [0.0, 0.0, 0.0]]
    );
    // Eq. 8 before the instant: nothing; at it: 1 + exp(0) = 2 per event.
    assert!(
        a.integration
            .index_axis(Axis(0), 0)
            .iter()
            .all(|&v| v == 0.0)
    );
    assert_eq!(
        a.integration.index_axis(Axis(0), 1),
        count.mapv(|c| 2.0 * c)
    );
    // Time surface at that instant: 1 where a pixel has an event of the polarity.
    assert_eq!(
        a.surface,
        ndarray::array![
            [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
            [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
        ]
    );
}

#[test]
fn timestamps_near_i64_max_and_over_the_whole_range() {
    let top = Events::from(&[
        (i64::MAX - 4, 0, 0, 1),
        (i64::MAX - 2, 0, 0, -1),
        (i64::MAX, 1, 0, 1),
    ]);
    let a = all(&top, 1, 2, &[i64::MAX - 2, i64::MAX], 2.0, 3, i64::MAX);
    a.assert_finite();
    // dt = 4: t* = 0, 1, 2.
    assert_eq!(
        a.voxel,
        ndarray::array![[[1.0, 0.0]], [[-1.0, 0.0]], [[0.0, 1.0]]]
    );
    assert_eq!(a.stack, a.voxel); // B (t - t0) / dt = 0, 1.5, 3 -> bins 0, 1, 2
    let ex = |x: f64| x.exp() as f32;
    assert_eq!(
        a.surface,
        ndarray::array![[[ex(-2.0), 1.0]], [[ex(-1.0), 0.0]]]
    );
    let want = (1.0 + (-2.0f64).exp()) - (1.0 + (-1.0f64).exp());
    assert!((f64::from(a.integration[[1, 0, 0]]) - want).abs() < 1e-6);

    // The full range: dt = 2^64 - 1, which no i64 holds.
    let wide = Events::from(&[(i64::MIN, 0, 0, 1), (0, 0, 0, 1), (i64::MAX, 0, 0, -1)]);
    let a = all(&wide, 1, 1, &[i64::MIN, 0, i64::MAX], 1e18, 3, i64::MAX);
    a.assert_finite();
    // t* = 0, 2 * 2^63 / (2^64 - 1) = 1 (after rounding to f64), 2.
    assert_eq!(
        a.voxel.iter().copied().collect::<Vec<_>>(),
        vec![1.0, 1.0, -1.0]
    );
    assert_eq!(
        a.stack.iter().copied().collect::<Vec<_>>(),
        vec![1.0, 1.0, -1.0]
    );
    let mut r = Array3::<f32>::zeros((3, 1, 1));
    voxel_grid_reference(wide.slice(), VoxelNorm::Raw, r.view_mut()).expect("reference");
    assert_eq!(r, a.voxel);
    event_stack_reference(wide.slice(), r.view_mut()).expect("reference");
    assert_eq!(r, a.stack);
    // ON last at 0, 2^63 - 1 ns before i64::MAX; OFF at i64::MAX itself.
    let on = (-(i64::MAX as f64) / 1e18).exp() as f32;
    assert_eq!(a.surface.iter().copied().collect::<Vec<_>>(), vec![on, 1.0]);
}

#[test]
fn integration_tau_towards_zero_approaches_the_plain_count() {
    // Eq. 8 at an instant after every event: 1 + exp(-(t - t_i) / tau) per event, which falls
    // monotonically to 1 as tau shrinks, and is exactly the count once exp underflows.
    let e = Events::from(&[
        (0, 0, 0, 1),
        (900, 0, 0, 1),
        (990, 0, 0, -1),
        (999, 1, 0, 1),
    ]);
    let count = ndarray::array![[1.0f32, 1.0]];
    let mut previous = f32::INFINITY;
    for tau in [
        1e6,
        1e3,
        10.0,
        1.0,
        1e-3,
        1e-300,
        f64::from_bits(1),
        0.0,
        -1.0,
    ] {
        let mut v = Array3::from_elem((1, 1, 2), f32::NAN);
        event_integration_into(e.slice(), 0, &[1_000], tau, v.view_mut()).expect("integration");
        let mut r = Array3::from_elem((1, 1, 2), f32::NAN);
        event_integration_reference(e.slice(), 0, &[1_000], tau, r.view_mut()).expect("ref");
        assert!((&v - &r).iter().all(|d| d.abs() < 1e-6), "tau = {tau}");
        assert!(v.iter().all(|x| x.is_finite()));
        assert!(v[[0, 0, 1]] <= previous, "tau = {tau}: not monotone");
        previous = v[[0, 0, 1]];
        if tau <= 1e-3 {
            assert_eq!(v.index_axis(Axis(0), 0), count, "tau = {tau}");
        }
    }
}

#[test]
fn integration_tau_towards_infinity_approaches_twice_the_count() {
    let e = Events::from(&[
        (i64::MIN, 0, 0, 1),
        (0, 0, 0, 1),
        (5, 0, 0, -1),
        (i64::MAX - 1, 1, 0, 1),
    ]);
    // Tolerance: the oldest event has aged 2^64 ns, so 1 - exp(-2^64 / tau) of its weight is gone.
    for (tau, tol) in [
        (1e21, 0.05),
        (1e30, 1e-6),
        (1e300, 0.0),
        (f64::MAX, 0.0),
        (f64::INFINITY, 0.0),
    ] {
        let mut v = Array3::from_elem((1, 1, 2), f32::NAN);
        event_integration_into(e.slice(), i64::MIN, &[i64::MAX], tau, v.view_mut())
            .expect("integration");
        assert!(
            (v[[0, 0, 0]] - 2.0).abs() <= tol,
            "tau = {tau}: {}",
            v[[0, 0, 0]]
        );
        assert!(
            (v[[0, 0, 1]] - 2.0).abs() <= tol,
            "tau = {tau}: {}",
            v[[0, 0, 1]]
        );
    }
}

#[test]
fn one_by_one_and_one_row_sensors() {
    // 1 x 1: every event at the one pixel.
    let e = Events::from(&[(0, 0, 0, 1), (10, 0, 0, 1), (20, 0, 0, -1), (40, 0, 0, 1)]);
    let a = all(&e, 1, 1, &[40], f64::INFINITY, 5, 40);
    a.assert_finite();
    assert_eq!(a.count[[0, 0]], 2.0);
    assert_eq!(a.integration[[0, 0, 0]], 4.0);
    // t* = 0, 1, 2, 4 over 5 bins.
    assert_eq!(
        a.voxel.iter().copied().collect::<Vec<_>>(),
        vec![1.0, 1.0, -1.0, 0.0, 1.0]
    );
    // B (t - t0) / dt = 0, 1.25, 2.5, 5 -> bins 0, 1, 2, 4.
    assert_eq!(a.stack, a.voxel);
    assert_eq!(
        a.surface.iter().copied().collect::<Vec<_>>(),
        vec![1.0, 1.0]
    );
    // 1 x W and H x 1: pixels stay apart.
    let row = Events::from(&[(0, 0, 0, 1), (5, 6, 0, -1), (10, 3, 0, 1)]);
    let a = all(&row, 1, 7, &[10], 1.0, 2, 10);
    a.assert_finite();
    assert_eq!(
        a.count,
        ndarray::array![[1.0, 0.0, 0.0, 1.0, 0.0, 0.0, -1.0]]
    );
    assert_eq!(
        a.voxel,
        ndarray::array![
            [[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, -0.5]],
            [[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, -0.5]]
        ]
    );
    let column = Events::from(&[(0, 0, 0, 1), (5, 0, 6, -1), (10, 0, 3, 1)]);
    let b = all(&column, 7, 1, &[10], 1.0, 2, 10);
    b.assert_finite();
    assert_eq!(
        b.voxel.iter().collect::<Vec<_>>(),
        a.voxel.iter().collect::<Vec<_>>()
    );
    assert_eq!(
        b.stack.iter().collect::<Vec<_>>(),
        a.stack.iter().collect::<Vec<_>>()
    );
}

#[test]
fn event_flood_of_ten_million_events() {
    // 10^7 events over 10 ms on a 346 x 260 sensor, one window.
    const N: usize = 10_000_000;
    let (h, w, bins) = (260, 346, 5);
    let e = Events::flood(N, h, w, 1_000_000_000, 10_000_000, 42);
    let counts = e.signed_counts(h, w);
    let total: i64 = counts.iter().sum();
    let ev = e.slice();

    let mut count = Array2::from_elem((h, w), f32::NAN);
    event_count_into(ev, count.view_mut()).expect("count");
    assert!(count.iter().zip(&counts).all(|(&a, &b)| a == b as f32));

    let mut voxel = Array3::from_elem((bins, h, w), f32::NAN);
    voxel_grid_into(ev, VoxelNorm::Raw, voxel.view_mut()).expect("voxel");
    assert!(voxel.iter().all(|v| v.is_finite()));
    let per_pixel = voxel.mapv(f64::from).sum_axis(Axis(0));
    for (got, &want) in per_pixel.iter().zip(&counts) {
        // At most ~250 events per pixel: the f32 roundings of 5 voxels stay far below 1e-3.
        assert!((got - want as f64).abs() < 1e-3, "{got} vs {want}");
    }
    assert!((per_pixel.sum() - total as f64).abs() < 1.0);
    let mut reference = Array3::from_elem((bins, h, w), f32::NAN);
    voxel_grid_reference(ev, VoxelNorm::Raw, reference.view_mut()).expect("reference");
    assert_eq!(voxel, reference);
    voxel_grid_into(ev, VoxelNorm::NonZeroStandard, voxel.view_mut()).expect("normalised");
    assert!(voxel.iter().all(|v| v.is_finite()));

    let mut stack = Array3::from_elem((bins, h, w), f32::NAN);
    event_stack_into(ev, stack.view_mut()).expect("stack");
    assert_eq!(stack.sum_axis(Axis(0)), count);
    // Each bin's total is the signed sum of the events of its fifth of the span.
    let t0 = e.t_ns[0];
    let mut per_bin = [0i64; 5];
    for (&t, &p) in e.t_ns.iter().zip(&e.polarity) {
        let b = ((t - t0) as u128 * bins as u128 / 10_000_000).min(bins as u128 - 1);
        per_bin[b as usize] += i64::from(p);
    }
    for (b, &want) in per_bin.iter().enumerate() {
        assert_eq!(
            f64::from(stack.index_axis(Axis(0), b).sum()),
            want as f64,
            "bin {b}"
        );
    }

    let mut integration = Array3::from_elem((2, h, w), f32::NAN);
    let ts = [1_005_000_000, 1_010_000_000];
    event_integration_into(ev, t0, &ts, f64::INFINITY, integration.view_mut()).expect("eq 8");
    assert_eq!(integration.index_axis(Axis(0), 1), count.mapv(|c| 2.0 * c));
    event_integration_into(ev, t0, &ts, 1e6, integration.view_mut()).expect("eq 8");
    assert!(integration.iter().all(|v| v.is_finite()));

    let mut surface = Array3::from_elem((2, h, w), f32::NAN);
    time_surface_into(ev, 1_010_000_000, 1e6, surface.view_mut()).expect("surface");
    assert!(surface.iter().all(|v| (0.0..=1.0).contains(v)));
    // With ~110 events per pixel and polarity every pixel has fired recently.
    assert!(surface.iter().all(|&v| v > 0.0));

    // The same flood on one pixel: exact totals in the integer kernels, f64 sums in the grid.
    let mut one = e;
    one.x.fill(0);
    one.y.fill(0);
    let a = all(&one, 1, 1, &ts, f64::INFINITY, bins, 1_010_000_000);
    a.assert_finite();
    assert_eq!(f64::from(a.count[[0, 0]]), total as f64);
    assert_eq!(f64::from(a.stack.sum()), total as f64);
    assert!((a.voxel.mapv(f64::from).sum() - total as f64).abs() < 1.0);
    assert_eq!(f64::from(a.integration[[1, 0, 0]]), 2.0 * total as f64);
}

#[test]
fn bad_parameters_are_errors_not_nan() {
    let e = Events::from(&[(0, 0, 0, 1)]);
    let mut v = Array3::<f32>::zeros((2, 1, 1));
    let err = time_surface_into(e.slice(), 0, 0.0, v.view_mut()).expect_err("tau 0");
    assert!(matches!(err, RepresentError::Param { .. }), "{err}");
    let err = event_integration_into(e.slice(), 0, &[0, 1], f64::NAN, v.view_mut()).expect_err("");
    assert!(matches!(err, RepresentError::Param { .. }), "{err}");
}

fn extreme_tau() -> impl Strategy<Value = f64> {
    prop_oneof![
        Just(0.0),
        Just(f64::from_bits(1)),
        Just(1e-300),
        Just(1.0),
        Just(1e300),
        Just(f64::MAX),
        Just(f64::INFINITY),
        1e-3f64..1e12,
    ]
}

proptest! {
    #[test]
    fn never_nan_nor_infinity(
        (e, h, w) in any_events(4, 5, 50),
        tau in extreme_tau(),
        ts in proptest::collection::vec(any::<i64>(), 0..4),
        bins in 1usize..6,
        t_ref in any::<i64>(),
    ) {
        let mut ts = ts;
        ts.sort_unstable();
        let a = all(&e, h, w, &ts, tau, bins, t_ref);
        a.assert_finite();
        let n = e.t_ns.len() as f32;
        prop_assert!(a.integration.iter().all(|v| v.abs() <= 2.0 * n));
        prop_assert!(a.voxel.iter().all(|v| v.abs() <= n));
        prop_assert!(a.stack.iter().all(|v| v.abs() <= n));
    }
}
