//! Moving a rendered image by a fraction of a pixel: the motion-compensated interpolation a
//! camera uses to make the images between two renders of a moving scene (see
//! `neuspike-spike-source`'s `--warp-step-ticks`).
//!
//! [`shift_into`] writes `dst[r][c] = src(c + margin - dx, r + margin - dy)`, `src` interpolated
//! with the Catmull-Rom cubic (separable, 4 x 4 taps): the image content moved by `(dx, dy)`
//! pixels, read from a source rendered with `margin` pixels beyond every edge of `dst`. The cubic
//! reproduces a shift by whole pixels exactly and a linear ramp at any shift; bilinear
//! interpolation would blur each shifted image by up to half a pixel. Where the taps would
//! reach past `src` (a shift larger than `margin - 2`), coordinates clamp to its edge. The fast
//! path (the horizontal pass four rows at a time, each output row from them, vectorised through
//! [`neuspike_simd::dispatch`]) is checked against [`shift_reference`], which computes every tap
//! from scratch.

use ndarray::{Array2, ArrayView2, ArrayViewMut2, Zip};

use crate::Scene;

/// The largest margin an [`Interpolator`] renders beyond each edge, pixels; motion beyond it
/// between two renders clamps the taps at the render's edge.
pub const MAX_MARGIN: usize = 256;

/// Images of a moving scene at any instant, made from renders every `step_ns` (at `origin_ns +
/// j step_ns`): the image at `t` between renders at `a <= t < b` is `(1 - w) A' + w B'`, `w = (t -
/// a) / (b - a)`, where `A'` and `B'` are the two renders moved ([`shift_into`]) by how far the
/// content at the view's centre moves from their instants to `t` ([`Scene::content_shift`]).
/// Translation is followed exactly (up to the cubic's interpolation); the turn and zoom about the
/// centre between two renders are not, and the blend of the two takes them up. Renders carry a
/// margin beyond every edge as wide as the fastest point moves between two renders (at most
/// [`MAX_MARGIN`]).
pub struct Interpolator {
    origin_ns: i64,
    step_ns: i64,
    margin: usize,
    rows: usize,
    cols: usize,
    /// The renders at the two nearest render instants (index `j`, image with margin).
    a: Option<(i64, Array2<f32>)>,
    b: Option<(i64, Array2<f32>)>,
    scratch: Vec<f32>,
}

impl Interpolator {
    /// For a `rows x cols` camera, rendering at `origin_ns + j step_ns` (`step_ns` at least 1).
    pub fn new(scene: &Scene, rows: usize, cols: usize, origin_ns: i64, step_ns: i64) -> Self {
        let step_ns = step_ns.max(1);
        let scale = (cols as f64 / scene.width().max(1) as f64)
            .max(rows as f64 / scene.height().max(1) as f64);
        let reach = scene.max_speed_px_per_s() * scale * step_ns as f64 * 1e-9;
        let margin = if reach.is_finite() {
            (reach.ceil() as usize).saturating_add(3).min(MAX_MARGIN)
        } else {
            MAX_MARGIN
        };
        Interpolator {
            origin_ns,
            step_ns,
            margin,
            rows,
            cols,
            a: None,
            b: None,
            scratch: Vec::new(),
        }
    }

    /// Nanoseconds between two renders.
    pub fn step_ns(&self) -> i64 {
        self.step_ns
    }

    /// Pixels rendered beyond each edge.
    pub fn margin(&self) -> usize {
        self.margin
    }

    /// The instant of render `j`.
    fn instant(&self, j: i64) -> i64 {
        self.origin_ns
            .saturating_add(j.saturating_mul(self.step_ns))
    }

