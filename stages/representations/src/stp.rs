//! TFSTP, texture from short-term plasticity (Zheng et al., "High-speed image reconstruction
//! through short-term plasticity for spiking cameras", CVPR 2021; SpikeCV's `TFSTP`).
//!
//! Each pixel's spikes drive a Tsodyks-Markram synapse. At a spike that comes `dt` ticks after the
//! pixel's previous one, the synapse's available resources `R` and release probability `u` become
//!
//! ```text
//! R' = 1 - (1 - R (1 - u)) exp(-dt / D)
//! u' = U + (u + f (1 - u) - U) exp(-dt / F)
//! ```
//!
//! Under a constant interval `dt` both settle where `exp(-dt / D) = (1 - R) / (1 - R (1 - u))`
//! and `exp(-dt / F) = (u - U) / (u + f (1 - u) - U)`, so each variable, inverted, gives the
//! firing rate `1 / dt`:
//!
//! ```text
//! rate_R = -1 / (D ln((1 - R) / (1 - R (1 - u))))
//! rate_u = -1 / (F ln((u - U) / (u + f (1 - u) - U)))
//! ```
//!
//! The estimate is their mean, in spikes per tick like TFP: `R` follows the latest intervals
//! (`D` is one tick), `u` averages over about `F / dt` of them, so the synapse smooths the noise
//! of single intervals (TFI) without a fixed window (TFP). Defaults are SpikeCV's TFSTP:
//! `U = 0.15`, `f = 0.15`, `D = 1` tick, `F = 10` ticks ([`StpParams::default`]).
//!
//! Numerics. The state is kept as `a = 1 - R` and `b = u - U` in `f64`: a long interval drives `R`
//! to 1 and `u` to `U`, where `1 - R` and `u - U` computed from `R` and `u` would cancel to 0, while
//! `a` and `b` keep full relative precision until they underflow (intervals beyond about
//! `745 D` and `745 F` ticks). Every division has a denominator of at least `min(U, f)` (stated at
//! each one); a logarithm's argument is in `(0, 1)`, and `0` (an underflowed variable) gives no
//! estimate from that variable rather than `-inf`.
//!
//! Conventions where this differs from SpikeCV (so figures compare knowingly):
//! - A pixel's first spike only starts its clock (SpikeCV counts an interval from tick 0). Its
//!   first interval sets the synapse to that interval's fixed point (a warm start), so the
//!   estimate is right from the first interval instead of converging over about ten spikes from
//!   `R = 1, u = U`. An interval so long that `b` underflowed warm-starts again.
//! - `rate_u` uses the fixed point's denominator `u + f (1 - u) - U`; SpikeCV's code has
//!   `F - U + u (1 - f)` (the time constant `F` where the fixed point has the increment `f`).
//! - The rate is calibrated (spikes per tick) where SpikeCV stretches each image to `[0, 255]` and
//!   equalises its histogram; the infer node turns it into luminance as it does TFP's.
//! - The estimate is capped at `1 / (ticks since the last spike)`: a pixel that went dark reads
//!   dark once its expected interval has passed, where the synapse alone would hold its last
//!   bright estimate until the next spike.
//! - Rates are at most 1 (a pixel fires at most once per tick) and 0 for a pixel without an
//!   interval yet.
//!
//! [`StpFilter`] is the stateful filter a node keeps across windows; it feeds each plane once,
//! whatever the windows' overlap, and counts the gaps between them. [`StpFilter::advance_packed`]
//! is the fast path (packed planes, 64 pixels a word, only firing pixels touched, decays from a
//! table); [`StpFilter::advance_reference`] the scalar oracle (one pixel at a time, `exp` per
//! interval). Both give bit-identical states (tested).

use std::collections::VecDeque;

use ndarray::{ArrayView3, ArrayViewMut2};

use crate::error::{RepresentError, shape_str};

