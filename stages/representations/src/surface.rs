//! Time surface: how long ago each pixel last fired, per polarity, through an exponential decay.

use ndarray::{ArrayViewMut3, Axis};
use rayon::prelude::*;

use crate::error::{RepresentError, shape_str};
use crate::event::EventSlice;
use crate::spike::MIN_ELEMENTS_FOR_RAYON;

/// Channels of a time surface: 0 is ON, 1 is OFF.
pub const TIME_SURFACE_CHANNELS: usize = 2;

/// Pixels of the exponential pass handed to one rayon task.
const PIXELS_PER_TASK: usize = 1 << 12;

/// Time surface at `t_ref_ns`: `dst[c, y, x] = exp(-(t_ref_ns - t_last) / tau_ns)` with `t_last`
/// the timestamp of the latest event at or before `t_ref_ns` at pixel `(x, y)` with polarity ON
/// (`c = 0`) or OFF (`c = 1`), and 0 where the pixel has no such event. `dst` is `[2, H, W]`.
///
/// Events after `t_ref_ns` are ignored; every event given at or before it counts (the caller
/// slices the window's start). Values lie in `[0, 1]`: 1 for an event exactly at `t_ref_ns`.
/// `t_ref_ns - t_last` is exact (`i128`) and converted to `f64`, so instants anywhere in the
/// `i64` range work; the exponential is taken in `f64` and rounded once to `f32`.
///
/// Limits of `tau_ns` (nanoseconds, must be `> 0`):
/// - `tau_ns -> 0+` (down to the smallest subnormal): 1 for an event exactly at `t_ref_ns`, 0 for
///   older events (`exp(-inf)`), i.e. a map of the events at that instant; never NaN.
/// - `tau_ns = +inf` (allowed): 1 wherever the pixel has an event of that polarity, 0 elsewhere,
///   i.e. a binary "has fired" mask.
///
/// The cost is one backward pass over the events (stopping once every pixel and polarity has
/// its latest event) plus one exponential per pixel and channel.
///
/// # Errors
/// - [`RepresentError::Param`] when `tau_ns` is NaN, zero or negative, when the events are not
///   sorted by time, or a polarity is not ±1.
/// - [`RepresentError::Shape`] when `dst` has not 2 channels or the event slices differ in length.
/// - [`RepresentError::Index`] for an event outside the `[H, W]` sensor.
///
/// ```
/// use ndarray::Array3;
/// use neuspike_representations::{EventSlice, time_surface_into};
/// let (t_ns, x, y, polarity) = (&[0, 500, 900], &[0, 0, 1], &[0; 3], &[1, 1, -1]);
/// let events = EventSlice { t_ns, x, y, polarity };
/// let mut s = Array3::<f32>::zeros((2, 1, 2));
/// time_surface_into(events, 1_000, 500.0, s.view_mut()).unwrap();
/// assert!((s[[0, 0, 0]] - (-1.0f32).exp()).abs() < 1e-7); // latest ON at 500
/// assert_eq!(s[[0, 0, 1]], 0.0); // no ON event there
/// assert!((s[[1, 0, 1]] - (-0.2f32).exp()).abs() < 1e-7);
/// ```
pub fn time_surface_into(
    events: EventSlice,
    t_ref_ns: i64,
    tau_ns: f64,
    dst: ArrayViewMut3<f32>,
) -> Result<(), RepresentError> {
    check_surface(events, tau_ns, dst.dim())?;
    let parallel = dst.len() >= MIN_ELEMENTS_FOR_RAYON;
    surface_fast(events, t_ref_ns, tau_ns, dst, PIXELS_PER_TASK, parallel);
    Ok(())
}

fn check_surface(
    events: EventSlice,
    tau_ns: f64,
    dst_dim: (usize, usize, usize),
) -> Result<(), RepresentError> {
    let (c, h, w) = dst_dim;
    if c != TIME_SURFACE_CHANNELS {
        return Err(RepresentError::Shape {
            what: "time surface dst (ON and OFF channels)",
            expected: format!("[{TIME_SURFACE_CHANNELS}, {h}, {w}]"),
            actual: shape_str(&[c, h, w]),
        });
    }
    if tau_ns.is_nan() || tau_ns <= 0.0 {
        return Err(RepresentError::Param {
            name: "tau_ns",
            value: format!("{tau_ns}"),
            reason: "the decay time must be > 0 (+inf for no decay)",
        });
    }
    events.validate(h, w)
}

