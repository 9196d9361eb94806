//! Every representation of `neuspike-representations` and every metric of `neuspike-metrics`,
//! on [`Spikes`](crate::values::Spikes) or unpacked planes, [`Events`], and frames.
//!
//! Packed spikes go to the kernels' packed paths (which count 64 pixels a word); unpacked planes
//! to the plain ones; both give the same values (the crate's own tests, and this package's).

use ndarray::Array2;
use numpy::PyReadonlyArray2;
use pyo3::prelude::*;

use neuspike_representations::{
    EventSlice, RepresentError, StpFilter, StpParams, TIME_SURFACE_CHANNELS, VoxelNorm,
    event_count_into, event_integration_into, event_stack_into, isi_into, isi_packed_into,
    spike_representation_into, spike_representation_packed_into, tfi_into, tfp_into,
    tfp_packed_into, time_surface_into, voxel_grid_into,
};

use crate::values::{Events, SpikesIn, frame_in, spikes_in, to_numpy, view2, view3};
use crate::{errors, threads};

/// The most values one kernel's output may hold (4 GiB of `float32`).
const MAX_OUTPUT_ELEMENTS: usize = 1 << 30;

/// Runs a kernel that fills a fresh array on the pool, GIL released; its refusal is an
/// `InputError`.
fn fill<
    D: ndarray::Dimension,
    S: ndarray::ShapeBuilder<Dim = D> + Send + Clone + std::fmt::Debug,
>(
    py: Python<'_>,
    shape: S,
    kernel: impl FnOnce(ndarray::ArrayViewMut<'_, f32, D>) -> Result<(), RepresentError> + Send,
) -> PyResult<ndarray::Array<f32, D>> {
    let dim = shape.clone().into_shape_with_order().raw_dim().clone();
    let elements = dim
        .slice()
        .iter()
        .try_fold(1usize, |n, &d| n.checked_mul(d))
        .filter(|&n| n <= MAX_OUTPUT_ELEMENTS);
    if elements.is_none() {
        return Err(errors::input(format!(
            "an output of shape {shape:?}: more than the {MAX_OUTPUT_ELEMENTS} values one call makes"
        )));
    }
    threads::run(py, || {
        let mut out = ndarray::Array::<f32, D>::zeros(shape);
        kernel(out.view_mut()).map(|()| out)
    })?
    .map_err(errors::input)
}

fn packed<'a>(bits: &'a numpy::PyReadonlyArray2<'_, u8>) -> PyResult<&'a [u8]> {
    bits.as_slice().map_err(errors::input)
}

/// The reference plane: `None` is the middle one, `N / 2`.
fn reference(r: Option<usize>, n: usize) -> usize {
    r.unwrap_or(n / 2)
}

/// TFP (texture from playback): each pixel's firing rate per tick over the planes given,
/// ``float32 [H, W]`` in ``[0, 1]``.
#[pyfunction]
pub fn tfp<'py>(py: Python<'py>, spikes: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    let input = spikes_in(spikes)?;
    let (n, h, w) = input.dim();
    let out = match &input {
        SpikesIn::Packed { bits, .. } => {
            let bits = packed(bits)?;
            fill(py, (h, w), |dst| tfp_packed_into(bits, 0..n, dst))?
        }
        SpikesIn::Planes(p) => {
            let view = view3(p)?;
            fill(py, (h, w), |dst| tfp_into(view, dst))?
        }
    };
    to_numpy(py, out)
}

