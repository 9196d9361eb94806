//! Texture canvases: the procedural generators, PNG loading, and periodic bilinear sampling.
//!
//! A texture is a `width x height` grid of values in `[min, 1]` that tiles the plane periodically.
//! Texel `(row i, col j)` sits at texture coordinates `(j + 0.5, i + 0.5)`, so sampling at a texel
//! centre returns the texel exactly. Procedural textures are generated seamless (periodic by
//! construction); PNG images are mirror-tiled (the canvas holds the image and its reflections,
//! `2W x 2H`), so no edge shows a jump.

use std::fmt;
use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use crate::error::SceneError;
use crate::fft::{Complex, dft2};
use crate::spec::{
    DEFAULT_GRATING_PERIOD_PX, DEFAULT_NOISE_BETA, DEFAULT_SHAPE_COUNT, DEFAULT_SQUARE_PX,
    MAX_TEXTURE_SIZE, TextureKind, TextureSpec,
};

/// Noise values map `mean +- NOISE_SIGMAS * std` onto `[0, 1]`.
const NOISE_SIGMAS: f64 = 3.0;
/// Sub-samples per axis used to anti-alias the edges of shapes.
const SHAPE_SUBSAMPLES: usize = 4;
/// Shape radii as fractions of the canvas side.
const SHAPE_RADIUS_FRACTION: (f64, f64) = (0.015, 0.10);
/// Strokes: glyph cell width, glyph height and line pitch in texture pixels.
const GLYPH_CELL_PX: usize = 12;
const GLYPH_HEIGHT_PX: f64 = 14.0;
const LINE_PITCH_PX: usize = 24;
/// Strokes: paper and ink levels before contrast.
const PAPER: f64 = 0.9;
const INK: f64 = 0.08;
/// Strokes: pen radius range in texture pixels.
const PEN_RADIUS_PX: (f64, f64) = (0.8, 1.4);
/// Strokes: chance that a glyph cell is a space between words.
const SPACE_PROBABILITY: f64 = 0.18;
/// Seed offsets so that kinds sharing a seed draw independent streams.
const SEED_SALT: u64 = 0x6e65_7573_7069_6b65; // "neuspike"

/// A periodic grey-level canvas, values in `[min, 1]`.
#[derive(Clone, PartialEq)]
pub struct Texture {
    width: usize,
    height: usize,
    data: Vec<f32>,
}

impl fmt::Debug for Texture {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Texture")
            .field("width", &self.width)
            .field("height", &self.height)
            .finish_non_exhaustive()
    }
}

impl Texture {
    /// A texture of the given texels (`width x height`, row-major; the caller checks the count).
    pub(crate) fn from_texels(width: usize, height: usize, data: Vec<f32>) -> Texture {
        debug_assert_eq!(data.len(), width * height);
        Texture {
            width,
            height,
            data,
        }
    }

    /// Period (canvas width) in texture pixels.
    pub fn width(&self) -> usize {
        self.width
    }
    /// Period (canvas height) in texture pixels.
    pub fn height(&self) -> usize {
        self.height
    }
    /// The texels, row-major.
    pub fn data(&self) -> &[f32] {
        &self.data
    }
    /// Texel at (`row`, `col`), both wrapped.
    pub fn texel(&self, row: i64, col: i64) -> f32 {
        let r = row.rem_euclid(self.height as i64) as usize;
        let c = col.rem_euclid(self.width as i64) as usize;
        self.data[r * self.width + c]
    }

    /// Bilinear sample at texture coordinates (`u` across, `v` down) with periodic wrap; the
    /// scalar oracle the fast renderer is checked against. Non-finite coordinates read as 0.
    pub fn sample(&self, u: f64, v: f64) -> f64 {
        let x = if u.is_finite() { u - 0.5 } else { 0.0 };
        let y = if v.is_finite() { v - 0.5 } else { 0.0 };
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (c0, r0) = (x0 as i64, y0 as i64);
        let t00 = f64::from(self.texel(r0, c0));
        let t01 = f64::from(self.texel(r0, c0 + 1));
        let t10 = f64::from(self.texel(r0 + 1, c0));
        let t11 = f64::from(self.texel(r0 + 1, c0 + 1));
        (1.0 - fy) * ((1.0 - fx) * t00 + fx * t01) + fy * ((1.0 - fx) * t10 + fx * t11)
    }

