//! One recording through one method, as the graph pays for it: the align stage's windows (the
//! recording replayed through the stage in a chain), the represent stage's `Representer`
//! computing only the kinds the method reads, and the infer stage's `Reconstructor`, timed per
//! window on a given number of threads; the scored frames kept for the metrics.

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

use eyre::{WrapErr, bail, eyre};
use ndarray::Array2;
use neuspike_align::{AlignConfig, AlignStage};
use neuspike_event_camera::{DvsConfig, EventCamera};
use neuspike_reconstruction::learned::{BF16_SUFFIX, INT8_SUFFIX, LearnedModel, Precision};
use neuspike_reconstruction::{
    EVENTS, InferConfig, Method, REPRESENTATION, Reconstructor, WINDOWS,
};
use neuspike_representations::{RepresentConfig, Representer, WindowStats};
use neuspike_schemas::{
    AlignedWindow, EventBatch, RepresentationKind, SpikeChunk, bytes_per_plane,
};
use neuspike_simd::bf16::Bf16Path;
use neuspike_simd::dot::DotPath;
use neuspike_spike_camera::{CameraConfig, SpikeCamera};
use neuspike_stage::{Chain, Msg, MsgType, Replay};

use super::grid::{self, SceneClass, TextureSet};
use crate::memory;

/// The planes of every classical method's window but TFP's (align's default).
pub const WINDOW_PLANES: u32 = 33;

/// How a method reconstructs.
#[derive(Clone, Debug, PartialEq)]
pub enum Recon {
    /// One of the infer node's classical methods.
    Classical(Method),
    /// A shipped network: its ONNX file and the representations it reads, in order, with their
    /// channel counts.
    Network {
        /// The ONNX file.
        path: PathBuf,
        /// Its inputs.
        inputs: Vec<(RepresentationKind, usize)>,
        /// The precision of its convolutions.
        precision: Precision,
    },
}

/// A method of the bench: a reconstruction and the window it reads.
#[derive(Clone, Debug, PartialEq)]
pub struct MethodSpec {
    /// Its name in the tables: `tfp-33`, `fusion`, `neuspike-fused-16`, ...
    pub name: String,
    /// How it reconstructs.
    pub recon: Recon,
    /// Planes per window.
    pub window_planes: u32,
    /// The representation it reads when not the method's default (`fusion` on TFP rates).
    pub representation: Option<RepresentationKind>,
}

impl MethodSpec {
    /// A classical method over `window_planes`.
    pub fn classical(name: &str, method: Method, window_planes: u32) -> MethodSpec {
        MethodSpec {
            name: name.to_string(),
            recon: Recon::Classical(method),
            window_planes,
            representation: None,
        }
    }

    /// A network, its inputs read from the file.
    ///
    /// # Errors
    /// The file is not a NeuSpike-Net the infer node can run.
    pub fn network(path: &Path) -> eyre::Result<MethodSpec> {
        let model = LearnedModel::load(path).map_err(|e| eyre!("{e}"))?;
        let inputs = model
            .inputs()
            .iter()
            .map(|i| i.representation())
            .zip(model.channels().iter().copied())
            .collect();
        let name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .ok_or_else(|| eyre!("{}: not a file name", path.display()))?;
        Ok(MethodSpec {
            name,
            recon: Recon::Network {
                path: path.to_path_buf(),
                inputs,
                precision: Precision::F32,
            },
            window_planes: WINDOW_PLANES,
            representation: None,
        })
    }

    /// The same network in `precision`, named with `suffix` ([`INT8_SUFFIX`],
    /// [`BF16_SUFFIX`]); `None` for a classical method.
    pub fn in_precision(&self, suffix: &str, precision: Precision) -> Option<MethodSpec> {
        let Recon::Network { path, inputs, .. } = &self.recon else {
            return None;
        };
        Some(MethodSpec {
            name: format!("{}{suffix}", self.name),
            recon: Recon::Network {
                path: path.clone(),
                inputs: inputs.clone(),
                precision,
            },
            ..self.clone()
        })
    }

