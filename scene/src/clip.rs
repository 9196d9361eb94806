//! A scene made of frames: a video clip seen by the cameras instead of a moving texture.
//!
//! Frame `k` of a `[T, H, W]` clip is the view (`W x H` scene pixels) at `t = k dt_ns`; between
//! two frames the light is linear in time, before the first it is the first and after the last
//! the last. Within a frame, texel `(r, c)` covers the scene square `[c, c + 1) x [r, r + 1)`,
//! its value at the centre, bilinear between centres and held at the edges (a clip does not
//! tile). A destination grid of another size samples it as a texture scene's does: each pixel
//! the mean of its `n x n` sub-samples (`samples_per_pixel`), so a grid of the clip's own size
//! with one sample a pixel reads the frames exactly, and one of half the size with two reads
//! the mean of each 2x2 block. Rendering is scalar, in `f64`, rows in parallel: it is its own
//! reference.

use ndarray::{Array3, ArrayViewMut2};

use crate::error::SceneError;
use crate::render::{self, Region};
use crate::spec::MAX_VIEW_SIDE;

/// Most frames a clip holds (a bound on what a caller may build a scene of, not on memory:
/// the frames are the caller's).
pub const MAX_CLIP_FRAMES: usize = 1 << 20;

/// The frames of a clip scene and the time between them. Values are luminance, finite and at
/// least 0 (`Clip::new` checks every one).
#[derive(Clone, PartialEq)]
pub struct Clip {
    frames: Array3<f32>,
    dt_ns: i64,
}

impl std::fmt::Debug for Clip {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Clip")
            .field("shape", &self.frames.dim())
            .field("dt_ns", &self.dt_ns)
            .finish_non_exhaustive()
    }
}

impl Clip {
    /// A clip of `frames` (`[T, H, W]`), one every `dt_ns`; `origin` names the frames in errors.
    ///
    /// # Errors
    /// No frame, a side of 0 or beyond [`MAX_VIEW_SIDE`], more than [`MAX_CLIP_FRAMES`] frames,
    /// `dt_ns` not above 0 or a clip longer than `i64` nanoseconds, or a value that is negative
    /// or not finite (named by frame, row and column).
    pub fn new(frames: Array3<f32>, dt_ns: i64, origin: &str) -> Result<Clip, SceneError> {
        let (t, h, w) = frames.dim();
        let invalid = |field: &str, value: String, reason: String| SceneError::Invalid {
            origin: origin.to_owned(),
            field: field.to_owned(),
            value,
            reason,
        };
        if !(1..=MAX_CLIP_FRAMES).contains(&t) {
            return Err(invalid(
                "frames",
                format!("{t} frames"),
                format!("must be 1..={MAX_CLIP_FRAMES}"),
            ));
        }
        for (field, side) in [("height", h), ("width", w)] {
            if !(1..=MAX_VIEW_SIDE).contains(&side) {
                return Err(invalid(
                    field,
                    side.to_string(),
                    format!("must be in 1..={MAX_VIEW_SIDE}"),
                ));
            }
        }
        if dt_ns <= 0 || dt_ns.checked_mul(t as i64 - 1).is_none() {
            return Err(invalid(
                "dt_ns",
                dt_ns.to_string(),
                format!("must be > 0, and {t} frames of it fit in i64 nanoseconds"),
            ));
        }
        if let Some(((k, r, c), v)) = frames
            .indexed_iter()
            .find(|(_, v)| !(v.is_finite() && **v >= 0.0))
        {
            return Err(invalid(
                &format!("frames[{k}][{r}][{c}]"),
                v.to_string(),
                "luminance must be finite and >= 0".to_owned(),
            ));
        }
        Ok(Clip { frames, dt_ns })
    }

    /// Frames in the clip.
    pub fn len(&self) -> usize {
        self.frames.dim().0
    }

