//! The last step of the rig's estimate: the geometry refined on every frame of every pixel.
//!
//! A pixel's events spell its log intensity as a staircase of thresholds; the line through the
//! levels at the events' times (each event at the level it crossed) follows the light without
//! the staircase's lag of half a threshold's time, and `exp(contrast * level)` is the light
//! relative to the pixel's start. The spike camera counts the light itself, frame by frame. So
//! at the right mapping each spike pixel's counts are a line (a gain and an offset of its own)
//! of the relative light the events give at its point. [`dense_score`] is the share of the
//! counts' variance those lines explain, the counts weighted by their Poisson noise.
//!
//! Three choices keep its peak where the truth is. The spike counts are the data and stay as
//! they are for every mapping; the events' light is what is interpolated (sampling the noisy
//! counts at moving points instead favours the points between pixel centres, where
//! interpolation averages the noise away: on the simulated rig that put the estimate 1-1.5 px
//! off). The spike pixels are a fixed set, those inside the event camera's frame at the start
//! (a set that followed the mapping would reward one that covers more pixels). And the light,
//! not the level, is fitted: the counts grow with the light, and a line through the log level
//! left the estimate 0.1-0.3 px further off on one texture (the contrast threshold is chosen
//! among a few, the one that explains the counts best).
//!
//! Unlike the events' polarities against the change at the events' times ([`super::estimate`]'s
//! earlier steps), this uses every frame of every pixel that fired and the counts undifferenced,
//! so it sees finer; but its basin is narrow, so it runs last, from their answer.

use neuspike_geometry::Homography;
use neuspike_schemas::{EventBatch, SpikeChunk, fired_pixels};

/// A level is taken to have been left at most this long before the event that crossed the next
/// one, after a pause (the first event of a burst): the light's change started shortly before.
const RISE_NS: i64 = 1_000_000;

/// The spike camera's counts per frame, pixel by pixel (`[pixel][frame]`: one pixel's series in
/// one run of memory).
pub(super) struct CountSeries {
    width: usize,
    height: usize,
    frames: usize,
    /// Time of frame 0's centre on the spike clock, and the frame period, ns.
    t0_ns: f64,
    period_ns: f64,
    counts: Vec<f32>,
    /// Each pixel's mean count per frame.
    mean: Vec<f64>,
    /// Each pixel's sum of squared deviations of its counts from their mean.
    spread: Vec<f64>,
}

impl CountSeries {
    /// Counts over frames of `frame_planes` planes; `None` without a whole frame or pixels.
    pub(super) fn new(spikes: &SpikeChunk, frame_planes: usize) -> Option<CountSeries> {
        let (w, h) = (spikes.width, spikes.height);
        let n = w * h;
        let frame_planes = frame_planes.max(1);
        let frames = spikes.n_planes / frame_planes;
        if frames < 2 || n == 0 {
            return None;
        }
        let per = n.div_ceil(8);
        let mut counts = vec![0f32; n * frames];
        for (k, plane) in spikes
            .bits
            .chunks_exact(per)
            .take(frames * frame_planes)
            .enumerate()
        {
            let f = k / frame_planes;
            for i in fired_pixels(plane, n) {
                counts[i * frames + f] += 1.0;
            }
        }
        let period_ns = (frame_planes as i64 * spikes.plane_period_ns) as f64;
        // Plane k covers (t_k - T, t_k]: frame 0 starts a period before the first plane's time.
        let t0_ns = spikes.t_first_ns as f64 - spikes.plane_period_ns as f64 + period_ns / 2.0;
        Some(CountSeries::from_counts(
            [w, h, frames],
            t0_ns,
            period_ns,
            counts,
        ))
    }

    /// The series of `counts` (`[pixel][frame]` of a `[width, height, frames]` recording),
    /// frame 0 centred on `t0_ns`, a frame every `period_ns`.
    fn from_counts(
        [width, height, frames]: [usize; 3],
        t0_ns: f64,
        period_ns: f64,
        counts: Vec<f32>,
    ) -> CountSeries {
        let frames = frames.max(1);
        let mean: Vec<f64> = counts
            .chunks_exact(frames)
            .map(|c| c.iter().map(|&v| f64::from(v)).sum::<f64>() / frames as f64)
            .collect();
        let spread = counts
            .chunks_exact(frames)
            .zip(&mean)
            .map(|(c, m)| c.iter().map(|&v| (f64::from(v) - m).powi(2)).sum())
            .collect();
        CountSeries {
            width,
            height,
            frames,
            t0_ns,
            period_ns,
            counts,
            mean,
            spread,
        }
    }
}

