//! Training and test sets for the learned reconstruction (NeuSpike-Net, paper Sec. 3.4), made
//! by the simulators: `neuspike dataset`.
//!
//! Every sample is a small scene (`size x size` pixels) seen through one aligned window of
//! `window_planes` spike planes around its reference plane `c = window_planes / 2`, exactly as
//! the graph's align and represent nodes see it:
//! - the **spike representation** (`channels`: 1 ISI + `channels - 1` raw planes) from the
//!   window's packed planes;
//! - the **event integration** (`channels` instants evenly spaced over the window's events
//!   `[t_first - T, t_last)`, Eq. 8 with `tau_ns`), from the events of a DVS of the same size
//!   and clock (pixel-registered);
//!
//!   both made by the graph's own align and represent stages, run in a chain on the two
//!   cameras' streams;
//! - the **ground truth**: scene luminance at `t_ref`, in `[0, 1]`, light scale not applied;
//! - the classical baselines the card compares with: TFP over the whole window and TFI, both
//!   calibrated to luminance with the sample's `lum_per_rate = phi / light_scale`.
//!
//! The grid is the paper's: 5 light scales x 5 motion speeds, `per_cell` samples each. Within a
//! cell a sample draws its texture (a procedural generator with its own seed, or a photograph
//! from `--textures`), the direction of motion, a small rotation, and the DVS thresholds, which
//! rise as light falls (`theta = 0.2 (1 + 0.25 ln(1 / light))`, jittered +-15% per polarity).
//! The spike camera keeps its noise: random initial accumulators and the fixed-pattern ISI cap.
//!
//! With `--clips` the scenes are real video instead: each sample a clip of frames at the tick
//! rate that `training/video.py` made around a real frame (the reference plane's time), seen by
//! the same cameras and stages; its truth that real frame, its speed the clip's own, its light the
//! grid's by index (sample `i` at `LIGHT_SCALES[i % 5]`).
//!
//! Train and test never share a texture: procedural seeds come from disjoint streams, the
//! parametric generators (grating, checkerboard) are used for training only, and photographs
//! come from folders the caller splits (training/prepare_textures.py does).
//!
//! Output (`out/`): shards of at most `shard` samples, `out/<shard:03>/{spike,events}.npy`
//! (`[n, channels, size, size]` float32) and `{truth,tfp,tfi}.npy` (`[n, size, size]`);
//! `samples.csv` (one row a sample: texture, light, speed, thresholds, `lum_per_rate`, whether the
//! scene is complex); `dataset.yml` (every setting, and the counts); with `--also`, one more
//! `<kind>.npy` a representation kind (`[n, bins, size, size]`: a voxel grid, an event stack or a
//! time surface for other networks). Deterministic for a seed.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use eyre::{WrapErr, bail, eyre};
use ndarray::{Array2, Array3, Axis};
use ndarray_npy::write_npy;
use neuspike_align::{AlignConfig, AlignStage};
use neuspike_event_camera::{DvsConfig, EventCamera};
use neuspike_reconstruction::{luminance_from_isi_into, luminance_from_rate_into};
use neuspike_representations::{RepresentConfig, RepresentStage, Representer};
use neuspike_scene::{Clip, Scene};

use crate::table::Table;

use neuspike_schemas::{AlignedWindow, EventBatch, Representation, RepresentationKind, SpikeChunk};
use neuspike_spike_camera::noise::{Noise, NoiseArgs};
use neuspike_spike_camera::{CameraConfig, SpikeCamera};
use neuspike_stage::{Chain, Msg, MsgType, Replay};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::sync::Mutex;

pub mod table;

/// The light scales of the grid (the spike camera's `phi` is 1: a pixel of luminance `L` fires
/// `L * light` times a tick on average).
pub const LIGHT_SCALES: [f64; 5] = [0.05, 0.1, 0.25, 0.5, 1.0];
/// The motion speeds of the grid, scene pixels per second (at 20 kHz, 8,000 px/s is 0.4 pixel
/// a plane: 13 pixels across a 33-plane window).
pub const SPEEDS_PX_S: [f64; 5] = [0.0, 300.0, 1_000.0, 3_000.0, 8_000.0];
/// A sample is *complex* when its light is at most this (dark)...
pub const COMPLEX_MAX_LIGHT: f64 = 0.1;
/// ... or its speed at least this (fast).
pub const COMPLEX_MIN_SPEED_PX_S: f64 = 3_000.0;

/// Which set: they differ in their texture streams.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Split {
    /// The training set.
    Train,
    /// The held-out set.
    Test,
}

/// What to generate (the `neuspike dataset` arguments).
#[derive(Clone, Debug, clap::Args)]
pub struct DatasetOptions {
    /// Output folder (must be empty or absent).
    #[arg(long)]
    pub out: PathBuf,
    /// Which set: train and test never share a texture.
    #[arg(long, value_enum)]
    pub split: Split,
    /// Samples per (light, speed) cell of the 5 x 5 grid.
    #[arg(long, default_value_t = 40)]
    pub per_cell: usize,
    /// Side of a sample, pixels.
    #[arg(long, default_value_t = 64)]
    pub size: usize,
    /// Planes per window (as align's --window-planes).
    #[arg(long, default_value_t = 33)]
    pub window_planes: usize,
    /// Channels of each representation (the paper's N_c = 32).
    #[arg(long, default_value_t = 32)]
    pub channels: usize,
    /// Event integration decay, nanoseconds (as represent's --tau-ns).
    #[arg(long, default_value_t = 500_000.0)]
    pub tau_ns: f64,
    /// Spike plane rate, Hz.
    #[arg(long, default_value_t = 20_000.0)]
    pub rate_hz: f64,
    /// A folder of PNG photographs for textures (half the samples), e.g. one split of
    /// training/prepare_textures.py.
    #[arg(long)]
    pub textures: Option<PathBuf>,
    /// Samples per .npy shard.
    #[arg(long, default_value_t = 500)]
    pub shard: usize,
    /// Seed of every draw.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// More representations of each sample's window, by the represent node's names (e.g.
    /// `voxel_grid,event_stack,time_surface` for E2VID-style networks), each written as
    /// `<kind>.npy` with represent's default settings (5 time bins, a 500 us time surface).
    #[arg(long, value_delimiter = ',')]
    pub also: Vec<RepresentationKind>,
    /// The spike camera's noise for every sample (a profile such as `vidar`, and per-term
    /// overrides); the paper's model by default.
    #[command(flatten)]
    pub noise: NoiseArgs,
    /// Draw each sample's spike camera at random (domain randomisation, [`CameraDraw`]): each
    /// noise term on or off and its value, the initial charge, the fixed-pattern cap, and the
    /// light scale within its cell. Not with `--profile` or a per-term override.
    #[arg(long)]
    pub randomise_camera: bool,
    /// With `--randomise-camera`, also draw the random-spike term (spikes read at random,
    /// `--random-spike-hz`): outside the clean share it is on with probability [`TERM_ON`], then
    /// log-uniform over the two decades up to this many Hz. 0 (the default) never draws it, so a
    /// set is the same as one made before the term existed.
    #[arg(long, default_value_t = 0.0)]
    pub random_spikes_max_hz: f64,
    /// Video instead of textures: a folder of clips as `training/video.py clips` writes them
    /// (`clips.csv` and one float32 `[T, size, size]` `.npy` of frames a sample). Each clip is
    /// one sample, its speed and direction as the clip measured them; the lights cycle through
    /// the grid's. `--per-cell` and `--textures` do not apply.
    #[arg(long, conflicts_with = "textures")]
    pub clips: Option<PathBuf>,
}

