//! Moving a rendered image by a fraction of a pixel: the motion-compensated interpolation a
//! camera uses to make the images between two renders of a moving scene (see
//! the spike camera's `--warp-step-ticks`).
//!
//! [`shift_into`] writes `dst[r][c] = src(c + margin - dx, r + margin - dy)`, `src` interpolated
//! with the Catmull-Rom cubic (separable, 4 x 4 taps): the image content moved by `(dx, dy)`
//! pixels, read from a source rendered with `margin` pixels beyond every edge of `dst`. The cubic
//! reproduces a shift by whole pixels exactly and a linear ramp at any shift; bilinear
//! interpolation would blur each shifted image by up to half a pixel. Where the taps would
//! reach past `src` (a shift larger than `margin - 2`), coordinates clamp to its edge.
//! [`shift_rows`] can first blend a second source into the first ([`Blended`]: read a whole
//! number of pixels further on), so that two renders of one instant's content cost one move.
//! The fast path (the horizontal pass four rows at a time, each output row from them, vectorised
//! through [`neuspike_simd::dispatch`]) is checked against [`blend_reference`] and
//! [`shift_reference`], which compute every value from scratch.

use ndarray::{Array2, ArrayView1, ArrayView2, ArrayViewMut2};

use crate::Scene;

/// The largest margin an [`Interpolator`] renders beyond each edge, pixels; motion beyond it
/// between two renders clamps the taps at the render's edge.
pub const MAX_MARGIN: usize = 256;

/// Images of a moving scene at any instant, made from renders every `step_ns` (at `origin_ns +
/// j step_ns`): the image at `t` between renders at `a <= t < b` is `(1 - w) A' + w B'`, `w = (t -
/// a) / (b - a)`, where `A'` and `B'` are the two renders moved by how far the content at the
/// view's centre moves from their instants to `t` ([`Scene::content_path`]).
///
/// Each render samples the view displaced by the fraction of a pixel its content has moved
/// since the motion started, so every render lies on one grid that moves with the content,
/// whole pixels apart: `A'` and `B'` then need the same fraction of a pixel's move, and
/// [`shift_rows`] blends the two renders first (B read the whole pixels further on) and moves
/// the blend once. Translation is followed exactly (up to the cubic); the turn and zoom about
/// the centre between two renders are not, and the blend of the two takes them up. Renders
/// carry a margin beyond every edge as wide as the fastest point moves between two renders (at
/// most [`MAX_MARGIN`]).
pub struct Interpolator {
    origin_ns: i64,
    step_ns: i64,
    margin: usize,
    rows: usize,
    cols: usize,
    /// The renders at the two nearest render instants.
    a: Option<Render>,
    b: Option<Render>,
    scratch: Vec<f32>,
}

/// Render `j` with a margin, sampled `frac` of a pixel further on, where the content's path
/// (sensor pixels, `[row, col]`) is `whole + frac`.
struct Render {
    j: i64,
    whole: [i64; 2],
    img: Array2<f32>,
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

    /// The content's path at `t_ns` ([`Scene::content_path`]) in sensor pixels, `[row, col]`.
    fn path(&self, scene: &Scene, t_ns: i64) -> [f64; 2] {
        let (dx, dy) = scene.content_path(t_ns);
        [
            dy * self.rows as f64 / scene.height().max(1) as f64,
            dx * self.cols as f64 / scene.width().max(1) as f64,
        ]
    }

    /// Render `j` into slot `a` or `b`, reusing the other slot when it holds it.
    fn render(&mut self, scene: &Scene, j: i64, slot_b: bool) {
        let has = |s: &Option<Render>| s.as_ref().is_some_and(|r| r.j == j);
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
        // The whole pixels of the path (clamped far beyond any image), and the fraction the
        // render is sampled further on.
        let path = self.path(scene, t);
        let whole = path.map(|p| p.floor().clamp(-1e15, 1e15) as i64);
        let frac = [path[0] - whole[0] as f64, path[1] - whole[1] as f64];
        let slot = if slot_b { &mut self.b } else { &mut self.a };
        let mut img = match slot.take() {
            Some(r) if r.img.dim() == shape => r.img,
            _ => Array2::zeros(shape),
        };
        let origin = frac.map(|f| f - m as f64);
        scene.render_region_into(t, [self.rows, self.cols], origin, img.view_mut());
        *slot = Some(Render { j, whole, img });
    }

