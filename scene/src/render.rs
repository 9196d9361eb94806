//! Rendering: the scalar reference (the oracle) and the fast path checked against it.
//!
//! Destination pixel `(r, c)` of an `R x C` grid covers scene points
//! `x = (c + (kx + 1/2) / n) * W / C`, `y = (r + (ky + 1/2) / n) * H / R` for the `n x n`
//! sub-samples. Each is mapped to texture coordinates by the affine [`ViewMap`] of the instant,
//! sampled bilinearly with periodic wrap, multiplied by the gain map if any, and averaged.

use ndarray::{ArrayViewMut2, Axis};
use rayon::prelude::*;

use crate::Scene;

/// Below this many sub-samples per frame the fast path stays on the calling thread.
pub(crate) const PARALLEL_MIN_SAMPLES: usize = 1 << 15;
/// Rows per rayon task.
pub(crate) const ROWS_PER_TASK: usize = 8;
/// `|log s(t)|` is clamped to this, so extreme zoom never produces infinities.
pub(crate) const MAX_LOG_ZOOM: f64 = 30.0;

/// Affine map from scene coordinates to texture coordinates at one instant:
/// `u = a11 x + a12 y + b1`, `v = a21 x + a22 y + b2`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ViewMap {
    pub a11: f64,
    pub a12: f64,
    pub a21: f64,
    pub a22: f64,
    pub b1: f64,
    pub b2: f64,
}

impl ViewMap {
    /// The map at `t_ns`: view point `p` shows texture point `R(-theta) (p - c) / s + c - v t`,
    /// with the translation reduced modulo the texture period (exact, the texture is periodic).
    pub fn at(scene: &Scene, t_ns: i64) -> ViewMap {
        let m = &scene.spec().motion;
        // Motion time: 0 until the motion starts, held once it stops.
        let t = m.elapsed_s(t_ns);
        let theta = (m.rotation_deg_s * t).rem_euclid(360.0).to_radians();
        let (sin, cos) = if theta == 0.0 {
            (0.0, 1.0)
        } else {
            theta.sin_cos()
        };
        let inv_s = (-m.zoom_per_s * t).clamp(-MAX_LOG_ZOOM, MAX_LOG_ZOOM).exp();
        let period = |x: f64, p: usize| {
            let r = x.rem_euclid(p as f64);
            if r.is_finite() { r } else { 0.0 }
        };
        let tx = period(m.vx_px_s * t, scene.texture.width());
        let ty = period(m.vy_px_s * t, scene.texture.height());
        let cx = scene.width() as f64 / 2.0;
        let cy = scene.height() as f64 / 2.0;
        let (a11, a12, a21, a22) = (inv_s * cos, inv_s * sin, -inv_s * sin, inv_s * cos);
        ViewMap {
            a11,
            a12,
            a21,
            a22,
            b1: cx - tx - (a11 * cx + a12 * cy),
            b2: cy - ty - (a21 * cx + a22 * cy),
        }
    }

    /// Whether `u` depends on `x` only and `v` on `y` only (no rotation).
    fn is_axis_aligned(&self) -> bool {
        self.a12 == 0.0 && self.a21 == 0.0
    }
}

/// Sub-sample offsets `(k + 1/2) / n` within a pixel.
fn sub_offsets(n: usize) -> Vec<f64> {
    (0..n).map(|k| (k as f64 + 0.5) / n as f64).collect()
}

/// Output clamp: without a gain map values stay in `[texture min, 1]` despite rounding; with one,
/// at or above 0. Non-finite means read as 0 first.
fn finish(scene: &Scene, mean: f32) -> f32 {
    clamp_finite(mean, output_bounds(scene))
}

/// The bounds [`finish`] clamps to.
fn output_bounds(scene: &Scene) -> [f32; 2] {
    match scene.gain {
        None => [scene.texture_min, 1.0],
        Some(_) => [0.0, f32::INFINITY],
    }
}

