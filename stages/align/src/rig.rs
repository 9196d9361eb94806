//! The geometry and clock of a rig of two sensors, estimated from what they recorded.
//!
//! An event at the event camera's pixel `p`, time `t` (its clock) says the light at the spike
//! camera's point `H p` changed, at spike-clock time `t - delta`, in the direction of its
//! polarity. The spike camera gives the light everywhere: `S(x, t)`, the spikes a pixel fired in
//! a short window. So the right `H` and `delta` make the events' polarities agree with the spike
//! camera's temporal change, the z-score of the count's change
//! `D(x, t) = (S(x, t + tau) - S(x, t - tau)) / sqrt(S(x, t + tau) + S(x, t - tau) + 1)`, sampled
//! at `(H p, t - delta)`. Why not the difference of the counts' logs, as a DVS's own quantity
//! suggests: it peaks where a window mixing an edge's two sides is mostly the darker one, which
//! moves the estimate up to 1 px, a different way at each edge. The counts' difference peaks with
//! the edge, and the square root, the Poisson noise of the counts, keeps a bright edge from
//! outweighing a dark one. [`estimate`] maximises their correlation (Pearson, over a sample of
//! the events): a grid over the scale and the shift on a blurred video, then Nelder-Mead over
//! the six affine coefficients of `H` (the perspective terms are kept from the start: they are
//! nearly invisible in a frame's middle and drift). Last, the geometry is refined on every frame
//! of every pixel, the spike counts against the light the events spell (the `levels` module):
//! that sees finer than the polarities at the events' times, but from near the answer only.
//!
//! The clock is known, or comes first from the two sensors' activity over time, geometry-free,
//! and is kept. The geometry and the clock are only separable where the motion changes (a
//! start, a stop, a change of speed or direction): a clock error `delta` moves every point by
//! its flow over `delta`, and a steady pan, turn or zoom is an affine flow, so an affine change
//! of `H` explains that alike. The activity sees the changes of motion alone; the polarities'
//! own clock trades against the geometry's last tenths of a pixel (on the simulated rig a point
//! moves 0.04 px per 100 us, and a search of both together came up to 0.68 ms off over noise
//! draws). Only when the activity does not correlate ([`ACTIVITY_MIN_CORRELATION`]: no change
//! of motion) is the clock searched with the geometry, on a grid at each round, then both
//! together, and the estimate says so ([`ClockSource::Searched`]).
//!
//! On a small simulated rig (`tests/rig.rs`: a 160x100 spike camera, a 138x104 DVS, three
//! textures, 40 ms whose first 12 hold still) the
//! homography comes within 0.09-0.20 px where both sensors see when the clock is known (0.25-0.63
//! without the last step), and the clock within 6-27 us when the homography is known (its search
//! takes only the events within bursts, [`BURST_NS`]); both unknown, within 0.06-0.30 px and
//! 14-55 us. Over four noise draws of each texture: 0.06-0.27 px with the clock known, and
//! 0.05-0.40 px and 98 us at worst with neither known. On the paper's rig, a 400x250 spike camera
//! with a DAVIS346 (the same motion and textures, four noise draws each), neither known: 0.06-0.22
//! px and -51 to +60 us (`neuspike calibrate-rig` on `neuspike simulate`'s recordings: 0.07-0.24
//! px, -42 to +55 us). The clock's error follows the texture more than the noise draw (on the
//! small rig one texture came 55-98 us late, another 14-54 us early). When the motion also stops
//! (`motion.stop_ns` at 28 or 32 ms), the activity's clock came 37-133 us early on the small rig
//! over the four draws of each texture.

use neuspike_geometry::Homography;
use neuspike_schemas::{EventBatch, SpikeChunk, fired_pixels};

mod levels;

/// Planes per frame of the change video (2: 100 us at 20 kHz).
pub const FRAME_PLANES: usize = 2;
/// Frames of the firing-rate window (24 planes: 1.2 ms at 20 kHz).
pub const RATE_FRAMES: usize = 12;
/// Frames either side of the temporal difference (`tau`: 16 planes, 0.8 ms at 20 kHz).
pub const DIFF_FRAMES: usize = 8;
/// Events used, at most (evenly spread over the recording).
pub const MAX_EVENTS: usize = 40_000;
/// Restarts of the joint search of the clock and the affine coefficients.
pub const JOINT_RESTARTS: usize = 1;
/// Coefficients fitted in the last rounds (8: the perspective terms too; 6: affine).
pub const PERSPECTIVE: usize = 6;