    /// Builds the texture `spec` describes. `seed` drives every random choice; `base_dir`
    /// resolves a relative PNG path; `origin` names the scene in errors.
    pub fn from_spec(
        spec: &TextureSpec,
        seed: u64,
        base_dir: Option<&Path>,
        origin: &str,
    ) -> Result<Texture, SceneError> {
        let size = spec.size_or_default();
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ SEED_SALT);
        let (width, height, raw) = match spec.kind {
            TextureKind::Noise => (
                size,
                size,
                noise(size, spec.beta.unwrap_or(DEFAULT_NOISE_BETA), &mut rng),
            ),
            TextureKind::Shapes => (
                size,
                size,
                shapes(size, spec.count.unwrap_or(DEFAULT_SHAPE_COUNT), &mut rng),
            ),
            TextureKind::Grating => (
                size,
                size,
                grating(
                    size,
                    spec.period_px.unwrap_or(DEFAULT_GRATING_PERIOD_PX),
                    spec.angle_deg.unwrap_or(0.0),
                ),
            ),
            TextureKind::Strokes => (size, size, strokes(size, &mut rng)),
            TextureKind::Checkerboard => (
                size,
                size,
                checkerboard(size, spec.square_px.unwrap_or(DEFAULT_SQUARE_PX)),
            ),
            TextureKind::Png => {
                let written = spec.path.as_deref().unwrap_or_default();
                load_png_mirrored(written, base_dir, origin)?
            }
        };
        let (contrast, min) = (spec.contrast, spec.min);
        let data = raw
            .into_iter()
            .map(|t| (0.5 + contrast * (t - 0.5)).clamp(min, 1.0) as f32)
            .collect();
        Ok(Texture {
            width,
            height,
            data,
        })
    }
}

/// Signed frequency of DFT bin `k` of `n`.
fn signed_frequency(k: usize, n: usize) -> f64 {
    if k <= n / 2 {
        k as f64
    } else {
        k as f64 - n as f64
    }
}

/// 1/f^beta Gaussian noise by spectral synthesis: periodic on the canvas by construction.
fn noise(size: usize, beta: f64, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let mut grid = vec![Complex::default(); size * size];
    for r in 0..size {
        let fy = signed_frequency(r, size);
        for c in 0..size {
            let fx = signed_frequency(c, size);
            let f = fx.hypot(fy);
            let re: f64 = rng.sample(StandardNormal);
            let im: f64 = rng.sample(StandardNormal);
            let amplitude = if f == 0.0 { 0.0 } else { f.powf(-beta / 2.0) };
            grid[r * size + c] = Complex::new(amplitude * re, amplitude * im);
        }
    }
    dft2(&mut grid, size, size, 1.0);
    let values: Vec<f64> = grid.iter().map(|z| z.re).collect();
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
    let std = var.sqrt();
    if !(std.is_finite() && std > 0.0) {
        return vec![0.5; values.len()];
    }
    values
        .into_iter()
        .map(|v| (0.5 + (v - mean) / (2.0 * NOISE_SIGMAS * std)).clamp(0.0, 1.0))
        .collect()
}

/// Random grey discs and rotated rectangles on a grey background, drawn with wrap-around and
/// anti-aliased edges.
fn shapes(size: usize, count: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let background: f64 = rng.random_range(0.3..0.7);
    let mut canvas = vec![background; size * size];
    let s = size as f64;
    // Keep every shape's box narrower than the canvas so no texel is visited twice.
    let max_radius = ((s - 3.0) / 2.0).max(0.5);
    let radius = |rng: &mut ChaCha8Rng| -> f64 {
        let r = rng.random_range(SHAPE_RADIUS_FRACTION.0..SHAPE_RADIUS_FRACTION.1) * s;
        r.clamp(0.5, max_radius)
    };
    for _ in 0..count {
        let is_disc = rng.random_bool(0.5);
        let cx: f64 = rng.random_range(0.0..s);
        let cy: f64 = rng.random_range(0.0..s);
        let grey: f64 = rng.random();
        let (a, b, angle) = if is_disc {
            let r = radius(rng);
            (r, r, 0.0)
        } else {
            let a = radius(rng);
            let b = radius(rng);
            (a, b, rng.random_range(0.0..std::f64::consts::PI))
        };
        let bound = if is_disc {
            a
        } else {
            a.hypot(b).min(max_radius)
        };
        let (sin, cos) = angle.sin_cos();
        let inside = |dx: f64, dy: f64| -> bool {
            if is_disc {
                dx * dx + dy * dy <= a * a
            } else {
                let along = cos * dx + sin * dy;
                let across = -sin * dx + cos * dy;
                along.abs() <= a && across.abs() <= b
            }
        };
        let r_lo = (cy - bound).floor() as i64 - 1;
        let r_hi = (cy + bound).ceil() as i64 + 1;
        let c_lo = (cx - bound).floor() as i64 - 1;
        let c_hi = (cx + bound).ceil() as i64 + 1;
        let sub = SHAPE_SUBSAMPLES as f64;
        for ty in r_lo..r_hi {
            for tx in c_lo..c_hi {
                let mut hits = 0usize;
                for sy in 0..SHAPE_SUBSAMPLES {
                    for sx in 0..SHAPE_SUBSAMPLES {
                        let px = tx as f64 + (sx as f64 + 0.5) / sub;
                        let py = ty as f64 + (sy as f64 + 0.5) / sub;
                        hits += usize::from(inside(px - cx, py - cy));
                    }
                }
                if hits == 0 {
                    continue;
                }
                let coverage = hits as f64 / (sub * sub);
                let idx = wrap_index(ty, tx, size);
                canvas[idx] = canvas[idx] * (1.0 - coverage) + grey * coverage;
            }
        }
    }
    canvas
}