    /// The representation kinds the represent stage computes for it.
    pub fn representations(&self) -> Vec<RepresentationKind> {
        match &self.recon {
            Recon::Classical(m) => self
                .representation
                .or(m.graph_representation())
                .into_iter()
                .collect(),
            Recon::Network { inputs, .. } => inputs.iter().map(|(k, _)| *k).collect(),
        }
    }

    /// Whether it reads align's event stream.
    pub fn reads_event_stream(&self) -> bool {
        matches!(&self.recon, Recon::Classical(m) if m.inputs().events)
    }

    /// Whether it needs an event camera at all.
    pub fn needs_events(&self) -> bool {
        self.reads_event_stream()
            || self
                .representations()
                .contains(&RepresentationKind::EventIntegration)
    }

    /// Whether a frame depends on earlier windows: such a method runs every window from the
    /// stream's start, as in a graph; the others run the scored windows only.
    pub fn stateful(&self) -> bool {
        matches!(
            self.recon,
            Recon::Classical(Method::Tfstp | Method::Hf | Method::Cf | Method::Fusion)
        )
    }

    /// The infer stage's settings for it.
    fn infer_config(&self, contrast: f64) -> InferConfig {
        let mut cfg = InferConfig {
            contrast,
            ..InferConfig::default()
        };
        match &self.recon {
            Recon::Classical(m) => cfg.method = *m,
            Recon::Network {
                path, precision, ..
            } => {
                cfg.method = Method::Learned;
                cfg.model = Some(path.clone());
                cfg.precision = *precision;
            }
        }
        cfg
    }

    /// The infer node's input ids for it.
    fn input_ids(&self) -> Vec<String> {
        let mut ids: Vec<String> = match &self.recon {
            Recon::Classical(m) if m.graph_representation().is_some() => {
                vec![REPRESENTATION.to_string()]
            }
            Recon::Classical(_) => vec![],
            // The infer stage makes a network's inputs of align's windows, as in the live graph
            // and in `auto`: the spike planes read bit-packed.
            Recon::Network { .. } => vec![WINDOWS.to_string()],
        };
        if self.reads_event_stream() {
            ids.push(EVENTS.to_string());
        }
        ids
    }

    /// The represent stage's settings for it (the network's channel counts).
    fn represent_config(&self) -> RepresentConfig {
        let mut cfg = RepresentConfig::default();
        if let Recon::Network { inputs, .. } = &self.recon {
            for (k, c) in inputs {
                let c = u32::try_from(*c).unwrap_or(u32::MAX);
                match k {
                    RepresentationKind::SpikeRepr => cfg.repr_channels = c,
                    RepresentationKind::EventIntegration => cfg.ei_channels = c,
                    _ => {}
                }
            }
        }
        cfg
    }
}