/// The least correlation of the two sensors' activity over time at which [`estimate`] takes
/// its clock from the activity. With a change of motion in the recordings it reached 0.98-0.995
/// on the simulated rig; under a steady motion alone, 0.08-0.41 (at a clock milliseconds off).
pub const ACTIVITY_MIN_CORRELATION: f64 = 0.8;

/// Where an estimate's clock offset came from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ClockSource {
    /// Given.
    Known,
    /// The two sensors' activity over time, which correlated this well (at least
    /// [`ACTIVITY_MIN_CORRELATION`]): the recordings hold a change of motion that times it.
    Activity(f64),
    /// Searched together with the geometry, as the activity correlated only this well (or
    /// never changed: 0): under a steady motion a clock error and an affine change of the
    /// geometry explain the events alike, so both may be off (milliseconds and pixels on the
    /// simulated rig). Give the clock, or a stretch where the motion starts, stops or turns.
    Searched(f64),
}

impl std::fmt::Display for ClockSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ClockSource::Known => write!(f, "given"),
            ClockSource::Activity(c) => write!(
                f,
                "from the two sensors' activity over time (correlation {c:.3})"
            ),
            ClockSource::Searched(c) => write!(
                f,
                "uncertain: the two sensors' activity over time correlates {c:.3} (under \
                 {ACTIVITY_MIN_CORRELATION}): the recordings hold no start, stop or turn of the \
                 motion to time the clock, and under a steady motion a clock error and the \
                 geometry trade off; give the clock offset, or a stretch where the motion changes"
            ),
        }
    }
}

/// What [`estimate`] found.
#[derive(Clone, Debug)]
pub struct RigEstimate {
    /// Event camera pixel -> spike camera pixel.
    pub homography: Homography,
    /// The event camera's clock minus the spike camera's, nanoseconds: align's
    /// `--event-offset-ns` is its negative.
    pub offset_ns: i64,
    /// The correlation reached (0 to 1).
    pub score: f64,
    /// Events used.
    pub events: usize,
    /// Where the clock offset came from.
    pub clock: ClockSource,
}

/// Why a rig cannot be estimated.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RigError {
    /// Too little data.
    #[error("rig: {0}")]
    TooLittle(String),
}

/// The spike camera's temporal change of light, frame by frame (`D` of the module docs).
struct ChangeVideo {
    width: usize,
    height: usize,
    /// Time of frame 0's centre, ns (spike clock), and the frame period.
    t0_ns: f64,
    period_ns: f64,
    frames: usize,
    /// `[frames, height, width]`.
    d: Vec<f32>,
}

impl ChangeVideo {
    fn new(spikes: &SpikeChunk) -> Option<ChangeVideo> {
        let (w, h) = (spikes.width, spikes.height);
        let n = w * h;
        let per = n.div_ceil(8);
        let frames = spikes.n_planes / FRAME_PLANES;
        if frames < RATE_FRAMES + 2 * DIFF_FRAMES + 2 || n == 0 {
            return None;
        }
        // Spike counts per frame.
        let mut counts = vec![0u16; frames * n];
        for (k, plane) in spikes
            .bits
            .chunks_exact(per)
            .take(frames * FRAME_PLANES)
            .enumerate()
        {
            let f = k / FRAME_PLANES;
            let row = &mut counts[f * n..(f + 1) * n];
            for i in fired_pixels(plane, n) {
                row[i] += 1;
            }
        }
        // Spikes over RATE_FRAMES frames: frame f covers frames f .. f + RATE_FRAMES.
        let lf = frames - RATE_FRAMES + 1;
        let mut window = vec![0f32; lf * n];
        let mut sum = vec![0u32; n];
        for f in 0..frames {
            for i in 0..n {
                sum[i] += u32::from(counts[f * n + i]);
            }
            if f + 1 >= RATE_FRAMES {
                let g = f + 1 - RATE_FRAMES;
                for i in 0..n {
                    window[g * n + i] = sum[i] as f32;
                    sum[i] -= u32::from(counts[g * n + i]);
                }
            }
        }
        let df = lf - 2 * DIFF_FRAMES;
        let mut d = vec![0f32; df * n];
        for f in 0..df {
            for i in 0..n {
                // The z-score of the change; the + 1 keeps the divisor at 1 or more where
                // neither window holds a spike.
                let (after, before) = (window[(f + 2 * DIFF_FRAMES) * n + i], window[f * n + i]);
                d[f * n + i] = (after - before) / (after + before + 1.0).sqrt();
            }
        }
        let period_ns = (FRAME_PLANES as i64 * spikes.plane_period_ns) as f64;
        // Frame f of `d` is centred on window f + DIFF_FRAMES, whose window covers planes
        // (f + DIFF_FRAMES) * FRAME_PLANES .. + RATE_FRAMES * FRAME_PLANES; plane k covers
        // (t_k - T, t_k].
        let first_plane_t = spikes.t_first_ns as f64 - spikes.plane_period_ns as f64;
        let t0_ns = first_plane_t + period_ns * (DIFF_FRAMES as f64 + RATE_FRAMES as f64 / 2.0);
        Some(ChangeVideo {
            width: w,
            height: h,
            t0_ns,
            period_ns,
            frames: df,
            d,
        })
    }