/// One clip of a `--clips` folder: a row of its `clips.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct ClipRow {
    /// The `.npy` of frames, `[T, size, size]` float32 luminance, frame `k` at `k dt_ns`; the
    /// window's reference plane `c` is at `c` periods.
    pub file: PathBuf,
    /// Which video it came from, and the frame that is the window's reference (for the
    /// sample's `texture` column: `source@frame`).
    pub source: String,
    /// The reference frame in that video.
    pub frame: u64,
    /// The motion's speed in the window, pixels per second (of the fastest motion in the crop, as
    /// `training/video.py` measures it).
    pub speed_px_s: f64,
    /// Its direction, degrees.
    pub angle_deg: f64,
    /// Time between frames of the `.npy`.
    pub dt_ns: i64,
}

/// Largest clip file read, bytes.
pub const MAX_CLIP_BYTES: u64 = 1 << 30;

/// The clips of a `--clips` folder, from its `clips.csv` (columns `file,source,frame,
/// speed_px_s,angle_deg,dt_ns` in any order, more allowed); a bad row is named by line, field
/// and value.
pub fn clips_in(dir: &Path) -> eyre::Result<Vec<ClipRow>> {
    let table = Table::read(&dir.join("clips.csv"), "")?;
    let [file, source, frame, speed, angle, dt] = [
        "file",
        "source",
        "frame",
        "speed_px_s",
        "angle_deg",
        "dt_ns",
    ]
    .map(|name| table.column(name));
    let (file, source, frame, speed, angle, dt) = (file?, source?, frame?, speed?, angle?, dt?);
    let rows = table
        .rows()
        .map(|row| {
            let speed_px_s = row.number(speed, "speed_px_s")?;
            if speed_px_s < 0.0 {
                return Err(row.bad("speed_px_s", &speed_px_s.to_string(), "at least 0"));
            }
            Ok(ClipRow {
                file: dir.join(row.field(file, "file")?),
                source: row.field(source, "source")?.to_owned(),
                frame: row.parse(frame, "frame", "a frame number")?,
                speed_px_s,
                angle_deg: row.number(angle, "angle_deg")?,
                dt_ns: row.parse(dt, "dt_ns", "a whole number of nanoseconds")?,
            })
        })
        .collect::<eyre::Result<Vec<_>>>()?;
    if rows.is_empty() {
        bail!("{}: no clips", dir.join("clips.csv").display());
    }
    Ok(rows)
}

impl ClipRow {
    /// The clip as a scene at `light`: its frames must be `size x size` and reach the window's
    /// last plane (`last_ns`).
    fn scene(&self, size: usize, last_ns: i64, light: f64) -> eyre::Result<Scene> {
        let name = self.file.display();
        let bytes = fs::metadata(&self.file)
            .wrap_err_with(|| format!("{name}: cannot read"))?
            .len();
        if bytes > MAX_CLIP_BYTES {
            bail!("{name}: {bytes} bytes, more than the {MAX_CLIP_BYTES} a clip may hold");
        }
        let frames: Array3<f32> = ndarray_npy::read_npy(&self.file)
            .map_err(|e| eyre!("{name}: not a float32 [T, H, W] .npy: {e}"))?;
        let (t, h, w) = frames.dim();
        if (h, w) != (size, size) {
            bail!("{name}: frames of {h}x{w}, the set's --size is {size}");
        }
        let clip = Clip::new(frames, self.dt_ns, &name.to_string())?;
        if clip.last_ns() < last_ns {
            bail!(
                "{name}: {t} frames {} ns apart end at {} ns, before the window's last plane at {last_ns} ns",
                self.dt_ns,
                clip.last_ns()
            );
        }
        Ok(Scene::from_clip(clip, light)?)
    }
}

/// One sample's spike camera under `--randomise-camera`: what the network must not depend on.
///
/// A share [`CLEAN_SHARE`] of the samples keep the paper's camera (no noise term; the initial
/// charge and the cap as the default camera has them), so that a network stays as good on clean
/// spikes. In the others each noise term is on with probability [`TERM_ON`] and then drawn over
/// a range that spans the paper's model (0) to about twice the `vidar` profile's value, so a
/// network sees cameras cleaner and noisier than the real one it will meet. The light scale is
/// the cell's times a log-uniform factor in `[1/1.4, 1.4]`: a threshold `phi` other than 1
/// changes a pixel's rate as a light scale does, so this also covers the threshold.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraDraw {
    /// The noise terms.
    pub noise: Noise,
    /// Random initial accumulators (on with probability 0.9).
    pub random_init: bool,
    /// The fixed-pattern ISI cap (on with probability 0.8), its mean and spread in ticks.
    pub fpn_cap: bool,
    /// Mean of the cap, ticks, in `[120, 260)`.
    pub fpn_mu: f64,
    /// Spread of the cap, ticks, in `[20, 80)`.
    pub fpn_sigma: f64,
    /// The light scale the sample is made with (the cell's, times the factor).
    pub light: f64,
}

/// The share of `--randomise-camera` samples that keep the paper's camera.
pub const CLEAN_SHARE: f64 = 0.25;
/// The probability that `--randomise-camera` turns a noise term on (outside the clean share).
pub const TERM_ON: f64 = 0.7;

impl CameraDraw {
    /// Draws a camera for a sample of the cell of light `light`.
    pub fn draw(rng: &mut ChaCha8Rng, light: f64, random_spikes_max_hz: f64) -> CameraDraw {
        let log_uniform =
            |rng: &mut ChaCha8Rng, lo: f64, hi: f64| (rng.random_range(lo.ln()..hi.ln())).exp();
        if rng.random_bool(CLEAN_SHARE) {
            let light = light * log_uniform(rng, 1.0 / 1.4, 1.4);
            return CameraDraw::fixed(Noise::OFF, light);
        }
        let on = |rng: &mut ChaCha8Rng| rng.random_bool(TERM_ON);
        let electrons_per_phi = if on(rng) {
            log_uniform(rng, 200.0, 100_000.0)
        } else {
            0.0
        };
        let threshold_jitter = if on(rng) {
            rng.random_range(0.0..0.18)
        } else {
            0.0
        };
        let threshold_offset = if on(rng) {
            rng.random_range(0.0..0.1)
        } else {
            0.0
        };
        let prnu = if on(rng) {
            rng.random_range(0.0..0.12)
        } else {
            0.0
        };
        let (dark_current_hz, dark_current_spread) = if on(rng) {
            (log_uniform(rng, 1.0, 300.0), rng.random_range(0.0..0.8))
        } else {
            (0.0, 0.0)
        };
        let reset_delay_ticks = if on(rng) {
            rng.random_range(0.0..0.05)
        } else {
            0.0
        };
        let random_init = rng.random_bool(0.9);
        let fpn_cap = rng.random_bool(0.8);
        let fpn_mu = rng.random_range(120.0..260.0);
        let fpn_sigma = rng.random_range(20.0..80.0);
        let light = light * log_uniform(rng, 1.0 / 1.4, 1.4);
        // Drawn last, and only when asked: every draw above stays as it was without it.
        let random_spike_hz = if random_spikes_max_hz > 0.0 && on(rng) {
            log_uniform(rng, random_spikes_max_hz / 100.0, random_spikes_max_hz)
        } else {
            0.0
        };
        CameraDraw {
            noise: Noise {
                electrons_per_phi,
                threshold_jitter,
                threshold_offset,
                prnu,
                dark_current_hz,
                dark_current_spread,
                reset_delay_ticks,
                random_spike_hz,
            },
            random_init,
            fpn_cap,
            fpn_mu,
            fpn_sigma,
            light,
        }
    }

    /// The camera of `opts` without randomisation: its noise, the paper's initial charge and cap,
    /// the cell's light.
    fn fixed(noise: Noise, light: f64) -> CameraDraw {
        let d = CameraConfig::default();
        CameraDraw {
            noise,
            random_init: d.random_init,
            fpn_cap: d.fpn_cap,
            fpn_mu: d.fpn_mu,
            fpn_sigma: d.fpn_sigma,
            light,
        }
    }
}