    /// Whether the clip is empty (never: [`Clip::new`] refuses it).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Frame height (the view's, in scene pixels).
    pub fn height(&self) -> usize {
        self.frames.dim().1
    }

    /// Frame width (the view's, in scene pixels).
    pub fn width(&self) -> usize {
        self.frames.dim().2
    }

    /// Nanoseconds between two frames.
    pub fn dt_ns(&self) -> i64 {
        self.dt_ns
    }

    /// The frames, `[T, H, W]`.
    pub fn frames(&self) -> &Array3<f32> {
        &self.frames
    }

    /// The time of the last frame (0 for one frame).
    pub fn last_ns(&self) -> i64 {
        self.dt_ns * (self.len() as i64 - 1)
    }

    /// The two frames around `t_ns` and the weight of the second: `(k, k + 1, w)`, or `(k, k,
    /// 0)` at or beyond either end.
    pub(crate) fn bracket(&self, t_ns: i64) -> (usize, usize, f64) {
        let last = self.len() - 1;
        if t_ns <= 0 {
            return (0, 0, 0.0);
        }
        if t_ns >= self.last_ns() {
            return (last, last, 0.0);
        }
        let k = (t_ns / self.dt_ns) as usize;
        let w = (t_ns - k as i64 * self.dt_ns) as f64 / self.dt_ns as f64;
        (k, (k + 1).min(last), w)
    }

    /// The light at view point `(x, y)` between frames `a` and `b` (weight `w` of `b`):
    /// bilinear between texel centres, held at the edges; a non-finite coordinate reads as 0.
    pub(crate) fn sample(&self, (a, b, w): (usize, usize, f64), x: f64, y: f64) -> f64 {
        let (h, wd) = (self.height(), self.width());
        let x = if x.is_finite() { x - 0.5 } else { 0.0 };
        let y = if y.is_finite() { y - 0.5 } else { 0.0 };
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let clamp = |i: f64, n: usize| i.clamp(0.0, (n - 1) as f64) as usize;
        let (c0, c1) = (clamp(x0, wd), clamp(x0 + 1.0, wd));
        let (r0, r1) = (clamp(y0, h), clamp(y0 + 1.0, h));
        let at = |k: usize| {
            let t = |r: usize, c: usize| f64::from(self.frames[[k, r, c]]);
            (1.0 - fy) * ((1.0 - fx) * t(r0, c0) + fx * t(r0, c1))
                + fy * ((1.0 - fx) * t(r1, c0) + fx * t(r1, c1))
        };
        if w == 0.0 {
            at(a)
        } else {
            (1.0 - w) * at(a) + w * at(b)
        }
    }
}

/// `v` (0 if not finite) at least 0: the bounds of a clip's light.
fn finish(v: f64) -> f32 {
    let v = v as f32;
    if v.is_finite() { v.max(0.0) } else { 0.0 }
}

/// A region of a sensor seeing `clip` at `t_ns`, with `n x n` sub-samples a pixel.
pub(crate) fn render_region(
    clip: &Clip,
    n: usize,
    t_ns: i64,
    region: Region,
    dst: ArrayViewMut2<'_, f32>,
) {
    let sx = clip.width() as f64 / region.sensor_cols.max(1) as f64;
    let sy = clip.height() as f64 / region.sensor_rows.max(1) as f64;
    let map = move |x: f64, y: f64| Some(((region.col0 + x) * sx, (region.row0 + y) * sy));
    render_mapped(clip, n, t_ns, &map, dst);
}

