//! The high-pass and complementary filters of Scheerlinck, Barnes and Mahony, "Continuous-time
//! intensity estimation using event cameras" (ACCV 2018), per pixel and in continuous time.
//!
//! Both keep, per pixel, a log intensity `L` as of the pixel's last update `t_last` and relax it
//! exponentially toward a reference level `L_F` between updates:
//!
//! `L(t) = L_F + exp(-alpha (t - t_last)) (L(t_last) - L_F)`,
//!
//! and an event of polarity `p` at `t` first brings the pixel to `t` that way, then adds `+on`
//! (ON) or `-off` (OFF) (its [`Contrast`]). This is the exact solution of
//! `dL/dt = e(t) - alpha (L - L_F)` with `e` a train of Dirac impulses.
//!
//! - [`HighPassFilter`]: events only, `L_F = 0`: the high-pass filter with cutoff `alpha` (rad/s).
//!   Output `REST_LUMINANCE * exp(L)`: a pixel whose events have died away is mid grey.
//! - [`ComplementaryFilter`]: `L_F = ln(max(frame, LUMINANCE_FLOOR))` of the latest frame, here a
//!   spike-camera luminance image (TFP or TFI) playing the part of a DAVIS's APS frame, with gain
//!   `alpha` (rad/s). Output `exp(L)`.
//!
//! Outputs are luminance, `exp(min(x, 0))` of the log value `x`, so in `[0, 1]`: a log value above
//! 0 (exp above 1, up to overflow) is clamped to 1, and no NaN or infinity is ever written.
//!
//! **Time.** Events, frames and reads go forward: every pushed instant must be at or after the
//! latest instant the filter has seen, and [`InferError::TimeBackwards`] names the offender
//! otherwise. Equal instants are allowed (a decay over 0 ns is exactly 1). Differences are taken
//! as `t - t_last` in wrapping `i64` arithmetic read as `u64`, exact over the whole `i64` range
//! (`t >= t_last` always holds), then converted to `f64`.
//!
//! **Paths.** Each operation has a plain scalar `*_reference` (indexed loops, event by event,
//! `f64::exp`) and a fast path; tests bound the difference (`1e-9` relative on `L`, `1e-6` on the
//! output). The fast event push has two forms, chosen by density (`BATCH_PIXELS_PER_EVENT`):
//! - dense (at least one event per 2 pixels): since the decay is linear, each event's contribution
//!   at the push's last instant `t_ref`, `step * exp(-alpha (t_ref - t_i))`, is computed in one
//!   vector pass over the events, summed per pixel (one scatter add per event), and one vector pass
//!   over the pixels brings every pixel to `t_ref` and adds its sum. A contribution below `1e-308`
//!   at `t_ref` is dropped.
//! - sparse: event by event in blocks of [`EVENT_BLOCK`]: a gather pass (decay exponent, `t_last`),
//!   one vector pass of exponentials, a scatter pass of the updates in event order.
//!
//! The two forms store different (equivalent) states: after a dense push every pixel refers to
//! `t_ref`, after the reference each pixel to its last event; `L(t)` for `t` at or after the
//! latest instant is the same, and that is all the public API exposes ([`HighPassFilter::log_into`],
//! `frame_into`). Exponentials run on the widest vector unit (see `neuspike_simd::fastmath`). Frame reads go row
//! by row through stack buffers (any `dst` layout) and, like frame pushes, use rayon from
//! [`MIN_PIXELS_FOR_RAYON`] pixels; event passes stay on one thread.

use ndarray::{Array2, ArrayView2, ArrayViewMut1, ArrayViewMut2, Axis, Zip};
use neuspike_representations::EventSlice;
use rayon::prelude::*;

use crate::{InferError, MIN_PIXELS_FOR_RAYON, check_shape};
use neuspike_simd::fastmath::{exp_nonpos, exp_nonpos_reference};

/// Luminance shown by a pixel with no information: the [`HighPassFilter`]'s output for `L = 0`,
/// and the [`ComplementaryFilter`]'s level before its first frame.
pub const REST_LUMINANCE: f64 = 0.5;

/// Floor applied to frame luminance before its log in the [`ComplementaryFilter`] (as the event
/// simulator's default `log_floor`), so `ln(0)` never happens: a black frame pixel pulls toward
/// `ln(1e-4) = -9.21`.
pub const LUMINANCE_FLOOR: f64 = 1e-4;

/// Largest accepted contrast (log intensity per event). Real sensors have 0.1 to 0.5; the cap keeps
/// the sum of any number of events far from overflowing `f64`.
pub const MAX_CONTRAST: f64 = 1e6;

/// Events per block of the fast event path (its scratch lives on the stack, 16 KiB).
pub const EVENT_BLOCK: usize = 1024;

/// Log-intensity step of one event: `+on` for ON, `-off` for OFF.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Contrast {
    /// Step of an ON event, `> 0`.
    pub on: f64,
    /// Size of the step of an OFF event (the step is `-off`), `> 0`.
    pub off: f64,
}

impl Contrast {
    /// The same contrast `c` for ON and OFF.
    pub fn symmetric(c: f64) -> Self {
        Contrast { on: c, off: c }
    }

    /// Both steps finite, `> 0` and at most [`MAX_CONTRAST`].
    pub(crate) fn check(self) -> Result<(), InferError> {
        for (name, value) in [("contrast.on", self.on), ("contrast.off", self.off)] {
            if !(value.is_finite() && value > 0.0 && value <= MAX_CONTRAST) {
                return Err(InferError::Param {
                    name,
                    value,
                    reason: "must be finite, > 0 and <= MAX_CONTRAST (1e6)",
                });
            }
        }
        Ok(())
    }

    /// `[step of OFF, step of ON]`, indexed by [`on_index`].
    #[inline(always)]
    fn steps(self) -> [f64; 2] {
        [-self.off, self.on]
    }
}

/// 1 for ON (`p > 0`), 0 for OFF.
#[inline(always)]
fn on_index(polarity: i8) -> usize {
    usize::from(polarity > 0)
}

/// `to - from` in nanoseconds for `to >= from`: exact over the whole `i64` range.
#[inline(always)]
pub(crate) fn elapsed_ns(from: i64, to: i64) -> u64 {
    to.wrapping_sub(from) as u64
}

/// `-alpha dt`, with `alpha` per nanosecond: the exponent of the decay factor, `<= 0`.
#[inline(always)]
fn decay_exponent(alpha_per_ns: f64, dt_ns: u64) -> f64 {
    -(alpha_per_ns * dt_ns as f64)
}

/// [`InferError::TimeBackwards`] unless `t_ns >= latest_ns`.
pub(crate) fn check_time(what: &'static str, t_ns: i64, latest_ns: i64) -> Result<(), InferError> {
    if t_ns < latest_ns {
        return Err(InferError::TimeBackwards {
            what,
            t_ns,
            latest_ns,
        });
    }
    Ok(())
}

/// Validates events for a `height x width` sensor and checks that they start at or after
/// `latest_ns`; returns the time of the last event, if any.
pub(crate) fn check_events(
    events: EventSlice,
    height: usize,
    width: usize,
    latest_ns: i64,
) -> Result<Option<i64>, InferError> {
    events.validate(height, width)?;
    if let Some(&first) = events.t_ns.first() {
        check_time("first event", first, latest_ns)?;
    }
    Ok(events.t_ns.last().copied())
}