impl CountSeries {
    /// Spike pixel `i`'s centre and the weight of its counts (the inverse of their mean, their
    /// Poisson variance; a mean under one count in the whole series counts as that).
    #[inline]
    fn centre_and_weight(&self, i: usize) -> ((f64, f64), f64) {
        let centre = ((i % self.width) as f64 + 0.5, (i / self.width) as f64 + 0.5);
        (centre, 1.0 / self.mean[i].max(1.0 / self.frames as f64))
    }
}

/// Every event pixel's light over the count frames: `exp(contrast * level)` scaled to the
/// pixel's mean light, centred (that mean taken away): `[pixel][frame]` over the event camera's
/// whole grid, zero where a pixel's level never changes.
pub(super) struct LevelSeries {
    width: usize,
    height: usize,
    frames: usize,
    levels: Vec<f32>,
    /// Pixels whose level changes.
    changing: usize,
}

impl LevelSeries {
    /// The light at the count frames' centres, `contrast` the log intensity of one event, the
    /// event clock `offset_ns` ahead of the spike clock, `light` each event pixel's mean light
    /// (see [`absolute_light`]).
    pub(super) fn new(
        events: &EventBatch,
        counts: &CountSeries,
        offset_ns: f64,
        contrast: f32,
        light: &[f32],
    ) -> LevelSeries {
        let (w, h) = (events.width, events.height);
        // Events of each pixel, in time order (the batch is).
        let mut per_pixel: Vec<Vec<(i64, f32)>> = vec![Vec::new(); w * h];
        for i in 0..events.len() {
            let (x, y) = (usize::from(events.x[i]), usize::from(events.y[i]));
            if x < w && y < h {
                let p = if events.polarity[i] > 0 { 1.0 } else { -1.0 };
                per_pixel[y * w + x].push((events.t_ns[i], p));
            }
        }
        let f = counts.frames;
        let mut levels = vec![0f32; w * h * f];
        let mut changing = 0;
        let mut knots: Vec<(f64, f32)> = Vec::new();
        for (p, (ev, series)) in per_pixel
            .iter()
            .zip(levels.chunks_exact_mut(f.max(1)))
            .enumerate()
        {
            if ev.is_empty() {
                continue;
            }
            // Knots (spike-clock time, level): each event at the level it reached; after a
            // pause, the level before it held until shortly before.
            knots.clear();
            let mut level = 0f32;
            for (k, &(t, p)) in ev.iter().enumerate() {
                let since = if k == 0 { i64::MAX } else { t - ev[k - 1].0 };
                if since > RISE_NS {
                    let next = ev.get(k + 1).map_or(RISE_NS, |n| (n.0 - t).min(RISE_NS));
                    knots.push(((t - next) as f64 - offset_ns, level));
                }
                level += p;
                knots.push((t as f64 - offset_ns, level));
            }
            let mut j = 0;
            for (k, s) in series.iter_mut().enumerate() {
                let t = counts.t0_ns + k as f64 * counts.period_ns;
                while j < knots.len() && knots[j].0 <= t {
                    j += 1;
                }
                *s = if j == 0 {
                    0.0
                } else if j == knots.len() {
                    knots[j - 1].1
                } else {
                    let (a, b) = (knots[j - 1], knots[j]);
                    let span = b.0 - a.0;
                    if span > 0.0 {
                        a.1 + (b.1 - a.1) * ((t - a.0) / span) as f32
                    } else {
                        b.1
                    }
                };
            }
            // The exponent within +-80: e^80 and e^-80 are finite and positive in f32, so the
            // mean below is too and the ratio to it is finite (a level 200 events from the
            // start at a contrast of 0.4 is clipped there).
            for v in series.iter_mut() {
                *v = (contrast * *v).clamp(-80.0, 80.0).exp();
            }
            // To the pixel's light.
            let relative_mean = series.iter().map(|&v| f64::from(v)).sum::<f64>() / f as f64;
            let mean = light.get(p).map_or(1.0, |&l| f64::from(l));
            let k = mean / relative_mean;
            let mut energy = 0.0;
            for v in series.iter_mut() {
                *v = (f64::from(*v) * k - mean) as f32;
                energy += f64::from(*v).powi(2);
            }
            if energy > 0.0 {
                changing += 1;
            }
        }
        LevelSeries {
            width: w,
            height: h,
            frames: f,
            levels,
            changing,
        }
    }

