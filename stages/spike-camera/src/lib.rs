//! The spike-camera model (PKU Vidar): each pixel integrates light and fires when its accumulator
//! reaches the threshold `phi`.
//!
//! Per tick of period `plane_period_ns`, pixel `i` adds `light_scale * I_i` (the scene luminance at
//! the middle of the tick) to its accumulator; at `acc >= phi` it fires and the accumulator is reset
//! by subtraction (`acc -= phi`, default) or to zero. A pixel fires at most once a tick: under
//! saturating light the remainder is clamped below `2 phi`, so the accumulator stays bounded and a
//! saturated pixel fires every tick (ISI 1).
//!
//! Noise, as the NeuSpike-Net paper describes it (both switchable):
//! - **random initial accumulator** (readout and reset jitter): `acc_0 ~ U[0, phi)` per pixel;
//! - **fixed-pattern cap**: each pixel draws `cap_i ~ N(mu, sigma)` ticks once (default
//!   `N(180, 50)`, rounded, at least 1); a pixel that has not fired for `cap_i` ticks fires anyway
//!   (dark current) and its accumulator restarts from 0.
//!
//! More noise terms (shot noise, threshold jitter and offset, gain, dark current, reset delay),
//! each switchable, and the named camera profiles that set them: [`noise`].
//!
//! The simulation is deterministic for a seed: the noise draws come from a ChaCha generator seeded
//! with it. The scene is rendered at key instants every `render_step_ticks` ticks and linearly
//! interpolated in time between them (1 = render every tick); the kernel goes through
//! [`KEY_INTERVALS`] such intervals in one pass over the pixels' state.
#![deny(missing_docs)]

use ndarray::Array2;
pub mod calibrate;
pub mod noise;

use neuspike_scene::Scene;
use neuspike_scene::shift::Interpolator;
use neuspike_schemas::{SpikeChunk, bytes_per_plane};
pub use noise::{Noise, NoiseArgs};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Geometric, Normal};

/// How the accumulator resets after a spike.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Reset {
    /// `acc -= phi`: the remainder carries over (the PKU camera).
    Subtract,
    /// `acc = 0`.
    Zero,
}

/// Spike-camera settings. Every field is a node argument in the graph YAML.
#[derive(Clone, Debug, clap::Args)]
pub struct CameraConfig {
    /// Sensor width in pixels.
    #[arg(long, default_value_t = 400)]
    pub width: usize,
    /// Sensor height in pixels.
    #[arg(long, default_value_t = 250)]
    pub height: usize,
    /// Plane rate in Hz (the tick period is rounded to whole nanoseconds).
    #[arg(long, default_value_t = 20_000.0)]
    pub rate_hz: f64,
    /// Firing threshold phi, in units of luminance x light scale per tick.
    #[arg(long, default_value_t = 1.0)]
    pub phi: f64,
    /// Accumulator reset after a spike.
    #[arg(long, value_enum, default_value_t = Reset::Subtract)]
    pub reset: Reset,
    /// Random initial accumulator (readout / reset jitter).
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    pub random_init: bool,
    /// Fixed-pattern noise: cap each pixel's inter-spike interval at a per-pixel draw.
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    pub fpn_cap: bool,
    /// Mean of the per-pixel ISI cap, ticks.
    #[arg(long, default_value_t = 180.0)]
    pub fpn_mu: f64,
    /// Standard deviation of the per-pixel ISI cap, ticks.
    #[arg(long, default_value_t = 50.0)]
    pub fpn_sigma: f64,
    /// Render the scene every this many ticks and interpolate between (0 = choose from the scene's
    /// motion so that no point moves more than a quarter pixel between renders, at most 64 and at
    /// most a clip scene's time between frames).
    #[arg(long, default_value_t = 0)]
    pub render_step_ticks: u32,
    /// Motion-compensated interpolation: render the scene only every this many ticks (rounded up
    /// to a multiple of the render step) and make the images between by moving the two nearest
    /// renders along the scene's motion (`neuspike_scene::shift::Interpolator`); 1 renders every
    /// image. Worth it where the scene moves fast: with it on, the automatic render step lets a
    /// point move half a pixel between images.
    #[arg(long, default_value_t = 1)]
    pub warp_step_ticks: u32,
    /// Seed of the noise draws (the scene has its own seed).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// The noise terms beyond the paper's: a profile and per-term overrides.
    #[command(flatten)]
    pub noise: NoiseArgs,
}

impl Default for CameraConfig {
    fn default() -> Self {
        CameraConfig {
            width: 400,
            height: 250,
            rate_hz: 20_000.0,
            phi: 1.0,
            reset: Reset::Subtract,
            random_init: true,
            fpn_cap: true,
            fpn_mu: 180.0,
            fpn_sigma: 50.0,
            render_step_ticks: 0,
            warp_step_ticks: 1,
            seed: 0,
            noise: NoiseArgs::default(),
        }
    }
}

/// A setting out of its range. The message names the setting and the value.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("spike camera: `{key}` = {value} is invalid: {why}")]
pub struct ConfigError {
    /// The setting.
    pub key: &'static str,
    /// Its value.
    pub value: String,
    /// What is wrong.
    pub why: &'static str,
}

impl CameraConfig {
    /// Checks every setting; returns the tick period in nanoseconds.
    pub fn validate(&self) -> Result<i64, ConfigError> {
        let bad = |key, value: String, why| Err(ConfigError { key, value, why });
        if self.width == 0 || self.width > u16::MAX as usize {
            return bad("width", self.width.to_string(), "must be in 1..=65535");
        }
        if self.height == 0 || self.height > u16::MAX as usize {
            return bad("height", self.height.to_string(), "must be in 1..=65535");
        }
        if self.width * self.height > neuspike_schemas::limits::max_sensor_pixels() {
            return bad(
                "width",
                format!("{}x{}", self.width, self.height),
                "the sensor has more pixels than NEUSPIKE_MAX_SENSOR_PIXELS allows (16777216, 4096x4096, unless set)",
            );
        }
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0 && self.rate_hz <= 1e9) {
            return bad("rate-hz", self.rate_hz.to_string(), "must be in (0, 1e9]");
        }
        if !(self.phi.is_finite() && self.phi > 0.0) {
            return bad("phi", self.phi.to_string(), "must be finite and > 0");
        }
        if !(self.fpn_mu.is_finite() && self.fpn_mu >= 1.0) {
            return bad(
                "fpn-mu",
                self.fpn_mu.to_string(),
                "must be finite and >= 1 tick",
            );
        }
        if !(self.fpn_sigma.is_finite() && self.fpn_sigma >= 0.0) {
            return bad(
                "fpn-sigma",
                self.fpn_sigma.to_string(),
                "must be finite and >= 0",
            );
        }
        if !(1..=MAX_WARP_STEP_TICKS).contains(&self.warp_step_ticks) {
            return bad(
                "warp-step-ticks",
                self.warp_step_ticks.to_string(),
                "must be in 1..=4096",
            );
        }
        Ok((1e9 / self.rate_hz).round().max(1.0) as i64)
    }
}

/// The largest `--warp-step-ticks`.
pub const MAX_WARP_STEP_TICKS: u32 = 4096;

/// A camera's noise settings could not be resolved (its profile, or a value).
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("{0}")]
pub struct NoiseError(pub String);

/// Why a camera could not be made.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CameraError {
    /// A setting out of range.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The noise profile or a noise value.
    #[error(transparent)]
    Noise(#[from] NoiseError),
}

/// The spike camera looking at a scene: state of every pixel plus the tick clock.
pub struct SpikeCamera {
    scene: Scene,
    cfg: CameraConfig,
    period_ns: i64,
    render_step: u64,
    light_scale: f32,
    phi: f32,
    acc: Vec<f32>,
    since: Vec<u32>,
    cap: Vec<u32>,
    /// Light per tick at the key instants `key_tick + s render_step`, `s = 0..=KEY_INTERVALS`
    /// (light scale, gain and dark light applied); in between, linear in time ([`KeyLight`]).
    keys: Vec<Vec<f32>>,
    /// The luminance of a render, without motion-compensated interpolation.
    lum: Array2<f32>,
    key_tick: u64,
    tick: u64,
    /// Motion-compensated interpolation between renders, when on.
    warp: Option<Interpolator>,
    /// The noise terms in effect.
    noise: Noise,
    /// Per-pixel light factor (gain over threshold offset) and dark light per tick, when on.
    factor: Option<Vec<f32>>,
    dark: Option<Vec<f32>>,
    /// Per-interval thresholds and their generators, when the per-fire noise is on.
    thr: Vec<f32>,
    rng: Vec<u32>,
    /// The random spikes, when on.
    random: Option<RandomSpikes>,
}

/// Spikes read at random ([`Noise::random_spike_hz`]): a Bernoulli draw for every pixel and tick,
/// made as the gaps between successes (geometric), over the pixel-ticks numbered `tick * n +
/// pixel` from the camera's start. The draws do not depend on how the planes are split into
/// chunks, and cost one draw per random spike.
struct RandomSpikes {
    gap: Geometric,
    rng: ChaCha8Rng,
    /// The pixel-tick of the next random spike.
    next: u64,
}

impl RandomSpikes {
    /// The seed's stream for the random spikes: the camera's other draws stay as they were.
    const STREAM: u64 = 0x7261_6e64;