    /// The image at `t_ns` into `dst` (`rows x cols`).
    pub fn image_into(&mut self, scene: &Scene, t_ns: i64, mut dst: ArrayViewMut2<'_, f32>) {
        self.image_rows(scene, t_ns, |r, row| {
            dst.row_mut(r).assign(&ArrayView1::from(row))
        });
    }

    /// The image at `t_ns` (`rows x cols`), handed to `row(r, values)` one row at a time, top
    /// first ([`shift_rows`]): a caller that uses each row while it is in the cache reads and
    /// writes no whole image between the renders and its own.
    pub fn image_rows(&mut self, scene: &Scene, t_ns: i64, row: impl FnMut(usize, &[f32])) {
        let j = t_ns.saturating_sub(self.origin_ns).div_euclid(self.step_ns);
        let (ta, tb) = (self.instant(j), self.instant(j.saturating_add(1)));
        self.render(scene, j, false);
        let blend = t_ns > ta && tb > ta;
        if blend {
            self.render(scene, j.saturating_add(1), true);
        }
        let path = self.path(scene, t_ns);
        let Some(a) = &self.a else { return };
        // Render a's grid moved by the path since its whole pixels.
        let moved = Moved {
            src: a.img.view(),
            shift: (path[1] - a.whole[1] as f64, path[0] - a.whole[0] as f64),
        };
        let b = match (&self.b, blend) {
            (Some(b), true) => Some(Blended {
                src: b.img.view(),
                offset: [
                    b.whole[0].saturating_sub(a.whole[0]),
                    b.whole[1].saturating_sub(a.whole[1]),
                ],
                weight: ((t_ns - ta) as f64 / (tb - ta) as f64) as f32,
            }),
            _ => None,
        };
        let shape = (self.rows, self.cols);
        shift_rows(self.margin, shape, moved, b, &mut self.scratch, row);
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

/// The scalar oracle of [`shift_into`]: each destination pixel's 16 taps, clamped to `src`, in the
/// fast path's order and roundings (the same bits).
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
    // Each sum as the fast path forms it: the first tap's product, then a fused multiply-add
    // for each further tap.
    let taps = |w: &[f32; 4], v: &dyn Fn(usize) -> f32| {
        (1..4).fold(w[0] * v(0), |acc, k| w[k].mul_add(v(k), acc))
    };
    for ((r, c), d) in dst.indexed_iter_mut() {
        let row = |j: usize| {
            let y = clamp(iy + r as i64 - 1 + j as i64, sh);
            taps(&wx, &|i| src[[y, clamp(ix + c as i64 - 1 + i as i64, sw)]])
        };
        *d = taps(&wy, &row);
    }
}

/// The content of `src` moved by `(dx, dy)` pixels into `dst` (see the module documentation);
/// `scratch` holds the rows of the horizontal pass between calls. The same bits as
/// [`shift_reference`].
pub fn shift_into(
    src: ArrayView2<'_, f32>,
    margin: usize,
    shift: (f64, f64),
    mut dst: ArrayViewMut2<'_, f32>,
    scratch: &mut Vec<f32>,
) {
    let (h, w) = dst.dim();
    let moved = Moved { src, shift };
    shift_rows(margin, (h, w), moved, None, scratch, |r, row| {
        dst.row_mut(r).assign(&ArrayView1::from(row))
    });
}

/// A rendered image with `margin` pixels beyond every edge and how far to move its content.
#[derive(Clone, Copy, Debug)]
pub struct Moved<'a> {
    /// The render, `margin` wider than the output on every side.
    pub src: ArrayView2<'a, f32>,
    /// `(dx, dy)` in pixels.
    pub shift: (f64, f64),
}