    /// Pixels whose level changes within the frames.
    pub(super) fn changing(&self) -> usize {
        self.changing
    }

    /// The level series at event point `(x, y)` (pixel centres at +0.5), bilinear, against the
    /// series `n`: `(sum of n * level, sum of level^2)`; `None` outside the grid. Eight
    /// partial sums, so that the loop runs in vector lanes.
    #[inline]
    fn fit(&self, x: f64, y: f64, n: &[f32]) -> Option<(f64, f64)> {
        let (fx, fy) = (x - 0.5, y - 0.5);
        if !(fx >= 0.0 && fy >= 0.0) {
            return None;
        }
        let (x0, y0) = (fx as usize, fy as usize);
        if x0 + 1 >= self.width || y0 + 1 >= self.height {
            return None;
        }
        let (ax, ay) = ((fx - x0 as f64) as f32, (fy - y0 as f64) as f32);
        let f = self.frames;
        let at = |px: usize, py: usize| {
            let i = py * self.width + px;
            &self.levels[i * f..(i + 1) * f]
        };
        let (a, b, c, d) = (
            at(x0, y0),
            at(x0 + 1, y0),
            at(x0, y0 + 1),
            at(x0 + 1, y0 + 1),
        );
        let (wa, wb, wc, wd) = (
            (1.0 - ax) * (1.0 - ay),
            ax * (1.0 - ay),
            (1.0 - ax) * ay,
            ax * ay,
        );
        const LANES: usize = 8;
        let (mut nl, mut ll) = ([0f32; LANES], [0f32; LANES]);
        let whole = f - f % LANES;
        fn lanes(s: &[f32], whole: usize) -> std::slice::ChunksExact<'_, f32> {
            s[..whole].chunks_exact(LANES)
        }
        for ((((n8, a8), b8), c8), d8) in lanes(n, whole)
            .zip(lanes(a, whole))
            .zip(lanes(b, whole))
            .zip(lanes(c, whole))
            .zip(lanes(d, whole))
        {
            for j in 0..LANES {
                let l = wa * a8[j] + wb * b8[j] + wc * c8[j] + wd * d8[j];
                nl[j] += n8[j] * l;
                ll[j] += l * l;
            }
        }
        let (mut snl, mut sll) = (0f64, 0f64);
        for j in 0..LANES {
            snl += f64::from(nl[j]);
            sll += f64::from(ll[j]);
        }
        for k in whole..f {
            let l = wa * a[k] + wb * b[k] + wc * c[k] + wd * d[k];
            snl += f64::from(n[k] * l);
            sll += f64::from(l * l);
        }
        Some((snl, sll))
    }
}

/// The spike pixels that `h` sends at least `margin` event pixels inside the event camera's
/// frame: the fixed set [`dense_score`] sums over (a set that followed the mapping would
/// reward a mapping that covers more pixels).
pub(super) fn pixels_inside(
    counts: &CountSeries,
    levels: &LevelSeries,
    h: &Homography,
    margin: f64,
) -> Vec<usize> {
    let inv = h.inverse();
    (0..counts.width * counts.height)
        .filter(|&i| {
            let (x, y) = (
                (i % counts.width) as f64 + 0.5,
                (i / counts.width) as f64 + 0.5,
            );
            inv.apply(x, y).is_some_and(|(u, v)| {
                u >= margin
                    && v >= margin
                    && u <= levels.width as f64 - margin
                    && v <= levels.height as f64 - margin
            })
        })
        .collect()
}

