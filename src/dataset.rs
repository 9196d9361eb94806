//! Training and test sets for the learned reconstruction (NeuSpike-Net, paper Sec. 3.4), made
//! by the simulators: `neuspike dataset`.
//!
//! Every sample is a small scene (`size x size` pixels) seen through one aligned window of
//! `window_planes` spike planes around its reference plane `c = window_planes / 2`, exactly as
//! the graph's align and represent nodes see it:
//! - the **spike representation** (`channels`: 1 ISI + `channels - 1` raw planes) from the
//!   window's packed planes, by the represent node's own `neuspike_represent::Representer`;
//! - the **event integration** (`channels` instants evenly spaced over the window's events
//!   `[t_first - T, t_last)`, Eq. 8 with `tau_ns`), by the same `Representer` on the events of a
//!   DVS of the same size and clock (pixel-registered);
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
use neuspike_event_source::{DvsConfig, EventCamera};
use neuspike_infer::{luminance_from_isi_into, luminance_from_rate_into};
use neuspike_represent::{RepresentConfig, Representer};
use neuspike_scene::Scene;
use neuspike_schemas::{AlignedWindow, RepresentationKind};
use neuspike_spike_source::{CameraConfig, SpikeCamera};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

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
    let stream = match opts.split {
        Split::Train => 0,
        Split::Test => 1,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    rng.set_stream(stream * (1 << 32) + index as u64);
    let (yaml, texture, angle_deg) = scene_yaml(opts, &mut rng, photos, light, speed)?;
    let scene = Scene::from_yaml_str(&yaml, &format!("dataset sample {index}"), None)?;

    let n = opts.window_planes;
    let s = opts.size;
    let spike_cfg = CameraConfig {
        width: s,
        height: s,
        rate_hz: opts.rate_hz,
        seed: rng.random(),
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

    // The represent node's own computation of each representation, on the same window.
    let k = opts.channels;
    let mut represent = Representer::new(RepresentConfig {
        repr_channels: k as u32,
        ei_channels: k as u32,
        tau_ns: opts.tau_ns,
        ..RepresentConfig::default()
    })?;
    let window = AlignedWindow {
        t_ref_ns,
        ref_plane: c as u64,
        spikes: chunk,
        events: batch,
    };
    let spike = represent
        .represent(RepresentationKind::SpikeRepr, &window)?
        .data;
    let events = represent
        .represent(RepresentationKind::EventIntegration, &window)?
        .data;
    let rate = represent.represent(RepresentationKind::Tfp, &window)?.data;
    let isi = represent.represent(RepresentationKind::Isi, &window)?.data;
    let also = opts
        .also
        .iter()
        .map(|&kind| Ok(represent.represent(kind, &window)?.data))
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
        light,
        speed_px_s: speed,
        angle_deg,
        theta_on,
        theta_off,
        lum_per_rate: camera.lum_per_rate(),
        events: window.events.t_ns.len(),
        complex: light <= COMPLEX_MAX_LIGHT || speed >= COMPLEX_MIN_SPEED_PX_S,
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

/// Generates the whole set into `opts.out`.
pub fn generate(opts: &DatasetOptions, progress: bool) -> eyre::Result<DatasetSummary> {
    check(opts)?;
    let photos = match &opts.textures {
        Some(dir) => photos_in(dir)?,
        None => Vec::new(),
    };
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
    let total = opts.per_cell * LIGHT_SCALES.len() * SPEEDS_PX_S.len();
    let bar = progress.then(|| indicatif::ProgressBar::new(total as u64));
    let csv_path = out.join("samples.csv");
    let mut csv = std::io::BufWriter::new(
        fs::File::create(&csv_path)
            .wrap_err_with(|| format!("cannot create {}", csv_path.display()))?,
    );
    writeln!(
        csv,
        "index,shard,texture,light,speed_px_s,angle_deg,theta_on,theta_off,lum_per_rate,events,complex"
    )?;
    let mut summary = DatasetSummary {
        samples: 0,
        shards: 0,
        complex: 0,
        photos: photos.len(),
    };
    for (shard, start) in (0..total).step_by(opts.shard).enumerate() {
        let end = (start + opts.shard).min(total);
        let samples: Vec<Sample> = (start..end)
            .into_par_iter()
            .map(|i| {
                let (light, speed) = cell_of(i);
                let s = sample(opts, &photos, i, light, speed)
                    .wrap_err_with(|| format!("dataset: sample {i}"));
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
            writeln!(
                csv,
                "{i},{shard},{},{},{},{:.3},{:.5},{:.5},{},{},{}",
                f.texture,
                f.light,
                f.speed_px_s,
                f.angle_deg,
                f.theta_on,
                f.theta_off,
                f.lum_per_rate,
                f.events,
                u8::from(f.complex)
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
    let yml = format!(
        "# neuspike dataset: see src/dataset.rs\nsplit: {:?}\nsamples: {}\nshards: {}\ncomplex: {}\n\
         per_cell: {}\nsize: {}\nwindow_planes: {}\nreference_plane: {}\nchannels: {}\ntau_ns: {}\n\
         rate_hz: {}\nphi: {}\nlight_scales: {:?}\nspeeds_px_s: {:?}\nphotos: {}\nseed: {}\nalso: [{}]\n",
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
        photos.len(),
        opts.seed,
        opts.also
            .iter()
            .map(|k| k.name())
            .collect::<Vec<_>>()
            .join(", ")
    );
    let yml_path = out.join("dataset.yml");
    fs::write(&yml_path, yml).wrap_err_with(|| format!("cannot write {}", yml_path.display()))?;
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opts(split: Split, out: PathBuf) -> DatasetOptions {
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
        }
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