    /// The video blurred in space by a box of `2 r + 1` pixels (a wider basin for the coarse
    /// search).
    fn blurred(&self, r: usize) -> ChangeVideo {
        let (w, h) = (self.width, self.height);
        let n = w * h;
        let mut d = vec![0f32; self.d.len()];
        let mut tmp = vec![0f32; n];
        for f in 0..self.frames {
            let src = &self.d[f * n..(f + 1) * n];
            for y in 0..h {
                for x in 0..w {
                    let (lo, hi) = (x.saturating_sub(r), (x + r + 1).min(w));
                    let s: f32 = src[y * w + lo..y * w + hi].iter().sum();
                    tmp[y * w + x] = s / (hi - lo) as f32;
                }
            }
            let dst = &mut d[f * n..(f + 1) * n];
            for y in 0..h {
                let (lo, hi) = (y.saturating_sub(r), (y + r + 1).min(h));
                for x in 0..w {
                    let s: f32 = (lo..hi).map(|yy| tmp[yy * w + x]).sum();
                    dst[y * w + x] = s / (hi - lo) as f32;
                }
            }
        }
        ChangeVideo {
            width: w,
            height: h,
            t0_ns: self.t0_ns,
            period_ns: self.period_ns,
            frames: self.frames,
            d,
        }
    }

    /// `D` at spike point `(x, y)` (pixel centres at +0.5) and spike-clock time `t_ns`,
    /// trilinear; `None` outside.
    #[inline]
    fn sample(&self, x: f64, y: f64, t_ns: f64) -> Option<f32> {
        let fx = x - 0.5;
        let fy = y - 0.5;
        let ft = (t_ns - self.t0_ns) / self.period_ns;
        if !(fx >= 0.0 && fy >= 0.0 && ft >= 0.0) {
            return None;
        }
        let (x0, y0, t0) = (fx as usize, fy as usize, ft as usize);
        if x0 + 1 >= self.width || y0 + 1 >= self.height || t0 + 1 >= self.frames {
            return None;
        }
        let (ax, ay, at) = (
            (fx - x0 as f64) as f32,
            (fy - y0 as f64) as f32,
            (ft - t0 as f64) as f32,
        );
        let n = self.width * self.height;
        let at_frame = |f: usize| {
            let base = f * n + y0 * self.width + x0;
            let d = &self.d;
            let top = d[base] * (1.0 - ax) + d[base + 1] * ax;
            let bottom = d[base + self.width] * (1.0 - ax) + d[base + self.width + 1] * ax;
            top * (1.0 - ay) + bottom * ay
        };
        Some(at_frame(t0) * (1.0 - at) + at_frame(t0 + 1) * at)
    }
}

/// An event says the light changed by a threshold since the pixel's previous event: it is
/// compared with the change around the middle of that interval, not at its end (a delta
/// modulator lags the light by half a threshold's time). Intervals longer than this are
/// taken as this long.
const MAX_INTERVAL_NS: i64 = 4_000_000;

/// Within a burst: an event whose previous one at its pixel is at most this long before it.
/// The change that fired such an event took the whole interval, so the interval's middle is
/// its time; the first event of a burst fires at the start of a change the spike camera sees
/// centred later, and would pull the clock late.
pub const BURST_NS: i64 = 1_000_000;

/// The events of the sample: every `stride`-th event that has an earlier one at its pixel (at
/// most `max_since_ns` earlier, when given), at the middle of the interval since that one.
fn sample_events(events: &EventBatch, max_since_ns: Option<i64>) -> Sample {
    let (w, h) = (events.width.max(1), events.height.max(1));
    let mut last = vec![i64::MIN; w * h];
    let stride = events.len().div_ceil(MAX_EVENTS).max(1);
    let mut ev = Sample {
        x: Vec::new(),
        y: Vec::new(),
        t: Vec::new(),
        p: Vec::new(),
    };
    for i in 0..events.len() {
        let (x, y) = (usize::from(events.x[i]), usize::from(events.y[i]));
        if x >= w || y >= h {
            continue;
        }
        let t = events.t_ns[i];
        let prev = std::mem::replace(&mut last[y * w + x], t);
        if prev == i64::MIN || i % stride != 0 {
            continue;
        }
        let since = t.saturating_sub(prev).max(0);
        if max_since_ns.is_some_and(|m| since > m) {
            continue;
        }
        let since = since.min(MAX_INTERVAL_NS);
        ev.x.push(x as f64 + 0.5);
        ev.y.push(y as f64 + 0.5);
        ev.t.push(t as f64 - since as f64 / 2.0);
        ev.p.push(f32::from(events.polarity[i]));
    }
    ev
}