/// The inter-spike interval in ticks at reference plane ``ref`` (default: the middle plane),
/// ``float32 [H, W]`` ``>= 1``, and ``bool [H, W]``: whether both spikes around it lie in the
/// window (elsewhere the value is the lower bound ``docs/definitions.md`` states).
#[pyfunction]
#[pyo3(signature = (spikes, r#ref = None))]
pub fn isi<'py>(
    py: Python<'py>,
    spikes: &Bound<'py, PyAny>,
    r#ref: Option<usize>,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    let input = spikes_in(spikes)?;
    let (n, h, w) = input.dim();
    let c = reference(r#ref, n);
    let (isi, valid) = match &input {
        SpikesIn::Packed { bits, .. } => {
            let bits = packed(bits)?;
            threads::run(py, || {
                let mut isi = Array2::<f32>::zeros((h, w));
                let mut valid = Array2::<bool>::from_elem((h, w), false);
                isi_packed_into(bits, n, c, isi.view_mut(), valid.view_mut()).map(|()| (isi, valid))
            })?
        }
        SpikesIn::Planes(p) => {
            let view = view3(p)?;
            threads::run(py, || {
                let mut isi = Array2::<f32>::zeros((h, w));
                let mut valid = Array2::<bool>::from_elem((h, w), false);
                isi_into(view, c, isi.view_mut(), valid.view_mut()).map(|()| (isi, valid))
            })?
        }
    }
    .map_err(errors::input)?;
    Ok((to_numpy(py, isi)?, to_numpy(py, valid)?))
}

/// TFI (texture from interval): ``1 / ISI`` at reference plane ``ref`` (default: the middle
/// plane), ``float32 [H, W]`` in ``(0, 1]``.
#[pyfunction]
#[pyo3(signature = (spikes, r#ref = None))]
pub fn tfi<'py>(
    py: Python<'py>,
    spikes: &Bound<'py, PyAny>,
    r#ref: Option<usize>,
) -> PyResult<Bound<'py, PyAny>> {
    let input = spikes_in(spikes)?;
    let (n, h, w) = input.dim();
    let c = reference(r#ref, n);
    let out = match &input {
        SpikesIn::Packed { bits, .. } => {
            let bits = packed(bits)?;
            fill(py, (h, w), |mut dst| {
                let mut valid = Array2::<bool>::from_elem((h, w), false);
                isi_packed_into(bits, n, c, dst.view_mut(), valid.view_mut())?;
                dst.mapv_inplace(|isi| 1.0 / isi);
                Ok(())
            })?
        }
        SpikesIn::Planes(p) => {
            let view = view3(p)?;
            fill(py, (h, w), |dst| tfi_into(view, c, dst))?
        }
    };
    to_numpy(py, out)
}

/// NeuSpike-Net's spike representation at reference plane ``ref`` (default: the middle plane):
/// ``float32 [channels, H, W]``, channel 0 the TFI, channels 1.. the raw planes centred on the
/// reference (shifted inwards at the window's edges).
#[pyfunction]
#[pyo3(signature = (spikes, r#ref = None, channels = 32))]
pub fn spike_representation<'py>(
    py: Python<'py>,
    spikes: &Bound<'py, PyAny>,
    r#ref: Option<usize>,
    channels: usize,
) -> PyResult<Bound<'py, PyAny>> {
    let input = spikes_in(spikes)?;
    let (n, h, w) = input.dim();
    let c = reference(r#ref, n);
    let out = match &input {
        SpikesIn::Packed { bits, .. } => {
            let bits = packed(bits)?;
            fill(py, (channels, h, w), |dst| {
                spike_representation_packed_into(bits, n, c, dst)
            })?
        }
        SpikesIn::Planes(p) => {
            let view = view3(p)?;
            fill(py, (channels, h, w), |dst| {
                spike_representation_into(view, c, dst)
            })?
        }
    };
    to_numpy(py, out)
}