/// The methods the bench compares: TFP over 8, 33, 128 and 256 planes, TFI, TFSTP, HF, CF, the
/// physics fusion on ISIs (Eq. 5-7) and on TFP rates (`fusion-tfp`), and every network in `models` (`*.onnx`, by name),
/// each also in 8 bits (`<name>-int8`) where this CPU runs 8 bits faster than `f32` (VNNI or AMX)
/// and in `bf16` (`<name>-bf16`) where it does so (AVX-512 BF16).
///
/// # Errors
/// A network that does not load.
pub fn methods(models: &Path) -> eyre::Result<Vec<MethodSpec>> {
    let mut out = vec![
        MethodSpec::classical("tfp-8", Method::Tfp, 8),
        MethodSpec::classical("tfp-33", Method::Tfp, 33),
        MethodSpec::classical("tfp-128", Method::Tfp, 128),
        MethodSpec::classical("tfp-256", Method::Tfp, 256),
        MethodSpec::classical("tfi", Method::Tfi, WINDOW_PLANES),
        MethodSpec::classical("tfstp", Method::Tfstp, WINDOW_PLANES),
        MethodSpec::classical("hf", Method::Hf, WINDOW_PLANES),
        MethodSpec::classical("cf", Method::Cf, WINDOW_PLANES),
        MethodSpec::classical("fusion", Method::Fusion, WINDOW_PLANES),
        MethodSpec {
            representation: Some(RepresentationKind::Tfp),
            ..MethodSpec::classical("fusion-tfp", Method::Fusion, WINDOW_PLANES)
        },
    ];
    let mut files: Vec<PathBuf> = std::fs::read_dir(models)
        .wrap_err_with(|| format!("--models {}: cannot list the networks", models.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "onnx"))
        .collect();
    files.sort();
    if files.is_empty() {
        bail!(
            "--models {}: no ONNX networks there (run from the repository root, or name the folder)",
            models.display()
        );
    }
    // The variants where this CPU has a path that pays (VNNI or AMX; AVX-512 BF16; plain loops
    // are slower than `f32`).
    let mut variants = Vec::new();
    if Precision::bf16() != Precision::Bf16(Bf16Path::Portable) {
        variants.push((BF16_SUFFIX, Precision::bf16()));
    }
    if Precision::int8() != Precision::Int8(DotPath::Portable) {
        variants.push((INT8_SUFFIX, Precision::int8()));
    }
    for f in files {
        let spec =
            MethodSpec::network(&f).wrap_err_with(|| format!("--models {}", models.display()))?;
        let more: Vec<MethodSpec> = variants
            .iter()
            .filter_map(|&(suffix, p)| spec.in_precision(suffix, p))
            .collect();
        out.push(spec);
        out.extend(more);
    }
    Ok(out)
}

/// A recording the methods run on: every plane, the events, and the truth of the scored
/// windows.
pub struct Recording {
    /// All planes, one chunk.
    pub spikes: SpikeChunk,
    /// All events, on the spike clock at the spike camera's size, if there is an event camera.
    pub events: Option<EventBatch>,
    /// The reference planes scored.
    pub scored: Vec<u64>,
    /// The truth at each scored plane (luminance in [0, 1]), if known.
    pub truth: Option<Vec<Array2<f32>>>,
    /// The DVS contrast threshold (the event methods' `contrast`).
    pub theta: f64,
}

/// The longest window a method of the bench reads (TFP over 256 planes).
pub const LONGEST_PLANES: u32 = 256;

/// The statistics of each scored window, as `auto` sees them (its 33 central planes, the event
/// rate also over the [`LONGEST_PLANES`] around it where the recording holds them:
/// [`neuspike_representations::choice_stats`]), and the milliseconds each took.
///
/// # Errors
/// Align did not cut a scored window.
pub fn window_stats(rec: &Recording) -> eyre::Result<Vec<(WindowStats, f64)>> {
    rec.scored
        .iter()
        .map(|&c| {
            let half = u64::from(LONGEST_PLANES / 2);
            let n = if c >= half && c + half <= rec.spikes.n_planes as u64 {
                LONGEST_PLANES
            } else {
                WINDOW_PLANES
            };
            let [cut] = <[_; 1]>::try_from(rec.windows(n, &[c], false)?)
                .map_err(|_| eyre!("align: no window at plane {c}"))?;
            let start = Instant::now();
            let s = neuspike_representations::choice_stats(
                &cut.window,
                WINDOW_PLANES as usize,
                LONGEST_PLANES as usize,
            )
            .unwrap_or_default();
            Ok((s, start.elapsed().as_secs_f64() * 1e3))
        })
        .collect()
}

/// The event camera of `neuspike bench --rig`, a DAVIS346's size.
pub const RIG_DVS_SIZE: (usize, usize) = (346, 260);
/// The `--rig` event camera's clock reads this much later than the spike camera's.
pub const RIG_CLOCK_OFFSET_NS: i64 = 3_000_000;
/// The `--rig` event camera's view turned against the spike camera's, degrees.
pub const RIG_TURN_DEG: f64 = 0.5;