/// Adds each event's polarity (+1 ON, -1 OFF) into `count` (`[H, W]` row-major, `width`
/// columns) at its pixel: the signed count `E` of Eq. 5. The events are checked already.
pub(crate) fn count_events(count: &mut [f64], width: usize, events: EventSlice) {
    let xy = events.x.iter().zip(events.y);
    for ((&x, &y), &p) in xy.zip(events.polarity) {
        count[usize::from(y) * width + usize::from(x)] += f64::from(p);
    }
}

/// A rate in rad/s: finite and `>= 0`.
fn check_rate(name: &'static str, value: f64) -> Result<(), InferError> {
    if !(value.is_finite() && value >= 0.0) {
        return Err(InferError::Param {
            name,
            value,
            reason: "must be finite and >= 0 (rad/s)",
        });
    }
    Ok(())
}

/// `ln(max(v, LUMINANCE_FLOOR))` with `+inf` read as `f32::MAX` and NaN as the floor: finite.
#[inline(always)]
fn log_luminance(v: f32) -> f64 {
    f64::from(v)
        .max(LUMINANCE_FLOOR)
        .min(f64::from(f32::MAX))
        .ln()
}

/// The elements of an array this crate allocated (always in standard layout).
pub(crate) fn owned_slice<T>(a: &Array2<T>) -> &[T] {
    a.as_slice()
        .expect("arrays allocated here are in standard layout")
}

/// The elements of an array this crate allocated, mutable.
pub(crate) fn owned_slice_mut<T>(a: &mut Array2<T>) -> &mut [T] {
    a.as_slice_mut()
        .expect("arrays allocated here are in standard layout")
}

/// The per-pixel state both filters share: `L` as of each pixel's last update.
#[derive(Clone, Debug)]
struct LogState {
    /// `L(t_last)` per pixel.
    log: Array2<f64>,
    /// `t_last` per pixel.
    t_last_ns: Array2<i64>,
    /// The latest instant pushed (or the start).
    latest_ns: i64,
    /// `alpha` in rad per nanosecond.
    alpha_per_ns: f64,
    /// Per-pixel sums of the dense push (zero between pushes).
    batch_sum: Array2<f64>,
}

/// The fast event push sums events per pixel ([`LogState::push_batch`], one pass over every pixel
/// per push) when a push has at least one event per this many pixels, and goes event by event
/// otherwise (measured at 346x260 on one core: 11 k events take 0.07 ms event by event and 0.18 ms
/// summed, 45 k events 0.31 and 0.28 ms).
const BATCH_PIXELS_PER_EVENT: usize = 2;

impl LogState {
    fn new(height: usize, width: usize, alpha_rad_s: f64, t_start_ns: i64, log0: f64) -> Self {
        LogState {
            log: Array2::from_elem((height, width), log0),
            t_last_ns: Array2::from_elem((height, width), t_start_ns),
            latest_ns: t_start_ns,
            alpha_per_ns: alpha_rad_s * 1e-9,
            batch_sum: Array2::zeros((height, width)),
        }
    }

    fn dim(&self) -> (usize, usize) {
        self.log.dim()
    }

    /// All checks of an event push; returns the new latest instant.
    fn check_push(&self, events: EventSlice, contrast: Contrast) -> Result<i64, InferError> {
        contrast.check()?;
        let (h, w) = self.dim();
        let last = check_events(events, h, w, self.latest_ns)?;
        Ok(last.unwrap_or(self.latest_ns))
    }

    /// All checks of a frame read.
    fn check_read(&self, t_ns: i64, dst: (usize, usize)) -> Result<(), InferError> {
        check_time("frame read", t_ns, self.latest_ns)?;
        check_shape("filter dst (shape of the sensor)", self.dim(), dst)
    }

    /// Scalar oracle: event by event, `f64::exp`.
    fn push_reference(&mut self, target: Option<&Array2<f64>>, events: EventSlice, c: Contrast) {
        for i in 0..events.len() {
            let at = [usize::from(events.y[i]), usize::from(events.x[i])];
            let t = events.t_ns[i];
            let tg = target.map_or(0.0, |a| a[at]);
            let f = exp_nonpos_reference(decay_exponent(
                self.alpha_per_ns,
                elapsed_ns(self.t_last_ns[at], t),
            ));
            self.log[at] = tg + f * (self.log[at] - tg) + c.steps()[on_index(events.polarity[i])];
            self.t_last_ns[at] = t;
        }
    }

    /// Fast path: [`Self::push_batch`] for dense pushes (at least one event per
    /// [`BATCH_PIXELS_PER_EVENT`] pixels), [`Self::push_blocks`] for sparse ones.
    fn push_fast(&mut self, target: Option<&Array2<f64>>, events: EventSlice, c: Contrast) {
        let batch = events.len().saturating_mul(BATCH_PIXELS_PER_EVENT) >= self.log.len();
        self.push_fast_with(target, events, c, batch);
    }

    fn push_fast_with(
        &mut self,
        target: Option<&Array2<f64>>,
        events: EventSlice,
        c: Contrast,
        batch: bool,
    ) {
        let Some(&t_ref) = events.t_ns.last() else {
            return;
        };
        match (target.map(owned_slice), batch) {
            (None, false) => self.push_blocks(
                events,
                c,
                #[inline(always)]
                |_| 0.0,
            ),
            (Some(tg), false) => self.push_blocks(
                events,
                c,
                #[inline(always)]
                |p| tg[p],
            ),
            (None, true) => self.push_batch(
                events,
                c,
                t_ref,
                #[inline(always)]
                |_| 0.0,
            ),
            (Some(tg), true) => self.push_batch(
                events,
                c,
                t_ref,
                #[inline(always)]
                |p| tg[p],
            ),
        }
    }

    /// Dense pushes: every event's contribution at the batch's last instant `t_ref`,
    /// `step * exp(-alpha (t_ref - t_i))` (vector pass over the events), summed per pixel (one
    /// scatter add per event), then every pixel brought to `t_ref` and given its sum (vector pass
    /// over the pixels). Exact in exact arithmetic (the decay is linear), rounded differently from
    /// the event-by-event reference; a contribution below `1e-308` at `t_ref` is dropped.
    #[inline(always)]
    fn push_batch(
        &mut self,
        events: EventSlice,
        c: Contrast,
        t_ref: i64,
        target: impl Fn(usize) -> f64,
    ) {
        let w = self.log.ncols();
        let alpha = self.alpha_per_ns;
        let (on, off) = (c.on, -c.off);
        let sum = owned_slice_mut(&mut self.batch_sum);
        let mut weight = [0.0f64; EVENT_BLOCK];
        let n = events.len();
        let mut start = 0;
        while start < n {
            let end = (start + EVENT_BLOCK).min(n);
            let wt = &mut weight[..end - start];
            let (ts, pol) = (&events.t_ns[start..end], &events.polarity[start..end]);
            let out = &mut *wt;
            // `move`: scalars captured by value, so the loop reads no memory that `wt` might alias
            // and vectorises.
            neuspike_simd::dispatch(
                #[inline(always)]
                move || {
                    for ((v, &t), &p) in out.iter_mut().zip(ts).zip(pol) {
                        let f = exp_nonpos(decay_exponent(alpha, elapsed_ns(t, t_ref)));
                        *v = f * if p > 0 { on } else { off };
                    }
                },
            );
            let xy = events.x[start..end].iter().zip(&events.y[start..end]);
            for (&v, (&x, &y)) in wt.iter().zip(xy) {
                sum[usize::from(y) * w + usize::from(x)] += v;
            }
            start = end;
        }
        let log = owned_slice_mut(&mut self.log);
        let t_last = owned_slice_mut(&mut self.t_last_ns);
        neuspike_simd::dispatch(
            #[inline(always)]
            move || {
                let pixels = log.iter_mut().zip(t_last.iter_mut()).zip(sum.iter_mut());
                for (p, ((l, tl), s)) in pixels.enumerate() {
                    let tg = target(p);
                    let f = exp_nonpos(decay_exponent(alpha, elapsed_ns(*tl, t_ref)));
                    *l = tg + f * (*l - tg) + *s;
                    *tl = t_ref;
                    *s = 0.0;
                }
            },
        );
    }

