//! Image-quality metrics, following `docs/definitions.md` ("Metrics").
//!
//! Images are `f32` luminance, nominally in `[0, 1]`; every sum is accumulated in `f64`.
//!
//! **Precondition:** the two images given to [`psnr`], [`gain_lsq`], [`psnr_after_gain`] and
//! [`ssim`] have the same shape. Call [`check_same_shape`] on data from outside first; in debug
//! builds a mismatch panics, in release builds the result is meaningless.
//!
//! NaN pixels are not cleaned: they make PSNR and SSIM NaN (which the report counts), while
//! [`entropy_2d`] quantises NaN to grey level 0.

use ndarray::ArrayView2;

/// Side of the SSIM window (Wang et al. 2004; scikit-image's `2 * int(3.5 * sigma + 0.5) + 1`).
pub const SSIM_WINDOW: usize = 11;
/// Standard deviation of the SSIM Gaussian window, in pixels.
pub const SSIM_SIGMA: f64 = 1.5;
/// `K1` of the SSIM stabilising constant `C1 = (K1 L)^2`.
pub const SSIM_K1: f64 = 0.01;
/// `K2` of the SSIM stabilising constant `C2 = (K2 L)^2`.
pub const SSIM_K2: f64 = 0.03;
/// Data range `L` of the images: luminance in `[0, 1]`.
pub const DATA_RANGE: f64 = 1.0;

const SSIM_RADIUS: usize = SSIM_WINDOW / 2;
const SSIM_C1: f64 = (SSIM_K1 * DATA_RANGE) * (SSIM_K1 * DATA_RANGE);
const SSIM_C2: f64 = (SSIM_K2 * DATA_RANGE) * (SSIM_K2 * DATA_RANGE);
/// Grey levels of the 8-bit quantisation used by [`entropy_2d`].
const GREY_LEVELS: usize = 256;

/// Two images that were to be compared differ in shape.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MetricsError {
    /// The image and its ground truth differ in shape (`[rows, cols]`).
    #[error("shape mismatch: image is {}x{}, ground truth is {}x{}", x[0], x[1], gt[0], gt[1])]
    ShapeMismatch {
        /// Shape of the image, `[rows, cols]`.
        x: [usize; 2],
        /// Shape of the ground truth, `[rows, cols]`.
        gt: [usize; 2],
    },
}

/// `Ok` when `x` and `gt` have the same shape, the precondition of every comparing metric here.
pub fn check_same_shape(x: ArrayView2<f32>, gt: ArrayView2<f32>) -> Result<(), MetricsError> {
    if x.dim() == gt.dim() {
        Ok(())
    } else {
        Err(MetricsError::ShapeMismatch {
            x: [x.nrows(), x.ncols()],
            gt: [gt.nrows(), gt.ncols()],
        })
    }
}

/// Lanes of the f64 sums: eight partial sums, added in a fixed order at the end, so the loop
/// vectorises and the result does not depend on the instruction set.
const LANES: usize = 8;

/// `sum over pixels of f(x, gt)` in f64, over eight lanes, pixels in row-major order.
#[inline(always)]
fn sum_pairs(x: ArrayView2<f32>, gt: ArrayView2<f32>, f: impl Fn(f64, f64) -> f64) -> f64 {
    let lanes = |xs: &[f32], gs: &[f32]| -> f64 {
        let mut acc = [0.0f64; LANES];
        let (xc, gc) = (xs.chunks_exact(LANES), gs.chunks_exact(LANES));
        let (xr, gr) = (xc.remainder(), gc.remainder());
        for (a, b) in xc.zip(gc) {
            for j in 0..LANES {
                acc[j] += f(f64::from(a[j]), f64::from(b[j]));
            }
        }
        for (j, (&a, &b)) in xr.iter().zip(gr).enumerate() {
            acc[j] += f(f64::from(a), f64::from(b));
        }
        acc.iter().sum()
    };
    match (x.as_slice(), gt.as_slice()) {
        (Some(xs), Some(gs)) => neuspike_simd::dispatch(
            #[inline(always)]
            || lanes(xs, gs),
        ),
        _ => {
            let (xs, gs): (Vec<f32>, Vec<f32>) =
                (x.iter().copied().collect(), gt.iter().copied().collect());
            lanes(&xs, &gs)
        }
    }
}