/// TFSTP (texture from short-term plasticity): each pixel's firing rate per tick after the
/// planes given, from SpikeCV's synapse model (``u0``, ``f``, and the time constants in ticks),
/// ``float32 [H, W]``.
#[pyfunction]
#[pyo3(signature = (spikes, *, u0 = 0.15, f = 0.15, tau_d_ticks = 1.0, tau_f_ticks = 10.0))]
pub fn tfstp<'py>(
    py: Python<'py>,
    spikes: &Bound<'py, PyAny>,
    u0: f64,
    f: f64,
    tau_d_ticks: f64,
    tau_f_ticks: f64,
) -> PyResult<Bound<'py, PyAny>> {
    let input = spikes_in(spikes)?;
    let (n, h, w) = input.dim();
    let params = StpParams {
        u0,
        f,
        tau_d_ticks,
        tau_f_ticks,
    };
    let repacked;
    let bits: &[u8] = match &input {
        SpikesIn::Packed { bits, .. } => packed(bits)?,
        SpikesIn::Planes(p) => {
            let view = view3(p)?;
            repacked = threads::run(py, || neuspike_schemas::pack_planes(view))?;
            &repacked
        }
    };
    let out = fill(py, (h, w), |dst| {
        let mut filter = StpFilter::new(h, w, params)?;
        if n > 0 {
            filter.advance_packed(bits, 0, n, n as u64 - 1)?;
        }
        filter.rate_into(dst)
    })?;
    to_numpy(py, out)
}

/// Runs an event kernel on an [`Events`]' columns.
fn on_events<
    D: ndarray::Dimension,
    S: ndarray::ShapeBuilder<Dim = D> + Send + Clone + std::fmt::Debug,
>(
    py: Python<'_>,
    events: &Bound<'_, Events>,
    shape: impl FnOnce(usize, usize) -> S,
    kernel: impl FnOnce(EventSlice<'_>, ndarray::ArrayViewMut<'_, f32, D>) -> Result<(), RepresentError>
    + Send,
) -> PyResult<ndarray::Array<f32, D>> {
    let ev = events.get();
    let (h, w) = ev.sensor();
    let columns = ev.columns(py);
    let slice = columns.slice()?;
    fill(py, shape(h, w), |dst| kernel(slice, dst))
}

/// The signed event count per pixel (ON +1, OFF -1), ``float32 [H, W]``.
#[pyfunction]
pub fn event_count<'py>(
    py: Python<'py>,
    events: &Bound<'py, Events>,
) -> PyResult<Bound<'py, PyAny>> {
    let out = on_events(py, events, |h, w| (h, w), event_count_into)?;
    to_numpy(py, out)
}

/// NeuSpike-Net's event integration (paper Eq. 8): for each instant of ``instants_ns``, the
/// events since ``t0_ns`` weighted by ``exp(-(t - t_i) / tau_ns)``, ``float32 [K, H, W]``.
#[pyfunction]
pub fn event_integration<'py>(
    py: Python<'py>,
    events: &Bound<'py, Events>,
    t0_ns: i64,
    instants_ns: Vec<i64>,
    tau_ns: f64,
) -> PyResult<Bound<'py, PyAny>> {
    let k = instants_ns.len();
    let out = on_events(
        py,
        events,
        |h, w| (k, h, w),
        |ev, dst| event_integration_into(ev, t0_ns, &instants_ns, tau_ns, dst),
    )?;
    to_numpy(py, out)
}

/// E2VID's voxel grid of ``bins`` bins over the events' span, ``float32 [bins, H, W]``; with
/// ``normalise``, the non-zero voxels standardised as E2VID does.
#[pyfunction]
#[pyo3(signature = (events, bins, *, normalise = false))]
pub fn voxel_grid<'py>(
    py: Python<'py>,
    events: &Bound<'py, Events>,
    bins: usize,
    normalise: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let norm = if normalise {
        VoxelNorm::NonZeroStandard
    } else {
        VoxelNorm::Raw
    };
    let out = on_events(
        py,
        events,
        |h, w| (bins, h, w),
        |ev, dst| voxel_grid_into(ev, norm, dst),
    )?;
    to_numpy(py, out)
}

