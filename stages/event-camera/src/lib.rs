//! The DVS event-camera model (DAVIS346-like) on the same scenes as the spike camera.
//!
//! Each pixel compares its log intensity `L = ln(max(I, log_floor))` (computed by [`ln_fast`])
//! against a reference level.
//! Whenever `L` rises by the pixel's ON threshold above the reference it emits an ON event and
//! moves the reference up by that threshold; likewise for OFF. Thresholds are
//! `theta * (1 + sigma * n)` with `n ~ N(0, 1)` drawn once per pixel (mismatch), clamped to at least
//! `MIN_THRESHOLD`.
//!
//! **Sampling and why no crossing is lost.** The scene is sampled every `step_ns`, and `L` is taken
//! as linear between two samples. Every crossing of the piecewise-linear `L` is emitted, however
//! many fall in one step (several events per step), each at its interpolated time. What
//! linear interpolation could miss is a change that goes and comes back between two samples; the
//! step is therefore chosen so that no point of the image moves more than `max_shift_px` (default
//! 0.25) pixels between samples, and at most `max_step_ns`. Textures are bilinear, so over a
//! quarter-pixel shift a pixel's intensity is monotone to within the texture's curvature.
//!
//! **Refractory period.** After an event a pixel emits nothing for `refractory_ns`; crossings that
//! fall inside it leave the reference where it was, so they are emitted (late, at the end of the
//! refractory period at the earliest) once the pixel is free, as a real pixel held in reset would.
//!
//! **Noise as v2e models it**, each term off by default and named as v2e names it:
//! - *leak events* (`--leak-rate-hz`, `--leak-jitter`): every pixel's reference level drifts
//!   down by `theta_on * rate_i` a second (`rate_i` drawn once per pixel with the jitter as its
//!   relative standard deviation, and a random starting phase), so a still pixel fires ON at
//!   `rate_i`. A drift of the reference is a ramp added to the pixel's log intensity, so the
//!   model compares `L(t) + theta_on rate_i t` with a fixed reference: exact and linear in time
//!   like `L` between samples.
//! - *shot-noise events* (`--shot-noise-rate-hz`): in each step, pixels fire ON or OFF (equally
//!   likely) at random at the rate times `1 - 0.75 i`, `i = clamp((255 I + 20) / 275, 0, 1)` the
//!   pixel's light on v2e's 8-bit scale (the full rate in the dark, a quarter in full light),
//!   times the nominal threshold over the pixel's. As in v2e (1.5), a pixel that fires a noise
//!   event forgets the change it had seen: its reference becomes its present log intensity.
//!   Drawn as a Poisson count of candidates per group of pixels of like thresholds, each kept
//!   with that probability.
//! - *photoreceptor bandwidth* (`--cutoff-hz`): the log intensity goes through a first-order
//!   low-pass, `lp += eps (L - lp)` each step with `eps = min(1, i dt 2 pi cutoff)`: slower in
//!   the dark.
//! - *threshold mismatch* (`--theta-sigma`, v2e's `sigma_thres`) and the *refractory period*
//!   (`--refractory-ns`, v2e's `refractory_period` in seconds) as above.
//!
//! With the leak or the low-pass on, every pixel's log is taken each step (the intensity
//! pre-check does not apply); shot noise adds only its events' work.
//!
//! Deterministic for a seed.
#![deny(missing_docs)]

use ndarray::Array2;
use neuspike_geometry::Homography;
use neuspike_scene::Scene;
use neuspike_scene::shift::Interpolator;
use neuspike_schemas::{Event, EventBatch};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Smallest contrast threshold a mismatch draw may produce.
pub const MIN_THRESHOLD: f64 = 0.01;

/// DVS settings. Every field is a node argument in the graph YAML.
#[derive(Clone, Debug, clap::Args)]
pub struct DvsConfig {
    /// Sensor width in pixels.
    #[arg(long, default_value_t = 346)]
    pub width: usize,
    /// Sensor height in pixels.
    #[arg(long, default_value_t = 260)]
    pub height: usize,
    /// ON contrast threshold (log intensity).
    #[arg(long, default_value_t = 0.2)]
    pub theta_on: f64,
    /// OFF contrast threshold (log intensity).
    #[arg(long, default_value_t = 0.2)]
    pub theta_off: f64,
    /// Per-pixel threshold mismatch, relative standard deviation.
    #[arg(long, default_value_t = 0.03)]
    pub theta_sigma: f64,
    /// Refractory period, nanoseconds.
    #[arg(long, default_value_t = 0)]
    pub refractory_ns: i64,
    /// Intensity floor before the log: `L = ln(max(I * light_scale, log_floor))`, at least 1e-30.
    #[arg(long, default_value_t = 1e-4)]
    pub log_floor: f64,
    /// Largest image motion between two samples, pixels.
    #[arg(long, default_value_t = 0.25)]
    pub max_shift_px: f64,
    /// Longest sampling step, nanoseconds (the scene is also sampled at least this often when it
    /// does not move).
    #[arg(long, default_value_t = 1_000_000)]
    pub max_step_ns: i64,
    /// Seed of the mismatch draws.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Leak events: each pixel's reference level drifts down by this many ON thresholds a
    /// second, so a still pixel fires ON at this rate (v2e's `leak_rate_hz`; 0 = off).
    #[arg(long, default_value_t = 0.0)]
    pub leak_rate_hz: f64,
    /// Relative standard deviation of the per-pixel leak rate (v2e's `leak_jitter_fraction`).
    #[arg(long, default_value_t = 0.1)]
    pub leak_jitter: f64,
    /// Where each pixel starts its leak cycle: `random` (a camera that has been running: each
    /// reference up to one ON threshold below its level) or `level` (every reference at its
    /// first level, as v2e starts: no leak event before `1 / rate` seconds).
    #[arg(long, value_enum, default_value_t = LeakStart::Random)]
    pub leak_start: LeakStart,
    /// Shot-noise events: a pixel in the dark fires ON or OFF at random at this rate, a quarter
    /// of it in full light (v2e's `shot_noise_rate_hz`; 0 = off).
    #[arg(long, default_value_t = 0.0)]
    pub shot_noise_rate_hz: f64,
    /// The photoreceptor's bandwidth in full light, Hz: its log intensity follows the light
    /// through a first-order low-pass whose cutoff falls with the light (v2e's `cutoff_hz`;
    /// 0 = off, infinitely fast).
    #[arg(long, default_value_t = 0.0)]
    pub cutoff_hz: f64,
    /// A rig of two sensors: the homography from this camera's pixels to the spike camera's
    /// (nine numbers, row-major), through which this camera sees the scene. Without it the two
    /// see the same view, each at its own size.
    #[arg(long, value_parser = parse_homography, allow_hyphen_values = true)]
    pub homography: Option<Homography>,
    /// The spike camera's width, the grid `--homography` maps onto.
    #[arg(long, default_value_t = 400)]
    pub rig_width: usize,
    /// The spike camera's height, the grid `--homography` maps onto.
    #[arg(long, default_value_t = 250)]
    pub rig_height: usize,
    /// This camera's clock reads this many nanoseconds later than the spike camera's: every
    /// timestamp it sends is shifted by it.
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    pub clock_offset_ns: i64,
    /// Motion-compensated interpolation: render the scene only every this many nanoseconds and
    /// make the samples between by moving the two nearest renders along the scene's motion
    /// (`neuspike_scene::shift::Interpolator`); 0 renders every sample. Not with
    /// `--homography`.
    #[arg(long, default_value_t = 0)]
    pub warp_step_ns: i64,
}

/// Where each pixel starts its leak cycle (`--leak-start`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LeakStart {
    /// Each reference up to one ON threshold below its level, uniformly: a camera that has been
    /// running, whose still pixels do not fire together.
    Random,
    /// Every reference at its first level, as v2e starts.
    Level,
}

/// `--homography`'s parser: the error names the value.
fn parse_homography(text: &str) -> Result<Homography, String> {
    Homography::parse(text).map_err(|e| e.to_string())
}

impl Default for DvsConfig {
    fn default() -> Self {
        DvsConfig {
            width: 346,
            height: 260,
            theta_on: 0.2,
            theta_off: 0.2,
            theta_sigma: 0.03,
            refractory_ns: 0,
            log_floor: 1e-4,
            max_shift_px: 0.25,
            max_step_ns: 1_000_000,
            seed: 0,
            leak_rate_hz: 0.0,
            leak_jitter: 0.1,
            leak_start: LeakStart::Random,
            shot_noise_rate_hz: 0.0,
            cutoff_hz: 0.0,
            homography: None,
            rig_width: 400,
            rig_height: 250,
            clock_offset_ns: 0,
            warp_step_ns: 0,
        }
    }
}

/// A setting out of its range. The message names the setting and the value.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("event camera: `{key}` = {value} is invalid: {why}")]
pub struct ConfigError {
    /// The setting.
    pub key: &'static str,
    /// Its value.
    pub value: String,
    /// What is wrong.
    pub why: &'static str,
}