/// A second render blended into a [`Moved`] one before the move: `src` read `offset` pixels
/// (`[rows, cols]`) further on than the first, taken the fraction `weight` of the way:
/// `a + weight (b - a)`.
#[derive(Clone, Copy, Debug)]
pub struct Blended<'a> {
    /// The second render.
    pub src: ArrayView2<'a, f32>,
    /// Where its pixels lie against the first's, `[rows, cols]`.
    pub offset: [i64; 2],
    /// How far towards it, 0 to 1.
    pub weight: f32,
}

/// The scalar oracle of the blend of [`shift_rows`]: over `a`'s shape, `a[r][c] + weight
/// (b[r + offset_r][c + offset_c] - a[r][c])`, `b`'s coordinates clamped to its edges (`a`
/// itself where `b` is empty).
pub fn blend_reference(a: ArrayView2<'_, f32>, b: &Blended<'_>) -> Array2<f32> {
    let (bh, bw) = b.src.dim();
    if bh == 0 || bw == 0 {
        return a.to_owned();
    }
    let clamp = |i: usize, d: i64, n: usize| (i as i64).saturating_add(d).clamp(0, n as i64 - 1);
    Array2::from_shape_fn(a.dim(), |(r, c)| {
        let y = clamp(r, b.offset[0], bh) as usize;
        let x = clamp(c, b.offset[1], bw) as usize;
        blend(a[[r, c]], b.src[[y, x]], b.weight)
    })
}

/// The `rows x cols` image `a` moved ([`shift_into`]), where `b` is given blended into `a`
/// first ([`Blended`]) and the blend moved, handed to `row(r, values)` one row at a time, top
/// first, so that a caller can use each row while it is in the cache. `scratch` holds the horizontal pass's rows
/// between calls. The same bits as [`blend_reference`] and then [`shift_reference`].
pub fn shift_rows<'a>(
    margin: usize,
    (h, w): (usize, usize),
    a: Moved<'a>,
    b: Option<Blended<'a>>,
    scratch: &mut Vec<f32>,
    mut row: impl FnMut(usize, &[f32]),
) {
    if h == 0 || w == 0 {
        return;
    }
    let Some(taps) = Taps::new(a, margin, (h, w), b.as_ref()) else {
        return slow_rows(margin, (h, w), a, b, row);
    };
    scratch.resize(6 * w + 3, 0.0);
    let (ring, rest) = scratch.split_at_mut(4 * w);
    let (out, mixed) = rest.split_at_mut(w);
    neuspike_simd::dispatch(
        #[inline(always)]
        || {
            taps.prime(ring, mixed);
            for r in 0..h {
                taps.row(r, ring, mixed, out);
                row(r, out);
            }
        },
    );
}

/// [`shift_rows`] where a tap would reach past a source or a source is not contiguous: the
/// blend through [`blend_reference`], moved through [`shift_reference`].
fn slow_rows(
    margin: usize,
    (h, w): (usize, usize),
    a: Moved<'_>,
    b: Option<Blended<'_>>,
    mut row: impl FnMut(usize, &[f32]),
) {
    let mixed = match &b {
        Some(b) => blend_reference(a.src, b),
        None => a.src.to_owned(),
    };
    let mut moved = Array2::zeros((h, w));
    shift_reference(mixed.view(), margin, a.shift, moved.view_mut());
    // A fresh array: standard layout, each row a slice.
    if let Some(all) = moved.as_slice() {
        for (r, values) in all.chunks_exact(w).enumerate() {
            row(r, values);
        }
    }
}