    /// Sparse pushes: event by event in blocks of [`EVENT_BLOCK`]: a gather pass (decay exponent,
    /// `t_last`), one vector pass of exponentials, a scatter pass of updates in event order.
    #[inline(always)]
    fn push_blocks(&mut self, events: EventSlice, c: Contrast, target: impl Fn(usize) -> f64) {
        let w = self.log.ncols();
        let alpha = self.alpha_per_ns;
        let steps = c.steps();
        let log = owned_slice_mut(&mut self.log);
        let t_last = owned_slice_mut(&mut self.t_last_ns);
        let mut idx = [0usize; EVENT_BLOCK];
        let mut factor = [0.0f64; EVENT_BLOCK];
        let n = events.len();
        let mut start = 0;
        while start < n {
            let end = (start + EVENT_BLOCK).min(n);
            let m = end - start;
            let xy = events.x[start..end].iter().zip(&events.y[start..end]);
            let slots = factor[..m].iter_mut().zip(&mut idx[..m]);
            for (((f, ix), &t), (&x, &y)) in slots.zip(&events.t_ns[start..end]).zip(xy) {
                let p = usize::from(y) * w + usize::from(x);
                *f = decay_exponent(alpha, elapsed_ns(t_last[p], t));
                t_last[p] = t;
                *ix = p;
            }
            let exps = &mut factor[..m];
            neuspike_simd::dispatch(
                #[inline(always)]
                || {
                    for f in exps.iter_mut() {
                        *f = exp_nonpos(*f);
                    }
                },
            );
            let updates = idx[..m].iter().zip(&factor[..m]);
            for ((&p, &f), &pol) in updates.zip(&events.polarity[start..end]) {
                let tg = target(p);
                log[p] = tg + f * (log[p] - tg) + steps[on_index(pol)];
            }
            start = end;
        }
    }

    /// `L(t)` per pixel with `f64::exp`: the state's meaning, whatever instant each pixel's
    /// stored value refers to.
    fn log_into(
        &self,
        target: Option<&Array2<f64>>,
        t_ns: i64,
        mut dst: ArrayViewMut2<f64>,
    ) -> Result<(), InferError> {
        check_time("log read", t_ns, self.latest_ns)?;
        check_shape("log dst (shape of the sensor)", self.dim(), dst.dim())?;
        for (at, d) in dst.indexed_iter_mut() {
            let l = self.log[at];
            let tg = target.map_or(0.0, |a| a[at]);
            let dt = elapsed_ns(self.t_last_ns[at], t_ns);
            *d = tg + exp_nonpos_reference(decay_exponent(self.alpha_per_ns, dt)) * (l - tg);
        }
        Ok(())
    }

    /// Scalar oracle of a frame read: `exp(min(L(t) + offset, 0))` per pixel.
    fn frame_reference(
        &self,
        target: Option<&Array2<f64>>,
        t_ns: i64,
        offset: f64,
        mut dst: ArrayViewMut2<f32>,
    ) {
        let (h, w) = self.dim();
        for y in 0..h {
            for x in 0..w {
                let tg = target.map_or(0.0, |a| a[[y, x]]);
                let dt = elapsed_ns(self.t_last_ns[[y, x]], t_ns);
                let f = exp_nonpos_reference(decay_exponent(self.alpha_per_ns, dt));
                let l = tg + f * (self.log[[y, x]] - tg);
                dst[[y, x]] = exp_nonpos_reference(l + offset) as f32;
            }
        }
    }

    /// Fast frame read: row by row over the state's flat slices, in chunks of [`ROW_CHUNK`]
    /// pixels computed into a stack buffer (so `dst` may have any layout), the exponentials on the
    /// vector unit; rows on rayon when `parallel`.
    fn frame_fast(
        &self,
        target: Option<&Array2<f64>>,
        t_ns: i64,
        offset: f64,
        mut dst: ArrayViewMut2<f32>,
        parallel: bool,
    ) {
        let w = self.log.ncols();
        let (log, t_last) = (owned_slice(&self.log), owned_slice(&self.t_last_ns));
        let target = target.map(owned_slice);
        let rows = Rows {
            w,
            log,
            t_last,
            target,
            alpha_per_ns: self.alpha_per_ns,
            t_ns,
            offset,
        };
        if parallel {
            dst.axis_iter_mut(Axis(0))
                .into_par_iter()
                .enumerate()
                .for_each(|(y, row)| {
                    neuspike_simd::dispatch(
                        #[inline(always)]
                        || rows.read(y, row),
                    )
                });
        } else {
            neuspike_simd::dispatch(
                #[inline(always)]
                || {
                    for (y, row) in dst.rows_mut().into_iter().enumerate() {
                        rows.read(y, row);
                    }
                },
            );
        }
    }
}

/// What a fast frame read needs, row by row.
#[derive(Clone, Copy)]
struct Rows<'a> {
    w: usize,
    log: &'a [f64],
    t_last: &'a [i64],
    target: Option<&'a [f64]>,
    alpha_per_ns: f64,
    t_ns: i64,
    offset: f64,
}

impl Rows<'_> {
    /// Writes row `y` in chunks of [`ROW_CHUNK`] pixels through a stack buffer.
    #[inline(always)]
    fn read(&self, y: usize, mut row: ArrayViewMut1<f32>) {
        let mut buf = [0.0f32; ROW_CHUNK];
        let mut a = y * self.w;
        for mut part in row.axis_chunks_iter_mut(Axis(0), ROW_CHUNK) {
            let r = a..a + part.len();
            let out = &mut buf[..part.len()];
            let (l, tl) = (&self.log[r.clone()], &self.t_last[r.clone()]);
            let (alpha, t, off) = (self.alpha_per_ns, self.t_ns, self.offset);
            match self.target {
                None => read_chunk(out, l, tl, |_| 0.0, alpha, t, off),
                Some(tg) => {
                    let tg = &tg[r];
                    read_chunk(out, l, tl, |i| tg[i], alpha, t, off)
                }
            }
            part.iter_mut().zip(out.iter()).for_each(|(d, &v)| *d = v);
            a += part.len();
        }
    }
}

/// Pixels per chunk of the fast frame reads (stack buffers).
const ROW_CHUNK: usize = 512;