/// Mean squared error of `map(x)` against `gt`, in f64. Zero for empty images.
#[inline(always)]
fn mse_by(x: ArrayView2<f32>, gt: ArrayView2<f32>, map: impl Fn(f64) -> f64) -> f64 {
    debug_assert_eq!(x.dim(), gt.dim(), "metrics need images of one shape");
    let n = x.len();
    if n == 0 {
        return 0.0;
    }
    sum_pairs(x, gt, |a, g| {
        let d = map(a) - g;
        d * d
    }) / n as f64
}

/// PSNR from an MSE: `10 log10(1 / MSE)`, infinite for an MSE of 0.
fn psnr_from_mse(mse: f64) -> f64 {
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (DATA_RANGE * DATA_RANGE / mse).log10()
    }
}

/// PSNR in dB: `10 log10(1 / MSE)` with data range 1, computed in f64.
///
/// An MSE of 0 (identical images, and by convention empty ones) gives `f64::INFINITY`: report such
/// frames as exact and never average them as a number. Precondition: equal shapes.
pub fn psnr(x: ArrayView2<f32>, gt: ArrayView2<f32>) -> f64 {
    psnr_from_mse(mse_by(x, gt, |v| v))
}

/// Least-squares gain `k = sum(x*g) / sum(x*x)` that best maps `x` onto `gt`.
///
/// When `sum(x*x) == 0` (an all-zero or empty `x`) no gain can help and `k = 1` is returned.
/// Precondition: equal shapes.
pub fn gain_lsq(x: ArrayView2<f32>, gt: ArrayView2<f32>) -> f64 {
    debug_assert_eq!(x.dim(), gt.dim(), "metrics need images of one shape");
    let sxg = sum_pairs(x, gt, |a, g| a * g);
    let sxx = sum_pairs(x, gt, |a, _| a * a);
    if sxx == 0.0 { 1.0 } else { sxg / sxx }
}

/// PSNR in dB after the least-squares gain: `k = `[`gain_lsq`]`(x, gt)`, `clip(k * x, 0, 1)`, then
/// [`psnr`]'s formula (infinite when the corrected image equals `gt`). For methods whose output
/// scale is arbitrary. Precondition: equal shapes.
pub fn psnr_after_gain(x: ArrayView2<f32>, gt: ArrayView2<f32>) -> f64 {
    let k = gain_lsq(x, gt);
    psnr_from_mse(mse_by(x, gt, |v| (k * v).clamp(0.0, DATA_RANGE)))
}

/// The 11 normalised taps of the SSIM Gaussian, as `scipy.ndimage.gaussian_filter1d` builds them.
fn gaussian_taps() -> [f64; SSIM_WINDOW] {
    let mut taps = [0.0; SSIM_WINDOW];
    let scale = -0.5 / (SSIM_SIGMA * SSIM_SIGMA);
    for (k, tap) in taps.iter_mut().enumerate() {
        let d = k as f64 - SSIM_RADIUS as f64;
        *tap = (scale * d * d).exp();
    }
    let sum: f64 = taps.iter().sum();
    taps.iter_mut().for_each(|t| *t /= sum);
    taps
}

/// The five local moments SSIM needs: E[x], E[y], E[x^2], E[y^2], E[xy].
type Moments = [f64; 5];

/// SSIM of one window from its (weighted) moments, population covariance.
fn ssim_from_moments([ux, uy, uxx, uyy, uxy]: Moments) -> f64 {
    let vx = uxx - ux * ux;
    let vy = uyy - uy * uy;
    let vxy = uxy - ux * uy;
    let a1 = 2.0 * ux * uy + SSIM_C1;
    let a2 = 2.0 * vxy + SSIM_C2;
    let b1 = ux * ux + uy * uy + SSIM_C1;
    let b2 = vx + vy + SSIM_C2;
    (a1 * a2) / (b1 * b2)
}

/// Mean structural similarity (Wang, Bovik, Sheikh and Simoncelli 2004) of `x` against `gt`.
///
/// Gaussian window 11x11 with sigma 1.5, `C1 = (0.01)^2`, `C2 = (0.03)^2`, population covariance,
/// mean of the SSIM map over the pixels whose whole window lies inside the image: this equals
/// scikit-image's `structural_similarity(x, gt, gaussian_weights=True, sigma=1.5,
/// use_sample_covariance=False, data_range=1)` on float64 input (a test checks it to 1e-9).
///
/// Images smaller than 11 pixels in either dimension have no such pixel (scikit-image refuses
/// them); here they get the global SSIM instead: the same formula with one window covering the
/// whole image, uniformly weighted (plain means and population variances). Empty images give 1.
/// Precondition: equal shapes. The Gaussian filtering is separable and runs on one thread (the
/// sink shares the machine with the rest of the graph), vectorised on the widest instruction set
/// the CPU has; the result does not depend on it.
pub fn ssim(x: ArrayView2<f32>, gt: ArrayView2<f32>) -> f64 {
    debug_assert_eq!(x.dim(), gt.dim(), "metrics need images of one shape");
    let (rows, cols) = x.dim();
    if rows == 0 || cols == 0 {
        1.0
    } else if rows < SSIM_WINDOW || cols < SSIM_WINDOW {
        ssim_global(x, gt)
    } else {
        neuspike_simd::dispatch(
            #[inline(always)]
            || ssim_windowed(x, gt),
        )
    }
}

