//! The physics fusion anchored on rates: TFP over a window that adapts to the scene, carried by
//! the events (paper Eq. 5: `ln I(t2) - ln I(t1) = theta E(t1, t2)`).
//!
//! Per pixel the state is a spike count `K` over an effective number of planes `N` (a TFP whose
//! window the pixel's own history sets) and the signed events `E` since the last window:
//! - **a window** of `k` spikes over `n` planes, after `E` events and `dt` seconds: the events
//!   say the luminance changed by `exp(theta E)`, so the past count is rescaled, `K *=
//!   exp(theta E)`; the past is trusted less the more changed, both `K` and `N` multiplied by
//!   `exp(-forget_per_event |E| - dt / tau_s)`; then `K += k`, `N += n`.
//! - **a frame** at `t`: `gain K / N`, carried by the events since the last window,
//!   `exp(theta E)`, clamped to `[0, 1]`; 0 where no window was taken yet.
//!
//! A still pixel keeps its whole recent history (`tau_s`: 50 ms, about 1,000 planes at 20 kHz
//! where TFP takes 33): in the dark that is the difference between a spike or two and dozens. A
//! pixel whose events say it changed forgets its past within a few events and follows its new
//! counts, while the events carry it between windows. The estimate is a ratio of counts, not a
//! mean of logarithms, so it stays unbiased where counts are small. `theta E` is clamped to
//! `[-50, 50]` before `exp`.
//!
//! Time and events follow [`crate::PhysicsFusion`]'s rules: pushed in time order, errors leave
//! the state untouched.

use ndarray::{Array2, ArrayView2, ArrayViewMut2};

use crate::filter::{check_events, check_time, count_events, owned_slice, owned_slice_mut};
use crate::{EventSlice, InferError, check_shape, gain};

/// Settings of [`RateFusion`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RateFusionParams {
    /// Luminance per unit firing rate (`phi / light_scale`), finite and `> 0`.
    pub lum_per_rate: f64,
    /// The DVS contrast threshold, log luminance per event, finite and `> 0`.
    pub theta: f64,
    /// How much of the past one event forgets (as `exp(-forget_per_event)`), finite, `>= 0`.
    pub forget_per_event: f64,
    /// The memory of a still pixel, seconds, finite and `> 0` (`inf`: never forgets).
    pub tau_s: f64,
}

impl RateFusionParams {
    /// Defaults: an event keeps half of the past (`forget_per_event` = ln 2), a still pixel
    /// remembers 50 ms.
    pub fn new(lum_per_rate: f64, theta: f64) -> Self {
        RateFusionParams {
            lum_per_rate,
            theta,
            forget_per_event: std::f64::consts::LN_2,
            tau_s: 0.05,
        }
    }

    fn check(&self) -> Result<(), InferError> {
        gain(self.lum_per_rate, 1.0)?;
        let bad = |name, value, reason| {
            Err(InferError::Param {
                name,
                value,
                reason,
            })
        };
        if !(self.theta.is_finite() && self.theta > 0.0) {
            return bad("theta", self.theta, "must be finite and > 0");
        }
        if !(self.forget_per_event.is_finite() && self.forget_per_event >= 0.0) {
            return bad(
                "forget_per_event",
                self.forget_per_event,
                "must be finite and >= 0",
            );
        }
        if self.tau_s.is_nan() || self.tau_s <= 0.0 {
            return bad("tau_s", self.tau_s, "must be > 0 (inf allowed)");
        }
        Ok(())
    }
}

/// The recursive rate fusion (see the module).
#[derive(Clone, Debug)]
pub struct RateFusion {
    params: RateFusionParams,
    gain: f64,
    /// Effective spike count.
    l: Array2<f64>,
    /// Effective planes.
    p: Array2<f64>,
    /// Signed events since the last window.
    count: Array2<f64>,
    /// Whether any window was taken.
    anchored: bool,
    latest_ns: i64,
    last_window_ns: Option<i64>,
}