/// `v` (0 if not finite) clamped to `[lo, hi]` (`lo <= hi`), branch-free so that loops of it
/// vectorise.
#[inline(always)]
fn clamp_finite(v: f32, [lo, hi]: [f32; 2]) -> f32 {
    let v = if v.is_finite() { v } else { 0.0 };
    v.max(lo).min(hi)
}

/// The light at view point `(x, y)` (scene pixels) at the instant of `map`: the texture there,
/// bilinear, times the gain map if any; `f64` throughout.
#[inline]
fn sample_view(scene: &Scene, map: &ViewMap, x: f64, y: f64) -> f64 {
    let u = map.a11 * x + map.a12 * y + map.b1;
    let v = map.a21 * x + map.a22 * y + map.b2;
    let s = scene.texture.sample(u, v);
    match &scene.gain {
        Some(gain) => s * gain.gain_at(x, y),
        None => s,
    }
}

/// Where a destination grid lies on a camera's sensor: the sensor's `rows x cols` pixels cover
/// the view, and destination pixel `(r, c)` is sensor pixel `(row0 + r, col0 + c)`, which may lie
/// outside the sensor (the scene goes on beyond the view: a margin).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Region {
    pub sensor_rows: usize,
    pub sensor_cols: usize,
    pub row0: f64,
    pub col0: f64,
}

impl Region {
    /// The region of a `sensor` (`[rows, cols]`) whose first pixel is sensor pixel `origin`
    /// (`[row, col]`, a non-finite one counting as 0).
    pub fn at(sensor: [usize; 2], origin: [f64; 2]) -> Region {
        let finite = |v: f64| if v.is_finite() { v } else { 0.0 };
        Region {
            sensor_rows: sensor[0],
            sensor_cols: sensor[1],
            row0: finite(origin[0]),
            col0: finite(origin[1]),
        }
    }

    /// The whole sensor of `rows x cols`.
    pub fn whole(rows: usize, cols: usize) -> Region {
        Region {
            sensor_rows: rows,
            sensor_cols: cols,
            row0: 0.0,
            col0: 0.0,
        }
    }

    /// Scene pixels per sensor pixel, across and down.
    fn scale(&self, scene: &Scene) -> (f64, f64) {
        (
            scene.width() as f64 / self.sensor_cols.max(1) as f64,
            scene.height() as f64 / self.sensor_rows.max(1) as f64,
        )
    }
}

/// The scalar oracle: every sub-sample computed from scratch in f64.
pub fn render_reference(scene: &Scene, t_ns: i64, dst: ArrayViewMut2<'_, f32>) {
    let (rows, cols) = dst.dim();
    render_reference_region(scene, t_ns, Region::whole(rows, cols), dst);
}

/// [`render_reference`] of a region of a sensor.
pub(crate) fn render_reference_region(
    scene: &Scene,
    t_ns: i64,
    region: Region,
    mut dst: ArrayViewMut2<'_, f32>,
) {
    let (rows, cols) = dst.dim();
    if rows == 0 || cols == 0 {
        return;
    }
    let map = ViewMap::at(scene, t_ns);
    let n = scene.spec().samples_per_pixel;
    let offsets = sub_offsets(n);
    let (sx, sy) = region.scale(scene);
    let (row0, col0) = (region.row0, region.col0);
    for r in 0..rows {
        for c in 0..cols {
            let mut sum = 0.0f64;
            for &oy in &offsets {
                let y = (row0 + r as f64 + oy) * sy;
                for &ox in &offsets {
                    sum += sample_view(scene, &map, (col0 + c as f64 + ox) * sx, y);
                }
            }
            dst[[r, c]] = finish(scene, (sum / (n * n) as f64) as f32);
        }
    }
}