/// `exp(-(t_ref - t_last) / tau)` for `t_last <= t_ref` and `tau > 0`, rounded to `f32`.
#[inline]
fn decayed(t_ref_ns: i64, t_last_ns: i64, tau_ns: f64) -> f32 {
    let dt = (i128::from(t_ref_ns) - i128::from(t_last_ns)) as f64;
    (-dt / tau_ns).exp() as f32
}

/// Scalar oracle for [`time_surface_into`]: for every channel and pixel, a scan of all events
/// for the latest matching one. Same checks.
#[doc(hidden)]
pub fn time_surface_reference(
    events: EventSlice,
    t_ref_ns: i64,
    tau_ns: f64,
    mut dst: ArrayViewMut3<f32>,
) -> Result<(), RepresentError> {
    check_surface(events, tau_ns, dst.dim())?;
    let (_, h, w) = dst.dim();
    for (c, polarity) in [(0, 1i8), (1, -1i8)] {
        for y in 0..h {
            for x in 0..w {
                let mut latest = None;
                for i in 0..events.len() {
                    if events.t_ns[i] <= t_ref_ns
                        && usize::from(events.x[i]) == x
                        && usize::from(events.y[i]) == y
                        && events.polarity[i] == polarity
                    {
                        latest =
                            Some(latest.map_or(events.t_ns[i], |t: i64| t.max(events.t_ns[i])));
                    }
                }
                dst[[c, y, x]] = latest.map_or(0.0, |t| decayed(t_ref_ns, t, tau_ns));
            }
        }
    }
    Ok(())
}