/// The `--rig` event camera's pixel -> the spike camera's: the spike sensor's width over its
/// own (a DAVIS346 pixel is 1.16 spike pixels across, its frame 300 spike rows high, so it sees
/// all of the spike camera's view), turned [`RIG_TURN_DEG`], the two frames' centres together.
pub fn rig_homography() -> neuspike_geometry::Homography {
    let (ew, eh) = (RIG_DVS_SIZE.0 as f64, RIG_DVS_SIZE.1 as f64);
    let k = grid::WIDTH as f64 / ew;
    let (sin, cos) = RIG_TURN_DEG.to_radians().sin_cos();
    let (a, b, d, e) = (k * cos, -k * sin, k * sin, k * cos);
    let (cx, cy) = (ew / 2.0, eh / 2.0);
    let (sx, sy) = (grid::WIDTH as f64 / 2.0, grid::HEIGHT as f64 / 2.0);
    neuspike_geometry::Homography::new([
        a,
        b,
        sx - (a * cx + b * cy),
        d,
        e,
        sy - (d * cx + e * cy),
        0.0,
        0.0,
        1.0,
    ])
    .expect("a turn and a scale are invertible")
}

/// Simulates texture `texture` of `class` with both cameras, the spike camera with `noise`;
/// with `rig`, the event camera as a sensor of its own ([`rig_homography`]), its events put on
/// the spike grid and clock as align puts them.
///
/// # Errors
/// A scene or camera setting out of range.
pub fn simulate(
    class: &SceneClass,
    set: TextureSet,
    texture: usize,
    noise: &neuspike_spike_camera::NoiseArgs,
    rig: bool,
) -> eyre::Result<(Recording, String)> {
    let (scene, label) = grid::scene(class, set, texture)?;
    let seed = 1_000 + texture as u64;
    let mut camera = SpikeCamera::new(
        scene.clone(),
        CameraConfig {
            width: grid::WIDTH,
            height: grid::HEIGHT,
            rate_hz: grid::RATE_HZ,
            seed,
            noise: noise.clone(),
            ..CameraConfig::default()
        },
    )
    .map_err(|e| eyre!("{e}"))?;
    let spikes = camera.next_chunk(grid::PLANES as usize, 0);
    let period = spikes.plane_period_ns;
    let theta = class.theta();
    let same_view = DvsConfig {
        width: grid::WIDTH,
        height: grid::HEIGHT,
        theta_on: theta,
        theta_off: theta,
        seed,
        ..DvsConfig::default()
    };
    let cfg = if rig {
        DvsConfig {
            width: RIG_DVS_SIZE.0,
            height: RIG_DVS_SIZE.1,
            homography: Some(rig_homography()),
            rig_width: grid::WIDTH,
            rig_height: grid::HEIGHT,
            clock_offset_ns: RIG_CLOCK_OFFSET_NS,
            ..same_view
        }
    } else {
        same_view
    };
    let mut dvs =
        EventCamera::new(scene, cfg, spikes.t_first_ns - period).map_err(|e| eyre!("{e}"))?;
    let mut events = dvs.advance_to(spikes.plane_time_ns(spikes.n_planes - 1), 0);
    if rig {
        events = neuspike_align::onto_spike_grid(
            &events,
            &rig_homography(),
            (grid::WIDTH, grid::HEIGHT),
            -RIG_CLOCK_OFFSET_NS,
        )
        .0;
    }
    let scored = grid::SCORED_PLANES.to_vec();
    let truth = scored.iter().map(|&k| camera.ground_truth(k)).collect();
    Ok((
        Recording {
            spikes,
            events: Some(events),
            scored,
            truth: Some(truth),
            theta,
        },
        label,
    ))
}

/// The most planes of a real recording the bench reads (the first ones).
pub const REAL_MAX_PLANES: u64 = 4_096;