/// [`crate::Scene::render_mapped_into`]: each sub-sample mapped to the view by `map`, sampled
/// as [`render_reference`] samples it.
pub(crate) fn render_mapped(
    scene: &Scene,
    t_ns: i64,
    map: &(dyn Fn(f64, f64) -> Option<(f64, f64)> + Sync),
    dst: ArrayViewMut2<'_, f32>,
) {
    let n = scene.spec().samples_per_pixel;
    let view = ViewMap::at(scene, t_ns);
    // Black where nothing is seen; else the clamp of a plain render.
    mapped_means(
        n,
        map,
        dst,
        &|x, y| sample_view(scene, &view, x, y),
        &|mean| {
            if mean == 0.0 {
                0.0
            } else {
                finish(scene, mean as f32)
            }
        },
    );
}

/// Each destination pixel `(r, c)` the mean of its `n x n` sub-samples at `(c + ox, r + oy)`,
/// taken by `map` to the view's coordinates and read there by `sample` (0 where `map` sends one
/// nowhere), turned into the pixel's value by `finish`. Scalar, in `f64`, rows in parallel.
pub(crate) fn mapped_means(
    n: usize,
    map: &(dyn Fn(f64, f64) -> Option<(f64, f64)> + Sync),
    mut dst: ArrayViewMut2<'_, f32>,
    sample: &(dyn Fn(f64, f64) -> f64 + Sync),
    finish: &(dyn Fn(f64) -> f32 + Sync),
) {
    let (rows, cols) = dst.dim();
    if rows == 0 || cols == 0 {
        return;
    }
    let offsets = sub_offsets(n);
    dst.axis_iter_mut(Axis(0))
        .into_par_iter()
        .enumerate()
        .for_each(|(r, mut row)| {
            for (c, d) in row.iter_mut().enumerate() {
                let mut sum = 0.0f64;
                for &oy in &offsets {
                    for &ox in &offsets {
                        if let Some((x, y)) = map(c as f64 + ox, r as f64 + oy) {
                            sum += sample(x, y);
                        }
                    }
                }
                *d = finish(sum / (n * n) as f64);
            }
        });
}

/// Horizontal bilinear tap of one column sub-sample: texel columns and the weight of the right.
#[derive(Debug, Clone, Copy)]
struct ColumnTap {
    c0: usize,
    c1: usize,
    w1: f32,
}

/// Wraps an integer texel coordinate; the common in-range case skips the division.
#[inline]
fn wrap(i: i64, period: usize) -> usize {
    let p = period as i64;
    if (0..p).contains(&i) {
        i as usize
    } else {
        i.rem_euclid(p) as usize
    }
}

/// Floor, fraction and the two wrapped texel indices of coordinate `u` (texel centres at +1/2).
#[inline]
fn split(u: f64, period: usize) -> (usize, usize, f32) {
    let x = if u.is_finite() { u - 0.5 } else { 0.0 };
    let x0 = x.floor();
    let i0 = wrap(x0 as i64, period);
    let i1 = if i0 + 1 == period { 0 } else { i0 + 1 };
    (i0, i1, (x - x0) as f32)
}

/// Everything that is the same for every row of one frame.
struct Plan<'a> {
    scene: &'a Scene,
    map: ViewMap,
    n: usize,
    offsets: Vec<f64>,
    sy: f64,
    /// The first destination row's sensor row.
    row0: f64,
    /// Scene x of every column sub-sample, `cols * n` long.
    xs: Vec<f64>,
    /// Axis-aligned maps: the horizontal taps of every column sub-sample.
    taps: Vec<ColumnTap>,
    /// Horizontal gain maps: the gain of every column sub-sample.
    column_gain: Vec<f32>,
}