/// The synapse's parameters; times in ticks (plane periods).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StpParams {
    /// `U`: the release probability at rest, in `(0, 1)`.
    pub u0: f64,
    /// `f`: the facilitation increment per spike, in `(0, 1]`.
    pub f: f64,
    /// `D`: the resources' recovery time constant, ticks, finite and `> 0`.
    pub tau_d_ticks: f64,
    /// `F`: the facilitation's decay time constant, ticks, finite and `> 0`.
    pub tau_f_ticks: f64,
}

impl Default for StpParams {
    /// SpikeCV's TFSTP: `U = 0.15`, `f = 0.15`, `D = 1`, `F = 10` ticks.
    fn default() -> Self {
        StpParams {
            u0: 0.15,
            f: 0.15,
            tau_d_ticks: 1.0,
            tau_f_ticks: 10.0,
        }
    }
}

impl StpParams {
    /// Checks every parameter's domain.
    ///
    /// # Errors
    /// [`RepresentError::Param`] naming the first parameter out of its domain.
    pub fn check(&self) -> Result<(), RepresentError> {
        let bad = |name, v: f64, reason| {
            Err(RepresentError::Param {
                name,
                value: v.to_string(),
                reason,
            })
        };
        if !(self.u0 > 0.0 && self.u0 < 1.0) {
            return bad("stp u0 (U)", self.u0, "must be in (0, 1)");
        }
        if !(self.f > 0.0 && self.f <= 1.0) {
            return bad("stp f", self.f, "must be in (0, 1]");
        }
        for (name, v) in [
            ("stp tau_d_ticks (D)", self.tau_d_ticks),
            ("stp tau_f_ticks (F)", self.tau_f_ticks),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(name, v, "must be finite and > 0");
            }
        }
        Ok(())
    }

    /// `(exp(-dt / D), exp(-dt / F))` for an interval of `dt >= 1` ticks: the one expression both
    /// paths use (the fast path tabulates it), in `[0, 1)`; 0 where it underflows.
    #[inline]
    fn decays(&self, dt: u64) -> (f64, f64) {
        let dt = dt as f64;
        (
            (-dt / self.tau_d_ticks).exp(),
            (-dt / self.tau_f_ticks).exp(),
        )
    }
}

/// One pixel's synapse: `a = 1 - R`, `b = u - U`, and the plane of its latest spike plus one (0:
/// none since the start or the last gap).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Synapse {
    a: f64,
    b: f64,
    last: u64,
}

impl Synapse {
    /// A spike at plane `plane`, with the decays of its interval when it has one.
    #[inline(always)]
    fn fire(&mut self, plane: u64, p: &StpParams, decays: impl FnOnce(u64) -> (f64, f64)) {
        if self.last != 0 {
            // `plane >= last` since planes come in increasing order: dt >= 1.
            let (ed, ef) = decays(plane + 1 - self.last);
            if self.b > 0.0 {
                let u = p.u0 + self.b;
                self.a = (self.a + (1.0 - self.a) * u) * ed;
                self.b = (self.b + p.f * (1.0 - u)) * ef;
            } else {
                // Warm start at the interval's fixed point. Denominators: `1 - ef (1 - f) >= f`
                // and `1 - ed (1 - u) >= u >= U`, both > 0.
                let b = p.f * (1.0 - p.u0) * ef / (1.0 - ef * (1.0 - p.f));
                let u = p.u0 + b;
                self.a = u * ed / (1.0 - ed * (1.0 - u));
                self.b = b;
            }
        }
        self.last = plane + 1;
    }

    /// The rate estimate, spikes per tick in `[0, 1]`, read at plane `now`.
    #[inline]
    fn rate(&self, now: u64, p: &StpParams) -> f64 {
        if self.b <= 0.0 {
            return 0.0;
        }
        // An interval `-tau ln(x)` from a ratio `x` in (0, 1]; the rate is its inverse, at most
        // one spike per tick (so `x` rounding to 1 gives 1, not infinity).
        let rate_of = |x: f64, tau: f64| 1.0 / (-tau * x.ln()).max(1.0);
        let u = p.u0 + self.b;
        // Denominator `b + f (1 - u) >= b > 0`.
        let mut rate = rate_of(self.b / (self.b + p.f * (1.0 - u)), p.tau_f_ticks);
        if self.a > 0.0 {
            // Denominator `a + (1 - a) u >= min(a, u) > 0` (a convex combination of 1 and u).
            let r = rate_of(self.a / (self.a + (1.0 - self.a) * u), p.tau_d_ticks);
            rate = 0.5 * (rate + r);
        }
        if self.last != 0 && now + 1 > self.last {
            rate = rate.min(1.0 / (now + 1 - self.last) as f64);
        }
        rate
    }
}

