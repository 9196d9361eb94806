//! A first convolution of event integration computed from the events themselves
//! ([`Conv3x3::run_edge_padded_events`]).
//!
//! Event integration (paper Eq. 8) gives channel `k` at a pixel the sum over its events `i` with
//! `t0 <= t_i <= ts_k` of `p_i (1 + exp(-(ts_k - t_i) / tau))`. A convolution is linear in its
//! input, so the convolution of those channels is the sum over events of each event's own
//! kernel, `G_i[o, tap] = p_i sum over k with ts_k >= t_i of W[o, k, tap] (1 + d(ts_k - t_i))`
//! (`d` the decay), added at the 9 outputs the event's pixel reaches. With `k0` the first
//! channel at or after `t_i`, `d(ts_k - t_i) = d(ts_k0 - t_i) d(ts_k - ts_k0)`, so
//! `G_i = p_i (A[k0] + d(ts_k0 - t_i) B[k0])` from two sums made once a window:
//! `A[k0] = sum over k >= k0 of W[k]`, `B[k0] = sum over k >= k0 of W[k] d(ts_k - ts_k0)`, every
//! decay at most 1. A window of 10,000 events then costs about 10,000 times 2 x 9 x `c_out`
//! operations, where making the 32 channels over 100,000 pixels and convolving them costs more
//! than 300 times that. The result is the `f32` convolution of the integration up to the order and
//! the width of its sums (tested with a tolerance).

use std::cell::RefCell;

use super::{Conv3x3, Conv3x3Error, TAPS};

thread_local! {
    /// The sums of [`Conv3x3::run_edge_padded_events`], point by point.
    static SUMS: RefCell<Vec<f32>> = RefCell::default();
}

/// A window's events, sorted by time.
#[derive(Clone, Copy, Debug)]
pub struct Events<'a> {
    /// Timestamps, nanoseconds, non-decreasing.
    pub t_ns: &'a [i64],
    /// Columns, below the width.
    pub x: &'a [u16],
    /// Rows, below the height.
    pub y: &'a [u16],
    /// `+1` (ON) or `-1` (OFF).
    pub polarity: &'a [i8],
}

/// The decay `d(dt) = exp(-dt / tau)` of a time difference `dt >= 0`, with the limits event
/// integration states: no decay (`1`) for `tau = +inf`, and for `tau <= 0` the `tau -> 0+`
/// limit, `1` at `dt = 0` and `0` after. `d(a + b) = d(a) d(b)` in all three.
#[derive(Clone, Copy, Debug)]
enum Decay {
    Exp(f64),
    Never,
    Instant,
}

impl Decay {
    fn new(tau_ns: f64) -> Option<Decay> {
        match tau_ns {
            t if t.is_nan() => None,
            t if t <= 0.0 => Some(Decay::Instant),
            f64::INFINITY => Some(Decay::Never),
            t => Some(Decay::Exp(t)),
        }
    }

    /// `d(later - earlier)`, the difference taken in `i128` (any two `i64` instants).
    fn factor(self, later: i64, earlier: i64) -> f64 {
        let dt = i128::from(later) - i128::from(earlier);
        match self {
            Decay::Exp(tau) => (-(dt as f64) / tau).exp(),
            Decay::Never => 1.0,
            Decay::Instant => f64::from(u8::from(dt == 0)),
        }
    }
}