/// The sampled events: pixel centres, times (event clock), polarities.
struct Sample {
    x: Vec<f64>,
    y: Vec<f64>,
    t: Vec<f64>,
    p: Vec<f32>,
}

/// Correlation of the polarities with `D` at the mapped points; 0 when under a third of the
/// events land inside the spike recording.
fn score(video: &ChangeVideo, ev: &Sample, h: &Homography, offset_ns: f64) -> f64 {
    let (mut n, mut sp, mut sd, mut spp, mut sdd, mut spd) = (0.0f64, 0.0, 0.0, 0.0, 0.0, 0.0);
    for i in 0..ev.x.len() {
        let Some((x, y)) = h.apply(ev.x[i], ev.y[i]) else {
            continue;
        };
        let Some(d) = video.sample(x, y, ev.t[i] - offset_ns) else {
            continue;
        };
        let (p, d) = (f64::from(ev.p[i]), f64::from(d));
        n += 1.0;
        sp += p;
        sd += d;
        spp += p * p;
        sdd += d * d;
        spd += p * d;
    }
    if n < ev.x.len() as f64 / 3.0 || n < 2.0 {
        return 0.0;
    }
    let cov = spd / n - (sp / n) * (sd / n);
    let vp = spp / n - (sp / n).powi(2);
    let vd = sdd / n - (sd / n).powi(2);
    if vp <= 0.0 || vd <= 0.0 {
        return 0.0;
    }
    cov / (vp * vd).sqrt()
}

/// Nelder-Mead: minimises `f` from `x0` with initial steps `step`, `iters` iterations.
fn nelder_mead(f: &dyn Fn(&[f64]) -> f64, x0: &[f64], step: &[f64], iters: usize) -> Vec<f64> {
    let n = x0.len();
    let mut simplex: Vec<(Vec<f64>, f64)> = (0..=n)
        .map(|k| {
            let mut x = x0.to_vec();
            if k > 0 {
                x[k - 1] += step[k - 1];
            }
            let v = f(&x);
            (x, v)
        })
        .collect();
    for _ in 0..iters {
        simplex.sort_by(|a, b| a.1.total_cmp(&b.1));
        let worst = simplex[n].clone();
        let centroid: Vec<f64> = (0..n)
            .map(|j| simplex[..n].iter().map(|s| s.0[j]).sum::<f64>() / n as f64)
            .collect();
        let along = |a: f64| -> Vec<f64> {
            centroid
                .iter()
                .zip(&worst.0)
                .map(|(c, w)| c + a * (w - c))
                .collect()
        };
        let r = along(-1.0);
        let fr = f(&r);
        if fr < simplex[0].1 {
            let e = along(-2.0);
            let fe = f(&e);
            simplex[n] = if fe < fr { (e, fe) } else { (r, fr) };
        } else if fr < simplex[n - 1].1 {
            simplex[n] = (r, fr);
        } else {
            let c = along(0.5);
            let fc = f(&c);
            if fc < worst.1 {
                simplex[n] = (c, fc);
            } else {
                let best = simplex[0].0.clone();
                for s in simplex.iter_mut().skip(1) {
                    s.0 =
                        s.0.iter()
                            .zip(&best)
                            .map(|(x, b)| b + 0.5 * (x - b))
                            .collect();
                    s.1 = f(&s.0);
                }
            }
        }
    }
    simplex.sort_by(|a, b| a.1.total_cmp(&b.1));
    simplex.swap_remove(0).0
}