/// Fast time surface, checked by the caller: the latest event of each pixel and polarity by a
/// backward scan from the last event at or before `t_ref_ns`, then the exponentials (in chunks of
/// `pixels_per_task` on rayon when `parallel`; element-wise, so identical either way).
fn surface_fast(
    events: EventSlice,
    t_ref_ns: i64,
    tau_ns: f64,
    mut dst: ArrayViewMut3<f32>,
    pixels_per_task: usize,
    parallel: bool,
) {
    let plane_len = dst.len_of(Axis(1)) * dst.len_of(Axis(2));
    let w = dst.len_of(Axis(2));
    let slots = TIME_SURFACE_CHANNELS * plane_len;
    let mut latest: Vec<Option<i64>> = vec![None; slots];
    let end = events.t_ns.partition_point(|&t| t <= t_ref_ns);
    let mut found = 0usize;
    for i in (0..end).rev() {
        if found == slots {
            break;
        }
        let channel = usize::from(events.polarity[i] < 0);
        let slot = channel * plane_len + usize::from(events.y[i]) * w + usize::from(events.x[i]);
        if latest[slot].is_none() {
            latest[slot] = Some(events.t_ns[i]);
            found += 1;
        }
    }
    let value = |t: &Option<i64>| t.map_or(0.0, |t| decayed(t_ref_ns, t, tau_ns));
    let fill = |(out, ts): (&mut [f32], &[Option<i64>])| {
        for (d, t) in out.iter_mut().zip(ts) {
            *d = value(t);
        }
    };
    let chunk = pixels_per_task.max(1);
    match dst.as_slice_mut() {
        Some(out) if parallel => out
            .par_chunks_mut(chunk)
            .zip(latest.par_chunks(chunk))
            .for_each(fill),
        Some(out) => fill((out, &latest)),
        None => {
            for (d, t) in dst.iter_mut().zip(&latest) {
                *d = value(t);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{Events, any_events};
    use ndarray::{Array3, array, s};
    use proptest::prelude::*;

    fn surface(e: &Events, t_ref: i64, tau: f64, h: usize, w: usize) -> Array3<f32> {
        let mut v = Array3::from_elem((2, h, w), f32::NAN);
        time_surface_into(e.slice(), t_ref, tau, v.view_mut()).expect("surface");
        let mut r = Array3::from_elem((2, h, w), f32::NAN);
        time_surface_reference(e.slice(), t_ref, tau, r.view_mut()).expect("reference");
        assert_eq!(v, r);
        v
    }

    #[test]
    fn latest_event_per_pixel_and_polarity_before_the_reference() {
        let e = Events::from(&[
            (100, 0, 0, 1),
            (300, 0, 0, 1),  // the latest ON at (0, 0)
            (350, 0, 0, -1), // the latest OFF at (0, 0)
            (400, 1, 0, -1),
            (600, 0, 0, 1), // after t_ref: ignored
            (700, 1, 0, 1), // after t_ref: ignored
        ]);
        let v = surface(&e, 500, 100.0, 1, 2);
        let ex = |dt: f64| (-dt / 100.0).exp() as f32;
        assert_eq!(
            v.slice(s![.., 0, ..]),
            array![[ex(200.0), 0.0], [ex(150.0), ex(100.0)]]
        );
        // An event exactly at t_ref gives 1.
        let v = surface(&e, 400, 100.0, 1, 2);
        assert_eq!(v[[1, 0, 1]], 1.0);
    }

    #[test]
    fn tau_limits_give_the_events_at_t_ref_and_the_fired_mask() {
        let e = Events::from(&[(10, 0, 0, 1), (20, 1, 0, 1), (20, 2, 0, -1)]);
        for tau in [f64::from_bits(1), 1e-300, 1e-9] {
            let v = surface(&e, 20, tau, 1, 3);
            assert_eq!(
                v,
                array![[[0.0, 1.0, 0.0]], [[0.0, 0.0, 1.0]]],
                "tau = {tau}"
            );
        }
        for tau in [f64::INFINITY, f64::MAX, 1e300] {
            let v = surface(&e, 20, tau, 1, 3);
            assert_eq!(
                v,
                array![[[1.0, 1.0, 0.0]], [[0.0, 0.0, 1.0]]],
                "tau = {tau}"
            );
        }
        // Over the whole i64 range, a finite tau decays to 0 and an infinite one does not.
        let e = Events::from(&[(i64::MIN, 0, 0, 1)]);
        assert_eq!(surface(&e, i64::MAX, 1e9, 1, 1)[[0, 0, 0]], 0.0);
        assert_eq!(surface(&e, i64::MAX, f64::INFINITY, 1, 1)[[0, 0, 0]], 1.0);
        let half = surface(&e, i64::MAX, 2f64.powi(64) / std::f64::consts::LN_2, 1, 1);
        assert!((half[[0, 0, 0]] - 0.5).abs() < 1e-6);
    }

    #[test]
    fn tau_zero_negative_or_nan_is_an_error() {
        let e = Events::from(&[(10, 0, 0, 1)]);
        let mut v = Array3::<f32>::zeros((2, 1, 1));
        for tau in [0.0, -0.0, -1.0, f64::NEG_INFINITY, f64::NAN] {
            let err = time_surface_into(e.slice(), 10, tau, v.view_mut()).expect_err("tau");
            assert!(err.to_string().contains("tau_ns"), "{err}");
        }
        let mut three = Array3::<f32>::zeros((3, 1, 1));
        let err = time_surface_into(e.slice(), 10, 1.0, three.view_mut()).expect_err("C");
        assert!(matches!(err, RepresentError::Shape { .. }), "{err}");
    }

    fn tau() -> impl Strategy<Value = f64> {
        prop_oneof![
            Just(f64::from_bits(1)),
            Just(f64::INFINITY),
            Just(f64::MAX),
            1e-3f64..1e3,
            1f64..1e19,
        ]
    }

    proptest! {
        #[test]
        fn surface_fast_matches_reference_bit_for_bit(
            (e, h, w) in any_events(5, 6, 60), t_ref in prop_oneof![any::<i64>(), -10i64..10],
            tau in tau(), chunk in 1usize..9, parallel in any::<bool>()
        ) {
            // The reference instant inside the events' range most of the time.
            let t_ref = match e.t_ns.get(t_ref.unsigned_abs() as usize % (e.t_ns.len() + 1)) {
                Some(&t) if t_ref >= 0 => t,
                _ => t_ref,
            };
            let mut slow = Array3::<f32>::zeros((2, h, w));
            time_surface_reference(e.slice(), t_ref, tau, slow.view_mut()).expect("ref");
            let mut fast = Array3::<f32>::from_elem((2, h, w), f32::NAN);
            surface_fast(e.slice(), t_ref, tau, fast.view_mut(), chunk, parallel);
            prop_assert_eq!(&fast, &slow);
            prop_assert!(fast.iter().all(|v| (0.0..=1.0).contains(v)));
        }
    }
}