/// SSIM with one uniform window over the whole image (two-pass means and variances).
fn ssim_global(x: ArrayView2<f32>, gt: ArrayView2<f32>) -> f64 {
    let n = x.len() as f64;
    let ux = x.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
    let uy = gt.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
    let (mut vx, mut vy, mut vxy) = (0.0, 0.0, 0.0);
    for (&a, &b) in x.iter().zip(gt.iter()) {
        let (da, db) = (f64::from(a) - ux, f64::from(b) - uy);
        vx += da * da;
        vy += db * db;
        vxy += da * db;
    }
    let (vx, vy, vxy) = (vx / n, vy / n, vxy / n);
    // Same as ssim_from_moments, written with the central moments directly.
    let a1 = 2.0 * ux * uy + SSIM_C1;
    let a2 = 2.0 * vxy + SSIM_C2;
    let b1 = ux * ux + uy * uy + SSIM_C1;
    let b2 = vx + vy + SSIM_C2;
    (a1 * a2) / (b1 * b2)
}

/// Gaussian-windowed SSIM over the valid region, separable: rows first, then columns. Each
/// filtered value adds its taps in tap order, so it equals the direct sum of the same products.
#[inline(always)]
fn ssim_windowed(x: ArrayView2<f32>, gt: ArrayView2<f32>) -> f64 {
    let (rows, cols) = x.dim();
    let out_rows = rows - 2 * SSIM_RADIUS;
    let out_cols = cols - 2 * SSIM_RADIUS;
    let taps = gaussian_taps();

    // Horizontal pass. Row r of the input gives five filtered rows (the moments E[x], E[y],
    // E[x^2], E[y^2], E[xy]), stored at `horizontal[(5 r + m) * out_cols..]`.
    let mut horizontal = vec![0.0f64; 5 * rows * out_cols];
    let mut signals = [
        vec![0.0f64; cols],
        vec![0.0f64; cols],
        vec![0.0f64; cols],
        vec![0.0f64; cols],
        vec![0.0f64; cols],
    ];
    for (r, out) in horizontal.chunks_exact_mut(5 * out_cols).enumerate() {
        let [xs, gs, xx, gg, xg] = &mut signals;
        for (c, (&a, &b)) in x.row(r).iter().zip(gt.row(r)).enumerate() {
            let (a, b) = (f64::from(a), f64::from(b));
            xs[c] = a;
            gs[c] = b;
            xx[c] = a * a;
            gg[c] = b * b;
            xg[c] = a * b;
        }
        for (signal, out) in signals.iter().zip(out.chunks_exact_mut(out_cols)) {
            for (k, &w) in taps.iter().enumerate() {
                for (o, &v) in out.iter_mut().zip(&signal[k..k + out_cols]) {
                    *o += w * v;
                }
            }
        }
    }

    // Vertical pass, one output row at a time, then the SSIM map summed in row-major order.
    let mut acc = vec![0.0f64; 5 * out_cols];
    let mut total = 0.0f64;
    for r in 0..out_rows {
        acc.fill(0.0);
        for (k, &w) in taps.iter().enumerate() {
            let src = &horizontal[5 * (r + k) * out_cols..5 * (r + k + 1) * out_cols];
            for (a, &v) in acc.iter_mut().zip(src) {
                *a += w * v;
            }
        }
        let (ux, rest) = acc.split_at(out_cols);
        let (uy, rest) = rest.split_at(out_cols);
        let (uxx, rest) = rest.split_at(out_cols);
        let (uyy, uxy) = rest.split_at(out_cols);
        let mut row = 0.0f64;
        for c in 0..out_cols {
            row += ssim_from_moments([ux[c], uy[c], uxx[c], uyy[c], uxy[c]]);
        }
        total += row;
    }
    total / (out_rows * out_cols) as f64
}