impl DvsConfig {
    /// The first setting given that applies to a simulated scene and not to frames the user
    /// holds (the rig's homography, the clock offset, motion-compensated warping), by its
    /// argument's name.
    pub fn scene_only_setting(&self) -> Option<&'static str> {
        [
            ("homography", self.homography.is_some()),
            ("clock-offset-ns", self.clock_offset_ns != 0),
            ("warp-step-ns", self.warp_step_ns != 0),
        ]
        .into_iter()
        .find_map(|(name, set)| set.then_some(name))
    }

    /// Checks every setting.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let bad = |key, value: String, why| Err(ConfigError { key, value, why });
        if self.width == 0 || self.width > usize::from(u16::MAX) {
            return bad("width", self.width.to_string(), "must be in 1..=65535");
        }
        if self.height == 0 || self.height > usize::from(u16::MAX) {
            return bad("height", self.height.to_string(), "must be in 1..=65535");
        }
        if self.width * self.height > neuspike_schemas::limits::max_sensor_pixels() {
            return bad(
                "width",
                format!("{}x{}", self.width, self.height),
                "the sensor has more pixels than NEUSPIKE_MAX_SENSOR_PIXELS allows (16777216, 4096x4096, unless set)",
            );
        }
        for (key, v) in [("theta-on", self.theta_on), ("theta-off", self.theta_off)] {
            if !(v.is_finite() && v >= MIN_THRESHOLD) {
                return bad(key, format!("{:?}", v), "must be finite and >= 0.01");
            }
        }
        if !(self.theta_sigma.is_finite() && self.theta_sigma >= 0.0) {
            return bad(
                "theta-sigma",
                format!("{:?}", self.theta_sigma),
                "must be finite and >= 0",
            );
        }
        if self.refractory_ns < 0 {
            return bad(
                "refractory-ns",
                self.refractory_ns.to_string(),
                "must be >= 0",
            );
        }
        if !(self.log_floor.is_finite() && self.log_floor >= 1e-30) {
            return bad(
                "log-floor",
                format!("{:?}", self.log_floor),
                "must be finite and >= 1e-30 (a normal single-precision number)",
            );
        }
        if !(self.max_shift_px.is_finite() && self.max_shift_px > 0.0) {
            return bad(
                "max-shift-px",
                format!("{:?}", self.max_shift_px),
                "must be finite and > 0",
            );
        }
        if self.max_step_ns <= 0 {
            return bad("max-step-ns", self.max_step_ns.to_string(), "must be > 0");
        }
        if self.warp_step_ns < 0 {
            return bad(
                "warp-step-ns",
                self.warp_step_ns.to_string(),
                "must be >= 0",
            );
        }
        if self.warp_step_ns > 0 && self.homography.is_some() {
            return bad(
                "warp-step-ns",
                self.warp_step_ns.to_string(),
                "moves renders of the plain view; a camera seeing it through --homography renders every sample",
            );
        }
        if self.rig_width == 0 || self.rig_height == 0 {
            return bad(
                "rig-width",
                format!("{}x{}", self.rig_width, self.rig_height),
                "the spike camera's grid must not be empty",
            );
        }
        for (key, v, max) in [
            ("leak-rate-hz", self.leak_rate_hz, 1e4),
            ("leak-jitter", self.leak_jitter, 1.0),
            ("shot-noise-rate-hz", self.shot_noise_rate_hz, 1e4),
            ("cutoff-hz", self.cutoff_hz, 1e7),
        ] {
            if !(v.is_finite() && (0.0..=max).contains(&v)) {
                return Err(ConfigError {
                    key,
                    value: format!("{v:?}"),
                    why: match key {
                        "leak-jitter" => "must be in [0, 1]",
                        "cutoff-hz" => "must be in [0, 1e7]",
                        _ => "must be in [0, 1e4]",
                    },
                });
            }
        }
        Ok(())
    }
}

pub use neuspike_simd::fastmath::ln_fast;
use neuspike_simd::fastmath::{max_or, min_or};

/// Log intensity of a frame: `dst[i] = ln_fast(max(frame[i] * light_scale, floor))`, on the
/// widest vector unit the CPU has.
pub fn log_intensity_into(frame: &[f32], light_scale: f32, floor: f32, dst: &mut [f32]) {
    neuspike_simd::dispatch(
        #[inline(always)]
        || {
            for (l, &i) in dst.iter_mut().zip(frame) {
                *l = ln_fast((i * light_scale).max(floor));
            }
        },
    );
}

/// The pixel array of a DVS: per-pixel thresholds, reference levels and refractory clocks. It
/// turns a sequence of intensity frames into events, like v2e does with video frames; the scene
/// sampling lives in [`EventCamera`].
///
/// A pixel's log intensity is `ln_fast(max(I * light_scale, floor))`. The fast path
/// ([`DvsPixels::step`]) does not take the log of every pixel: it compares the intensities
/// themselves against per-pixel linear levels `exp(level -/+ margin)` and takes logs only in the
/// few blocks of pixels that may cross; the margin covers `ln_fast`'s error bound, so the
/// pre-check never misses a crossing (tested, and argued at [`linear_levels`]).
#[derive(Clone)]
pub struct DvsPixels {
    width: usize,
    refractory_ns: i64,
    light_scale: f32,
    floor: f32,
    /// Per-pixel state, together, so an event touches one cache line.
    state: Vec<PixelState>,
    /// Whether the steps compare intensities (no leak, no low-pass) rather than logs.
    linear: bool,
    /// Linear pre-check levels: a pixel whose scaled intensity `x` has `lower < x < upper` has
    /// no crossing (empty unless `linear`).
    upper: Vec<f32>,
    lower: Vec<f32>,
    /// Log pre-check levels of the step on logs: `reference + theta_on` rounded down and
    /// `reference - theta_off` rounded up, a superset of the pixels that cross (empty when
    /// `linear`).
    upper_log: Vec<f32>,
    lower_log: Vec<f32>,
    /// Scratch of [`DvsPixels::step`]: one bit per pixel that may cross, and those pixels.
    block_masks: Vec<Mask>,
    candidates: Candidates,
    /// The noise terms' state.
    noise: NoiseState,
}

/// The state of v2e's noise terms in a pixel array.
#[derive(Clone)]
struct NoiseState {
    /// Per-pixel leak ramp, log units a second (`theta_on * rate_i`); empty when off.
    leak: Vec<f32>,
    /// Time the leak ramps start from (set at the first step; moved forward when they grow).
    ramp_origin_ns: Option<i64>,
    /// The photoreceptor's cutoff in full light, Hz (0 = off).
    cutoff_hz: f32,
    /// Shot-noise rate in the dark, Hz per pixel (0 = off).
    shot_rate_hz: f64,
    /// The largest of `leak` (0 when off).
    max_leak: f32,
    /// With the leak or the low-pass: every pixel's (filtered) log intensity at the end of the
    /// last step.
    lp: Vec<f32>,
    /// The draws of the shot noise.
    rng: ChaCha8Rng,
    /// The nominal ON and OFF thresholds.
    theta_nominal: (f32, f32),
    /// The pixels grouped by polarity and by their ratio of nominal to own threshold (within a
    /// factor `SHOT_BUCKET_SPREAD`), so that each group draws candidates at its own largest
    /// ratio and few are rejected.
    shot_buckets: Vec<ShotBucket>,
    /// Scratch of a step's shot-noise candidates: pixel, bucket, keep draw, time.
    shot_candidates: Vec<ShotCandidate>,
}

/// The pixels of one polarity whose ratio of nominal to own threshold lies within a factor
/// [`SHOT_BUCKET_SPREAD`]: shot noise draws their candidates at `max_ratio` and keeps each with
/// its own ratio over it.
#[derive(Clone, Debug, Default)]
struct ShotBucket {
    polarity: i8,
    max_ratio: f32,
    /// Each pixel and its ratio over `max_ratio`, the chance a candidate of it is kept in the
    /// dark (together, so that a candidate reads one place).
    pixels: Vec<(u32, f32)>,
}

/// One candidate of a step's shot noise.
#[derive(Clone, Copy, Debug)]
struct ShotCandidate {
    /// First the candidate's place in its bucket's list, then its pixel.
    pixel: u32,
    bucket: u32,
    /// Its chance of being kept in the dark, and the uniform draw that decides.
    keep: f32,
    u: f32,
    t_ns: i64,
}

/// The largest ratio between two pixels' shot-noise rates in one bucket, so that at most a fifth
/// of a bucket's candidates are rejected for their threshold (one bucket for the whole array, at
/// a threshold spread of 25%, rejected 19 of 20).
const SHOT_BUCKET_SPREAD: f32 = 1.25;

/// The shot-noise buckets of the pixels `state` (see [`ShotBucket`]).
fn shot_buckets(state: &[PixelState], (on, off): (f32, f32)) -> Vec<ShotBucket> {
    let mut out: Vec<ShotBucket> = Vec::new();
    for polarity in [1i8, -1] {
        let ratio = |p: &PixelState| {
            if polarity > 0 {
                on / p.theta_on
            } else {
                off / p.theta_off
            }
        };
        let mut by_key: std::collections::BTreeMap<i32, ShotBucket> = Default::default();
        for (i, p) in state.iter().enumerate() {
            let r = ratio(p);
            // Thresholds are at least MIN_THRESHOLD, so the ratio is finite and > 0.
            let key = (r.ln() / SHOT_BUCKET_SPREAD.ln()).floor() as i32;
            let b = by_key.entry(key).or_default();
            b.polarity = polarity;
            b.max_ratio = b.max_ratio.max(r);
            b.pixels.push((i as u32, r));
        }
        for b in by_key.values_mut() {
            let max = b.max_ratio;
            b.pixels.iter_mut().for_each(|(_, r)| *r /= max);
        }
        out.extend(by_key.into_values());
    }
    out
}

/// A leak ramp larger than this (log units) is folded into the reference levels.
const MAX_RAMP: f32 = 8.0;

/// v2e's light on its 8-bit scale, `clamp((255 x + 20) / 275, 0, 1)` of the scaled intensity.
#[inline(always)]
fn inten01(x: f32) -> f32 {
    // The quotients as constants: a multiply and an add, no division in the pixel loop; a NaN
    // gives 0.
    min_or(max_or(x * (255.0 / 275.0) + 20.0 / 275.0, 0.0), 1.0)
}