/// What one sample was made of (a row of `samples.csv`).
#[derive(Clone, Debug, PartialEq)]
pub struct SampleInfo {
    /// Texture: `kind:seed` of a generator, or the photograph's file name.
    pub texture: String,
    /// Light scale.
    pub light: f64,
    /// Speed, scene pixels per second.
    pub speed_px_s: f64,
    /// Direction of motion, degrees.
    pub angle_deg: f64,
    /// DVS ON threshold.
    pub theta_on: f64,
    /// DVS OFF threshold.
    pub theta_off: f64,
    /// `phi / light`.
    pub lum_per_rate: f64,
    /// Events in the window.
    pub events: usize,
    /// Dark or fast.
    pub complex: bool,
    /// The spike camera it was seen by.
    pub camera: CameraDraw,
}

/// One generated sample.
#[derive(Clone, Debug)]
pub struct Sample {
    /// `[channels, size, size]`.
    pub spike: Array3<f32>,
    /// `[channels, size, size]`.
    pub events: Array3<f32>,
    /// `[size, size]`, luminance in `[0, 1]`.
    pub truth: Array2<f32>,
    /// TFP over the window, as luminance.
    pub tfp: Array2<f32>,
    /// TFI at the reference plane, as luminance.
    pub tfi: Array2<f32>,
    /// The representations of `--also`, in its order.
    pub also: Vec<ndarray::Array3<f32>>,
    /// How it was made.
    pub info: SampleInfo,
}

/// What was written.
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetSummary {
    /// Samples.
    pub samples: usize,
    /// Shards.
    pub shards: usize,
    /// Complex samples.
    pub complex: usize,
    /// Photographs used.
    pub photos: usize,
}

/// The procedural generators and their parameter draws; `seeded` ones differ by seed, the others
/// only by parameters (used for training only).
const GENERATORS: [(&str, bool); 5] = [
    ("noise", true),
    ("shapes", true),
    ("strokes", true),
    ("grating", false),
    ("checkerboard", false),
];

/// Checks the options, naming the bad one.
fn check(opts: &DatasetOptions) -> eyre::Result<()> {
    let bad = |name: &str, value: String, why: &str| {
        Err(eyre!("dataset: --{name} = {value} is invalid: {why}"))
    };
    if opts.per_cell == 0 {
        return bad("per-cell", "0".into(), "must be at least 1");
    }
    if !(8..=1024).contains(&opts.size) {
        return bad("size", opts.size.to_string(), "must be in 8..=1024");
    }
    if opts.channels < 2 {
        return bad("channels", opts.channels.to_string(), "must be at least 2");
    }
    if opts.window_planes < opts.channels - 1 || opts.window_planes > 4096 {
        return bad(
            "window-planes",
            opts.window_planes.to_string(),
            "must hold the raw channels (>= channels - 1) and be at most 4096",
        );
    }
    if !(opts.tau_ns.is_finite() && opts.tau_ns > 0.0) {
        return bad("tau-ns", opts.tau_ns.to_string(), "must be finite and > 0");
    }
    if opts.shard == 0 {
        return bad("shard", "0".into(), "must be at least 1");
    }
    opts.noise.resolve().map_err(|e| eyre!("dataset: {e}"))?;
    let max = opts.random_spikes_max_hz;
    if !(max.is_finite() && max >= 0.0 && max < opts.rate_hz) {
        return bad(
            "random-spikes-max-hz",
            max.to_string(),
            "must be finite, >= 0 and below --rate-hz",
        );
    }
    if max > 0.0 && !opts.randomise_camera {
        return bad(
            "random-spikes-max-hz",
            max.to_string(),
            "draws the term of each sample's camera: only with --randomise-camera (a fixed camera takes --random-spike-hz)",
        );
    }
    if opts.randomise_camera {
        let n = &opts.noise;
        let overrides = [
            ("profile", (n.profile != "paper").then(|| n.profile.clone())),
            (
                "electrons-per-phi",
                n.electrons_per_phi.map(|v| v.to_string()),
            ),
            (
                "threshold-jitter",
                n.threshold_jitter.map(|v| v.to_string()),
            ),
            (
                "threshold-offset",
                n.threshold_offset.map(|v| v.to_string()),
            ),
            ("prnu", n.prnu.map(|v| v.to_string())),
            ("dark-current-hz", n.dark_current_hz.map(|v| v.to_string())),
            (
                "dark-current-spread",
                n.dark_current_spread.map(|v| v.to_string()),
            ),
            (
                "reset-delay-ticks",
                n.reset_delay_ticks.map(|v| v.to_string()),
            ),
            ("random-spike-hz", n.random_spike_hz.map(|v| v.to_string())),
        ];
        if let Some((name, Some(value))) = overrides.into_iter().find(|(_, v)| v.is_some()) {
            return bad(
                name,
                value,
                "--randomise-camera draws every sample's camera; give one or the other",
            );
        }
    }
    Ok(())
}

/// The PNG files of a folder, sorted by name.
fn photos_in(dir: &Path) -> eyre::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for entry in fs::read_dir(dir).wrap_err_with(|| format!("--textures {}", dir.display()))? {
        let path = entry
            .wrap_err_with(|| format!("--textures {}", dir.display()))?
            .path();
        if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("png"))
        {
            out.push(path);
        }
    }
    out.sort();
    if out.is_empty() {
        bail!("--textures {}: no PNG files there", dir.display());
    }
    Ok(out)
}

/// The scene YAML of one sample.
fn scene_yaml(
    opts: &DatasetOptions,
    rng: &mut ChaCha8Rng,
    photos: &[PathBuf],
    light: f64,
    speed: f64,
) -> eyre::Result<(String, String, f64)> {
    let angle_deg: f64 = rng.random_range(0.0..360.0);
    let (vx, vy) = (
        speed * angle_deg.to_radians().cos(),
        speed * angle_deg.to_radians().sin(),
    );
    // A little rotation now and then, so that not every motion is a translation.
    let rotation = if speed > 0.0 && rng.random_bool(0.25) {
        rng.random_range(-200.0..200.0)
    } else {
        0.0
    };
    let contrast: f64 = rng.random_range(0.6..1.0);
    // The window and the DVS start: the scene must last past the window.
    let period_ns = (1e9 / opts.rate_hz).round().max(1.0);
    let duration_ns = (period_ns * (opts.window_planes as f64 + 4.0)).ceil() as u64;
    let use_photo = !photos.is_empty() && rng.random_bool(0.5);
    let (texture, label) = if use_photo {
        let p = &photos[rng.random_range(0..photos.len())];
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        (
            format!(
                "{{ kind: png, path: {:?}, contrast: {contrast} }}",
                p.display().to_string()
            ),
            name,
        )
    } else {
        let pool: Vec<&str> = GENERATORS
            .iter()
            .filter(|(_, seeded)| *seeded || opts.split == Split::Train)
            .map(|(k, _)| *k)
            .collect();
        let kind = pool[rng.random_range(0..pool.len())];
        let extra = match kind {
            "noise" => format!("beta: {:.3}", rng.random_range(1.5..3.0)),
            "shapes" => format!("count: {}", rng.random_range(10..120)),
            "grating" => format!(
                "period_px: {:.2}, angle_deg: {:.1}",
                rng.random_range(4.0..48.0),
                rng.random_range(0.0..180.0)
            ),
            "checkerboard" => format!("square_px: {:.2}", rng.random_range(4.0..40.0)),
            _ => String::new(),
        };
        let sep = if extra.is_empty() { "" } else { ", " };
        (
            format!("{{ kind: {kind}, contrast: {contrast}{sep}{extra} }}"),
            kind.to_string(),
        )
    };
    // Seeds of the two splits never meet: train even, test odd.
    let seed = 2 * (rng.random::<u64>() >> 2)
        + match opts.split {
            Split::Train => 0,
            Split::Test => 1,
        };
    let label = if use_photo {
        label
    } else {
        format!("{label}:{seed}")
    };
    let yaml = format!(
        "width: {s}\nheight: {s}\nduration_ns: {duration_ns}\nseed: {seed}\nlight_scale: {light}\n\
         texture: {texture}\nmotion: {{ vx_px_s: {vx}, vy_px_s: {vy}, rotation_deg_s: {rotation} }}\n",
        s = opts.size,
    );
    Ok((yaml, label, angle_deg))
}