/// The share of the spike counts' variance the events explain through `h` (event pixel ->
/// spike pixel), over the spike pixels `pixels`: for each, the events' level interpolated at
/// the point `h` sends there, fitted to the pixel's counts by a line (a gain and an offset of
/// its own), the variance explained weighted by the inverse of the pixel's mean count (its
/// Poisson noise), summed and divided by the pixels' weighted variance. The spike counts are
/// the data and stay as they are for every `h` (sampling the noisy counts at moving points
/// instead would favour points between pixel centres, where interpolation averages noise
/// away); a pixel sent outside the event camera's frame explains nothing.
pub(super) fn dense_score(
    counts: &CountSeries,
    levels: &LevelSeries,
    h: &Homography,
    pixels: &[usize],
) -> f64 {
    let f = counts.frames;
    let inv = h.inverse();
    let (mut explained, mut total) = (0.0f64, 0.0f64);
    for &i in pixels {
        let n = &counts.counts[i * f..(i + 1) * f];
        let ((x, y), weight) = counts.centre_and_weight(i);
        total += counts.spread[i] * weight;
        let Some((u, v)) = inv.apply(x, y) else {
            continue;
        };
        let Some((nl, ll)) = levels.fit(u, v, n) else {
            continue;
        };
        if ll > 1e-6 {
            explained += nl * nl / ll * weight;
        }
    }
    if total <= 0.0 { 0.0 } else { explained / total }
}

/// Event pixels either side of a spike pixel's starting point that [`Tabled`] holds products
/// for: the refinement may move a point this far (less one) before the slow path takes over.
const REACH: usize = 3;
/// The side of the tabled window.
const SIDE: usize = 2 * REACH;

/// [`dense_score`] for mappings near a starting one, from tables of the series' products: each
/// spike pixel's counts against the level series of a `SIDE x SIDE` window of event pixels
/// around its starting point, and each event pixel's levels against its own and its right,
/// lower and diagonal neighbours'. A bilinear sample's products with the counts and with itself
/// are then sums of a few table entries, so a score takes a few operations per pixel instead of
/// a pass over every frame. Points that leave their window take the slow path.
pub(super) struct Tabled<'a> {
    counts: &'a CountSeries,
    levels: &'a LevelSeries,
    pixels: &'a [usize],
    /// Per pixel of `pixels`: the window's first column and row.
    origin: Vec<(usize, usize)>,
    /// Per pixel of `pixels`: `SIDE * SIDE` products of its counts with the window's levels.
    dots: Vec<f64>,
    /// Per event pixel: `[self, right, down, down-right, right x down]` products.
    gram: Vec<[f64; 5]>,
}

