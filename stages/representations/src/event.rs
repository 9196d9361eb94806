//! Event representations: the paper's event integration (Eq. 8) and the signed event count.
//!
//! Events arrive as an [`EventSlice`], a struct of slices sorted by time. The sensor's size is the
//! destination's `[H, W]`; an event outside it is an error, never clipped.
//!
//! Each kernel has a plain `*_reference` (the oracle) and a fast path. The fast path of event
//! integration costs `O(events + K * H * W)` instead of the reference's `O(events * K + K * H * W)`
//! and, when the work reaches [`MIN_ELEMENTS_FOR_RAYON`] and rayon has at least four threads,
//! splits the sensor into one band of rows per thread (each task picks its band's events itself).
//! The signed count splits long event runs over rayon threads, one histogram each, and sums them.

use neuspike_simd::fastmath::exp_neg;
use std::ops::Range;

use ndarray::{ArrayViewMut2, ArrayViewMut3, Axis};
use rayon::prelude::*;

use crate::error::{RepresentError, shape_str};
use crate::spike::{MIN_ELEMENTS_FOR_RAYON, ROWS_PER_TASK};

/// Events as parallel slices: event `i` is `(t_ns[i], x[i], y[i], polarity[i])`.
///
/// Invariants every kernel checks (see [`EventSlice::validate`]): the four slices have equal
/// lengths, `t_ns` is sorted non-decreasing, `polarity` is `+1` (ON) or `-1` (OFF), and
/// `x < W`, `y < H` for the sensor the kernel writes.
#[derive(Clone, Copy, Debug, Default)]
pub struct EventSlice<'a> {
    /// Timestamps in nanoseconds, non-decreasing.
    pub t_ns: &'a [i64],
    /// Column, `0..W`.
    pub x: &'a [u16],
    /// Row, `0..H` (row 0 at the top, as in the spike planes).
    pub y: &'a [u16],
    /// `+1` for ON (brighter), `-1` for OFF (darker).
    pub polarity: &'a [i8],
}

impl<'a> EventSlice<'a> {
    /// Number of events (the length of `t_ns`).
    pub fn len(&self) -> usize {
        self.t_ns.len()
    }

    /// Whether there are no events.
    pub fn is_empty(&self) -> bool {
        self.t_ns.is_empty()
    }