/// Intervals (ticks) whose decays [`StpFilter`] tabulates; longer ones are computed.
const DECAY_TABLE: usize = 1024;

/// TFSTP's per-pixel synapses, fed plane by plane across windows (see the module docs).
#[derive(Clone, Debug)]
pub struct StpFilter {
    height: usize,
    width: usize,
    params: StpParams,
    synapses: Vec<Synapse>,
    /// `decays(dt)` for `dt < DECAY_TABLE` (index 0 unused).
    table: Vec<(f64, f64)>,
    /// The latest plane fed.
    last_fed: Option<u64>,
    /// Planes received after the `through` of their call, fed first by the next call.
    pending: VecDeque<(u64, Vec<u8>)>,
    gaps: u64,
}

impl StpFilter {
    /// Synapses at rest for a `height` x `width` sensor.
    ///
    /// # Errors
    /// [`RepresentError::Param`] for a parameter out of its domain ([`StpParams::check`]).
    pub fn new(height: usize, width: usize, params: StpParams) -> Result<Self, RepresentError> {
        params.check()?;
        let table = (0..DECAY_TABLE as u64)
            .map(|dt| params.decays(dt))
            .collect();
        Ok(StpFilter {
            height,
            width,
            params,
            synapses: vec![Synapse::default(); height * width],
            table,
            last_fed: None,
            pending: VecDeque::new(),
            gaps: 0,
        })
    }

    /// The sensor's `(height, width)`.
    pub fn dim(&self) -> (usize, usize) {
        (self.height, self.width)
    }

    /// The latest plane fed, if any.
    pub fn last_fed(&self) -> Option<u64> {
        self.last_fed
    }

    /// Gaps seen: planes skipped between two fed planes. At a gap every pixel forgets its last
    /// spike (the interval across it is unknown) and keeps its synapse.
    pub fn gaps(&self) -> u64 {
        self.gaps
    }

    /// Feeds packed planes `first_plane .. first_plane + n_planes` (`bits` as a `SpikeChunk`
    /// carries them: `ceil(H W / 8)` bytes a plane, bit `k & 7` of byte `k >> 3` for pixel `k`
    /// row-major) up to and including plane `through_plane`. Planes after it are kept and fed by
    /// a later call (first, before that call's own planes), so a window's planes after its
    /// reference instant still count, once. Planes at or before the latest fed are skipped:
    /// overlapping windows feed each plane once. Bits past the `H W` pixels are ignored.
    ///
    /// # Errors
    /// - [`RepresentError::Shape`] when `bits` holds fewer than `n_planes` planes.
    /// - [`RepresentError::Param`] when the plane numbers would pass `u64::MAX - 1`.
    pub fn advance_packed(
        &mut self,
        bits: &[u8],
        first_plane: u64,
        n_planes: usize,
        through_plane: u64,
    ) -> Result<(), RepresentError> {
        let per = (self.height * self.width).div_ceil(8);
        check_planes(first_plane, n_planes, bits.len(), per)?;
        // The planes kept by the last call, then this call's; only those past `through_plane`
        // are copied (to be kept in turn).
        let kept = std::mem::take(&mut self.pending);
        let chunk = (0..n_planes).map(|k| (first_plane + k as u64, &bits[k * per..(k + 1) * per]));
        let mut words = vec![0u64; per.div_ceil(8)];
        for (plane, bits) in kept.iter().map(|(p, b)| (*p, b.as_slice())).chain(chunk) {
            if plane > through_plane {
                if self.pending.back().is_none_or(|&(p, _)| p < plane) {
                    self.pending.push_back((plane, bits.to_vec()));
                }
                continue;
            }
            if !self.enter(plane) {
                continue;
            }
            crate::spike::plane_words(bits, &mut words);
            self.fire_packed(plane, &words);
        }
        Ok(())
    }