impl Conv3x3 {
    /// [`run_edge_padded`](Self::run_edge_padded) of the event integration of `events`
    /// (`[K, h, w]`, `K = ts_ns.len()` the input channels, channel `k` at instant `ts_ns[k]`,
    /// from `t0_ns`, decay `tau_ns`, as `neuspike_representations::event_integration_into`
    /// makes it) without making it: each event's kernel added where its pixel reaches (see the
    /// module). Stride 1 only; one thread (the events' sums would race); worth it while the
    /// events are few against the pixels.
    ///
    /// # Errors
    /// [`Conv3x3Error::Stride`] at stride 2; [`Conv3x3Error::Shape`] when `ts_ns` has not one
    /// instant per input channel, the sizes do not fit or the event slices differ in length;
    /// [`Conv3x3Error::Events`] naming the first event or instant that breaks the rules (outside
    /// the sensor, out of time order, a polarity not ±1, instants decreasing, `tau_ns` NaN).
    #[allow(clippy::too_many_arguments)]
    pub fn run_edge_padded_events(
        &self,
        events: Events,
        t0_ns: i64,
        ts_ns: &[i64],
        tau_ns: f64,
        (h, w): (usize, usize),
        (hp, wp): (usize, usize),
        output: &mut [f32],
    ) -> Result<(), Conv3x3Error> {
        if self.stride != 1 {
            return Err(Conv3x3Error::Stride(self.stride));
        }
        let n = events.t_ns.len();
        let same = events.x.len() == n && events.y.len() == n && events.polarity.len() == n;
        if ts_ns.len() != self.c_in
            || !same
            || h == 0
            || w == 0
            || h > hp
            || w > wp
            || output.len() != self.c_out * hp * wp
        {
            return Err(Conv3x3Error::Shape {
                input: vec![ts_ns.len(), h, w, n],
                output: output.len(),
                c_in: self.c_in,
                c_out: self.c_out,
            });
        }
        let bad = |what: String| Err(Conv3x3Error::Events(what));
        let Some(decay) = Decay::new(tau_ns) else {
            return bad(format!("tau_ns = {tau_ns}"));
        };
        if let Some(k) = (1..ts_ns.len()).find(|&k| ts_ns[k] < ts_ns[k - 1]) {
            return bad(format!(
                "instant {k} ({} ns) before instant {} ({} ns)",
                ts_ns[k],
                k - 1,
                ts_ns[k - 1]
            ));
        }
        for i in 0..n {
            let (x, y, p) = (events.x[i], events.y[i], events.polarity[i]);
            if usize::from(x) >= w || usize::from(y) >= h {
                return bad(format!(
                    "event {i} at ({x}, {y}), outside the {w}x{h} sensor"
                ));
            }
            if p != 1 && p != -1 {
                return bad(format!("event {i}: polarity {p}, not +1 or -1"));
            }
            if i > 0 && events.t_ns[i] < events.t_ns[i - 1] {
                return bad(format!(
                    "event {i} at {} ns before the one before it",
                    events.t_ns[i]
                ));
            }
        }
        let plane = hp * wp;
        let k_all = ts_ns.len();
        let per = self.c_out * TAPS;
        // A[k0] and B[k0], `[k0][o][tap]`, from the last channel back.
        let mut a = vec![0f64; k_all * per];
        let mut b = vec![0f64; k_all * per];
        for k in (0..k_all).rev() {
            // The sums from channel k + 1 on (none past the last), B's decayed to ts_k.
            let decay_next = match ts_ns.get(k + 1) {
                Some(&next) => decay.factor(next, ts_ns[k]),
                None => 0.0,
            };
            for o in 0..self.c_out {
                for tap in 0..TAPS {
                    let j = k * per + o * TAPS + tap;
                    let weight = f64::from(self.weight(o, k, tap / 3, tap % 3));
                    a[j] = weight + a.get(j + per).copied().unwrap_or(0.0);
                    b[j] = weight + decay_next * b.get(j + per).copied().unwrap_or(0.0);
                }
            }
        }
        let a: Vec<f32> = a.iter().map(|&v| v as f32).collect();
        let b: Vec<f32> = b.iter().map(|&v| v as f32).collect();
        let Some(&last) = ts_ns.last() else {
            // No channel: the bias alone.
            for (o, out) in output.chunks_mut(plane.max(1)).enumerate() {
                out.fill(self.bias[o]);
            }
            self.finish(output);
            return Ok(());
        };
        let c_out = self.c_out;
        // The sums point by point, the outputs of a point side by side (an event's 72 adds then
        // touch a few cache lines, not one per output plane), put in planes at the end.
        SUMS.with_borrow_mut(|sums| {
            sums.clear();
            sums.resize(plane * c_out, 0.0);
            self.scatter(
                events,
                (t0_ns, ts_ns, last),
                decay,
                (&a, &b),
                (h, w),
                (hp, wp),
                sums,
            );
            for (i, point) in sums.chunks_exact(c_out).enumerate() {
                for (o, (s, bias)) in point.iter().zip(&self.bias).enumerate() {
                    output[o * plane + i] = bias + s;
                }
            }
        });
        self.finish(output);
        Ok(())
    }