/// One step of the photoreceptor's low-pass: `lp + eps (l - lp)`, `eps = min(1, i dt 2 pi fc)`.
#[inline(always)]
fn low_pass(lp: f32, l: f32, x: f32, dt_2pi_fc: f32) -> f32 {
    let eps = min_or(inten01(x) * dt_2pi_fc, 1.0);
    lp + eps * (l - lp)
}

/// What the step on logs computes each pixel's new level from, and the levels it compares.
struct LogStep<'a> {
    frame_b: &'a [f32],
    /// Log pre-check levels.
    upper: &'a [f32],
    lower: &'a [f32],
    /// Per-pixel leak ramps, log units a second (empty: none).
    leak: &'a [f32],
    scale: f32,
    floor: f32,
    filter: bool,
    dt_2pi_fc: f32,
    /// The leak ramps' times at the step's start and end, seconds.
    tau_a: f32,
    tau_b: f32,
}

/// A pixel's log intensity at the step's end, from its intensity `v`, low-passed from its last
/// level `lp` when the filter is on.
#[inline(always)]
fn log_level(a: &LogStep, filter: bool, v: f32, lp: f32) -> f32 {
    let x = max_or(v * a.scale, a.floor);
    let l = ln_fast(x);
    if filter {
        low_pass(lp, l, x, a.dt_2pi_fc)
    } else {
        l
    }
}

/// The step on logs in one pass over the array, [`CANDIDATE_BLOCK`] pixels at a time: each
/// pixel's new level (vectorised) replaces its last in `lp`, its level plus its leak ramp is
/// compared with the pre-check levels (vectorised, one bit a pixel), and the few pixels past one
/// join `c` with their levels at both ends of the step. One pass, so that each of the arrays
/// (together larger than a core's L2 cache at 346x260) is read once a step.
#[inline(always)]
fn scan_logs(a: &LogStep, lp: &mut [f32], c: &mut Candidates) {
    const B: usize = CANDIDATE_BLOCK;
    // Whole blocks have a fixed length, so the compiler turns each into vector code; the last,
    // shorter block takes the plain loop.
    let (fb, fb_tail) = a.frame_b.as_chunks::<B>();
    let (lpc, lp_tail) = lp.as_chunks_mut::<B>();
    let (up, up_tail) = a.upper.as_chunks::<B>();
    let (lo, lo_tail) = a.lower.as_chunks::<B>();
    let tail = fb.len() * B;
    let mut new = [0.0f32; B];
    if a.leak.is_empty() {
        let blocks = fb.iter().zip(lpc.iter_mut()).zip(up).zip(lo);
        for (b, (((fb, lp), up), lo)) in blocks.enumerate() {
            log_block(a, b * B, fb, lp, up, lo, None, &mut new, c);
        }
        log_block(
            a, tail, fb_tail, lp_tail, up_tail, lo_tail, None, &mut new, c,
        );
    } else {
        let (lk, lk_tail) = a.leak.as_chunks::<B>();
        let blocks = fb.iter().zip(lpc.iter_mut()).zip(up).zip(lo).zip(lk);
        for (b, ((((fb, lp), up), lo), lk)) in blocks.enumerate() {
            log_block(a, b * B, fb, lp, up, lo, Some(lk), &mut new, c);
        }
        let lk_tail = Some(lk_tail);
        log_block(
            a, tail, fb_tail, lp_tail, up_tail, lo_tail, lk_tail, &mut new, c,
        );
    }
}

/// One block of [`scan_logs`], its first pixel `start`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn log_block(
    a: &LogStep,
    start: usize,
    fb: &[f32],
    lp: &mut [f32],
    up: &[f32],
    lo: &[f32],
    leak: Option<&[f32]>,
    new: &mut [f32; CANDIDATE_BLOCK],
    c: &mut Candidates,
) {
    let new = &mut new[..fb.len()];
    // The filter's branch outside the loop, so that each loop vectorises.
    // In parts of 16, which keep the AVX2 build's registers from spilling (1.3x).
    let parts = new.chunks_mut(16).zip(fb.chunks(16)).zip(lp.chunks(16));
    if a.filter {
        for ((new, fb), lp) in parts {
            for ((o, &v), &l) in new.iter_mut().zip(fb).zip(lp) {
                *o = log_level(a, true, v, l);
            }
        }
    } else {
        for ((new, fb), lp) in parts {
            for ((o, &v), &l) in new.iter_mut().zip(fb).zip(lp) {
                *o = log_level(a, false, v, l);
            }
        }
    }
    let mut m = level_mask(new, up, lo, leak, a.tau_b);
    while m != 0 {
        let j = m.trailing_zeros() as usize;
        m &= m - 1;
        let ramp = |tau: f32| leak.map_or(0.0, |k| k[j] * tau);
        c.index.push(start + j);
        c.la.push(lp[j] + ramp(a.tau_a));
        c.lb.push(new[j] + ramp(a.tau_b));
    }
    lp.copy_from_slice(new);
}

/// The mask of the pixels of one block whose level (plus its leak ramp `leak * tau`) is at or
/// past a pre-check level.
#[inline(always)]
fn level_mask(next: &[f32], upper: &[f32], lower: &[f32], leak: Option<&[f32]>, tau: f32) -> Mask {
    let mut m: Mask = 0;
    match leak {
        None => {
            for (j, ((&l, &u), &d)) in next.iter().zip(upper).zip(lower).enumerate() {
                m |= Mask::from((l >= u) | (l <= d)) << j;
            }
        }
        Some(leak) => {
            for (j, (((&l, &u), &d), &k)) in next.iter().zip(upper).zip(lower).zip(leak).enumerate()
            {
                let l = l + k * tau;
                m |= Mask::from((l >= u) | (l <= d)) << j;
            }
        }
    }
    m
}

/// One pixel's thresholds, reference level and refractory clock.
#[derive(Clone, Copy, Debug, PartialEq)]
struct PixelState {
    reference: f32,
    theta_on: f32,
    theta_off: f32,
    /// `exp(theta_on)` rounded down, `exp(-theta_off)` rounded up (see [`linear_levels`]).
    gain_on: f32,
    gain_off: f32,
    last_event_ns: i64,
}

/// The pixels that may cross in a step: their indices and their two log intensities.
#[derive(Clone, Default)]
struct Candidates {
    index: Vec<usize>,
    la: Vec<f32>,
    lb: Vec<f32>,
    state: Vec<PixelState>,
}

impl Candidates {
    fn clear(&mut self) {
        self.index.clear();
        self.la.clear();
        self.lb.clear();
        self.state.clear();
    }
}

/// Pixels per mask of the vectorised pre-check in [`DvsPixels::step`] (bits of a [`Mask`]).
const CANDIDATE_BLOCK: usize = 64;

/// One bit per pixel of a block.
type Mask = u64;

/// The pre-check of up to [`CANDIDATE_BLOCK`] pixels: bit `j` is set when pixel `j`'s scaled
/// intensity `x = max(v * scale, floor)` may cross (`x >= upper` or `x <= lower`, see
/// [`linear_levels`]).
#[inline(always)]
fn may_cross_mask(fb: &[f32], up: &[f32], lo: &[f32], scale: f32, floor: f32) -> Mask {
    let mut m: Mask = 0;
    for (j, ((&v, &up), &lo)) in fb.iter().zip(up).zip(lo).enumerate() {
        let x = (v * scale).max(floor);
        m |= Mask::from((x >= up) | (x <= lo)) << j;
    }
    m
}

/// Relative error bound of [`ln_fast`] used by the pre-check: `|ln_fast(x) - ln x| <=
/// LN_FAST_ERROR * max(1, |ln x|)` (the test checks 2e-6; twice that is the margin's unit).
const LN_FAST_ERROR: f64 = 4e-6;

/// The largest `f32` at or below `y`.
fn f32_at_or_below(y: f64) -> f32 {
    let f = y as f32;
    if f64::from(f) > y { f.next_down() } else { f }
}

/// The smallest `f32` at or above `y`.
fn f32_at_or_above(y: f64) -> f32 {
    let f = y as f32;
    if f64::from(f) < y { f.next_up() } else { f }
}

/// Linear pre-check levels `(upper, lower)` of a pixel with reference `r` and thresholds `on`,
/// `off` (so log levels `up = r + on`, `lo = r - off`), given `gain_on <= exp(on)` and
/// `gain_off >= exp(-off)`: every `x >= f32::MIN_POSITIVE` (the log floor, at least 1e-30,
/// guarantees it) with `ln_fast(x) >= up` has `x >= upper`, and every such `x` with
/// `ln_fast(x) <= lo` has `x <= lower`. One exponential per call: an event flood moves
/// millions of levels a second.
///
/// Why: with `e = LN_FAST_ERROR` and margin `m = 2 e max(1, |up|)`, take `x < exp(up - m)`, so
/// `L = ln x < up - m`. If `|L| <= 2|up| + 1`, `ln_fast(x) <= L + (e/2)(2 max(1,|up|) + 1) <
/// L + m < up`. Otherwise `L < -(2|up| + 1)` and `ln_fast(x) <= L (1 - e/2) < -|up| <= up`. The
/// OFF side is the mirror image. `exp(up - m) >= exp(r) gain_on (1 - m)`; the products' and
/// `exp`'s roundings (below 1e-15 relative) are covered by a further 1e-12, and the f32
/// rounding is outwards. Levels beyond the f32 range become `f32::MAX`/infinity or 0, which
/// keeps the implication. OFF: `exp(m) <= 1 + m + m^2` for `m <= 1`.
fn linear_levels(r: f64, on: f64, off: f64, gain_on: f64, gain_off: f64) -> (f32, f32) {
    let m_up = 2.0 * LN_FAST_ERROR * (r + on).abs().max(1.0);
    let m_lo = (2.0 * LN_FAST_ERROR * (r - off).abs().max(1.0)).min(1.0);
    let e = r.exp();
    (
        f32_at_or_below(e * gain_on * (1.0 - m_up - 1e-12)),
        f32_at_or_above(e * gain_off * (1.0 + m_lo + m_lo * m_lo + 1e-12)),
    )
}