/// `out[i] = exp(min(L(t) + offset, 0))` for one chunk: branch-free, vectorised.
#[inline(always)]
fn read_chunk(
    out: &mut [f32],
    log: &[f64],
    t_last: &[i64],
    target: impl Fn(usize) -> f64,
    alpha_per_ns: f64,
    t_ns: i64,
    offset: f64,
) {
    let n = out.len();
    let (log, t_last) = (&log[..n], &t_last[..n]);
    for i in 0..n {
        let tg = target(i);
        let f = exp_nonpos(decay_exponent(alpha_per_ns, elapsed_ns(t_last[i], t_ns)));
        out[i] = exp_nonpos(tg + f * (log[i] - tg) + offset) as f32;
    }
}

// ---------------------------------------------------------------------------------------------
// High-pass filter
// ---------------------------------------------------------------------------------------------

/// Scheerlinck et al.'s high-pass filter: log intensity from events alone.
///
/// Per pixel, `L` starts at 0; an event at `t` sets `L = exp(-alpha (t - t_last)) L + step` and
/// `t_last = t`; a read at `t` gives `L(t) = exp(-alpha (t - t_last)) L`. The output is
/// `min(REST_LUMINANCE * exp(L(t)), 1)`, computed as `exp(min(L(t) + ln REST_LUMINANCE, 0))`:
/// mid grey where the events have decayed away, 1 where `L > ln 2` (exp overflow included), toward 0
/// for strongly negative `L`. The output is relative (events carry no absolute level): compare it
/// with PSNR after gain.
///
/// `alpha = 0` disables the decay: `L` is then the plain sum of steps, the direct integration of
/// events. `L` is accumulated in `f64`.
///
/// ```
/// use neuspike_reconstruction::{Contrast, EventSlice, HighPassFilter};
/// let mut hf = HighPassFilter::new(1, 2, 0.0, 0).unwrap();
/// let events = EventSlice { t_ns: &[10, 20], x: &[0, 0], y: &[0, 0], polarity: &[1, 1] };
/// hf.push_events(events, Contrast::symmetric(0.2)).unwrap();
/// let mut out = ndarray::Array2::<f32>::zeros((1, 2));
/// hf.frame_into(30, out.view_mut()).unwrap();
/// assert!((out[[0, 0]] - 0.5 * 0.4f32.exp()).abs() < 1e-6);
/// assert_eq!(out[[0, 1]], 0.5);
/// ```
#[derive(Clone, Debug)]
pub struct HighPassFilter {
    state: LogState,
}

impl HighPassFilter {
    /// A `height x width` filter with cutoff `cutoff_rad_s` (rad/s, finite, `>= 0`), every pixel at
    /// `L = 0` as of `t_start_ns`.
    ///
    /// # Errors
    /// [`InferError::Param`] when `cutoff_rad_s` is negative, NaN or infinite.
    pub fn new(
        height: usize,
        width: usize,
        cutoff_rad_s: f64,
        t_start_ns: i64,
    ) -> Result<Self, InferError> {
        check_rate("cutoff_rad_s", cutoff_rad_s)?;
        Ok(HighPassFilter {
            state: LogState::new(height, width, cutoff_rad_s, t_start_ns, 0.0),
        })
    }

    /// Applies `events` in order (each pixel decays to the event's time, then steps by `contrast`).
    ///
    /// # Errors
    /// Nothing is applied when any check fails:
    /// - [`InferError::Param`] for a contrast that is not finite, `> 0` and `<= MAX_CONTRAST`;
    /// - [`InferError::Events`] for events breaking [`EventSlice`]'s invariants (unsorted, polarity
    ///   not ±1, outside the sensor, slices of unequal length);
    /// - [`InferError::TimeBackwards`] when the first event is before the latest instant pushed.
    pub fn push_events(
        &mut self,
        events: EventSlice,
        contrast: Contrast,
    ) -> Result<(), InferError> {
        let latest = self.state.check_push(events, contrast)?;
        self.state.push_fast(None, events, contrast);
        self.state.latest_ns = latest;
        Ok(())
    }

    /// Scalar oracle for [`Self::push_events`].
    #[doc(hidden)]
    pub fn push_events_reference(
        &mut self,
        events: EventSlice,
        contrast: Contrast,
    ) -> Result<(), InferError> {
        let latest = self.state.check_push(events, contrast)?;
        self.state.push_reference(None, events, contrast);
        self.state.latest_ns = latest;
        Ok(())
    }

    /// Writes the luminance at `t_ns` into `dst` (`[H, W]`, in `[0, 1]`); the state is unchanged.
    ///
    /// # Errors
    /// - [`InferError::TimeBackwards`] when `t_ns` is before the latest event pushed;
    /// - [`InferError::Shape`] when `dst` is not `[H, W]`.
    pub fn frame_into(&self, t_ns: i64, dst: ArrayViewMut2<f32>) -> Result<(), InferError> {
        self.state.check_read(t_ns, dst.dim())?;
        let parallel = dst.len() >= MIN_PIXELS_FOR_RAYON;
        self.state
            .frame_fast(None, t_ns, REST_LUMINANCE.ln(), dst, parallel);
        Ok(())
    }

    /// Scalar oracle for [`Self::frame_into`].
    #[doc(hidden)]
    pub fn frame_into_reference(
        &self,
        t_ns: i64,
        dst: ArrayViewMut2<f32>,
    ) -> Result<(), InferError> {
        self.state.check_read(t_ns, dst.dim())?;
        self.state
            .frame_reference(None, t_ns, REST_LUMINANCE.ln(), dst);
        Ok(())
    }

    /// Writes `L(t_ns)` per pixel into `dst` (`[H, W]`): the log intensity behind
    /// [`Self::frame_into`], before the output mapping, computed with `f64::exp`.
    ///
    /// # Errors
    /// As [`Self::frame_into`].
    pub fn log_into(&self, t_ns: i64, dst: ArrayViewMut2<f64>) -> Result<(), InferError> {
        self.state.log_into(None, t_ns, dst)
    }

    /// The latest instant pushed; reads must be at or after it.
    pub fn latest_ns(&self) -> i64 {
        self.state.latest_ns
    }

    /// `(height, width)`.
    pub fn dim(&self) -> (usize, usize) {
        self.state.dim()
    }
}

// ---------------------------------------------------------------------------------------------
// Complementary filter
// ---------------------------------------------------------------------------------------------

/// Scheerlinck et al.'s complementary filter: events for the high frequencies, frames for the
/// absolute level, here frames from the spike camera (TFP or TFI luminance) the way a DAVIS uses
/// its APS frames.
///
/// Per pixel, `dL/dt = e(t) - alpha (L - L_F)` with `L_F = ln(max(frame, LUMINANCE_FLOOR))` of the
/// latest frame, solved exactly between updates (see the module). A frame pushed at `t_f` first
/// relaxes every pixel to `t_f` toward the previous `L_F`, then makes itself the new `L_F`. The
/// first frame instead sets `L = L_F` (events before it carry no absolute level). Before any frame,
/// `L_F = ln REST_LUMINANCE`, so the filter is then exactly the [`HighPassFilter`] with cutoff
/// `alpha`. Output `min(exp(L(t)), 1)`.
///
/// Frame luminance: NaN and values below `LUMINANCE_FLOOR` (0 and negatives included) count as the
/// floor, `+inf` as `f32::MAX`; the log is always finite. `alpha = 0` ignores every frame after the
/// first: pure event integration from it.
#[derive(Clone, Debug)]
pub struct ComplementaryFilter {
    state: LogState,
    /// `L_F` per pixel.
    target: Array2<f64>,
    frames: u64,
}