    /// Events `r` of this slice.
    pub(crate) fn range(&self, r: Range<usize>) -> EventSlice<'a> {
        EventSlice {
            t_ns: &self.t_ns[r.clone()],
            x: &self.x[r.clone()],
            y: &self.y[r.clone()],
            polarity: &self.polarity[r],
        }
    }

    /// The first `mid` events and the rest.
    pub(crate) fn split_at(&self, mid: usize) -> (EventSlice<'a>, EventSlice<'a>) {
        (self.range(0..mid), self.range(mid..self.len()))
    }

    /// Checks the invariants for a sensor of `height` rows and `width` columns, in one pass.
    ///
    /// # Errors
    /// - [`RepresentError::Shape`] when `x`, `y` or `polarity` is not as long as `t_ns`.
    /// - [`RepresentError::Param`] when `t_ns` decreases somewhere or a polarity is not ±1
    ///   (the message gives the event's index and value).
    /// - [`RepresentError::Index`] when an event lies outside the sensor (`x >= width` or
    ///   `y >= height`), naming the event and the coordinate.
    pub fn validate(&self, height: usize, width: usize) -> Result<(), RepresentError> {
        if self.is_valid(height, width) {
            return Ok(());
        }
        self.first_violation(height, width)
    }

    /// Whether every invariant holds: branch-free reductions over blocks of events that the
    /// compiler vectorises, several times faster than [`Self::first_violation`]'s event-by-event
    /// checks, which run only when this says no (to name the first offending event).
    fn is_valid(&self, height: usize, width: usize) -> bool {
        let n = self.t_ns.len();
        if self.x.len() != n || self.y.len() != n || self.polarity.len() != n {
            return false;
        }
        if n == 0 {
            return true;
        }
        // x < width and y < height as u16 bounds; a sensor wider than u16 holds every x.
        let x_limit = u16::try_from(width).unwrap_or(u16::MAX).saturating_sub(1);
        let y_limit = u16::try_from(height).unwrap_or(u16::MAX).saturating_sub(1);
        let (x_all, y_all) = (
            width > usize::from(u16::MAX),
            height > usize::from(u16::MAX),
        );
        if width == 0 || height == 0 {
            return false;
        }
        neuspike_simd::dispatch(
            #[inline(always)]
            || self.blocks_valid(x_limit, y_limit, x_all, y_all),
        )
    }

    /// [`Self::is_valid`]'s reductions, block by block (the slices' lengths agree, `n > 0`).
    #[inline(always)]
    fn blocks_valid(&self, x_limit: u16, y_limit: u16, x_all: bool, y_all: bool) -> bool {
        /// Events per block; a violation stops the scan at the end of its block.
        const BLOCK: usize = 1 << 12;
        let n = self.t_ns.len();
        let mut start = 0;
        while start < n {
            let end = (start + BLOCK).min(n);
            let t = &self.t_ns[start..end];
            let before = if start > 0 {
                self.t_ns[start - 1]
            } else {
                t[0]
            };
            let unsorted = (t[0] < before)
                | t.iter()
                    .zip(&t[1..])
                    .fold(false, |bad, (a, b)| bad | (b < a));
            let x_max = self.x[start..end].iter().fold(0u16, |m, &v| m.max(v));
            let y_max = self.y[start..end].iter().fold(0u16, |m, &v| m.max(v));
            // p = 1 maps to 2 and p = -1 to 0; every other byte keeps a bit outside 0b10.
            let bad_polarity = self.polarity[start..end]
                .iter()
                .fold(0u8, |bad, &p| bad | ((p as u8).wrapping_add(1) & !2));
            if unsorted
                || (x_max > x_limit && !x_all)
                || (y_max > y_limit && !y_all)
                || bad_polarity != 0
            {
                return false;
            }
            start = end;
        }
        true
    }

    /// The event-by-event checks: the error for the first violation, `Ok` if there is none.
    fn first_violation(&self, height: usize, width: usize) -> Result<(), RepresentError> {
        let n = self.t_ns.len();
        for (what, len) in [
            ("event slice x length", self.x.len()),
            ("event slice y length", self.y.len()),
            ("event slice polarity length", self.polarity.len()),
        ] {
            if len != n {
                return Err(RepresentError::Shape {
                    what,
                    expected: format!("[{n}] (the length of t_ns)"),
                    actual: shape_str(&[len]),
                });
            }
        }
        for i in 0..n {
            if i > 0 && self.t_ns[i] < self.t_ns[i - 1] {
                return Err(RepresentError::Param {
                    name: "events.t_ns",
                    value: format!(
                        "t_ns[{i}] = {} after t_ns[{}] = {}",
                        self.t_ns[i],
                        i - 1,
                        self.t_ns[i - 1]
                    ),
                    reason: "events must be sorted by time (non-decreasing)",
                });
            }
            let (x, y) = (usize::from(self.x[i]), usize::from(self.y[i]));
            if x >= width {
                return Err(RepresentError::Index {
                    what: format!("x of event {i}"),
                    value: x as u64,
                    limit: width as u64,
                });
            }
            if y >= height {
                return Err(RepresentError::Index {
                    what: format!("y of event {i}"),
                    value: y as u64,
                    limit: height as u64,
                });
            }
            let p = self.polarity[i];
            if p != 1 && p != -1 {
                return Err(RepresentError::Param {
                    name: "events.polarity",
                    value: format!("polarity[{i}] = {p}"),
                    reason: "must be +1 (ON) or -1 (OFF)",
                });
            }
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------------
// Decay
// ---------------------------------------------------------------------------------------------

/// The decay kernel `exp(-dt / tau)` with its two limits made explicit.
#[derive(Clone, Copy, Debug)]
enum Decay {
    /// `tau -> 0`: 1 at `dt = 0`, 0 for any `dt > 0`.
    Instant,
    /// A finite positive `tau` in nanoseconds.
    Exp(f64),
    /// `tau = +inf`: 1 for every `dt`.
    Never,
}

impl Decay {
    fn new(tau_ns: f64) -> Result<Self, RepresentError> {
        if tau_ns.is_nan() {
            return Err(RepresentError::Param {
                name: "tau_ns",
                value: format!("{tau_ns}"),
                reason: "the decay time must be a number (<= 0 for the tau -> 0 limit, +inf for no decay)",
            });
        }
        // A tau so small that 1 / tau overflows (subnormal) weighs as the limit does: 1 at dt = 0,
        // `exp(-dt / tau) = 0` for any dt >= 1 ns.
        Ok(if tau_ns <= 0.0 || (1.0 / tau_ns).is_infinite() {
            Self::Instant
        } else if tau_ns == f64::INFINITY {
            Self::Never
        } else {
            Self::Exp(tau_ns)
        })
    }

    /// `exp(-(later - earlier) / tau)` for `later >= earlier`, in `[0, 1]`. The difference is taken
    /// in `i128`, so any two `i64` instants work, then converted to `f64`. Division (not
    /// multiplication by `1 / tau`) keeps `dt = 0` at exactly 1 even for a subnormal `tau`.
    #[inline]
    fn factor(self, later_ns: i64, earlier_ns: i64) -> f64 {
        let dt = i128::from(later_ns) - i128::from(earlier_ns);
        match self {
            Self::Instant => {
                if dt == 0 {
                    1.0
                } else {
                    0.0
                }
            }
            Self::Exp(tau) => (-(dt as f64) / tau).exp(),
            Self::Never => 1.0,
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Event integration
// ---------------------------------------------------------------------------------------------

/// Event integration, paper Eq. 8: `K` channels of `V(t)` at the instants `ts_ns`.
///
/// For channel `k` and each pixel,
/// `dst[k, y, x] = V_on - V_off` with
/// `V_on = sum over ON events at the pixel with t0_ns <= t_i <= ts_ns[k] of (1 + exp(-(ts_ns[k] - t_i) / tau_ns))`
/// and `V_off` the same sum over OFF events: the plain signed count plus the exponentially decayed
/// count, ON and OFF accumulated separately in `f64` and summed at the end (docs/definitions.md).
/// Both window ends are inclusive. `K = ts_ns.len()`, `dst` is `[K, H, W]` and `[H, W]` is the
/// sensor. The output is finite, with `|dst| <= 2 * (events at the pixel)`.
///
/// Limits of `tau_ns`:
/// - `tau_ns <= 0` (also `-inf`) is the `tau -> 0+` limit: the decay term is 0 for events before
///   `ts_ns[k]`, so the channel is the plain signed count, except that an event exactly at
///   `ts_ns[k]` has `exp(0) = 1` for every `tau` and so contributes 2 (±).
/// - `tau_ns = +inf`: no decay, the channel is twice the signed count.
///
/// Time differences are taken in `i128` and converted to `f64`, so instants anywhere in the `i64`
/// range (near `i64::MAX` included) work without overflow. The fast path keeps each pixel's sum
/// of `±exp((t_i - t_base) / tau)` against a base instant that moves on as the channels do (see
/// `integrate_block`), and matches the reference to about `1e-12` relative before the final
/// rounding to `f32`.
///
/// # Errors
/// - [`RepresentError::Shape`] when `dst` has not `ts_ns.len()` channels, or the event slices differ
///   in length.
/// - [`RepresentError::Param`] when `tau_ns` is NaN, `ts_ns` decreases somewhere, the events are
///   not sorted by time, or a polarity is not ±1.
/// - [`RepresentError::Index`] for an event outside the sensor, naming the event and coordinate.
///
/// No events, or none in a channel's window, give zeros. `K = 0` writes nothing.
///
/// ```
/// use ndarray::Array3;
/// use neuspike_representations::{EventSlice, event_integration_into};
/// let events = EventSlice { t_ns: &[1_000], x: &[0], y: &[0], polarity: &[1] };
/// let mut v = Array3::<f32>::zeros((2, 1, 1));
/// event_integration_into(events, 0, &[500, 1_500], 500.0, v.view_mut()).unwrap();
/// assert_eq!(v[[0, 0, 0]], 0.0); // the event comes after the first instant
/// assert!((v[[1, 0, 0]] - (1.0 + (-1.0f32).exp())).abs() < 1e-6);
/// ```
pub fn event_integration_into(
    events: EventSlice,
    t0_ns: i64,
    ts_ns: &[i64],
    tau_ns: f64,
    dst: ArrayViewMut3<f32>,
) -> Result<(), RepresentError> {
    let (decay, window) = check_integration(events, t0_ns, ts_ns, tau_ns, dst.dim())?;
    let (k, h, w) = dst.dim();
    // One band per thread, and only from four threads on: each band re-reads the whole window,
    // and on two threads that made it 1.14x slower than one (`bench_spike`: 7.4 against 6.5 ms
    // for a million events); no larger machine was at hand to measure.
    let threads = rayon::current_num_threads();
    let bands = (threads >= 4 && k * h * w + window.len() >= MIN_ELEMENTS_FOR_RAYON)
        .then(|| h.div_ceil(threads).max(ROWS_PER_TASK));
    integration_fast(events, window, ts_ns, decay, dst, bands);
    Ok(())
}

/// The `k` instants of event integration over a window `[t_start_ns, t_end_ns)`, as the
/// represent node uses them: `t_start + round(i (t_end - t_start) / k)` for `i = 1..=k`, so the
/// last instant is the window's end. The span is formed in `f64` (exact below 2^53 ns, 104 days);
/// `k = 0` gives none, and an empty or reversed window gives `k` copies of `t_start_ns`.
pub fn integration_instants(t_start_ns: i64, t_end_ns: i64, k: usize) -> Vec<i64> {
    let span = (t_end_ns.saturating_sub(t_start_ns)).max(0) as f64;
    (1..=k)
        .map(|i| t_start_ns.saturating_add((span * i as f64 / k as f64).round() as i64))
        .collect()
}

/// Checks for event integration; returns the decay and the range of events with
/// `t0_ns <= t_i <= max(ts_ns)`.
fn check_integration(
    events: EventSlice,
    t0_ns: i64,
    ts_ns: &[i64],
    tau_ns: f64,
    dst_dim: (usize, usize, usize),
) -> Result<(Decay, Range<usize>), RepresentError> {
    let (k, h, w) = dst_dim;
    if k != ts_ns.len() {
        return Err(RepresentError::Shape {
            what: "event integration dst (one channel per instant in ts_ns)",
            expected: format!("[{}, {h}, {w}]", ts_ns.len()),
            actual: shape_str(&[k, h, w]),
        });
    }
    let decay = Decay::new(tau_ns)?;
    if let Some(i) = (1..ts_ns.len()).find(|&i| ts_ns[i] < ts_ns[i - 1]) {
        return Err(RepresentError::Param {
            name: "ts_ns",
            value: format!(
                "ts_ns[{i}] = {} after ts_ns[{}] = {}",
                ts_ns[i],
                i - 1,
                ts_ns[i - 1]
            ),
            reason: "channel instants must be non-decreasing",
        });
    }
    events.validate(h, w)?;
    let first = events.t_ns.partition_point(|&t| t < t0_ns);
    let last = match ts_ns.last() {
        Some(&t_max) => events.t_ns.partition_point(|&t| t <= t_max),
        None => first,
    };
    Ok((decay, first..last.max(first)))
}

/// Scalar oracle for [`event_integration_into`]: for every channel, every event of the window,
/// the closed form `p * (1 + exp(-(ts - t_i) / tau))` summed per polarity in `f64`. Same checks.
#[doc(hidden)]
pub fn event_integration_reference(
    events: EventSlice,
    t0_ns: i64,
    ts_ns: &[i64],
    tau_ns: f64,
    mut dst: ArrayViewMut3<f32>,
) -> Result<(), RepresentError> {
    let (decay, _) = check_integration(events, t0_ns, ts_ns, tau_ns, dst.dim())?;
    let (_, h, w) = dst.dim();
    for (k, &t_k) in ts_ns.iter().enumerate() {
        let mut on = vec![0.0f64; h * w];
        let mut off = vec![0.0f64; h * w];
        for i in 0..events.len() {
            let t_i = events.t_ns[i];
            if t_i < t0_ns || t_i > t_k {
                continue;
            }
            let p = usize::from(events.y[i]) * w + usize::from(events.x[i]);
            let weight = 1.0 + decay.factor(t_k, t_i);
            if events.polarity[i] > 0 {
                on[p] += weight;
            } else {
                off[p] += weight;
            }
        }
        for y in 0..h {
            for x in 0..w {
                dst[[k, y, x]] = (on[y * w + x] - off[y * w + x]) as f32;
            }
        }
    }
    Ok(())
}

/// Fast event integration. `window` holds the events with `t0 <= t_i <= max(ts)`; everything
/// was checked by the caller. `bands` of `Some(r)` splits the sensor into bands of `r` rows, one
/// rayon task each; every task picks its band's events out of the window itself (one branchless
/// pass over the window, in parallel), so no serial bucketing stands before the parallel part.
fn integration_fast(
    events: EventSlice,
    window: Range<usize>,
    ts_ns: &[i64],
    decay: Decay,
    mut dst: ArrayViewMut3<f32>,
    bands: Option<usize>,
) {
    let events = events.range(window);
    match bands {
        Some(rows) => {
            dst.axis_chunks_iter_mut(Axis(1), rows.max(1))
                .into_par_iter()
                .enumerate()
                .for_each(|(b, block)| {
                    let y0 = b * rows.max(1);
                    let band = Band::of(events, y0..y0 + block.len_of(Axis(1)));
                    integrate_block(band.slice(), ts_ns, decay, y0, block);
                });
        }
        None => integrate_block(events, ts_ns, decay, 0, dst),
    }
}

/// Integrates `events` (time-ordered, all in rows `y0..y0 + rows`) into the block `dst`
/// `[K, rows, W]`, channel by channel: add the events up to the next instant, write.
///
/// Each pixel carries its signed count and `G`, the signed sum of `exp((t_i - t_base) / tau)`
/// over its events (ON minus OFF, in `f64`: the same value as summing ON and OFF apart, to
/// rounding), side by side so an event touches one cache line. Channel `k` is then
/// `count + G exp(-(t_k - t_base) / tau)`: a read-only pass over the sums, where carrying decayed
/// sums from instant to instant would write them all back every channel. `t_base` moves on to
/// `t_k` (one pass scaling `G` down) whenever `(t_k - t_base) / tau` passes [`REBASE_AT`], so `G`
/// stays below `events * e^REBASE_AT`, far inside `f64`.
///
/// A channel's events are a contiguous run of `events`, taken in batches of [`BATCH`] so the
/// batch stays in the first-level cache; their pixels, signs and weights
/// `p exp(-(t_k - t_i) / tau) exp((t_k - t_base) / tau)` are computed in vectorised passes
/// ([`neuspike_simd::fastmath::exp_neg`]), then added one by one; the output is a vectorised pass over the pixels. No
/// branch depends on a polarity. For `tau -> 0` only events at `t_k` itself weigh: their `G` is
/// cleared again once the channels move past `t_k` (it was 0 before; channels repeating `t_k`
/// weigh them again), for `tau = inf` `G` is the signed count.
fn integrate_block(
    events: EventSlice,
    ts_ns: &[i64],
    decay: Decay,
    y0: usize,
    mut dst: ArrayViewMut3<f32>,
) {
    let (_, rows, w) = dst.dim();
    // [signed count, G] per pixel.
    let mut sums = vec![[0.0f64; 2]; rows * w];
    let mut batch = ChannelBatch::default();
    let mut rest = events;
    let mut t_base = ts_ns.first().copied().unwrap_or(0);
    // The first event whose `G` a `tau -> 0` integration has not cleared yet.
    let mut uncleared = 0;
    for (k, &t_k) in ts_ns.iter().enumerate() {
        let (now, later) = rest.split_at(rest.t_ns.partition_point(|&t| t <= t_k));
        rest = later;
        // exp((t_k - t_base) / tau) and its inverse, rebasing first when it would grow too large.
        let (scale, unscale) = match decay {
            Decay::Exp(tau) => {
                let mut a = ((i128::from(t_k) - i128::from(t_base)) as f64) / tau;
                if a > REBASE_AT {
                    let f = (-a).exp();
                    sums.iter_mut().for_each(|s| s[1] *= f);
                    t_base = t_k;
                    a = 0.0;
                }
                (a.exp(), (-a).exp())
            }
            Decay::Instant | Decay::Never => (1.0, 1.0),
        };
        let mut start = 0;
        while start < now.len() {
            let part = now.range(start..(start + BATCH).min(now.len()));
            start += part.len();
            batch.fill(part, t_k, y0, w, decay, scale);
            for ((&p, &s), &wt) in batch.pixel.iter().zip(&batch.sign).zip(&batch.weight) {
                let sum = &mut sums[p];
                sum[0] += s;
                sum[1] += wt;
            }
        }
        let mut plane = dst.index_axis_mut(Axis(0), k);
        match plane.as_slice_mut() {
            Some(out) => neuspike_simd::dispatch(
                #[inline(always)]
                || {
                    for (d, s) in out.iter_mut().zip(sums.iter()) {
                        *d = (s[0] + s[1] * unscale) as f32;
                    }
                },
            ),
            None => {
                for (d, s) in plane.iter_mut().zip(sums.iter()) {
                    *d = (s[0] + s[1] * unscale) as f32;
                }
            }
        }
        // For `tau -> 0`, the events at `t_k` leave `G` once the instants move past `t_k` (a
        // repeated instant counts them again).
        if matches!(decay, Decay::Instant) && ts_ns.get(k + 1) != Some(&t_k) {
            let done = events.len() - rest.len();
            let at_t_k = events.range(uncleared..done);
            for (&x, &y) in at_t_k.x.iter().zip(at_t_k.y) {
                sums[(usize::from(y) - y0) * w + usize::from(x)][1] = 0.0;
            }
            uncleared = done;
        }
    }
}

/// Events per batch of [`integrate_block`]: three arrays of 8-byte values, 24 KiB in all.
const BATCH: usize = 1 << 10;

/// `(t_k - t_base) / tau` beyond which [`integrate_block`] rebases: `e^500` is about `1.4e217`.
const REBASE_AT: f64 = 500.0;

/// One batch of a channel's events in a block: pixel (index in the block), polarity as `±1.0`,
/// and the weight added to `G`.
#[derive(Default)]
struct ChannelBatch {
    pixel: Vec<usize>,
    sign: Vec<f64>,
    weight: Vec<f64>,
}

impl ChannelBatch {
    /// The batch of `events` (all at or before `t_k`, in rows `y0..` of a sensor `w` wide):
    /// `weight = sign * scale * exp(-(t_k - t_i) / tau)`, with the limits of [`Decay`]:
    /// `tau -> 0` keeps only `t_i = t_k` (weight ±1), `tau = inf` weighs every event ±1 (`scale`
    /// is 1 for both).
    fn fill(
        &mut self,
        events: EventSlice,
        t_k: i64,
        y0: usize,
        w: usize,
        decay: Decay,
        scale: f64,
    ) {
        let n = events.len();
        self.pixel.resize(n, 0);
        self.sign.resize(n, 0.0);
        self.weight.resize(n, 0.0);
        let (pixel, sign, weight) = (&mut self.pixel, &mut self.sign, &mut self.weight);
        // `0 <= t_k - t_i < 2^52` for every event when it holds for the earliest: then the
        // difference converts to f64 exactly through its bits (vectorises without AVX-512 DQ).
        let fits = events
            .t_ns
            .first()
            .is_none_or(|&t| t_k.checked_sub(t).is_some_and(|dt| dt < 1 << 52));
        neuspike_simd::dispatch(
            #[inline(always)]
            || {
                for ((p, &x), &y) in pixel.iter_mut().zip(events.x).zip(events.y) {
                    *p = (usize::from(y) - y0) * w + usize::from(x);
                }
                for (s, &q) in sign.iter_mut().zip(events.polarity) {
                    *s = f64::from(q);
                }
                if fits {
                    const TWO_52: f64 = 4_503_599_627_370_496.0;
                    for (d, &t) in weight.iter_mut().zip(events.t_ns) {
                        *d = f64::from_bits((t_k - t) as u64 | TWO_52.to_bits()) - TWO_52;
                    }
                }
            },
        );
        if !fits {
            for (d, &t) in weight.iter_mut().zip(events.t_ns) {
                *d = (i128::from(t_k) - i128::from(t)) as f64;
            }
        }
        match decay {
            Decay::Instant => {
                for (d, &s) in weight.iter_mut().zip(sign.iter()) {
                    *d = if *d == 0.0 { s } else { 0.0 };
                }
            }
            Decay::Never => weight.copy_from_slice(sign),
            // A product with -1 / tau, not a division (several times the cost): the argument is
            // off by at most an ulp, the weight by `|dt / tau| * 2^-52` relative. `dt = 0` still
            // gives exactly 1: `Decay::new` takes a tau whose inverse overflows as `tau -> 0`.
            Decay::Exp(tau) => {
                let minus_inv = -1.0 / tau;
                neuspike_simd::dispatch(
                    #[inline(always)]
                    || {
                        for (d, &s) in weight.iter_mut().zip(sign.iter()) {
                            *d = (s * scale) * exp_neg(*d * minus_inv);
                        }
                    },
                )
            }
        }
    }
}

/// Events below which one rayon task of [`event_count_into`] does not go.
const MIN_EVENTS_PER_TASK: usize = 1 << 15;

/// The events of a band of rows, in time order: a copy of the columns, picked without branches
/// (every event is written, the write position moves on only for the band's).
struct Band {
    t_ns: Vec<i64>,
    x: Vec<u16>,
    y: Vec<u16>,
    polarity: Vec<i8>,
}

impl Band {
    fn of(events: EventSlice, rows: Range<usize>) -> Self {
        let n = events.len();
        let mut band = Band {
            t_ns: vec![0; n + 1],
            x: vec![0; n + 1],
            y: vec![0; n + 1],
            polarity: vec![0; n + 1],
        };
        let (lo, hi) = (rows.start, rows.end);
        let mut kept = 0;
        for i in 0..n {
            let y = events.y[i];
            band.t_ns[kept] = events.t_ns[i];
            band.x[kept] = events.x[i];
            band.y[kept] = y;
            band.polarity[kept] = events.polarity[i];
            kept += usize::from((lo..hi).contains(&usize::from(y)));
        }
        band.t_ns.truncate(kept);
        band.x.truncate(kept);
        band.y.truncate(kept);
        band.polarity.truncate(kept);
        band
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

// ---------------------------------------------------------------------------------------------
// Event count
// ---------------------------------------------------------------------------------------------

/// Signed event count per pixel over all events given: ON adds 1, OFF subtracts 1.
///
/// `dst` is `[H, W]`, the sensor. Counts are exact integers (kept in `i64`, written as `f32`,
/// exact up to `2^24` in magnitude). No events give zeros. Time is not looked at beyond the
/// sortedness check: the caller slices the window.
///
/// # Errors
/// As [`EventSlice::validate`]: unequal slice lengths (`Shape`), unsorted times or a polarity not
/// ±1 (`Param`), an event outside the sensor (`Index`, naming the event and coordinate).
pub fn event_count_into(events: EventSlice, dst: ArrayViewMut2<f32>) -> Result<(), RepresentError> {
    let (h, w) = dst.dim();
    events.validate(h, w)?;
    let parallel = events.len() >= MIN_ELEMENTS_FOR_RAYON;
    count_fast(events, dst, MIN_EVENTS_PER_TASK, parallel);
    Ok(())
}

/// Scalar oracle for [`event_count_into`].
#[doc(hidden)]
pub fn event_count_reference(
    events: EventSlice,
    mut dst: ArrayViewMut2<f32>,
) -> Result<(), RepresentError> {
    let (h, w) = dst.dim();
    events.validate(h, w)?;
    let mut on = vec![0i64; h * w];
    let mut off = vec![0i64; h * w];
    for i in 0..events.len() {
        let p = usize::from(events.y[i]) * w + usize::from(events.x[i]);
        if events.polarity[i] > 0 {
            on[p] += 1;
        } else {
            off[p] += 1;
        }
    }
    for y in 0..h {
        for x in 0..w {
            dst[[y, x]] = (on[y * w + x] - off[y * w + x]) as f32;
        }
    }
    Ok(())
}

/// Fast signed count: the events split into at most one contiguous run per rayon thread (each at
/// least `min_events_per_task` long), one `i64` histogram per run, histograms summed. Exact, so
/// identical to the reference. Checked by the caller.
fn count_fast(
    events: EventSlice,
    mut dst: ArrayViewMut2<f32>,
    min_events_per_task: usize,
    parallel: bool,
) {
    let (h, w) = dst.dim();
    let n = events.len();
    let histogram = |range: Range<usize>| {
        let mut counts = vec![0i64; h * w];
        for i in range {
            let p = usize::from(events.y[i]) * w + usize::from(events.x[i]);
            counts[p] += i64::from(events.polarity[i]);
        }
        counts
    };
    let min_run = min_events_per_task.max(1);
    let counts = if parallel && n > min_run {
        let run = n.div_ceil(rayon::current_num_threads()).max(min_run);
        (0..n.div_ceil(run))
            .into_par_iter()
            .map(|r| histogram(r * run..((r + 1) * run).min(n)))
            .reduce_with(|mut a, b| {
                for (x, y) in a.iter_mut().zip(&b) {
                    *x += y;
                }
                a
            })
            .unwrap_or_else(|| vec![0; h * w])
    } else {
        histogram(0..n)
    };
    match dst.as_slice_mut() {
        Some(out) => {
            for (d, &c) in out.iter_mut().zip(&counts) {
                *d = c as f32;
            }
        }
        None => {
            for (d, &c) in dst.iter_mut().zip(&counts) {
                *d = c as f32;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::Events;
    use ndarray::{Array2, Array3};
    use proptest::prelude::*;

    fn integrate(e: &Events, t0: i64, ts: &[i64], tau: f64, h: usize, w: usize) -> Array3<f32> {
        let mut v = Array3::from_elem((ts.len(), h, w), f32::NAN);
        event_integration_into(e.slice(), t0, ts, tau, v.view_mut()).expect("integration");
        let mut r = Array3::from_elem((ts.len(), h, w), f32::NAN);
        event_integration_reference(e.slice(), t0, ts, tau, r.view_mut()).expect("reference");
        for (a, b) in v.iter().zip(&r) {
            assert!(
                (a - b).abs() <= 1e-6 * (1.0 + b.abs()),
                "fast {a} vs reference {b}"
            );
        }
        v
    }

    fn count(e: &Events, h: usize, w: usize) -> Array2<f32> {
        let mut c = Array2::from_elem((h, w), f32::NAN);
        event_count_into(e.slice(), c.view_mut()).expect("count");
        c
    }

    /// A few events over a 2 x 3 sensor, none exactly at the instants used below.
    fn scene() -> Events {
        Events::from(&[
            (100, 0, 0, 1),
            (150, 2, 1, -1),
            (200, 0, 0, 1),
            (250, 1, 1, 1),
            (300, 0, 0, -1),
            (350, 2, 1, -1),
            (420, 1, 0, 1),
        ])
    }

    #[test]
    fn tau_to_zero_gives_the_plain_count_and_infinity_doubles_it() {
        let e = scene();
        let c = count(&e, 2, 3);
        for tau in [0.0, -5.0, f64::NEG_INFINITY, 1e-300] {
            let v = integrate(&e, 0, &[1_000], tau, 2, 3);
            assert_eq!(v.index_axis(Axis(0), 0), c, "tau = {tau}");
        }
        let v = integrate(&e, 0, &[1_000], f64::INFINITY, 2, 3);
        assert_eq!(v.index_axis(Axis(0), 0), c.mapv(|n| 2.0 * n));
        assert_eq!(c[[0, 0]], 1.0);
        assert_eq!(c[[1, 2]], -2.0);
    }

    #[test]
    fn single_event_decays_to_one_plus_exp_minus_one_after_tau() {
        let e = Events::from(&[(1_000, 0, 0, 1)]);
        let v = integrate(&e, 0, &[1_000, 1_500, 2_000], 500.0, 1, 1);
        assert_eq!(v[[0, 0, 0]], 2.0);
        assert!((f64::from(v[[1, 0, 0]]) - (1.0 + (-1.0f64).exp())).abs() < 1e-6);
        assert!((f64::from(v[[2, 0, 0]]) - (1.0 + (-2.0f64).exp())).abs() < 1e-6);
        let off = Events::from(&[(1_000, 0, 0, -1)]);
        let v = integrate(&off, 0, &[1_500], 500.0, 1, 1);
        assert!((f64::from(v[[0, 0, 0]]) + (1.0 + (-1.0f64).exp())).abs() < 1e-6);
    }

    #[test]
    fn events_at_identical_timestamps_all_count() {
        let e = Events::from(&[
            (700, 0, 0, 1),
            (700, 0, 0, 1),
            (700, 0, 0, 1),
            (700, 1, 0, -1),
        ]);
        let v = integrate(&e, 700, &[700, 700, 1_200], 500.0, 1, 2);
        // At the instant itself every event weighs 1 + exp(0) = 2, also in the tau -> 0 limit.
        assert_eq!(
            v.slice(ndarray::s![0..2, 0, ..]).to_owned(),
            ndarray::array![[6.0, -2.0], [6.0, -2.0]]
        );
        let expected = 3.0 * (1.0 + (-1.0f64).exp());
        assert!((f64::from(v[[2, 0, 0]]) - expected).abs() < 1e-5);
        let v = integrate(&e, 0, &[700, 701], 0.0, 1, 2);
        assert_eq!(v.index_axis(Axis(0), 0), ndarray::array![[6.0, -2.0]]);
        assert_eq!(v.index_axis(Axis(0), 1), ndarray::array![[3.0, -1.0]]);
    }

    #[test]
    fn on_and_off_cancel() {
        let e = Events::from(&[(10, 0, 0, 1), (10, 0, 0, -1), (20, 0, 0, -1), (30, 0, 0, 1)]);
        let v = integrate(&e, 0, &[10, 30, 100], 20.0, 1, 1);
        assert_eq!(v[[0, 0, 0]], 0.0);
        assert_eq!(count(&e, 1, 1)[[0, 0]], 0.0);
        // At 30: counts cancel; decayed parts 1 - exp(-0.5) (the ON at 30 against the OFF at 20).
        let expected = 1.0 - (-0.5f64).exp();
        assert!((f64::from(v[[1, 0, 0]]) - expected).abs() < 1e-6);
        let v = integrate(&e, 0, &[100], f64::INFINITY, 1, 1);
        assert_eq!(v[[0, 0, 0]], 0.0);
    }

    #[test]
    fn window_start_and_channel_instants_are_inclusive() {
        let e = Events::from(&[
            (99, 0, 0, 1),
            (100, 0, 0, 1),
            (200, 0, 0, 1),
            (201, 0, 0, 1),
        ]);
        let v = integrate(&e, 100, &[50, 100, 200, 10_000], f64::INFINITY, 1, 1);
        let got: Vec<f32> = v.iter().copied().collect();
        assert_eq!(got, vec![0.0, 2.0, 4.0, 6.0]);
    }

    #[test]
    fn zero_events_give_zeros() {
        let e = Events::default();
        let v = integrate(&e, 0, &[0, 5, 9], 3.0, 2, 4);
        assert!(v.iter().all(|&x| x == 0.0));
        assert!(count(&e, 2, 4).iter().all(|&x| x == 0.0));
        let mut empty = Array3::<f32>::zeros((0, 2, 4));
        event_integration_into(e.slice(), 0, &[], 3.0, empty.view_mut()).expect("K = 0");
    }

    #[test]
    fn timestamps_near_the_ends_of_i64_do_not_overflow() {
        let e = Events::from(&[
            (i64::MIN, 0, 0, 1),
            (i64::MAX - 10, 0, 0, 1),
            (i64::MAX, 0, 0, -1),
        ]);
        let v = integrate(
            &e,
            i64::MIN,
            &[i64::MIN, i64::MAX - 10, i64::MAX],
            10.0,
            1,
            1,
        );
        assert_eq!(v[[0, 0, 0]], 2.0);
        assert_eq!(v[[1, 0, 0]], 3.0); // the first has decayed over ~2^64 ns to nothing
        let expected = 2.0 + (-1.0f64).exp() - 2.0;
        assert!((f64::from(v[[2, 0, 0]]) - expected).abs() < 1e-6);
        assert!(v.iter().all(|x| x.is_finite()));
        let v = integrate(&e, i64::MIN, &[i64::MAX], f64::MAX, 1, 1);
        assert!(v.iter().all(|x| x.is_finite()));
    }

    #[test]
    fn bad_inputs_are_errors_naming_the_value() {
        let e = Events::from(&[(1, 0, 0, 1), (2, 3, 0, 1)]);
        let mut v = Array3::<f32>::zeros((1, 2, 3));
        let err = event_integration_into(e.slice(), 0, &[5], 1.0, v.view_mut()).expect_err("x");
        assert!(
            matches!(
                &err,
                RepresentError::Index {
                    value: 3,
                    limit: 3,
                    ..
                }
            ),
            "{err}"
        );
        assert!(err.to_string().contains("x of event 1"), "{err}");

        let e = Events::from(&[(1, 0, 2, 1)]);
        let mut c = Array2::<f32>::zeros((2, 3));
        let err = event_count_into(e.slice(), c.view_mut()).expect_err("y");
        assert!(err.to_string().contains("y of event 0 = 2"), "{err}");

        let e = Events::from(&[(5, 0, 0, 1), (4, 0, 0, 1)]);
        let err = event_count_into(e.slice(), c.view_mut()).expect_err("unsorted");
        assert!(err.to_string().contains("t_ns[1] = 4"), "{err}");

        let e = Events::from(&[(5, 0, 0, 0)]);
        let err = event_count_into(e.slice(), c.view_mut()).expect_err("polarity");
        assert!(err.to_string().contains("polarity[0] = 0"), "{err}");

        let mut e = Events::from(&[(5, 0, 0, 1)]);
        e.x.push(1);
        let err = event_count_into(e.slice(), c.view_mut()).expect_err("lengths");
        assert!(matches!(err, RepresentError::Shape { .. }), "{err}");

        let e = scene();
        let err = event_integration_into(e.slice(), 0, &[5, 6], 1.0, v.view_mut()).expect_err("K");
        assert!(matches!(err, RepresentError::Shape { .. }), "{err}");
        let mut v2 = Array3::<f32>::zeros((2, 2, 3));
        let err =
            event_integration_into(e.slice(), 0, &[6, 5], 1.0, v2.view_mut()).expect_err("ts");
        assert!(err.to_string().contains("ts_ns[1] = 5"), "{err}");
        let err =
            event_integration_into(e.slice(), 0, &[5], f64::NAN, v.view_mut()).expect_err("tau");
        assert!(err.to_string().contains("tau_ns = NaN"), "{err}");
    }

    #[test]
    fn large_input_takes_the_rayon_path_and_matches() {
        let (h, w, n) = (37, 50, 70_000usize);
        let mut e = Events::default();
        for i in 0..n {
            e.t_ns.push(i as i64 * 3);
            e.x.push(((i * 7919) % w) as u16);
            e.y.push(((i * 104_729) % h) as u16);
            e.polarity.push(if i.is_multiple_of(3) { -1 } else { 1 });
        }
        let ts: Vec<i64> = (1..=8).map(|k| k * 25_000).collect();
        let serial = integrate(&e, 1_000, &ts, 20_000.0, h, w);
        // Forced onto 5 threads, whatever the machine: the bands must give the same bits.
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(5)
            .build()
            .expect("pool");
        let banded = pool.install(|| integrate(&e, 1_000, &ts, 20_000.0, h, w));
        assert_eq!(banded, serial);
        let mut c = Array2::<f32>::zeros((h, w));
        event_count_reference(e.slice(), c.view_mut()).expect("ref");
        assert_eq!(count(&e, h, w), c);
    }

    /// Random sorted events on a small sensor, sorted channel instants and a decay of each kind.
    fn case() -> impl Strategy<Value = (Events, usize, usize, i64, Vec<i64>, f64)> {
        (1usize..6, 1usize..7, 0usize..40).prop_flat_map(|(h, w, n)| {
            let event = (
                0i64..200,
                0..w as u16,
                0..h as u16,
                prop_oneof![Just(1i8), Just(-1i8)],
            );
            (
                proptest::collection::vec(event, n),
                Just((h, w)),
                -20i64..100,
                proptest::collection::vec(0i64..220, 0..5),
                // Small taus make `integrate_block` rebase (gaps past 500 tau); 1e-300 is a tau
                // whose inverse overflows.
                prop_oneof![
                    Just(0.0),
                    Just(-1.0),
                    Just(f64::INFINITY),
                    Just(1e-300),
                    0.01f64..0.5,
                    0.5f64..500.0
                ],
            )
                .prop_map(|(mut list, (h, w), t0, mut ts, tau)| {
                    list.sort_by_key(|e| e.0);
                    ts.sort_unstable();
                    (Events::from(&list), h, w, t0, ts, tau)
                })
        })
    }

    /// Events that break one invariant now and then: a time step back, a coordinate one past
    /// the sensor, a polarity of 0 or ±2, a missing element; several blocks long at times.
    fn maybe_invalid() -> impl Strategy<Value = (Events, usize, usize)> {
        (
            1usize..4,
            1usize..4,
            prop_oneof![0usize..20, 4_000usize..9_000],
        )
            .prop_flat_map(|(h, w, n)| {
                let event = (0i64..3, 0..=w as u16, 0..=h as u16, -2i8..=2);
                (
                    proptest::collection::vec(event, n),
                    any::<bool>(),
                    0usize..4,
                    Just((h, w)),
                )
                    .prop_map(|(list, cut, which, (h, w))| {
                        // Mostly valid: clamp all but a few rare offenders back into range.
                        let mut t = 0i64;
                        let mut e = Events::default();
                        for (k, (dt, x, y, p)) in list.into_iter().enumerate() {
                            let rare = k % 997 == 3 && cut;
                            t += if rare && which == 0 { -1 } else { dt };
                            let x = if rare && which == 1 {
                                x
                            } else {
                                x.min(w as u16 - 1)
                            };
                            let y = if rare && which == 2 {
                                y
                            } else {
                                y.min(h as u16 - 1)
                            };
                            let p = if rare && which == 3 {
                                p
                            } else if p < 0 {
                                -1
                            } else {
                                1
                            };
                            e.push(t, x, y, p);
                        }
                        if cut && which == 0 && !e.y.is_empty() && e.t_ns.len() % 2 == 0 {
                            e.y.pop();
                        }
                        (e, h, w)
                    })
            })
    }

    /// Thousands of events per channel (several batches), channels far apart against tau (the
    /// sums rebase) or close (they do not), many events on few pixels.
    #[test]
    fn integration_over_batches_and_rebases_matches_the_reference() {
        let (h, w, n) = (3, 5, 7_000);
        let mut list: Vec<(i64, u16, u16, i8)> = (0..n)
            .map(|i| {
                let i = i as u64;
                let t = (i * 997 % 1_000_003) as i64;
                (
                    t,
                    (i * 7 % 5) as u16,
                    (i * 11 % 3) as u16,
                    if i.is_multiple_of(3) { -1 } else { 1 },
                )
            })
            .collect();
        list.sort_by_key(|e| e.0);
        let e = Events::from(&list);
        let ts: Vec<i64> = (1..=8).map(|k| k * 125_000).collect();
        for tau in [50.0, 300.0, 1e5, 1e9, 0.0, f64::INFINITY] {
            let mut slow = Array3::<f32>::zeros((8, h, w));
            event_integration_reference(e.slice(), 0, &ts, tau, slow.view_mut()).expect("ref");
            let mut fast = Array3::<f32>::from_elem((8, h, w), f32::NAN);
            event_integration_into(e.slice(), 0, &ts, tau, fast.view_mut()).expect("fast");
            for (a, b) in fast.iter().zip(&slow) {
                assert!(
                    (a - b).abs() <= 1e-9 * n as f32 + 1e-6 * b.abs(),
                    "tau {tau}: {a} vs {b}"
                );
            }
        }
    }

    #[test]
    fn a_repeated_instant_weighs_the_events_at_it_each_time_with_tau_zero() {
        // Two ON events at 0 ns and one at 100 ns, all at one pixel; the instant 100 ns twice.
        let e = EventSlice {
            t_ns: &[0, 0, 100],
            x: &[0; 3],
            y: &[0; 3],
            polarity: &[1; 3],
        };
        let ts = [100, 100, 200];
        let mut slow = Array3::<f32>::zeros((3, 1, 1));
        event_integration_reference(e, 0, &ts, 0.0, slow.view_mut()).expect("reference");
        let mut fast = Array3::<f32>::from_elem((3, 1, 1), f32::NAN);
        event_integration_into(e, 0, &ts, 0.0, fast.view_mut()).expect("fast");
        // At 100 ns: 1 + 1 for the earlier events, 1 + exp(0) = 2 for the one at the instant.
        assert_eq!(fast.as_slice(), Some(&[4.0, 4.0, 3.0][..]));
        assert_eq!(fast, slow);
    }

    proptest! {
        #[test]
        fn quick_validation_agrees_with_the_event_by_event_checks((e, h, w) in maybe_invalid()) {
            let s = e.slice();
            prop_assert_eq!(s.is_valid(h, w), s.first_violation(h, w).is_ok());
            prop_assert_eq!(s.validate(h, w).is_ok(), s.first_violation(h, w).is_ok());
            // A sensor bigger than any u16 coordinate accepts every coordinate.
            if s.first_violation(h, w).is_ok() {
                prop_assert!(s.is_valid(70_000, 70_000));
            }
        }

        #[test]
        fn integration_fast_matches_reference(
            (e, h, w, t0, ts, tau) in case(), rows in 1usize..4, par in any::<bool>()
        ) {
            let k = ts.len();
            let mut slow = Array3::<f32>::zeros((k, h, w));
            event_integration_reference(e.slice(), t0, &ts, tau, slow.view_mut()).expect("ref");
            let (decay, window) = check_integration(e.slice(), t0, &ts, tau, (k, h, w)).expect("ok");
            let mut fast = Array3::<f32>::from_elem((k, h, w), f32::NAN);
            integration_fast(e.slice(), window, &ts, decay, fast.view_mut(), par.then_some(rows));
            // Tolerance: 1e-5 absolute per unit of |value| bound (2 per event at the pixel).
            let bound = 2.0 * e.t_ns.len() as f32 + 1.0;
            for (a, b) in fast.iter().zip(&slow) {
                prop_assert!(a.is_finite());
                prop_assert!((a - b).abs() <= 1e-6 * bound, "fast {} vs reference {}", a, b);
                prop_assert!(b.abs() <= bound);
            }
        }

        #[test]
        fn count_fast_matches_reference_exactly(
            (e, h, w, _t0, _ts, _tau) in case(), run in 1usize..8, par in any::<bool>()
        ) {
            let mut slow = Array2::<f32>::zeros((h, w));
            event_count_reference(e.slice(), slow.view_mut()).expect("ref");
            let mut fast = Array2::<f32>::from_elem((h, w), f32::NAN);
            count_fast(e.slice(), fast.view_mut(), run, par);
            prop_assert_eq!(&fast, &slow);
            prop_assert_eq!(fast.sum(), e.polarity.iter().map(|&p| f32::from(p)).sum::<f32>());
        }

        #[test]
        fn infinite_tau_is_twice_tau_zero_away_from_the_instants(
            (e, h, w, t0, ts, _tau) in case()
        ) {
            // Shift the instants off the event grid (events at even times, instants odd).
            let e = Events { t_ns: e.t_ns.iter().map(|t| 2 * t).collect(), ..e };
            let ts: Vec<i64> = ts.iter().map(|t| 2 * t + 1).collect();
            let k = ts.len();
            let mut zero = Array3::<f32>::zeros((k, h, w));
            let mut inf = Array3::<f32>::zeros((k, h, w));
            event_integration_into(e.slice(), t0, &ts, 0.0, zero.view_mut()).expect("zero");
            event_integration_into(e.slice(), t0, &ts, f64::INFINITY, inf.view_mut()).expect("inf");
            prop_assert_eq!(inf, zero.mapv(|v| 2.0 * v));
        }
    }

    #[test]
    fn integration_instants_end_at_the_window_end_and_survive_degenerate_windows() {
        assert_eq!(integration_instants(100, 500, 4), vec![200, 300, 400, 500]);
        assert_eq!(integration_instants(0, 10, 3), vec![3, 7, 10]);
        assert!(integration_instants(0, 10, 0).is_empty());
        assert_eq!(integration_instants(50, 50, 2), vec![50, 50]);
        assert_eq!(integration_instants(50, 10, 2), vec![50, 50]);
        let far = integration_instants(i64::MAX - 10, i64::MAX, 2);
        assert_eq!(far, vec![i64::MAX - 5, i64::MAX]);
    }
}