    fn new(noise: &Noise, cfg: &CameraConfig) -> Result<Option<Self>, ConfigError> {
        if noise.random_spike_hz == 0.0 {
            return Ok(None);
        }
        let p = noise.random_spike_hz / cfg.rate_hz;
        let gap = Geometric::new(p)
            .ok()
            .filter(|_| p < 1.0)
            .ok_or(ConfigError {
                key: "random-spike-hz",
                value: noise.random_spike_hz.to_string(),
                why: "must be below the plane rate (--rate-hz)",
            })?;
        let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
        rng.set_stream(Self::STREAM);
        let next = gap.sample(&mut rng);
        Ok(Some(RandomSpikes { gap, rng, next }))
    }

    /// Sets the random spikes of planes `first..first + planes` (pixel-ticks from `first * n`)
    /// in `bits`, `per` bytes a plane. After a jump past the next one (a camera moved on), the
    /// gap is drawn afresh from `first`: a geometric gap has no memory.
    fn apply(&mut self, first: u64, planes: usize, n: usize, per: usize, bits: &mut [u8]) {
        let n64 = n as u64;
        let start = first.saturating_mul(n64);
        let end = start.saturating_add(planes as u64 * n64);
        if self.next < start {
            self.next = start.saturating_add(self.gap.sample(&mut self.rng));
        }
        while self.next < end {
            let at = self.next - start;
            let (plane, pixel) = ((at / n64) as usize, (at % n64) as usize);
            bits[plane * per + pixel / 8] |= 1 << (pixel % 8);
            self.next = self
                .next
                .saturating_add(self.gap.sample(&mut self.rng))
                .saturating_add(1);
        }
    }
}

impl SpikeCamera {
    /// A camera at tick 0.
    ///
    /// # Errors
    /// A setting out of range, or a noise profile that cannot be loaded.
    pub fn new(scene: Scene, cfg: CameraConfig) -> Result<Self, CameraError> {
        let period_ns = cfg.validate()?;
        let noise = cfg.noise.resolve().map_err(NoiseError)?;
        let n = cfg.width * cfg.height;
        let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
        let phi = cfg.phi as f32;
        let acc = if cfg.random_init {
            (0..n).map(|_| rng.random::<f32>() * phi).collect()
        } else {
            vec![0.0; n]
        };
        let cap = if cfg.fpn_cap {
            let normal = Normal::new(cfg.fpn_mu, cfg.fpn_sigma).map_err(|_| ConfigError {
                key: "fpn-sigma",
                value: cfg.fpn_sigma.to_string(),
                why: "not a valid standard deviation",
            })?;
            (0..n)
                .map(|_| normal.sample(&mut rng).round().clamp(1.0, u32::MAX as f64) as u32)
                .collect()
        } else {
            vec![u32::MAX; n]
        };
        // The fixed patterns, each drawn only when its term is on, after the paper's draws (so
        // the paper's model gives the same spikes for a seed with every other term off).
        let std_normal = Normal::new(0.0f64, 1.0).expect("unit normal");
        // A threshold offset acts on light and dark current alike (1 / (1 + o)); the gain on the
        // light alone.
        let offset: Option<Vec<f64>> = (noise.threshold_offset > 0.0).then(|| {
            (0..n)
                .map(|_| {
                    1.0 / (1.0 + noise.threshold_offset * std_normal.sample(&mut rng)).max(0.05)
                })
                .collect()
        });
        let gain: Option<Vec<f64>> = (noise.prnu > 0.0).then(|| {
            (0..n)
                .map(|_| (1.0 + noise.prnu * std_normal.sample(&mut rng)).max(0.0))
                .collect()
        });
        let at = |v: &Option<Vec<f64>>, i: usize| v.as_ref().map_or(1.0, |v| v[i]);
        let factor = (offset.is_some() || gain.is_some()).then(|| {
            (0..n)
                .map(|i| (at(&gain, i) * at(&offset, i)) as f32)
                .collect()
        });
        let dark = (noise.dark_current_hz > 0.0).then(|| {
            // Log-normal with mean `d`: d exp(s z - s^2 / 2).
            let d = noise.dark_current_hz / cfg.rate_hz * cfg.phi;
            let sd = noise.dark_current_spread;
            (0..n)
                .map(|i| {
                    let z = std_normal.sample(&mut rng);
                    (d * (sd * z - sd * sd / 2.0).exp() * at(&offset, i)) as f32
                })
                .collect()
        });
        let (thr, rng_state) = if noise.per_fire() {
            let seeds = (0..n).map(|_| rng.random::<u32>() | 1).collect();
            (vec![phi; n], seeds)
        } else {
            (Vec::new(), Vec::new())
        };
        let warped = cfg.warp_step_ticks > 1;
        let render_step = if cfg.render_step_ticks > 0 {
            u64::from(cfg.render_step_ticks)
        } else {
            let max_shift_px = if warped { 0.5 } else { 0.25 };
            auto_render_step(&scene, period_ns, cfg.width, max_shift_px)
        };
        // Renders on key ticks, a whole number of key steps apart.
        let warp_step = u64::from(cfg.warp_step_ticks).div_ceil(render_step) * render_step;
        // A clip has no motion to move renders along.
        let moving = !scene.is_static() && scene.clip().is_none();
        let warp = (warped && warp_step > render_step && moving).then(|| {
            let step_ns =
                i64::try_from(warp_step).map_or(i64::MAX, |s| s.saturating_mul(period_ns));
            let origin = mid_tick_ns(period_ns, 0);
            Interpolator::new(&scene, cfg.height, cfg.width, origin, step_ns)
        });
        let random = RandomSpikes::new(&noise, &cfg)?;
        let light_scale = scene.light_scale() as f32;
        let shape = (cfg.height, cfg.width);
        let mut cam = SpikeCamera {
            scene,
            period_ns,
            render_step,
            light_scale,
            phi,
            acc,
            since: vec![0; n],
            cap,
            keys: vec![vec![0.0; n]; KEY_INTERVALS as usize + 1],
            lum: Array2::zeros(if warp.is_some() { (0, 0) } else { shape }),
            key_tick: 0,
            tick: 0,
            warp,
            noise,
            factor,
            dark,
            thr,
            rng: rng_state,
            random,
            cfg,
        };
        cam.render_key(0);
        Ok(cam)
    }

    /// Tick period in nanoseconds.
    pub fn period_ns(&self) -> i64 {
        self.period_ns
    }

    /// Ticks between two scene images (renders, or with `--warp-step-ticks` moved renders).
    pub fn render_step(&self) -> u64 {
        self.render_step
    }

    /// Ticks between two renders under motion-compensated interpolation, when it is on.
    pub fn warp_step(&self) -> Option<u64> {
        self.warp
            .as_ref()
            .map(|w| (w.step_ns() / self.period_ns.max(1)) as u64)
    }

    /// Index of the next plane to be produced.
    pub fn tick(&self) -> u64 {
        self.tick
    }

    /// Time of plane `k`.
    pub fn plane_time_ns(&self, k: u64) -> i64 {
        (k as i64).saturating_mul(self.period_ns)
    }

    /// Number of planes that fit in the scene's duration.
    pub fn total_planes(&self) -> u64 {
        (self.scene.duration_ns() / self.period_ns).max(0) as u64
    }

    /// Luminance per unit firing rate: `phi / light_scale`.
    pub fn lum_per_rate(&self) -> f64 {
        self.cfg.phi / self.scene.light_scale()
    }

    /// The scene being watched.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// Ticks the key images of one pass cover: [`KEY_INTERVALS`] render steps.
    fn group(&self) -> u64 {
        self.render_step * KEY_INTERVALS
    }

    /// Renders the key instants from `key_tick` (the middle of ticks `key_tick + s render_step`,
    /// `s = 0..=KEY_INTERVALS`): the per-tick light of the intervals between them.
    fn render_key(&mut self, key_tick: u64) {
        if key_tick != 0 && self.scene.is_static() {
            // Every render gives the same image: the light of tick 0's interval holds forever.
            self.key_tick = key_tick;
            return;
        }
        let period = self.period_ns;
        let t = move |k: u64| mid_tick_ns(period, k);
        let last = KEY_INTERVALS as usize;
        // The last key of the group before is this group's first.
        let first = if key_tick != 0 && key_tick == self.key_tick + self.group() {
            self.keys.swap(0, last);
            1
        } else {
            0
        };
        for s in first..=last {
            self.key_light(t(key_tick + s as u64 * self.render_step), s);
        }
        self.key_tick = key_tick;
    }

    /// The light per tick of the scene at `t_ns` (rendered, or moved from the nearest renders)
    /// into key image `index`, row by row, so that each row of the image is used while it is in
    /// the cache.
    fn key_light(&mut self, t_ns: i64, index: usize) {
        let cols = self.cfg.width;
        let light = LightMap {
            ls: self.light_scale,
            factor: self.factor.as_deref(),
            dark: self.dark.as_deref(),
        };
        let out = &mut self.keys[index];
        // Each row compiled for the CPU's widest vectors (a closure handed on is not inlined
        // into the caller's).
        let mut put = |r: usize, lum: &[f32]| {
            neuspike_simd::dispatch(
                #[inline(always)]
                || light.row(lum, r * cols, &mut out[r * cols..(r + 1) * cols]),
            )
        };
        match &mut self.warp {
            Some(w) => w.image_rows(&self.scene, t_ns, put),
            None => {
                self.scene.render_into(t_ns, self.lum.view_mut());
                if let Some(lum) = self.lum.as_slice() {
                    lum.chunks_exact(cols.max(1))
                        .enumerate()
                        .for_each(|(r, row)| put(r, row));
                }
            }
        }
    }