/// Every event's time for the activity over time (event clock, ns): the middle of the interval
/// since the previous event at its pixel, as the change that fired it took that interval. The
/// first event after a pause (none at its pixel within [`MAX_INTERVAL_NS`]) fired only once the
/// change had reached a threshold: the middle of an interval as long as the one to the next
/// event at its pixel (its own time when there is none within [`MAX_INTERVAL_NS`] either).
/// Leaving those events out put the activity's clock 0.5-0.7 ms late on the simulated rig,
/// where every pixel's first event is at the motion's start.
fn activity_times(events: &EventBatch) -> Vec<f64> {
    let (w, h) = (events.width.max(1), events.height.max(1));
    let n = events.len();
    let pixel = |i: usize| {
        let (x, y) = (usize::from(events.x[i]), usize::from(events.y[i]));
        (x < w && y < h).then_some(y * w + x)
    };
    // The time to the next event at the same pixel, from the end.
    let mut to_next = vec![i64::MAX; n];
    let mut later = vec![i64::MIN; w * h];
    for i in (0..n).rev() {
        if let Some(p) = pixel(i) {
            if later[p] != i64::MIN {
                to_next[i] = later[p].saturating_sub(events.t_ns[i]);
            }
            later[p] = events.t_ns[i];
        }
    }
    let mut earlier = later;
    earlier.fill(i64::MIN);
    let mut times = Vec::with_capacity(n);
    for (i, &next) in to_next.iter().enumerate() {
        let Some(p) = pixel(i) else {
            continue;
        };
        let t = events.t_ns[i];
        let prev = std::mem::replace(&mut earlier[p], t);
        let since = if prev == i64::MIN {
            i64::MAX
        } else {
            t.saturating_sub(prev)
        };
        let interval = if since <= MAX_INTERVAL_NS {
            since
        } else if next <= MAX_INTERVAL_NS {
            next
        } else {
            0
        };
        times.push(t as f64 - interval as f64 / 2.0);
    }
    times
}

/// The clock offset from the two sensors' activity over time, geometry-free: the spike camera's
/// mean absolute change `|D|` frame by frame against the count of events (`times`, see
/// [`activity_times`]) on the same frames, smoothed by the kernel `D` applies (a box of the
/// rate window, differenced `2 tau` apart), correlated over offsets within `max_offset_ns` (a
/// grid of 1/16 frame, the peak refined by a parabola). `None` when the activity never changes
/// (a constant pan: use [`estimate`]).
fn activity_offset(video: &ChangeVideo, times: &[f64], max_offset_ns: f64) -> Option<(f64, f64)> {
    let n = video.width * video.height;
    let spike: Vec<f64> = (0..video.frames)
        .map(|f| {
            video.d[f * n..(f + 1) * n]
                .iter()
                .map(|v| f64::from(v.abs()))
                .sum::<f64>()
                / n as f64
        })
        .collect();
    let mean = spike.iter().sum::<f64>() / spike.len() as f64;
    let var = spike.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / spike.len() as f64;
    if var <= 1e-12 * mean.max(1e-12).powi(2) {
        return None;
    }
    // Fine bins of 1/16 frame: event counts; the kernel's taps in fine bins.
    const SUB: usize = 16;
    let fine = video.period_ns / SUB as f64;
    let rate = RATE_FRAMES * SUB;
    let gap = 2 * DIFF_FRAMES * SUB;
    let score_at = |offset: f64| -> f64 {
        // Event counts on the fine grid of the spike clock, from a margin before frame 0.
        let margin = (rate + gap) as f64 * fine;
        let t_lo = video.t0_ns - margin;
        let bins = (video.frames * SUB) + 2 * (rate + gap);
        let mut hist = vec![0f64; bins];
        for &t in times {
            let b = ((t - offset - t_lo) / fine).floor();
            if b >= 0.0 && (b as usize) < bins {
                hist[b as usize] += 1.0;
            }
        }
        // Smooth: a box of `rate` fine bins, spread over `gap` (the difference's two ends).
        let mut cum = vec![0f64; bins + 1];
        for i in 0..bins {
            cum[i + 1] = cum[i] + hist[i];
        }
        // The span a change of light shows in `D(f)`: the two rate windows `2 tau` apart.
        let half = (gap + rate) as f64 / 2.0;
        let ev: Vec<f64> = (0..video.frames)
            .map(|f| {
                let c = margin / fine + (f * SUB) as f64;
                let lo = (c - half).max(0.0) as usize;
                let hi = ((c + half).max(0.0) as usize).min(bins);
                if hi > lo { cum[hi] - cum[lo] } else { 0.0 }
            })
            .collect();
        let me = ev.iter().sum::<f64>() / ev.len() as f64;
        let cov: f64 = spike
            .iter()
            .zip(&ev)
            .map(|(a, b)| (a - mean) * (b - me))
            .sum();
        let ve: f64 = ev.iter().map(|b| (b - me).powi(2)).sum();
        if ve <= 0.0 {
            return 0.0;
        }
        cov / (var * spike.len() as f64 * ve).sqrt()
    };
    let step = fine;
    let k = (max_offset_ns / step).round() as i64;
    let (mut best, mut best_s) = (0.0, f64::MIN);
    for j in -k..=k {
        let o = j as f64 * step;
        let s = score_at(o);
        if s > best_s {
            (best, best_s) = (o, s);
        }
    }
    let (sl, sr) = (score_at(best - step), score_at(best + step));
    let curve = sl - 2.0 * best_s + sr;
    if curve < 0.0 {
        best += 0.5 * step * (sl - sr) / curve;
    }
    Some((best, best_s))
}