impl ComplementaryFilter {
    /// A `height x width` filter with gain `gain_rad_s` (rad/s, finite, `>= 0`), every pixel at
    /// `L = L_F = ln REST_LUMINANCE` as of `t_start_ns`.
    ///
    /// # Errors
    /// [`InferError::Param`] when `gain_rad_s` is negative, NaN or infinite.
    pub fn new(
        height: usize,
        width: usize,
        gain_rad_s: f64,
        t_start_ns: i64,
    ) -> Result<Self, InferError> {
        check_rate("gain_rad_s", gain_rad_s)?;
        let rest = REST_LUMINANCE.ln();
        Ok(ComplementaryFilter {
            state: LogState::new(height, width, gain_rad_s, t_start_ns, rest),
            target: Array2::from_elem((height, width), rest),
            frames: 0,
        })
    }

    fn check_frame(&self, t_ns: i64, luminance: &ArrayView2<f32>) -> Result<(), InferError> {
        check_time("frame", t_ns, self.state.latest_ns)?;
        check_shape(
            "complementary filter frame (shape of the sensor)",
            self.state.dim(),
            luminance.dim(),
        )
    }

    /// Takes `luminance` (`[H, W]`) as the frame at `t_ns`.
    ///
    /// # Errors
    /// Nothing changes when a check fails:
    /// - [`InferError::TimeBackwards`] when `t_ns` is before the latest instant pushed;
    /// - [`InferError::Shape`] when `luminance` is not `[H, W]`.
    pub fn push_frame(&mut self, t_ns: i64, luminance: ArrayView2<f32>) -> Result<(), InferError> {
        self.check_frame(t_ns, &luminance)?;
        let parallel = luminance.len() >= MIN_PIXELS_FOR_RAYON;
        self.push_frame_fast(t_ns, luminance, parallel);
        Ok(())
    }

    /// The fast frame push, checks done, on rayon when `parallel`.
    fn push_frame_fast(&mut self, t_ns: i64, luminance: ArrayView2<f32>, parallel: bool) {
        let first = self.frames == 0;
        let alpha = self.state.alpha_per_ns;
        let px = |l: &mut f64, tl: &mut i64, tg: &mut f64, &v: &f32| {
            let new_tg = log_luminance(v);
            *l = if first {
                new_tg
            } else {
                let f = exp_nonpos(decay_exponent(alpha, elapsed_ns(*tl, t_ns)));
                *tg + f * (*l - *tg)
            };
            *tg = new_tg;
            *tl = t_ns;
        };
        let zip = Zip::from(&mut self.state.log)
            .and(&mut self.state.t_last_ns)
            .and(&mut self.target)
            .and(luminance);
        if parallel {
            zip.par_for_each(px);
        } else {
            neuspike_simd::dispatch(
                #[inline(always)]
                || zip.for_each(px),
            );
        }
        self.state.latest_ns = t_ns;
        self.frames += 1;
    }

    /// Scalar oracle for [`Self::push_frame`].
    #[doc(hidden)]
    pub fn push_frame_reference(
        &mut self,
        t_ns: i64,
        luminance: ArrayView2<f32>,
    ) -> Result<(), InferError> {
        self.check_frame(t_ns, &luminance)?;
        let (h, w) = self.state.dim();
        for y in 0..h {
            for x in 0..w {
                let new_tg = log_luminance(luminance[[y, x]]);
                self.state.log[[y, x]] = if self.frames == 0 {
                    new_tg
                } else {
                    let dt = elapsed_ns(self.state.t_last_ns[[y, x]], t_ns);
                    let f = exp_nonpos_reference(decay_exponent(self.state.alpha_per_ns, dt));
                    self.target[[y, x]] + f * (self.state.log[[y, x]] - self.target[[y, x]])
                };
                self.target[[y, x]] = new_tg;
                self.state.t_last_ns[[y, x]] = t_ns;
            }
        }
        self.state.latest_ns = t_ns;
        self.frames += 1;
        Ok(())
    }

    /// Applies `events` in order. Errors as [`HighPassFilter::push_events`].
    pub fn push_events(
        &mut self,
        events: EventSlice,
        contrast: Contrast,
    ) -> Result<(), InferError> {
        let latest = self.state.check_push(events, contrast)?;
        self.state.push_fast(Some(&self.target), events, contrast);
        self.state.latest_ns = latest;
        Ok(())
    }

    /// Scalar oracle for [`Self::push_events`].
    #[doc(hidden)]
    pub fn push_events_reference(
        &mut self,
        events: EventSlice,
        contrast: Contrast,
    ) -> Result<(), InferError> {
        let latest = self.state.check_push(events, contrast)?;
        self.state
            .push_reference(Some(&self.target), events, contrast);
        self.state.latest_ns = latest;
        Ok(())
    }

    /// Writes the luminance at `t_ns`, `min(exp(L(t)), 1)`, into `dst` (`[H, W]`); the state is
    /// unchanged. Errors as [`HighPassFilter::frame_into`].
    pub fn frame_into(&self, t_ns: i64, dst: ArrayViewMut2<f32>) -> Result<(), InferError> {
        self.state.check_read(t_ns, dst.dim())?;
        let parallel = dst.len() >= MIN_PIXELS_FOR_RAYON;
        self.state
            .frame_fast(Some(&self.target), t_ns, 0.0, dst, parallel);
        Ok(())
    }

    /// Scalar oracle for [`Self::frame_into`].
    #[doc(hidden)]
    pub fn frame_into_reference(
        &self,
        t_ns: i64,
        dst: ArrayViewMut2<f32>,
    ) -> Result<(), InferError> {
        self.state.check_read(t_ns, dst.dim())?;
        self.state
            .frame_reference(Some(&self.target), t_ns, 0.0, dst);
        Ok(())
    }

    /// Writes `L(t_ns)` per pixel into `dst` (`[H, W]`): the log intensity behind
    /// [`Self::frame_into`], computed with `f64::exp`. Errors as [`Self::frame_into`].
    pub fn log_into(&self, t_ns: i64, dst: ArrayViewMut2<f64>) -> Result<(), InferError> {
        self.state.log_into(Some(&self.target), t_ns, dst)
    }

