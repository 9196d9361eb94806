//! Events binned over time: the E2VID voxel grid and SBT-style event stacking.
//!
//! Both take the time span from the events themselves: `t_0` is the first event's timestamp and
//! `t_last` the last one's (the caller slices the window), `dt = t_last - t_0`, or `dt = 1` when
//! all events share one timestamp. Differences of `i64` instants are exact (taken in `i128`, or
//! as the `u64` they always fit in), so instants anywhere in the `i64` range work.
//!
//! The fast paths use that events are sorted by time: an event's bin never decreases along the
//! slice, so the events of each bin are a contiguous range (found by binary search). The voxel
//! grid makes one pass over the events on the calling thread, keeping only two bins per pixel
//! hot; it stays single-threaded on purpose: the deterministic parallel splits (a task per bin,
//! computing each event twice) were slower than this pass on the 2-core machine measured, and
//! the node runs beside five other stages anyway. Each voxel receives its events in time order,
//! so the result equals the scalar reference bit for bit. Stacking is exact integer counting,
//! one bin per rayon task once there are [`MIN_ELEMENTS_FOR_RAYON`] events.

use std::ops::Range;

use ndarray::{ArrayViewMut3, Axis};
use rayon::prelude::*;

use crate::error::{RepresentError, shape_str};
use crate::event::EventSlice;
use crate::spike::MIN_ELEMENTS_FOR_RAYON;

/// What [`voxel_grid_into`] does to the weighted sums before writing them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum VoxelNorm {
    /// The weighted sums as they are.
    #[default]
    Raw,
    /// E2VID's normalisation: the non-zero voxels are shifted and scaled to mean 0 and standard
    /// deviation 1 (population standard deviation over the non-zero voxels only); zero voxels
    /// stay 0. With no non-zero voxel the grid stays all zeros; when the standard deviation is 0
    /// (every non-zero voxel has the same value) the mean is only subtracted, which writes 0
    /// there (E2VID's PyTorch code would divide by zero).
    NonZeroStandard,
}

/// Checks shared by the binning kernels: at least one bin, then the event invariants.
fn check_bins(
    events: EventSlice,
    dst_dim: (usize, usize, usize),
    what: &'static str,
) -> Result<(), RepresentError> {
    let (b, h, w) = dst_dim;
    if b == 0 {
        return Err(RepresentError::Shape {
            what,
            expected: format!("[B >= 1, {h}, {w}]"),
            actual: shape_str(&[b, h, w]),
        });
    }
    events.validate(h, w)
}

/// `t_last - t_0` of sorted timestamps as the `u64` it always fits in, or 1 when it is 0 (all
/// events at one instant) or there are no events.
fn span_ns(t_ns: &[i64]) -> (i64, u64) {
    match (t_ns.first(), t_ns.last()) {
        (Some(&first), Some(&last)) => (first, (last.wrapping_sub(first) as u64).max(1)),
        _ => (0, 1),
    }
}

// ---------------------------------------------------------------------------------------------
// Voxel grid
// ---------------------------------------------------------------------------------------------

