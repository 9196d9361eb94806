//! Both cameras on one scene: a built-in scene, a scene YAML file, or frames the user passes.
//!
//! The cameras' settings are the node arguments of the graphs (`spike-source`, `event-source`),
//! given as a dict whose keys are the arguments without their dashes (`{"phi": 2.0, "profile":
//! "vidar"}`), and parsed by the same definitions, so every setting, profile and noise term is
//! there and refused with the same message.

use clap::Parser;

use crate::settings::{flags, parse};
use ndarray::Array3;
use numpy::{PyArray1, PyReadonlyArray3};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use neuspike_event_camera::{DvsConfig, EventCamera, FrameSteps};
use neuspike_scene::Clip;
use neuspike_scene::Scene;
use neuspike_schemas::EventBatch;
use neuspike_spike_camera::{CameraConfig, SpikeCamera};

use crate::values::{Events, Spikes};
use crate::{errors, threads};

/// The most planes one call simulates.
const MAX_PLANES: u64 = 1 << 20;
/// The most bytes of packed planes, and of ground truth, one call makes (4 GiB: 343,597 planes
/// of 400x250); longer recordings are simulated in several calls or written by
/// `neuspike simulate`.
const MAX_SPIKE_BYTES: u64 = 1 << 32;

#[derive(Debug, Parser)]
#[command(
    name = "spike_camera",
    args_override_self = true,
    no_binary_name = true
)]
struct SpikeArgs {
    #[command(flatten)]
    camera: CameraConfig,
}

#[derive(Debug, Parser)]
#[command(
    name = "event_camera",
    args_override_self = true,
    no_binary_name = true
)]
struct DvsArgs {
    #[command(flatten)]
    camera: DvsConfig,
}

/// What :func:`simulate` made: the spike planes, the events (or ``None``), and the ground truth
/// (the scene's luminance, clipped to ``[0, 1]``) at every ``truth_every``-th plane.
#[pyclass(module = "neuspike", frozen, get_all)]
pub struct Simulation {
    /// The spike camera's planes, or ``None``.
    spikes: Option<Py<Spikes>>,
    /// The DVS's events of ``[0, planes * plane_period_ns)``, or ``None``.
    events: Option<Py<Events>>,
    /// Ground truth, ``float32 [K, H, W]``.
    truth: Py<PyAny>,
    /// The plane each truth frame belongs to, ``uint64 [K]``.
    truth_planes: Py<PyArray1<u64>>,
    /// Each truth frame's time, ``int64 [K]`` ns (its plane's time stamp).
    truth_t_ns: Py<PyArray1<i64>>,
}

#[pymethods]
impl Simulation {
    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        let events = match &self.events {
            Some(e) => e.bind(py).repr()?.to_string(),
            None => "None".into(),
        };
        let spikes = match &self.spikes {
            Some(s) => s.bind(py).repr()?.to_string(),
            None => "None".into(),
        };
        Ok(format!(
            "Simulation(spikes={spikes}, events={events}, truth={} frames)",
            self.truth_planes.bind(py).len()?
        ))
    }
}

/// The built-in scenes' names.
#[pyfunction]
pub fn scenes() -> Vec<&'static str> {
    Scene::builtin_names().to_vec()
}