/// A real spike recording (PKU `.dat`, 400x250 at 20 kHz), scored without truth at three
/// windows in its middle. No calibration comes with it: its gain maps the mean firing rate to
/// luminance 0.5 (1 / (2 x the mean rate)), for every method alike.
///
/// # Errors
/// The file cannot be read, or is too short for a window of 128 planes.
pub fn real(path: &Path) -> eyre::Result<Recording> {
    let opts = neuspike_formats::pku::PkuOptions::default();
    // The planes the file holds, from its size, and at most REAL_MAX_PLANES of them: the reader
    // allocates what it is asked for.
    let planes = neuspike_formats::pku::plane_count(path, &opts.geometry)
        .wrap_err_with(|| format!("--real {}", path.display()))?;
    let planes = usize::try_from(planes.min(REAL_MAX_PLANES))
        .unwrap_or(1)
        .max(1);
    let mut reader = neuspike_formats::pku::PkuReader::open(path, &opts)
        .wrap_err_with(|| format!("--real {}", path.display()))?;
    let mut spikes = reader
        .next_chunk(planes)
        .wrap_err_with(|| format!("--real {}", path.display()))?
        .ok_or_else(|| eyre!("--real {}: no planes", path.display()))?;
    let n = spikes.n_planes as u64;
    if n < 140 {
        bail!(
            "--real {}: {n} planes; at least 140 are needed",
            path.display()
        );
    }
    let mid = (n / 2) / grid::STRIDE_PLANES * grid::STRIDE_PLANES;
    let scored = vec![mid - grid::STRIDE_PLANES, mid, mid + grid::STRIDE_PLANES];
    let pixels = (spikes.width * spikes.height) as f64 * n as f64;
    let rate = spikes.spike_count() as f64 / pixels.max(1.0);
    // No spikes at all: any gain gives black frames; 1 keeps them defined.
    spikes.lum_per_rate = Some(if rate > 0.0 { 0.5 / rate } else { 1.0 });
    Ok(Recording {
        spikes,
        events: None,
        scored,
        truth: None,
        theta: 0.2,
    })
}

impl Recording {
    /// Whether `spec` can run here: events when it needs them, and every scored window inside
    /// the planes.
    pub fn fits(&self, spec: &MethodSpec) -> bool {
        let n = u64::from(spec.window_planes);
        (self.events.is_some() || !spec.needs_events())
            && self
                .scored
                .iter()
                .all(|&c| c >= n / 2 && c + n - 1 - n / 2 < self.spikes.n_planes as u64)
    }

    /// The windows of `n` planes that align cuts at the reference planes `refs` (multiples of
    /// the stride, ascending), each with the event stream align cuts at it when `stream` and the
    /// recording has events: the recording replayed, in chunks of [`grid::STRIDE_PLANES`]
    /// planes, through the align stage in a chain, as a graph's align gets it from a camera.
    ///
    /// # Errors
    /// Align refused the recording, or did not cut every window asked for (a reference plane
    /// off the stride, or too near an end of the recording).
    pub(crate) fn windows(&self, n: u32, refs: &[u64], stream: bool) -> eyre::Result<Vec<Cut>> {
        let Some(&last) = refs.iter().max() else {
            return Ok(Vec::new());
        };
        let sp = &self.spikes;
        let n64 = u64::from(n);
        // Planes up to the last window's end: align needs nothing after it.
        let planes = last.saturating_add(n64 - n64 / 2).min(sp.n_planes as u64);
        let per = bytes_per_plane(sp.width, sp.height);
        let step = grid::STRIDE_PLANES;
        let chunks = (0..planes.div_ceil(step)).map(move |k| {
            let first = k * step;
            let count = step.min(planes - first);
            Msg::from(SpikeChunk {
                first_plane: first,
                n_planes: count as usize,
                t_first_ns: sp.plane_time_ns(first as usize),
                seq: k,
                bits: sp.bits[first as usize * per..(first + count) as usize * per].to_vec(),
                width: sp.width,
                height: sp.height,
                plane_period_ns: sp.plane_period_ns,
                lum_per_rate: sp.lum_per_rate,
            })
        });
        let with_events = self.events.is_some();
        let stream = stream && with_events;
        let mut replay = Replay::new("recording").output("spikes", MsgType::SpikeChunk, chunks);
        if let Some(ev) = &self.events {
            replay = replay.output("events", MsgType::EventBatch, [Msg::from(ev.clone())]);
        }
        let cfg = AlignConfig {
            window_planes: n,
            stride_planes: step,
            ..AlignConfig::default()
        };
        let cuts = Mutex::new(Vec::<Cut>::with_capacity(refs.len()));
        let mut chain = Chain::new();
        chain
            .add("recording", replay)?
            .add("align", AlignStage::new(cfg, with_events, stream))?
            .connect("recording/spikes", "align/spikes")?;
        if with_events {
            chain.connect("recording/events", "align/events")?;
        }
        chain.tap("align/windows", |m| {
            let window = AlignedWindow::try_from(m)?;
            if refs.binary_search(&window.ref_plane).is_ok() {
                lock(&cuts).push(Cut {
                    window,
                    stream: None,
                });
            }
            Ok(())
        })?;
        if stream {
            // Each window's batch of the stream comes right after it, with its number.
            chain.tap("align/events", |m| {
                let batch = EventBatch::try_from(m)?;
                if let Some(cut) = lock(&cuts).last_mut()
                    && cut.window.seq() == batch.seq
                {
                    cut.stream = Some(batch);
                }
                Ok(())
            })?;
        }
        chain.run()?;
        let cuts = cuts.into_inner().unwrap_or_else(|e| e.into_inner());
        if cuts.len() != refs.len() {
            bail!(
                "align cut {} of the {} windows of {n} planes asked for (reference planes {refs:?}, \
                 {} planes recorded)",
                cuts.len(),
                refs.len(),
                sp.n_planes
            );
        }
        Ok(cuts)
    }
}