impl<'a> Tabled<'a> {
    pub(super) fn new(
        counts: &'a CountSeries,
        levels: &'a LevelSeries,
        h: &Homography,
        pixels: &'a [usize],
    ) -> Tabled<'a> {
        let f = levels.frames;
        let (w, ht) = (levels.width, levels.height);
        let series = |p: usize| &levels.levels[p * f..(p + 1) * f];
        let dot = |a: &[f32], b: &[f32]| -> f64 {
            a.iter()
                .zip(b)
                .map(|(x, y)| f64::from(*x) * f64::from(*y))
                .sum()
        };
        let mut gram = vec![[0f64; 5]; w * ht];
        for y in 0..ht {
            for x in 0..w {
                let p = y * w + x;
                let g = &mut gram[p];
                g[0] = dot(series(p), series(p));
                if x + 1 < w {
                    g[1] = dot(series(p), series(p + 1));
                }
                if y + 1 < ht {
                    g[2] = dot(series(p), series(p + w));
                }
                if x + 1 < w && y + 1 < ht {
                    g[3] = dot(series(p), series(p + w + 1));
                    g[4] = dot(series(p + 1), series(p + w));
                }
            }
        }
        let inv = h.inverse();
        let mut origin = Vec::with_capacity(pixels.len());
        let mut dots = vec![0f64; pixels.len() * SIDE * SIDE];
        for (k, &i) in pixels.iter().enumerate() {
            let (x, y) = (
                (i % counts.width) as f64 + 0.5,
                (i / counts.width) as f64 + 0.5,
            );
            let (u, v) = inv.apply(x, y).unwrap_or((-1e9, -1e9));
            // The window starts REACH - 1 pixels before the sample's first corner.
            let start = |c: f64, size: usize| {
                let first = (c - 0.5).floor();
                if first.is_finite() {
                    (first as i64 - (REACH as i64 - 1)).clamp(0, size.saturating_sub(SIDE) as i64)
                        as usize
                } else {
                    0
                }
            };
            let (ox, oy) = (start(u, w), start(v, ht));
            origin.push((ox, oy));
            let n = &counts.counts[i * counts.frames..(i + 1) * counts.frames];
            for j in 0..SIDE.min(ht) {
                for q in 0..SIDE.min(w) {
                    dots[k * SIDE * SIDE + j * SIDE + q] = dot(n, series((oy + j) * w + ox + q));
                }
            }
        }
        Tabled {
            counts,
            levels,
            pixels,
            origin,
            dots,
            gram,
        }
    }

    /// [`dense_score`] of `h`.
    pub(super) fn score(&self, h: &Homography) -> f64 {
        let (counts, levels) = (self.counts, self.levels);
        let f = counts.frames;
        let w = levels.width;
        let inv = h.inverse();
        let (mut explained, mut total) = (0.0f64, 0.0f64);
        for (k, &i) in self.pixels.iter().enumerate() {
            let ((x, y), weight) = counts.centre_and_weight(i);
            total += counts.spread[i] * weight;
            let Some((u, v)) = inv.apply(x, y) else {
                continue;
            };
            let (fx, fy) = (u - 0.5, v - 0.5);
            if !(fx >= 0.0 && fy >= 0.0) {
                continue;
            }
            let (x0, y0) = (fx as usize, fy as usize);
            if x0 + 1 >= w || y0 + 1 >= levels.height {
                continue;
            }
            let (ox, oy) = self.origin[k];
            let fit = if x0 >= ox && y0 >= oy && x0 + 1 < ox + SIDE && y0 + 1 < oy + SIDE {
                let (ax, ay) = ((fx - x0 as f64) as f32, (fy - y0 as f64) as f32);
                let (wa, wb, wc, wd) = (
                    f64::from((1.0 - ax) * (1.0 - ay)),
                    f64::from(ax * (1.0 - ay)),
                    f64::from((1.0 - ax) * ay),
                    f64::from(ax * ay),
                );
                let d = &self.dots[k * SIDE * SIDE..(k + 1) * SIDE * SIDE];
                let at = (y0 - oy) * SIDE + (x0 - ox);
                let nl = wa * d[at] + wb * d[at + 1] + wc * d[at + SIDE] + wd * d[at + SIDE + 1];
                let a = y0 * w + x0;
                let (ga, gb, gc, gd) = (
                    self.gram[a],
                    self.gram[a + 1],
                    self.gram[a + w],
                    self.gram[a + w + 1],
                );
                let ll = wa * wa * ga[0]
                    + wb * wb * gb[0]
                    + wc * wc * gc[0]
                    + wd * wd * gd[0]
                    + 2.0
                        * (wa * wb * ga[1]
                            + wa * wc * ga[2]
                            + wa * wd * ga[3]
                            + wb * wc * ga[4]
                            + wb * wd * gb[2]
                            + wc * wd * gc[1]);
                (nl, ll)
            } else {
                let n = &counts.counts[i * f..(i + 1) * f];
                match levels.fit(u, v, n) {
                    Some(fit) => fit,
                    None => continue,
                }
            };
            let (nl, ll) = fit;
            if ll > 1e-6 {
                explained += nl * nl / ll * weight;
            }
        }
        if total <= 0.0 { 0.0 } else { explained / total }
    }
}

/// Planes per frame of the count series (4: 200 us at 20 kHz), at least.
pub(super) const COUNT_FRAME_PLANES: usize = 4;
/// Frames of the count series, at most: longer recordings take longer frames (the series hold
/// `pixels x frames` values, 92 MB for a DAVIS346's levels at this many).
pub(super) const MAX_COUNT_FRAMES: usize = 256;

/// Event-camera pixels a spike pixel's point must lie inside the event camera's frame to be
/// counted, at the geometry the refinement starts from.
const MARGIN_PX: f64 = 2.5;

/// The contrast thresholds tried (log intensity per event), the best kept.
const CONTRASTS: [f32; 6] = [0.1, 0.15, 0.2, 0.25, 0.3, 0.4];

