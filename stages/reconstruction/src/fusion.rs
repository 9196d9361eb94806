//! The physics fusion of spikes and events of NeuSpike-Net (Zhang et al., ICCV 2021), Eq. 5-7.
//!
//! The spike camera measures absolute luminance where it measures an inter-spike interval:
//! `I = phi / (ISI * light_scale)` (Eq. 3). The event camera measures changes of log luminance:
//! `ln I(t2) - ln I(t1) = theta E(t1, t2)` (Eq. 5) with `E` the signed event count between the two
//! instants (docs/definitions.md). Per pixel, [`PhysicsFusion`]
//!
//! - keeps an **anchor**: the log luminance of the last reliable ISI, `ln I(t0) = ln(phi /
//!   light_scale) - ln ISI(t0)`, and the signed count `E(t0, t)` of the events since;
//! - estimates the contrast threshold from two consecutive reliable ISIs and the events between
//!   them, Eq. 6: `theta = ln(ISI_1 / ISI_2) / E(t1, t2)`;
//! - reads the luminance forward from the anchor, Eq. 7: `I(t) = I(t0) exp(theta E(t0, t))`.
//!
//! **Estimating theta.** One pair gives Eq. 6. Over several pairs the fusion keeps the
//! least-squares solution of Eq. 5, `theta = sum(E_j d_j) / sum(E_j^2)` with `d_j = ln(ISI_1 /
//! ISI_2)` (for a single pair this is Eq. 6 exactly); equivalently the mean of the pairs' Eq. 6
//! estimates weighted by `E_j^2`, which gives the pairs with many events, least hurt by the
//! whole-tick rounding of ISIs, the most say. [`ThetaMode`] chooses whether each pixel uses its own
//! pairs, the pool of all pixels' pairs, or the fixed initial value. A pair is not used when:
//!
//! | case | counted in [`IsiUpdateStats`] as |
//! |---|---|
//! | an ISI of 1 tick: saturated, a bound on the light, not a measurement | `theta_saturated` |
//! | `E = 0` or equal ISIs: Eq. 6 is 0/0 or says "no change" below the ISI's resolution | `theta_undefined` |
//! | the estimate is outside `[theta_min, theta_max]` (wrong sign included) | `theta_rejected` |
//!
//! and the previous theta (of the pixel, or the pool, or `theta_init`) is kept.
//!
//! **Anchors.** A valid ISI (the validity mask of `neuspike_representations::isi_into`) re-anchors the
//! pixel and restarts its count. An invalid one (the pixel did not fire on both sides within the
//! search window) is a lower bound on the ISI: a pixel that has a measured anchor keeps it and goes
//! on counting events (`carried`); a pixel without one takes the bound as a provisional anchor
//! (`bounded`: the luminance is an upper bound, as TFI shows it, and the output is flagged not
//! valid). ISIs below 1 tick count as 1 (the shortest a spike camera reports), `+inf` as
//! `f32::MAX`; a NaN ISI leaves the pixel untouched (`ignored`).
//!
//! **Output.** `exp(min(x, 0))` of `x = ln I(t0) + theta E(t0, t)`, so in `[0, 1]`. Where `x > 0`
//! (the estimate exceeds the sensor's range 1, exp overflow beyond `x > ln(f64::MAX)` included)
//! the output is 1 and [`FusionFrameStats`] counts it. A pixel with no anchor at all (no ISI map
//! pushed yet) gives 0, not valid.
//!
//! **Time.** Events and ISI maps are pushed in time order (events at the map's instant before or
//! after it, as the caller decides which interval they belong to); reads at or after the latest
//! instant. [`InferError::TimeBackwards`] otherwise.
//!
//! **Paths.** Event pushes (one add per event) and ISI pushes are exact in both paths: the fast
//! ones run over flat slices and rows instead of indexing. Reads take the exponentials on the
//! vector unit (within a few ulp of `f64::exp`; tests bound the difference).

use ndarray::{Array2, ArrayView2, ArrayViewMut1, ArrayViewMut2, Axis, Zip};
use neuspike_representations::EventSlice;

use crate::filter::{check_events, check_time, count_events, owned_slice, owned_slice_mut};
use crate::{InferError, check_shape, gain};
use neuspike_simd::fastmath::{exp_nonpos, exp_nonpos_reference};

/// Pixels per chunk of the fast frame read (stack buffers).
const ROW_CHUNK: usize = 512;

/// `ln(f64::MAX)`: above it `exp` overflows to infinity.
const LN_F64_MAX: f64 = 709.782_712_893_384;

/// Per-pixel anchor kinds.
const NO_ANCHOR: u8 = 0;
/// Provisional anchor from an invalid ISI (an upper bound on the luminance).
const BOUND: u8 = 1;
/// Anchor from a valid ISI.
const MEASURED: u8 = 2;

/// Which pairs of ISIs the contrast threshold is estimated from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ThetaMode {
    /// `theta_init` everywhere; estimates are still made and reported, not used.
    Fixed,
    /// One theta for the sensor: the least-squares estimate over every pixel's accepted pairs,
    /// `theta_init` until the first.
    Global,
    /// Each pixel its own least-squares estimate; a pixel without an accepted pair uses the global
    /// one (then `theta_init`).
    PerPixel,
}

/// A name that is not a [`ThetaMode`].
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0:?} is not one of fixed, global, per-pixel")]
pub struct UnknownThetaMode(pub String);

impl std::str::FromStr for ThetaMode {
    type Err = UnknownThetaMode;

    /// `fixed`, `global` or `per-pixel`, exactly.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "fixed" => Ok(ThetaMode::Fixed),
            "global" => Ok(ThetaMode::Global),
            "per-pixel" => Ok(ThetaMode::PerPixel),
            _ => Err(UnknownThetaMode(s.to_string())),
        }
    }
}

/// Settings of the [`PhysicsFusion`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FusionParams {
    /// The spike camera's firing threshold (finite, `> 0`).
    pub phi: f64,
    /// Charge per tick a pixel of luminance 1 collects (finite, `> 0`).
    pub light_scale: f64,
    /// Contrast threshold (log luminance per event) before any estimate, in
    /// `[theta_min, theta_max]`.
    pub theta_init: f64,
    /// Smallest Eq. 6 estimate accepted (finite, `> 0`).
    pub theta_min: f64,
    /// Largest Eq. 6 estimate accepted (finite, `>= theta_min`).
    pub theta_max: f64,
    /// Where each pixel's theta comes from.
    pub mode: ThetaMode,
}