/// Row-major index of (`row`, `col`) wrapped onto a `size x size` canvas.
fn wrap_index(row: i64, col: i64, size: usize) -> usize {
    let n = size as i64;
    (row.rem_euclid(n) * n + col.rem_euclid(n)) as usize
}

/// Sinusoidal grating. The wave vector is snapped to whole cycles per canvas (so the pattern is
/// seamless); the realised period and angle may differ slightly from the requested ones.
fn grating(size: usize, period_px: f64, angle_deg: f64) -> Vec<f64> {
    let s = size as f64;
    let (sin, cos) = angle_deg.to_radians().sin_cos();
    let kx = (s * cos / period_px).round();
    let ky = (s * sin / period_px).round();
    // period <= size guarantees one of |kx|, |ky| rounds to >= 1; keep a fallback anyway.
    let (kx, ky) = if kx == 0.0 && ky == 0.0 {
        (1.0, 0.0)
    } else {
        (kx, ky)
    };
    let mut out = Vec::with_capacity(size * size);
    for r in 0..size {
        for c in 0..size {
            let phase = std::f64::consts::TAU * (kx * (c as f64 + 0.5) + ky * (r as f64 + 0.5)) / s;
            out.push(0.5 + 0.5 * phase.sin());
        }
    }
    out
}

/// Measure of the odd stripes (width `square`) in `[0, x]`.
fn odd_stripe_measure(x: f64, square: f64) -> f64 {
    let k = (x / square).floor();
    let rem = x - k * square;
    let odd = k.rem_euclid(2.0) == 1.0;
    (k / 2.0).floor() * square + if odd { rem } else { 0.0 }
}

/// Black and white squares, area-averaged per texel. The square count per side is snapped to
/// an even number so the board tiles seamlessly.
fn checkerboard(size: usize, square_px: f64) -> Vec<f64> {
    let s = size as f64;
    let pairs = (s / (2.0 * square_px)).round().max(1.0);
    let square = s / (2.0 * pairs);
    let fraction: Vec<f64> = (0..size)
        .map(|i| {
            let x = i as f64;
            odd_stripe_measure(x + 1.0, square) - odd_stripe_measure(x, square)
        })
        .collect();
    let mut out = Vec::with_capacity(size * size);
    for &b in &fraction {
        for &a in &fraction {
            // Mean of xor(odd column stripe, odd row stripe) over the texel.
            out.push(a * (1.0 - b) + b * (1.0 - a));
        }
    }
    out
}