/// One pixel's window: `(k_eff, n_eff, events)` updated by `k` spikes over `n` planes; the rule
/// both paths use. `prm` is `(theta, forget_per_event, forget_dt)`.
#[inline(always)]
fn correct(
    k_eff: &mut f64,
    n_eff: &mut f64,
    count: &mut f64,
    rate: f32,
    n: f64,
    prm: (f64, f64, f64),
) {
    let (theta, forget_per_event, forget_dt) = prm;
    let e = *count;
    *count = 0.0;
    let keep = (-forget_per_event * e.abs() - forget_dt).exp();
    *k_eff *= (theta * e).clamp(-50.0, 50.0).exp() * keep;
    *n_eff *= keep;
    if rate.is_nan() {
        return;
    }
    *k_eff += (f64::from(rate) * n).clamp(0.0, n);
    *n_eff += n;
}

impl RateFusion {
    /// A `height x width` fusion with no estimate anywhere, its clock at `t_start_ns`.
    ///
    /// # Errors
    /// [`InferError::Param`] naming a setting out of its domain.
    pub fn new(
        height: usize,
        width: usize,
        params: RateFusionParams,
        t_start_ns: i64,
    ) -> Result<Self, InferError> {
        params.check()?;
        Ok(RateFusion {
            gain: params.lum_per_rate,
            params,
            l: Array2::zeros((height, width)),
            p: Array2::zeros((height, width)),
            count: Array2::zeros((height, width)),
            anchored: false,
            latest_ns: t_start_ns,
            last_window_ns: None,
        })
    }

    fn dim(&self) -> (usize, usize) {
        self.l.dim()
    }

    /// Counts events into each pixel's `E` (ON +1, OFF -1).
    ///
    /// # Errors
    /// As [`crate::PhysicsFusion::push_events`]; nothing is counted then.
    pub fn push_events(&mut self, events: EventSlice) -> Result<(), InferError> {
        let (h, w) = self.dim();
        let last = check_events(events, h, w, self.latest_ns)?;
        count_events(owned_slice_mut(&mut self.count), w, events);
        self.latest_ns = last.unwrap_or(self.latest_ns);
        Ok(())
    }

    fn prepare(
        &self,
        t_ns: i64,
        rate: &ArrayView2<f32>,
        n_planes: usize,
    ) -> Result<(f64, f64), InferError> {
        check_time("rate fusion window", t_ns, self.latest_ns)?;
        check_shape(
            "rate fusion rate (shape of the sensor)",
            self.dim(),
            rate.dim(),
        )?;
        if n_planes == 0 {
            return Err(InferError::Param {
                name: "n_planes",
                value: 0.0,
                reason: "a rate needs at least one plane",
            });
        }
        let dt_s = self
            .last_window_ns
            .map_or(0.0, |t| (t_ns.saturating_sub(t)).max(0) as f64 / 1e9);
        Ok((n_planes as f64, dt_s / self.params.tau_s))
    }

    /// Takes a window's rate (spikes per plane over `n_planes` planes, as TFP writes it) at
    /// `t_ns`: every pixel predicted by its events, then corrected by its count.
    ///
    /// # Errors
    /// [`InferError::TimeBackwards`], [`InferError::Shape`], or `n_planes` 0; nothing changes.
    pub fn push_rate(
        &mut self,
        t_ns: i64,
        rate: ArrayView2<f32>,
        n_planes: usize,
    ) -> Result<(), InferError> {
        let (n, forget_dt) = self.prepare(t_ns, &rate, n_planes)?;
        let prm = (self.params.theta, self.params.forget_per_event, forget_dt);
        let w = self.dim().1;
        let (l, p, c) = (
            owned_slice_mut(&mut self.l),
            owned_slice_mut(&mut self.p),
            owned_slice_mut(&mut self.count),
        );
        for (y, row) in rate.rows().into_iter().enumerate() {
            let r = y * w..(y + 1) * w;
            let state = l[r.clone()]
                .iter_mut()
                .zip(&mut p[r.clone()])
                .zip(&mut c[r]);
            for (((l, p), c), &v) in state.zip(row) {
                correct(l, p, c, v, n, prm);
            }
        }
        self.anchored = true;
        self.latest_ns = t_ns;
        self.last_window_ns = Some(t_ns);
        Ok(())
    }