    /// The scalar oracle of [`StpFilter::advance_packed`]: feeds unpacked planes `[N, H, W]`
    /// (nonzero = spike) numbered from `first_plane`, every one of them, one pixel at a time,
    /// with `exp` for every interval. Pending planes of the packed path are not used.
    ///
    /// # Errors
    /// - [`RepresentError::Shape`] when the planes are not `H x W`.
    /// - [`RepresentError::Param`] when the plane numbers would pass `u64::MAX - 1`.
    pub fn advance_reference(
        &mut self,
        spikes: ArrayView3<u8>,
        first_plane: u64,
    ) -> Result<(), RepresentError> {
        let (n, h, w) = spikes.dim();
        if (h, w) != (self.height, self.width) {
            return Err(RepresentError::Shape {
                what: "stp spike planes [N, H, W]",
                expected: shape_str(&[n, self.height, self.width]),
                actual: shape_str(&[n, h, w]),
            });
        }
        check_planes(first_plane, n, 0, 0)?;
        for (k, plane) in spikes.outer_iter().enumerate() {
            let plane_no = first_plane + k as u64;
            if !self.enter(plane_no) {
                continue;
            }
            for y in 0..h {
                for x in 0..w {
                    if plane[[y, x]] != 0 {
                        self.synapses[y * w + x]
                            .fire(plane_no, &self.params, |dt| self.params.decays(dt));
                    }
                }
            }
        }
        Ok(())
    }

    /// Writes the rate estimate (spikes per tick, `[0, 1]`) of every pixel at the latest plane
    /// fed into `dst` `[H, W]`; zeros before any plane.
    ///
    /// # Errors
    /// [`RepresentError::Shape`] when `dst` is not `[H, W]`.
    pub fn rate_into(&self, mut dst: ArrayViewMut2<f32>) -> Result<(), RepresentError> {
        if dst.dim() != (self.height, self.width) {
            return Err(RepresentError::Shape {
                what: "stp rate destination",
                expected: shape_str(&[self.height, self.width]),
                actual: shape_str(&[dst.dim().0, dst.dim().1]),
            });
        }
        let now = self.last_fed.unwrap_or(0);
        let p = self.params;
        match dst.as_slice_mut() {
            Some(out) => {
                for (d, s) in out.iter_mut().zip(&self.synapses) {
                    *d = s.rate(now, &p) as f32;
                }
            }
            None => {
                for ((y, x), d) in dst.indexed_iter_mut() {
                    *d = self.synapses[y * self.width + x].rate(now, &p) as f32;
                }
            }
        }
        Ok(())
    }

    /// Takes plane `plane` in: false when it was fed already; a gap before it makes every pixel
    /// forget its last spike.
    fn enter(&mut self, plane: u64) -> bool {
        match self.last_fed {
            Some(last) if plane <= last => return false,
            Some(last) if plane > last + 1 => {
                self.gaps += 1;
                self.synapses.iter_mut().for_each(|s| s.last = 0);
            }
            _ => {}
        }
        self.last_fed = Some(plane);
        true
    }

    /// Fires the pixels set in one plane's 64-pixel words: only nonzero words are visited, their
    /// set bits in order; bits past the last pixel are ignored.
    fn fire_packed(&mut self, plane: u64, words: &[u64]) {
        let pixels = self.synapses.len();
        let (p, table) = (self.params, &self.table);
        let decays = |dt: u64| match table.get(dt as usize) {
            Some(&d) => d,
            None => p.decays(dt),
        };
        for (i, &word) in words.iter().enumerate() {
            // Only the low `pixels - 64 i` bits of the last word are pixels.
            let mut bits = word & low_mask(pixels.saturating_sub(i * 64));
            while bits != 0 {
                let k = i * 64 + bits.trailing_zeros() as usize;
                bits &= bits - 1;
                self.synapses[k].fire(plane, &p, decays);
            }
        }
    }
}