impl FusionParams {
    /// Defaults around a DAVIS346's threshold: `theta_init` 0.2, accepted estimates in
    /// `[0.01, 2]`, [`ThetaMode::Global`].
    pub fn new(phi: f64, light_scale: f64) -> Self {
        FusionParams {
            phi,
            light_scale,
            theta_init: 0.2,
            theta_min: 0.01,
            theta_max: 2.0,
            mode: ThetaMode::Global,
        }
    }

    /// Checks every field; returns `ln(phi / light_scale)`.
    fn check(&self) -> Result<f64, InferError> {
        let g = gain(self.phi, self.light_scale)?;
        let bad = |name, value, reason| {
            Err(InferError::Param {
                name,
                value,
                reason,
            })
        };
        if !(self.theta_min.is_finite() && self.theta_min > 0.0) {
            return bad("theta_min", self.theta_min, "must be finite and > 0");
        }
        if !(self.theta_max.is_finite() && self.theta_max >= self.theta_min) {
            return bad(
                "theta_max",
                self.theta_max,
                "must be finite and >= theta_min",
            );
        }
        if !(self.theta_init >= self.theta_min && self.theta_init <= self.theta_max) {
            return bad(
                "theta_init",
                self.theta_init,
                "must lie in [theta_min, theta_max]",
            );
        }
        if g == 0.0 {
            return bad("phi / light_scale", g, "the gain underflows to 0");
        }
        Ok(g.ln())
    }
}

/// What one [`PhysicsFusion::push_isi`] did, pixel by pixel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct IsiUpdateStats {
    /// Valid ISIs: pixels re-anchored on a measurement.
    pub measured: usize,
    /// Invalid ISIs at pixels without a measured anchor: provisional anchor on the bound.
    pub bounded: usize,
    /// Invalid ISIs at pixels with a measured anchor: anchor kept, events still counted.
    pub carried: usize,
    /// NaN ISIs: pixel untouched.
    pub ignored: usize,
    /// Pairs of measured ISIs whose Eq. 6 estimate entered theta.
    pub theta_accepted: usize,
    /// Pairs with `E = 0` or equal ISIs: theta undefined, previous kept.
    pub theta_undefined: usize,
    /// Pairs with an ISI of 1 tick (saturated light): not used.
    pub theta_saturated: usize,
    /// Pairs whose estimate fell outside `[theta_min, theta_max]`: not used.
    pub theta_rejected: usize,
}

impl std::ops::AddAssign for IsiUpdateStats {
    /// Field by field: the counts of several updates.
    fn add_assign(&mut self, b: Self) {
        self.measured += b.measured;
        self.bounded += b.bounded;
        self.carried += b.carried;
        self.ignored += b.ignored;
        self.theta_accepted += b.theta_accepted;
        self.theta_undefined += b.theta_undefined;
        self.theta_saturated += b.theta_saturated;
        self.theta_rejected += b.theta_rejected;
    }
}

/// What one [`PhysicsFusion::frame_into`] wrote.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FusionFrameStats {
    /// Pixels read from a measured anchor (valid).
    pub measured: usize,
    /// Pixels read from a provisional anchor (an ISI bound; not valid).
    pub bounded: usize,
    /// Pixels with no anchor at all: 0, not valid.
    pub no_anchor: usize,
    /// Pixels whose Eq. 7 estimate exceeded 1 and was clamped to 1.
    pub clamped: usize,
    /// Of those, the pixels whose exponent exceeded `ln(f64::MAX)`: `exp` would have overflowed.
    pub exp_overflow: usize,
}

impl std::ops::AddAssign for FusionFrameStats {
    /// Field by field: the counts of several frames.
    fn add_assign(&mut self, b: Self) {
        self.measured += b.measured;
        self.bounded += b.bounded;
        self.no_anchor += b.no_anchor;
        self.clamped += b.clamped;
        self.exp_overflow += b.exp_overflow;
    }
}

/// NeuSpike-Net's physics fusion of ISI maps and events (paper Eq. 5-7); see the module.
///
/// ```
/// use ndarray::{array, Array2};
/// use neuspike_reconstruction::{EventSlice, FusionParams, PhysicsFusion};
/// let mut f = PhysicsFusion::new(1, 1, FusionParams::new(1.0, 1.0), 0).unwrap();
/// f.push_isi(0, array![[8.0f32]].view(), array![[true]].view()).unwrap();
/// let on = EventSlice { t_ns: &[5, 6, 7], x: &[0; 3], y: &[0; 3], polarity: &[1; 3] };
/// f.push_events(on).unwrap();
/// let s = f.push_isi(10, array![[2.0f32]].view(), array![[true]].view()).unwrap();
/// assert_eq!(s.theta_accepted, 1);
/// // Eq. 6: ln(8 / 2) / 3.
/// assert!((f.theta_global().unwrap() - 4f64.ln() / 3.0).abs() < 1e-15);
/// f.push_events(EventSlice { t_ns: &[12], x: &[0], y: &[0], polarity: &[-1] }).unwrap();
/// let (mut lum, mut valid) = (Array2::<f32>::zeros((1, 1)), Array2::from_elem((1, 1), false));
/// f.frame_into(20, lum.view_mut(), valid.view_mut()).unwrap();
/// // Eq. 7: (1 / 2) exp(-theta).
/// assert!((f64::from(lum[[0, 0]]) - 0.5 * (-4f64.ln() / 3.0).exp()).abs() < 1e-6);
/// assert!(valid[[0, 0]]);
/// ```
#[derive(Clone, Debug)]
pub struct PhysicsFusion {
    params: FusionParams,
    /// `ln(phi / light_scale)`.
    ln_gain: f64,
    /// `ln ISI` of the anchor, ticks.
    ln_isi: Array2<f64>,
    /// [`NO_ANCHOR`], [`BOUND`] or [`MEASURED`].
    kind: Array2<u8>,
    /// Signed event count since the anchor (exact up to `2^53`).
    count: Array2<f64>,
    /// Per-pixel least-squares sums of accepted pairs: `sum E d`, `sum E^2`.
    num: Array2<f64>,
    den: Array2<f64>,
    /// Theta in use per pixel.
    theta: Array2<f64>,
    /// Pooled estimate, `None` before any accepted pair.
    theta_global: Option<f64>,
    latest_ns: i64,
}