/// 8-bit grey level of a luminance: `round(clamp(v, 0, 1) * 255)`, half away from zero, in f64;
/// NaN gives 0. (`floor(y + 0.5)` is that rounding for `y >= 0`, exact here; `NaN as u8` is 0.)
#[inline(always)]
fn grey_level(v: f32) -> u8 {
    (f64::from(v).clamp(0.0, 1.0) * (GREY_LEVELS - 1) as f64 + 0.5) as u8
}

/// 2D entropy in bits (the paper's no-reference metric, `docs/definitions.md`), between 0 and 16.
///
/// Each pixel is quantised to 8 bits, `i = round(clamp(v, 0, 1) * 255)` (half away from zero;
/// NaN counts as 0); `j` is the rounded mean of the grey levels of its 3x3 neighbourhood with the
/// edges replicated (a sum of nine integers over 9 never ends in .5, so the rounding has no ties);
/// with `p_ij` the frequency of the pair over all pixels, `H2 = -sum p_ij log2 p_ij`. A constant
/// image gives 0, and so does an empty one. The value is at most `log2(pixels)`.
pub fn entropy_2d(x: ArrayView2<f32>) -> f64 {
    let (rows, cols) = x.dim();
    let n = rows * cols;
    if n == 0 {
        return 0.0;
    }
    let levels: Vec<u8> = match x.as_slice() {
        Some(xs) => neuspike_simd::dispatch(
            #[inline(always)]
            || xs.iter().map(|&v| grey_level(v)).collect(),
        ),
        None => x.iter().map(|&v| grey_level(v)).collect(),
    };
    // 3x3 box sums with the edges replicated: along rows, then along columns.
    let mut across = vec![0u16; n];
    for (row, out) in levels.chunks_exact(cols).zip(across.chunks_exact_mut(cols)) {
        for c in 0..cols {
            let (l, r) = (c.saturating_sub(1), (c + 1).min(cols - 1));
            out[c] = u16::from(row[l]) + u16::from(row[c]) + u16::from(row[r]);
        }
    }
    let mut counts = vec![0u64; GREY_LEVELS * GREY_LEVELS];
    for r in 0..rows {
        let at = |rr: usize| &across[rr * cols..(rr + 1) * cols];
        let (up, mid, down) = (at(r.saturating_sub(1)), at(r), at((r + 1).min(rows - 1)));
        let lv = &levels[r * cols..(r + 1) * cols];
        for c in 0..cols {
            let j = (usize::from(up[c]) + usize::from(mid[c]) + usize::from(down[c]) + 4) / 9;
            counts[usize::from(lv[c]) * GREY_LEVELS + j] += 1;
        }
    }
    let n = n as f64;
    counts
        .iter()
        .filter(|&&count| count > 0)
        .fold(0.0, |h, &count| {
            let p = count as f64 / n;
            h - p * p.log2()
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;
    use proptest::prelude::*;

    /// The generators below are reproduced exactly by the Python snippet that produced the
    /// scikit-image figures (see `skimage_reference_figures`).
    fn lcg(seed: u32) -> impl FnMut() -> f64 {
        let mut s = seed;
        move || {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            f64::from(s >> 8) / 16_777_216.0
        }
    }

    fn pattern(rows: usize, cols: usize) -> Array2<f32> {
        Array2::from_shape_fn((rows, cols), |(r, c)| {
            let (r, c) = (r as f64, c as f64);
            (0.5 + 0.3 * (0.37 * c + 0.11 * r).sin() * (0.23 * r).cos()
                + 0.15 * (0.5 * c - 0.3 * r).cos()) as f32
        })
    }

    fn noisy(a: &Array2<f32>, seed: u32) -> Array2<f32> {
        let mut next = lcg(seed);
        // row-major draw order, as in the Python loops
        let v: Vec<f32> = a
            .iter()
            .map(|&v| (f64::from(v) + 0.2 * (next() - 0.5)).clamp(0.0, 1.0) as f32)
            .collect();
        Array2::from_shape_vec(a.dim(), v).expect("shape")
    }

    fn affine(a: &Array2<f32>) -> Array2<f32> {
        a.mapv(|v| (0.8 * f64::from(v) + 0.1) as f32)
    }

    fn uniform(rows: usize, cols: usize, seed: u32) -> Array2<f32> {
        let mut next = lcg(seed);
        let v: Vec<f32> = (0..rows * cols).map(|_| next() as f32).collect();
        Array2::from_shape_vec((rows, cols), v).expect("shape")
    }

    /// Direct (non-separable) 2D Gaussian-window SSIM: the oracle for the separable fast path.
    fn ssim_direct(x: &Array2<f32>, y: &Array2<f32>) -> f64 {
        let taps = gaussian_taps();
        let (rows, cols) = x.dim();
        let mut total = 0.0;
        let mut n = 0usize;
        for r in SSIM_RADIUS..rows - SSIM_RADIUS {
            for c in SSIM_RADIUS..cols - SSIM_RADIUS {
                let mut m = [0.0; 5];
                for i in 0..SSIM_WINDOW {
                    for j in 0..SSIM_WINDOW {
                        let w = taps[i] * taps[j];
                        let a = f64::from(x[[r + i - SSIM_RADIUS, c + j - SSIM_RADIUS]]);
                        let b = f64::from(y[[r + i - SSIM_RADIUS, c + j - SSIM_RADIUS]]);
                        m[0] += w * a;
                        m[1] += w * b;
                        m[2] += w * a * a;
                        m[3] += w * b * b;
                        m[4] += w * a * b;
                    }
                }
                total += ssim_from_moments(m);
                n += 1;
            }
        }
        total / n as f64
    }

    #[test]
    fn generators_match_the_python_snippet() {
        // Printed by the snippet's last line: a[3,5], noisy(a,12345)[3,5], uniform(11,13,7)[0,0].
        let a = pattern(32, 40);
        assert_eq!(a[[3, 5]], 0.685_370_6_f32);
        assert_eq!(noisy(&a, 12345)[[3, 5]], 0.646_273_7_f32);
        assert_eq!(uniform(11, 13, 7)[[0, 0]], 0.238_780_8_f32);
    }

    #[test]
    fn psnr_of_identical_images_is_infinite() {
        let a = pattern(20, 30);
        assert_eq!(psnr(a.view(), a.view()), f64::INFINITY);
    }

    #[test]
    fn psnr_of_known_offsets() {
        let gt = Array2::<f32>::zeros((8, 9));
        // 0.5 and 0.25 are exact in f32: MSE 1/4 and 1/16.
        let half = Array2::<f32>::from_elem((8, 9), 0.5);
        assert_eq!(psnr(half.view(), gt.view()), 10.0 * 4f64.log10());
        let quarter = Array2::<f32>::from_elem((8, 9), 0.25);
        assert_eq!(psnr(quarter.view(), gt.view()), 10.0 * 16f64.log10());
        // 0.1 is not exact in f32 (0.100000001490116), so 20 dB holds to about 1.3e-7 dB.
        let tenth = pattern(8, 9).mapv(|v| v + 0.1);
        let base = pattern(8, 9);
        let p = psnr(tenth.view(), base.view());
        assert!((p - 20.0).abs() < 1e-5, "psnr {p}");
    }

    #[test]
    fn psnr_of_half_scale_is_finite_but_exact_after_gain() {
        let gt = pattern(24, 24);
        let x = gt.mapv(|v| v / 2.0);
        assert!((gain_lsq(x.view(), gt.view()) - 2.0).abs() < 1e-12);
        let plain = psnr(x.view(), gt.view());
        assert!(plain.is_finite() && plain < 20.0, "plain psnr {plain}");
        let gained = psnr_after_gain(x.view(), gt.view());
        assert!(gained > 100.0, "gain-corrected psnr {gained}");
    }

    #[test]
    fn gain_clips_to_the_unit_range() {
        // k = 2 here; 2 * 0.75 = 1.5 is clipped to 1, leaving MSE (1 - 1.5)^2 / 2 on purpose.
        let x = Array2::from_shape_vec((1, 2), vec![0.25f32, 0.75]).expect("shape");
        let gt = Array2::from_shape_vec((1, 2), vec![0.5f32, 1.5]).expect("shape");
        assert_eq!(gain_lsq(x.view(), gt.view()), 2.0);
        let p = psnr_after_gain(x.view(), gt.view());
        assert_eq!(p, 10.0 * (1.0 / 0.125f64).log10());
    }

    #[test]
    fn gain_of_a_black_image_is_one() {
        let x = Array2::<f32>::zeros((4, 4));
        let gt = pattern(4, 4);
        assert_eq!(gain_lsq(x.view(), gt.view()), 1.0);
        assert_eq!(
            psnr_after_gain(x.view(), gt.view()),
            psnr(x.view(), gt.view())
        );
    }

    #[test]
    fn shape_check_names_both_shapes() {
        let a = Array2::<f32>::zeros((3, 4));
        let b = Array2::<f32>::zeros((4, 3));
        assert!(check_same_shape(a.view(), a.view()).is_ok());
        let err = check_same_shape(a.view(), b.view()).expect_err("mismatch");
        assert_eq!(
            err,
            MetricsError::ShapeMismatch {
                x: [3, 4],
                gt: [4, 3]
            }
        );
        assert_eq!(
            err.to_string(),
            "shape mismatch: image is 3x4, ground truth is 4x3"
        );
    }

    #[test]
    fn ssim_of_identical_images_is_one() {
        for (rows, cols) in [(32, 40), (11, 11), (5, 7), (200, 150)] {
            let a = pattern(rows, cols);
            let s = ssim(a.view(), a.view());
            assert!((s - 1.0).abs() < 1e-12, "{rows}x{cols}: {s}");
        }
    }

    /// Figures from scikit-image 0.26.0, printed by this snippet (`python3 ssim_ref.py`):
    ///
    /// ```python
    /// import math
    /// import numpy as np
    /// from skimage.metrics import structural_similarity
    ///
    /// def lcg(seed):
    ///     s = seed
    ///     while True:
    ///         s = (s * 1664525 + 1013904223) % 2**32
    ///         yield (s >> 8) / 16777216.0
    ///
    /// def pattern(rows, cols):
    ///     return np.array([[np.float32(0.5 + 0.3 * math.sin(0.37 * c + 0.11 * r) * math.cos(0.23 * r)
    ///                                  + 0.15 * math.cos(0.5 * c - 0.3 * r))
    ///                       for c in range(cols)] for r in range(rows)], dtype=np.float32)
    ///
    /// def noisy(a, seed):
    ///     g = lcg(seed)
    ///     out = np.empty_like(a)
    ///     for r in range(a.shape[0]):
    ///         for c in range(a.shape[1]):
    ///             out[r, c] = np.float32(min(1.0, max(0.0, float(a[r, c]) + 0.2 * (next(g) - 0.5))))
    ///     return out
    ///
    /// def affine(a):
    ///     return np.array([[np.float32(0.8 * float(v) + 0.1) for v in row] for row in a], dtype=np.float32)
    ///
    /// def uniform(rows, cols, seed):
    ///     g = lcg(seed)
    ///     return np.array([[np.float32(next(g)) for _ in range(cols)] for _ in range(rows)], dtype=np.float32)
    ///
    /// def ssim(x, y):
    ///     # float64 so that skimage computes in double precision, as our Rust code does
    ///     return structural_similarity(x.astype(np.float64), y.astype(np.float64), gaussian_weights=True,
    ///                                  sigma=1.5, use_sample_covariance=False, data_range=1)
    ///
    /// a = pattern(32, 40)
    /// print("pattern_vs_noisy_32x40", repr(ssim(a, noisy(a, 12345))))
    /// print("pattern_vs_affine_32x40", repr(ssim(a, affine(a))))
    /// s = pattern(17, 23)
    /// print("pattern_vs_noisy_17x23", repr(ssim(s, noisy(s, 2024))))
    /// print("uniform_vs_uniform_11x13", repr(ssim(uniform(11, 13, 7), uniform(11, 13, 99))))
    /// print("checks", a[3,5], noisy(a,12345)[3,5], uniform(11,13,7)[0,0])
    /// ```
    #[test]
    fn ssim_matches_skimage_reference_figures() {
        let a = pattern(32, 40);
        let s = pattern(17, 23);
        let cases = [
            (
                "pattern_vs_noisy_32x40",
                a.clone(),
                noisy(&a, 12345),
                0.877_330_377_374_263,
            ),
            (
                "pattern_vs_affine_32x40",
                a.clone(),
                affine(&a),
                0.974_591_557_031_474_2,
            ),
            (
                "pattern_vs_noisy_17x23",
                s.clone(),
                noisy(&s, 2024),
                0.865_572_455_716_934_6,
            ),
            (
                "uniform_vs_uniform_11x13",
                uniform(11, 13, 7),
                uniform(11, 13, 99),
                -0.053_189_491_648_546_27,
            ),
        ];
        for (name, x, y, skimage) in cases {
            let ours = ssim(x.view(), y.view());
            assert!(
                (ours - skimage).abs() < 1e-9,
                "{name}: ours {ours}, skimage {skimage}"
            );
        }
    }

    #[test]
    fn separable_ssim_matches_the_direct_window_oracle() {
        let x = pattern(29, 34);
        let y = noisy(&x, 5);
        let direct = ssim_direct(&x, &y);
        let fast = ssim(x.view(), y.view());
        assert!((fast - direct).abs() < 1e-12, "{fast} vs {direct}");
    }

    #[test]
    fn ssim_is_the_same_on_every_instruction_set() {
        let x = pattern(250, 400);
        let y = noisy(&x, 77);
        let want = neuspike_simd::with_isa(neuspike_simd::Isa::Baseline, || {
            ssim_windowed(x.view(), y.view())
        });
        for isa in neuspike_simd::Isa::ALL {
            let got = neuspike_simd::with_isa(
                isa,
                #[inline(always)]
                || ssim_windowed(x.view(), y.view()),
            );
            assert_eq!(got.to_bits(), want.to_bits(), "{}", isa.name());
        }
    }

    #[test]
    fn ssim_works_on_non_contiguous_views() {
        let x = pattern(40, 30);
        let y = noisy(&x, 9);
        let xt = x.t().to_owned();
        let yt = y.t().to_owned();
        let on_views = ssim(x.t(), y.t());
        let on_owned = ssim(xt.view(), yt.view());
        assert_eq!(on_views, on_owned);
    }

    #[test]
    fn ssim_of_constant_images_has_the_closed_form() {
        // Variances vanish, so SSIM = (2 a b + C1) / (a^2 + b^2 + C1); windowed and global agree.
        let expected = (2.0 * 0.25 * 0.5 + SSIM_C1) / (0.25 * 0.25 + 0.5 * 0.5 + SSIM_C1);
        for (rows, cols) in [(16, 16), (4, 30), (1, 1)] {
            let x = Array2::<f32>::from_elem((rows, cols), 0.25);
            let y = Array2::<f32>::from_elem((rows, cols), 0.5);
            let s = ssim(x.view(), y.view());
            assert!((s - expected).abs() < 1e-12, "{rows}x{cols}: {s}");
        }
    }

    #[test]
    fn global_ssim_of_small_images_follows_the_formula() {
        // 1x2 images: x = (0, 1), y = (1, 0): ux = uy = 1/2, vx = vy = 1/4, vxy = -1/4.
        let x = Array2::from_shape_vec((1, 2), vec![0.0f32, 1.0]).expect("shape");
        let y = Array2::from_shape_vec((1, 2), vec![1.0f32, 0.0]).expect("shape");
        let expected = ((0.5 + SSIM_C1) * (-0.5 + SSIM_C2)) / ((0.5 + SSIM_C1) * (0.5 + SSIM_C2));
        assert!((ssim(x.view(), y.view()) - expected).abs() < 1e-15);
        let empty = Array2::<f32>::zeros((0, 3));
        assert_eq!(ssim(empty.view(), empty.view()), 1.0);
    }

    #[test]
    fn ssim_of_nan_is_nan() {
        let x = pattern(12, 12);
        let mut y = x.clone();
        y[[6, 6]] = f32::NAN;
        assert!(ssim(x.view(), y.view()).is_nan());
        assert!(psnr(x.view(), y.view()).is_nan());
    }

    #[test]
    fn entropy_of_a_constant_image_is_zero() {
        for v in [0.0f32, 0.3, 1.0, 7.0, f32::NAN] {
            let x = Array2::<f32>::from_elem((9, 13), v);
            let h = entropy_2d(x.view());
            assert_eq!(h.to_bits(), 0f64.to_bits(), "value {v}: {h}");
        }
        assert_eq!(entropy_2d(Array2::<f32>::zeros((0, 0)).view()), 0.0);
    }

    #[test]
    fn entropy_of_a_4x4_checkerboard_is_two_bits() {
        // Levels 0 and 255. With edges replicated, the 3x3 sums are:
        // - interior and corner pixels: 4 * 255 neighbours of the other colour (j = 113) around a
        //   0, and 5 * 255 (j = 142) around a 255;
        // - edge (non-corner) pixels the reverse: a 0 sees 5 * 255 (j = 142), a 255 sees 4 * 255.
        // 16 pixels: (0,113) x4 [2 corners + 2 interior], (255,142) x4, (0,142) x4, (255,113) x4,
        // so four pairs of probability 1/4: H2 = 2 bits.
        let x = Array2::from_shape_fn((4, 4), |(r, c)| ((r + c) % 2) as f32);
        assert_eq!(entropy_2d(x.view()), 2.0);
    }

    #[test]
    fn entropy_of_a_large_checkerboard_counts_its_border() {
        // Interior and corner pixels give the two "normal" pairs (0,113) and (255,142), each
        // (n-2)^2/2 + 2 times; the 4n - 8 edge pixels give the swapped pairs, each 2n - 4 times.
        let n = 100;
        let x = Array2::from_shape_fn((n, n), |(r, c)| ((r + c) % 2) as f32);
        let pixels = (n * n) as f64;
        let p_normal = (((n - 2) * (n - 2) / 2 + 2) as f64) / pixels;
        let p_swapped = ((2 * n - 4) as f64) / pixels;
        let expected = -2.0 * (p_normal * p_normal.log2() + p_swapped * p_swapped.log2());
        // the border keeps it well above the 1 bit of an infinite board
        assert!(expected > 1.2 && expected < 1.3, "{expected}");
        assert!((entropy_2d(x.view()) - expected).abs() < 1e-12);
    }

    /// Figures from an independent numpy implementation, with `pattern` and `noisy` as in the SSIM
    /// snippet above:
    ///
    /// ```python
    /// def entropy2d(x):
    ///     q = np.floor(np.clip(x.astype(np.float64), 0, 1) * 255 + 0.5).astype(np.int64)
    ///     p = np.pad(q, 1, mode='edge')
    ///     s = sum(p[1+dr:1+dr+q.shape[0], 1+dc:1+dc+q.shape[1]] for dr in (-1,0,1) for dc in (-1,0,1))
    ///     j = np.floor(s / 9 + 0.5).astype(np.int64)
    ///     _, counts = np.unique(q * 256 + j, return_counts=True)
    ///     pr = counts / q.size
    ///     return float(-(pr * np.log2(pr)).sum())
    /// a = pattern(32, 40)
    /// print(entropy2d(a), entropy2d(noisy(a, 12345)))
    /// ```
    #[test]
    fn entropy_matches_numpy_reference_figures() {
        let a = pattern(32, 40);
        let h = entropy_2d(a.view());
        assert!((h - 9.289_603_403_557_257).abs() < 1e-12, "{h}");
        let h = entropy_2d(noisy(&a, 12345).view());
        assert!((h - 10.186_756_571_443_1).abs() < 1e-12, "{h}");
    }

    #[test]
    fn entropy_of_uniform_noise_is_high() {
        let x = uniform(256, 256, 1);
        let h = entropy_2d(x.view());
        assert!(h > 12.0 && h <= 16.0, "entropy {h}");
    }

    #[test]
    fn entropy_quantises_out_of_range_values_by_clamping() {
        let a = Array2::from_shape_fn(
            (6, 6),
            |(r, c)| if (r * 6 + c) % 3 == 0 { 2.0 } else { -1.0 },
        );
        let b = Array2::from_shape_fn(
            (6, 6),
            |(r, c)| if (r * 6 + c) % 3 == 0 { 1.0 } else { 0.0 },
        );
        assert_eq!(entropy_2d(a.view()), entropy_2d(b.view()));
    }

    fn image_pair() -> impl Strategy<Value = (Array2<f32>, Array2<f32>)> {
        (1usize..24, 1usize..24).prop_flat_map(|(rows, cols)| {
            let n = rows * cols;
            (
                proptest::collection::vec(0.0f32..=1.0, n),
                proptest::collection::vec(0.0f32..=1.0, n),
            )
                .prop_map(move |(a, b)| {
                    (
                        Array2::from_shape_vec((rows, cols), a).expect("shape"),
                        Array2::from_shape_vec((rows, cols), b).expect("shape"),
                    )
                })
        })
    }

    proptest! {
        #[test]
        fn psnr_is_symmetric((a, b) in image_pair()) {
            prop_assert_eq!(psnr(a.view(), b.view()), psnr(b.view(), a.view()));
        }

        #[test]
        fn ssim_is_bounded_and_symmetric((a, b) in image_pair()) {
            let ab = ssim(a.view(), b.view());
            let ba = ssim(b.view(), a.view());
            prop_assert!((-1.0 - 1e-12..=1.0 + 1e-12).contains(&ab), "ssim {}", ab);
            prop_assert!((ab - ba).abs() <= 1e-15, "{} vs {}", ab, ba);
        }

        #[test]
        fn entropy_is_within_bounds((a, _b) in image_pair()) {
            let h = entropy_2d(a.view());
            prop_assert!(h >= 0.0);
            prop_assert!(h <= 16.0);
            prop_assert!(h <= (a.len() as f64).log2() + 1e-12);
        }
    }
}