/// Each event pixel's mean light, in spike counts per frame: the spike pixels' mean counts,
/// bilinear, at the point `h` sends the pixel's centre to (clamped to the spike frame; a point
/// at infinity keeps 1). The events give each pixel's light relative to its own start only; a
/// point between event pixels blends their series, and relative series weigh a pixel that
/// started dark as much as one that started bright, which moves where an edge seems to be (on
/// the simulated rig, up to 0.3 px of an x-stretch on a texture of few edges). The means come
/// from the mapping the refinement starts at; near the answer they hardly change.
fn absolute_light(counts: &CountSeries, events: &EventBatch, h: &Homography) -> Vec<f32> {
    let (w, ht) = (events.width, events.height);
    let mut out = vec![1f32; w * ht];
    for v in 0..ht {
        for u in 0..w {
            let Some((x, y)) = h.apply(u as f64 + 0.5, v as f64 + 0.5) else {
                continue;
            };
            let fx = (x - 0.5).clamp(0.0, (counts.width - 1) as f64);
            let fy = (y - 0.5).clamp(0.0, (counts.height - 1) as f64);
            let (x0, y0) = (fx as usize, fy as usize);
            let (x1, y1) = (
                (x0 + 1).min(counts.width - 1),
                (y0 + 1).min(counts.height - 1),
            );
            let (ax, ay) = (fx - x0 as f64, fy - y0 as f64);
            let m = |xx: usize, yy: usize| counts.mean[yy * counts.width + xx];
            let val = (1.0 - ax) * (1.0 - ay) * m(x0, y0)
                + ax * (1.0 - ay) * m(x1, y0)
                + (1.0 - ax) * ay * m(x0, y1)
                + ax * ay * m(x1, y1);
            out[v * w + u] = val.max(1e-3) as f32;
        }
    }
    out
}