/// The cuts being collected (a tap that panicked poisoned nothing worth refusing).
fn lock(cuts: &Mutex<Vec<Cut>>) -> std::sync::MutexGuard<'_, Vec<Cut>> {
    cuts.lock().unwrap_or_else(|e| e.into_inner())
}

/// A window align cut, and the event stream it cut at the window's reference instant (when
/// asked for and the recording has events).
pub(crate) struct Cut {
    /// The window.
    pub window: AlignedWindow,
    /// The events since the previous window's reference instant.
    pub stream: Option<EventBatch>,
}

/// What one pass of a method over a recording gave.
pub struct Pass {
    /// The frames of the scored windows, in order.
    pub frames: Vec<Array2<f32>>,
    /// Milliseconds of each scored window, in order.
    pub scored_ms: Vec<f64>,
    /// Milliseconds of each window (representation plus reconstruction).
    pub times_ms: Vec<f64>,
    /// Most heap bytes the pass held above what was in use before it (0 where the counting
    /// allocator is not installed), the network's weights and plan included.
    pub peak_bytes: usize,
}

/// A network's infer stage, kept from recording to recording (it has no state between
/// windows): what a graph loads once.
pub struct Loaded {
    reconstructor: Reconstructor,
    /// Heap bytes the network took to load (weights, plan).
    bytes: usize,
}

/// Networks loaded, by method name and thread count.
#[derive(Default)]
pub struct Cache {
    loaded: Vec<((String, usize), Loaded)>,
}

/// Runs `spec` over `rec` on `threads` threads (rayon and tract): every window from the stream's
/// start for a stateful method, the scored windows otherwise.
///
/// # Errors
/// The method refused a window (a bug: the recordings are well formed), or the network failed.
pub fn pass(
    spec: &MethodSpec,
    rec: &Recording,
    threads: usize,
    cache: &mut Cache,
) -> eyre::Result<Pass> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .wrap_err("cannot start a thread pool")?;
    neuspike_reconstruction::learned::set_threads(threads);
    pool.install(|| pass_on_this_pool(spec, rec, threads, cache))
}