/// One pixel's anchor state, mutable.
struct PixelMut<'a> {
    ln_isi: &'a mut f64,
    kind: &'a mut u8,
    count: &'a mut f64,
    num: &'a mut f64,
    den: &'a mut f64,
}

/// The ISI update of one pixel; the one rule both paths use.
#[inline(always)]
fn update_pixel(
    isi: f32,
    valid: bool,
    px: PixelMut,
    range: (f64, f64),
    stats: &mut IsiUpdateStats,
) {
    if isi.is_nan() {
        stats.ignored += 1;
        return;
    }
    let ln_isi = f64::from(isi).max(1.0).min(f64::from(f32::MAX)).ln();
    if valid {
        if *px.kind == MEASURED {
            let d = *px.ln_isi - ln_isi;
            let e = *px.count;
            if *px.ln_isi <= 0.0 || ln_isi <= 0.0 {
                stats.theta_saturated += 1;
            } else if e == 0.0 || d == 0.0 {
                stats.theta_undefined += 1;
            } else {
                let estimate = d / e;
                if estimate >= range.0 && estimate <= range.1 {
                    *px.num += e * d;
                    *px.den += e * e;
                    stats.theta_accepted += 1;
                } else {
                    stats.theta_rejected += 1;
                }
            }
        }
        *px.ln_isi = ln_isi;
        *px.count = 0.0;
        *px.kind = MEASURED;
        stats.measured += 1;
    } else if *px.kind == MEASURED {
        stats.carried += 1;
    } else {
        *px.ln_isi = ln_isi;
        *px.count = 0.0;
        *px.kind = BOUND;
        stats.bounded += 1;
    }
}

/// Eq. 7 for one pixel: `(luminance, valid)`, with the frame statistics.
#[inline(always)]
fn read_pixel(
    ln_gain: f64,
    kind: u8,
    ln_isi: f64,
    count: f64,
    theta: f64,
    exp: impl Fn(f64) -> f64,
    stats: &mut FusionFrameStats,
) -> (f32, bool) {
    let x = ln_gain - ln_isi + theta * count;
    let anchored = kind != NO_ANCHOR;
    stats.measured += usize::from(kind == MEASURED);
    stats.bounded += usize::from(kind == BOUND);
    stats.no_anchor += usize::from(!anchored);
    stats.clamped += usize::from(anchored & (x > 0.0));
    stats.exp_overflow += usize::from(anchored & (x > LN_F64_MAX));
    let lum = if anchored { exp(x) as f32 } else { 0.0 };
    (lum, kind == MEASURED)
}

impl PhysicsFusion {
    /// A `height x width` fusion with no anchor anywhere, its clock at `t_start_ns`.
    ///
    /// # Errors
    /// [`InferError::Param`] naming the field: `phi` or `light_scale` not finite and `> 0` (or
    /// their ratio overflowing or underflowing), `theta_min` not finite and `> 0`, `theta_max` not
    /// finite and `>= theta_min`, `theta_init` outside `[theta_min, theta_max]`.
    pub fn new(
        height: usize,
        width: usize,
        params: FusionParams,
        t_start_ns: i64,
    ) -> Result<Self, InferError> {
        let ln_gain = params.check()?;
        let zeros = || Array2::<f64>::zeros((height, width));
        Ok(PhysicsFusion {
            params,
            ln_gain,
            ln_isi: zeros(),
            kind: Array2::from_elem((height, width), NO_ANCHOR),
            count: zeros(),
            num: zeros(),
            den: zeros(),
            theta: Array2::from_elem((height, width), params.theta_init),
            theta_global: None,
            latest_ns: t_start_ns,
        })
    }

    /// Counts `events` into every pixel's `E` (ON +1, OFF -1).
    ///
    /// # Errors
    /// Nothing is counted when a check fails: [`InferError::Events`] for events breaking
    /// [`EventSlice`]'s invariants, [`InferError::TimeBackwards`] when the first event is before
    /// the latest instant pushed.
    pub fn push_events(&mut self, events: EventSlice) -> Result<(), InferError> {
        let (h, w) = self.dim();
        let last = check_events(events, h, w, self.latest_ns)?;
        count_events(owned_slice_mut(&mut self.count), w, events);
        self.latest_ns = last.unwrap_or(self.latest_ns);
        Ok(())
    }

    /// Scalar oracle for [`Self::push_events`].
    #[doc(hidden)]
    pub fn push_events_reference(&mut self, events: EventSlice) -> Result<(), InferError> {
        let (h, w) = self.dim();
        let last = check_events(events, h, w, self.latest_ns)?;
        for i in 0..events.len() {
            let at = [usize::from(events.y[i]), usize::from(events.x[i])];
            self.count[at] += f64::from(events.polarity[i]);
        }
        self.latest_ns = last.unwrap_or(self.latest_ns);
        Ok(())
    }

    fn check_isi(
        &self,
        t_ns: i64,
        isi: &ArrayView2<f32>,
        valid: &ArrayView2<bool>,
    ) -> Result<(), InferError> {
        check_time("isi map", t_ns, self.latest_ns)?;
        check_shape("isi map (shape of the sensor)", self.dim(), isi.dim())?;
        check_shape(
            "isi validity (shape of the sensor)",
            self.dim(),
            valid.dim(),
        )
    }

    /// Takes the ISI map `isi` (ticks) with its validity `valid` (both `[H, W]`) as measured at
    /// `t_ns`: Eq. 6 for every pixel with two consecutive measured ISIs, then re-anchoring (see the
    /// module for invalid and NaN ISIs).
    ///
    /// # Errors
    /// Nothing changes when a check fails: [`InferError::TimeBackwards`] when `t_ns` is before the
    /// latest instant pushed, [`InferError::Shape`] when `isi` or `valid` is not `[H, W]`.
    pub fn push_isi(
        &mut self,
        t_ns: i64,
        isi: ArrayView2<f32>,
        valid: ArrayView2<bool>,
    ) -> Result<IsiUpdateStats, InferError> {
        self.check_isi(t_ns, &isi, &valid)?;
        let mut stats = IsiUpdateStats::default();
        let range = (self.params.theta_min, self.params.theta_max);
        let w = self.dim().1;
        let ln_isi = owned_slice_mut(&mut self.ln_isi);
        let kind = owned_slice_mut(&mut self.kind);
        let count = owned_slice_mut(&mut self.count);
        let num = owned_slice_mut(&mut self.num);
        let den = owned_slice_mut(&mut self.den);
        for (y, (isi_row, valid_row)) in isi.rows().into_iter().zip(valid.rows()).enumerate() {
            let row = y * w..(y + 1) * w;
            let state = ln_isi[row.clone()]
                .iter_mut()
                .zip(&mut kind[row.clone()])
                .zip(&mut count[row.clone()])
                .zip(num[row.clone()].iter_mut().zip(&mut den[row]));
            for ((((l, k), c), (n, d)), (&i, &v)) in state.zip(isi_row.iter().zip(valid_row)) {
                let px = PixelMut {
                    ln_isi: l,
                    kind: k,
                    count: c,
                    num: n,
                    den: d,
                };
                update_pixel(i, v, px, range, &mut stats);
            }
        }
        self.refresh_theta();
        self.latest_ns = t_ns;
        Ok(stats)
    }