/// E2VID voxel grid (Rebecq et al. 2019) of the events, `B` bins, written to `dst` `[B, H, W]`.
///
/// With `t_0` the first event's timestamp, `t_last` the last one's and `dt = t_last - t_0` (or
/// `dt = 1` when all events share one timestamp, so that they all land in bin 0), each event `i`
/// has the normalised time `t*_i = (B - 1) (t_i - t_0) / dt` in `[0, B - 1]` and adds
/// `p_i * max(0, 1 - |b - t*_i|)` to voxel `[b, y_i, x_i]` for every bin `b`: only bins
/// `floor(t*_i)` and `floor(t*_i) + 1` receive a non-zero weight, and the two weights sum to 1.
/// Polarity counts `+1` for ON and **`-1` for OFF** (tonic, given boolean polarities, adds OFF
/// events as `+1` and divides by `B` instead of `B - 1`; we follow E2VID and docs/definitions.md).
///
/// Arithmetic, fixed so that the result is reproducible: `t_i - t_0` and `dt` are exact integers
/// converted to `f64`, `t*_i = min(B - 1, ((B - 1) * (t_i - t_0)) / dt)` in `f64` (the order of
/// E2VID's NumPy code), sums accumulated per voxel in `f64` in event order and rounded once to
/// `f32`. `norm` then applies [`VoxelNorm`]. The cost is linear in the number of events (two
/// voxel updates per event, one pass, on the calling thread) plus `O(B * H * W)`; scratch memory
/// is 16 bytes per pixel, plus 8 per voxel with the normalisation, whatever the number of events.
/// With `B = 1` every event weighs 1 (the signed count). No events give zeros.
///
/// # Errors
/// - [`RepresentError::Shape`] when `dst` has no bin (`B = 0`) or the event slices differ in
///   length.
/// - [`RepresentError::Param`] when the events are not sorted by time or a polarity is not ±1.
/// - [`RepresentError::Index`] for an event outside the `[H, W]` sensor.
///
/// ```
/// use ndarray::Array3;
/// use neuspike_representations::{EventSlice, VoxelNorm, voxel_grid_into};
/// // Three bins over [0, 100]: t* = 0, 0.5 and 2.
/// let (t_ns, x, y, polarity) = (&[0, 25, 100], &[0, 0, 1], &[0; 3], &[1, -1, 1]);
/// let events = EventSlice { t_ns, x, y, polarity };
/// let mut v = Array3::<f32>::zeros((3, 1, 2));
/// voxel_grid_into(events, VoxelNorm::Raw, v.view_mut()).unwrap();
/// assert_eq!(v, ndarray::array![[[0.5, 0.0]], [[-0.5, 0.0]], [[0.0, 1.0]]]);
/// ```
pub fn voxel_grid_into(
    events: EventSlice,
    norm: VoxelNorm,
    dst: ArrayViewMut3<f32>,
) -> Result<(), RepresentError> {
    check_bins(events, dst.dim(), "voxel grid dst")?;
    voxel_fast(events, norm, dst);
    Ok(())
}

/// Scalar oracle for [`voxel_grid_into`]: for every event and every bin, the closed form
/// `p * max(0, 1 - |b - t*|)` added to an `f64` grid, then the normalisation. Same checks.
#[doc(hidden)]
pub fn voxel_grid_reference(
    events: EventSlice,
    norm: VoxelNorm,
    mut dst: ArrayViewMut3<f32>,
) -> Result<(), RepresentError> {
    check_bins(events, dst.dim(), "voxel grid dst")?;
    let (bins, h, w) = dst.dim();
    let n = events.len();
    let b1 = (bins - 1) as f64;
    let mut grid = vec![0.0f64; bins * h * w];
    if n > 0 {
        let t0 = events.t_ns[0];
        let mut dt = (i128::from(events.t_ns[n - 1]) - i128::from(t0)) as f64;
        if dt == 0.0 {
            dt = 1.0;
        }
        for i in 0..n {
            let t_star = ((b1 * (i128::from(events.t_ns[i]) - i128::from(t0)) as f64) / dt).min(b1);
            let p = f64::from(events.polarity[i]);
            let pixel = usize::from(events.y[i]) * w + usize::from(events.x[i]);
            for b in 0..bins {
                let weight = (1.0 - (b as f64 - t_star).abs()).max(0.0);
                grid[b * h * w + pixel] += p * weight;
            }
        }
    }
    if norm == VoxelNorm::NonZeroStandard {
        let nonzero: Vec<f64> = grid.iter().copied().filter(|&v| v != 0.0).collect();
        if !nonzero.is_empty() {
            let count = nonzero.len() as f64;
            let mean = nonzero.iter().sum::<f64>() / count;
            let var = nonzero.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / count;
            let std = var.sqrt();
            for v in grid.iter_mut().filter(|v| **v != 0.0) {
                *v = if std > 0.0 {
                    (*v - mean) / std
                } else {
                    *v - mean
                };
            }
        }
    }
    for b in 0..bins {
        for y in 0..h {
            for x in 0..w {
                dst[[b, y, x]] = grid[(b * h + y) * w + x] as f32;
            }
        }
    }
    Ok(())
}