/// The affine coefficients of `h` refined on the dense evidence at the clock offset `offset_ns`
/// (the event clock minus the spike clock): Nelder-Mead, restarted once, after the contrast
/// threshold is chosen at `h`. `None` when under 100 event pixels change within the spike
/// recording or the recording is shorter than two count frames.
pub(super) fn refine(
    spikes: &SpikeChunk,
    events: &EventBatch,
    h: &Homography,
    offset_ns: f64,
) -> Option<Homography> {
    let frame_planes = COUNT_FRAME_PLANES.max(spikes.n_planes.div_ceil(MAX_COUNT_FRAMES));
    let counts = CountSeries::new(spikes, frame_planes)?;
    let scale = absolute_light(&counts, events, h);
    let probe = LevelSeries::new(events, &counts, offset_ns, CONTRASTS[0], &scale);
    if probe.changing() < 100 {
        return None;
    }
    let pixels = pixels_inside(&counts, &probe, h, MARGIN_PX);
    // The contrast threshold that explains the counts best at `h`, the probe's first.
    let mut best = (
        dense_score(&counts, &probe, h, &pixels),
        probe,
        CONTRASTS[0],
    );
    for c in &CONTRASTS[1..] {
        let lv = LevelSeries::new(events, &counts, offset_ns, *c, &scale);
        let s = dense_score(&counts, &lv, h, &pixels);
        if s > best.0 {
            best = (s, lv, *c);
        }
    }
    let (_, lv, contrast) = best;
    let tabled = Tabled::new(&counts, &lv, h, &pixels);
    let c0 = h.coefficients();
    let objective = |v: &[f64]| {
        let mut c = c0;
        c[..6].copy_from_slice(v);
        match Homography::new(c) {
            Ok(m) => -tabled.score(&m),
            Err(_) => 0.0,
        }
    };
    let step = [0.003, 0.003, 0.15, 0.003, 0.003, 0.15];
    // Restarted with a simplex twice as large: the first stops in the valley's nearest part.
    let mut v = super::nelder_mead(&objective, &c0[..6], &step, 600);
    let wide = step.map(|s| 2.0 * s);
    v = super::nelder_mead(&objective, &v, &wide, 600);
    tracing::debug!(
        contrast,
        before = -objective(&c0[..6]),
        after = -objective(&v),
        "rig: dense"
    );
    let mut c = c0;
    c[..6].copy_from_slice(&v);
    Homography::new(c).ok()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Counts and levels of random content: a 12x10 spike grid, a 10x9 event grid, 37 frames
    /// (not a multiple of the eight lanes).
    fn series(seed: u64) -> (CountSeries, LevelSeries) {
        let mut state = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        let mut next = move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let frames = 37;
        let (w, h) = (12, 10);
        let counts: Vec<f32> = (0..w * h * frames)
            .map(|_| (next() * 4.0).floor())
            .collect();
        let counts = CountSeries::from_counts([w, h, frames], 0.0, 100_000.0, counts);
        let (lw, lh) = (10, 9);
        let levels = LevelSeries {
            width: lw,
            height: lh,
            frames,
            levels: (0..lw * lh * frames).map(|_| next() - 0.5).collect(),
            changing: lw * lh,
        };
        (counts, levels)
    }

    proptest! {
        /// The tabled score is the plain one, near the starting mapping (the tables) and far
        /// from it (the slow path).
        #[test]
        fn the_tabled_score_is_the_plain_one(
            seed in 0u64..1000,
            scale in 0.8f64..1.0,
            dx in -3.0f64..3.0,
            dy in -3.0f64..3.0,
            turn in -0.05f64..0.05,
        ) {
            let (counts, levels) = series(seed);
            let start = Homography::scale_translate(1.2, 1.1, -0.5, 0.3).expect("a start");
            let pixels: Vec<usize> = (0..counts.width * counts.height).collect();
            let tabled = Tabled::new(&counts, &levels, &start, &pixels);
            let moved = Homography::new([
                1.2 * scale, turn, -0.5 + dx, -turn, 1.1 * scale, 0.3 + dy, 0.0, 0.0, 1.0,
            ])
            .expect("a mapping");
            for h in [start, moved] {
                let (fast, plain) = (tabled.score(&h), dense_score(&counts, &levels, &h, &pixels));
                prop_assert!(plain > 0.0);
                prop_assert!((fast - plain).abs() <= 1e-5 * plain, "{fast} vs {plain}");
            }
        }
    }

    /// Two event pixels of a 2x1 camera: the first brightens by `up` events `gap_ns` apart
    /// from 2 ms on, the second darkens by one event at 3 ms. Ten count frames of 1 ms
    /// centred on 0.5, 1.5, ... ms.
    fn two_pixels(up: usize, gap_ns: i64) -> (EventBatch, CountSeries) {
        let mut ev = EventBatch::empty(2, 1, 0, 10_000_000, 0);
        for k in 0..up {
            ev.t_ns.push(2_000_000 + gap_ns * k as i64);
            ev.x.push(0);
            ev.y.push(0);
            ev.polarity.push(1);
        }
        // The batch in time order.
        let at = ev.t_ns.partition_point(|&t| t <= 3_000_000);
        ev.t_ns.insert(at, 3_000_000);
        ev.x.insert(at, 1);
        ev.y.insert(at, 0);
        ev.polarity.insert(at, -1);
        let counts = CountSeries::from_counts([2, 1, 10], 500_000.0, 1_000_000.0, vec![1.0; 20]);
        (ev, counts)
    }

    /// Each pixel's series is its light, the mean given: its mean over the frames is that
    /// light (the series holds the light less it), and frames a level apart differ by
    /// `exp(contrast)`.
    #[test]
    fn a_pixels_series_is_its_light_at_the_mean_given() {
        let (ev, counts) = two_pixels(3, 1_000_000);
        let light = [40.0f32, 5.0];
        let lv = LevelSeries::new(&ev, &counts, 0.0, 0.2, &light);
        assert_eq!(lv.changing(), 2);
        for (p, &l) in light.iter().enumerate() {
            let series: Vec<f64> = lv.levels[p * 10..(p + 1) * 10]
                .iter()
                .map(|&v| f64::from(v) + f64::from(l))
                .collect();
            let mean = series.iter().sum::<f64>() / 10.0;
            assert!(
                (mean - f64::from(l)).abs() < 1e-4 * f64::from(l),
                "{p}: {mean}"
            );
            // Before the first event and after the last, the level holds.
            let (first, last) = (series[0], series[9]);
            let ratio = if p == 0 { 0.2f64 * 3.0 } else { -0.2 };
            assert!(
                (last / first - ratio.exp()).abs() < 1e-4,
                "{p}: {first} -> {last}"
            );
        }
    }

    /// A level far from the start (500 events within 5 ms at a contrast of 0.4: e^200
    /// overflows) keeps every value finite.
    #[test]
    fn a_level_far_from_the_start_stays_finite() {
        let (ev, counts) = two_pixels(500, 10_000);
        let lv = LevelSeries::new(&ev, &counts, 0.0, 0.4, &[30.0, 30.0]);
        assert!(lv.levels.iter().all(|v| v.is_finite()));
        assert_eq!(lv.changing(), 2);
    }
}