/// Four taps `w . v`, in order, each after the first a fused multiply-add.
#[inline(always)]
fn taps4(w: [f32; 4], v: [f32; 4]) -> f32 {
    w[3].mul_add(v[3], w[2].mul_add(v[2], w[1].mul_add(v[1], w[0] * v[0])))
}

/// `x` moved the fraction `w` of the way to `y`: `x + w (y - x)`, a fused multiply-add.
#[inline(always)]
fn blend(x: f32, y: f32, w: f32) -> f32 {
    w.mul_add(y - x, x)
}

/// The taps on the fast path: every tap inside a contiguous source, and the blended source's
/// window inside it too.
struct Taps<'a> {
    s: &'a [f32],
    sw: usize,
    w: usize,
    x0: usize,
    y0: usize,
    wx: [f32; 4],
    wy: [f32; 4],
    /// The blended source, its stride, where the window starts in it, and the weight.
    b: Option<(&'a [f32], usize, usize, f32)>,
}

impl<'a> Taps<'a> {
    /// `None` where a tap would reach past `moved.src` or `b.src`, or one is not contiguous.
    fn new(
        moved: Moved<'a>,
        margin: usize,
        (h, w): (usize, usize),
        b: Option<&Blended<'a>>,
    ) -> Option<Taps<'a>> {
        let (sh, sw) = moved.src.dim();
        let (ix, fx) = split(margin, moved.shift.0);
        let (iy, fy) = split(margin, moved.shift.1);
        let inside =
            ix >= 1 && iy >= 1 && (ix as usize) + w + 2 <= sw && (iy as usize) + h + 2 <= sh;
        let s = moved.src.to_slice()?;
        if !inside {
            return None;
        }
        let (x0, y0) = (ix as usize - 1, iy as usize - 1);
        let b = match b {
            None => None,
            Some(b) => {
                let (bh, bw) = b.src.dim();
                let bx = i64::try_from(x0).ok()?.checked_add(b.offset[1])?;
                let by = i64::try_from(y0).ok()?.checked_add(b.offset[0])?;
                let fits = bx >= 0
                    && by >= 0
                    && (bx as usize).checked_add(w + 3)? <= bw
                    && (by as usize).checked_add(h + 3)? <= bh;
                if !fits {
                    return None;
                }
                Some((
                    b.src.to_slice()?,
                    bw,
                    by as usize * bw + bx as usize,
                    b.weight,
                ))
            }
        };
        Some(Taps {
            s,
            sw,
            w,
            x0,
            y0,
            wx: cubic_weights(fx),
            wy: cubic_weights(fy),
            b,
        })
    }

    /// Source row `k` of the window (blended, when a second source is) through the horizontal
    /// taps into ring slot `k % 4`; `mixed` holds the blended row.
    #[inline(always)]
    fn across(&self, k: usize, ring: &mut [f32], mixed: &mut [f32]) {
        let w = self.w;
        let start = (self.y0 + k) * self.sw + self.x0;
        let mut row = &self.s[start..start + w + 3];
        if let Some((b, bw, b0, weight)) = self.b {
            let other = &b[b0 + k * bw..b0 + k * bw + w + 3];
            let mixed = &mut mixed[..w + 3];
            for i in 0..w + 3 {
                mixed[i] = blend(row[i], other[i], weight);
            }
            row = mixed;
        }
        let t = &mut ring[(k % 4) * w..(k % 4 + 1) * w];
        let (a, b, c, e) = (&row[..w], &row[1..w + 1], &row[2..w + 2], &row[3..w + 3]);
        let wx = self.wx;
        for i in 0..w {
            t[i] = taps4(wx, [a[i], b[i], c[i], e[i]]);
        }
    }

    /// The horizontal pass of the first three rows the vertical taps read.
    #[inline(always)]
    fn prime(&self, ring: &mut [f32], mixed: &mut [f32]) {
        for k in 0..3 {
            self.across(k, ring, mixed);
        }
    }

    /// Output row `r` into `out`, after rows `0..r` (the ring holds rows `r..r + 3`): the
    /// horizontal pass of row `r + 3`, then the vertical taps. Each source row goes through the
    /// horizontal pass once.
    #[inline(always)]
    fn row(&self, r: usize, ring: &mut [f32], mixed: &mut [f32], out: &mut [f32]) {
        let w = self.w;
        self.across(r + 3, ring, mixed);
        let slot = |j: usize| &ring[((r + j) % 4) * w..((r + j) % 4 + 1) * w];
        let (a, b, c, e) = (slot(0), slot(1), slot(2), slot(3));
        // As long as the slots, so that the loop has no bounds checks and vectorises.
        let out = &mut out[..w];
        let wy = self.wy;
        for i in 0..w {
            out[i] = taps4(wy, [a[i], b[i], c[i], e[i]]);
        }
    }
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
                prop_assert_eq!(a.to_bits(), b.to_bits(), "{} vs {}", a, b);
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(100))]

        /// Two images blended and moved row by row give the bits of the blend and then the
        /// move, on the fast path and where the taps clamp at an edge of either.
        #[test]
        fn blended_rows_are_the_blend_then_the_move(
            (h, w, margin) in (1usize..40, 1usize..40, 0usize..8),
            (dx, dy) in (-10.0f64..10.0, -10.0f64..10.0),
            (oy, ox) in (-6i64..6, -6i64..6),
            weight in 0.0f32..=1.0,
            seed in any::<u64>(),
        ) {
            let src_a = image(h + 2 * margin, w + 2 * margin, seed);
            let src_b = image(h + 2 * margin, w + 2 * margin, seed ^ 1);
            let b = Blended { src: src_b.view(), offset: [oy, ox], weight };
            let mixed = blend_reference(src_a.view(), &b);
            let mut want = Array2::zeros((h, w));
            shift_reference(mixed.view(), margin, (dx, dy), want.view_mut());
            let mut got = Array2::from_elem((h, w), f32::NAN);
            let a = Moved { src: src_a.view(), shift: (dx, dy) };
            let mut scratch = Vec::new();
            let mut seen = 0;
            shift_rows(margin, (h, w), a, Some(b), &mut scratch, |r, row| {
                assert_eq!(r, seen);
                seen += 1;
                got.row_mut(r).assign(&ndarray::ArrayView1::from(row));
            });
            prop_assert_eq!(seen, h);
            for (a, b) in got.iter().zip(&want) {
                prop_assert_eq!(a.to_bits(), b.to_bits());
            }
        }
    }

    /// The blend reads the second image `offset` further on: an image blended with itself moved
    /// by that offset is itself, at any weight, where the offset stays inside.
    #[test]
    fn the_blend_reads_the_second_image_its_offset_further_on() {
        let a = image(20, 30, 3);
        let (oy, ox) = (2usize, 3usize);
        // b[y][x] = a[y - oy][x - ox]: a's content `offset` further on.
        let b = Array2::from_shape_fn((20 + oy, 30 + ox), |(y, x)| {
            a[[y.saturating_sub(oy), x.saturating_sub(ox)]]
        });
        let mixed = blend_reference(
            a.view(),
            &Blended {
                src: b.view(),
                offset: [oy as i64, ox as i64],
                weight: 0.37,
            },
        );
        assert_eq!(mixed, a);
        let mut scratch = Vec::new();
        let mut got = Array2::zeros((16, 26));
        shift_rows(
            2,
            (16, 26),
            Moved {
                src: a.view(),
                shift: (0.25, -0.5),
            },
            Some(Blended {
                src: b.view(),
                offset: [oy as i64, ox as i64],
                weight: 0.8,
            }),
            &mut scratch,
            |r, row| got.row_mut(r).assign(&ndarray::ArrayView1::from(row)),
        );
        let mut alone = Array2::zeros((16, 26));
        shift_into(a.view(), 2, (0.25, -0.5), alone.view_mut(), &mut scratch);
        assert_eq!(got, alone);
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