/// `(gain_on, gain_off)` of [`linear_levels`] for thresholds `on`, `off`.
fn threshold_gains(on: f32, off: f32) -> (f32, f32) {
    (
        f32_at_or_below(f64::from(on).exp()),
        f32_at_or_above((-f64::from(off)).exp()),
    )
}

impl DvsPixels {
    /// A pixel array whose reference levels and last frame are `frame_start` (intensities,
    /// row-major, `width` columns) seen at `light_scale`, with mismatch drawn from `cfg.seed`.
    pub fn new(
        cfg: &DvsConfig,
        light_scale: f32,
        frame_start: &[f32],
    ) -> Result<Self, ConfigError> {
        cfg.validate()?;
        let n = cfg.width * cfg.height;
        if frame_start.len() != n {
            return Err(ConfigError {
                key: "width",
                value: format!("{}x{}", cfg.width, cfg.height),
                why: "does not match the size of the first frame",
            });
        }
        let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
        let normal = Normal::new(0.0, cfg.theta_sigma).map_err(|_| ConfigError {
            key: "theta-sigma",
            value: cfg.theta_sigma.to_string(),
            why: "not a valid standard deviation",
        })?;
        let mut draw = |theta: f64| -> Vec<f32> {
            (0..n)
                .map(|_| (theta * (1.0 + normal.sample(&mut rng))).max(MIN_THRESHOLD) as f32)
                .collect()
        };
        let theta_on = draw(cfg.theta_on);
        let theta_off = draw(cfg.theta_off);
        // The noise terms' draws come after the mismatch's, each only when its term is on, so
        // a seed gives the same thresholds with or without them.
        let (leak, phase) = if cfg.leak_rate_hz > 0.0 {
            let jitter = Normal::new(0.0, cfg.leak_jitter).map_err(|_| ConfigError {
                key: "leak-jitter",
                value: cfg.leak_jitter.to_string(),
                why: "not a valid standard deviation",
            })?;
            let leak: Vec<f32> = theta_on
                .iter()
                .map(|&on| {
                    let rate = (cfg.leak_rate_hz * (1.0 + jitter.sample(&mut rng))).max(0.0);
                    (f64::from(on) * rate) as f32
                })
                .collect();
            // Drawn either way, so that the draws after them do not depend on the start.
            let mut phase: Vec<f32> = (0..n).map(|_| rand::Rng::random::<f32>(&mut rng)).collect();
            if cfg.leak_start == LeakStart::Level {
                phase.fill(0.0);
            }
            (leak, phase)
        } else {
            (Vec::new(), Vec::new())
        };
        let max_leak = leak.iter().copied().fold(0.0f32, f32::max);
        let linear = leak.is_empty() && cfg.cutoff_hz <= 0.0;
        // The shot noise's own stream of the seed.
        let mut noise_rng = ChaCha8Rng::seed_from_u64(cfg.seed);
        noise_rng.set_stream(1);
        let mut px = DvsPixels {
            width: cfg.width,
            refractory_ns: cfg.refractory_ns,
            light_scale,
            floor: cfg.log_floor as f32,
            state: theta_on
                .iter()
                .zip(&theta_off)
                .map(|(&theta_on, &theta_off)| {
                    let (gain_on, gain_off) = threshold_gains(theta_on, theta_off);
                    PixelState {
                        reference: 0.0,
                        theta_on,
                        theta_off,
                        gain_on,
                        gain_off,
                        last_event_ns: i64::MIN,
                    }
                })
                .collect(),
            linear,
            upper: vec![0.0; if linear { n } else { 0 }],
            lower: vec![0.0; if linear { n } else { 0 }],
            upper_log: vec![0.0; if linear { 0 } else { n }],
            lower_log: vec![0.0; if linear { 0 } else { n }],
            block_masks: Vec::new(),
            candidates: Candidates::default(),
            noise: NoiseState {
                leak,
                ramp_origin_ns: None,
                cutoff_hz: cfg.cutoff_hz as f32,
                shot_rate_hz: cfg.shot_noise_rate_hz,
                max_leak,
                lp: Vec::new(),
                rng: noise_rng,
                theta_nominal: (cfg.theta_on as f32, cfg.theta_off as f32),
                shot_buckets: Vec::new(),
                shot_candidates: Vec::new(),
            },
        };
        for (i, &v) in frame_start.iter().enumerate() {
            let l = px.log_of(v);
            // With the leak, each pixel starts at a random phase of its cycle (its reference
            // up to one ON threshold below its level), or at its level (`LeakStart::Level`).
            let below = phase.get(i).map_or(0.0, |p| p * px.state[i].theta_on);
            px.set_reference(i, f64::from(l - below));
        }
        if !px.linear {
            px.noise.lp = frame_start.iter().map(|&v| px.log_of(v)).collect();
        }
        if cfg.shot_noise_rate_hz > 0.0 {
            px.noise.shot_buckets = shot_buckets(&px.state, px.noise.theta_nominal);
        }
        Ok(px)
    }

    /// The log intensity the pixels see for intensity `v`.
    #[inline(always)]
    fn log_of(&self, v: f32) -> f32 {
        ln_fast(self.scaled(v))
    }

    /// `max(v * light_scale, floor)`: what the log is taken of.
    #[inline(always)]
    fn scaled(&self, v: f32) -> f32 {
        (v * self.light_scale).max(self.floor)
    }

    /// Appends to `out` every crossing of the linear log-intensity path from `frame_a` (the
    /// frame of the previous step, at `t_a_ns`) to `frame_b` (at `t_b_ns`), pixel by pixel, each
    /// inside `[t_a_ns, t_b_ns)`. Fast: a vectorised pass over the intensities finds the blocks
    /// of pixels that may cross and only those take logs and the scalar path; equal to
    /// [`DvsPixels::step_reference`] event for event (tested).
    pub fn step(
        &mut self,
        frame_a: &[f32],
        frame_b: &[f32],
        t_a_ns: i64,
        t_b_ns: i64,
        out: &mut Vec<Event>,
    ) {
        self.step_with(
            neuspike_simd::detect(),
            frame_a,
            frame_b,
            t_a_ns,
            t_b_ns,
            out,
        );
    }

    /// [`DvsPixels::step`] compiled for a chosen instruction set (tests and benchmarks).
    pub fn step_with(
        &mut self,
        isa: neuspike_simd::Isa,
        frame_a: &[f32],
        frame_b: &[f32],
        t_a_ns: i64,
        t_b_ns: i64,
        out: &mut Vec<Event>,
    ) {
        let n = self.state.len();
        assert!(frame_a.len() == n && frame_b.len() == n, "frame size");
        if !self.linear {
            self.step_logs(Some(isa), frame_b, t_a_ns, t_b_ns, out);
            self.shot_noise(frame_b, t_a_ns, t_b_ns, out);
            return;
        }
        // Pass 1, vectorised: one bit per pixel, set when the pixel may cross (`x >= upper`
        // or `x <= lower`, see `linear_levels`), 64 pixels to a mask.
        let mut masks = std::mem::take(&mut self.block_masks);
        masks.clear();
        masks.resize(n.div_ceil(CANDIDATE_BLOCK), 0);
        let (scale, floor) = (self.light_scale, self.floor);
        neuspike_simd::with_isa(
            isa,
            #[inline(always)]
            || {
                let (fb, fb_tail) = frame_b.as_chunks::<CANDIDATE_BLOCK>();
                let (up, up_tail) = self.upper.as_chunks::<CANDIDATE_BLOCK>();
                let (lo, lo_tail) = self.lower.as_chunks::<CANDIDATE_BLOCK>();
                // Whole blocks have a fixed length, so the compiler unrolls them into full
                // vectors with no remainder loop (1.2x the variable-length loop).
                for (mask, ((fb, up), lo)) in masks.iter_mut().zip(fb.iter().zip(up).zip(lo)) {
                    *mask = may_cross_mask(fb, up, lo, scale, floor);
                }
                if let Some(mask) = masks.get_mut(fb.len()) {
                    *mask = may_cross_mask(fb_tail, up_tail, lo_tail, scale, floor);
                }
            },
        );
        // Pass 2: the candidates and their scaled intensities, gathered (independent loads, so
        // their cache misses overlap); their logs, vectorised; then their crossings, one by one.
        let mut c = std::mem::take(&mut self.candidates);
        c.clear();
        for (b, &m) in masks.iter().enumerate() {
            let mut m = m;
            while m != 0 {
                let i = b * CANDIDATE_BLOCK + m.trailing_zeros() as usize;
                m &= m - 1;
                c.index.push(i);
                c.lb.push(self.scaled(frame_b[i]));
            }
        }
        c.la.extend(c.index.iter().map(|&i| self.scaled(frame_a[i])));
        c.state.extend(c.index.iter().map(|&i| self.state[i]));
        neuspike_simd::with_isa(
            isa,
            #[inline(always)]
            || {
                for v in c.la.iter_mut() {
                    *v = ln_fast(*v);
                }
                for v in c.lb.iter_mut() {
                    *v = ln_fast(*v);
                }
            },
        );
        for (((&i, &la), &lb), &px) in c.index.iter().zip(&c.la).zip(&c.lb).zip(&c.state) {
            self.emit_pixel(i, px, la, lb, t_a_ns, t_b_ns, out);
        }
        self.block_masks = masks;
        self.candidates = c;
        self.shot_noise(frame_b, t_a_ns, t_b_ns, out);
    }