    /// Scalar oracle for [`Self::push_isi`].
    #[doc(hidden)]
    pub fn push_isi_reference(
        &mut self,
        t_ns: i64,
        isi: ArrayView2<f32>,
        valid: ArrayView2<bool>,
    ) -> Result<IsiUpdateStats, InferError> {
        self.check_isi(t_ns, &isi, &valid)?;
        let mut stats = IsiUpdateStats::default();
        let range = (self.params.theta_min, self.params.theta_max);
        let (h, w) = self.dim();
        for y in 0..h {
            for x in 0..w {
                let px = PixelMut {
                    ln_isi: &mut self.ln_isi[[y, x]],
                    kind: &mut self.kind[[y, x]],
                    count: &mut self.count[[y, x]],
                    num: &mut self.num[[y, x]],
                    den: &mut self.den[[y, x]],
                };
                update_pixel(isi[[y, x]], valid[[y, x]], px, range, &mut stats);
            }
        }
        self.refresh_theta();
        self.latest_ns = t_ns;
        Ok(stats)
    }

    /// Recomputes the pooled estimate and the theta of every pixel from the least-squares sums
    /// (both paths share it, so the sums are taken in one order).
    fn refresh_theta(&mut self) {
        let num: f64 = owned_slice(&self.num).iter().sum();
        let den: f64 = owned_slice(&self.den).iter().sum();
        self.theta_global = (den > 0.0).then(|| num / den);
        let pooled = self.theta_global.unwrap_or(self.params.theta_init);
        match self.params.mode {
            ThetaMode::Fixed => self.theta.fill(self.params.theta_init),
            ThetaMode::Global => self.theta.fill(pooled),
            ThetaMode::PerPixel => Zip::from(&mut self.theta)
                .and(&self.num)
                .and(&self.den)
                .for_each(|t, &n, &d| *t = if d > 0.0 { n / d } else { pooled }),
        }
    }

    fn check_read(
        &self,
        t_ns: i64,
        dst: (usize, usize),
        valid: (usize, usize),
    ) -> Result<(), InferError> {
        check_time("fusion frame read", t_ns, self.latest_ns)?;
        check_shape("fusion dst (shape of the sensor)", self.dim(), dst)?;
        check_shape("fusion valid (shape of the sensor)", self.dim(), valid)
    }

    /// Writes the Eq. 7 luminance at `t_ns` into `dst` and whether it rests on a measured ISI into
    /// `valid` (both `[H, W]`); the state is unchanged. Returns what it wrote (clamps counted).
    ///
    /// # Errors
    /// [`InferError::TimeBackwards`] when `t_ns` is before the latest instant pushed,
    /// [`InferError::Shape`] when `dst` or `valid` is not `[H, W]`.
    pub fn frame_into(
        &self,
        t_ns: i64,
        mut dst: ArrayViewMut2<f32>,
        mut valid: ArrayViewMut2<bool>,
    ) -> Result<FusionFrameStats, InferError> {
        self.check_read(t_ns, dst.dim(), valid.dim())?;
        let mut stats = FusionFrameStats::default();
        let rows = dst.rows_mut().into_iter().zip(valid.rows_mut());
        neuspike_simd::dispatch(
            #[inline(always)]
            || {
                for (y, (d, v)) in rows.enumerate() {
                    self.read_row(y, d, v, &mut stats);
                }
            },
        );
        Ok(stats)
    }

    /// The fast read of row `y`, in chunks of [`ROW_CHUNK`] pixels through stack buffers.
    #[inline(always)]
    fn read_row(
        &self,
        y: usize,
        mut dst: ArrayViewMut1<f32>,
        mut valid: ArrayViewMut1<bool>,
        stats: &mut FusionFrameStats,
    ) {
        let w = self.dim().1;
        let (kind, ln_isi) = (owned_slice(&self.kind), owned_slice(&self.ln_isi));
        let (count, theta) = (owned_slice(&self.count), owned_slice(&self.theta));
        let mut lum = [0.0f32; ROW_CHUNK];
        let mut ok = [false; ROW_CHUNK];
        let parts = dst
            .axis_chunks_iter_mut(Axis(0), ROW_CHUNK)
            .zip(valid.axis_chunks_iter_mut(Axis(0), ROW_CHUNK));
        let mut a = y * w;
        for (mut d, mut v) in parts {
            let n = d.len();
            let r = a..a + n;
            let pixels = kind[r.clone()]
                .iter()
                .zip(&ln_isi[r.clone()])
                .zip(count[r.clone()].iter().zip(&theta[r]));
            let outs = lum[..n].iter_mut().zip(&mut ok[..n]);
            for ((o, b), ((&k, &l), (&c, &t))) in outs.zip(pixels) {
                (*o, *b) = read_pixel(self.ln_gain, k, l, c, t, exp_nonpos, stats);
            }
            d.iter_mut().zip(&lum[..n]).for_each(|(d, &x)| *d = x);
            v.iter_mut().zip(&ok[..n]).for_each(|(v, &x)| *v = x);
            a += n;
        }
    }

    /// Scalar oracle for [`Self::frame_into`].
    #[doc(hidden)]
    pub fn frame_into_reference(
        &self,
        t_ns: i64,
        mut dst: ArrayViewMut2<f32>,
        mut valid: ArrayViewMut2<bool>,
    ) -> Result<FusionFrameStats, InferError> {
        self.check_read(t_ns, dst.dim(), valid.dim())?;
        let mut stats = FusionFrameStats::default();
        let (h, w) = self.dim();
        for y in 0..h {
            for x in 0..w {
                let at = [y, x];
                (dst[at], valid[at]) = read_pixel(
                    self.ln_gain,
                    self.kind[at],
                    self.ln_isi[at],
                    self.count[at],
                    self.theta[at],
                    exp_nonpos_reference,
                    &mut stats,
                );
            }
        }
        Ok(stats)
    }