impl<'a> Plan<'a> {
    fn new(scene: &'a Scene, t_ns: i64, region: Region, cols: usize) -> Plan<'a> {
        let map = ViewMap::at(scene, t_ns);
        let n = scene.spec().samples_per_pixel;
        let offsets = sub_offsets(n);
        let (sx, sy) = region.scale(scene);
        let col0 = region.col0;
        let xs: Vec<f64> = (0..cols)
            .flat_map(|c| offsets.iter().map(move |&ox| (col0 + c as f64 + ox) * sx))
            .collect();
        let taps = if map.is_axis_aligned() {
            let w = scene.texture.width();
            xs.iter()
                .map(|&x| {
                    // Same expression as the reference (a12 * y is exactly 0 here).
                    let (c0, c1, w1) = split(map.a11 * x + 0.0 + map.b1, w);
                    ColumnTap { c0, c1, w1 }
                })
                .collect()
        } else {
            Vec::new()
        };
        let column_gain = match &scene.gain {
            Some(g) if g.is_horizontal() => xs.iter().map(|&x| g.gain_at(x, 0.0) as f32).collect(),
            _ => Vec::new(),
        };
        Plan {
            scene,
            map,
            n,
            offsets,
            sy,
            row0: region.row0,
            xs,
            taps,
            column_gain,
        }
    }

    /// Renders destination row `r` into `acc` (`cols` long): the sum over sub-samples.
    fn row_sums(&self, r: usize, acc: &mut [f32], scratch: &mut WalkScratch) {
        acc.fill(0.0);
        let tex = &self.scene.texture;
        let (tw, th) = (tex.width(), tex.height());
        let data = tex.data();
        let n = self.n;
        let radial = self.scene.gain.filter(|g| !g.is_horizontal());
        for &oy in &self.offsets {
            let y = (self.row0 + r as f64 + oy) * self.sy;
            // Same expression order as the reference, so coordinates agree bit for bit.
            let (u_y, v_y) = (self.map.a12 * y, self.map.a22 * y);
            if self.map.is_axis_aligned() {
                let (r0, r1, wy1) = split(v_y + self.map.b2, th); // a21 * x is (-)0 here
                let wy0 = 1.0 - wy1;
                let (row0, row1) = (&data[r0 * tw..(r0 + 1) * tw], &data[r1 * tw..(r1 + 1) * tw]);
                for (c, (a, taps)) in acc.iter_mut().zip(self.taps.chunks_exact(n)).enumerate() {
                    let mut s = 0.0f32;
                    for (k, tap) in taps.iter().enumerate() {
                        let w0 = 1.0 - tap.w1;
                        let top = row0[tap.c0] * w0 + row0[tap.c1] * tap.w1;
                        let bottom = row1[tap.c0] * w0 + row1[tap.c1] * tap.w1;
                        let mut v = top * wy0 + bottom * wy1;
                        v *= self.gain_factor(radial.as_ref(), c * n + k, y);
                        s += v;
                    }
                    *a += s;
                }
            } else {
                let walked = radial.is_none()
                    && self.column_gain.is_empty()
                    && self.row_fixed_point(u_y, v_y, acc, scratch);
                if walked {
                    continue;
                }
                for (c, a) in acc.iter_mut().enumerate() {
                    let mut s = 0.0f32;
                    for k in 0..n {
                        let i = c * n + k;
                        let x = self.xs[i];
                        let u = self.map.a11 * x + u_y + self.map.b1;
                        let v = self.map.a21 * x + v_y + self.map.b2;
                        let (c0, c1, wx1) = split(u, tw);
                        let (r0, r1, wy1) = split(v, th);
                        let wx0 = 1.0 - wx1;
                        let top = data[r0 * tw + c0] * wx0 + data[r0 * tw + c1] * wx1;
                        let bottom = data[r1 * tw + c0] * wx0 + data[r1 * tw + c1] * wx1;
                        let mut val = top * (1.0 - wy1) + bottom * wy1;
                        val *= self.gain_factor(radial.as_ref(), i, y);
                        s += val;
                    }
                    *a += s;
                }
            }
        }
    }

    /// One sub-row of a turned or zoomed view without a gain map, added into `acc`: the texture
    /// coordinates of consecutive column sub-samples step by a constant, so they are walked in
    /// 32.32 fixed point (integer texel and fraction without a floor or a division per sample).
    /// The coordinates differ from the reference's by at most the steps' rounding, `cols * n *
    /// 2^-33` texels (under 1e-6 for any grid this renders), far inside the renderer's
    /// tolerance. The coordinates ([`walk_corners`], vectorised through [`neuspike_simd::dispatch`])
    /// and then the samples ([`neuspike_simd::gather::bilinear`]) go a sub-row at a time. `false`
    /// (nothing added) where the walk does not apply: [`WALK_LANES`] steps of a whole period or
    /// more, or coordinates beyond 2^30 texels.
    fn row_fixed_point(
        &self,
        u_y: f64,
        v_y: f64,
        acc: &mut [f32],
        scratch: &mut WalkScratch,
    ) -> bool {
        const ONE: f64 = 4_294_967_296.0; // 2^32
        const LIMIT: f64 = 1_073_741_824.0; // 2^30
        let tex = &self.scene.texture;
        let (tw, th) = (tex.width(), tex.height());
        let n = self.n;
        let count = self.xs.len();
        if count == 0 {
            return true;
        }
        let m = &self.map;
        // Texel-centre coordinates (the reference's `u - 1/2`) of the first sub-sample, and the
        // step from one sub-sample to the next (they are evenly spaced).
        let x0 = self.xs[0];
        let dx = if count > 1 {
            (self.xs[count - 1] - x0) / (count - 1) as f64
        } else {
            0.0
        };
        let u0 = m.a11 * x0 + u_y + m.b1 - 0.5;
        let v0 = m.a21 * x0 + v_y + m.b2 - 0.5;
        let (du, dv) = (m.a11 * dx, m.a21 * dx);
        let ok = |x: f64| x.is_finite() && x.abs() < LIMIT;
        if !(ok(u0) && ok(v0) && du.abs() < tw as f64 && dv.abs() < th as f64) {
            return false;
        }
        let (pu, pv) = ((tw as i64) << 32, (th as i64) << 32);
        let (duf, dvf) = ((du * ONE).round() as i64, (dv * ONE).round() as i64);
        let lanes = WALK_LANES as i64;
        if lanes * duf.abs() >= pu || lanes * dvf.abs() >= pv {
            return false;
        }
        let fixed = |x: f64, period: usize| (x.rem_euclid(period as f64) * ONE) as i64;
        // `rem_euclid` may round up to the period itself.
        let (mut uf, mut vf) = (fixed(u0, tw), fixed(v0, th));
        if uf >= pu {
            uf -= pu;
        }
        if vf >= pv {
            vf -= pv;
        }
        let walk = Walk {
            size: [tw, th],
            start: [uf, vf],
            step: [duf, dvf],
        };
        let WalkScratch {
            index,
            weight,
            samples,
        } = scratch;
        // Whole chunks of the walk; the samples stop at `count`.
        let padded = count.next_multiple_of(WALK_LANES);
        for v in index.iter_mut() {
            v.resize(padded, 0);
        }
        for v in weight.iter_mut() {
            v.resize(padded, 0.0);
        }
        samples.resize(count, 0.0);
        neuspike_simd::dispatch(
            #[inline(always)]
            || walk_corners(&walk, index, weight),
        );
        let corners = neuspike_simd::gather::Corners {
            texels: tex.data(),
            index: [&index[0], &index[1], &index[2], &index[3]],
            weight: [&weight[0], &weight[1]],
        };
        neuspike_simd::gather::bilinear(neuspike_simd::detect(), &corners, samples);
        match n {
            1 => sum_samples::<1>(samples, acc),
            2 => sum_samples::<2>(samples, acc),
            3 => sum_samples::<3>(samples, acc),
            4 => sum_samples::<4>(samples, acc),
            _ => {
                for (a, s) in acc.iter_mut().zip(samples.chunks_exact(n)) {
                    *a += s.iter().sum::<f32>();
                }
            }
        }
        true
    }

    /// Gain of column sub-sample `i` at scene row `y` (1 without a gain map).
    #[inline]
    fn gain_factor(&self, radial: Option<&crate::gain::GainMap>, i: usize, y: f64) -> f32 {
        if let Some(g) = radial {
            g.gain_at(self.xs[i], y) as f32
        } else if self.column_gain.is_empty() {
            1.0
        } else {
            self.column_gain[i]
        }
    }

    /// Renders a block of consecutive rows starting at `first_row`.
    fn render_block(&self, first_row: usize, mut block: ArrayViewMut2<'_, f32>, acc: &mut [f32]) {
        let scale = 1.0 / (self.n * self.n) as f32;
        let mut scratch = WalkScratch::default();
        let bounds = output_bounds(self.scene);
        for (i, mut row) in block.axis_iter_mut(Axis(0)).enumerate() {
            self.row_sums(first_row + i, acc, &mut scratch);
            let out = |d: &mut f32, &s: &f32| *d = clamp_finite(s * scale, bounds);
            match row.as_slice_mut() {
                Some(row) => neuspike_simd::dispatch(
                    #[inline(always)]
                    || row.iter_mut().zip(acc.iter()).for_each(|(d, s)| out(d, s)),
                ),
                None => row.iter_mut().zip(acc.iter()).for_each(|(d, s)| out(d, s)),
            }
        }
    }
}

/// Sub-samples whose coordinates the fixed-point walk computes from one start: each from the
/// start without a dependency on the one before, so that the loop vectorises.
pub(crate) const WALK_LANES: usize = 16;

/// A walk along one sub-row in 32.32 fixed point: a texture of `size` = `[width, height]`, the
/// first sub-sample's texel-centre coordinates `start` (each in `[0, period)`) and the step
/// `step` between sub-samples (less than a period over [`WALK_LANES`] steps).
struct Walk {
    size: [usize; 2],
    start: [i64; 2],
    step: [i64; 2],
}

/// The texels and weights of a sub-row's bilinear samples ([`neuspike_simd::gather::Corners`]),
/// kept between rows.
#[derive(Default)]
pub(crate) struct WalkScratch {
    index: [Vec<u32>; 4],
    weight: [Vec<f32>; 2],
    samples: Vec<f32>,
}

/// The four texel indices and two weights of every sub-sample along `walk`, `index[0].len()`
/// of them (a multiple of [`WALK_LANES`], every slice as long): sub-sample `i` at `start + i step`, wrapped into the period, bit for bit the
/// coordinates of a walk that steps and wraps one sub-sample at a time.
#[inline(always)]
fn walk_corners(walk: &Walk, index: &mut [Vec<u32>; 4], weight: &mut [Vec<f32>; 2]) {
    const FRAC: f32 = 1.0 / 4_294_967_296.0;
    let [tw, th] = walk.size;
    let (pu, pv) = ((tw as i64) << 32, (th as i64) << 32);
    // One period added or taken away at most: every offset below is under a period.
    let wrap = |x: i64, p: i64| {
        if x >= p {
            x - p
        } else if x < 0 {
            x + p
        } else {
            x
        }
    };
    let next = |c: u32, n: u32| if c + 1 == n { 0 } else { c + 1 };
    // Each lane's offset from the chunk's start, split into whole texels and a 32-bit
    // fraction, so that the lanes' arithmetic is 32-bit (twice the lanes of 64-bit).
    let offset = |a: usize, j: usize| j as i64 * walk.step[a];
    let whole: [[i32; WALK_LANES]; 2] =
        std::array::from_fn(|a| std::array::from_fn(|j| (offset(a, j) >> 32) as i32));
    let part: [[u32; WALK_LANES]; 2] =
        std::array::from_fn(|a| std::array::from_fn(|j| offset(a, j) as u32));
    // The texel and fraction of `base + offset`, the texel wrapped into `[0, n)`: the same as
    // wrapping the 64-bit sum.
    let lane = |(bi, bf): (i32, u32), oi: i32, of: u32, n: u32| {
        let f = bf.wrapping_add(of);
        let i = bi + oi + i32::from(f < bf);
        let i = if i >= n as i32 {
            i - n as i32
        } else if i < 0 {
            i + n as i32
        } else {
            i
        };
        (i as u32, f)
    };
    let [mut uf, mut vf] = walk.start;
    let (w, h) = (tw as u32, th as u32);
    for s in (0..index[0].len()).step_by(WALK_LANES) {
        let mut at = [[0u32; WALK_LANES]; 4];
        let mut by = [[0f32; WALK_LANES]; 2];
        let split = |x: i64| ((x >> 32) as i32, x as u32);
        let (bu, bv) = (split(uf), split(vf));
        for j in 0..WALK_LANES {
            let (c0, fu) = lane(bu, whole[0][j], part[0][j], w);
            let (r0, fv) = lane(bv, whole[1][j], part[1][j], h);
            let (c1, r1) = (next(c0, w), next(r0, h));
            by[0][j] = fu as f32 * FRAC;
            by[1][j] = fv as f32 * FRAC;
            at[0][j] = r0 * w + c0;
            at[1][j] = r0 * w + c1;
            at[2][j] = r1 * w + c0;
            at[3][j] = r1 * w + c1;
        }
        for (dst, src) in index.iter_mut().zip(&at) {
            dst[s..s + WALK_LANES].copy_from_slice(src);
        }
        for (dst, src) in weight.iter_mut().zip(&by) {
            dst[s..s + WALK_LANES].copy_from_slice(src);
        }
        uf = wrap(uf + WALK_LANES as i64 * walk.step[0], pu);
        vf = wrap(vf + WALK_LANES as i64 * walk.step[1], pv);
    }
}

/// Each pixel's `N` consecutive samples summed in order into `acc`.
fn sum_samples<const N: usize>(samples: &[f32], acc: &mut [f32]) {
    let (whole, _) = samples.as_chunks::<N>();
    for (a, s) in acc.iter_mut().zip(whole) {
        *a += s.iter().sum::<f32>();
    }
}

/// The fast path: per-frame tables, per-row invariants, rayon over row blocks when `parallel`.
pub(crate) fn render_fast(scene: &Scene, t_ns: i64, dst: ArrayViewMut2<'_, f32>, parallel: bool) {
    let (rows, cols) = dst.dim();
    render_fast_region(scene, t_ns, Region::whole(rows, cols), dst, parallel);
}

/// [`render_fast`] of a region of a sensor.
pub(crate) fn render_fast_region(
    scene: &Scene,
    t_ns: i64,
    region: Region,
    mut dst: ArrayViewMut2<'_, f32>,
    parallel: bool,
) {
    let (rows, cols) = dst.dim();
    if rows == 0 || cols == 0 {
        return;
    }
    let plan = Plan::new(scene, t_ns, region, cols);
    if parallel {
        dst.axis_chunks_iter_mut(Axis(0), ROWS_PER_TASK)
            .into_par_iter()
            .enumerate()
            .for_each(|(b, block)| {
                let mut acc = vec![0.0f32; cols];
                plan.render_block(b * ROWS_PER_TASK, block, &mut acc);
            });
    } else {
        let mut acc = vec![0.0f32; cols];
        plan.render_block(0, dst.view_mut(), &mut acc);
    }
}

/// Whether a frame is large enough to be worth splitting over threads.
pub(crate) fn worth_parallel(scene: &Scene, rows: usize, cols: usize) -> bool {
    let n = scene.spec().samples_per_pixel;
    rows.saturating_mul(cols).saturating_mul(n * n) >= PARALLEL_MIN_SAMPLES
}