/// Generates sample `index` of the grid cell `(light, speed)`; deterministic in
/// `(opts.seed, opts.split, index)`.
pub fn sample(
    opts: &DatasetOptions,
    photos: &[PathBuf],
    index: usize,
    light: f64,
    speed: f64,
) -> eyre::Result<Sample> {
    sample_seen(opts, index, light, speed, |rng, light| {
        let (yaml, texture, angle_deg) = scene_yaml(opts, rng, photos, light, speed)?;
        let scene = Scene::from_yaml_str(&yaml, &format!("dataset sample {index}"), None)?;
        Ok((scene, texture, angle_deg))
    })
}

/// Generates sample `index` from a clip of video at the cell's `light`, as [`sample`] does from
/// a texture: the same cameras, draws and stages; the truth the clip's frame at `t_ref`.
pub fn sample_of_clip(
    opts: &DatasetOptions,
    clip: &ClipRow,
    index: usize,
    light: f64,
) -> eyre::Result<Sample> {
    let period_ns = (1e9 / opts.rate_hz).round().max(1.0) as i64;
    let last_ns = period_ns * (opts.window_planes as i64 - 1);
    sample_seen(opts, index, light, clip.speed_px_s, |_, light| {
        let scene = clip.scene(opts.size, last_ns, light)?;
        Ok((
            scene,
            format!("{}@{}", clip.source, clip.frame),
            clip.angle_deg,
        ))
    })
}