    /// Each event's kernel added into `sums` (`[hp * wp][c_out]`).
    #[allow(clippy::too_many_arguments)]
    fn scatter(
        &self,
        events: Events,
        (t0_ns, ts_ns, last): (i64, &[i64], i64),
        decay: Decay,
        (a, b): (&[f32], &[f32]),
        (h, w): (usize, usize),
        (hp, wp): (usize, usize),
        sums: &mut [f32],
    ) {
        let c_out = self.c_out;
        let per = c_out * TAPS;
        let start = events.t_ns.partition_point(|&t| t < t0_ns);
        let end = events.t_ns.partition_point(|&t| t <= last).max(start);
        let mut k0 = 0;
        let mut kernel = vec![0f32; per];
        for i in start..end {
            let t = events.t_ns[i];
            while ts_ns[k0] < t {
                k0 += 1;
            }
            let e = decay.factor(ts_ns[k0], t) as f32;
            let p = f32::from(events.polarity[i]);
            let (a, b) = (&a[k0 * per..(k0 + 1) * per], &b[k0 * per..(k0 + 1) * per]);
            for ((g, a), b) in kernel.iter_mut().zip(a).zip(b) {
                *g = p * (a + e * b);
            }
            let (ex, ey) = (usize::from(events.x[i]), usize::from(events.y[i]));
            // The padded input's points holding this pixel's value: the edge row and column
            // repeat to `hp` and `wp`.
            let ys = ey..if ey + 1 == h { hp } else { ey + 1 };
            let xs = ex..if ex + 1 == w { wp } else { ex + 1 };
            for py in ys {
                for ky in 0..3 {
                    let Some(oy) = (py + 1).checked_sub(ky).filter(|&oy| oy < hp) else {
                        continue;
                    };
                    for px in xs.clone() {
                        for kx in 0..3 {
                            let Some(ox) = (px + 1).checked_sub(kx).filter(|&ox| ox < wp) else {
                                continue;
                            };
                            let at = (oy * wp + ox) * c_out;
                            let tap = ky * 3 + kx;
                            for (s, k) in sums[at..at + c_out]
                                .iter_mut()
                                .zip(kernel[tap..].iter().step_by(TAPS))
                            {
                                *s += k;
                            }
                        }
                    }
                }
            }
        }
    }