    /// Moves the camera to tick `tick` without simulating the ticks between, as a camera switched
    /// off and on again: its pixels keep their charge and restart their interval counts, and the
    /// scene is rendered at the new time. Used when a source restarts mid-run.
    pub fn jump_to(&mut self, tick: u64) {
        self.tick = tick;
        self.since.fill(0);
        let key = tick - tick % self.group();
        if key != self.key_tick {
            self.render_key(key);
        }
    }

    /// Simulates the next `n` planes into a spike chunk with sequence number `seq`.
    pub fn next_chunk(&mut self, n: usize, seq: u64) -> SpikeChunk {
        let per = bytes_per_plane(self.cfg.width, self.cfg.height);
        let mut bits = vec![0u8; n * per];
        let first = self.tick;
        let mut done = 0;
        while done < n {
            let group = self.group();
            let key = self.tick - self.tick % group;
            if key != self.key_tick {
                self.render_key(key);
            }
            let k0 = self.tick - key;
            // Runs of at most `MAX_RUN_TICKS`: a block's planes stay close in memory.
            let run = ((group - k0) as usize).min(n - done).min(MAX_RUN_TICKS);
            let keys: [&[f32]; KEY_INTERVALS as usize + 1] =
                std::array::from_fn(|s| &self.keys[s][..]);
            let light = KeyLight {
                keys: &keys,
                step: u32::try_from(self.render_step).unwrap_or(u32::MAX),
            };
            let px = PixelState {
                acc: &mut self.acc,
                since: &mut self.since,
                cap: &self.cap,
            };
            let out = &mut bits[done * per..(done + run) * per];
            if self.noise.per_fire() {
                let fire = FireNoise {
                    sigma: self.noise.fire_sigma() as f32,
                    reset_delay: self.noise.reset_delay_ticks as f32,
                    thr: &mut self.thr,
                    rng: &mut self.rng,
                };
                integrate_ticks_noisy(light, k0 as u32, self.phi, self.cfg.reset, px, fire, out);
            } else {
                integrate_ticks(light, k0 as u32, self.phi, self.cfg.reset, px, out);
            }
            self.tick += run as u64;
            done += run;
        }
        if let Some(random) = &mut self.random {
            let n_px = self.cfg.width * self.cfg.height;
            random.apply(first, n, n_px, per, &mut bits);
        }
        SpikeChunk {
            width: self.cfg.width,
            height: self.cfg.height,
            first_plane: first,
            n_planes: n,
            t_first_ns: self.plane_time_ns(first),
            plane_period_ns: self.period_ns,
            seq,
            bits,
            lum_per_rate: Some(self.lum_per_rate()),
        }
    }

    /// The ground-truth luminance at plane `k`'s time stamp, clipped to [0, 1].
    pub fn ground_truth(&self, k: u64) -> Array2<f32> {
        let mut gt = self
            .scene
            .render(self.plane_time_ns(k), self.cfg.height, self.cfg.width);
        gt.mapv_inplace(|v| v.clamp(0.0, 1.0));
        gt
    }
}

/// How a render's luminance becomes each pixel's light per tick: times the light scale `ls`,
/// clamped to `>= 0` (NaN to 0), then the fixed patterns (a pixel's light `factor`, then its
/// `dark` light), each when on.
struct LightMap<'a> {
    ls: f32,
    factor: Option<&'a [f32]>,
    dark: Option<&'a [f32]>,
}

impl LightMap<'_> {
    /// The light of pixels `first..first + lum.len()` from their luminance `lum` into `out`:
    /// one loop without branches for each combination of patterns.
    #[inline(always)]
    fn row(&self, lum: &[f32], first: usize, out: &mut [f32]) {
        let ls = self.ls;
        let light = |l: f32| {
            if l.is_finite() {
                (ls * l).max(0.0)
            } else {
                0.0
            }
        };
        let at = first..first + lum.len();
        let pairs = out.iter_mut().zip(lum);
        match (self.factor, self.dark) {
            (None, None) => pairs.for_each(|(o, &l)| *o = light(l)),
            (Some(f), None) => pairs
                .zip(&f[at])
                .for_each(|((o, &l), &f)| *o = light(l) * f),
            (None, Some(d)) => pairs
                .zip(&d[at])
                .for_each(|((o, &l), &d)| *o = light(l) + d),
            (Some(f), Some(d)) => pairs
                .zip(f[at.clone()].iter().zip(&d[at]))
                .for_each(|((o, &l), (&f, &d))| *o = light(l) * f + d),
        }
    }
}

/// Key intervals the kernel goes through in one pass over the pixels' state: each pass reads and
/// writes every pixel's state once, so a moving scene's short intervals (a few ticks each) read
/// and write it a quarter as often as they would one by one.
pub const KEY_INTERVALS: u64 = 4;

/// The most ticks one call of the kernel goes through: each block writes a byte range of every
/// tick's plane, and longer runs spread those writes over more memory than the caches hold.
const MAX_RUN_TICKS: usize = 64;

/// Middle of tick `k` of ticks of `period_ns`: tick `k` covers `((k - 1) T, k T]`.
fn mid_tick_ns(period_ns: i64, k: u64) -> i64 {
    (k as i64).saturating_mul(period_ns) - period_ns / 2
}

/// Render step that keeps image motion under `max_shift_px` between renders.
fn auto_render_step(scene: &Scene, period_ns: i64, width: usize, max_shift_px: f64) -> u64 {
    const MAX_STEP: u64 = 64;
    // Scene pixels to sensor pixels.
    let scale = width as f64 / scene.width().max(1) as f64;
    let speed = scene.max_speed_px_per_s() * scale;
    // A clip's light is linear between its frames only: render at least once a frame.
    let linear = scene.linear_for_ns().map_or(MAX_STEP, |ns| {
        (ns / period_ns.max(1)).clamp(1, MAX_STEP as i64) as u64
    });
    if speed <= 0.0 {
        return linear;
    }
    let ticks = max_shift_px / (speed * period_ns as f64 * 1e-9);
    (ticks.floor() as u64).clamp(1, linear)
}

/// The light every pixel receives in one tick: `start[i] + slope * k`, `slope = (end[i] -
/// start[i]) * inv_step` (light scale applied, >= 0), one entry per pixel, row-major.
#[derive(Clone, Copy, Debug)]
pub struct TickLight<'a> {
    /// Light at the start of the key interval.
    pub start: &'a [f32],
    /// Light at its end.
    pub end: &'a [f32],
    /// One over the key interval's ticks.
    pub inv_step: f32,
    /// Ticks since the start of the key interval.
    pub k: f32,
}

/// The light over consecutive key intervals of `step` ticks: key image `keys[s]` holds each
/// pixel's light at tick `s step`, and tick `k` of interval `s` (tick `s step + k` of the run)
/// gives pixel `i` `keys[s][i] + slope * k`, `slope = (keys[s + 1][i] - keys[s][i]) / step`
/// (light scale applied, >= 0), one entry per pixel, row-major; ticks past the last key
/// continue the last interval's line. The kernels compute each pixel's slope from the ends, so
/// that no image of slopes is written and read again, and go through several intervals in one
/// pass over the pixels' state.
#[derive(Clone, Copy, Debug)]
pub struct KeyLight<'a> {
    /// The key images (at least two), `step` ticks apart.
    pub keys: &'a [&'a [f32]],
    /// Ticks between two keys (at least 1).
    pub step: u32,
}

impl KeyLight<'_> {
    /// The interval of tick `k` of the run (the last one for ticks past it) and the tick in it.
    #[inline(always)]
    fn interval(&self, k: usize) -> (usize, f32) {
        let step = self.step.max(1) as usize;
        let s = (k / step).min(self.keys.len().saturating_sub(2));
        (s, (k - s * step) as f32)
    }

    /// One over the ticks between two keys.
    #[inline(always)]
    fn inv_step(&self) -> f32 {
        1.0 / self.step.max(1) as f32
    }

    /// The light of pixels `from..` at tick `k` of the run.
    fn tick(&self, k: usize, from: usize) -> TickLight<'_> {
        let (s, k) = self.interval(k);
        TickLight {
            start: &self.keys[s][from..],
            end: &self.keys[s + 1][from..],
            inv_step: self.inv_step(),
            k,
        }
    }
}

impl TickLight<'_> {
    /// The light of pixel `i` in this tick.
    #[inline(always)]
    fn at(&self, i: usize) -> f32 {
        self.start[i] + (self.end[i] - self.start[i]) * self.inv_step * self.k
    }
}

/// The state of every pixel, one entry per pixel, row-major.
#[derive(Debug)]
pub struct PixelState<'a> {
    /// Accumulators.
    pub acc: &'a mut [f32],
    /// Ticks since the last spike.
    pub since: &'a mut [u32],
    /// Fixed-pattern ISI cap (`u32::MAX` when off).
    pub cap: &'a [u32],
}

/// One tick of every pixel, the plain loop (the oracle of [`integrate_ticks`]): integrate, fire at
/// `acc >= phi` or when the ISI cap is reached, reset, and set the fired pixels' bits in `plane`
/// (zeroed by the caller).
pub fn integrate_tick_reference(
    light: TickLight,
    phi: f32,
    reset: Reset,
    px: PixelState,
    plane: &mut [u8],
) {
    let n = px.acc.len();
    for i in 0..n {
        let gain = light.at(i);
        let a = px.acc[i] + gain;
        let s = px.since[i].saturating_add(1);
        let fired = if a >= phi {
            px.acc[i] = match reset {
                Reset::Subtract => below(a - phi, phi),
                Reset::Zero => 0.0,
            };
            true
        } else if s >= px.cap[i] {
            px.acc[i] = 0.0;
            true
        } else {
            px.acc[i] = a;
            false
        };
        px.since[i] = if fired { 0 } else { s };
        if fired {
            plane[i >> 3] |= 1 << (i & 7);
        }
    }
}