/// A sample of the scene `look` makes from the sample's generator and its light (with the
/// texture's label and the direction of motion).
fn sample_seen(
    opts: &DatasetOptions,
    index: usize,
    light: f64,
    speed: f64,
    look: impl FnOnce(&mut ChaCha8Rng, f64) -> eyre::Result<(Scene, String, f64)>,
) -> eyre::Result<Sample> {
    let stream = match opts.split {
        Split::Train => 0,
        Split::Test => 1,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    rng.set_stream(stream * (1 << 32) + index as u64);
    // The camera draws from a stream of its own, so that a set made without randomisation is
    // the same sample for sample as before it existed.
    let cam = if opts.randomise_camera {
        let mut cam_rng = ChaCha8Rng::seed_from_u64(opts.seed);
        cam_rng.set_stream((1 << 48) + stream * (1 << 32) + index as u64);
        CameraDraw::draw(&mut cam_rng, light, opts.random_spikes_max_hz)
    } else {
        let noise = opts.noise.resolve().map_err(|e| eyre!("dataset: {e}"))?;
        CameraDraw::fixed(noise, light)
    };
    let cell_light = light;
    let light = cam.light;
    let (scene, texture, angle_deg) = look(&mut rng, light)?;

    let n = opts.window_planes;
    let s = opts.size;
    let spike_cfg = CameraConfig {
        width: s,
        height: s,
        rate_hz: opts.rate_hz,
        seed: rng.random(),
        random_init: cam.random_init,
        fpn_cap: cam.fpn_cap,
        fpn_mu: cam.fpn_mu,
        fpn_sigma: cam.fpn_sigma,
        noise: NoiseArgs::from(cam.noise),
        ..CameraConfig::default()
    };
    let mut camera = SpikeCamera::new(scene.clone(), spike_cfg)?;
    let chunk = camera.next_chunk(n, 0);
    let c = n / 2;
    let t_ref_ns = chunk.plane_time_ns(c);
    let period = chunk.plane_period_ns;
    let (t_start_ns, t_end_ns) = (chunk.t_first_ns - period, chunk.plane_time_ns(n - 1));

    // Thresholds rise in the dark, as a DVS's effective contrast sensitivity falls.
    let theta = 0.2 * (1.0 + 0.25 * (1.0 / light).ln().max(0.0));
    let (theta_on, theta_off) = (
        theta * rng.random_range(0.85..1.15),
        theta * rng.random_range(0.85..1.15),
    );
    let dvs_cfg = DvsConfig {
        width: s,
        height: s,
        theta_on,
        theta_off,
        seed: rng.random(),
        ..DvsConfig::default()
    };
    let mut dvs = EventCamera::new(scene.clone(), dvs_cfg, t_start_ns)?;
    let batch = dvs.advance_to(t_end_ns, 0);
    let lum_per_rate = camera.lum_per_rate();

    // The graph's own align and represent stages, in a chain, on the two cameras' streams.
    let k = opts.channels;
    let mut kinds = vec![
        RepresentationKind::SpikeRepr,
        RepresentationKind::EventIntegration,
        RepresentationKind::Tfp,
        RepresentationKind::Isi,
    ];
    for &kind in &opts.also {
        if !kinds.contains(&kind) {
            kinds.push(kind);
        }
    }
    let got = window_through_the_stages(
        chunk,
        batch,
        Representer::new(RepresentConfig {
            repr_channels: k as u32,
            ei_channels: k as u32,
            tau_ns: opts.tau_ns,
            ..RepresentConfig::default()
        })?,
        &kinds,
    )?;
    if got.window.ref_plane != c as u64 || got.window.t_ref_ns != t_ref_ns {
        bail!(
            "dataset sample {index}: align cut the window at plane {}, not {c}",
            got.window.ref_plane
        );
    }
    let take = |kind: RepresentationKind| -> eyre::Result<Array3<f32>> {
        kinds
            .iter()
            .position(|&k| k == kind)
            .and_then(|i| got.representations.get(i).cloned())
            .ok_or_else(|| eyre!("dataset sample {index}: represent made no {kind}"))
    };
    let spike = take(RepresentationKind::SpikeRepr)?;
    let events = take(RepresentationKind::EventIntegration)?;
    let rate = take(RepresentationKind::Tfp)?;
    let isi = take(RepresentationKind::Isi)?;
    let also = opts
        .also
        .iter()
        .map(|&kind| take(kind))
        .collect::<eyre::Result<Vec<_>>>()?;

    let phi = CameraConfig::default().phi;
    let mut tfp = Array2::<f32>::zeros((s, s));
    luminance_from_rate_into(rate.index_axis(Axis(0), 0), phi, light, tfp.view_mut())?;
    let mut tfi = Array2::<f32>::zeros((s, s));
    luminance_from_isi_into(isi.index_axis(Axis(0), 0), phi, light, tfi.view_mut())?;

    let mut truth = scene.render(t_ref_ns, s, s);
    truth.mapv_inplace(|v| v.clamp(0.0, 1.0));
    let info = SampleInfo {
        texture,
        light: cell_light,
        speed_px_s: speed,
        angle_deg,
        theta_on,
        theta_off,
        lum_per_rate,
        events: got.window.events.t_ns.len(),
        complex: cell_light <= COMPLEX_MAX_LIGHT || speed >= COMPLEX_MIN_SPEED_PX_S,
        camera: cam,
    };
    Ok(Sample {
        spike,
        events,
        truth,
        tfp,
        tfi,
        also,
        info,
    })
}

/// A sample's window, cut by align from the spike camera's `chunk` and the DVS's `batch`, and
/// its representations of `kinds` (in that order), made by `representer`: the align and
/// represent stages in a chain, as a graph runs them. Align's stride is half the chunk, so its
/// first window is the one around the chunk's middle plane.
struct Through {
    window: AlignedWindow,
    representations: Vec<Array3<f32>>,
}

fn window_through_the_stages(
    chunk: SpikeChunk,
    batch: EventBatch,
    representer: Representer,
    kinds: &[RepresentationKind],
) -> eyre::Result<Through> {
    let n = u32::try_from(chunk.n_planes)
        .map_err(|_| eyre!("dataset: {} planes in a window", chunk.n_planes))?;
    let align = AlignConfig {
        window_planes: n,
        stride_planes: u64::from(n / 2).max(1),
        ..AlignConfig::default()
    };
    let window = Mutex::new(None);
    let made = Mutex::new(vec![None; kinds.len()]);
    let mut chain = Chain::new();
    chain
        .add(
            "cameras",
            Replay::new("cameras")
                .output("spikes", MsgType::SpikeChunk, [Msg::from(chunk)])
                .output("events", MsgType::EventBatch, [Msg::from(batch)]),
        )?
        .add("align", AlignStage::new(align, true, false))?
        .add("represent", RepresentStage::new(representer, kinds))?
        .connect("cameras/spikes", "align/spikes")?
        .connect("cameras/events", "align/events")?
        .connect("align/windows", "represent/windows")?;
    chain.tap("align/windows", |m| {
        let mut w = window.lock().unwrap_or_else(|e| e.into_inner());
        // The first window only: the chunk holds one.
        if w.is_none() {
            *w = Some(AlignedWindow::try_from(m)?);
        }
        Ok(())
    })?;
    for (i, kind) in kinds.iter().enumerate() {
        let made = &made;
        chain.tap(&format!("represent/{}", kind.name()), move |m| {
            let r = Representation::try_from(m)?;
            let mut made = made.lock().unwrap_or_else(|e| e.into_inner());
            if made[i].is_none() {
                made[i] = Some(r.data);
            }
            Ok(())
        })?;
    }
    chain.run()?;
    let window = window
        .into_inner()
        .unwrap_or_else(|e| e.into_inner())
        .ok_or_else(|| eyre!("dataset: align cut no window"))?;
    let representations = made
        .into_inner()
        .unwrap_or_else(|e| e.into_inner())
        .into_iter()
        .zip(kinds)
        .map(|(r, k)| r.ok_or_else(|| eyre!("dataset: represent made no {k}")))
        .collect::<eyre::Result<_>>()?;
    Ok(Through {
        window,
        representations,
    })
}

/// The grid cell of sample `index`: samples cycle through the 25 cells.
pub fn cell_of(index: usize) -> (f64, f64) {
    let cell = index % (LIGHT_SCALES.len() * SPEEDS_PX_S.len());
    (
        LIGHT_SCALES[cell / SPEEDS_PX_S.len()],
        SPEEDS_PX_S[cell % SPEEDS_PX_S.len()],
    )
}

/// Stacks one array of every sample along a new first axis and writes it.
fn save_stacked<D>(path: &Path, items: &[ndarray::ArrayView<f32, D>]) -> eyre::Result<()>
where
    D: ndarray::Dimension,
    D::Larger: ndarray::RemoveAxis,
{
    let stacked = ndarray::stack(Axis(0), items)
        .wrap_err_with(|| format!("cannot stack the samples of {}", path.display()))?;
    save(path, &stacked)
}

fn save<A: ndarray_npy::WritableElement, D: ndarray::Dimension>(
    path: &Path,
    a: &ndarray::Array<A, D>,
) -> eyre::Result<()> {
    write_npy(path, a).wrap_err_with(|| format!("cannot write {}", path.display()))
}

/// The samples of a set, each made on demand: sample `i` is the one `neuspike dataset` writes as
/// sample `i` (deterministic in the seed, the split and `i`), whether it is asked for alone, in
/// any order, in any process, or generated into shards.
#[derive(Clone, Debug)]
pub struct Samples {
    opts: DatasetOptions,
    photos: Vec<PathBuf>,
    clips: Vec<ClipRow>,
}

impl Samples {
    /// Checks the options and lists the photographs and clips they name (`out` is not used).
    ///
    /// # Errors
    /// A bad option, named; a textures or clips folder that cannot be read.
    pub fn new(opts: DatasetOptions) -> eyre::Result<Samples> {
        check(&opts)?;
        let photos = match &opts.textures {
            Some(dir) => photos_in(dir)?,
            None => Vec::new(),
        };
        let clips = match &opts.clips {
            Some(dir) => clips_in(dir)?,
            None => Vec::new(),
        };
        Ok(Samples {
            opts,
            photos,
            clips,
        })
    }

    /// The set's size: `per_cell` samples in each of the grid's 25 cells, or one a clip.
    pub fn len(&self) -> usize {
        if self.clips.is_empty() {
            self.opts.per_cell * LIGHT_SCALES.len() * SPEEDS_PX_S.len()
        } else {
            self.clips.len()
        }
    }

    /// Whether the set is empty (never: the options hold at least one sample).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The options.
    pub fn options(&self) -> &DatasetOptions {
        &self.opts
    }

    /// The photographs the textures come from.
    pub fn photos(&self) -> usize {
        self.photos.len()
    }

    /// Sample `i`, `i < len()`.
    ///
    /// # Errors
    /// `i` out of range, or a clip that cannot be read; each names the sample.
    pub fn get(&self, i: usize) -> eyre::Result<Sample> {
        if i >= self.len() {
            bail!("dataset: sample {i} of a set of {}", self.len());
        }
        let (light, speed) = cell_of(i);
        match self.clips.get(i) {
            Some(clip) => sample_of_clip(&self.opts, clip, i, LIGHT_SCALES[i % LIGHT_SCALES.len()]),
            None => sample(&self.opts, &self.photos, i, light, speed),
        }
        .wrap_err_with(|| format!("dataset: sample {i}"))
    }
}

/// Generates the whole set into `opts.out`.
pub fn generate(opts: &DatasetOptions, progress: bool) -> eyre::Result<DatasetSummary> {
    let set = Samples::new(opts.clone())?;
    let out = &opts.out;
    if out.exists()
        && fs::read_dir(out)
            .wrap_err_with(|| format!("--out {}", out.display()))?
            .next()
            .is_some()
    {
        bail!("dataset: --out {} exists and is not empty", out.display());
    }
    fs::create_dir_all(out).wrap_err_with(|| format!("cannot create {}", out.display()))?;
    let total = set.len();
    let bar = progress.then(|| indicatif::ProgressBar::new(total as u64));
    let csv_path = out.join("samples.csv");
    let mut csv = std::io::BufWriter::new(
        fs::File::create(&csv_path)
            .wrap_err_with(|| format!("cannot create {}", csv_path.display()))?,
    );
    writeln!(
        csv,
        "index,shard,texture,light,speed_px_s,angle_deg,theta_on,theta_off,lum_per_rate,events,complex,\
         camera_light,electrons_per_phi,threshold_jitter,threshold_offset,prnu,dark_current_hz,\
         dark_current_spread,reset_delay_ticks,random_spike_hz,random_init,fpn_cap,fpn_mu,fpn_sigma"
    )?;
    let mut summary = DatasetSummary {
        samples: 0,
        shards: 0,
        complex: 0,
        photos: set.photos(),
    };
    for (shard, start) in (0..total).step_by(opts.shard).enumerate() {
        let end = (start + opts.shard).min(total);
        let samples: Vec<Sample> = (start..end)
            .into_par_iter()
            .map(|i| {
                let s = set.get(i);
                if let Some(bar) = &bar {
                    bar.inc(1);
                }
                s
            })
            .collect::<eyre::Result<_>>()?;
        let dir = out.join(format!("{shard:03}"));
        fs::create_dir_all(&dir).wrap_err_with(|| format!("cannot create {}", dir.display()))?;
        let views = |f: fn(&Sample) -> ndarray::ArrayViewD<'_, f32>| {
            samples.iter().map(f).collect::<Vec<_>>()
        };
        save_stacked(
            &dir.join("spike.npy"),
            &views(|s| s.spike.view().into_dyn()),
        )?;
        save_stacked(
            &dir.join("events.npy"),
            &views(|s| s.events.view().into_dyn()),
        )?;
        save_stacked(
            &dir.join("truth.npy"),
            &views(|s| s.truth.view().into_dyn()),
        )?;
        save_stacked(&dir.join("tfp.npy"), &views(|s| s.tfp.view().into_dyn()))?;
        save_stacked(&dir.join("tfi.npy"), &views(|s| s.tfi.view().into_dyn()))?;
        for (k, kind) in opts.also.iter().enumerate() {
            let arrays: Vec<_> = samples.iter().map(|s| s.also[k].view()).collect();
            save_stacked(&dir.join(format!("{}.npy", kind.name())), &arrays)?;
        }
        for (i, s) in (start..end).zip(&samples) {
            let f = &s.info;
            let (c, n) = (&f.camera, &f.camera.noise);
            writeln!(
                csv,
                "{i},{shard},{},{},{},{:.3},{:.5},{:.5},{},{},{},{:.5},{:.1},{:.5},{:.5},{:.5},{:.3},{:.4},{:.5},{:.2},{},{},{:.2},{:.2}",
                f.texture,
                f.light,
                f.speed_px_s,
                f.angle_deg,
                f.theta_on,
                f.theta_off,
                f.lum_per_rate,
                f.events,
                u8::from(f.complex),
                c.light,
                n.electrons_per_phi,
                n.threshold_jitter,
                n.threshold_offset,
                n.prnu,
                n.dark_current_hz,
                n.dark_current_spread,
                n.reset_delay_ticks,
                n.random_spike_hz,
                u8::from(c.random_init),
                u8::from(c.fpn_cap),
                c.fpn_mu,
                c.fpn_sigma,
            )?;
            summary.complex += usize::from(f.complex);
        }
        summary.samples += samples.len();
        summary.shards += 1;
    }
    csv.flush()
        .wrap_err_with(|| format!("cannot write {}", csv_path.display()))?;
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    let camera = if opts.randomise_camera {
        "randomised (each sample's in samples.csv)".to_string()
    } else {
        let n = opts.noise.resolve().map_err(|e| eyre!("dataset: {e}"))?;
        format!(
            "\"profile {}: {}\"",
            opts.noise.profile,
            serde_yaml::to_string(&n)
                .unwrap_or_default()
                .trim()
                .replace('\n', ", ")
        )
    };
    let yml = format!(
        "# neuspike dataset: see dataset/src/lib.rs\nsplit: {:?}\nsamples: {}\nshards: {}\ncomplex: {}\n\
         per_cell: {}\nsize: {}\nwindow_planes: {}\nreference_plane: {}\nchannels: {}\ntau_ns: {}\n\
         rate_hz: {}\nphi: {}\nlight_scales: {:?}\nspeeds_px_s: {:?}\nphotos: {}\nseed: {}\nalso: [{}]\n\
         camera: {}\nclips: {}\n",
        opts.split,
        summary.samples,
        summary.shards,
        summary.complex,
        opts.per_cell,
        opts.size,
        opts.window_planes,
        opts.window_planes / 2,
        opts.channels,
        opts.tau_ns,
        opts.rate_hz,
        CameraConfig::default().phi,
        LIGHT_SCALES,
        SPEEDS_PX_S,
        set.photos(),
        opts.seed,
        opts.also
            .iter()
            .map(|k| k.name())
            .collect::<Vec<_>>()
            .join(", "),
        camera,
        opts.clips.as_ref().map_or("none".to_string(), |d| format!(
            "{:?} ({} clips)",
            d.display().to_string(),
            set.len()
        ))
    );
    let yml_path = out.join("dataset.yml");
    neuspike_formats::atomic::write(&yml_path, yml)
        .wrap_err_with(|| format!("cannot write {}", yml_path.display()))?;
    Ok(summary)
}