/// The normalised time `t*` of the voxel grid, with the operations in the reference's order.
#[derive(Clone, Copy, Debug)]
struct BinTime {
    t0_ns: i64,
    /// `B - 1`.
    b1: f64,
    /// `dt` in nanoseconds (at least 1).
    dt: f64,
}

impl BinTime {
    fn new(t_ns: &[i64], bins: usize) -> Self {
        let (t0_ns, dt) = span_ns(t_ns);
        Self {
            t0_ns,
            b1: (bins - 1) as f64,
            dt: dt as f64,
        }
    }

    /// `t*` of an event at `t_ns >= t0_ns`: the difference is exact as a `u64` (wrapping
    /// subtraction of two `i64` whose true difference lies in `[0, 2^64)`), and converts to the
    /// same `f64` as the reference's `i128`.
    #[inline(always)]
    fn t_star(self, t_ns: i64) -> f64 {
        let d = t_ns.wrapping_sub(self.t0_ns) as u64 as f64;
        ((self.b1 * d) / self.dt).min(self.b1)
    }
}

/// `starts[k]` (`k = 0..=B`): the first event with `floor(t*) >= k`, so that the events with
/// `floor(t*) = k` are `starts[k]..starts[k + 1]` (`t*` never decreases along sorted events).
fn bin_starts(t_ns: &[i64], time: BinTime, bins: usize) -> Vec<usize> {
    let mut starts = Vec::with_capacity(bins + 1);
    starts.push(0);
    for k in 1..bins {
        starts.push(t_ns.partition_point(|&t| time.t_star(t) < k as f64));
    }
    starts.push(t_ns.len());
    starts
}

/// Fast voxel grid, checked by the caller: one pass over the events, bin by bin. The events
/// with `floor(t*) = k` add their lower weight to bin `k` and their upper weight to bin `k + 1`
/// of their pixel, kept side by side (`pairs`, one cache line per event); once they are done,
/// bin `k` is final: it is written out (to `dst`, or to an `f64` grid for the normalisation) and
/// bin `k + 1` moves down. Each voxel receives its events in time order, as in the reference.
fn voxel_fast(events: EventSlice, norm: VoxelNorm, mut dst: ArrayViewMut3<f32>) {
    let (bins, h, w) = dst.dim();
    let plane_len = h * w;
    let time = BinTime::new(events.t_ns, bins);
    let starts = bin_starts(events.t_ns, time, bins);
    let mut pairs = vec![[0.0f64; 2]; plane_len];
    let mut grid = match norm {
        VoxelNorm::Raw => Vec::new(),
        VoxelNorm::NonZeroStandard => vec![0.0f64; bins * plane_len],
    };
    for k in 0..bins {
        add_pairs(events, time, starts[k]..starts[k + 1], w, k, &mut pairs);
        let next = |pair: &mut [f64; 2]| {
            let done = pair[0];
            *pair = [pair[1], 0.0];
            done
        };
        match norm {
            VoxelNorm::Raw => {
                let mut plane = dst.index_axis_mut(Axis(0), k);
                match plane.as_slice_mut() {
                    Some(out) => {
                        for (d, pair) in out.iter_mut().zip(&mut pairs) {
                            *d = next(pair) as f32;
                        }
                    }
                    None => {
                        for (d, pair) in plane.iter_mut().zip(&mut pairs) {
                            *d = next(pair) as f32;
                        }
                    }
                }
            }
            VoxelNorm::NonZeroStandard => {
                let plane = &mut grid[k * plane_len..(k + 1) * plane_len];
                for (g, pair) in plane.iter_mut().zip(&mut pairs) {
                    *g = next(pair);
                }
            }
        }
    }
    if norm == VoxelNorm::NonZeroStandard {
        standardise_nonzero(&mut grid);
        match dst.as_slice_mut() {
            Some(out) => {
                for (d, &v) in out.iter_mut().zip(&grid) {
                    *d = v as f32;
                }
            }
            None => {
                for (d, &v) in dst.iter_mut().zip(&grid) {
                    *d = v as f32;
                }
            }
        }
    }
}