    /// A step on the logs of every pixel (leak or low-pass on): each pixel's log intensity at
    /// `t_b`, low-passed, plus its leak ramp, against its reference; the pixels past a level emit
    /// their crossings of the linear path from the last step's value. `isa` vectorises the logs
    /// and the filter; `None` is the scalar oracle, equal bit for bit.
    fn step_logs(
        &mut self,
        isa: Option<neuspike_simd::Isa>,
        frame_b: &[f32],
        t_a_ns: i64,
        t_b_ns: i64,
        out: &mut Vec<Event>,
    ) {
        let n = self.state.len();
        // The leak's ramps, from their origin; folded into the references when they grow.
        let origin = *self.noise.ramp_origin_ns.get_or_insert(t_a_ns);
        let secs = |t: i64| (t.saturating_sub(origin) as f64 * 1e-9) as f32;
        let max_leak = self.noise.max_leak;
        let (mut tau_a, mut tau_b) = (secs(t_a_ns), secs(t_b_ns));
        if max_leak * tau_b > MAX_RAMP {
            for i in 0..n {
                let r = f64::from(self.state[i].reference) - f64::from(self.noise.leak[i] * tau_a);
                self.set_reference(i, r);
            }
            self.noise.ramp_origin_ns = Some(t_a_ns);
            (tau_a, tau_b) = (0.0, ((t_b_ns - t_a_ns) as f64 * 1e-9) as f32);
        }
        let dt_2pi_fc = (((t_b_ns - t_a_ns) as f64 * 1e-9)
            * 2.0
            * std::f64::consts::PI
            * f64::from(self.noise.cutoff_hz)) as f32;
        let leak = std::mem::take(&mut self.noise.leak);
        let mut lp = std::mem::take(&mut self.noise.lp);
        let upper = std::mem::take(&mut self.upper_log);
        let lower = std::mem::take(&mut self.lower_log);
        let args = LogStep {
            frame_b,
            upper: &upper,
            lower: &lower,
            leak: &leak,
            scale: self.light_scale,
            floor: self.floor,
            filter: self.noise.cutoff_hz > 0.0,
            dt_2pi_fc,
            tau_a,
            tau_b,
        };
        let mut c = std::mem::take(&mut self.candidates);
        c.clear();
        match isa {
            Some(isa) => neuspike_simd::with_isa(
                isa,
                #[inline(always)]
                || scan_logs(&args, &mut lp, &mut c),
            ),
            // The oracle: every pixel's level, then its crossings, one pixel after another.
            None => {
                for (i, (lp, &v)) in lp.iter_mut().zip(frame_b).enumerate() {
                    let l = log_level(&args, args.filter, v, *lp);
                    let ramp = |tau: f32| leak.get(i).map_or(0.0, |k| k * tau);
                    c.index.push(i);
                    c.la.push(*lp + ramp(tau_a));
                    c.lb.push(l + ramp(tau_b));
                    *lp = l;
                }
            }
        }
        self.upper_log = upper;
        self.lower_log = lower;
        self.noise.leak = leak;
        self.noise.lp = lp;
        // The candidates' states first (independent loads, so that their cache misses
        // overlap), then their crossings.
        c.state.extend(c.index.iter().map(|&i| self.state[i]));
        for (((&i, &la), &lb), &px) in c.index.iter().zip(&c.la).zip(&c.lb).zip(&c.state) {
            self.emit_pixel(i, px, la, lb, t_a_ns, t_b_ns, out);
        }
        self.candidates = c;
    }

    /// The shot-noise events of a step, as v2e makes them: a Poisson count of candidates over
    /// the array, each kept with probability `(1 - 0.75 i) theta / theta_i` (its light at `t_b`,
    /// the nominal over the pixel's threshold of the polarity), each polarity at half the rate,
    /// at a uniform time in the step; the count is drawn per bucket of pixels of like
    /// thresholds ([`ShotBucket`]). As in v2e (1.5), a pixel that fires a noise event forgets its
    /// change so far: its reference becomes its (filtered) log intensity at `t_b`.
    fn shot_noise(&mut self, frame_b: &[f32], t_a_ns: i64, t_b_ns: i64, out: &mut Vec<Event>) {
        let dt = t_b_ns.saturating_sub(t_a_ns);
        if self.noise.shot_rate_hz <= 0.0 || dt <= 0 {
            return;
        }
        let width = self.width;
        // The leak's ramp at `t_b`, as `step_logs` left it.
        let tau_b = self
            .noise
            .ramp_origin_ns
            .map_or(0.0, |o| (t_b_ns.saturating_sub(o) as f64 * 1e-9) as f32);
        // Each polarity at half the rate; a bucket's candidates at its largest ratio. First every
        // candidate's draws, then its pixel and its chance for its threshold, then those kept for
        // their light, then the kept ones' events and references: each pass a tight loop of
        // loads independent of each other, so that their cache misses overlap.
        let per_pixel = 0.5 * self.noise.shot_rate_hz * dt as f64 * 1e-9;
        let buckets = std::mem::take(&mut self.noise.shot_buckets);
        let mut c = std::mem::take(&mut self.noise.shot_candidates);
        c.clear();
        for (k, b) in buckets.iter().enumerate() {
            let mean = b.pixels.len() as f64 * per_pixel * f64::from(b.max_ratio);
            let Ok(poisson) = rand_distr::Poisson::new(mean) else {
                continue;
            };
            let count = poisson.sample(&mut self.noise.rng) as u64;
            let rng = &mut self.noise.rng;
            for _ in 0..count {
                let j = rand::Rng::random_range(&mut *rng, 0..b.pixels.len()) as u32;
                let u: f32 = rand::Rng::random(&mut *rng);
                let t_ns = t_a_ns + rand::Rng::random_range(&mut *rng, 0..dt);
                c.push(ShotCandidate {
                    pixel: j,
                    bucket: k as u32,
                    keep: 0.0,
                    u,
                    t_ns,
                });
            }
        }
        for s in c.iter_mut() {
            (s.pixel, s.keep) = buckets[s.bucket as usize].pixels[s.pixel as usize];
        }
        c.retain(|s| {
            let light = 1.0 - 0.75 * inten01(self.scaled(frame_b[s.pixel as usize]));
            s.u < light * s.keep
        });
        for s in &c {
            let i = s.pixel as usize;
            out.push(Event {
                t_ns: s.t_ns,
                x: (i % width) as u16,
                y: (i / width) as u16,
                polarity: buckets[s.bucket as usize].polarity,
            });
            let level = if !self.linear {
                self.noise.lp[i] + self.noise.leak.get(i).map_or(0.0, |k| k * tau_b)
            } else {
                self.log_of(frame_b[i])
            };
            self.set_reference(i, f64::from(level));
        }
        self.noise.shot_candidates = c;
        self.noise.shot_buckets = buckets;
    }

    /// [`DvsPixels::step`] as the plain loop over every pixel (the oracle): the log of every
    /// pixel of both frames, then every pixel's crossings.
    pub fn step_reference(
        &mut self,
        frame_a: &[f32],
        frame_b: &[f32],
        t_a_ns: i64,
        t_b_ns: i64,
        out: &mut Vec<Event>,
    ) {
        if !self.linear {
            self.step_logs(None, frame_b, t_a_ns, t_b_ns, out);
            self.shot_noise(frame_b, t_a_ns, t_b_ns, out);
            return;
        }
        let log_a: Vec<f32> = frame_a.iter().map(|&v| self.log_of(v)).collect();
        let log_b: Vec<f32> = frame_b.iter().map(|&v| self.log_of(v)).collect();
        for (i, (&la, &lb)) in log_a.iter().zip(&log_b).enumerate() {
            self.emit_pixel(i, self.state[i], la, lb, t_a_ns, t_b_ns, out);
        }
        self.shot_noise(frame_b, t_a_ns, t_b_ns, out);
    }

    /// Emits every crossing of pixel `i` (whose state is `px`) between `t_a` and `t_b`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn emit_pixel(
        &mut self,
        i: usize,
        mut px: PixelState,
        la: f32,
        lb: f32,
        t_a: i64,
        t_b: i64,
        out: &mut Vec<Event>,
    ) {
        let dt = (t_b - t_a) as f64;
        let (la, lb) = (f64::from(la), f64::from(lb));
        // Pixel indices fit in 32 bits (x and y in 16 each), whose division is the faster.
        let (i32, w32) = (i as u32, self.width as u32);
        let (x, y) = ((i32 % w32) as u16, (i32 / w32) as u16);
        let mut r = f64::from(px.reference);
        let (on, off) = (f64::from(px.theta_on), f64::from(px.theta_off));
        loop {
            let (level, polarity) = if lb >= r + on {
                (r + on, 1i8)
            } else if lb <= r - off {
                (r - off, -1i8)
            } else {
                break;
            };
            // Time at which the linear path reaches `level`; a level already passed at t_a
            // (left behind during a refractory period) fires at t_a.
            let frac = if lb != la {
                ((level - la) / (lb - la)).clamp(0.0, 1.0)
            } else {
                0.0
            };
            // Events of this step stay inside [t_a, t_b): a crossing exactly at t_b is
            // stamped one nanosecond earlier. Rounded to the nearest nanosecond, halves up
            // (`frac * dt >= 0`; no library call).
            let mut t = (t_a + (frac * dt + 0.5) as i64).min(t_b - 1);
            let free_at = px.last_event_ns.saturating_add(self.refractory_ns);
            if t < free_at {
                if free_at >= t_b {
                    break; // still in reset at the end of the step: the reference waits
                }
                t = free_at;
            }
            r = level;
            px.last_event_ns = t;
            out.push(Event {
                t_ns: t,
                x,
                y,
                polarity,
            });
        }
        let moved = r != f64::from(px.reference);
        self.state[i] = px;
        if moved {
            self.set_reference(i, r);
        }
    }

    /// Moves pixel `i`'s reference level to `r` (rounded to single precision) and its
    /// pre-check levels with it.
    #[inline(always)]
    fn set_reference(&mut self, i: usize, r: f64) {
        let px = &mut self.state[i];
        px.reference = r as f32;
        let r = f64::from(px.reference);
        if self.linear {
            (self.upper[i], self.lower[i]) = linear_levels(
                r,
                f64::from(px.theta_on),
                f64::from(px.theta_off),
                f64::from(px.gain_on),
                f64::from(px.gain_off),
            );
        } else {
            self.upper_log[i] = f32_at_or_below(r + f64::from(px.theta_on));
            self.lower_log[i] = f32_at_or_above(r - f64::from(px.theta_off));
        }
    }
}