/// The event stack (SBT): the signed count per pixel in each of ``bins`` equal spans of time,
/// ``float32 [bins, H, W]``.
#[pyfunction]
pub fn event_stack<'py>(
    py: Python<'py>,
    events: &Bound<'py, Events>,
    bins: usize,
) -> PyResult<Bound<'py, PyAny>> {
    let out = on_events(py, events, |h, w| (bins, h, w), event_stack_into)?;
    to_numpy(py, out)
}

/// The time surface ``exp(-(t_ref - t_last) / tau_ns)`` of each pixel's latest ON and OFF event
/// at or before ``t_ref_ns``, ``float32 [2, H, W]`` (0 where there is none).
#[pyfunction]
pub fn time_surface<'py>(
    py: Python<'py>,
    events: &Bound<'py, Events>,
    t_ref_ns: i64,
    tau_ns: f64,
) -> PyResult<Bound<'py, PyAny>> {
    let out = on_events(
        py,
        events,
        |h, w| (TIME_SURFACE_CHANNELS, h, w),
        |ev, dst| time_surface_into(ev, t_ref_ns, tau_ns, dst),
    )?;
    to_numpy(py, out)
}

/// Two frames of one shape, for a metric.
fn pair<'py>(
    x: &Bound<'py, PyAny>,
    gt: &Bound<'py, PyAny>,
) -> PyResult<(PyReadonlyArray2<'py, f32>, PyReadonlyArray2<'py, f32>)> {
    Ok((frame_in(x, "x")?, frame_in(gt, "gt")?))
}

/// Runs a metric of two frames of one shape, GIL released.
fn compare(
    py: Python<'_>,
    x: &Bound<'_, PyAny>,
    gt: &Bound<'_, PyAny>,
    metric: fn(ndarray::ArrayView2<f32>, ndarray::ArrayView2<f32>) -> f64,
) -> PyResult<f64> {
    let (x, gt) = pair(x, gt)?;
    let (x, gt) = (view2(&x)?, view2(&gt)?);
    neuspike_metrics::check_same_shape(x, gt).map_err(errors::input)?;
    threads::run(py, || metric(x, gt))
}

/// PSNR in dB with data range 1 (``docs/definitions.md``); identical frames give ``inf``.
#[pyfunction]
pub fn psnr(py: Python<'_>, x: &Bound<'_, PyAny>, gt: &Bound<'_, PyAny>) -> PyResult<f64> {
    compare(py, x, gt, neuspike_metrics::psnr)
}

/// PSNR in dB after the least-squares gain that best maps ``x`` onto ``gt`` (and clipping to
/// ``[0, 1]``): for methods whose output scale is arbitrary.
#[pyfunction]
pub fn psnr_after_gain(
    py: Python<'_>,
    x: &Bound<'_, PyAny>,
    gt: &Bound<'_, PyAny>,
) -> PyResult<f64> {
    compare(py, x, gt, neuspike_metrics::psnr_after_gain)
}

/// The least-squares gain ``sum(x * gt) / sum(x * x)`` (1 when ``x`` is all zeros).
#[pyfunction]
pub fn gain(py: Python<'_>, x: &Bound<'_, PyAny>, gt: &Bound<'_, PyAny>) -> PyResult<f64> {
    compare(py, x, gt, neuspike_metrics::gain_lsq)
}

/// SSIM with an 11-tap Gaussian window of sigma 1.5 and data range 1 (Wang et al. 2004, as
/// ``docs/definitions.md`` fixes it).
#[pyfunction]
pub fn ssim(py: Python<'_>, x: &Bound<'_, PyAny>, gt: &Bound<'_, PyAny>) -> PyResult<f64> {
    compare(py, x, gt, neuspike_metrics::ssim)
}

/// The 2D entropy of a frame in bits: grey level against its 3x3 neighbourhood mean, 8-bit.
#[pyfunction]
pub fn entropy_2d(py: Python<'_>, x: &Bound<'_, PyAny>) -> PyResult<f64> {
    let x = frame_in(x, "x")?;
    let x = view2(&x)?;
    threads::run(py, || neuspike_metrics::entropy_2d(x))
}