/// `v`, but at most `hi`: [`f32::min`] without its case for NaN, which the kernels' values never
/// are (one instruction in a vector loop instead of three). A NaN `v` gives `hi`.
#[inline(always)]
fn below(v: f32, hi: f32) -> f32 {
    if v < hi { v } else { hi }
}

/// `v`, but at least `lo` ([`below`]'s other side). A NaN `v` gives `lo`.
#[inline(always)]
fn above(v: f32, lo: f32) -> f32 {
    if v > lo { v } else { lo }
}

/// Consecutive ticks `k0, k0 + 1, ..` of one key interval, tick by tick with
/// [`integrate_tick_reference`] (the oracle of [`integrate_ticks`]). `planes` holds one packed
/// plane of `n.div_ceil(8)` bytes per tick, zeroed by the caller.
pub fn integrate_ticks_reference(
    light: KeyLight,
    k0: u32,
    phi: f32,
    reset: Reset,
    px: PixelState,
    planes: &mut [u8],
) {
    let per = px.acc.len().div_ceil(8);
    for (t, plane) in planes.chunks_exact_mut(per.max(1)).enumerate() {
        let light = light.tick(k0 as usize + t, 0);
        let px = PixelState {
            acc: &mut *px.acc,
            since: &mut *px.since,
            cap: px.cap,
        };
        integrate_tick_reference(light, phi, reset, px, plane);
    }
}

/// [`integrate_ticks_reference`], fast: equal to it bit for bit (tested).
///
/// The loop runs over blocks of [`BLOCK`] pixels outside and ticks inside, so a block's state
/// stays in registers and L1 while all its ticks are simulated, and the inner loop has no
/// branches, so the compiler vectorises it. The widest vector unit the CPU has (AVX-512, AVX2,
/// else the baseline) is chosen at run time; the arithmetic is the same IEEE single-precision
/// sequence on every path (no fused multiply-add), so every path gives the same bits.
pub fn integrate_ticks(
    light: KeyLight,
    k0: u32,
    phi: f32,
    reset: Reset,
    px: PixelState,
    planes: &mut [u8],
) {
    integrate_ticks_with(neuspike_simd::detect(), light, k0, phi, reset, px, planes);
}

/// Pixels per block of the fast path: 64, so a tick of a block is one `u64` of fire flags.
pub const BLOCK: usize = 64;
const _: () = assert!(BLOCK == 64, "a block's tick is one u64 of flags");

/// One block's light in the current key interval: its start and its slope `(end - start) /
/// step`, as [`TickLight`] computes them, and the tick in the interval, counted without a
/// division.
struct BlockLight {
    /// The block's first pixel.
    first: usize,
    /// The interval `base` and `slope` are of, and the tick in it.
    interval: usize,
    tick: usize,
    base: [f32; BLOCK],
    slope: [f32; BLOCK],
}

impl BlockLight {
    /// At tick `k0` of the run.
    #[inline(always)]
    fn new(light: &KeyLight, first: usize, k0: usize) -> BlockLight {
        let (interval, tick) = light.interval(k0);
        let mut bl = BlockLight {
            first,
            interval,
            tick: tick as usize,
            base: [0.0; BLOCK],
            slope: [0.0; BLOCK],
        };
        bl.load(light);
        bl
    }

    /// The current interval's start and slope.
    #[inline(always)]
    fn load(&mut self, light: &KeyLight) {
        let s = self.interval;
        let at = self.first..self.first + BLOCK;
        let (start, end) = (&light.keys[s][at.clone()], &light.keys[s + 1][at]);
        let inv_step = light.inv_step();
        self.base.copy_from_slice(start);
        for ((sl, &a), &b) in self.slope.iter_mut().zip(start).zip(end) {
            *sl = (b - a) * inv_step;
        }
    }

    /// The tick in the current interval.
    #[inline(always)]
    fn k(&self) -> f32 {
        self.tick as f32
    }

    /// On to the next tick: into the next interval at its end, but past the last one.
    #[inline(always)]
    fn advance(&mut self, light: &KeyLight) {
        self.tick += 1;
        if self.tick >= light.step.max(1) as usize && self.interval + 2 < light.keys.len() {
            self.interval += 1;
            self.tick = 0;
            self.load(light);
        }
    }
}

/// The fast path's body, inlined into each instruction-set variant of [`simd`].
#[inline(always)]
fn ticks_blocked<const SUBTRACT: bool, P: Pack64>(
    packer: P,
    light: KeyLight,
    k0: u32,
    phi: f32,
    px: PixelState,
    planes: &mut [u8],
) {
    let n = px.acc.len();
    let per = n.div_ceil(8);
    if per == 0 {
        return;
    }
    let n_ticks = planes.len() / per;
    let whole = n / BLOCK * BLOCK;
    let (acc, acc_tail) = px.acc.split_at_mut(whole);
    let (since, since_tail) = px.since.split_at_mut(whole);
    let blocks = acc
        .chunks_exact_mut(BLOCK)
        .zip(since.chunks_exact_mut(BLOCK))
        .zip(px.cap[..whole].chunks_exact(BLOCK));
    for (b, ((acc, since), cap)) in blocks.enumerate() {
        let mut bl = BlockLight::new(&light, b * BLOCK, k0 as usize);
        let mut a = [0f32; BLOCK];
        let mut s = [0u32; BLOCK];
        a.copy_from_slice(acc);
        s.copy_from_slice(since);
        let byte0 = b * (BLOCK / 8);
        for t in 0..n_ticks {
            let k = bl.k();
            let (base, slope) = (&bl.base, &bl.slope);
            let mut flags = [0u8; BLOCK];
            for j in 0..BLOCK {
                let x = a[j] + (base[j] + slope[j] * k);
                let si = s[j].saturating_add(1);
                let over = x >= phi;
                let fire = over | (si >= cap[j]);
                let reset_to = if SUBTRACT { below(x - phi, phi) } else { 0.0 };
                a[j] = if over {
                    reset_to
                } else if fire {
                    0.0
                } else {
                    x
                };
                s[j] = if fire { 0 } else { si };
                flags[j] = u8::from(fire);
            }
            planes[t * per + byte0..][..BLOCK / 8]
                .copy_from_slice(&packer.pack64(&flags).to_le_bytes());
            bl.advance(&light);
        }
        acc.copy_from_slice(&a);
        since.copy_from_slice(&s);
    }
    if whole < n {
        let reset = if SUBTRACT {
            Reset::Subtract
        } else {
            Reset::Zero
        };
        for t in 0..n_ticks {
            let light = light.tick(k0 as usize + t, whole);
            let px = PixelState {
                acc: &mut *acc_tail,
                since: &mut *since_tail,
                cap: &px.cap[whole..],
            };
            integrate_tick_reference(
                light,
                phi,
                reset,
                px,
                &mut planes[t * per + whole / 8..][..per - whole / 8],
            );
        }
    }
}

pub use neuspike_simd::Isa;
use neuspike_simd::bits::{Pack64, Packer};

pub mod playback;
pub mod truth;

/// [`integrate_ticks`] compiled for a chosen instruction set (for tests and benchmarks); the
/// widest one below it that the CPU supports runs.
pub fn integrate_ticks_with(
    isa: Isa,
    light: KeyLight,
    k0: u32,
    phi: f32,
    reset: Reset,
    px: PixelState,
    planes: &mut [u8],
) {
    // One variant per instruction set, each with its own way of packing the fire flags.
    #[inline(always)]
    fn on<P: Pack64>(
        packer: P,
        isa: Isa,
        args: (KeyLight, u32, f32, Reset, PixelState, &mut [u8]),
    ) {
        let (light, k0, phi, reset, px, planes) = args;
        neuspike_simd::with_isa(
            isa,
            #[inline(always)]
            || match reset {
                Reset::Subtract => ticks_blocked::<true, P>(packer, light, k0, phi, px, planes),
                Reset::Zero => ticks_blocked::<false, P>(packer, light, k0, phi, px, planes),
            },
        );
    }
    let packer = Packer::new(isa);
    let args = (light, k0, phi, reset, px, planes);
    match packer {
        Packer::Avx512(p) => on(p, packer.isa(), args),
        Packer::Avx2(p) => on(p, packer.isa(), args),
        Packer::Scalar(p) => on(p, packer.isa(), args),
    }
}

/// The per-interval noise the noisy kernels draw: each pixel's threshold for its current
/// interval, redrawn at each fire from its generator, and the light lost after a fire.
#[derive(Debug)]
pub struct FireNoise<'a> {
    /// Relative standard deviation of an interval's threshold ([`Noise::fire_sigma`], at most
    /// [`noise::MAX_FIRE_SIGMA`]).
    pub sigma: f32,
    /// Light lost after a fire, in ticks of the pixel's light (< 1).
    pub reset_delay: f32,
    /// Each pixel's threshold for its current interval.
    pub thr: &'a mut [f32],
    /// Each pixel's generator state ([`lcg_step`]), advanced every tick.
    pub rng: &'a mut [u32],
}

/// One step of the per-pixel generator: the 32-bit linear congruential generator of Numerical
/// Recipes (`r 1664525 + 1013904223` modulo `2^32`, full period). Only its top 16 bits are drawn
/// from, whose periods are `2^24` and more; two vector instructions a step, where xorshift32
/// takes six.
#[inline(always)]
pub fn lcg_step(r: u32) -> u32 {
    r.wrapping_mul(1_664_525).wrapping_add(1_013_904_223)
}