/// The event camera looking at a scene.
pub struct EventCamera {
    scene: Scene,
    cfg: DvsConfig,
    step_ns: i64,
    pixels: DvsPixels,
    /// The scene at `t_ns` and at the end of the step being simulated.
    frame_now: Array2<f32>,
    frame_next: Array2<f32>,
    t_ns: i64,
    scratch: Vec<Event>,
    /// Motion-compensated interpolation between renders, when on.
    warp: Option<Interpolator>,
}

impl EventCamera {
    /// A camera whose reference levels are the scene at `t_start_ns`.
    pub fn new(scene: Scene, cfg: DvsConfig, t_start_ns: i64) -> Result<Self, ConfigError> {
        cfg.validate()?;
        // Sensor pixels per scene pixel: through a homography, its local scale.
        let scale = match &cfg.homography {
            None => cfg.width as f64 / scene.width().max(1) as f64,
            Some(h) => {
                let c = h.coefficients();
                let spike_per_dvs = (c[0] * c[4] - c[1] * c[3]).abs().sqrt().max(1e-9);
                cfg.rig_width as f64 / scene.width().max(1) as f64 / spike_per_dvs
            }
        };
        let speed = scene.max_speed_px_per_s() * scale;
        let step_ns = if speed > 0.0 {
            ((cfg.max_shift_px / speed) * 1e9)
                .floor()
                .clamp(1.0, cfg.max_step_ns as f64) as i64
        } else {
            cfg.max_step_ns
        };
        // A clip's light is linear between its frames only: a step at most a frame.
        let step_ns = scene
            .linear_for_ns()
            .map_or(step_ns, |ns| step_ns.min(ns.max(1)));
        let mut frame = Array2::zeros((cfg.height, cfg.width));
        render_view(&scene, &cfg, t_start_ns, &mut frame);
        let pixels = DvsPixels::new(&cfg, scene.light_scale() as f32, pixels_of(&frame))?;
        // A clip has no motion to move renders along.
        let moving = !scene.is_static() && scene.clip().is_none();
        let warp = (cfg.warp_step_ns > step_ns && moving).then(|| {
            Interpolator::new(&scene, cfg.height, cfg.width, t_start_ns, cfg.warp_step_ns)
        });
        Ok(EventCamera {
            warp,
            frame_next: frame.clone(),
            frame_now: frame,
            scene,
            step_ns,
            pixels,
            t_ns: t_start_ns,
            scratch: Vec::new(),
            cfg,
        })
    }

    /// The sampling step, nanoseconds.
    pub fn step_ns(&self) -> i64 {
        self.step_ns
    }

    /// Nanoseconds between two renders under motion-compensated interpolation, when it is on.
    pub fn warp_step_ns(&self) -> Option<i64> {
        self.warp.as_ref().map(Interpolator::step_ns)
    }

    /// Simulated time so far.
    pub fn time_ns(&self) -> i64 {
        self.t_ns
    }

    /// The scene being watched.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// Simulates up to `t_end_ns` and returns the events of `[time_ns(), t_end_ns)` as a batch.
    pub fn advance_to(&mut self, t_end_ns: i64, seq: u64) -> EventBatch {
        let mut batch =
            EventBatch::empty(self.cfg.width, self.cfg.height, self.t_ns, t_end_ns, seq);
        while self.t_ns < t_end_ns {
            let t_b = (self.t_ns + self.step_ns).min(t_end_ns);
            if !self.scene.is_static() {
                match &mut self.warp {
                    Some(w) => w.image_into(&self.scene, t_b, self.frame_next.view_mut()),
                    None => render_view(&self.scene, &self.cfg, t_b, &mut self.frame_next),
                }
            }
            self.scratch.clear();
            self.pixels.step(
                pixels_of(&self.frame_now),
                pixels_of(&self.frame_next),
                self.t_ns,
                t_b,
                &mut self.scratch,
            );
            std::mem::swap(&mut self.frame_now, &mut self.frame_next);
            // Events of one step come pixel by pixel; the batch is in time order.
            sort_by_time(&mut self.scratch);
            for e in &self.scratch {
                batch.push(*e);
            }
            self.t_ns = t_b;
        }
        // On this camera's clock.
        let off = self.cfg.clock_offset_ns;
        if off != 0 {
            batch.t_start_ns = batch.t_start_ns.saturating_add(off);
            batch.t_end_ns = batch.t_end_ns.saturating_add(off);
            for t in &mut batch.t_ns {
                *t = t.saturating_add(off);
            }
        }
        batch
    }
}

/// The scene as the camera sees it at `t_ns`: the whole view at the sensor's size, or through
/// the rig's homography (this camera's pixel -> spike camera's pixel -> scene).
fn render_view(scene: &Scene, cfg: &DvsConfig, t_ns: i64, frame: &mut Array2<f32>) {
    match &cfg.homography {
        None => scene.render_into(t_ns, frame.view_mut()),
        Some(h) => {
            let sx = scene.width() as f64 / cfg.rig_width as f64;
            let sy = scene.height() as f64 / cfg.rig_height as f64;
            let map = |x: f64, y: f64| h.apply(x, y).map(|(u, v)| (u * sx, v * sy));
            scene.render_mapped_into(t_ns, &map, frame.view_mut());
        }
    }
}

/// The pixel array run on a sequence of frames, a frame every `dt_ns`, as v2e runs its emulator
/// on video (`neuspike frames-to-events`, and the Python package's `frames_to_events`): the first
/// frame sets every pixel's reference level, each later one adds the crossings of the
/// log-intensity path from the frame before, and that interval's noise, exactly as
/// [`DvsPixels::step`] does inside the event camera.
pub struct FrameSteps {
    pixels: DvsPixels,
    frames: u64,
    dt_ns: i64,
    events: Vec<Event>,
}

impl FrameSteps {
    /// Starts at frame 0, `first` (intensities, row-major, `cfg.width` columns), seen at
    /// `light_scale`.
    ///
    /// # Errors
    /// A setting out of range, or a frame of another size than `cfg`'s.
    pub fn new(
        cfg: &DvsConfig,
        light_scale: f32,
        first: &[f32],
        dt_ns: i64,
    ) -> Result<Self, ConfigError> {
        Ok(FrameSteps {
            pixels: DvsPixels::new(cfg, light_scale, first)?,
            frames: 1,
            dt_ns,
            events: Vec::new(),
        })
    }

    /// The events from `prev` (the frame before, which the caller keeps) to `frame`, the next
    /// frame, `dt_ns` later, sorted by time.
    pub fn next(&mut self, prev: &[f32], frame: &[f32]) -> &[Event] {
        let k = self.frames as i64;
        let t_a = (k - 1).saturating_mul(self.dt_ns);
        let t_b = k.saturating_mul(self.dt_ns);
        self.events.clear();
        self.pixels.step(prev, frame, t_a, t_b, &mut self.events);
        sort_by_time(&mut self.events);
        self.frames += 1;
        &self.events
    }
}

/// Sorts events by time, stably (events of the same nanosecond keep their order, which is pixel
/// order for one step's events): a radix sort on `t_ns` that skips the bytes all the times share,
/// so a step's events (times within 2^24 ns of each other) take three linear passes instead of a
/// comparison sort's `n log n`, which mattered in event floods.
pub fn sort_by_time(events: &mut [Event]) {
    radsort::sort_by_key(events, |e| e.t_ns);
}

/// The pixels of a frame the camera rendered (standard layout, so always one slice).
fn pixels_of(frame: &Array2<f32>) -> &[f32] {
    frame.as_slice().unwrap_or(&[])
}