/// Whether the clock offset is known or searched for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Clock {
    /// The event camera's clock minus the spike camera's, nanoseconds.
    Known(i64),
    /// Searched for within this many nanoseconds either way.
    Within(i64),
}

/// The clock offset that best explains the recordings at a known geometry: a grid of 1/8 frame
/// within 5 frames of `around_ns`, then 1/16 frame and a parabola through the peak.
fn fine_offset(video: &ChangeVideo, ev: &Sample, h: &Homography, around_ns: f64) -> f64 {
    let grid = |center: f64, half: f64, step: f64| {
        let k = (half / step).round() as i64;
        (-k..=k)
            .map(|j| {
                let o = center + j as f64 * step;
                (o, score(video, ev, h, o))
            })
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap_or((center, 0.0))
    };
    let (o, _) = grid(around_ns, video.period_ns * 5.0, video.period_ns / 8.0);
    let step = video.period_ns / 16.0;
    let (o, s) = grid(o, video.period_ns / 4.0, step);
    let (sl, sr) = (score(video, ev, h, o - step), score(video, ev, h, o + step));
    let curve = sl - 2.0 * s + sr;
    if curve < 0.0 {
        o + 0.5 * step * (sl - sr) / curve
    } else {
        o
    }
}

/// The clock offset at a known geometry `h`, searched within `max_offset_ns` (a grid of half a
/// frame, then 1/8 and 1/16 of a frame within 5 frames of the best, a parabola through the
/// peak).
///
/// # Errors
/// Too few planes or events.
pub fn estimate_offset(
    spikes: &SpikeChunk,
    events: &EventBatch,
    h: &Homography,
    max_offset_ns: i64,
) -> Result<i64, RigError> {
    let video = ChangeVideo::new(spikes)
        .ok_or_else(|| RigError::TooLittle(format!("{} spike planes", spikes.n_planes)))?;
    let ev = sample_events(events, Some(BURST_NS));
    if ev.x.len() < 300 {
        return Err(RigError::TooLittle(format!("{} usable events", ev.x.len())));
    }
    let step = video.period_ns / 2.0;
    let k = (max_offset_ns.max(0) as f64 / step).round() as i64;
    let coarse = (-k..=k)
        .map(|j| {
            let o = j as f64 * step;
            (o, score(&video, &ev, h, o))
        })
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map_or(0.0, |b| b.0);
    Ok(fine_offset(&video, &ev, h, coarse).round() as i64)
}

/// How well a rig's homography and clock offset explain the two recordings: the correlation
/// [`estimate`] maximises (0 when too few events land inside the spike recording).
pub fn agreement(spikes: &SpikeChunk, events: &EventBatch, h: &Homography, offset_ns: i64) -> f64 {
    let Some(video) = ChangeVideo::new(spikes) else {
        return 0.0;
    };
    score(&video, &sample_events(events, None), h, offset_ns as f64)
}