    /// The theta each pixel uses now (log luminance per event).
    pub fn theta(&self) -> ArrayView2<'_, f64> {
        self.theta.view()
    }

    /// The pooled least-squares estimate over every accepted pair so far, `None` before the first.
    pub fn theta_global(&self) -> Option<f64> {
        self.theta_global
    }

    /// Signed event count per pixel since its anchor, `E(t0, now)`.
    pub fn event_count(&self) -> ArrayView2<'_, f64> {
        self.count.view()
    }

    /// The settings.
    pub fn params(&self) -> &FusionParams {
        &self.params
    }

    /// The latest instant pushed; reads must be at or after it.
    pub fn latest_ns(&self) -> i64 {
        self.latest_ns
    }

    /// `(height, width)`.
    pub fn dim(&self) -> (usize, usize) {
        self.kind.dim()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{EventBuf, close, stream};
    use ndarray::{Array2, Array3, array};
    use proptest::prelude::*;

    fn params(mode: ThetaMode) -> FusionParams {
        FusionParams {
            mode,
            ..FusionParams::new(1.0, 1.0)
        }
    }

    fn one(isi: f32) -> Array2<f32> {
        array![[isi]]
    }

    fn yes() -> Array2<bool> {
        array![[true]]
    }

    /// `n` events of `polarity` at pixel (0, 0) from `t0_ns`, one per ns.
    fn burst(t0_ns: i64, n: usize, polarity: i8) -> EventBuf {
        let mut b = EventBuf::default();
        for i in 0..n {
            b.push(t0_ns + i as i64, 0, 0, polarity);
        }
        b
    }

    fn read(f: &PhysicsFusion, t: i64) -> (Array2<f32>, Array2<bool>, FusionFrameStats) {
        let mut d = Array2::from_elem(f.dim(), f32::NAN);
        let mut v = Array2::from_elem(f.dim(), false);
        let s = f.frame_into(t, d.view_mut(), v.view_mut()).expect("read");
        let mut dr = Array2::from_elem(f.dim(), f32::NAN);
        let mut vr = Array2::from_elem(f.dim(), true);
        let sr = f
            .frame_into_reference(t, dr.view_mut(), vr.view_mut())
            .expect("reference read");
        assert!(
            d.iter().zip(&dr).all(|(a, b)| (a - b).abs() <= 1e-6),
            "{d} vs {dr}"
        );
        assert_eq!((&v, s), (&vr, sr));
        (d, v, s)
    }

    #[test]
    fn eq6_theta_from_two_isis_and_the_events_between() {
        // ISI 20 -> 10 ticks: the light doubled; 4 ON events between: theta = ln 2 / 4.
        let mut f = PhysicsFusion::new(1, 1, params(ThetaMode::PerPixel), 0).expect("new");
        let s = f
            .push_isi(0, one(20.0).view(), yes().view())
            .expect("first");
        assert_eq!((s.measured, s.theta_accepted), (1, 0));
        f.push_events(burst(10, 4, 1).slice()).expect("events");
        assert_eq!(f.event_count()[[0, 0]], 4.0);
        let s = f
            .push_isi(100, one(10.0).view(), yes().view())
            .expect("second");
        assert_eq!(s.theta_accepted, 1);
        let want = 2f64.ln() / 4.0;
        assert!(close(f.theta()[[0, 0]], want, 1e-15));
        assert!(close(f.theta_global().expect("pooled"), want, 1e-15));
        assert_eq!(f.event_count()[[0, 0]], 0.0);
        // A second pair, ISI 10 -> 20 with 2 OFF events (theta ln 2 / 2): the least-squares
        // combination sum(E d) / sum(E^2) = (4 ln 2 + 2 ln 2) / (16 + 4).
        f.push_events(burst(200, 2, -1).slice()).expect("events");
        f.push_isi(300, one(20.0).view(), yes().view())
            .expect("third");
        assert!(close(f.theta()[[0, 0]], 6.0 * 2f64.ln() / 20.0, 1e-15));
    }

    #[test]
    fn eq7_carries_the_anchor_forward_with_events() {
        let mut p = params(ThetaMode::Fixed);
        p.theta_init = 0.25;
        let (phi, scale) = (2.0, 0.5);
        p.phi = phi;
        p.light_scale = scale;
        let mut f = PhysicsFusion::new(1, 2, p, 0).expect("new");
        let isi = array![[40.0f32, 16.0]];
        f.push_isi(0, isi.view(), array![[true, true]].view())
            .expect("isi");
        let mut ev = EventBuf::default();
        for i in 0..3 {
            ev.push(10 + i, 0, 0, 1);
            ev.push(10 + i, 1, 0, -1);
        }
        ev.push(20, 1, 0, -1);
        f.push_events(ev.slice()).expect("events");
        let (d, v, s) = read(&f, 30);
        let i0 = phi / (40.0 * scale);
        let i1 = phi / (16.0 * scale);
        assert!(close(
            f64::from(d[[0, 0]]),
            i0 * (0.25f64 * 3.0).exp(),
            1e-6
        ));
        assert!(close(
            f64::from(d[[0, 1]]),
            i1 * (-0.25f64 * 4.0).exp(),
            1e-6
        ));
        assert_eq!(v, array![[true, true]]);
        assert_eq!(
            s,
            FusionFrameStats {
                measured: 2,
                ..Default::default()
            }
        );
    }

    #[test]
    fn equal_isis_keep_the_previous_theta_and_are_counted() {
        let mut f = PhysicsFusion::new(1, 1, params(ThetaMode::PerPixel), 0).expect("new");
        f.push_isi(0, one(20.0).view(), yes().view()).expect("isi");
        f.push_events(burst(1, 4, 1).slice()).expect("ev");
        f.push_isi(10, one(10.0).view(), yes().view()).expect("isi");
        let theta = f.theta()[[0, 0]];
        f.push_events(burst(11, 3, 1).slice()).expect("ev");
        let s = f
            .push_isi(20, one(10.0).view(), yes().view())
            .expect("equal");
        assert_eq!((s.theta_undefined, s.theta_accepted), (1, 0));
        assert_eq!(f.theta()[[0, 0]], theta);
        // Before any accepted pair, the previous theta is theta_init.
        let mut g = PhysicsFusion::new(1, 1, params(ThetaMode::PerPixel), 0).expect("new");
        g.push_isi(0, one(7.0).view(), yes().view()).expect("isi");
        g.push_events(burst(1, 2, -1).slice()).expect("ev");
        let s = g
            .push_isi(10, one(7.0).view(), yes().view())
            .expect("equal");
        assert_eq!(s.theta_undefined, 1);
        assert_eq!(g.theta()[[0, 0]], 0.2);
        assert_eq!(g.theta_global(), None);
    }

    #[test]
    fn zero_event_integral_keeps_the_previous_theta_and_is_counted() {
        let mut f = PhysicsFusion::new(1, 1, params(ThetaMode::Global), 0).expect("new");
        f.push_isi(0, one(20.0).view(), yes().view()).expect("isi");
        // No events at all, then as many ON as OFF: E = 0 either way.
        let s = f.push_isi(10, one(10.0).view(), yes().view()).expect("isi");
        assert_eq!(s.theta_undefined, 1);
        let mut ev = burst(11, 3, 1);
        for i in 0..3 {
            ev.push(20 + i, 0, 0, -1);
        }
        f.push_events(ev.slice()).expect("ev");
        let s = f.push_isi(30, one(5.0).view(), yes().view()).expect("isi");
        assert_eq!((s.theta_undefined, s.theta_accepted), (1, 0));
        assert_eq!(f.theta()[[0, 0]], 0.2);
        assert_eq!(f.theta_global(), None);
    }

    #[test]
    fn wrong_sign_or_out_of_range_estimates_are_rejected() {
        let mut f = PhysicsFusion::new(1, 1, params(ThetaMode::PerPixel), 0).expect("new");
        f.push_isi(0, one(20.0).view(), yes().view()).expect("isi");
        // Brighter (ISI 20 -> 10) but OFF events: negative estimate.
        f.push_events(burst(1, 3, -1).slice()).expect("ev");
        let s = f.push_isi(10, one(10.0).view(), yes().view()).expect("isi");
        assert_eq!(s.theta_rejected, 1);
        // ISI 10 -> 1000 over one OFF event: 4.6 per event, above theta_max = 2.
        f.push_events(burst(11, 1, -1).slice()).expect("ev");
        let s = f
            .push_isi(20, one(1000.0).view(), yes().view())
            .expect("isi");
        assert_eq!(s.theta_rejected, 1);
        assert_eq!(f.theta()[[0, 0]], 0.2);
        // The rejected pairs still re-anchored the pixel.
        let (d, _, _) = read(&f, 20);
        assert!(close(f64::from(d[[0, 0]]), 1e-3, 1e-6));
    }

    #[test]
    fn exponent_overflow_clamps_to_one_and_is_counted() {
        let mut p = params(ThetaMode::Fixed);
        p.theta_init = 2.0;
        let mut f = PhysicsFusion::new(1, 3, p, 0).expect("new");
        f.push_isi(
            0,
            array![[100.0f32, 100.0, 100.0]].view(),
            array![[true; 3]].view(),
        )
        .expect("isi");
        let mut ev = EventBuf::default();
        // Pixel 0: 400 ON events, x = ln 0.01 + 800: exp overflows f64. Pixel 1: 3 ON, x = 1.4:
        // above 1, clamped. Pixel 2: 400 OFF: underflow to 0, not a clamp.
        for i in 0..400 {
            ev.push(i, 0, 0, 1);
            ev.push(i, 2, 0, -1);
        }
        for i in 0..3 {
            ev.push(400 + i, 1, 0, 1);
        }
        f.push_events(ev.slice()).expect("ev");
        let (d, v, s) = read(&f, 1_000);
        assert_eq!(d, array![[1.0f32, 1.0, 0.0]]);
        assert_eq!(v, array![[true; 3]]);
        assert_eq!((s.clamped, s.exp_overflow, s.measured), (2, 1, 3));
    }

    #[test]
    fn no_events_gives_the_isi_luminance() {
        let isi = array![[1.0f32, 2.0, 3.0], [7.0, 33.0, 1e6]];
        let (phi, scale) = (1.5, 0.75);
        let mut p = params(ThetaMode::PerPixel);
        (p.phi, p.light_scale) = (phi, scale);
        let mut f = PhysicsFusion::new(2, 3, p, 0).expect("new");
        f.push_isi(5, isi.view(), Array2::from_elem((2, 3), true).view())
            .expect("isi");
        f.push_events(EventBuf::default().slice())
            .expect("no events");
        let (d, v, s) = read(&f, 5);
        let mut tfi = Array2::zeros((2, 3));
        crate::luminance_from_isi_into(isi.view(), phi, scale, tfi.view_mut()).expect("tfi");
        assert!(
            d.iter().zip(&tfi).all(|(a, b)| (a - b).abs() <= 1e-6),
            "{d} vs {tfi}"
        );
        assert!(v.iter().all(|&v| v));
        // ISI 1 tick: phi / light_scale = 2, clamped to 1.
        assert_eq!((d[[0, 0]], s.clamped), (1.0, 1));
    }

    /// `n` planes of a `h x w` sensor where pixel `(y, x)` fires on the planes `fire(y, x, k)`.
    fn planes(
        n: usize,
        h: usize,
        w: usize,
        fire: impl Fn(usize, usize, usize) -> bool,
    ) -> Array3<u8> {
        Array3::from_shape_fn((n, h, w), |(k, y, x)| u8::from(fire(y, x, k)))
    }

    #[test]
    fn no_light_gives_a_defined_output_and_no_validity() {
        let mut f = PhysicsFusion::new(2, 2, params(ThetaMode::PerPixel), 0).expect("new");
        // Nothing pushed at all: 0 everywhere, nothing valid.
        let (d, v, s) = read(&f, 0);
        assert!(d.iter().all(|&x| x == 0.0) && v.iter().all(|&x| !x));
        assert_eq!(s.no_anchor, 4);
        // Events without any ISI: still no anchor.
        f.push_events(burst(1, 5, 1).slice()).expect("ev");
        let (d, _, s) = read(&f, 10);
        assert_eq!((d[[0, 0]], s.no_anchor, s.clamped), (0.0, 4, 0));
        // A dark window from the represent node: no spike, ISI unknown (N + 1 = 33), invalid.
        let dark = planes(32, 2, 2, |_, _, _| false);
        let (mut isi, mut valid) = (Array2::zeros((2, 2)), Array2::from_elem((2, 2), true));
        neuspike_representations::isi_into(dark.view(), 16, isi.view_mut(), valid.view_mut())
            .expect("isi");
        let s = f.push_isi(20, isi.view(), valid.view()).expect("push");
        assert_eq!((s.bounded, s.measured), (4, 0));
        let (d, v, s) = read(&f, 20);
        // The bound phi / (33 light_scale), as TFI shows it, flagged not valid.
        assert!(
            d.iter().all(|&x| close(f64::from(x), 1.0 / 33.0, 1e-6)),
            "{d}"
        );
        assert!(v.iter().all(|&x| !x));
        assert_eq!((s.bounded, s.measured, s.no_anchor), (4, 0, 0));
    }

    #[test]
    fn saturating_light_isi_of_one_tick() {
        // A pixel firing on every plane: ISI 1 (valid), luminance phi / light_scale, clamped.
        let bright = planes(32, 1, 2, |_, x, k| x == 0 || k % 4 == 0);
        let (mut isi, mut valid) = (Array2::zeros((1, 2)), Array2::from_elem((1, 2), false));
        neuspike_representations::isi_into(bright.view(), 16, isi.view_mut(), valid.view_mut())
            .expect("isi");
        assert_eq!((isi[[0, 0]], valid[[0, 0]]), (1.0, true));
        let mut p = params(ThetaMode::PerPixel);
        p.light_scale = 0.5; // luminance 2 at ISI 1.
        let mut f = PhysicsFusion::new(1, 2, p, 0).expect("new");
        f.push_isi(0, isi.view(), valid.view()).expect("isi");
        let (d, v, s) = read(&f, 0);
        assert_eq!((d[[0, 0]], v[[0, 0]], s.clamped), (1.0, true, 1));
        assert!(close(f64::from(d[[0, 1]]), 2.0 / 4.0, 1e-6));
        // Pairs with a saturated ISI do not enter theta, on either side.
        let mut ev = burst(1, 3, -1);
        ev.push(4, 1, 0, 1);
        f.push_events(ev.slice()).expect("ev");
        let s = f
            .push_isi(
                10,
                array![[4.0f32, 1.0]].view(),
                array![[true, true]].view(),
            )
            .expect("isi");
        assert_eq!((s.theta_saturated, s.theta_accepted), (2, 0));
        assert_eq!(f.theta_global(), None);
    }

    #[test]
    fn invalid_isi_keeps_a_measured_anchor_and_nan_is_ignored() {
        let mut f = PhysicsFusion::new(1, 2, params(ThetaMode::Fixed), 0).expect("new");
        f.push_isi(
            0,
            array![[10.0f32, 10.0]].view(),
            array![[true, true]].view(),
        )
        .expect("isi");
        let mut ev = burst(1, 2, 1);
        ev.push(3, 1, 0, 1);
        f.push_events(ev.slice()).expect("ev");
        // An invalid bound and a NaN: both pixels keep anchor and count.
        let s = f
            .push_isi(
                10,
                array![[33.0f32, f32::NAN]].view(),
                array![[false, true]].view(),
            )
            .expect("isi");
        assert_eq!((s.carried, s.ignored, s.measured), (1, 1, 0));
        assert_eq!(f.event_count(), array![[2.0, 1.0]]);
        let (d, v, _) = read(&f, 10);
        assert!(close(f64::from(d[[0, 0]]), 0.1 * 0.4f64.exp(), 1e-6));
        assert!(close(f64::from(d[[0, 1]]), 0.1 * 0.2f64.exp(), 1e-6));
        assert_eq!(v, array![[true, true]]);
        // A NaN ISI at a pixel without anchor leaves it without one.
        let mut g = PhysicsFusion::new(1, 1, params(ThetaMode::Fixed), 0).expect("new");
        g.push_isi(0, one(f32::NAN).view(), yes().view())
            .expect("isi");
        assert_eq!(read(&g, 0).2.no_anchor, 1);
        // ISIs below 1 count as 1, +inf as f32::MAX: finite either way.
        g.push_isi(1, array![[0.25f32]].view(), yes().view())
            .expect("isi");
        assert_eq!(read(&g, 1).0[[0, 0]], 1.0);
        g.push_isi(2, array![[f32::INFINITY]].view(), yes().view())
            .expect("isi");
        let dark = read(&g, 2).0[[0, 0]];
        assert!((0.0..1e-38).contains(&dark), "{dark}");
    }

    #[test]
    fn theta_modes_pick_their_pool() {
        // Pixel 0 sees theta ln 2 / 2, pixel 1 ln 2 / 4, pixel 2 no pair.
        let run = |mode| {
            let mut f = PhysicsFusion::new(1, 3, params(mode), 0).expect("new");
            let all = array![[true; 3]];
            f.push_isi(0, array![[20.0f32, 20.0, 20.0]].view(), all.view())
                .expect("isi");
            let mut ev = EventBuf::default();
            for i in 0..4 {
                if i < 2 {
                    ev.push(i, 0, 0, 1);
                }
                ev.push(i, 1, 0, 1);
            }
            f.push_events(ev.slice()).expect("ev");
            f.push_isi(10, array![[10.0f32, 10.0, 20.0]].view(), all.view())
                .expect("isi");
            f
        };
        let ln2 = 2f64.ln();
        let pooled = (2.0 * ln2 + 4.0 * ln2) / (4.0 + 16.0);
        let f = run(ThetaMode::PerPixel);
        assert!(close(f.theta()[[0, 0]], ln2 / 2.0, 1e-15));
        assert!(close(f.theta()[[0, 1]], ln2 / 4.0, 1e-15));
        assert!(close(f.theta()[[0, 2]], pooled, 1e-15));
        let f = run(ThetaMode::Global);
        assert!(f.theta().iter().all(|&t| close(t, pooled, 1e-15)));
        let f = run(ThetaMode::Fixed);
        assert!(f.theta().iter().all(|&t| t == 0.2));
        assert!(close(f.theta_global().expect("estimated"), pooled, 1e-15));
    }

    #[test]
    fn time_shape_and_event_checks_leave_the_state_alone() {
        let mut f = PhysicsFusion::new(2, 2, params(ThetaMode::PerPixel), 100).expect("new");
        let isi = Array2::from_elem((2, 2), 4.0f32);
        let valid = Array2::from_elem((2, 2), true);
        let e = f.push_isi(99, isi.view(), valid.view()).expect_err("time");
        assert_eq!(
            e.to_string(),
            "isi map: t = 99 ns is before 100 ns, the latest instant already pushed"
        );
        let e = f
            .push_isi(100, isi.view(), Array2::from_elem((2, 3), true).view())
            .expect_err("shape");
        assert!(e.to_string().contains("isi validity"), "{e}");
        assert!(f.push_isi_reference(99, isi.view(), valid.view()).is_err());
        f.push_events(EventBuf::from(&[(150, 1, 1, 1)]).slice())
            .expect("ev");
        let bad = EventBuf::from(&[(160, 2, 0, 1)]);
        assert!(matches!(
            f.push_events(bad.slice()),
            Err(InferError::Events(_))
        ));
        assert!(matches!(
            f.push_events_reference(EventBuf::from(&[(140, 0, 0, 1)]).slice()),
            Err(InferError::TimeBackwards { .. })
        ));
        assert_eq!(f.event_count(), array![[0.0, 0.0], [0.0, 1.0]]);
        assert_eq!(f.latest_ns(), 150);
        let (mut d, mut v) = (Array2::zeros((2, 2)), Array2::from_elem((2, 2), false));
        assert!(f.frame_into(149, d.view_mut(), v.view_mut()).is_err());
        let mut v3 = Array2::from_elem((3, 2), false);
        let e = f
            .frame_into(150, d.view_mut(), v3.view_mut())
            .expect_err("shape");
        assert!(e.to_string().contains("fusion valid"), "{e}");
    }

    #[test]
    fn bad_parameters_name_the_value() {
        let base = FusionParams::new(1.0, 1.0);
        for (p, needle) in [
            (FusionParams { phi: 0.0, ..base }, "phi = 0"),
            (
                FusionParams {
                    light_scale: f64::NAN,
                    ..base
                },
                "light_scale = NaN",
            ),
            (
                FusionParams {
                    theta_min: 0.0,
                    ..base
                },
                "theta_min = 0",
            ),
            (
                FusionParams {
                    theta_max: 0.001,
                    ..base
                },
                "theta_max = 0.001",
            ),
            (
                FusionParams {
                    theta_max: f64::INFINITY,
                    ..base
                },
                "theta_max = inf",
            ),
            (
                FusionParams {
                    theta_init: 3.0,
                    ..base
                },
                "theta_init = 3",
            ),
            (
                FusionParams {
                    theta_init: f64::NAN,
                    ..base
                },
                "theta_init = NaN",
            ),
            (
                FusionParams {
                    phi: 1e-300,
                    light_scale: 1e300,
                    ..base
                },
                "phi / light_scale = 0",
            ),
        ] {
            let e = PhysicsFusion::new(1, 1, p, 0).expect_err(needle);
            assert!(e.to_string().contains(needle), "{e}");
        }
    }

    /// One step of a random run: events up to a cut, then maybe an ISI map.
    fn isi_maps() -> impl Strategy<Value = Vec<Vec<(f32, bool)>>> {
        let isi = prop_oneof![
            4 => (1u32..40).prop_map(|v| v as f32),
            1 => Just(f32::NAN),
            1 => Just(0.5f32),
            1 => Just(f32::INFINITY),
        ];
        proptest::collection::vec(proptest::collection::vec((isi, any::<bool>()), 36), 0..5)
    }

    proptest! {
        #[test]
        fn fast_matches_reference(
            (h, w, ev, cuts) in stream(6, 200, 1_000),
            maps in isi_maps(),
            mode in prop_oneof![Just(ThetaMode::Fixed), Just(ThetaMode::Global), Just(ThetaMode::PerPixel)],
            theta_init in 0.05f64..0.5, light_scale in 0.1f64..10.0,
            transposed in any::<bool>(),
        ) {
            let p = FusionParams { theta_init, light_scale, mode, ..FusionParams::new(1.0, 1.0) };
            let mut fast = PhysicsFusion::new(h, w, p, 0).expect("new");
            let mut slow = fast.clone();
            let mut a = 0;
            for (i, &b) in cuts.iter().enumerate() {
                fast.push_events(ev.range(a, b)).expect("fast");
                slow.push_events_reference(ev.range(a, b)).expect("slow");
                prop_assert_eq!(fast.event_count(), slow.event_count());
                if let Some(map) = maps.get(i) {
                    let isi = Array2::from_shape_fn((h, w), |(y, x)| map[y * w + x].0);
                    let valid = Array2::from_shape_fn((h, w), |(y, x)| map[y * w + x].1);
                    let (isi, valid) = if transposed {
                        (isi.t().to_owned().reversed_axes(), valid.t().to_owned().reversed_axes())
                    } else {
                        (isi, valid)
                    };
                    let t = fast.latest_ns();
                    let sf = fast.push_isi(t, isi.view(), valid.view()).expect("fast isi");
                    let sr = slow.push_isi_reference(t, isi.view(), valid.view()).expect("slow isi");
                    prop_assert_eq!(sf, sr);
                    prop_assert_eq!(fast.theta(), slow.theta());
                    prop_assert_eq!(&fast.ln_isi, &slow.ln_isi);
                    prop_assert_eq!(&fast.kind, &slow.kind);
                    prop_assert_eq!(&fast.num, &slow.num);
                }
                let t = fast.latest_ns();
                let (mut d, mut v) = (Array2::from_elem((w, h), f32::NAN).reversed_axes(),
                    Array2::from_elem((h, w), false));
                let (mut dr, mut vr) = (Array2::from_elem((h, w), f32::NAN), Array2::from_elem((h, w), true));
                let sf = fast.frame_into(t, d.view_mut(), v.view_mut()).expect("fast read");
                let sr = slow.frame_into_reference(t, dr.view_mut(), vr.view_mut()).expect("slow read");
                prop_assert_eq!(sf, sr);
                prop_assert_eq!(&v, &vr);
                prop_assert!(d.iter().zip(&dr).all(|(a, b)| (a - b).abs() <= 1e-6));
                prop_assert!(d.iter().all(|x| (0.0..=1.0).contains(x)));
                a = b;
            }
        }
    }
}