/// [`crate::Scene::render_mapped_into`] of a clip: black where `map` sends a sub-sample nowhere.
pub(crate) fn render_mapped(
    clip: &Clip,
    n: usize,
    t_ns: i64,
    map: &(dyn Fn(f64, f64) -> Option<(f64, f64)> + Sync),
    dst: ArrayViewMut2<'_, f32>,
) {
    let when = clip.bracket(t_ns);
    render::mapped_means(n, map, dst, &|x, y| clip.sample(when, x, y), &finish);
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::{Array2, Axis, s};

    fn ramp(t: usize, h: usize, w: usize) -> Array3<f32> {
        Array3::from_shape_fn((t, h, w), |(k, r, c)| {
            (k * 100 + r * 10 + c) as f32 / 1000.0
        })
    }

    fn render(clip: &Clip, n: usize, t_ns: i64, rows: usize, cols: usize) -> Array2<f32> {
        let mut out = Array2::zeros((rows, cols));
        render_region(clip, n, t_ns, Region::whole(rows, cols), out.view_mut());
        out
    }

    #[test]
    fn its_own_grid_reads_the_frames_and_blends_linearly_between() {
        let clip = Clip::new(ramp(3, 4, 6), 1_000, "test").unwrap();
        for k in 0..3 {
            let got = render(&clip, 1, k as i64 * 1_000, 4, 6);
            assert_eq!(got, clip.frames().index_axis(Axis(0), k));
        }
        // A quarter of the way from frame 1 to frame 2: +25 / 1000 on every pixel.
        let got = render(&clip, 1, 1_250, 4, 6);
        let want = clip.frames().index_axis(Axis(0), 1).mapv(|v| v + 0.025);
        assert!(got.iter().zip(&want).all(|(a, b)| (a - b).abs() < 1e-6));
        // Before the first and after the last: held.
        assert_eq!(render(&clip, 1, -5, 4, 6), render(&clip, 1, 0, 4, 6));
        assert_eq!(render(&clip, 1, 9_999, 4, 6), render(&clip, 1, 2_000, 4, 6));
    }

    #[test]
    fn half_the_grid_with_two_samples_reads_block_means() {
        let clip = Clip::new(ramp(1, 4, 6), 10, "test").unwrap();
        let got = render(&clip, 2, 0, 2, 3);
        let f = clip.frames().index_axis(Axis(0), 0);
        for r in 0..2 {
            for c in 0..3 {
                let block = f.slice(s![2 * r..2 * r + 2, 2 * c..2 * c + 2]);
                assert!((got[[r, c]] - block.mean().unwrap()).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn edges_hold_and_nothing_seen_is_black() {
        let clip = Clip::new(ramp(2, 5, 7), 100, "test").unwrap();
        // A region one pixel beyond the top-left corner reads the corner texel.
        let mut out = Array2::zeros((2, 2));
        render_region(
            &clip,
            1,
            0,
            Region::at([5, 7], [-1.0, -1.0]),
            out.view_mut(),
        );
        assert_eq!(out[[0, 0]], clip.frames()[[0, 0, 0]]);
        assert_eq!(out[[1, 1]], clip.frames()[[0, 0, 0]]);
        // A map that sends nothing anywhere sees black.
        let mut dark = Array2::from_elem((3, 3), 1.0f32);
        render_mapped(&clip, 2, 0, &|_, _| None, dark.view_mut());
        assert!(dark.iter().all(|&v| v == 0.0));
    }

    #[test]
    fn bad_clips_are_named() {
        let mut frames = ramp(2, 3, 3);
        frames[[1, 2, 0]] = f32::NAN;
        let e = Clip::new(frames, 10, "clip.npy").unwrap_err().to_string();
        assert!(
            e.contains("clip.npy") && e.contains("frames[1][2][0]"),
            "{e}"
        );
        let e = Clip::new(ramp(2, 3, 3), 0, "c").unwrap_err().to_string();
        assert!(e.contains("dt_ns") && e.contains('0'), "{e}");
        let e = Clip::new(Array3::zeros((0, 3, 3)), 10, "c")
            .unwrap_err()
            .to_string();
        assert!(e.contains("frames"), "{e}");
        let e = Clip::new(Array3::zeros((3, 3, 3)), i64::MAX, "c")
            .unwrap_err()
            .to_string();
        assert!(e.contains("dt_ns"), "{e}");
    }
}