/// The events `range` as `(t_ns, pixel index, polarity as f64)`; every `x < w` was checked.
#[inline(always)]
fn pixels(
    events: EventSlice<'_>,
    range: Range<usize>,
    w: usize,
) -> impl Iterator<Item = (i64, usize, f64)> + '_ {
    let t_ns = &events.t_ns[range.clone()];
    let xs = &events.x[range.clone()];
    let ys = &events.y[range.clone()];
    let ps = &events.polarity[range];
    t_ns.iter()
        .zip(xs)
        .zip(ys)
        .zip(ps)
        .map(move |(((&t, &x), &y), &p)| (t, usize::from(y) * w + usize::from(x), f64::from(p)))
}

/// Adds the weights of the events `range` (those with `floor(t*) = k`): `p * (1 - (t* - k))`
/// to `pairs[pixel][0]` (bin `k`) and `p * (1 - ((k + 1) - t*))` to `pairs[pixel][1]` (bin
/// `k + 1`; for `k = B - 1` that weight is 0, as `t* = B - 1` there, and is dropped).
fn add_pairs(
    events: EventSlice,
    time: BinTime,
    range: Range<usize>,
    w: usize,
    k: usize,
    pairs: &mut [[f64; 2]],
) {
    let (k, b) = (k as f64, (k + 1) as f64);
    // In runs: the pixels and weights of a run in one vectorised pass, then the scatter.
    const RUN: usize = 2048;
    let mut pixel = [0usize; RUN];
    let mut lower = [0.0f64; RUN];
    let mut upper = [0.0f64; RUN];
    let mut start = range.start;
    while start < range.end {
        let end = (start + RUN).min(range.end);
        let n = end - start;
        let (pixel, lower, upper) = (&mut pixel[..n], &mut lower[..n], &mut upper[..n]);
        neuspike_simd::dispatch(
            #[inline(always)]
            || {
                for (j, (t, px, p)) in pixels(events, start..end, w).enumerate() {
                    let t_star = time.t_star(t);
                    pixel[j] = px;
                    lower[j] = p * (1.0 - (t_star - k));
                    upper[j] = p * (1.0 - (b - t_star));
                }
            },
        );
        for ((&px, &lo), &up) in pixel.iter().zip(lower.iter()).zip(upper.iter()) {
            let pair = &mut pairs[px];
            pair[0] += lo;
            pair[1] += up;
        }
        start = end;
    }
}

/// [`VoxelNorm::NonZeroStandard`] in place, summing in the grid's order as the reference does.
fn standardise_nonzero(grid: &mut [f64]) {
    let (mut count, mut sum) = (0usize, 0.0f64);
    for &v in grid.iter().filter(|v| **v != 0.0) {
        count += 1;
        sum += v;
    }
    if count == 0 {
        return;
    }
    let count = count as f64;
    let mean = sum / count;
    let mut squares = 0.0f64;
    for &v in grid.iter().filter(|v| **v != 0.0) {
        squares += (v - mean) * (v - mean);
    }
    let std = (squares / count).sqrt();
    for v in grid.iter_mut().filter(|v| **v != 0.0) {
        *v = if std > 0.0 {
            (*v - mean) / std
        } else {
            *v - mean
        };
    }
}

// ---------------------------------------------------------------------------------------------
// Event stacking
// ---------------------------------------------------------------------------------------------