/// Distance from point `p` to segment `a`-`b`.
fn segment_distance(p: (f64, f64), a: (f64, f64), b: (f64, f64)) -> f64 {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 {
        (((p.0 - a.0) * dx + (p.1 - a.1) * dy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let (qx, qy) = (a.0 + t * dx, a.1 + t * dy);
    (p.0 - qx).hypot(p.1 - qy)
}

/// Text-like random pen strokes: lines of "words" of glyphs, each glyph a few short polylines,
/// dark ink on bright paper, anti-aliased and drawn with wrap-around.
fn strokes(size: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let mut ink = vec![0.0f64; size * size];
    let lines = (size / LINE_PITCH_PX).max(1);
    let cells = (size / GLYPH_CELL_PX).max(1);
    let glyph_h = GLYPH_HEIGHT_PX.min(size as f64 - 2.0).max(1.0);
    let cell_w = GLYPH_CELL_PX as f64;
    for line in 0..lines {
        let top = (line * LINE_PITCH_PX) as f64 + (LINE_PITCH_PX as f64 - glyph_h) / 2.0;
        for cell in 0..cells {
            if rng.random_bool(SPACE_PROBABILITY) {
                continue;
            }
            let left = (cell * GLYPH_CELL_PX) as f64;
            let n_strokes = rng.random_range(1..=3);
            for _ in 0..n_strokes {
                let pen: f64 = rng.random_range(PEN_RADIUS_PX.0..PEN_RADIUS_PX.1);
                let n_points = rng.random_range(2..=4);
                let points: Vec<(f64, f64)> = (0..n_points)
                    .map(|_| {
                        (
                            left + rng.random_range(1.5..(cell_w - 1.5).max(1.6)),
                            top + rng.random_range(0.0..glyph_h),
                        )
                    })
                    .collect();
                for pair in points.windows(2) {
                    draw_segment(&mut ink, size, pair[0], pair[1], pen);
                }
            }
        }
    }
    ink.into_iter().map(|c| PAPER + (INK - PAPER) * c).collect()
}

/// Adds an anti-aliased segment of pen radius `pen` to the ink coverage (max blend, wrapped).
fn draw_segment(ink: &mut [f64], size: usize, a: (f64, f64), b: (f64, f64), pen: f64) {
    let reach = pen + 1.0;
    let c_lo = (a.0.min(b.0) - reach).floor() as i64;
    let c_hi = (a.0.max(b.0) + reach).ceil() as i64;
    let r_lo = (a.1.min(b.1) - reach).floor() as i64;
    let r_hi = (a.1.max(b.1) + reach).ceil() as i64;
    for ty in r_lo..r_hi {
        for tx in c_lo..c_hi {
            let d = segment_distance((tx as f64 + 0.5, ty as f64 + 0.5), a, b);
            let coverage = (pen + 0.5 - d).clamp(0.0, 1.0);
            if coverage > 0.0 {
                let idx = wrap_index(ty, tx, size);
                ink[idx] = ink[idx].max(coverage);
            }
        }
    }
}

/// Rec. 709 luminance weights, applied to the stored (not linearised) channel values.
const REC709: [f32; 3] = [0.2126, 0.7152, 0.0722];

/// Loads a PNG as luminance in [0, 1] and mirror-tiles it to `2W x 2H`.
fn load_png_mirrored(
    written: &str,
    base_dir: Option<&Path>,
    origin: &str,
) -> Result<(usize, usize, Vec<f64>), SceneError> {
    let as_written = PathBuf::from(written);
    let path = match base_dir {
        Some(dir) if as_written.is_relative() => dir.join(&as_written),
        _ => as_written,
    };
    let bytes = std::fs::read(&path).map_err(|source| SceneError::TextureRead {
        origin: origin.to_owned(),
        value: written.to_owned(),
        path: path.clone(),
        source,
    })?;
    let decode_error = |reason: String| SceneError::TextureDecode {
        origin: origin.to_owned(),
        value: written.to_owned(),
        reason,
    };
    let image = image::load_from_memory_with_format(&bytes, image::ImageFormat::Png)
        .map_err(|e| decode_error(e.to_string()))?;
    let (w, h) = (image.width() as usize, image.height() as usize);
    if w == 0 || h == 0 || w > MAX_TEXTURE_SIZE || h > MAX_TEXTURE_SIZE {
        return Err(decode_error(format!(
            "size {w}x{h} is outside 1..={MAX_TEXTURE_SIZE} per side"
        )));
    }
    let rgb = image.to_rgb32f();
    let luminance: Vec<f64> = rgb
        .pixels()
        .map(|p| {
            let y = REC709[0] * p.0[0] + REC709[1] * p.0[1] + REC709[2] * p.0[2];
            f64::from(y).clamp(0.0, 1.0)
        })
        .collect();
    let (mw, mh) = (2 * w, 2 * h);
    let mut out = Vec::with_capacity(mw * mh);
    for r in 0..mh {
        let src_r = if r < h { r } else { mh - 1 - r };
        for c in 0..mw {
            let src_c = if c < w { c } else { mw - 1 - c };
            out.push(luminance[src_r * w + src_c]);
        }
    }
    Ok((mw, mh, out))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn build(kind: TextureKind, seed: u64) -> Texture {
        let mut spec = TextureSpec::new(kind);
        spec.size = Some(64);
        match Texture::from_spec(&spec, seed, None, "test") {
            Ok(t) => t,
            Err(e) => panic!("{e}"),
        }
    }

    /// Mean |difference| across the wrap seam vs between interior neighbours: a seamless
    /// texture has no larger jumps at the seam than elsewhere.
    fn seam_ratio(t: &Texture) -> f64 {
        let (w, h) = (t.width() as i64, t.height() as i64);
        let mut seam = 0.0;
        let mut inner = 0.0;
        for r in 0..h {
            seam += (t.texel(r, w - 1) - t.texel(r, 0)).abs() as f64;
            for c in 0..w - 1 {
                inner += (t.texel(r, c) - t.texel(r, c + 1)).abs() as f64;
            }
        }
        (seam / h as f64) / (inner / (h * (w - 1)) as f64).max(1e-12)
    }

    #[test]
    fn procedural_textures_are_seamless() {
        // (The checkerboard has an edge at the seam by design; its periodicity is tested below.)
        for kind in [
            TextureKind::Noise,
            TextureKind::Grating,
            TextureKind::Shapes,
            TextureKind::Strokes,
        ] {
            let t = build(kind, 3);
            let ratio = seam_ratio(&t);
            assert!(
                ratio < 3.0,
                "{kind}: seam jump {ratio} x the interior jumps"
            );
        }
    }

    #[test]
    fn procedural_textures_have_contrast() {
        for kind in [
            TextureKind::Noise,
            TextureKind::Grating,
            TextureKind::Checkerboard,
            TextureKind::Shapes,
            TextureKind::Strokes,
        ] {
            let t = build(kind, 11);
            let lo = t.data().iter().copied().fold(f32::INFINITY, f32::min);
            let hi = t.data().iter().copied().fold(f32::NEG_INFINITY, f32::max);
            assert!(hi - lo > 0.3, "{kind}: range {lo}..{hi}");
        }
    }

    #[test]
    fn sampling_at_texel_centres_returns_texels() {
        let t = build(TextureKind::Noise, 1);
        for (r, c) in [(0i64, 0i64), (5, 63), (63, 0), (31, 17)] {
            let s = t.sample(c as f64 + 0.5, r as f64 + 0.5);
            assert_eq!(s as f32, t.texel(r, c));
            // One period away is the same texel.
            let s2 = t.sample(c as f64 + 0.5 + 64.0, r as f64 + 0.5 - 128.0);
            assert_eq!(s2 as f32, t.texel(r, c));
        }
    }

    #[test]
    fn checkerboard_is_exact_for_whole_squares() {
        let t = build(TextureKind::Checkerboard, 0);
        // 64 / 32 -> 2 squares per side: top-left dark (0 -> floor), top-right bright.
        assert_eq!(t.texel(0, 0), 0.02);
        assert_eq!(t.texel(0, 40), 1.0);
        assert_eq!(t.texel(40, 40), 0.02);
    }

    #[test]
    fn checkerboard_repeats_every_two_squares_across_the_seam() {
        let mut spec = TextureSpec::new(TextureKind::Checkerboard);
        spec.size = Some(60);
        spec.square_px = Some(10.0);
        let t = Texture::from_spec(&spec, 0, None, "test").expect("checkerboard");
        for r in 0..60 {
            for c in 0..60 {
                assert_eq!(t.texel(r, c), t.texel(r, c + 20), "({r}, {c})");
                assert_eq!(t.texel(r, c), t.texel(r + 20, c), "({r}, {c})");
                assert_ne!(t.texel(r, c), t.texel(r, c + 10), "({r}, {c})");
            }
        }
    }

    #[test]
    fn odd_stripes_are_measured() {
        assert_eq!(odd_stripe_measure(0.0, 2.0), 0.0);
        assert_eq!(odd_stripe_measure(2.0, 2.0), 0.0);
        assert_eq!(odd_stripe_measure(3.0, 2.0), 1.0);
        assert_eq!(odd_stripe_measure(4.0, 2.0), 2.0);
        assert_eq!(odd_stripe_measure(7.0, 2.0), 3.0);
    }
}