pub mod playback;
#[cfg(feature = "ros2")]
pub mod ros2;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_clip_fires_where_its_frames_change() {
        // Pixel 0 holds still; pixel 1's log intensity rises 0.45 over frames 1 ms apart.
        let frames = ndarray::Array3::from_shape_fn((3, 1, 2), |(k, _, c)| {
            if c == 0 {
                0.5
            } else {
                0.5 * (0.225 * k as f32).exp()
            }
        });
        let clip = neuspike_scene::Clip::new(frames, 1_000_000, "test").expect("clip");
        let scene = Scene::from_clip(clip, 1.0).expect("scene");
        let cfg = DvsConfig {
            width: 2,
            height: 1,
            theta_sigma: 0.0,
            ..DvsConfig::default()
        };
        let mut cam = EventCamera::new(scene, cfg, 0).expect("camera");
        // A step at most a frame, though nothing moves.
        assert!(cam.step_ns() <= 1_000_000, "{}", cam.step_ns());
        let batch = cam.advance_to(3_000_000, 0);
        let on: Vec<_> = (0..batch.len()).map(|i| batch.get(i)).collect();
        assert_eq!(on.len(), 2, "{on:?}");
        assert!(on.iter().all(|e| e.x == 1 && e.polarity == 1), "{on:?}");
        // The first crossing (0.2 of 0.45, linear in intensity between frames) is in the first
        // frame interval, the second in the second.
        assert!(on[0].t_ns < 1_000_000 && on[1].t_ns >= 1_000_000, "{on:?}");
    }

    fn scene(yaml_motion: &str, light: f64) -> Scene {
        let yaml = format!(
            "width: 32\nheight: 16\nduration_ms: 20\nlight_scale: {light}\nsamples_per_pixel: 1\n\
             texture:\n  kind: grating\n  period_px: 16\n{yaml_motion}"
        );
        Scene::from_yaml_str(&yaml, "test", None).expect("scene")
    }

    fn cfg() -> DvsConfig {
        DvsConfig {
            width: 32,
            height: 16,
            theta_sigma: 0.0,
            ..Default::default()
        }
    }

    #[test]
    fn static_scene_is_silent() {
        let mut cam = EventCamera::new(scene("", 1.0), cfg(), 0).unwrap();
        assert!(cam.advance_to(10_000_000, 0).is_empty());
    }

    #[test]
    fn moving_scene_fires_and_events_are_ordered_and_inside() {
        let mut cam =
            EventCamera::new(scene("motion:\n  vx_px_s: 500.0\n", 1.0), cfg(), 0).unwrap();
        let b = cam.advance_to(5_000_000, 3);
        assert!(b.len() > 100, "{} events", b.len());
        b.validate("test").unwrap();
        assert!(b.polarity.contains(&1) && b.polarity.contains(&-1));
        assert_eq!((b.t_start_ns, b.t_end_ns, b.seq), (0, 5_000_000, 3));
    }

    /// A scene that starts and stops (`motion.start_ns`, `stop_ns`) fires only while it moves:
    /// nothing before the start, nothing after the stop, plenty between.
    #[test]
    fn a_scene_fires_only_while_it_moves() {
        let s = scene(
            "motion:\n  vx_px_s: 500.0\n  start_ns: 4000000\n  stop_ns: 9000000\n",
            1.0,
        );
        let mut cam = EventCamera::new(s, cfg(), 0).unwrap();
        let b = cam.advance_to(16_000_000, 0);
        assert!(b.len() > 100, "{} events", b.len());
        let (first, last) = (b.t_ns[0], b.t_ns[b.len() - 1]);
        assert!(
            first > 4_000_000 && last <= 9_000_000,
            "events from {first} to {last} ns"
        );
    }

    /// Summing the events times the threshold gives back the change of log intensity, to within
    /// one threshold per pixel: no crossing is lost.
    #[test]
    fn event_sum_tracks_log_intensity() {
        let c = cfg();
        let s = scene("motion:\n  vx_px_s: 300.0\n", 1.0);
        let mut cam = EventCamera::new(s.clone(), c.clone(), 0).unwrap();
        let b = cam.advance_to(8_000_000, 0);
        let start = s.render(0, 16, 32);
        let end = s.render(8_000_000, 16, 32);
        let mut sum = Array2::<f64>::zeros((16, 32));
        for i in 0..b.len() {
            let e = b.get(i);
            sum[[usize::from(e.y), usize::from(e.x)]] += f64::from(e.polarity) * c.theta_on;
        }
        for ((y, x), &s) in sum.indexed_iter() {
            let dl =
                f64::from(end[[y, x]].max(1e-4)).ln() - f64::from(start[[y, x]].max(1e-4)).ln();
            assert!(
                (s - dl).abs() <= c.theta_on + 1e-3,
                "pixel ({x},{y}): events {s} vs dL {dl}"
            );
        }
    }

    /// `bright-fast` at full size for 5 ms, the scene rendered every sample against every 3.2 ms
    /// and moved along its motion between: the event counts agree within 10% (the moved images
    /// are a little smoother: 7% fewer events here) and the per-pixel signed sums (the change of
    /// log intensity each pixel saw) correlate above 0.9 (0.994). Through a homography the
    /// option is refused by name.
    #[test]
    fn a_warped_dvs_fires_as_a_rendering_one_does() {
        let s = Scene::load("bright-fast").unwrap();
        let run = |warp_step_ns: i64| {
            let c = DvsConfig {
                warp_step_ns,
                ..DvsConfig::default()
            };
            let mut cam = EventCamera::new(s.clone(), c.clone(), 0).unwrap();
            let b = cam.advance_to(5_000_000, 0);
            let mut sum = Array2::<f64>::zeros((c.height, c.width));
            for i in 0..b.len() {
                let e = b.get(i);
                sum[[usize::from(e.y), usize::from(e.x)]] += f64::from(e.polarity);
            }
            (b.len() as f64, sum, cam.warp_step_ns())
        };
        let (n_plain, plain, none) = run(0);
        let (n_warped, warped, step) = run(3_200_000);
        assert_eq!((none, step), (None, Some(3_200_000)));
        let n = plain.len() as f64;
        let (ma, mb) = (plain.sum() / n, warped.sum() / n);
        let cov: f64 = plain
            .iter()
            .zip(&warped)
            .map(|(a, b)| (a - ma) * (b - mb))
            .sum();
        let va: f64 = plain.iter().map(|a| (a - ma).powi(2)).sum();
        let vb: f64 = warped.iter().map(|b| (b - mb).powi(2)).sum();
        let corr = cov / (va * vb).sqrt();
        eprintln!("events: rendering {n_plain}, warped {n_warped}; correlation {corr:.3}");
        assert!(
            (n_warped / n_plain - 1.0).abs() < 0.1,
            "{n_plain} vs {n_warped}"
        );
        assert!(corr > 0.9, "{corr}");
        let rig = DvsConfig {
            warp_step_ns: 3_200_000,
            homography: Some(
                Homography::new([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]).unwrap(),
            ),
            ..DvsConfig::default()
        };
        let e = EventCamera::new(s, rig, 0).err().unwrap().to_string();
        assert!(
            e.contains("warp-step-ns") && e.contains("homography"),
            "{e}"
        );
    }

    #[test]
    fn refractory_period_spaces_events() {
        let mut c = cfg();
        c.refractory_ns = 1_000_000;
        let mut cam = EventCamera::new(scene("motion:\n  vx_px_s: 2000.0\n", 1.0), c, 0).unwrap();
        let b = cam.advance_to(10_000_000, 0);
        let mut last = std::collections::HashMap::new();
        for i in 0..b.len() {
            let e = b.get(i);
            if let Some(prev) = last.insert((e.x, e.y), e.t_ns) {
                assert!(
                    e.t_ns - prev >= 1_000_000,
                    "pixel ({},{}) fired after {} ns",
                    e.x,
                    e.y,
                    e.t_ns - prev
                );
            }
        }
    }

    #[test]
    fn deterministic_for_a_seed() {
        let mk = |seed| {
            let c = DvsConfig { seed, ..cfg() };
            let c = DvsConfig {
                theta_sigma: 0.1,
                ..c
            };
            EventCamera::new(scene("motion:\n  vx_px_s: 400.0\n", 1.0), c, 0)
                .unwrap()
                .advance_to(3_000_000, 0)
        };
        assert_eq!(mk(1), mk(1));
        assert_ne!(mk(1), mk(2));
    }

    #[test]
    fn bad_settings_name_the_key() {
        let c = DvsConfig {
            theta_on: 0.0,
            ..cfg()
        };
        let e = EventCamera::new(scene("", 1.0), c, 0)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("theta-on") && e.contains('0'), "{e}");
        let c = DvsConfig {
            width: 65_535,
            height: 65_535,
            ..cfg()
        };
        let e = EventCamera::new(scene("", 1.0), c, 0)
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("65535x65535") && e.contains("NEUSPIKE_MAX_SENSOR_PIXELS"),
            "{e}"
        );
    }

    proptest::proptest! {
        #[test]
        fn fast_step_equals_reference(
            w in 1usize..40,
            h in 1usize..12,
            seed in proptest::prelude::any::<u64>(),
            refractory_ns in 0i64..300,
            steps in 1usize..6,
            isa in 0usize..3,
            noise in 0usize..5,
        ) {
            let isa = neuspike_simd::Isa::ALL[isa];
            // No noise (steps of 100 ns); with noise, steps of 1 ms: the leak (about two events
            // a step), shot noise, the low-pass alone, the low-pass with both.
            let (leak_rate_hz, shot_noise_rate_hz, cutoff_hz) = match noise {
                0 => (0.0, 0.0, 0.0),
                1 => (2000.0, 0.0, 0.0),
                2 => (0.0, 5000.0, 0.0),
                3 => (0.0, 0.0, 50.0),
                _ => (2000.0, 5000.0, 50.0),
            };
            let dt: i64 = if noise == 0 { 100 } else { 1_000_000 };
            let refractory_ns = refractory_ns * (dt / 100);
            let c = DvsConfig { width: w, height: h, refractory_ns, theta_sigma: 0.1, seed, ..Default::default() };
            let c = DvsConfig { leak_rate_hz, shot_noise_rate_hz, cutoff_hz, ..c };
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            // Small changes of log intensity (most pixels stay below a threshold) with an
            // occasional jump; the frames are the intensities.
            let mut prev: Vec<f32> = (0..w * h).map(|_| rand::Rng::random_range(&mut rng, -3.0f32..1.0)).collect();
            let mut frame = || -> Vec<f32> {
                for v in prev.iter_mut() {
                    let jump = rand::Rng::random_bool(&mut rng, 0.05);
                    *v += if jump { rand::Rng::random_range(&mut rng, -1.0f32..1.0) } else { rand::Rng::random_range(&mut rng, -0.1f32..0.1) };
                }
                prev.iter().map(|l| l.exp()).collect()
            };
            let start = frame();
            let mut fast = DvsPixels::new(&c, 1.3, &start).unwrap();
            let mut slow = DvsPixels::new(&c, 1.3, &start).unwrap();
            let (mut e1, mut e2) = (Vec::new(), Vec::new());
            let mut last = start.clone();
            for k in 0..steps as i64 {
                let next = frame();
                fast.step_with(isa, &last, &next, k * dt, (k + 1) * dt, &mut e1);
                slow.step_reference(&last, &next, k * dt, (k + 1) * dt, &mut e2);
                last = next;
            }
            proptest::prop_assert_eq!(e1, e2);
            proptest::prop_assert_eq!(&fast.state, &slow.state);
            proptest::prop_assert_eq!(&fast.upper, &slow.upper);
            proptest::prop_assert_eq!(&fast.lower, &slow.lower);
            proptest::prop_assert_eq!(&fast.upper_log, &slow.upper_log);
            proptest::prop_assert_eq!(&fast.lower_log, &slow.lower_log);
            proptest::prop_assert_eq!(&fast.noise.lp, &slow.noise.lp);
        }

        /// The linear pre-check never misses an intensity whose `ln_fast` reaches the level:
        /// intensities at, just around and far from the linear levels, at log levels across
        /// the whole f32 range.
        #[test]
        fn linear_levels_never_miss_a_crossing(
            r in -95.0f32..95.0,
            on in 0.01f32..3.0,
            off in 0.01f32..3.0,
            rel in -1e-4f64..1e-4,
            ulps in -8i32..8,
            far in -100.0f64..100.0,
        ) {
            let (up, lo) = (f64::from(r) + f64::from(on), f64::from(r) - f64::from(off));
            let (g_on, g_off) = threshold_gains(on, off);
            let (u, l) = linear_levels(
                f64::from(r), f64::from(on), f64::from(off), f64::from(g_on), f64::from(g_off),
            );
            let nudge = |v: f32| -> f32 {
                let mut v = v;
                for _ in 0..ulps.unsigned_abs() {
                    v = if ulps > 0 { v.next_up() } else { v.next_down() };
                }
                v
            };
            let candidates = [
                nudge(u), nudge(l), (f64::from(u) * (1.0 + rel)) as f32,
                (f64::from(l) * (1.0 + rel)) as f32, up.exp() as f32, lo.exp() as f32,
                far.exp() as f32,
            ];
            for x in candidates {
                // The floor (at least 1e-30) keeps the pixels out of ln_fast's clamp.
                if !(x >= f32::MIN_POSITIVE && x.is_finite()) {
                    continue;
                }
                let lx = f64::from(ln_fast(x));
                proptest::prop_assert!(lx < up || x >= u, "x {x} ln_fast {lx} >= {up} but below {u}");
                proptest::prop_assert!(lx > lo || x <= l, "x {x} ln_fast {lx} <= {lo} but above {l}");
            }
        }
    }

    /// A still 32x16 scene at light 1 (half grey) for `ms` milliseconds with `cfg`'s noise.
    fn still_events(c: DvsConfig, light: f64, ms: i64) -> EventBatch {
        EventCamera::new(scene("", light), c, 0)
            .unwrap()
            .advance_to(ms * 1_000_000, 0)
    }

    #[test]
    fn leak_events_come_at_the_leak_rate_and_are_on() {
        let c = DvsConfig {
            leak_rate_hz: 50.0,
            leak_jitter: 0.1,
            ..cfg()
        };
        let b = still_events(c, 1.0, 400);
        // 512 pixels x 50 Hz x 0.4 s = 10,240 events, all ON, each pixel about 20.
        let n = b.len() as f64;
        assert!((n - 10_240.0).abs() < 0.05 * 10_240.0, "{n} events");
        assert!(b.polarity.iter().all(|&p| p == 1));
        b.validate("leak").unwrap();
        // The random phases spread the first events over the first cycle (20 ms).
        let first = b.t_ns.iter().copied().filter(|&t| t < 20_000_000).count();
        assert!((400..=620).contains(&first), "{first} in the first cycle");
    }

    #[test]
    fn a_leak_started_at_the_level_waits_one_cycle_as_v2e_does() {
        let c = DvsConfig {
            leak_rate_hz: 50.0,
            leak_jitter: 0.1,
            leak_start: LeakStart::Level,
            ..cfg()
        };
        let b = still_events(c, 1.0, 400);
        // No pixel fires before most of its first cycle (20 ms at 50 Hz, 10% spread), and over
        // the whole run each still fires at its rate: about 512 x 50 x 0.4 less the first
        // cycle's share, 512 x 19 or 20 events.
        assert!(
            b.t_ns.iter().all(|&t| t > 12_000_000),
            "{:?}",
            b.t_ns.iter().min()
        );
        let n = b.len() as f64;
        assert!((9_000.0..=10_500.0).contains(&n), "{n} events");
        assert!(b.polarity.iter().all(|&p| p == 1));
    }

    #[test]
    fn shot_noise_is_the_rate_in_the_dark_and_a_quarter_in_full_light() {
        let c = DvsConfig {
            shot_noise_rate_hz: 20.0,
            ..cfg()
        };
        // The rate, times 1 - 0.75 i of each pixel's light (no echo: the reference moves instead).
        let want = |light: f64| {
            let frame = scene("", light).render(0, 16, 32);
            frame
                .iter()
                .map(|&v| 20.0 * 0.5 * f64::from(1.0 - 0.75 * inten01(v * light as f32)))
                .sum::<f64>()
        };
        for light in [1e-3, 4.0] {
            let got = still_events(c.clone(), light, 500).len() as f64;
            let want = want(light);
            assert!(
                (got - want).abs() < 0.08 * want,
                "light {light}: {got}, want {want}"
            );
        }
        assert!(want(4.0) < 0.5 * want(1e-3));
        let b = still_events(c, 1e-3, 500);
        let on = b.polarity.iter().filter(|&&p| p == 1).count() as f64;
        assert!((on / b.len() as f64 - 0.5).abs() < 0.05);
        b.validate("shot").unwrap();
    }

    #[test]
    fn the_photoreceptor_low_pass_spreads_a_step_of_light_in_time() {
        let w = 8;
        let c = DvsConfig {
            width: w,
            height: 1,
            theta_sigma: 0.0,
            ..Default::default()
        };
        let run = |cutoff_hz: f64| {
            let c = DvsConfig {
                cutoff_hz,
                ..c.clone()
            };
            let (dim, bright) = (vec![0.1f32; w], vec![1.0f32; w]);
            let mut px = DvsPixels::new(&c, 1.0, &dim).unwrap();
            let mut out = Vec::new();
            px.step(&dim, &bright, 0, 100_000, &mut out);
            for k in 1..200 {
                px.step(&bright, &bright, k * 100_000, (k + 1) * 100_000, &mut out);
            }
            out
        };
        // ln 10 / 0.2 = 11.5: eleven ON events a pixel either way.
        let sharp = run(0.0);
        let slow = run(100.0);
        assert_eq!(sharp.len(), 11 * w);
        assert_eq!(slow.len(), 11 * w);
        assert!(sharp.iter().all(|e| e.t_ns < 100_000 && e.polarity == 1));
        // 100 Hz in full light: a time constant of 1.6 ms; the last event comes after 2 ms.
        let last = slow.iter().map(|e| e.t_ns).max().unwrap();
        assert!(last > 2_000_000, "last event at {last} ns");
    }

    #[test]
    fn vectorised_log_equals_scalar_ln_fast() {
        let frame: Vec<f32> = (0..10_007)
            .map(|i| (i as f32 * 0.731).sin().abs() * 3.0)
            .collect();
        let mut log = vec![0.0; frame.len()];
        log_intensity_into(&frame, 0.7, 1e-4, &mut log);
        for (l, f) in log.iter().zip(&frame) {
            assert_eq!(l.to_bits(), ln_fast((f * 0.7).max(1e-4)).to_bits());
        }
    }

    proptest::proptest! {
        #[test]
        fn sort_by_time_is_the_stable_sort(
            raw in proptest::collection::vec((any_time(), 0u16..8, 0u16..8, proptest::bool::ANY), 0..400),
        ) {
            let events: Vec<Event> = raw
                .iter()
                .map(|&(t_ns, x, y, on)| Event { t_ns, x, y, polarity: if on { 1 } else { -1 } })
                .collect();
            let mut fast = events.clone();
            sort_by_time(&mut fast);
            let mut oracle = events;
            oracle.sort_by_key(|e| e.t_ns);
            proptest::prop_assert_eq!(fast, oracle);
        }
    }

    /// Times in a step (many ties), anywhere, and at the ends of the i64 range.
    fn any_time() -> impl proptest::strategy::Strategy<Value = i64> {
        proptest::prop_oneof![0i64..20, -1_000_000i64..1_000_000, proptest::num::i64::ANY]
    }

    #[test]
    fn tiny_log_floor_is_refused_by_name() {
        let c = DvsConfig {
            log_floor: 1e-300,
            ..cfg()
        };
        let e = EventCamera::new(scene("", 1.0), c, 0)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("log-floor") && e.contains("1e-300"), "{e}");
    }
}