/// Estimates the rig from a stretch of both recordings: `spikes` (at least 100 planes, the
/// spike clock), `events` (the event camera's pixels and clock), starting from `init` (for
/// example the two sensors' sizes: the same view) and searching clock offsets within
/// `max_offset_ns`.
///
/// # Errors
/// Too few planes or events.
pub fn estimate(
    spikes: &SpikeChunk,
    events: &EventBatch,
    init: Homography,
    clock: Clock,
) -> Result<RigEstimate, RigError> {
    let max_offset_ns = match clock {
        Clock::Known(_) => 0,
        Clock::Within(ns) => ns.max(0),
    };
    let video = ChangeVideo::new(spikes).ok_or_else(|| {
        RigError::TooLittle(format!(
            "{} spike planes; at least {} are needed",
            spikes.n_planes,
            FRAME_PLANES * (RATE_FRAMES + 2 * DIFF_FRAMES + 2)
        ))
    })?;
    if events.len() < 500 {
        return Err(RigError::TooLittle(format!(
            "{} events; at least 500 are needed",
            events.len()
        )));
    }
    let ev = sample_events(events, None);
    if ev.x.len() < 300 {
        return Err(RigError::TooLittle(format!(
            "{} events follow an earlier one at their pixel; at least 300 are needed",
            ev.x.len()
        )));
    }
    // The clock's fine search takes the events within bursts (see [`BURST_NS`]), when there are
    // enough of them.
    let bursts = sample_events(events, Some(BURST_NS));
    let clock_ev = if bursts.x.len() >= 300 { &bursts } else { &ev };
    let with_shift = |h: &Homography, dx: f64, dy: f64| {
        let mut c = h.coefficients();
        c[0] += dx * c[6];
        c[1] += dx * c[7];
        c[2] += dx * c[8];
        c[3] += dy * c[6];
        c[4] += dy * c[7];
        c[5] += dy * c[8];
        Homography::new(c).unwrap_or(*h)
    };
    let offsets = |h: &Homography, center: f64, half: f64, step: f64| {
        let k = (half / step).round() as i64;
        (-k..=k)
            .map(|j| {
                let o = center + j as f64 * step;
                (o, score(&video, clock_ev, h, o))
            })
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap_or((center, 0.0))
    };
    let mut h = init;
    // The clock: known, or from the activity over time when it varies, and then kept: a clock
    // error moves the events by their flow, and under a steady pan, turn or zoom an affine
    // change of the geometry does the same, so the polarities' own clock trades against the
    // geometry's last tenths of a pixel (on the simulated rig it came up to 0.68 ms off over
    // noise draws, the activity's within 0.1 ms). Else, when the activity does not correlate
    // (no change of motion), coarse (half a frame) at the initial geometry, refined with it.
    let (fixed, source) = match clock {
        Clock::Known(ns) => (Some(ns as f64), ClockSource::Known),
        Clock::Within(_) => {
            match activity_offset(&video, &activity_times(events), max_offset_ns as f64) {
                Some((o, c)) if c >= ACTIVITY_MIN_CORRELATION => {
                    (Some(o), ClockSource::Activity(c))
                }
                found => (None, ClockSource::Searched(found.map_or(0.0, |(_, c)| c))),
            }
        }
    };
    let mut offset = match fixed {
        Some(o) => o,
        None => offsets(&h, 0.0, max_offset_ns as f64, video.period_ns / 2.0).0,
    };
    // Scale and shift, coarse: scales of the event camera's frame about its centre within
    // 10% (2% steps) and shifts within 16 pixels (2-pixel steps), on the video blurred over 5
    // pixels and a tenth of the events; then the shift to half a pixel.
    let coarse = video.blurred(2);
    let few = Sample {
        x: ev.x.iter().step_by(10).copied().collect(),
        y: ev.y.iter().step_by(10).copied().collect(),
        t: ev.t.iter().step_by(10).copied().collect(),
        p: ev.p.iter().step_by(10).copied().collect(),
    };
    let (cx, cy) = (events.width as f64 / 2.0, events.height as f64 / 2.0);
    let scaled = |h: &Homography, k: f64| {
        Homography::scale_translate(k, k, cx * (1.0 - k), cy * (1.0 - k))
            .map_or(*h, |s| h.after(&s))
    };
    let mut best = (h, f64::MIN);
    for j in -5..=5 {
        let hs = scaled(&h, 1.0 + 0.02 * f64::from(j));
        for dy in -8..=8 {
            for dx in -8..=8 {
                let m = with_shift(&hs, 2.0 * f64::from(dx), 2.0 * f64::from(dy));
                let s = score(&coarse, &few, &m, offset);
                if s > best.1 {
                    best = (m, s);
                }
            }
        }
    }
    let mut fine = (best.0, f64::MIN);
    for dy in -4..=4 {
        for dx in -4..=4 {
            let m = with_shift(&best.0, 0.5 * f64::from(dx), 0.5 * f64::from(dy));
            let s = score(&coarse, &ev, &m, offset);
            if s > fine.1 {
                fine = (m, s);
            }
        }
    }
    h = fine.0;
    let best = (0.0, 0.0, fine.1);
    tracing::debug!(
        offset,
        dx = best.0,
        dy = best.1,
        score = best.2,
        "rig: coarse"
    );
    // Nelder-Mead over the coefficients at a fixed clock. Affine first (the perspective terms
    // are nearly invisible in the middle of the frame and drift): six coefficients in rounds 0
    // and 1, all eight after; round 0 on the blurred video with larger steps.
    let refine = |h: Homography, offset: f64, round: usize| -> Homography {
        let params = if round < 2 { 6 } else { PERSPECTIVE };
        let c0 = h.coefficients();
        let on = if round == 0 { &coarse } else { &video };
        let objective = |v: &[f64]| {
            let mut c = c0;
            c[..params].copy_from_slice(v);
            match Homography::new(c) {
                Ok(m) => -score(on, &ev, &m, offset),
                Err(_) => 0.0,
            }
        };
        let scale = if round == 0 { 1.0 } else { 0.3 };
        let step = [
            0.01 * scale,
            0.01 * scale,
            0.5 * scale,
            0.01 * scale,
            0.01 * scale,
            0.5 * scale,
            2e-6,
            2e-6,
        ];
        let v = nelder_mead(&objective, &c0[..params], &step[..params], 600);
        let mut c = c0;
        c[..params].copy_from_slice(&v);
        let h = Homography::new(c).unwrap_or(h);
        tracing::debug!(
            round,
            offset,
            score = score(&video, &ev, &h, offset),
            "rig: round"
        );
        h
    };
    for round in 0..4 {
        if fixed.is_none() {
            (offset, _) = offsets(&h, offset, video.period_ns * 2.0, video.period_ns / 8.0);
        }
        h = refine(h, offset, round);
    }
    // The clock again with the geometry found (within 5 frames), the geometry at that clock,
    // then the clock fine: a parabola through the best of a 1/16-frame grid and its neighbours.
    if fixed.is_none() {
        (offset, _) = offsets(&h, offset, video.period_ns * 5.0, video.period_ns / 8.0);
    }
    h = refine(h, offset, 4);
    if fixed.is_none() {
        offset = fine_offset(&video, clock_ev, &h, offset);
        // Clock and geometry together: along a motion a clock error and a shift explain the
        // events alike, and refining one at a time stops in that valley.
        let c0 = h.coefficients();
        let objective = |v: &[f64]| {
            let mut c = c0;
            c[..6].copy_from_slice(&v[..6]);
            match Homography::new(c) {
                Ok(m) => -score(&video, &ev, &m, v[6]),
                Err(_) => 0.0,
            }
        };
        let mut v = c0[..6].to_vec();
        v.push(offset);
        let step = [
            0.003,
            0.003,
            0.15,
            0.003,
            0.003,
            0.15,
            video.period_ns / 8.0,
        ];
        // Restarted: a simplex that has shrunk across the valley crawls along it.
        for _ in 0..JOINT_RESTARTS {
            v = nelder_mead(&objective, &v, &step, 800);
        }
        let mut c = c0;
        c[..6].copy_from_slice(&v[..6]);
        // The best of the separate and the joint answers, scored as the clock is searched (on
        // the events within bursts, which time the clock best).
        if let Ok(joint) = Homography::new(c) {
            let mut best = (score(&video, clock_ev, &h, offset), h, offset);
            for o in [v[6], fine_offset(&video, clock_ev, &joint, v[6])] {
                let s = score(&video, clock_ev, &joint, o);
                if s > best.0 {
                    best = (s, joint, o);
                }
            }
            (h, offset) = (best.1, best.2);
        }
    }
    // Last, the geometry on the dense evidence at the clock found.
    if let Some(better) = levels::refine(spikes, events, &h, offset) {
        h = better;
    }
    let score = score(&video, &ev, &h, offset);
    Ok(RigEstimate {
        homography: h,
        offset_ns: offset.round() as i64,
        score,
        events: ev.x.len(),
        clock: source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A burst's first event is timed half the burst's next interval early, the others at the
    /// middle of the interval since the one before; a lone event (nothing at its pixel within
    /// [`MAX_INTERVAL_NS`] either side) at itself; another pixel's events do not mix in.
    #[test]
    fn an_events_activity_time_is_the_middle_of_its_interval() {
        let mut ev = EventBatch::empty(3, 2, 0, 40_000_000, 0);
        for (t, x, y) in [
            (10_000_000, 0, 0),
            (10_100_000, 2, 1),
            (10_200_000, 0, 0),
            (10_400_000, 0, 0),
            (11_000_000, 2, 1),
            (30_000_000, 1, 0),
        ] {
            ev.t_ns.push(t);
            ev.x.push(x);
            ev.y.push(y);
            ev.polarity.push(1);
        }
        let times = activity_times(&ev);
        let expected = [
            9_900_000.0,
            9_650_000.0,
            10_100_000.0,
            10_300_000.0,
            10_550_000.0,
            30_000_000.0,
        ];
        assert_eq!(times.len(), expected.len());
        for (t, e) in times.iter().zip(expected) {
            assert!((t - e).abs() < 1.0, "{times:?}");
        }
    }
}