    /// `L_F` per pixel: the log of the latest frame (floored), or `ln REST_LUMINANCE` before any.
    pub fn frame_log(&self) -> ArrayView2<'_, f64> {
        self.target.view()
    }

    /// Frames pushed so far.
    pub fn frames_pushed(&self) -> u64 {
        self.frames
    }

    /// The latest instant pushed; reads must be at or after it.
    pub fn latest_ns(&self) -> i64 {
        self.state.latest_ns
    }

    /// `(height, width)`.
    pub fn dim(&self) -> (usize, usize) {
        self.state.dim()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{EventBuf, close, stream};
    use ndarray::{Array2, array};
    use proptest::prelude::*;

    const C: Contrast = Contrast { on: 0.2, off: 0.3 };

    fn hf_log(hf: &HighPassFilter) -> Array2<f64> {
        let mut d = Array2::from_elem(hf.dim(), f64::NAN);
        hf.log_into(hf.latest_ns(), d.view_mut()).expect("log");
        d
    }

    fn cf_log(cf: &ComplementaryFilter) -> Array2<f64> {
        let mut d = Array2::from_elem(cf.dim(), f64::NAN);
        cf.log_into(cf.latest_ns(), d.view_mut()).expect("log");
        d
    }

    fn hf_frame(hf: &HighPassFilter, t: i64) -> Array2<f32> {
        let mut d = Array2::from_elem(hf.dim(), f32::NAN);
        hf.frame_into(t, d.view_mut()).expect("frame");
        d
    }

    fn cf_frame(cf: &ComplementaryFilter, t: i64) -> Array2<f32> {
        let mut d = Array2::from_elem(cf.dim(), f32::NAN);
        cf.frame_into(t, d.view_mut()).expect("frame");
        d
    }

    #[test]
    fn hf_single_event_decays_exponentially() {
        let alpha = 2.0 * std::f64::consts::PI * 50.0;
        let mut hf = HighPassFilter::new(1, 2, alpha, 0).expect("new");
        hf.push_events(EventBuf::from(&[(1_000, 1, 0, 1)]).slice(), C)
            .expect("push");
        for dt_ns in [0i64, 1_000_000, 5_000_000, 100_000_000] {
            let l = 0.2 * (-alpha * dt_ns as f64 * 1e-9).exp();
            let f = hf_frame(&hf, 1_000 + dt_ns);
            assert!(
                close(f64::from(f[[0, 1]]), 0.5 * l.exp(), 1e-6),
                "{dt_ns}: {f}"
            );
            assert_eq!(f[[0, 0]], 0.5);
        }
        // A second event decays the first, then adds its own step.
        hf.push_events(EventBuf::from(&[(2_001_000, 1, 0, -1)]).slice(), C)
            .expect("push");
        let l = 0.2 * (-alpha * 2e-3).exp() - 0.3;
        assert!(close(hf_log(&hf)[[0, 1]], l, 1e-12));
        assert_eq!(hf_log(&hf)[[0, 0]], 0.0);
    }

    #[test]
    fn hf_zero_cutoff_integrates_events() {
        let mut hf = HighPassFilter::new(2, 2, 0.0, 0).expect("new");
        let mut ev = EventBuf::default();
        for i in 0..1000 {
            ev.push(i * 1_000_000, 1, 1, if i % 3 == 0 { -1 } else { 1 });
        }
        hf.push_events(ev.slice(), C).expect("push");
        let want = 666.0 * 0.2 - 334.0 * 0.3;
        assert!(close(hf_log(&hf)[[1, 1]], want, 1e-12));
        // Long after, nothing has decayed.
        let f = hf_frame(&hf, i64::MAX);
        assert_eq!(f[[1, 1]], 1.0);
        assert_eq!(f[[0, 0]], 0.5);
    }

    #[test]
    fn hf_no_events_is_rest_luminance() {
        let mut hf = HighPassFilter::new(3, 4, 10.0, -5).expect("new");
        hf.push_events(EventBuf::default().slice(), C)
            .expect("empty");
        assert_eq!(hf.latest_ns(), -5);
        for t in [-5, 0, i64::MAX] {
            assert!(hf_frame(&hf, t).iter().all(|&v| v == 0.5));
        }
    }

    #[test]
    fn hf_events_at_one_instant_add_without_decay() {
        let mut hf = HighPassFilter::new(1, 1, 1e12, 0).expect("new");
        let ev = EventBuf::from(&[(7, 0, 0, 1), (7, 0, 0, 1), (7, 0, 0, 1)]);
        hf.push_events(ev.slice(), C).expect("push");
        // The first event decays the empty state to 0 (alpha dt is huge), the next two add.
        assert!(close(hf_log(&hf)[[0, 0]], 0.6, 1e-15));
        assert!(close(
            f64::from(hf_frame(&hf, 7)[[0, 0]]),
            0.5 * 0.6f64.exp(),
            1e-7
        ));
        // One nanosecond later at 1e12 rad/s: exp(-1000) = 0.
        assert_eq!(hf_frame(&hf, 8)[[0, 0]], 0.5);
    }

    #[test]
    fn hf_log_beyond_range_clamps_to_one_and_zero() {
        let mut hf = HighPassFilter::new(1, 2, 0.0, 0).expect("new");
        let mut ev = EventBuf::default();
        for i in 0..2000 {
            ev.push(i, 0, 0, 1);
            ev.push(i, 1, 0, -1);
        }
        // exp(2000) overflows f64; exp(-2000) underflows.
        hf.push_events(ev.slice(), Contrast::symmetric(1.0))
            .expect("push");
        let f = hf_frame(&hf, 5_000);
        assert_eq!(f, array![[1.0f32, 0.0]]);
        let mut r = Array2::zeros((1, 2));
        hf.frame_into_reference(5_000, r.view_mut()).expect("ref");
        assert_eq!(r, f);
    }

    #[test]
    fn hf_time_going_backwards_is_refused_and_state_kept() {
        let mut hf = HighPassFilter::new(1, 1, 1.0, 100).expect("new");
        let e = hf
            .push_events(EventBuf::from(&[(99, 0, 0, 1)]).slice(), C)
            .expect_err("before start");
        assert_eq!(
            e.to_string(),
            "first event: t = 99 ns is before 100 ns, the latest instant already pushed"
        );
        hf.push_events(EventBuf::from(&[(200, 0, 0, 1)]).slice(), C)
            .expect("push");
        let before = hf_log(&hf);
        assert!(matches!(
            hf.push_events(EventBuf::from(&[(150, 0, 0, 1)]).slice(), C),
            Err(InferError::TimeBackwards {
                t_ns: 150,
                latest_ns: 200,
                ..
            })
        ));
        let mut d = Array2::zeros((1, 1));
        let e = hf.frame_into(199, d.view_mut()).expect_err("read before");
        assert!(e.to_string().contains("frame read: t = 199 ns"), "{e}");
        assert!(hf.frame_into_reference(199, d.view_mut()).is_err());
        assert_eq!(hf_log(&hf), before);
        assert_eq!(hf.latest_ns(), 200);
        // Same instant is fine.
        hf.push_events(EventBuf::from(&[(200, 0, 0, -1)]).slice(), C)
            .expect("same instant");
    }

    #[test]
    fn hf_bad_events_are_refused_and_state_kept() {
        let mut hf = HighPassFilter::new(2, 3, 1.0, 0).expect("new");
        let cases: [(EventBuf, &str); 4] = [
            (EventBuf::from(&[(1, 3, 0, 1)]), "x of event 0"),
            (EventBuf::from(&[(1, 0, 2, 1)]), "y of event 0"),
            (EventBuf::from(&[(1, 0, 0, 0)]), "polarity"),
            (EventBuf::from(&[(5, 0, 0, 1), (4, 0, 0, 1)]), "t_ns"),
        ];
        for (ev, needle) in cases {
            let e = hf.push_events(ev.slice(), C).expect_err(needle);
            assert!(matches!(e, InferError::Events(_)), "{e}");
            assert!(e.to_string().contains(needle), "{e}");
            assert!(hf.push_events_reference(ev.slice(), C).is_err());
        }
        let mut short = EventBuf::from(&[(1, 0, 0, 1)]);
        short.polarity.clear();
        assert!(hf.push_events(short.slice_unchecked(), C).is_err());
        assert!(hf_log(&hf).iter().all(|&l| l == 0.0));
        assert_eq!(hf.latest_ns(), 0);
    }

    #[test]
    fn bad_parameters_name_the_value() {
        for (alpha, needle) in [
            (f64::NAN, "cutoff_rad_s = NaN"),
            (-1.0, "cutoff_rad_s = -1"),
            (f64::INFINITY, "cutoff_rad_s = inf"),
        ] {
            let e = HighPassFilter::new(1, 1, alpha, 0).expect_err(needle);
            assert!(e.to_string().contains(needle), "{e}");
            let e = ComplementaryFilter::new(1, 1, alpha, 0).expect_err(needle);
            assert!(
                e.to_string().contains(&needle.replace("cutoff", "gain")),
                "{e}"
            );
        }
        let mut hf = HighPassFilter::new(1, 1, 1.0, 0).expect("new");
        let ev = EventBuf::from(&[(1, 0, 0, 1)]);
        for (c, needle) in [
            (Contrast { on: 0.0, off: 0.1 }, "contrast.on = 0"),
            (Contrast { on: 0.1, off: -0.1 }, "contrast.off = -0.1"),
            (Contrast::symmetric(f64::NAN), "contrast.on = NaN"),
            (Contrast { on: 0.1, off: 2e6 }, "contrast.off = 2000000"),
        ] {
            let e = hf.push_events(ev.slice(), c).expect_err(needle);
            assert!(e.to_string().contains(needle), "{e}");
        }
        assert_eq!(hf.latest_ns(), 0);
    }

    #[test]
    fn timestamps_at_the_ends_of_i64() {
        for alpha in [0.0, 1e-9, 1.0] {
            let mut hf = HighPassFilter::new(1, 1, alpha, i64::MIN).expect("new");
            let mut cf = ComplementaryFilter::new(1, 1, alpha, i64::MIN).expect("new");
            let ev = EventBuf::from(&[(i64::MIN, 0, 0, 1), (i64::MAX, 0, 0, 1)]);
            hf.push_events(ev.slice(), C).expect("hf");
            cf.push_events(ev.slice(), C).expect("cf");
            // The gap is 2^64 - 1 ns, 584 years: exp(-alpha gap) is 1, 1 - 1.8e-8 and 0.
            let gap = u64::MAX as f64 * 1e-9;
            let want = 0.2 * (-alpha * gap).exp() + 0.2;
            assert!(close(hf_log(&hf)[[0, 0]], want, 1e-12), "{alpha}");
            let f = hf_frame(&hf, i64::MAX);
            assert!(f.iter().all(|v| v.is_finite() && (0.0..=1.0).contains(v)));
            let g = cf_frame(&cf, i64::MAX);
            assert!(
                close(f64::from(g[[0, 0]]), f64::from(f[[0, 0]]), 1e-6),
                "{alpha}"
            );
        }
    }

    #[test]
    fn one_pixel_one_row_one_column_match_the_reference() {
        for (h, w) in [(1usize, 1usize), (1, 7), (7, 1)] {
            let mut ev = EventBuf::default();
            for i in 0..50u16 {
                let x = (i * 3) % w as u16;
                let y = (i * 5) % h as u16;
                ev.push(i64::from(i) * 10_000, x, y, if i % 4 == 0 { -1 } else { 1 });
            }
            let mut fast = HighPassFilter::new(h, w, 3e3, 0).expect("new");
            let mut slow = fast.clone();
            fast.push_events(ev.slice(), C).expect("fast");
            slow.push_events_reference(ev.slice(), C).expect("slow");
            let mut r = Array2::zeros((h, w));
            slow.frame_into_reference(600_000, r.view_mut())
                .expect("ref");
            let f = hf_frame(&fast, 600_000);
            assert!(
                f.iter().zip(&r).all(|(a, b)| (a - b).abs() <= 1e-6),
                "{h}x{w}"
            );
        }
    }

    #[test]
    fn cf_without_frames_equals_high_pass() {
        let mut ev = EventBuf::default();
        for i in 0..300u16 {
            ev.push(
                i64::from(i) * 7_000,
                i % 5,
                (i / 5) % 3,
                if i % 3 == 0 { -1 } else { 1 },
            );
        }
        let alpha = 50.0;
        let mut hf = HighPassFilter::new(3, 5, alpha, 0).expect("hf");
        let mut cf = ComplementaryFilter::new(3, 5, alpha, 0).expect("cf");
        hf.push_events(ev.slice(), C).expect("hf");
        cf.push_events(ev.slice(), C).expect("cf");
        let (a, b) = (hf_frame(&hf, 3_000_000), cf_frame(&cf, 3_000_000));
        assert!(
            a.iter().zip(&b).all(|(a, b)| (a - b).abs() <= 1e-6),
            "{a}\n{b}"
        );
        assert_eq!(cf.frames_pushed(), 0);
    }

    #[test]
    fn cf_first_frame_sets_the_state() {
        let mut cf = ComplementaryFilter::new(1, 2, 10.0, 0).expect("new");
        cf.push_events(EventBuf::from(&[(5, 0, 0, 1)]).slice(), C)
            .expect("events");
        cf.push_frame(10, array![[0.25f32, 0.8]].view())
            .expect("frame");
        assert_eq!(cf_log(&cf), array![[0.25f64.ln(), 0.8f32.ln_f64()]]);
        assert_eq!(cf.frame_log(), cf_log(&cf));
        let f = cf_frame(&cf, 10);
        assert!(close(f64::from(f[[0, 0]]), 0.25, 1e-7) && close(f64::from(f[[0, 1]]), 0.8, 1e-7));
    }

    #[test]
    fn cf_relaxes_toward_the_frame_at_rate_gain() {
        let alpha = 100.0;
        let mut cf = ComplementaryFilter::new(1, 1, alpha, 0).expect("new");
        cf.push_frame(0, array![[0.2f32]].view()).expect("frame");
        cf.push_events(EventBuf::from(&[(1_000_000, 0, 0, 1)]).slice(), C)
            .expect("event");
        let lf = f64::from(0.2f32).ln();
        for dt in [0i64, 1_000_000, 10_000_000] {
            let want = (lf + 0.2 * (-alpha * dt as f64 * 1e-9).exp()).exp();
            let got = f64::from(cf_frame(&cf, 1_000_000 + dt)[[0, 0]]);
            assert!(close(got, want, 1e-6), "{dt}: {got} vs {want}");
        }
        // A new frame: the pixel first relaxes toward 0.2 until 3 ms, then toward 0.6.
        cf.push_frame(3_000_000, array![[0.6f32]].view())
            .expect("frame");
        let l3 = lf + 0.2 * (-alpha * 2e-3).exp();
        assert!(close(cf_log(&cf)[[0, 0]], l3, 1e-12));
        let lf2 = f64::from(0.6f32).ln();
        let want = (lf2 + (l3 - lf2) * (-alpha * 5e-3).exp()).exp();
        assert!(close(
            f64::from(cf_frame(&cf, 8_000_000)[[0, 0]]),
            want,
            1e-6
        ));
        // Long after, the frame alone.
        assert!(close(f64::from(cf_frame(&cf, i64::MAX)[[0, 0]]), 0.6, 1e-7));
    }

    #[test]
    fn cf_zero_gain_keeps_the_first_frame_and_events() {
        let mut cf = ComplementaryFilter::new(1, 1, 0.0, 0).expect("new");
        cf.push_frame(0, array![[0.1f32]].view()).expect("frame");
        cf.push_events(EventBuf::from(&[(5, 0, 0, 1), (6, 0, 0, 1)]).slice(), C)
            .expect("events");
        cf.push_frame(10, array![[0.9f32]].view()).expect("frame");
        let want = (f64::from(0.1f32).ln() + 0.4).exp();
        assert!(close(
            f64::from(cf_frame(&cf, i64::MAX)[[0, 0]]),
            want,
            1e-6
        ));
    }

    #[test]
    fn cf_dark_and_non_finite_frames_are_floored() {
        let lum = array![[
            0.0f32,
            -1.0,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            1e-30
        ]];
        let mut cf = ComplementaryFilter::new(1, 6, 1.0, 0).expect("new");
        cf.push_frame(0, lum.view()).expect("frame");
        let floor = LUMINANCE_FLOOR.ln();
        let got = cf.frame_log();
        assert_eq!(got[[0, 3]], f64::from(f32::MAX).ln());
        for x in [0, 1, 2, 4, 5] {
            assert_eq!(got[[0, x]], floor, "{x}");
        }
        let f = cf_frame(&cf, 1);
        assert!(close(f64::from(f[[0, 0]]), LUMINANCE_FLOOR, 1e-6));
        assert_eq!(f[[0, 3]], 1.0);
        assert!(f.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn cf_frame_shape_and_time_are_checked() {
        let mut cf = ComplementaryFilter::new(2, 3, 1.0, 50).expect("new");
        let e = cf
            .push_frame(60, Array2::<f32>::zeros((3, 2)).view())
            .expect_err("shape");
        assert!(e.to_string().contains("[3, 2]"), "{e}");
        let e = cf
            .push_frame(40, Array2::<f32>::zeros((2, 3)).view())
            .expect_err("time");
        assert!(e.to_string().starts_with("frame: t = 40 ns"), "{e}");
        assert!(
            cf.push_frame_reference(40, Array2::<f32>::zeros((2, 3)).view())
                .is_err()
        );
        assert_eq!(cf.frames_pushed(), 0);
        let mut d = Array2::zeros((2, 2));
        assert!(matches!(
            cf.frame_into(60, d.view_mut()),
            Err(InferError::Shape { .. })
        ));
    }

    /// `ln` of an `f32` taken in `f64`.
    trait LnF64 {
        fn ln_f64(self) -> f64;
    }
    impl LnF64 for f32 {
        fn ln_f64(self) -> f64 {
            f64::from(self).ln()
        }
    }

    impl EventBuf {
        /// The columns as they are, lengths unchecked (for the length error).
        fn slice_unchecked(&self) -> EventSlice<'_> {
            EventSlice {
                t_ns: &self.t_ns,
                x: &self.x,
                y: &self.y,
                polarity: &self.polarity,
            }
        }
    }

    fn states_close(a: &Array2<f64>, b: &Array2<f64>) -> bool {
        a.iter().zip(b.iter()).all(|(&a, &b)| close(a, b, 1e-9))
    }

    /// The fast push with the dense (`batch`) or sparse path forced.
    fn push_with(
        st: &mut LogState,
        target: Option<&Array2<f64>>,
        ev: EventSlice,
        c: Contrast,
        batch: bool,
    ) {
        let latest = st.check_push(ev, c).expect("checks");
        st.push_fast_with(target, ev, c, batch);
        st.latest_ns = latest;
    }

    /// `dst` in Fortran layout when `transposed`, to exercise the `Zip` paths on strided views.
    fn dst(h: usize, w: usize, transposed: bool) -> Array2<f32> {
        if transposed {
            Array2::from_elem((w, h), f32::NAN).reversed_axes()
        } else {
            Array2::from_elem((h, w), f32::NAN)
        }
    }

    proptest! {
        #[test]
        fn hf_fast_matches_reference(
            (h, w, ev, cuts) in stream(6, 80, 3_000),
            alpha in prop_oneof![Just(0.0), 0.0f64..1e7],
            on in 0.01f64..1.0, off in 0.01f64..1.0,
            read_after in 0i64..20_000, par in any::<bool>(), transposed in any::<bool>(),
            batch in any::<bool>(),
        ) {
            let c = Contrast { on, off };
            let mut fast = HighPassFilter::new(h, w, alpha, 0).expect("new");
            let mut slow = fast.clone();
            let mut a = 0;
            for &b in &cuts {
                push_with(&mut fast.state, None, ev.range(a, b), c, batch);
                slow.push_events_reference(ev.range(a, b), c).expect("slow");
                prop_assert_eq!(fast.latest_ns(), slow.latest_ns());
                prop_assert!(states_close(&hf_log(&fast), &hf_log(&slow)));
                let t = fast.latest_ns() + read_after;
                let mut f = dst(h, w, transposed);
                let mut r = dst(h, w, !transposed);
                fast.state.check_read(t, f.dim()).expect("read");
                fast.state.frame_fast(None, t, REST_LUMINANCE.ln(), f.view_mut(), par);
                slow.frame_into_reference(t, r.view_mut()).expect("ref");
                prop_assert!(f.iter().zip(&r).all(|(a, b)| (a - b).abs() <= 1e-6));
                prop_assert!(f.iter().all(|v| (0.0..=1.0).contains(v)));
                a = b;
            }
        }

        #[test]
        fn cf_fast_matches_reference(
            (h, w, ev, cuts) in stream(5, 60, 3_000),
            frames in proptest::collection::vec(
                proptest::collection::vec(prop_oneof![Just(0.0f32), Just(f32::NAN), -0.5f32..1.5], 25), 1..4),
            alpha in prop_oneof![Just(0.0), 0.0f64..1e7],
            contrast in 0.01f64..1.0, read_after in 0i64..20_000,
            par in any::<bool>(), transposed in any::<bool>(), batch in any::<bool>(),
        ) {
            let c = Contrast::symmetric(contrast);
            let mut fast = ComplementaryFilter::new(h, w, alpha, 0).expect("new");
            let mut slow = fast.clone();
            let mut a = 0;
            for (i, &b) in cuts.iter().enumerate() {
                push_with(&mut fast.state, Some(&fast.target), ev.range(a, b), c, batch);
                slow.push_events_reference(ev.range(a, b), c).expect("slow");
                if let Some(lum) = frames.get(i) {
                    let lum = Array2::from_shape_vec((h, w), lum[..h * w].to_vec()).expect("lum");
                    let lum = if transposed { lum.t().to_owned().reversed_axes() } else { lum };
                    let next = ev.t_ns.get(b).copied().unwrap_or(i64::MAX);
                    let t = (fast.latest_ns() + read_after / 2).min(next);
                    fast.push_frame_fast(t, lum.view(), par);
                    slow.push_frame_reference(t, lum.view()).expect("slow frame");
                }
                prop_assert_eq!(fast.frame_log(), slow.frame_log());
                prop_assert!(states_close(&cf_log(&fast), &cf_log(&slow)));
                let t = fast.latest_ns() + read_after;
                let mut f = dst(h, w, transposed);
                let mut r = dst(h, w, false);
                fast.state.frame_fast(Some(&fast.target), t, 0.0, f.view_mut(), par);
                slow.frame_into_reference(t, r.view_mut()).expect("ref");
                prop_assert!(f.iter().zip(&r).all(|(a, b)| (a - b).abs() <= 1e-6));
                prop_assert!(f.iter().all(|v| (0.0..=1.0).contains(v)));
                a = b;
            }
        }
    }
}