    /// The ReLU where the convolution has one.
    fn finish(&self, output: &mut [f32]) {
        if self.relu {
            for v in output {
                *v = v.max(0.0);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{conv, pattern};
    use ndarray::Array3;

    /// Events over `h x w` between 0 and 1,000 ns, sorted, some at the channels' instants, some
    /// on the edge row and column.
    fn events(
        n: usize,
        (h, w): (usize, usize),
        seed: u32,
    ) -> (Vec<i64>, Vec<u16>, Vec<u16>, Vec<i8>) {
        let v = pattern(4 * n, seed);
        let mut t: Vec<i64> = (0..n).map(|i| ((v[i] + 1.0) * 500.0) as i64).collect();
        if n > 2 {
            t[1] = 250;
            t[2] = 250;
        }
        t.sort_unstable();
        let x = (0..n)
            .map(|i| if i % 7 == 0 { w - 1 } else { ((v[n + i] + 1.0) * 0.5 * w as f32) as usize % w } as u16)
            .collect();
        let y = (0..n)
            .map(|i| if i % 5 == 0 { h - 1 } else { ((v[2 * n + i] + 1.0) * 0.5 * h as f32) as usize % h } as u16)
            .collect();
        let p = (0..n)
            .map(|i| if v[3 * n + i] > 0.0 { 1 } else { -1 })
            .collect();
        (t, x, y, p)
    }

    /// The integration by its definition, in `f64`, ON and OFF apart.
    fn integration(
        ev: &Events,
        t0: i64,
        ts: &[i64],
        tau: f64,
        (h, w): (usize, usize),
    ) -> Array3<f32> {
        let decay = Decay::new(tau).unwrap();
        Array3::from_shape_fn((ts.len(), h, w), |(k, y, x)| {
            let (mut on, mut off) = (0f64, 0f64);
            for i in 0..ev.t_ns.len() {
                let t = ev.t_ns[i];
                if t < t0 || t > ts[k] || usize::from(ev.x[i]) != x || usize::from(ev.y[i]) != y {
                    continue;
                }
                let v = 1.0 + decay.factor(ts[k], t);
                if ev.polarity[i] > 0 {
                    on += v
                } else {
                    off += v
                }
            }
            (on - off) as f32
        })
    }

    fn check(
        c_out: usize,
        k: usize,
        (h, w): (usize, usize),
        (hp, wp): (usize, usize),
        n: usize,
        tau: f64,
        seed: u32,
    ) {
        let base = conv(k, c_out, 1, seed);
        let base = if seed % 2 == 1 {
            base.with_relu()
        } else {
            base
        };
        let (t, x, y, p) = events(n, (h, w), seed + 1);
        let ev = Events {
            t_ns: &t,
            x: &x,
            y: &y,
            polarity: &p,
        };
        let ts: Vec<i64> = (1..=k as i64).map(|i| 1000 * i / k as i64).collect();
        let t0 = 100;
        let v = integration(&ev, t0, &ts, tau, (h, w));
        let mut want = vec![f32::NAN; c_out * hp * wp];
        base.run_edge_padded(v.view(), (hp, wp), &mut want, None)
            .unwrap();
        let mut got = vec![f32::NAN; c_out * hp * wp];
        base.run_edge_padded_events(ev, t0, &ts, tau, (h, w), (hp, wp), &mut got)
            .unwrap();
        let vmax = v.iter().fold(0f32, |m, v| m.max(v.abs()));
        let wsum: f32 = pattern(c_out * k * 9, seed).iter().map(|w| w.abs()).sum();
        let tol = 1e-5 * (wsum * vmax.max(1.0) + 2.0);
        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
            assert!(
                (g - w).abs() <= tol,
                "{k} channels -> {c_out}, {h}x{w} as {hp}x{wp}, {n} events, tau {tau}: output {i}: {g} against {w}"
            );
        }
    }

    #[test]
    fn events_give_the_convolution_of_their_integration() {
        // The network's size; padded rows and columns (edge events repeated); one pixel; no
        // events; a decay at each limit (instant, none) and one far longer than the window.
        check(8, 32, (25, 40), (32, 40), 300, 300.0, 1);
        check(4, 5, (9, 13), (16, 16), 200, 50.0, 2);
        check(4, 3, (1, 1), (3, 5), 6, 400.0, 3);
        check(8, 4, (6, 7), (8, 8), 0, 300.0, 4);
        check(4, 6, (7, 9), (8, 16), 150, 0.0, 5);
        check(4, 6, (7, 9), (8, 16), 150, f64::NEG_INFINITY, 6);
        check(4, 6, (7, 9), (8, 16), 150, f64::INFINITY, 7);
        check(4, 6, (7, 9), (8, 16), 150, 1e12, 8);
    }

    #[test]
    fn bad_events_are_refused_by_name() {
        let conv = conv(2, 4, 1, 1);
        let mut out = vec![0f32; 4 * 4 * 4];
        let run =
            |t: &[i64], x: &[u16], y: &[u16], p: &[i8], ts: &[i64], tau: f64, out: &mut [f32]| {
                let ev = Events {
                    t_ns: t,
                    x,
                    y,
                    polarity: p,
                };
                conv.run_edge_padded_events(ev, 0, ts, tau, (4, 4), (4, 4), out)
            };
        let ts = [5, 10];
        for (t, x, y, p, ts, tau, want) in [
            (
                &[1i64][..],
                &[4u16][..],
                &[0u16][..],
                &[1i8][..],
                &ts[..],
                1.0,
                "outside the 4x4",
            ),
            (&[1], &[0], &[4], &[1], &ts, 1.0, "outside the 4x4"),
            (&[1], &[0], &[0], &[0], &ts, 1.0, "polarity 0"),
            (
                &[3, 1],
                &[0, 0],
                &[0, 0],
                &[1, 1],
                &ts,
                1.0,
                "event 1 at 1 ns",
            ),
            (&[1], &[0], &[0], &[1], &[10, 5], 1.0, "instant 1 (5 ns)"),
            (&[1], &[0], &[0], &[1], &ts, f64::NAN, "tau_ns = NaN"),
        ] {
            let err = run(t, x, y, p, ts, tau, &mut out).unwrap_err();
            assert!(err.to_string().contains(want), "{err}");
        }
        // Sizes: another channel count, slices of different lengths, a stride of 2.
        assert!(matches!(
            run(&[1], &[0], &[0], &[1], &[1, 2, 3], 1.0, &mut out),
            Err(Conv3x3Error::Shape { .. })
        ));
        assert!(matches!(
            run(&[1], &[0, 1], &[0], &[1], &ts, 1.0, &mut out),
            Err(Conv3x3Error::Shape { .. })
        ));
        let two = crate::testing::conv(2, 4, 2, 1);
        let ev = Events {
            t_ns: &[],
            x: &[],
            y: &[],
            polarity: &[],
        };
        let err = two.run_edge_padded_events(ev, 0, &ts, 1.0, (4, 4), (4, 4), &mut out[..16]);
        assert_eq!(err, Err(Conv3x3Error::Stride(2)));
    }
}