/// The low `n` bits set (`n >= 64`: all).
fn low_mask(n: usize) -> u64 {
    if n >= 64 { u64::MAX } else { (1u64 << n) - 1 }
}

/// Checks that `n` planes numbered from `first` stay below `u64::MAX` (a pixel's last spike is
/// kept as its plane plus one) and, with `per > 0`, that `len` bytes hold them.
fn check_planes(first: u64, n: usize, len: usize, per: usize) -> Result<(), RepresentError> {
    if first
        .checked_add(n as u64)
        .is_none_or(|end| end == u64::MAX)
    {
        return Err(RepresentError::Param {
            name: "stp first plane",
            value: first.to_string(),
            reason: "plane numbers must stay below u64::MAX - 1",
        });
    }
    if per > 0 && len < n * per {
        return Err(RepresentError::Shape {
            what: "stp packed spike planes",
            expected: format!("at least {} bytes ({n} planes of {per})", n * per),
            actual: format!("{len} bytes"),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::{Array2, Array3, s};
    use neuspike_schemas::pack_planes;
    use proptest::prelude::*;

    /// `n` planes of `h x w` where pixel `(y, x)` fires at the planes `fires(y, x)` lists.
    fn planes(
        n: usize,
        h: usize,
        w: usize,
        fires: impl Fn(usize, usize, usize) -> bool,
    ) -> Array3<u8> {
        Array3::from_shape_fn((n, h, w), |(k, y, x)| u8::from(fires(k, y, x)))
    }

    fn rate(f: &StpFilter) -> Array2<f32> {
        let (h, w) = f.dim();
        let mut r = Array2::zeros((h, w));
        f.rate_into(r.view_mut()).unwrap();
        r
    }

    fn fed(spikes: &Array3<u8>, first: u64) -> StpFilter {
        let (n, h, w) = spikes.dim();
        let mut f = StpFilter::new(h, w, StpParams::default()).unwrap();
        f.advance_packed(&pack_planes(spikes.view()), first, n, u64::MAX - 1)
            .unwrap();
        f
    }

    #[test]
    fn a_constant_interval_reads_its_rate_from_the_first_interval_on() {
        for period in [1usize, 2, 4, 7, 30, 200, 900] {
            let n = 3 * period + 1;
            let s = planes(n, 1, 1, |k, _, _| k % period == 0);
            let mut f = StpFilter::new(1, 1, StpParams::default()).unwrap();
            // Read at every spike after the first interval: the warm start and the updates both
            // stay at the fixed point.
            for k in 0..n {
                f.advance_packed(
                    &pack_planes(s.slice(s![k..k + 1, .., ..])),
                    k as u64,
                    1,
                    k as u64,
                )
                .unwrap();
                if k >= period && k % period == 0 {
                    let r = f64::from(rate(&f)[[0, 0]]);
                    let want = 1.0 / period as f64;
                    assert!(
                        (r - want).abs() < 1e-6 * want,
                        "period {period} plane {k}: {r}"
                    );
                }
            }
        }
    }

    #[test]
    fn no_light_reads_zero_and_saturating_light_reads_one() {
        let dark = fed(&planes(1000, 2, 3, |_, _, _| false), 0);
        assert!(rate(&dark).iter().all(|&r| r == 0.0));
        let one_spike = fed(&planes(10, 1, 1, |k, _, _| k == 3), 0);
        assert_eq!(rate(&one_spike)[[0, 0]], 0.0, "one spike gives no interval");
        let bright = fed(&planes(1000, 2, 3, |_, _, _| true), 0);
        assert!(
            rate(&bright).iter().all(|&r| r == 1.0),
            "{:?}",
            rate(&bright)
        );
    }

    #[test]
    fn a_pixel_that_goes_dark_reads_at_most_one_over_the_time_since_its_last_spike() {
        // Fires every 2 ticks up to plane 100, then never again.
        let s = planes(400, 1, 1, |k, _, _| k <= 100 && k % 2 == 0);
        let f = fed(&s, 0);
        let r = rate(&f)[[0, 0]];
        assert_eq!(
            r,
            (1.0f64 / 299.0) as f32,
            "last spike at plane 100, read at plane 399"
        );
    }

    #[test]
    fn the_synapse_smooths_jittered_intervals_where_one_interval_does_not() {
        // Intervals alternate 3 and 5 ticks: the mean rate is 2 / 8.
        let mut fires = vec![0usize];
        while *fires.last().unwrap() < 2000 {
            let d = if fires.len() % 2 == 0 { 3 } else { 5 };
            fires.push(fires.last().unwrap() + d);
        }
        let n = *fires.last().unwrap() + 1;
        let f = fed(&planes(n, 1, 1, |k, _, _| fires.contains(&k)), 0);
        // One interval reads 1/3 or 1/5 (33% or 20% off the mean rate). The facilitation `u`
        // averages over about F / dt intervals: within 10%.
        let (p, s) = (StpParams::default(), f.synapses[0]);
        let u = p.u0 + s.b;
        let rate_u = 1.0 / (-p.tau_f_ticks * (s.b / (s.b + p.f * (1.0 - u))).ln());
        assert!((rate_u - 0.25).abs() < 0.025, "{rate_u}");
        // The estimate averages it with `R`'s, which follows the latest interval (D is 1 tick):
        // it lies between the two intervals' rates (measured: 0.296 after an interval of 3).
        let r = f64::from(rate(&f)[[0, 0]]);
        assert!(
            r > 0.2 && r < 1.0 / 3.0 && (r - 0.25).abs() < (1.0 / 3.0 - 0.25),
            "{r}"
        );
    }

    #[test]
    fn long_intervals_stay_finite_and_fall_back_on_u_once_r_underflows() {
        // exp(-1500 / D) underflows with D = 1: a = 0, so the rate comes from u alone.
        let s = planes(4501, 1, 1, |k, _, _| k % 1500 == 0);
        let f = fed(&s, 0);
        assert_eq!(f.synapses[0].a, 0.0);
        let r = f64::from(rate(&f)[[0, 0]]);
        assert!((r - 1.0 / 1500.0).abs() < 1e-3 / 1500.0, "{r}");
    }

    #[test]
    fn overlapping_windows_feed_each_plane_once_and_gaps_forget_the_last_spike() {
        let s = planes(40, 2, 2, |k, y, x| (k + y + 2 * x) % 3 == 0);
        let bits = pack_planes(s.view());
        let per = 1; // 4 pixels in one byte
        let once = fed(&s, 0);
        // Windows of 10 planes every 5, each fed through its middle plane.
        let mut f = StpFilter::new(2, 2, StpParams::default()).unwrap();
        for start in (0..=30).step_by(5) {
            let b = &bits[start * per..(start + 10) * per];
            f.advance_packed(b, start as u64, 10, start as u64 + 4)
                .unwrap();
        }
        f.advance_packed(&[], 40, 0, 39).unwrap();
        assert_eq!(f.synapses, once.synapses);
        assert_eq!((f.gaps(), f.last_fed()), (0, Some(39)));
        // Windows of 5 planes every 10: each skips 5 planes.
        let mut g = StpFilter::new(2, 2, StpParams::default()).unwrap();
        for start in (0..40).step_by(10) {
            g.advance_packed(&bits[start..start + 5], start as u64, 5, start as u64 + 4)
                .unwrap();
        }
        assert_eq!(g.gaps(), 3);
        // After the last gap (planes 30..35) each pixel's clock restarted at its first spike.
        let mut h = StpFilter::new(2, 2, StpParams::default()).unwrap();
        h.synapses = g.synapses.clone();
        assert!(g.synapses.iter().all(|s| s.last == 0 || s.last > 30));
    }

    #[test]
    fn plane_numbers_near_the_end_of_u64_and_bad_input_are_named() {
        let s = planes(8, 1, 2, |k, _, x| k % (x + 1) == 0);
        let first = u64::MAX - 9;
        let f = fed(&s, first);
        assert_eq!(rate(&f)[[0, 0]], 1.0);
        assert_eq!(rate(&f)[[0, 1]], 0.5);
        let mut f = StpFilter::new(1, 2, StpParams::default()).unwrap();
        let err = f.advance_packed(&[0; 8], u64::MAX - 5, 8, 0).unwrap_err();
        assert!(err.to_string().contains("stp first plane"), "{err}");
        let err = f.advance_packed(&[0; 3], 0, 8, 0).unwrap_err();
        assert!(err.to_string().contains("at least 8 bytes"), "{err}");
        let err = f.rate_into(Array2::zeros((2, 1)).view_mut()).unwrap_err();
        assert!(err.to_string().contains("stp rate destination"), "{err}");
        for (p, name) in [
            (
                StpParams {
                    u0: 0.0,
                    ..StpParams::default()
                },
                "stp u0",
            ),
            (
                StpParams {
                    u0: 1.0,
                    ..StpParams::default()
                },
                "stp u0",
            ),
            (
                StpParams {
                    f: f64::NAN,
                    ..StpParams::default()
                },
                "stp f",
            ),
            (
                StpParams {
                    tau_d_ticks: 0.0,
                    ..StpParams::default()
                },
                "tau_d",
            ),
            (
                StpParams {
                    tau_f_ticks: f64::INFINITY,
                    ..StpParams::default()
                },
                "tau_f",
            ),
        ] {
            let err = StpFilter::new(1, 1, p).unwrap_err();
            assert!(err.to_string().contains(name), "{err}");
        }
    }

    #[test]
    fn bits_past_the_last_pixel_are_ignored() {
        // 1 x 3 pixels: one byte a plane, bits 3..7 are padding, set here.
        let bits = vec![0xFFu8; 20];
        let mut f = StpFilter::new(1, 3, StpParams::default()).unwrap();
        f.advance_packed(&bits, 0, 20, 19).unwrap();
        assert!(rate(&f).iter().all(|&r| r == 1.0));
        assert_eq!(f.synapses.len(), 3);
    }

    fn spikes() -> impl Strategy<Value = (Array3<u8>, Vec<u64>)> {
        (1usize..40, 1usize..5, 1usize..70, 0u32..4, any::<u64>()).prop_flat_map(
            |(n, h, w, thin, seed)| {
                let mut x = seed | 1;
                let data: Vec<u8> = (0..n * h * w)
                    .map(|_| {
                        x ^= x << 13;
                        x ^= x >> 7;
                        x ^= x << 17;
                        u8::from(x % (1 << thin) == 0) * (1 + (x >> 40) as u8 % 3)
                    })
                    .collect();
                let a = Array3::from_shape_vec((n, h, w), data).unwrap();
                (Just(a), proptest::collection::vec(0u64..n as u64, 0..6))
            },
        )
    }

    proptest! {
        /// The packed path, fed in windows cut anywhere (pending planes included), leaves the same
        /// synapses, bit for bit, as the scalar reference fed every plane once.
        #[test]
        fn packed_equals_the_reference((s, cuts) in spikes(), first in 0u64..1_000_000) {
            let (n, h, w) = s.dim();
            let mut reference = StpFilter::new(h, w, StpParams::default()).unwrap();
            reference.advance_reference(s.view(), first).unwrap();
            let mut fast = StpFilter::new(h, w, StpParams::default()).unwrap();
            let mut cuts = cuts;
            cuts.push(n as u64);
            cuts.sort_unstable();
            let mut start = 0usize;
            for &c in &cuts {
                let end = (c as usize).max(start);
                let through = first + (start + end) as u64 / 2;
                let chunk = pack_planes(s.slice(s![start..end, .., ..]));
                fast.advance_packed(&chunk, first + start as u64, end - start, through).unwrap();
                start = end;
            }
            fast.advance_packed(&[], first + n as u64, 0, u64::MAX - 1).unwrap();
            prop_assert_eq!(&fast.synapses, &reference.synapses);
            prop_assert_eq!(fast.last_fed(), reference.last_fed());
            prop_assert_eq!(fast.gaps(), 0);
            let r = rate(&fast);
            prop_assert!(r.iter().all(|&v| (0.0..=1.0).contains(&v)));
            prop_assert_eq!(r, rate(&reference));
        }
    }
}