/// Simulates the spike camera (unless ``spikes=False``) and the DVS (unless ``events=False``) on
/// one scene for ``planes`` planes of the spike camera's clock, deterministically for ``seed``.
///
/// The scene is a built-in name (:func:`scenes`), a scene YAML file, or ``frames``: luminance
/// ``[T, H, W]`` (``float32``, a frame every ``frame_dt_ns``, linear in time between frames and
/// held after the last), seen at ``light_scale``. ``spike_camera`` and ``event_camera`` hold the
/// cameras' settings under the node arguments' names (``{"phi": 2.0, "profile": "vidar"}``;
/// the sensors default to the frames' size for ``frames``). Ground truth comes every
/// ``truth_every`` planes (0: none).
#[pyfunction]
#[pyo3(signature = (scene = "bright-slow", planes = 400, *, seed = 0, truth_every = 20, spikes = true, events = true, spike_camera = None, event_camera = None, frames = None, frame_dt_ns = 1_000_000, light_scale = 1.0))]
pub fn simulate(
    py: Python<'_>,
    scene: &str,
    planes: u64,
    seed: u64,
    truth_every: u64,
    spikes: bool,
    events: bool,
    spike_camera: Option<&Bound<'_, PyDict>>,
    event_camera: Option<&Bound<'_, PyDict>>,
    frames: Option<&Bound<'_, PyAny>>,
    frame_dt_ns: i64,
    light_scale: f64,
) -> PyResult<Simulation> {
    if !(1..=MAX_PLANES).contains(&planes) {
        return Err(errors::config(format!(
            "planes = {planes}: must be 1..={MAX_PLANES}"
        )));
    }
    let mut base = vec![format!("--seed={seed}")];
    let scene = match frames {
        Some(f) => {
            let f = crate::values::contiguous(py, f, "float32")?
                .extract::<PyReadonlyArray3<'_, f32>>()
                .map_err(|_| errors::input("frames: expected luminance [T, H, W]"))?;
            let view = crate::values::view3(&f)?;
            let f = threads::run(py, || view.to_owned())?;
            let (_, h, w) = f.dim();
            base.push(format!("--width={w}"));
            base.push(format!("--height={h}"));
            let clip = Clip::new(f, frame_dt_ns, "frames").map_err(errors::config)?;
            Scene::from_clip(clip, light_scale).map_err(errors::config)?
        }
        None => Scene::load(scene).map_err(errors::config)?,
    };
    let spike_args: SpikeArgs = parse(
        "spike_camera",
        &[
            base.clone(),
            flags::<SpikeArgs>("spike_camera", spike_camera)?,
        ]
        .concat(),
    )?;
    let dvs_args: Option<DvsArgs> = if events {
        Some(parse(
            "event_camera",
            &[base, flags::<DvsArgs>("event_camera", event_camera)?].concat(),
        )?)
    } else {
        None
    };
    let c = &spike_args.camera;
    let side = crate::values::MAX_SIDE;
    if !(1..=side).contains(&c.width) || !(1..=side).contains(&c.height) {
        return Err(errors::config(format!(
            "spike_camera: {}x{} planes: each side must be 1..={side}",
            c.width, c.height
        )));
    }
    let pixels = (c.width * c.height) as u64;
    let bytes = planes.saturating_mul(pixels.div_ceil(8));
    if spikes && bytes > MAX_SPIKE_BYTES {
        return Err(errors::config(format!(
            "planes = {planes}: {bytes} bytes of {}x{} planes, more than the {MAX_SPIKE_BYTES} one call makes",
            c.width, c.height
        )));
    }
    let truths = if truth_every == 0 {
        0
    } else {
        planes.div_ceil(truth_every)
    };
    let truth_bytes = truths.saturating_mul(pixels).saturating_mul(4);
    if truth_bytes > MAX_SPIKE_BYTES {
        return Err(errors::config(format!(
            "truth_every = {truth_every}: {truths} frames of {}x{} ({truth_bytes} bytes), more than the {MAX_SPIKE_BYTES} one call makes",
            c.width, c.height
        )));
    }
    let n = usize::try_from(planes).map_err(errors::config)?;
    let (chunk, truth, truth_planes, batch) = threads::run(py, || -> Result<_, String> {
        let mut camera =
            SpikeCamera::new(scene.clone(), spike_args.camera).map_err(|e| e.to_string())?;
        let period = camera.period_ns();
        // Without the spike planes the camera still sets the clock and renders the truth.
        let chunk = camera.next_chunk(if spikes { n } else { 0 }, 0);
        let truth_planes: Vec<u64> = if truth_every == 0 {
            Vec::new()
        } else {
            (0..planes)
                .step_by(truth_every.try_into().unwrap_or(usize::MAX))
                .collect()
        };
        let (h, w) = (chunk.height, chunk.width);
        let mut truth = Array3::<f32>::zeros((truth_planes.len(), h, w));
        for (i, &k) in truth_planes.iter().enumerate() {
            truth
                .index_axis_mut(ndarray::Axis(0), i)
                .assign(&camera.ground_truth(k));
        }
        let batch = match dvs_args {
            Some(a) => {
                let mut dvs = EventCamera::new(scene, a.camera, 0)
                    .map_err(|e| format!("event camera: {e}"))?;
                Some(dvs.advance_to((planes as i64).saturating_mul(period), 0))
            }
            None => None,
        };
        Ok((chunk, truth, truth_planes, batch))
    })?
    .map_err(errors::config)?;
    let truth_t_ns: Vec<i64> = truth_planes
        .iter()
        .map(|&k| (k as i64).saturating_mul(chunk.plane_period_ns))
        .collect();
    let spikes = if spikes {
        Some(Py::new(py, Spikes::from_chunk(py, chunk)?)?)
    } else {
        None
    };
    let events = match batch {
        Some(b) => Some(Py::new(py, Events::from_batch(py, b))?),
        None => None,
    };
    Ok(Simulation {
        spikes,
        events,
        truth: crate::values::to_numpy(py, truth)?.unbind(),
        truth_planes: PyArray1::from_vec(py, truth_planes).unbind(),
        truth_t_ns: PyArray1::from_vec(py, truth_t_ns).unbind(),
    })
}