fn pass_on_this_pool(
    spec: &MethodSpec,
    rec: &Recording,
    threads: usize,
    cache: &mut Cache,
) -> eyre::Result<Pass> {
    let ids = spec.input_ids();
    let last = *rec.scored.last().ok_or_else(|| eyre!("no scored window"))?;
    let refs: Vec<u64> = if spec.stateful() {
        let first = u64::from(spec.window_planes)
            .div_ceil(2)
            .div_ceil(grid::STRIDE_PLANES);
        (first.max(1)..)
            .map(|k| k * grid::STRIDE_PLANES)
            .take_while(|&c| c <= last)
            .collect()
    } else {
        rec.scored.clone()
    };
    // Cut before the pass is measured: a graph's align holds one window at a time.
    let cuts = rec
        .windows(spec.window_planes, &refs, spec.reads_event_stream())
        .wrap_err_with(|| format!("{}: align", spec.name))?;
    let before = memory::reset_peak();
    let cfg = spec.infer_config(rec.theta);
    let key = (spec.name.clone(), threads);
    let mut fresh;
    let mut warm_up = false;
    let (reconstructor, loaded_bytes) = match &spec.recon {
        Recon::Network { .. } => {
            let i = match cache.loaded.iter().position(|(k, _)| *k == key) {
                Some(i) => i,
                None => {
                    warm_up = true;
                    let before = memory::live_bytes();
                    let reconstructor = cfg.reconstructor(&ids).map_err(|e| eyre!("{e}"))?;
                    let bytes = memory::live_bytes().saturating_sub(before);
                    cache.loaded.push((
                        key,
                        Loaded {
                            reconstructor,
                            bytes,
                        },
                    ));
                    cache.loaded.len() - 1
                }
            };
            let l = &mut cache.loaded[i].1;
            (&mut l.reconstructor, l.bytes)
        }
        Recon::Classical(_) => {
            fresh = cfg.reconstructor(&ids).map_err(|e| eyre!("{e}"))?;
            (&mut fresh, 0)
        }
    };
    // A network's load is counted once (`loaded_bytes`); a classical method's state is built
    // in the pass.
    let base = match spec.recon {
        Recon::Network { .. } => memory::reset_peak(),
        Recon::Classical(_) => before,
    };
    let mut represent = Representer::new(spec.represent_config()).map_err(|e| eyre!("{e}"))?;
    let network = matches!(spec.recon, Recon::Network { .. });
    let kinds = if network {
        Vec::new()
    } else {
        spec.representations()
    };
    let mut frames = Vec::with_capacity(rec.scored.len());
    let mut times_ms = Vec::with_capacity(refs.len());
    let mut scored_ms = Vec::with_capacity(rec.scored.len());
    let mut step = |cut: &Cut| -> eyre::Result<(f64, Array2<f32>)> {
        let (window, c) = (&cut.window, cut.window.ref_plane);
        let stream = cut.stream.clone();
        // A copy of the window for the network (align sends it; not the stage's cost).
        let owned = network.then(|| window.clone());
        let start = Instant::now();
        for &k in &kinds {
            let r = represent
                .represent(k, window)
                .map_err(|e| eyre!("{}: window at plane {c}: {e}", spec.name))?;
            reconstructor.push_representation(REPRESENTATION, r);
        }
        if let Some(w) = owned {
            reconstructor.push_window(w);
        }
        if let Some(s) = stream {
            reconstructor.push_events(s);
        }
        let out = reconstructor
            .ready(false)
            .map_err(|e| eyre!("{}: window at plane {c}: {e}", spec.name))?;
        let ms = start.elapsed().as_secs_f64() * 1e3;
        let [frame] = <[_; 1]>::try_from(out)
            .map_err(|v: Vec<_>| eyre!("{}: window at plane {c}: {} frames", spec.name, v.len()))?;
        Ok((ms, frame.data))
    };
    if warm_up {
        // A network's first frame of a size plans it and times its convolution paths (the infer
        // node does this once, at its first window): not a frame's cost.
        step(&cuts[0])?;
    }
    for cut in &cuts {
        let c = cut.window.ref_plane;
        let (ms, frame) = step(cut)?;
        times_ms.push(ms);
        if rec.scored.contains(&c) {
            frames.push(frame);
            scored_ms.push(ms);
        }
    }
    let peak_bytes = memory::peak_bytes().saturating_sub(base) + loaded_bytes;
    Ok(Pass {
        frames,
        scored_ms,
        times_ms,
        peak_bytes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use neuspike_scene::Scene;

    /// A small recording of a moving scene, with events, every plane from 0.
    fn recording(planes: usize) -> Recording {
        let scene = Scene::from_yaml_str(
            "width: 24\nheight: 16\nseed: 5\ntexture:\n  kind: strokes\nmotion:\n  vx_px_s: 2000.0\n",
            "test",
            None,
        )
        .expect("scene");
        let cfg = CameraConfig {
            width: 24,
            height: 16,
            ..CameraConfig::default()
        };
        let spikes = SpikeCamera::new(scene.clone(), cfg)
            .expect("camera")
            .next_chunk(planes, 0);
        let dvs = DvsConfig {
            width: 24,
            height: 16,
            ..DvsConfig::default()
        };
        let period = spikes.plane_period_ns;
        let events = EventCamera::new(scene, dvs, spikes.t_first_ns - period)
            .expect("dvs")
            .advance_to(spikes.plane_time_ns(planes - 1), 0);
        Recording {
            spikes,
            events: Some(events),
            scored: vec![100, 120],
            truth: None,
            theta: 0.2,
        }
    }

    /// The window of `n` planes around `c` cut by hand from the recording: planes
    /// `[c - n/2, c + n - 1 - n/2]`, the events of `[t(first) - period, t(last))`.
    fn by_hand(rec: &Recording, c: u64, n: u32) -> (Vec<u8>, Vec<i64>) {
        let sp = &rec.spikes;
        let n = u64::from(n);
        let first = c - n / 2;
        let per = bytes_per_plane(sp.width, sp.height);
        let bits = sp.bits[first as usize * per..(first + n) as usize * per].to_vec();
        let t0 = sp.plane_time_ns(first as usize) - sp.plane_period_ns;
        let t1 = sp.plane_time_ns((first + n - 1) as usize);
        let ev = rec.events.as_ref().expect("events");
        let t = ev
            .t_ns
            .iter()
            .copied()
            .filter(|&t| t >= t0 && t < t1)
            .collect();
        (bits, t)
    }

    #[test]
    fn align_cuts_each_asked_window_as_the_planes_and_events_around_it() {
        let rec = recording(200);
        for n in [1u32, 20, 33, 64, 129] {
            let refs = [80u64, 100, 120];
            let cuts = rec.windows(n, &refs, false).expect("cut");
            assert_eq!(cuts.len(), refs.len(), "{n} planes");
            for (cut, &c) in cuts.iter().zip(&refs) {
                let (bits, t) = by_hand(&rec, c, n);
                assert_eq!(cut.window.ref_plane, c, "{n} planes");
                assert_eq!(cut.window.spikes.n_planes, n as usize, "{n} planes at {c}");
                assert!(
                    cut.window.spikes.bits == bits,
                    "{n} planes at {c}: planes differ"
                );
                assert_eq!(
                    cut.window.events.t_ns, t,
                    "{n} planes at {c}: events differ"
                );
                assert!(cut.stream.is_none());
            }
        }
    }

    #[test]
    fn the_event_stream_is_cut_at_each_reference_instant_and_misses_nothing() {
        let rec = recording(200);
        let refs: Vec<u64> = (1..=8).map(|k| k * grid::STRIDE_PLANES).collect();
        let cuts = rec.windows(33, &refs, true).expect("cut");
        let ev = rec.events.as_ref().expect("events");
        let t_last = cuts.last().expect("cuts").window.t_ref_ns;
        let mut streamed = Vec::new();
        for cut in &cuts {
            let s = cut.stream.as_ref().expect("a stream batch at every window");
            assert!(s.t_ns.iter().all(|&t| t < cut.window.t_ref_ns));
            streamed.extend_from_slice(&s.t_ns);
        }
        let want: Vec<i64> = ev.t_ns.iter().copied().filter(|&t| t < t_last).collect();
        assert!(!want.is_empty());
        assert_eq!(streamed, want);
    }

    #[test]
    fn a_window_the_recording_cannot_hold_is_refused_in_one_line() {
        let rec = recording(60);
        let e = format!(
            "{:#}",
            rec.windows(33, &[60], false).err().expect("refused")
        );
        assert!(e.contains("align cut 0 of the 1 windows"), "{e}");
        assert!(!e.contains('\n'), "{e}");
    }
}