    /// Scalar oracle for [`Self::push_rate`].
    #[doc(hidden)]
    pub fn push_rate_reference(
        &mut self,
        t_ns: i64,
        rate: ArrayView2<f32>,
        n_planes: usize,
    ) -> Result<(), InferError> {
        let (n, forget_dt) = self.prepare(t_ns, &rate, n_planes)?;
        let prm = (self.params.theta, self.params.forget_per_event, forget_dt);
        let (h, w) = self.dim();
        for y in 0..h {
            for x in 0..w {
                let (mut l, mut p, mut c) = (self.l[[y, x]], self.p[[y, x]], self.count[[y, x]]);
                correct(&mut l, &mut p, &mut c, rate[[y, x]], n, prm);
                (self.l[[y, x]], self.p[[y, x]], self.count[[y, x]]) = (l, p, c);
            }
        }
        self.anchored = true;
        self.latest_ns = t_ns;
        self.last_window_ns = Some(t_ns);
        Ok(())
    }

    /// The luminance at `t_ns`: `gain K / N` carried by the events since the last window,
    /// clamped to `[0, 1]`; 0 where no window was taken yet.
    ///
    /// # Errors
    /// [`InferError::TimeBackwards`] or [`InferError::Shape`].
    pub fn frame_into(&self, t_ns: i64, mut dst: ArrayViewMut2<f32>) -> Result<(), InferError> {
        check_time("rate fusion frame read", t_ns, self.latest_ns)?;
        check_shape(
            "rate fusion dst (shape of the sensor)",
            self.dim(),
            dst.dim(),
        )?;
        if !self.anchored {
            dst.fill(0.0);
            return Ok(());
        }
        let (theta, g) = (self.params.theta, self.gain);
        let (k, n, c) = (
            owned_slice(&self.l),
            owned_slice(&self.p),
            owned_slice(&self.count),
        );
        let w = self.dim().1;
        for (y, mut row) in dst.rows_mut().into_iter().enumerate() {
            let r = y * w..(y + 1) * w;
            let px = k[r.clone()].iter().zip(&n[r.clone()]).zip(&c[r]);
            for (d, ((&k, &n), &c)) in row.iter_mut().zip(px) {
                let lum = if n > 0.0 {
                    g * k / n * (theta * c).clamp(-50.0, 50.0).exp()
                } else {
                    0.0
                };
                *d = if lum.is_nan() {
                    0.0
                } else {
                    lum.clamp(0.0, 1.0) as f32
                };
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::array;
    use proptest::prelude::*;

    #[test]
    fn a_still_pixel_averages_its_windows_and_events_carry_a_change() {
        let mut f = RateFusion::new(1, 2, RateFusionParams::new(1.0, 0.2), 0).expect("new");
        let mut dst = Array2::<f32>::zeros((1, 2));
        f.frame_into(0, dst.view_mut()).expect("read");
        assert_eq!(dst, array![[0.0f32, 0.0]]);
        // Pixel 0 fires 1 spike in 4 planes each window, pixel 1 3 in 4.
        for k in 1..=50 {
            f.push_rate(k * 1_000_000, array![[0.25f32, 0.75]].view(), 4)
                .expect("rate");
        }
        f.frame_into(50_000_000, dst.view_mut()).expect("read");
        // The rates themselves, over about 50 windows of 4 planes (tau 50 ms at 1 ms a window).
        assert!(
            (dst[[0, 0]] - 0.25).abs() < 1e-6 && (dst[[0, 1]] - 0.75).abs() < 1e-6,
            "{dst}"
        );
        assert!(f.p[[0, 0]] > 4.0 * 30.0, "{}", f.p[[0, 0]]);
        // Two ON events at pixel 0: read through them at once, e^(0.4) brighter.
        let on = EventSlice {
            t_ns: &[50_000_001, 50_000_002],
            x: &[0, 0],
            y: &[0, 0],
            polarity: &[1, 1],
        };
        f.push_events(on).expect("events");
        f.frame_into(50_000_003, dst.view_mut()).expect("read");
        assert!(
            (f64::from(dst[[0, 0]]) - 0.25 * 0.4f64.exp()).abs() < 1e-5,
            "{dst}"
        );
        // The next window: the past rescaled by the events and mostly forgotten (a quarter kept
        // after two events), the new count added.
        let (k0, n0) = (f.l[[0, 0]], f.p[[0, 0]]);
        f.push_rate(51_000_000, array![[1.0f32, 0.75]].view(), 4)
            .expect("rate");
        let keep = (-2.0 * std::f64::consts::LN_2 - 1e-3 / 0.05f64).exp();
        assert!((f.l[[0, 0]] - (k0 * 0.4f64.exp() * keep + 4.0)).abs() < 1e-9);
        assert!((f.p[[0, 0]] - (n0 * keep + 4.0)).abs() < 1e-9);
        // Backwards in time is refused; nothing changed.
        let before = f.clone();
        assert!(f.push_rate(1, array![[0.0f32, 0.0]].view(), 4).is_err());
        assert!(
            f.push_rate(60_000_000, array![[0.0f32, 0.0]].view(), 0)
                .is_err()
        );
        assert_eq!((f.l.clone(), f.p.clone()), (before.l, before.p));
        assert!(RateFusion::new(1, 1, RateFusionParams::new(1.0, 0.0), 0).is_err());
        assert!(RateFusion::new(1, 1, RateFusionParams::new(f64::NAN, 0.2), 0).is_err());
    }

    proptest! {
        #[test]
        fn the_fast_path_equals_the_reference(
            rates in proptest::collection::vec(prop_oneof![0.0f32..=1.0, Just(f32::NAN), Just(2.0f32)], 12),
            ev in proptest::collection::vec((0u16..4, 0u16..3, prop_oneof![Just(1i8), Just(-1i8)]), 0..20),
            n in 1usize..64,
        ) {
            let rate = Array2::from_shape_vec((3, 4), rates).expect("shape");
            let mut a = RateFusion::new(3, 4, RateFusionParams::new(1.5, 0.2), 0).expect("new");
            let mut b = a.clone();
            for step in 1..4i64 {
                let t: Vec<i64> = (0..ev.len() as i64).map(|i| step * 1_000 + i).collect();
                let x: Vec<u16> = ev.iter().map(|e| e.0).collect();
                let y: Vec<u16> = ev.iter().map(|e| e.1).collect();
                let p: Vec<i8> = ev.iter().map(|e| e.2).collect();
                let e = EventSlice { t_ns: &t, x: &x, y: &y, polarity: &p };
                a.push_events(e).expect("a");
                b.push_events(e).expect("b");
                a.push_rate(step * 1_000 + 500, rate.view(), n).expect("a");
                b.push_rate_reference(step * 1_000 + 500, rate.view(), n).expect("b");
            }
            prop_assert_eq!(&a.l, &b.l);
            prop_assert_eq!(&a.p, &b.p);
            let (mut da, mut db) = (Array2::<f32>::zeros((3, 4)), Array2::<f32>::zeros((3, 4)));
            a.frame_into(10_000, da.view_mut()).expect("a");
            b.frame_into(10_000, db.view_mut()).expect("b");
            prop_assert_eq!(&da, &db);
            prop_assert!(da.iter().all(|v| v.is_finite() && (0.0..=1.0).contains(v)));
        }
    }
}