/// Event stacking by time (SBT-style): `B` bins of equal duration, each the signed event count
/// per pixel, written to `dst` `[B, H, W]`.
///
/// With `t_0`, `t_last` and `dt` as in [`voxel_grid_into`] (`dt = 1` when all events share one
/// timestamp), event `i` adds its polarity (`+1` ON, `-1` OFF) to bin
/// `min(B - 1, floor(B (t_i - t_0) / dt))`, computed exactly in integers: bins are the half-open
/// intervals `[t_0 + b dt / B, t_0 + (b + 1) dt / B)`, except that the last bin also holds the
/// last instant `t_last`. All events at one timestamp land in bin 0. Counts are exact integers
/// (`i64`), written as `f32` (exact up to `2^24` in magnitude). Summed over the bins the result
/// is [`event_count_into`](crate::event_count_into). No events give zeros.
///
/// # Errors
/// As [`voxel_grid_into`]: no bin or unequal slice lengths (`Shape`), unsorted times or a
/// polarity not ±1 (`Param`), an event outside the sensor (`Index`).
///
/// ```
/// use ndarray::Array3;
/// use neuspike_representations::{EventSlice, event_stack_into};
/// let (t_ns, polarity) = (&[0, 49, 50, 100], &[1, 1, -1, 1]);
/// let events = EventSlice { t_ns, x: &[0; 4], y: &[0; 4], polarity };
/// let mut s = Array3::<f32>::zeros((2, 1, 1));
/// event_stack_into(events, s.view_mut()).unwrap();
/// assert_eq!(s, ndarray::array![[[2.0]], [[0.0]]]); // 50 opens bin 1, which keeps the last event
/// ```
pub fn event_stack_into(events: EventSlice, dst: ArrayViewMut3<f32>) -> Result<(), RepresentError> {
    check_bins(events, dst.dim(), "event stack dst")?;
    let parallel = events.len() >= MIN_ELEMENTS_FOR_RAYON;
    stack_fast(events, dst, parallel);
    Ok(())
}

/// Scalar oracle for [`event_stack_into`]: each event's bin from the formula in `u128`.
#[doc(hidden)]
pub fn event_stack_reference(
    events: EventSlice,
    mut dst: ArrayViewMut3<f32>,
) -> Result<(), RepresentError> {
    check_bins(events, dst.dim(), "event stack dst")?;
    let (bins, h, w) = dst.dim();
    let mut counts = vec![0i64; bins * h * w];
    let n = events.len();
    if n > 0 {
        let t0 = i128::from(events.t_ns[0]);
        let mut dt = i128::from(events.t_ns[n - 1]) - t0;
        if dt == 0 {
            dt = 1;
        }
        for i in 0..n {
            let d = i128::from(events.t_ns[i]) - t0;
            let bin = ((bins as u128 * d as u128) / dt as u128).min(bins as u128 - 1) as usize;
            let pixel = usize::from(events.y[i]) * w + usize::from(events.x[i]);
            counts[bin * h * w + pixel] += i64::from(events.polarity[i]);
        }
    }
    for b in 0..bins {
        for y in 0..h {
            for x in 0..w {
                dst[[b, y, x]] = counts[(b * h + y) * w + x] as f32;
            }
        }
    }
    Ok(())
}