/// The DVS pixel array run on frames the user holds, as v2e runs its emulator on video frames
/// (``neuspike frames-to-events``): ``frames`` ``float32 [T, H, W]`` luminance, frame ``k`` at
/// ``k * frame_dt_ns``; the first sets every pixel's reference level, each later one adds the
/// crossings of the log-intensity path from the frame before (and that interval's noise).
/// ``event_camera`` holds the DVS settings by the event source's argument names (v2e's in
/// ``docs/camera.md``); the frames give the size. Returns the events, sorted by time.
#[pyfunction]
#[pyo3(signature = (frames, frame_dt_ns, *, light_scale = 1.0, event_camera = None))]
pub fn frames_to_events<'py>(
    py: Python<'py>,
    frames: &Bound<'py, PyAny>,
    frame_dt_ns: i64,
    light_scale: f32,
    event_camera: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, Events>> {
    if frame_dt_ns <= 0 {
        return Err(errors::config(format!(
            "frame_dt_ns = {frame_dt_ns}: must be > 0"
        )));
    }
    if !(light_scale.is_finite() && light_scale > 0.0) {
        return Err(errors::config(format!(
            "light_scale = {light_scale}: must be finite and > 0"
        )));
    }
    let frames = crate::values::contiguous(py, frames, "float32")?
        .extract::<PyReadonlyArray3<'py, f32>>()
        .map_err(|_| errors::input("frames: expected luminance [T, H, W]"))?;
    let view = crate::values::view3(&frames)?;
    let (t, h, w) = view.dim();
    if t < 2 || h == 0 || w == 0 {
        return Err(errors::input(format!(
            "frames: {t} frames of {h}x{w}; at least 2 frames of at least one pixel are needed"
        )));
    }
    let bad = threads::run(py, || {
        view.indexed_iter()
            .find(|(_, v)| !v.is_finite() || **v < 0.0)
            .map(|(i, v)| (i, *v))
    })?;
    if let Some(((k, y, x), v)) = bad {
        return Err(errors::input(format!(
            "frames: frame {k} row {y} column {x} is {v}: luminance must be finite and >= 0"
        )));
    }
    let base = vec![format!("--width={w}"), format!("--height={h}")];
    let args: DvsArgs = parse(
        "event_camera",
        &[base, flags::<DvsArgs>("event_camera", event_camera)?].concat(),
    )?;
    if let Some(name) = args.camera.scene_only_setting() {
        return Err(errors::config(format!(
            "event_camera: {} applies to a simulated scene, not to frames",
            name.replace('-', "_")
        )));
    }
    // The frames as they lie in the array (C-contiguous): one slice a frame, no copy.
    let flat = frames.as_slice().map_err(errors::input)?;
    let mut batch = threads::run(py, || -> Result<EventBatch, String> {
        let mut frames = flat.chunks_exact(h * w);
        let mut prev = frames.next().unwrap_or_default();
        let mut steps = FrameSteps::new(&args.camera, light_scale, prev, frame_dt_ns)
            .map_err(|e| e.to_string())?;
        let end = (t as i64 - 1).saturating_mul(frame_dt_ns);
        let mut batch = EventBatch::empty(w, h, 0, end, 0);
        for cur in frames {
            for e in steps.next(prev, cur) {
                batch.t_ns.push(e.t_ns);
                batch.x.push(e.x);
                batch.y.push(e.y);
                batch.polarity.push(e.polarity);
            }
            prev = cur;
        }
        Ok(batch)
    })?
    .map_err(errors::config)?;
    batch.seq = 0;
    Bound::new(py, Events::from_batch(py, batch))
}