/// The threshold a draw gives: `phi + (u1 + u2 - 255) scale`, the top two bytes of `r` as two
/// uniforms (a triangular draw; one fused multiply-add, so one rounding).
#[inline(always)]
fn drawn_threshold(r: u32, scale: f32, offset: f32) -> f32 {
    let tri = ((r >> 24) + ((r >> 16) & 0xff)) as f32;
    tri.mul_add(scale, offset)
}

/// The constant term of [`drawn_threshold`]: `phi - 255 scale`.
#[inline(always)]
fn draw_offset(phi: f32, scale: f32) -> f32 {
    (-255.0f32).mul_add(scale, phi)
}

/// The scale of a draw: `sigma phi / TRIANGLE_STD`.
#[inline(always)]
fn draw_scale(sigma: f32, phi: f32) -> f32 {
    sigma * phi / noise::TRIANGLE_STD
}

/// One tick of every pixel with per-interval noise, the plain loop (the oracle of
/// [`integrate_ticks_noisy`]): every pixel's generator steps; a pixel fires at `acc >= thr` (its
/// interval's threshold) or at its ISI cap, and then takes the drawn threshold for its next
/// interval; the subtracting reset keeps `acc - thr` less the light of the reset delay, at
/// least 0 and below the next threshold.
pub fn integrate_tick_noisy_reference(
    light: TickLight,
    phi: f32,
    reset: Reset,
    px: PixelState,
    fire: FireNoise,
    plane: &mut [u8],
) {
    let scale = draw_scale(fire.sigma, phi);
    let offset = draw_offset(phi, scale);
    for i in 0..px.acc.len() {
        let l = light.at(i);
        let a = px.acc[i] + l;
        let s = px.since[i].wrapping_add(1);
        let r = lcg_step(fire.rng[i]);
        fire.rng[i] = r;
        let next = drawn_threshold(r, scale, offset);
        let thr = fire.thr[i];
        let fired = a >= thr || s >= px.cap[i];
        // A fire at the cap has `a < thr`, so the subtracting reset empties the accumulator
        // (the light is never negative).
        px.acc[i] = match (fired, reset) {
            (false, _) => a,
            (true, Reset::Subtract) => {
                below(above((-fire.reset_delay).mul_add(l, a - thr), 0.0), next)
            }
            (true, Reset::Zero) => 0.0,
        };
        px.since[i] = if fired { 0 } else { s };
        if fired {
            fire.thr[i] = next;
            plane[i >> 3] |= 1 << (i & 7);
        }
    }
}

/// Consecutive ticks of one key interval with [`integrate_tick_noisy_reference`] (the oracle of
/// [`integrate_ticks_noisy`]).
pub fn integrate_ticks_noisy_reference(
    light: KeyLight,
    k0: u32,
    phi: f32,
    reset: Reset,
    px: PixelState,
    fire: FireNoise,
    planes: &mut [u8],
) {
    let per = px.acc.len().div_ceil(8);
    for (t, plane) in planes.chunks_exact_mut(per.max(1)).enumerate() {
        let light = light.tick(k0 as usize + t, 0);
        let px = PixelState {
            acc: &mut *px.acc,
            since: &mut *px.since,
            cap: px.cap,
        };
        let fire = FireNoise {
            sigma: fire.sigma,
            reset_delay: fire.reset_delay,
            thr: &mut *fire.thr,
            rng: &mut *fire.rng,
        };
        integrate_tick_noisy_reference(light, phi, reset, px, fire, plane);
    }
}

/// [`integrate_ticks_noisy_reference`], fast: equal to it bit for bit (tested), blocked and
/// vectorised as [`integrate_ticks`] is.
pub fn integrate_ticks_noisy(
    light: KeyLight,
    k0: u32,
    phi: f32,
    reset: Reset,
    px: PixelState,
    fire: FireNoise,
    planes: &mut [u8],
) {
    integrate_ticks_noisy_with(
        neuspike_simd::detect(),
        light,
        k0,
        phi,
        reset,
        px,
        fire,
        planes,
    );
}

/// [`integrate_ticks_noisy`] compiled for a chosen instruction set (tests and benchmarks).
#[allow(clippy::too_many_arguments)]
pub fn integrate_ticks_noisy_with(
    isa: Isa,
    light: KeyLight,
    k0: u32,
    phi: f32,
    reset: Reset,
    px: PixelState,
    fire: FireNoise,
    planes: &mut [u8],
) {
    #[inline(always)]
    fn on<P: Pack64>(
        packer: P,
        isa: Isa,
        args: (KeyLight, u32, f32, Reset, PixelState, FireNoise, &mut [u8]),
    ) {
        let (light, k0, phi, reset, px, fire, planes) = args;
        neuspike_simd::with_isa(
            isa,
            #[inline(always)]
            || match reset {
                Reset::Subtract => {
                    noisy_blocked::<true, P>(packer, light, k0, phi, px, fire, planes)
                }
                Reset::Zero => noisy_blocked::<false, P>(packer, light, k0, phi, px, fire, planes),
            },
        );
    }
    let packer = Packer::new(isa);
    let args = (light, k0, phi, reset, px, fire, planes);
    match packer {
        Packer::Avx512(p) => on(p, packer.isa(), args),
        Packer::Avx2(p) => on(p, packer.isa(), args),
        Packer::Scalar(p) => on(p, packer.isa(), args),
    }
}