/// A small set's options for tests (this crate's and the program's): one sample of 16x16 a cell,
/// shards of 10, seed 7.
#[doc(hidden)]
pub fn tiny_options(split: Split, out: PathBuf) -> DatasetOptions {
    DatasetOptions {
        out,
        split,
        per_cell: 1,
        size: 16,
        window_planes: 33,
        channels: 32,
        tau_ns: 500_000.0,
        rate_hz: 20_000.0,
        textures: None,
        shard: 10,
        seed: 7,
        also: Vec::new(),
        noise: NoiseArgs::default(),
        randomise_camera: false,
        random_spikes_max_hz: 0.0,
        clips: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use super::tiny_options as opts;

    /// A `--clips` folder of two 16x16 clips of `frames` frames, a bright bar moving right
    /// by a pixel a frame over a dim ramp.
    fn clip_folder(dir: &Path, frames: usize) {
        fs::create_dir_all(dir).expect("dir");
        let mut csv = String::from("file,source,frame,speed_px_s,angle_deg,dt_ns,note\n");
        for k in 0..2 {
            let clip = Array3::<f32>::from_shape_fn((frames, 16, 16), |(t, r, c)| {
                if c == (t + k) % 16 {
                    0.9
                } else {
                    0.05 + 0.01 * r as f32
                }
            });
            ndarray_npy::write_npy(dir.join(format!("{k}.npy")), &clip).expect("npy");
            csv += &format!("{k}.npy,video{k},{},20000,0,50000,x\n", 10 + k);
        }
        fs::write(dir.join("clips.csv"), csv).expect("csv");
    }

    #[test]
    fn clips_of_video_are_samples_with_their_frame_as_truth() {
        let dir = tempfile::tempdir().expect("tempdir");
        clip_folder(&dir.path().join("clips"), 34);
        let o = DatasetOptions {
            clips: Some(dir.path().join("clips")),
            randomise_camera: true,
            noise: profile_only("paper"),
            ..opts(Split::Train, dir.path().join("set"))
        };
        let summary = generate(&o, false).expect("generate");
        assert_eq!(summary.samples, 2);
        let truth: Array3<f32> = ndarray_npy::read_npy(o.out.join("000/truth.npy")).expect("truth");
        // The reference plane 16 is at 16 periods: frame 16, whose bar is at column 16 + k.
        for k in 0..2 {
            let row = truth.index_axis(Axis(0), k);
            let bar = (16 + k) % 16;
            assert!((row[[3, bar]] - 0.9).abs() < 1e-6, "sample {k}: {row:?}");
            assert!((row[[3, (bar + 5) % 16]] - 0.08).abs() < 1e-6, "sample {k}");
        }
        let rows = fs::read_to_string(o.out.join("samples.csv")).expect("csv");
        assert!(
            rows.contains(",video0@10,") && rows.contains(",video1@11,"),
            "{rows}"
        );
        // The moving bar makes events and spikes; the lights are the grid's first two.
        let spike: ndarray::Array4<f32> =
            ndarray_npy::read_npy(o.out.join("000/spike.npy")).expect("spike");
        assert!(spike.iter().any(|&v| v > 0.0));
        assert!(
            rows.lines().nth(1).expect("row").contains(",0.05,20000,"),
            "{rows}"
        );
        assert!(
            fs::read_to_string(o.out.join("dataset.yml"))
                .expect("yml")
                .contains("(2 clips)")
        );
    }

    #[test]
    fn bad_clips_are_named() {
        let dir = tempfile::tempdir().expect("tempdir");
        let clips = dir.path().join("clips");
        clip_folder(&clips, 20);
        let o = DatasetOptions {
            clips: Some(clips.clone()),
            ..opts(Split::Train, dir.path().join("set"))
        };
        let e = format!("{:#}", generate(&o, false).unwrap_err());
        assert!(
            e.contains("0.npy") && e.contains("before the window's last plane"),
            "{e}"
        );
        fs::write(
            clips.join("clips.csv"),
            "file,source,frame,speed_px_s,dt_ns\n0.npy,a,1,2,3\n",
        )
        .expect("csv");
        let e = format!("{:#}", clips_in(&clips).unwrap_err());
        assert!(e.contains("clips.csv") && e.contains("angle_deg"), "{e}");
        fs::write(
            clips.join("clips.csv"),
            "file,source,frame,speed_px_s,angle_deg,dt_ns\n0.npy,a,1,fast,0,3\n",
        )
        .expect("csv");
        let e = format!("{:#}", clips_in(&clips).unwrap_err());
        assert!(
            e.contains("line 2") && e.contains("speed_px_s") && e.contains("fast"),
            "{e}"
        );
    }

    #[test]
    fn also_writes_the_other_representations_of_each_window() {
        let dir = tempfile::tempdir().expect("tempdir");
        let also = vec![
            RepresentationKind::VoxelGrid,
            RepresentationKind::EventStack,
            RepresentationKind::TimeSurface,
        ];
        let o = DatasetOptions {
            also: also.clone(),
            ..opts(Split::Train, dir.path().join("set"))
        };
        generate(&o, false).expect("generate");
        assert!(
            fs::read_to_string(o.out.join("dataset.yml"))
                .expect("yml")
                .contains("also: [voxel_grid, event_stack, time_surface]")
        );
        // Sample 24 (the fastest speed in the brightest light) is the fifth of shard 2.
        let (light, speed) = cell_of(24);
        let direct = sample(&o, &[], 24, light, speed).expect("sample 24");
        assert!(direct.info.events > 0);
        for (k, kind) in also.iter().enumerate() {
            let stacked: ndarray::Array4<f32> =
                ndarray_npy::read_npy(o.out.join(format!("002/{}.npy", kind.name()))).expect("npy");
            assert_eq!(stacked.dim().0, 5, "{}", kind.name());
            assert_eq!(
                stacked.index_axis(Axis(0), 4),
                direct.also[k],
                "{}",
                kind.name()
            );
            assert!(direct.also[k].iter().any(|&v| v != 0.0), "{}", kind.name());
        }
    }

    #[test]
    fn the_stages_see_the_whole_chunk_as_one_window_as_the_shipped_sets_were_made() {
        // The shipped networks were trained on windows holding the camera's chunk whole, with
        // the DVS batch of its span: align must cut exactly that, and represent make from it
        // what the `Representer` makes on that window directly.
        let scene = Scene::from_yaml_str(
            "width: 24\nheight: 24\nseed: 3\ntexture:\n  kind: strokes\nmotion:\n  vx_px_s: 3000.0\n  rotation_deg_s: 90.0\n",
            "test",
            None,
        )
        .expect("scene");
        for n in [2usize, 31, 33, 64] {
            let cfg = CameraConfig {
                width: 24,
                height: 24,
                ..CameraConfig::default()
            };
            let chunk = SpikeCamera::new(scene.clone(), cfg)
                .expect("camera")
                .next_chunk(n, 0);
            let (t0, t1) = (
                chunk.t_first_ns - chunk.plane_period_ns,
                chunk.plane_time_ns(n - 1),
            );
            let dvs = DvsConfig {
                width: 24,
                height: 24,
                ..DvsConfig::default()
            };
            let batch = EventCamera::new(scene.clone(), dvs, t0)
                .expect("dvs")
                .advance_to(t1, 0);
            let cfg = RepresentConfig {
                repr_channels: 2,
                ei_channels: 4,
                ..RepresentConfig::default()
            };
            let kinds = [
                RepresentationKind::SpikeRepr,
                RepresentationKind::EventIntegration,
                RepresentationKind::VoxelGrid,
            ];
            let got = window_through_the_stages(
                chunk.clone(),
                batch.clone(),
                Representer::new(cfg.clone()).expect("representer"),
                &kinds,
            )
            .expect("through the stages");
            let whole = AlignedWindow {
                t_ref_ns: chunk.plane_time_ns(n / 2),
                ref_plane: (n / 2) as u64,
                spikes: chunk.clone(),
                events: batch.clone(),
            };
            assert!(!batch.t_ns.is_empty(), "{n} planes: the scene moves");
            assert_eq!(got.window.ref_plane, whole.ref_plane, "{n} planes");
            assert_eq!(got.window.spikes.bits, chunk.bits, "{n} planes");
            assert_eq!(got.window.events.t_ns, batch.t_ns, "{n} planes");
            let mut direct = Representer::new(cfg).expect("representer");
            for (k, kind) in kinds.iter().enumerate() {
                let want = direct.represent(*kind, &whole).expect("represent").data;
                assert_eq!(got.representations[k], want, "{n} planes, {kind}");
            }
        }
    }

    #[test]
    fn a_sample_is_deterministic_and_its_channels_are_what_represent_makes() {
        let o = opts(Split::Train, PathBuf::from("unused"));
        let (light, speed) = cell_of(23);
        let a = sample(&o, &[], 23, light, speed).expect("sample");
        let b = sample(&o, &[], 23, light, speed).expect("sample again");
        assert_eq!(a.spike, b.spike);
        assert_eq!(a.events, b.events);
        assert_eq!(a.truth, b.truth);
        assert_eq!(a.info, b.info);
        assert_eq!(a.spike.dim(), (32, 16, 16));
        // Channel 0 is 1/ISI in (0, 1]; the raw planes are 0 or 1 and the window has spikes.
        assert!(
            a.spike
                .index_axis(Axis(0), 0)
                .iter()
                .all(|&v| v > 0.0 && v <= 1.0)
        );
        let raw = a.spike.slice(ndarray::s![1.., .., ..]);
        assert!(raw.iter().all(|&v| v == 0.0 || v == 1.0));
        assert!(raw.iter().any(|&v| v == 1.0));
        // A moving scene makes events, and the last channel (at the window's end) has seen them.
        assert!(speed > 0.0 && a.info.events > 0, "{:?}", a.info);
        assert!(a.events.index_axis(Axis(0), 31).iter().any(|&v| v != 0.0));
        assert!(a.truth.iter().all(|&v| (0.0..=1.0).contains(&v)));
        assert_eq!(a.info.lum_per_rate, 1.0 / light);
        // Another index is another sample.
        let c = sample(&o, &[], 48, light, speed).expect("sample 48");
        assert_ne!(a.truth, c.truth);
    }

    #[test]
    fn a_randomised_camera_is_drawn_per_sample_and_leaves_the_scene_as_it_was() {
        let plain = opts(Split::Train, PathBuf::from("unused"));
        let random = DatasetOptions {
            randomise_camera: true,
            noise: profile_only("paper"),
            ..plain.clone()
        };
        check(&random).expect("random camera, no profile");
        // With a profile or an override it is refused by name.
        for (noise, name) in [
            (profile_only("vidar"), "--profile"),
            (NoiseArgs::default(), "--electrons-per-phi"),
        ] {
            let bad = DatasetOptions {
                noise,
                ..random.clone()
            };
            let e = check(&bad).expect_err(name).to_string();
            assert!(e.contains(name) && e.contains("--randomise-camera"), "{e}");
        }
        let (light, speed) = cell_of(23);
        let a = sample(&random, &[], 23, light, speed).expect("sample");
        assert_eq!(
            a.info,
            sample(&random, &[], 23, light, speed).expect("again").info
        );
        // The scene draws are the plain set's: the same texture, direction and truth up to the
        // light, which the draw scales within [1/1.4, 1.4].
        let p = sample(&plain, &[], 23, light, speed).expect("plain");
        assert_eq!(
            (a.info.texture.as_str(), a.info.angle_deg),
            (p.info.texture.as_str(), p.info.angle_deg)
        );
        assert_eq!(p.info.camera, CameraDraw::fixed(Noise::OFF, light));
        let ratio = a.info.camera.light / light;
        assert!((1.0 / 1.4..=1.4).contains(&ratio), "{ratio}");
        assert_eq!(a.info.light, light);
        assert!((a.info.lum_per_rate * a.info.camera.light - 1.0).abs() < 1e-9);
        // Over many samples every term is sometimes on, sometimes off, and always in range.
        let draws: Vec<CameraDraw> = (0..200)
            .map(|i| {
                let mut rng = ChaCha8Rng::seed_from_u64(i);
                CameraDraw::draw(&mut rng, 0.5, 0.0)
            })
            .collect();
        for (name, f) in [
            (
                "electrons",
                (|d: &CameraDraw| d.noise.electrons_per_phi) as fn(&CameraDraw) -> f64,
            ),
            ("jitter", |d| d.noise.threshold_jitter),
            ("offset", |d| d.noise.threshold_offset),
            ("prnu", |d| d.noise.prnu),
            ("dark", |d| d.noise.dark_current_hz),
            ("reset", |d| d.noise.reset_delay_ticks),
        ] {
            let on = draws.iter().filter(|d| f(d) > 0.0).count();
            // 0.75 x 0.7 of them on average: 105.
            assert!((75..=140).contains(&on), "{name}: {on} of 200 on");
        }
        let clean = draws.iter().filter(|d| d.noise == Noise::OFF).count();
        assert!((30..=75).contains(&clean), "{clean} of 200 clean");
        assert!(draws.iter().all(|d| d.noise.check().is_ok()));
        assert!(draws.iter().any(|d| !d.random_init) && draws.iter().any(|d| !d.fpn_cap));
        assert!(draws.iter().all(|d| d.noise.random_spike_hz == 0.0));
    }

    #[test]
    fn the_random_spike_term_is_drawn_last_and_only_when_asked() {
        let mut with_term = 0;
        for i in 0..200 {
            let draw = |max| CameraDraw::draw(&mut ChaCha8Rng::seed_from_u64(i), 0.5, max);
            let (plain, more) = (draw(0.0), draw(400.0));
            let hz = more.noise.random_spike_hz;
            // Every other draw is the one made without the term.
            let back = CameraDraw {
                noise: Noise {
                    random_spike_hz: 0.0,
                    ..more.noise
                },
                ..more.clone()
            };
            assert_eq!(back, plain, "draw {i}");
            assert!(hz == 0.0 || (4.0..=400.0).contains(&hz), "{hz}");
            with_term += usize::from(hz > 0.0);
        }
        // 0.75 x 0.7 of them on average: 105.
        assert!((75..=140).contains(&with_term), "{with_term} of 200 on");
        // The option is checked and needs the randomised camera.
        let plain = opts(Split::Train, PathBuf::from("unused"));
        for (randomise, max, ok) in [
            (true, 400.0, true),
            (false, 400.0, false),
            (true, -1.0, false),
            (true, 20_000.0, false),
            (true, f64::NAN, false),
        ] {
            let o = DatasetOptions {
                randomise_camera: randomise,
                random_spikes_max_hz: max,
                noise: profile_only("paper"),
                ..plain.clone()
            };
            match check(&o) {
                Ok(()) => assert!(ok, "{max} accepted"),
                Err(e) => {
                    assert!(!ok, "{max}: {e}");
                    assert!(e.to_string().contains("--random-spikes-max-hz"), "{e}");
                }
            }
        }
    }

    /// A profile without overrides, as the command line gives it.
    fn profile_only(name: &str) -> NoiseArgs {
        NoiseArgs {
            profile: name.into(),
            electrons_per_phi: None,
            threshold_jitter: None,
            threshold_offset: None,
            prnu: None,
            dark_current_hz: None,
            dark_current_spread: None,
            reset_delay_ticks: None,
            random_spike_hz: None,
        }
    }

    #[test]
    fn a_profile_reaches_the_spike_camera_and_a_bad_one_is_refused() {
        let plain = opts(Split::Train, PathBuf::from("unused"));
        let vidar = DatasetOptions {
            noise: profile_only("vidar"),
            ..plain.clone()
        };
        let (light, speed) = cell_of(12);
        let a = sample(&plain, &[], 12, light, speed).expect("paper");
        let b = sample(&vidar, &[], 12, light, speed).expect("vidar");
        assert_eq!(a.truth, b.truth);
        assert_ne!(a.spike, b.spike);
        assert_eq!(
            b.info.camera.noise,
            neuspike_spike_camera::noise::profile("vidar").unwrap()
        );
        let bad = DatasetOptions {
            noise: profile_only("no-such-camera"),
            ..plain
        };
        let err = generate(&bad, false).expect_err("bad profile").to_string();
        assert!(err.contains("no-such-camera"), "{err}");
    }

    #[test]
    fn train_and_test_draw_different_textures() {
        let (tr, te) = (
            opts(Split::Train, PathBuf::new()),
            opts(Split::Test, PathBuf::new()),
        );
        let mut train = std::collections::BTreeSet::new();
        let mut test = std::collections::BTreeSet::new();
        for i in 0..50 {
            let (l, s) = cell_of(i);
            train.insert(sample(&tr, &[], i, l, s).expect("train").info.texture);
            let t = sample(&te, &[], i, l, s).expect("test").info.texture;
            // Parametric generators are for training only.
            assert!(
                !t.starts_with("grating") && !t.starts_with("checkerboard"),
                "{t}"
            );
            test.insert(t);
        }
        assert!(train.is_disjoint(&test));
        // Seeds: even for train, odd for test.
        let odd = |t: &String| {
            t.rsplit(':')
                .next()
                .and_then(|s| s.parse::<u64>().ok())
                .map(|s| s % 2)
        };
        assert!(train.iter().filter_map(odd).all(|p| p == 0));
        assert!(test.iter().filter_map(odd).all(|p| p == 1));
    }

    #[test]
    fn generate_writes_shards_csv_and_settings_and_refuses_bad_options() {
        let dir = tempfile::tempdir().expect("tempdir");
        let o = opts(Split::Test, dir.path().join("set"));
        let sum = generate(&o, false).expect("generate");
        assert_eq!(sum.samples, 25);
        assert_eq!(sum.shards, 3);
        let csv = fs::read_to_string(o.out.join("samples.csv")).expect("csv");
        assert_eq!(csv.lines().count(), 26);
        let spike: ndarray::Array4<f32> =
            ndarray_npy::read_npy(o.out.join("002/spike.npy")).expect("npy");
        assert_eq!(spike.dim(), (5, 32, 16, 16));
        let truth: Array3<f32> = ndarray_npy::read_npy(o.out.join("000/truth.npy")).expect("npy");
        assert_eq!(truth.dim(), (10, 16, 16));
        assert!(
            fs::read_to_string(o.out.join("dataset.yml"))
                .expect("yml")
                .contains("samples: 25")
        );
        // Not into a folder that holds something.
        let err = generate(&o, false).expect_err("not empty").to_string();
        assert!(err.contains("not empty"), "{err}");
        for (bad, name) in [
            (
                DatasetOptions {
                    per_cell: 0,
                    ..o.clone()
                },
                "--per-cell",
            ),
            (
                DatasetOptions {
                    size: 4,
                    ..o.clone()
                },
                "--size",
            ),
            (
                DatasetOptions {
                    window_planes: 10,
                    ..o.clone()
                },
                "--window-planes",
            ),
            (
                DatasetOptions {
                    tau_ns: f64::NAN,
                    ..o.clone()
                },
                "--tau-ns",
            ),
        ] {
            let err = generate(&bad, false).expect_err(name).to_string();
            assert!(err.contains(name), "{name}: {err}");
        }
    }
}