/// Fast stacking, checked by the caller: bin boundaries by binary search on the sorted times
/// (`B * d >= k * dt` in `u128`, the reference's floor exactly), then one `i64` plane per bin;
/// bins on rayon when `parallel`. Exact, so identical to the reference.
fn stack_fast(events: EventSlice, mut dst: ArrayViewMut3<f32>, parallel: bool) {
    let (bins, h, w) = dst.dim();
    let (t0, dt) = span_ns(events.t_ns);
    let mut starts = Vec::with_capacity(bins + 1);
    starts.push(0);
    for k in 1..bins {
        starts.push(events.t_ns.partition_point(|&t| {
            let d = t.wrapping_sub(t0) as u64;
            (bins as u128) * u128::from(d) < (k as u128) * u128::from(dt)
        }));
    }
    starts.push(events.len());
    let fill = |(b, mut plane): (usize, ndarray::ArrayViewMut2<f32>)| {
        let mut counts = vec![0i64; h * w];
        let range = starts[b]..starts[b + 1];
        for (&x, (&y, &p)) in events.x[range.clone()]
            .iter()
            .zip(events.y[range.clone()].iter().zip(&events.polarity[range]))
        {
            counts[usize::from(y) * w + usize::from(x)] += i64::from(p);
        }
        match plane.as_slice_mut() {
            Some(out) => {
                for (d, &c) in out.iter_mut().zip(&counts) {
                    *d = c as f32;
                }
            }
            None => {
                for (d, &c) in plane.iter_mut().zip(&counts) {
                    *d = c as f32;
                }
            }
        }
    };
    if parallel {
        dst.axis_iter_mut(Axis(0))
            .into_par_iter()
            .enumerate()
            .for_each(fill);
    } else {
        dst.axis_iter_mut(Axis(0)).enumerate().for_each(fill);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::event_count_into;
    use crate::testing::{Events, any_events};
    use ndarray::{Array2, Array3, array, s};
    use proptest::prelude::*;

    /// Fast path (through the public entry) checked bit for bit against the reference.
    fn voxel(e: &Events, norm: VoxelNorm, bins: usize, h: usize, w: usize) -> Array3<f32> {
        let mut v = Array3::from_elem((bins, h, w), f32::NAN);
        voxel_grid_into(e.slice(), norm, v.view_mut()).expect("voxel grid");
        let mut r = Array3::from_elem((bins, h, w), f32::NAN);
        voxel_grid_reference(e.slice(), norm, r.view_mut()).expect("reference");
        assert_eq!(v, r);
        v
    }

    fn stack(e: &Events, bins: usize, h: usize, w: usize) -> Array3<f32> {
        let mut v = Array3::from_elem((bins, h, w), f32::NAN);
        event_stack_into(e.slice(), v.view_mut()).expect("stack");
        let mut r = Array3::from_elem((bins, h, w), f32::NAN);
        event_stack_reference(e.slice(), r.view_mut()).expect("reference");
        assert_eq!(v, r);
        v
    }

    #[test]
    fn voxel_weights_split_between_the_two_neighbouring_bins() {
        // Five bins over [1000, 1400]: t* = (t - 1000) / 100.
        let e = Events::from(&[
            (1_000, 0, 0, 1),  // t* = 0: bin 0 only
            (1_125, 1, 0, 1),  // t* = 1.25: 0.75 to bin 1, 0.25 to bin 2
            (1_300, 1, 0, -1), // t* = 3: bin 3 only, OFF counts -1
            (1_350, 2, 0, -1), // t* = 3.5: -0.5 to bins 3 and 4
            (1_400, 2, 0, 1),  // t* = 4 (the last event): bin 4 only
        ]);
        let v = voxel(&e, VoxelNorm::Raw, 5, 1, 3);
        assert_eq!(
            v.slice(s![.., 0, ..]),
            array![
                [1.0, 0.0, 0.0],
                [0.0, 0.75, 0.0],
                [0.0, 0.25, 0.0],
                [0.0, -1.0, -0.5],
                [0.0, 0.0, 0.5],
            ]
        );
    }

    #[test]
    fn voxel_off_events_subtract_unlike_tonic_boolean_polarity() {
        // One ON and one OFF event at the same pixel and time cancel; tonic's boolean default
        // would add both as +1 and give 2.
        let e = Events::from(&[(0, 0, 0, 1), (0, 0, 0, -1), (10, 0, 0, -1)]);
        let v = voxel(&e, VoxelNorm::Raw, 2, 1, 1);
        assert_eq!(v.iter().copied().collect::<Vec<_>>(), vec![0.0, -1.0]);
    }

    #[test]
    fn voxel_with_one_bin_is_the_signed_count() {
        let e = Events::flood(5_000, 3, 4, -7, 1_000_003, 11);
        let v = voxel(&e, VoxelNorm::Raw, 1, 3, 4);
        let mut c = Array2::<f32>::zeros((3, 4));
        event_count_into(e.slice(), c.view_mut()).expect("count");
        assert_eq!(v.index_axis(Axis(0), 0), c);
    }

    #[test]
    fn voxel_normalisation_gives_mean_zero_and_std_one_over_the_nonzero_voxels() {
        let e = Events::flood(2_000, 5, 7, 0, 999, 3);
        let raw = voxel(&e, VoxelNorm::Raw, 4, 5, 7);
        let norm = voxel(&e, VoxelNorm::NonZeroStandard, 4, 5, 7);
        let nonzero: Vec<f64> = raw
            .iter()
            .zip(&norm)
            .filter(|(r, _)| **r != 0.0)
            .map(|(_, &n)| f64::from(n))
            .collect();
        assert!(nonzero.len() > 50);
        let count = nonzero.len() as f64;
        let mean = nonzero.iter().sum::<f64>() / count;
        let std = (nonzero.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / count).sqrt();
        assert!(mean.abs() < 1e-6, "mean {mean}");
        assert!((std - 1.0).abs() < 1e-6, "std {std}");
        for (r, n) in raw.iter().zip(&norm) {
            if *r == 0.0 {
                assert_eq!(*n, 0.0);
            }
        }
    }

    #[test]
    fn voxel_normalisation_edge_cases_std_zero_and_no_nonzero_voxel() {
        // Every non-zero voxel equal (std 0): the mean is subtracted, giving zeros, never NaN.
        let e = Events::from(&[(5, 0, 0, 1), (5, 1, 0, 1)]);
        let v = voxel(&e, VoxelNorm::NonZeroStandard, 3, 1, 2);
        assert!(v.iter().all(|&x| x == 0.0));
        // ON and OFF cancelling everywhere: no non-zero voxel, the grid stays zero.
        let e = Events::from(&[(5, 0, 0, 1), (5, 0, 0, -1)]);
        let v = voxel(&e, VoxelNorm::NonZeroStandard, 3, 1, 2);
        assert!(v.iter().all(|&x| x == 0.0));
        let v = voxel(&Events::default(), VoxelNorm::NonZeroStandard, 3, 1, 2);
        assert!(v.iter().all(|&x| x == 0.0));
        // Two different values: +1 and -1 around mean 0.
        let e = Events::from(&[(5, 0, 0, 1), (5, 1, 0, 1), (5, 1, 0, 1)]);
        let v = voxel(&e, VoxelNorm::NonZeroStandard, 1, 1, 2);
        assert_eq!(v, array![[[-1.0, 1.0]]]);
    }

    #[test]
    fn voxel_accepts_a_strided_destination() {
        let e = Events::flood(3_000, 4, 6, 0, 12_345, 5);
        let want = voxel(&e, VoxelNorm::NonZeroStandard, 3, 4, 6);
        let mut big = Array3::from_elem((3, 4, 12), f32::NAN);
        let view = big.slice_mut(s![.., .., ..;2]);
        voxel_grid_into(e.slice(), VoxelNorm::NonZeroStandard, view).expect("strided");
        assert_eq!(big.slice(s![.., .., ..;2]), want);
        let mut stacked = Array3::from_elem((3, 4, 12), f32::NAN);
        event_stack_into(e.slice(), stacked.slice_mut(s![.., .., 1..;2])).expect("strided");
        assert_eq!(stacked.slice(s![.., .., 1..;2]), stack(&e, 3, 4, 6));
    }

    #[test]
    fn stack_bins_are_half_open_and_the_last_event_is_in_the_last_bin() {
        // Three bins over [0, 30]: [0, 10), [10, 20), [20, 30].
        let e = Events::from(&[
            (0, 0, 0, 1),
            (9, 0, 0, 1),
            (10, 0, 0, -1),
            (19, 1, 0, 1),
            (20, 1, 0, 1),
            (30, 1, 0, -1),
        ]);
        let v = stack(&e, 3, 1, 2);
        assert_eq!(
            v.slice(s![.., 0, ..]),
            array![[2.0, 0.0], [-1.0, 1.0], [0.0, 0.0]]
        );
        // Bin 2 holds +1 and -1 at pixel 1: they cancel, as a signed count does.
        let e = Events::from(&[(0, 0, 0, 1), (7, 0, 0, 1)]);
        assert_eq!(
            stack(&e, 4, 1, 1),
            array![[[1.0]], [[0.0]], [[0.0]], [[1.0]]]
        );
    }

    #[test]
    fn stack_boundaries_are_exact_for_spans_that_do_not_divide() {
        // dt = 10, B = 3: bin 1 opens at 10/3 (t = 4), bin 2 at 20/3 (t = 7).
        let list: Vec<(i64, u16, u16, i8)> = (0..=10).map(|t| (t, t as u16, 0, 1)).collect();
        let v = stack(&Events::from(&list), 3, 1, 11);
        let bin_of: Vec<usize> = (0..11)
            .map(|x| (0..3).find(|&b| v[[b, 0, x]] == 1.0).expect("one bin"))
            .collect();
        assert_eq!(bin_of, vec![0, 0, 0, 0, 1, 1, 1, 2, 2, 2, 2]);
    }

    #[test]
    fn binning_errors_name_the_problem() {
        let e = Events::from(&[(1, 0, 0, 1)]);
        let mut none = Array3::<f32>::zeros((0, 1, 1));
        let err = voxel_grid_into(e.slice(), VoxelNorm::Raw, none.view_mut()).expect_err("B=0");
        assert!(err.to_string().contains("B >= 1"), "{err}");
        let err = event_stack_into(e.slice(), none.view_mut()).expect_err("B = 0");
        assert!(matches!(err, RepresentError::Shape { .. }), "{err}");
        let e = Events::from(&[(2, 0, 0, 1), (1, 0, 0, 1)]);
        let mut v = Array3::<f32>::zeros((2, 1, 1));
        let err = voxel_grid_into(e.slice(), VoxelNorm::Raw, v.view_mut()).expect_err("order");
        assert!(err.to_string().contains("t_ns[1] = 1"), "{err}");
        let e = Events::from(&[(2, 1, 0, 1)]);
        let err = event_stack_into(e.slice(), v.view_mut()).expect_err("x");
        assert!(err.to_string().contains("x of event 0"), "{err}");
    }

    fn norm() -> impl Strategy<Value = VoxelNorm> {
        prop_oneof![Just(VoxelNorm::Raw), Just(VoxelNorm::NonZeroStandard)]
    }

    proptest! {
        #[test]
        fn voxel_fast_matches_reference_bit_for_bit(
            (e, h, w) in any_events(5, 6, 60), bins in 1usize..7, norm in norm()
        ) {
            let mut slow = Array3::<f32>::zeros((bins, h, w));
            voxel_grid_reference(e.slice(), norm, slow.view_mut()).expect("ref");
            let mut fast = Array3::<f32>::from_elem((bins, h, w), f32::NAN);
            voxel_fast(e.slice(), norm, fast.view_mut());
            prop_assert_eq!(&fast, &slow);
            prop_assert!(fast.iter().all(|v| v.is_finite()));
        }

        #[test]
        fn voxel_weights_of_each_event_sum_to_one(
            (e, h, w) in any_events(4, 5, 60), bins in 1usize..7
        ) {
            // Summed over the bins, each pixel holds its signed count (tolerance: one f32
            // rounding per voxel plus 1e-12 per event).
            let mut v = Array3::<f32>::zeros((bins, h, w));
            voxel_grid_into(e.slice(), VoxelNorm::Raw, v.view_mut()).expect("voxel");
            let counts = e.signed_counts(h, w);
            for y in 0..h {
                for x in 0..w {
                    let sum: f64 = (0..bins).map(|b| f64::from(v[[b, y, x]])).sum();
                    let want = counts[y * w + x] as f64;
                    let tolerance = 1e-6 * bins as f64 * (1.0 + e.t_ns.len() as f64);
                    prop_assert!((sum - want).abs() <= tolerance,
                        "pixel ({}, {}): {} vs {}", x, y, sum, want);
                }
            }
            // Weights lie in [0, 1]: no voxel exceeds the number of events.
            prop_assert!(v.iter().all(|x| x.abs() <= e.t_ns.len() as f32));
        }

        #[test]
        fn stack_fast_matches_reference_exactly_and_sums_to_the_count(
            (e, h, w) in any_events(5, 6, 60), bins in 1usize..7, parallel in any::<bool>()
        ) {
            let mut slow = Array3::<f32>::zeros((bins, h, w));
            event_stack_reference(e.slice(), slow.view_mut()).expect("ref");
            let mut fast = Array3::<f32>::from_elem((bins, h, w), f32::NAN);
            stack_fast(e.slice(), fast.view_mut(), parallel);
            prop_assert_eq!(&fast, &slow);
            let mut count = Array2::<f32>::zeros((h, w));
            event_count_into(e.slice(), count.view_mut()).expect("count");
            prop_assert_eq!(fast.sum_axis(Axis(0)), count);
        }
    }
}