/// The noisy fast path's body (see [`ticks_blocked`]).
#[inline(always)]
fn noisy_blocked<const SUBTRACT: bool, P: Pack64>(
    packer: P,
    light: KeyLight,
    k0: u32,
    phi: f32,
    px: PixelState,
    fire: FireNoise,
    planes: &mut [u8],
) {
    let n = px.acc.len();
    let per = n.div_ceil(8);
    if per == 0 {
        return;
    }
    let n_ticks = planes.len() / per;
    let scale = draw_scale(fire.sigma, phi);
    let offset = draw_offset(phi, scale);
    let delay = fire.reset_delay;
    let whole = n / BLOCK * BLOCK;
    let (acc, acc_tail) = px.acc.split_at_mut(whole);
    let (since, since_tail) = px.since.split_at_mut(whole);
    let (thr, thr_tail) = fire.thr.split_at_mut(whole);
    let (rng, rng_tail) = fire.rng.split_at_mut(whole);
    let blocks = acc
        .chunks_exact_mut(BLOCK)
        .zip(since.chunks_exact_mut(BLOCK))
        .zip(px.cap[..whole].chunks_exact(BLOCK))
        .zip(thr.chunks_exact_mut(BLOCK))
        .zip(rng.chunks_exact_mut(BLOCK));
    for (b, ((((acc, since), cap), thr), rng)) in blocks.enumerate() {
        let mut bl = BlockLight::new(&light, b * BLOCK, k0 as usize);
        let mut a = [0f32; BLOCK];
        let mut s = [0u32; BLOCK];
        let mut th = [0f32; BLOCK];
        let mut r = [0u32; BLOCK];
        a.copy_from_slice(acc);
        s.copy_from_slice(since);
        th.copy_from_slice(thr);
        r.copy_from_slice(rng);
        let byte0 = b * (BLOCK / 8);
        for t in 0..n_ticks {
            let k = bl.k();
            let (base, slope) = (&bl.base, &bl.slope);
            let mut flags = [0u8; BLOCK];
            // The new accumulators and thresholds go to fresh arrays: a select written back to
            // the array it read from becomes a masked store, which keeps the array in memory.
            let mut a_next = [0f32; BLOCK];
            let mut th_next = [0f32; BLOCK];
            for j in 0..BLOCK {
                let l = base[j] + slope[j] * k;
                let x = a[j] + l;
                let si = s[j].wrapping_add(1);
                let rj = lcg_step(r[j]);
                r[j] = rj;
                let next = drawn_threshold(rj, scale, offset);
                let fired = (x >= th[j]) | (si >= cap[j]);
                let reset_to = if SUBTRACT {
                    below(above((-delay).mul_add(l, x - th[j]), 0.0), next)
                } else {
                    0.0
                };
                a_next[j] = if fired { reset_to } else { x };
                th_next[j] = if fired { next } else { th[j] };
                s[j] = if fired { 0 } else { si };
                flags[j] = u8::from(fired);
            }
            a = a_next;
            th = th_next;
            planes[t * per + byte0..][..BLOCK / 8]
                .copy_from_slice(&packer.pack64(&flags).to_le_bytes());
            bl.advance(&light);
        }
        acc.copy_from_slice(&a);
        since.copy_from_slice(&s);
        thr.copy_from_slice(&th);
        rng.copy_from_slice(&r);
    }
    if whole < n {
        let reset = if SUBTRACT {
            Reset::Subtract
        } else {
            Reset::Zero
        };
        for t in 0..n_ticks {
            let light = light.tick(k0 as usize + t, whole);
            let px = PixelState {
                acc: &mut *acc_tail,
                since: &mut *since_tail,
                cap: &px.cap[whole..],
            };
            let fire = FireNoise {
                sigma: fire.sigma,
                reset_delay: delay,
                thr: &mut *thr_tail,
                rng: &mut *rng_tail,
            };
            integrate_tick_noisy_reference(
                light,
                phi,
                reset,
                px,
                fire,
                &mut planes[t * per + whole / 8..][..per - whole / 8],
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array3;
    use neuspike_schemas::unpack_planes_into;

    #[test]
    fn a_clip_is_seen_frame_by_frame() {
        // Pixel 0 at 0.25 throughout; pixel 1 ramping from 0 by 0.05 a frame; a frame every 4
        // ticks.
        let period = 50_000;
        let frames = Array3::from_shape_fn(
            (12, 1, 2),
            |(k, _, c)| {
                if c == 0 { 0.25 } else { 0.05 * k as f32 }
            },
        );
        let clip = neuspike_scene::Clip::new(frames, 4 * period, "test").expect("clip");
        let scene = Scene::from_clip(clip, 1.0).expect("scene");
        let cfg = CameraConfig {
            width: 2,
            height: 1,
            random_init: false,
            fpn_cap: false,
            ..CameraConfig::default()
        };
        let mut cam = SpikeCamera::new(scene, cfg).expect("camera");
        // The automatic step renders once a frame, not every 64 ticks of a scene without motion.
        assert_eq!(cam.render_step(), 4);
        let chunk = cam.next_chunk(41, 0);
        let mut p = Array3::<u8>::zeros((41, 1, 2));
        unpack_planes_into(&chunk.bits, p.view_mut());
        let fired = |c: usize| -> Vec<usize> { (0..41).filter(|&k| p[[k, 0, c]] == 1).collect() };
        // 0.25 a tick from 0 fires every fourth tick, exactly (plane `i` is tick `i`, which
        // sees the light at `(i - 1/2) T`; tick 0 the first frame's).
        assert_eq!(fired(0), (1..=10).map(|i| 4 * i - 1).collect::<Vec<_>>());
        // The ramp: tick k sees 0.0125 (k - 1/2) (its middle, linear between frames), so the
        // charge after tick k is 0.0125 k^2 / 2 (first spike at k = 13); 10 in all by tick
        // 40, give or take the rounding at the 10th.
        let ramp = fired(1);
        assert_eq!(ramp.first(), Some(&13), "{ramp:?}");
        assert!((9..=10).contains(&ramp.len()), "{ramp:?}");
        // Ground truth reads the frames, linear between them.
        let gt = cam.ground_truth(6);
        let t = cam.plane_time_ns(6) as f32 / (4 * period) as f32;
        assert!((gt[[0, 1]] - 0.05 * t).abs() < 1e-6, "{gt:?}");
    }

    fn flat_scene(lum: f32, light_scale: f64) -> Scene {
        // A checkerboard with huge squares is one flat grey level over a small view.
        let yaml = format!(
            "width: 8\nheight: 4\nduration_ms: 10\nlight_scale: {light_scale}\nsamples_per_pixel: 1\n\
             texture:\n  kind: checkerboard\n  square_px: 64\n  contrast: 0.0\n  min: 0.01\n"
        );
        let s = Scene::from_yaml_str(&yaml, "test", None).expect("scene");
        let v = s.render(0, 1, 1)[[0, 0]];
        assert!(
            (v - 0.5).abs() < 1e-6 || lum < 0.0,
            "flat scene renders {v}"
        );
        s
    }

    fn quiet(w: usize, h: usize) -> CameraConfig {
        CameraConfig {
            width: w,
            height: h,
            random_init: false,
            fpn_cap: false,
            ..Default::default()
        }
    }

    fn planes(chunk: &SpikeChunk) -> Array3<u8> {
        let mut p = Array3::zeros((chunk.n_planes, chunk.height, chunk.width));
        unpack_planes_into(&chunk.bits, p.view_mut());
        p
    }

    #[test]
    fn half_grey_fires_every_second_tick() {
        let mut cam = SpikeCamera::new(flat_scene(0.5, 1.0), quiet(8, 4)).unwrap();
        let chunk = cam.next_chunk(100, 0);
        let p = planes(&chunk);
        // acc: 0.5, 1.0 -> fire at ticks 1, 3, 5, ...
        for k in 0..100 {
            assert_eq!(p[[k, 2, 3]], (k % 2) as u8, "tick {k}");
        }
        assert!((cam.lum_per_rate() - 1.0).abs() < 1e-12);
        assert_eq!(chunk.t_first_ns, 0);
        assert_eq!(chunk.plane_period_ns, 50_000);
    }

    #[test]
    fn tfp_rate_recovers_luminance_in_the_dark() {
        let mut cam = SpikeCamera::new(flat_scene(0.5, 0.05), quiet(8, 4)).unwrap();
        let p = planes(&cam.next_chunk(4000, 0));
        let rate = p.iter().map(|&v| f64::from(v)).sum::<f64>() / p.len() as f64;
        // rate * phi / light_scale == luminance
        assert!(
            (rate * cam.lum_per_rate() - 0.5).abs() < 0.01,
            "rate {rate}"
        );
    }

    #[test]
    fn saturating_light_fires_every_tick_and_stays_bounded() {
        let mut cam = SpikeCamera::new(flat_scene(0.5, 1000.0), quiet(8, 4)).unwrap();
        let p = planes(&cam.next_chunk(500, 0));
        assert!(p.iter().all(|&v| v == 1));
        assert!(cam.acc.iter().all(|a| a.is_finite() && *a < 2.0 * cam.phi));
    }

    #[test]
    fn fpn_cap_fires_dark_pixels() {
        let mut cfg = quiet(8, 4);
        cfg.fpn_cap = true;
        cfg.fpn_mu = 10.0;
        cfg.fpn_sigma = 0.0;
        let mut cam = SpikeCamera::new(flat_scene(0.5, 1e-9), cfg).unwrap();
        let p = planes(&cam.next_chunk(100, 0));
        // Every pixel fires exactly every 10 ticks.
        let per_pixel = p.sum_axis(ndarray::Axis(0));
        assert!(per_pixel.iter().all(|&n| n == 10), "{per_pixel:?}");
    }

    #[test]
    fn deterministic_for_a_seed() {
        let cfg = CameraConfig {
            width: 8,
            height: 4,
            seed: 3,
            ..Default::default()
        };
        let a = SpikeCamera::new(flat_scene(0.5, 0.3), cfg.clone())
            .unwrap()
            .next_chunk(50, 0);
        let b = SpikeCamera::new(flat_scene(0.5, 0.3), cfg.clone())
            .unwrap()
            .next_chunk(50, 0);
        assert_eq!(a, b);
        let c = SpikeCamera::new(flat_scene(0.5, 0.3), CameraConfig { seed: 4, ..cfg })
            .unwrap()
            .next_chunk(50, 0);
        assert_ne!(a.bits, c.bits);
    }

    #[test]
    fn bad_settings_name_the_key() {
        let cfg = CameraConfig {
            rate_hz: -1.0,
            ..Default::default()
        };
        let e = SpikeCamera::new(flat_scene(0.5, 1.0), cfg)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("rate-hz") && e.contains("-1"), "{e}");
        // A sensor beyond the pixel limit is refused before anything is allocated.
        let cfg = CameraConfig {
            width: 65_535,
            height: 65_535,
            ..Default::default()
        };
        let e = SpikeCamera::new(flat_scene(0.5, 1.0), cfg)
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
        fn fast_kernel_equals_reference_on_every_isa(
            n in 1usize..700,
            ticks in 1usize..24,
            seed in proptest::prelude::any::<u64>(),
            k0 in 0u32..16,
            subtract in proptest::prelude::any::<bool>(),
            step in 1u32..12,
        ) {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let start: Vec<f32> = (0..n).map(|_| rng.random::<f32>() * 1.5).collect();
            let end: Vec<f32> = start.iter().map(|&a| a + (rng.random::<f32>() - 0.5) * 0.8).collect();
            let mid: Vec<f32> = (0..n).map(|_| rng.random::<f32>() * 1.5).collect();
            let acc0: Vec<f32> = (0..n).map(|_| rng.random::<f32>() * 2.0).collect();
            let since0: Vec<u32> = (0..n).map(|_| rng.random_range(0..20)).collect();
            let cap: Vec<u32> = (0..n).map(|_| rng.random_range(1..25)).collect();
            let reset = if subtract { Reset::Subtract } else { Reset::Zero };
            let light = KeyLight { keys: &[&start, &end, &mid, &start], step };
            let per = n.div_ceil(8);
            let (mut a1, mut s1, mut p1) = (acc0.clone(), since0.clone(), vec![0u8; per * ticks]);
            integrate_ticks_reference(light, k0, 1.0, reset, PixelState { acc: &mut a1, since: &mut s1, cap: &cap }, &mut p1);
            for isa in Isa::ALL {
                let (mut a2, mut s2, mut p2) = (acc0.clone(), since0.clone(), vec![0u8; per * ticks]);
                integrate_ticks_with(isa, light, k0, 1.0, reset, PixelState { acc: &mut a2, since: &mut s2, cap: &cap }, &mut p2);
                proptest::prop_assert_eq!(&p1, &p2, "{:?}", isa);
                proptest::prop_assert_eq!(&s1, &s2, "{:?}", isa);
                proptest::prop_assert_eq!(a1.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), a2.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), "{:?}", isa);
            }
        }
    }

    proptest::proptest! {
        #[test]
        fn noisy_kernel_equals_its_reference_on_every_isa(
            n in 1usize..700,
            ticks in 1usize..24,
            seed in proptest::prelude::any::<u64>(),
            k0 in 0u32..16,
            subtract in proptest::prelude::any::<bool>(),
            sigma in 0.0f32..0.4,
            delay in 0.0f32..0.9,
            step in 1u32..12,
        ) {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let start: Vec<f32> = (0..n).map(|_| rng.random::<f32>() * 1.5).collect();
            let end: Vec<f32> = start.iter().map(|&a| a + (rng.random::<f32>() - 0.5) * 0.8).collect();
            let mid: Vec<f32> = (0..n).map(|_| rng.random::<f32>() * 1.5).collect();
            let acc0: Vec<f32> = (0..n).map(|_| rng.random::<f32>() * 2.0).collect();
            let since0: Vec<u32> = (0..n).map(|_| rng.random_range(0..20)).collect();
            let cap: Vec<u32> = (0..n).map(|_| rng.random_range(1..25)).collect();
            let thr0: Vec<f32> = (0..n).map(|_| 0.5 + rng.random::<f32>()).collect();
            let rng0: Vec<u32> = (0..n).map(|_| rng.random::<u32>() | 1).collect();
            let reset = if subtract { Reset::Subtract } else { Reset::Zero };
            let light = KeyLight { keys: &[&start, &end, &mid, &start], step };
            let per = n.div_ceil(8);
            let run = |isa: Option<Isa>| {
                let (mut a, mut s, mut th, mut r, mut p) =
                    (acc0.clone(), since0.clone(), thr0.clone(), rng0.clone(), vec![0u8; per * ticks]);
                let px = PixelState { acc: &mut a, since: &mut s, cap: &cap };
                let fire = FireNoise { sigma, reset_delay: delay, thr: &mut th, rng: &mut r };
                match isa {
                    Some(isa) => integrate_ticks_noisy_with(isa, light, k0, 1.0, reset, px, fire, &mut p),
                    None => integrate_ticks_noisy_reference(light, k0, 1.0, reset, px, fire, &mut p),
                }
                (p, s, r, a.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), th.iter().map(|v| v.to_bits()).collect::<Vec<_>>())
            };
            let want = run(None);
            for isa in Isa::ALL {
                proptest::prop_assert_eq!(&want, &run(Some(isa)), "{:?}", isa);
            }
        }
    }

    #[test]
    fn the_noisy_kernel_without_noise_is_the_papers_kernel() {
        let n = 300;
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let start: Vec<f32> = (0..n).map(|_| rng.random::<f32>() * 1.2).collect();
        let end: Vec<f32> = start
            .iter()
            .map(|&a| a + (rng.random::<f32>() - 0.5) * 2.0)
            .collect();
        let cap: Vec<u32> = (0..n).map(|_| rng.random_range(5..40)).collect();
        let light = KeyLight {
            keys: &[&start, &end, &start],
            step: 100,
        };
        let ticks = 200;
        let (mut a1, mut s1, mut p1) = (vec![0.0f32; n], vec![0u32; n], vec![0u8; 38 * ticks]);
        integrate_ticks(
            light,
            0,
            1.0,
            Reset::Subtract,
            PixelState {
                acc: &mut a1,
                since: &mut s1,
                cap: &cap,
            },
            &mut p1,
        );
        let (mut a2, mut s2, mut p2) = (vec![0.0f32; n], vec![0u32; n], vec![0u8; 38 * ticks]);
        let (mut th, mut r) = (vec![1.0f32; n], vec![7u32; n]);
        let fire = FireNoise {
            sigma: 0.0,
            reset_delay: 0.0,
            thr: &mut th,
            rng: &mut r,
        };
        integrate_ticks_noisy(
            light,
            0,
            1.0,
            Reset::Subtract,
            PixelState {
                acc: &mut a2,
                since: &mut s2,
                cap: &cap,
            },
            fire,
            &mut p2,
        );
        assert_eq!(p1, p2);
        assert_eq!(a1, a2);
    }

    /// A flat scene seen by a camera with only `noise` on (no random start, no cap), `ticks`
    /// planes: every pixel's spike times.
    fn spike_times(light: f64, noise: Noise, ticks: usize) -> Vec<Vec<usize>> {
        let cfg = CameraConfig {
            noise: NoiseArgs::from(noise),
            seed: 11,
            ..quiet(32, 8)
        };
        let mut cam = SpikeCamera::new(flat_scene(0.5, light), cfg).unwrap();
        let p = planes(&cam.next_chunk(ticks, 0));
        let mut out = vec![Vec::new(); 32 * 8];
        for ((k, y, x), &v) in p.indexed_iter() {
            if v == 1 {
                out[y * 32 + x].push(k);
            }
        }
        out
    }

    fn isi_cv(times: &[Vec<usize>]) -> (f64, f64) {
        let isis: Vec<f64> = times
            .iter()
            .flat_map(|t| t.windows(2).map(|w| (w[1] - w[0]) as f64))
            .collect();
        let mean = isis.iter().sum::<f64>() / isis.len() as f64;
        let var = isis.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / isis.len() as f64;
        (mean, var.sqrt() / mean)
    }

    #[test]
    fn shot_noise_and_jitter_spread_the_interval_by_their_combined_sigma() {
        // 0.025 phi a tick (light 0.05 x luminance 0.5): intervals of 40 ticks, quantisation
        // adds at most 1/40 to the spread.
        let (mean, cv) = isi_cv(&spike_times(0.05, Noise::OFF, 20_000));
        assert!((mean - 40.0).abs() < 0.1 && cv < 0.01, "{mean} {cv}");
        let noise = Noise {
            electrons_per_phi: 400.0,
            threshold_jitter: 0.08,
            ..Noise::OFF
        };
        let want = (0.08f64 * 0.08 + 1.0 / 400.0).sqrt();
        assert!((noise.fire_sigma() - want).abs() < 1e-12);
        let (mean, cv) = isi_cv(&spike_times(0.05, noise, 20_000));
        assert!((mean - 40.0).abs() < 0.5, "mean {mean}");
        assert!((cv - want).abs() < 0.1 * want, "cv {cv}, sigma {want}");
    }

    #[test]
    fn gain_offset_dark_current_and_reset_delay_do_what_they_say() {
        let rate = |t: &Vec<usize>, ticks: usize| t.len() as f64 / ticks as f64;
        // PRNU: the spread of per-pixel rates on flat light is the gain's.
        let ticks = 4_000;
        let t = spike_times(
            1.0,
            Noise {
                prnu: 0.1,
                ..Noise::OFF
            },
            ticks,
        );
        let r: Vec<f64> = t.iter().map(|t| rate(t, ticks)).collect();
        let mean = r.iter().sum::<f64>() / r.len() as f64;
        let sd = (r.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / r.len() as f64).sqrt();
        assert!(
            (mean - 0.5).abs() < 0.02 && (sd / mean - 0.1).abs() < 0.03,
            "{mean} {sd}"
        );
        // Threshold offset: the rate goes as 1 / (1 + o).
        let t = spike_times(
            1.0,
            Noise {
                threshold_offset: 0.1,
                ..Noise::OFF
            },
            ticks,
        );
        let r: Vec<f64> = t.iter().map(|t| rate(t, ticks)).collect();
        let mean = r.iter().sum::<f64>() / r.len() as f64;
        let sd = (r.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / r.len() as f64).sqrt();
        assert!((sd / mean - 0.1).abs() < 0.03, "{mean} {sd}");
        // Dark current: in the dark, pixels fire at the dark rate on average (log-normal spread).
        let ticks = 40_000;
        let noise = Noise {
            dark_current_hz: 200.0,
            dark_current_spread: 0.3,
            ..Noise::OFF
        };
        let t = spike_times(1e-9, noise, ticks);
        let hz: Vec<f64> = t.iter().map(|t| rate(t, ticks) * 20_000.0).collect();
        let mean = hz.iter().sum::<f64>() / hz.len() as f64;
        assert!((mean - 200.0).abs() < 20.0, "dark {mean} Hz");
        assert!(
            hz.iter().any(|&h| h < 170.0) && hz.iter().any(|&h| h > 230.0),
            "{hz:?}"
        );
        // Reset delay: bright light loses `r` ticks of light per interval: rate l / (phi + r l).
        let ticks = 10_000;
        let t = spike_times(
            0.8,
            Noise {
                reset_delay_ticks: 0.5,
                ..Noise::OFF
            },
            ticks,
        );
        let r = rate(&t[0], ticks);
        let want = 0.4 / (1.0 + 0.5 * 0.4);
        assert!((r - want).abs() < 0.01, "rate {r}, want {want}");
    }

    #[test]
    fn random_spikes_come_at_their_rate_anywhere_and_leave_the_rest_as_it_was() {
        let cfg = |hz: f64| CameraConfig {
            noise: NoiseArgs {
                random_spike_hz: Some(hz),
                ..NoiseArgs::default()
            },
            ..quiet(32, 16)
        };
        // In the dark, every spike is a random one: 200 Hz at 20 kHz is 1 % of pixel-ticks.
        let mut cam = SpikeCamera::new(flat_scene(0.5, 1e-9), cfg(200.0)).unwrap();
        let p = planes(&cam.next_chunk(4_000, 0));
        let rate = p.iter().map(|&v| f64::from(v)).sum::<f64>() / p.len() as f64;
        assert!((rate - 0.01).abs() < 0.001, "rate {rate}");
        // Spread over the pixels: every one has some.
        let per_pixel = p.sum_axis(ndarray::Axis(0));
        assert!(per_pixel.iter().all(|&n| n > 0), "{per_pixel:?}");
        // The same spikes whichever way the planes are cut into chunks.
        let mut again = SpikeCamera::new(flat_scene(0.5, 1e-9), cfg(200.0)).unwrap();
        let mut cut = Vec::new();
        for n in [1, 999, 3_000] {
            cut.extend(planes(&again.next_chunk(n, 0)));
        }
        assert_eq!(cut, p.iter().copied().collect::<Vec<_>>());
        // Under light, the pixel's own spikes are those of the camera without the term, plus
        // spikes read at random (an OR: the charge is left as it was).
        let lit = |hz| {
            let mut cam = SpikeCamera::new(flat_scene(0.5, 0.3), cfg(hz)).unwrap();
            planes(&cam.next_chunk(2_000, 0))
        };
        let (clean, noisy) = (lit(0.0), lit(400.0));
        assert!(clean.iter().zip(&noisy).all(|(&c, &n)| n >= c));
        let count = |p: &Array3<u8>| p.iter().map(|&v| u64::from(v)).sum::<u64>();
        let extra = (count(&noisy) - count(&clean)) as f64 / clean.len() as f64;
        // 2 % of pixel-ticks, less those that fired anyway (15 % of them).
        assert!((extra - 0.02 * 0.85).abs() < 0.003, "extra {extra}");
        // At or above the plane rate the term is refused by name.
        let e = SpikeCamera::new(flat_scene(0.5, 0.3), cfg(20_000.0))
            .err()
            .expect("refused");
        assert!(e.to_string().contains("random-spike-hz"), "{e}");
    }

    #[test]
    fn static_scene_renders_once_and_moving_scene_follows_motion() {
        // A static scene keeps the light of its first render; the camera output over a chunk that
        // spans many key intervals equals one with a render every tick.
        let s = Scene::load("bright-static").unwrap();
        assert!(s.is_static());
        let cfg = CameraConfig {
            width: 40,
            height: 25,
            ..Default::default()
        };
        let a = SpikeCamera::new(s.clone(), cfg.clone())
            .unwrap()
            .next_chunk(100, 0);
        let b = SpikeCamera::new(
            s,
            CameraConfig {
                render_step_ticks: 1,
                ..cfg.clone()
            },
        )
        .unwrap()
        .next_chunk(100, 0);
        assert_eq!(a.bits, b.bits);
        assert!(!Scene::load("bright-slow").unwrap().is_static());
    }

    /// `bright-fast` (2,000 px/s while turning 90 deg/s) seen with renders every 64 ticks and the
    /// images between moved along the motion, against a camera that renders every image: TFP over
    /// 33 planes scores within half a decibel of it against the truth.
    #[test]
    fn a_warped_camera_sees_a_fast_scene_as_a_rendering_one_does() {
        let s = Scene::load("bright-fast").unwrap();
        let run = |warp_step_ticks: u32| {
            let mut cam = SpikeCamera::new(
                s.clone(),
                CameraConfig {
                    warp_step_ticks,
                    ..Default::default()
                },
            )
            .unwrap();
            let p = planes(&cam.next_chunk(330, 0));
            let mut psnr = 0.0;
            for w in 0..10 {
                let win = p.slice(ndarray::s![33 * w..33 * (w + 1), .., ..]);
                let rate = win.mapv(f64::from).sum_axis(ndarray::Axis(0)) / 33.0;
                let truth = cam.ground_truth(33 * w as u64 + 17);
                let mse = rate
                    .iter()
                    .zip(truth.iter())
                    .map(|(r, t)| ((r * cam.lum_per_rate()).min(1.0) - f64::from(*t)).powi(2))
                    .sum::<f64>()
                    / truth.len() as f64;
                psnr += 10.0 * (1.0 / mse).log10() / 10.0;
            }
            (psnr, cam.render_step(), cam.warp_step())
        };
        let (plain, plain_step, none) = run(1);
        let (warped, step, warp) = run(64);
        eprintln!("TFP-33 PSNR: warped {warped:.2} dB, rendering {plain:.2} dB");
        assert_eq!((plain_step, none), (2, None));
        assert_eq!((step, warp), (4, Some(64)));
        // The moved images' light error (about 36 dB PSNR per tick) adds to TFP's: 0.3 dB here.
        assert!(
            (warped - plain).abs() < 0.5,
            "TFP-33 PSNR: warped {warped:.2} dB, rendering {plain:.2} dB"
        );
    }

    #[test]
    fn consecutive_chunks_continue_the_clock() {
        let mut cam = SpikeCamera::new(flat_scene(0.5, 1.0), quiet(8, 4)).unwrap();
        let a = cam.next_chunk(20, 0);
        let b = cam.next_chunk(20, 1);
        assert_eq!(b.first_plane, 20);
        assert_eq!(b.t_first_ns, a.t_first_ns + 20 * a.plane_period_ns);
    }

    /// Spike counts over 10^8 ticks (83 minutes of a 20 kHz camera) against exact arithmetic:
    /// with the subtracting reset the f32 accumulator stays in [0, phi) and its rounding does not
    /// accumulate: every pixel, from 1e-6 to 1 phi of light per tick (six decades), ends within
    /// `1 + 1e-7 * count` spikes of `floor(ticks * light / phi)` (measured: at most 2 spikes, at
    /// 2/3 phi, out of 66.7 million). About 4 s in release.
    #[test]
    fn hundred_million_ticks_do_not_drift() {
        const TICKS: u64 = 100_000_000;
        const RUN: usize = 64;
        let levels: [f32; 8] = [0.3, 0.5, 2.0 / 3.0, 0.123_456_7, 0.999_9, 1e-2, 1e-3, 1e-6];
        // 64 pixels (one fast-path block): pixel i gets levels[i % 8].
        let light: Vec<f32> = (0..BLOCK).map(|i| levels[i % 8]).collect();
        let mut acc = vec![0.0f32; BLOCK];
        let mut since = vec![0u32; BLOCK];
        let cap = vec![u32::MAX; BLOCK];
        let mut planes = vec![0u8; RUN * BLOCK / 8];
        let mut counts = vec![0u64; BLOCK];
        let mut t = 0;
        while t < TICKS {
            planes.fill(0);
            integrate_ticks(
                KeyLight {
                    keys: &[&light, &light],
                    step: 1,
                },
                0,
                1.0,
                Reset::Subtract,
                PixelState {
                    acc: &mut acc,
                    since: &mut since,
                    cap: &cap,
                },
                &mut planes,
            );
            for plane in planes.chunks_exact(BLOCK / 8) {
                for (i, c) in counts.iter_mut().enumerate() {
                    *c += u64::from((plane[i >> 3] >> (i & 7)) & 1);
                }
            }
            t += RUN as u64;
        }
        for (i, &l) in levels.iter().enumerate() {
            let exact = (TICKS as f64 * f64::from(l)).floor();
            let off = (counts[i] as f64 - exact).abs();
            assert!(
                off <= 1.0 + 1e-7 * exact,
                "light {l}: {} spikes, exact {exact}",
                counts[i]
            );
            assert!(acc[i].is_finite() && (0.0..1.0).contains(&acc[i]));
        }
    }

    /// A static scene whose light spans six decades across its width (a horizontal gain map
    /// over a flat texture), 64x4 pixels.
    fn hdr_scene() -> Scene {
        let yaml = "width: 64\nheight: 4\nduration_ms: 60000\nlight_scale: 0.001\n\
                    samples_per_pixel: 1\ntexture:\n  kind: checkerboard\n  square_px: 64\n  \
                    contrast: 0.0\n  min: 0.01\nlight:\n  gain_map:\n    kind: horizontal\n    \
                    decades: 6.0\n";
        Scene::from_yaml_str(yaml, "hdr test", None).expect("scene")
    }

    /// Six decades of light in one scene, with and without the fixed-pattern cap: over 10^6
    /// ticks every pixel's spike count matches a double-precision model of the same pixel to
    /// within one spike (plus 1e-6 relative), the accumulators stay finite and in [0, phi).
    #[test]
    fn six_decades_of_light_match_a_double_precision_model_with_and_without_the_cap() {
        const TICKS: usize = 1_000_000;
        const CHUNK: usize = 1000;
        for cap_on in [false, true] {
            let cfg = CameraConfig {
                width: 64,
                height: 4,
                random_init: false,
                fpn_cap: cap_on,
                seed: 5,
                ..Default::default()
            };
            let mut cam = SpikeCamera::new(hdr_scene(), cfg).unwrap();
            let light = cam.keys[0].clone();
            let cap = cam.cap.clone();
            let lo = light.iter().copied().fold(f32::INFINITY, f32::min);
            let hi = light.iter().copied().fold(0.0f32, f32::max);
            // Pixel centres sample 10^-3..10^3 of gain: 5.9 decades.
            assert!(lo > 0.0 && hi < 1.0 && hi / lo > 7e5, "light {lo}..{hi}");
            let mut counts = vec![0u64; light.len()];
            for _ in 0..TICKS / CHUNK {
                let chunk = cam.next_chunk(CHUNK, 0);
                for plane in chunk.bits.chunks_exact(light.len() / 8) {
                    for (i, c) in counts.iter_mut().enumerate() {
                        *c += u64::from((plane[i >> 3] >> (i & 7)) & 1);
                    }
                }
            }
            for (i, (&l, &got)) in light.iter().zip(&counts).enumerate() {
                let (mut acc, mut since, mut want) = (0.0f64, 0u32, 0u64);
                for _ in 0..TICKS {
                    acc += f64::from(l);
                    since = since.saturating_add(1);
                    if acc >= 1.0 {
                        acc = (acc - 1.0).min(1.0);
                        since = 0;
                        want += 1;
                    } else if since >= cap[i] {
                        acc = 0.0;
                        since = 0;
                        want += 1;
                    }
                }
                let off = (got as f64 - want as f64).abs();
                assert!(
                    off <= 1.0 + 1e-6 * want as f64,
                    "cap {cap_on}, pixel {i}, light {l}: {got} spikes, model {want}"
                );
                assert!(cam.acc[i].is_finite() && (0.0..1.0).contains(&cam.acc[i]));
            }
        }
    }
}