    /// Render `j` into slot `a` or `b`, reusing the other slot when it holds it.
    fn render(&mut self, scene: &Scene, j: i64, slot_b: bool) {
        let has = |s: &Option<(i64, Array2<f32>)>| s.as_ref().is_some_and(|(i, _)| *i == j);
        if (!slot_b && has(&self.a)) || (slot_b && has(&self.b)) {
            return;
        }
        if !slot_b && has(&self.b) {
            std::mem::swap(&mut self.a, &mut self.b);
            return;
        }
        let t = self.instant(j);
        let m = self.margin;
        let shape = (self.rows + 2 * m, self.cols + 2 * m);
        let slot = if slot_b { &mut self.b } else { &mut self.a };
        let mut img = match slot.take() {
            Some((_, img)) if img.dim() == shape => img,
            _ => Array2::zeros(shape),
        };
        let origin = -(m as i64);
        scene.render_region_into(t, [self.rows, self.cols], [origin, origin], img.view_mut());
        *slot = Some((j, img));
    }

    /// The image at `t_ns` into `dst` (`rows x cols`).
    pub fn image_into(&mut self, scene: &Scene, t_ns: i64, mut dst: ArrayViewMut2<'_, f32>) {
        let j = t_ns.saturating_sub(self.origin_ns).div_euclid(self.step_ns);
        let (ta, tb) = (self.instant(j), self.instant(j.saturating_add(1)));
        self.render(scene, j, false);
        let (fx, fy) = (
            self.cols as f64 / scene.width().max(1) as f64,
            self.rows as f64 / scene.height().max(1) as f64,
        );
        let to_sensor = |(dx, dy): (f64, f64)| (dx * fx, dy * fy);
        let m = self.margin;
        let Some((_, a)) = &self.a else { return };
        let sa = to_sensor(scene.content_shift(ta, t_ns));
        shift_into(a.view(), m, sa, dst.view_mut(), &mut self.scratch);
        if t_ns <= ta || tb <= ta {
            return;
        }
        self.render(scene, j.saturating_add(1), true);
        let Some((_, b)) = &self.b else { return };
        let sb = to_sensor(scene.content_shift(tb, t_ns));
        let w = ((t_ns - ta) as f64 / (tb - ta) as f64) as f32;
        shift_blend_into(b.view(), m, sb, w, dst, &mut self.scratch);
    }
}

/// The Catmull-Rom weights of the four taps at `x - 1, x, x + 1, x + 2` for fraction `t` in
/// `[0, 1)`; they sum to 1, and `t = 0` gives `[0, 1, 0, 0]` exactly.
pub fn cubic_weights(t: f32) -> [f32; 4] {
    let (t2, t3) = (t * t, t * t * t);
    [
        -0.5 * t3 + t2 - 0.5 * t,
        1.5 * t3 - 2.5 * t2 + 1.0,
        -1.5 * t3 + 2.0 * t2 + 0.5 * t,
        0.5 * t3 - 0.5 * t2,
    ]
}

/// Integer part and fraction of the source coordinate of destination index 0 along one axis:
/// `margin - d`. A non-finite shift reads as 0.
fn split(margin: usize, d: f64) -> (i64, f32) {
    let x = margin as f64 - if d.is_finite() { d } else { 0.0 };
    let x = x.clamp(-1e9, 1e9);
    let i = x.floor();
    (i as i64, ((x - i) as f32).clamp(0.0, 1.0))
}

/// The scalar oracle of [`shift_into`]: each destination pixel's 16 taps, clamped to `src`.
pub fn shift_reference(
    src: ArrayView2<'_, f32>,
    margin: usize,
    (dx, dy): (f64, f64),
    mut dst: ArrayViewMut2<'_, f32>,
) {
    let (sh, sw) = src.dim();
    if sh == 0 || sw == 0 {
        dst.fill(0.0);
        return;
    }
    let (ix, fx) = split(margin, dx);
    let (iy, fy) = split(margin, dy);
    let (wx, wy) = (cubic_weights(fx), cubic_weights(fy));
    let clamp = |i: i64, n: usize| i.clamp(0, n as i64 - 1) as usize;
    for ((r, c), d) in dst.indexed_iter_mut() {
        let mut sum = 0.0f32;
        for (j, wyj) in wy.iter().enumerate() {
            let y = clamp(iy + r as i64 - 1 + j as i64, sh);
            let mut row = 0.0f32;
            for (i, wxi) in wx.iter().enumerate() {
                let x = clamp(ix + c as i64 - 1 + i as i64, sw);
                row += wxi * src[[y, x]];
            }
            sum += wyj * row;
        }
        *d = sum;
    }
}

/// The content of `src` moved by `(dx, dy)` pixels into `dst` (see the module documentation);
/// `scratch` holds four rows of the horizontal pass between calls. Equal to [`shift_reference`]
/// up to rounding.
pub fn shift_into(
    src: ArrayView2<'_, f32>,
    margin: usize,
    shift: (f64, f64),
    dst: ArrayViewMut2<'_, f32>,
    scratch: &mut Vec<f32>,
) {
    shift_with::<false>(src, margin, shift, 0.0, dst, scratch);
}

/// `dst` moved a fraction `w` of the way towards the content of `src` moved by `(dx, dy)`:
/// `dst + w (shifted - dst)`, the same bits as [`shift_into`] into an image and that blend, in
/// one pass over `dst`.
pub fn shift_blend_into(
    src: ArrayView2<'_, f32>,
    margin: usize,
    shift: (f64, f64),
    w: f32,
    dst: ArrayViewMut2<'_, f32>,
    scratch: &mut Vec<f32>,
) {
    shift_with::<true>(src, margin, shift, w, dst, scratch);
}

/// [`shift_into`] (`BLEND` false) or [`shift_blend_into`] (`BLEND` true, towards by `blend`).
fn shift_with<const BLEND: bool>(
    src: ArrayView2<'_, f32>,
    margin: usize,
    shift: (f64, f64),
    blend: f32,
    mut dst: ArrayViewMut2<'_, f32>,
    scratch: &mut Vec<f32>,
) {
    let (sh, sw) = src.dim();
    let (h, w) = dst.dim();
    let (ix, fx) = split(margin, shift.0);
    let (iy, fy) = split(margin, shift.1);
    // The fast path needs every tap inside `src`, both arrays contiguous.
    let inside = ix >= 1
        && iy >= 1
        && (ix as usize) + w + 2 <= sw
        && (iy as usize) + h + 2 <= sh
        && h > 0
        && w > 0;
    let contiguous = src.as_slice().is_some() && dst.as_slice().is_some();
    if !(inside && contiguous) {
        if BLEND {
            let mut moved = Array2::zeros((h, w));
            shift_reference(src, margin, shift, moved.view_mut());
            Zip::from(&mut dst)
                .and(&moved)
                .for_each(|d, &m| *d += blend * (m - *d));
        } else {
            shift_reference(src, margin, shift, dst);
        }
        return;
    }
    let (Some(s), Some(d)) = (src.as_slice(), dst.as_slice_mut()) else {
        return;
    };
    let (wx, wy) = (cubic_weights(fx), cubic_weights(fy));
    let (x0, y0) = (ix as usize - 1, iy as usize - 1);
    scratch.resize(4 * w, 0.0);
    neuspike_simd::dispatch(
        #[inline(always)]
        || {
            // Source row `k` of the window through the horizontal taps, into `t` (a function,
            // so that it is inlined into each instruction set's variant).
            #[inline(always)]
            fn across(row: &[f32], wx: [f32; 4], t: &mut [f32]) {
                let w = t.len();
                let (a, b, c, e) = (&row[..w], &row[1..w + 1], &row[2..w + 2], &row[3..w + 3]);
                for i in 0..w {
                    t[i] = wx[0] * a[i] + wx[1] * b[i] + wx[2] * c[i] + wx[3] * e[i];
                }
            }
            let src_row = |k: usize| &s[(y0 + k) * sw + x0..(y0 + k) * sw + x0 + w + 3];
            // The horizontal pass keeps the four rows the vertical taps read (row `k` in slot
            // `k % 4`), so that both passes and the blend read and write each image once.
            for k in 0..3 {
                across(src_row(k), wx, &mut scratch[k * w..(k + 1) * w]);
            }
            for (r, out) in d.chunks_exact_mut(w).enumerate() {
                let k = r + 3;
                across(src_row(k), wx, &mut scratch[(k % 4) * w..(k % 4 + 1) * w]);
                let row = |j: usize| &scratch[((r + j) % 4) * w..((r + j) % 4 + 1) * w];
                let (a, b, c, e) = (row(0), row(1), row(2), row(3));
                for i in 0..w {
                    let v = wy[0] * a[i] + wy[1] * b[i] + wy[2] * c[i] + wy[3] * e[i];
                    out[i] = if BLEND {
                        out[i] + blend * (v - out[i])
                    } else {
                        v
                    };
                }
            }
        },
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;
    use proptest::prelude::*;

    fn image(h: usize, w: usize, seed: u64) -> Array2<f32> {
        let mut x = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        Array2::from_shape_fn((h, w), |_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 40) as f32 / (1u64 << 24) as f32
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]

        #[test]
        fn fast_equals_reference(
            (h, w, margin) in (1usize..40, 1usize..40, 0usize..8),
            (dx, dy) in (-10.0f64..10.0, -10.0f64..10.0),
            seed in any::<u64>(),
        ) {
            let src = image(h + 2 * margin, w + 2 * margin, seed);
            let mut fast = Array2::zeros((h, w));
            let mut reference = Array2::zeros((h, w));
            let mut scratch = Vec::new();
            shift_into(src.view(), margin, (dx, dy), fast.view_mut(), &mut scratch);
            shift_reference(src.view(), margin, (dx, dy), reference.view_mut());
            for (a, b) in fast.iter().zip(&reference) {
                prop_assert!((a - b).abs() < 1e-5, "{} vs {}", a, b);
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(100))]

        /// The blend in the same pass gives the bits of the shift and then the blend, on the
        /// fast path and where the taps clamp at the edge.
        #[test]
        fn shift_blend_is_the_shift_then_the_blend(
            (h, w, margin) in (1usize..40, 1usize..40, 0usize..8),
            (dx, dy) in (-10.0f64..10.0, -10.0f64..10.0),
            weight in 0.0f32..=1.0,
            seed in any::<u64>(),
        ) {
            let src = image(h + 2 * margin, w + 2 * margin, seed);
            let before = image(h, w, seed ^ 1);
            let mut scratch = Vec::new();
            let mut moved = Array2::zeros((h, w));
            shift_into(src.view(), margin, (dx, dy), moved.view_mut(), &mut scratch);
            let mut want = before.clone();
            want.zip_mut_with(&moved, |d, &m| *d += weight * (m - *d));
            let mut got = before.clone();
            shift_blend_into(src.view(), margin, (dx, dy), weight, got.view_mut(), &mut scratch);
            for (a, b) in got.iter().zip(&want) {
                prop_assert_eq!(a.to_bits(), b.to_bits());
            }
        }
    }

    #[test]
    fn whole_pixels_move_exactly_and_a_ramp_stays_a_ramp() {
        let src = image(30, 40, 7);
        let mut dst = Array2::zeros((20, 30));
        let mut scratch = Vec::new();
        shift_into(src.view(), 5, (2.0, -3.0), dst.view_mut(), &mut scratch);
        for ((r, c), v) in dst.indexed_iter() {
            assert_eq!(*v, src[[r + 5 + 3, c + 5 - 2]]);
        }
        // A linear ramp, moved by a fraction, is the ramp at the moved coordinate.
        let ramp = Array2::from_shape_fn((30, 40), |(r, c)| 0.01 * c as f32 + 0.02 * r as f32);
        shift_into(ramp.view(), 5, (0.3, 0.7), dst.view_mut(), &mut scratch);
        for ((r, c), v) in dst.indexed_iter() {
            let want = 0.01 * (c as f32 + 5.0 - 0.3) + 0.02 * (r as f32 + 5.0 - 0.7);
            assert!((v - want).abs() < 1e-5, "({r}, {c}): {v} vs {want}");
        }
        // Past the margin the taps clamp to the edge: finite, no panic.
        shift_into(src.view(), 5, (1e6, f64::NAN), dst.view_mut(), &mut scratch);
        assert!(dst.iter().all(|v| v.is_finite()));
    }
}
