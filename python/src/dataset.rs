//! Training samples made on demand: `neuspike dataset`'s samples, each deterministic in its
//! index and the seed, for a PyTorch `Dataset` or any loop.

use ndarray::Array1;
use pyo3::exceptions::PyIndexError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};

use neuspike_dataset::{DatasetOptions, Sample, Samples as Set};

use crate::settings::{flags, parse};
use crate::values::to_numpy;
use crate::{errors, threads};

#[derive(Debug, clap::Parser)]
#[command(name = "samples", args_override_self = true, no_binary_name = true)]
struct Options {
    #[command(flatten)]
    set: DatasetOptions,
}

/// The samples of a simulated training or test set, made on demand: ``samples[i]`` is sample
/// ``i`` of ``neuspike dataset`` with the same options (the same arrays, whether asked for alone,
/// in any order or process, or written to disk), each scene drawn from the 5 x 5 grid of light
/// and speed, its spike camera drawn at random by default (``randomise_camera``).
///
/// The options are ``neuspike dataset``'s under their names without dashes (``size=64``,
/// ``window_planes=33``, ``textures="photos/"``, ``clips="clips/"``, ``also=["voxel_grid"]``,
/// ``per_cell=40``, ...). A sample is a dict: ``spike`` and ``events`` ``float32 [C, S, S]``
/// (the spike representation and the event integration), ``truth``, ``tfp`` and ``tfi``
/// ``float32 [S, S]`` (luminance), the ``also`` representations by kind, and how it was made
/// (``texture``, ``light``, ``speed_px_s``, ``angle_deg``, ``theta_on``, ``theta_off``,
/// ``lum_per_rate``, ``event_count``, ``complex``).
#[pyclass(module = "neuspike", frozen)]
pub struct Samples {
    set: Set,
    split: String,
    options: Py<PyDict>,
}

fn sample_dict<'py>(py: Python<'py>, set: &Set, s: Sample) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let info = s.info;
    d.set_item("spike", to_numpy(py, s.spike)?)?;
    d.set_item("events", to_numpy(py, s.events)?)?;
    d.set_item("truth", to_numpy(py, s.truth)?)?;
    d.set_item("tfp", to_numpy(py, s.tfp)?)?;
    d.set_item("tfi", to_numpy(py, s.tfi)?)?;
    let also = PyDict::new(py);
    for (kind, a) in set.options().also.iter().zip(s.also) {
        also.set_item(kind.name(), to_numpy(py, a)?)?;
    }
    d.set_item("also", also)?;
    d.set_item("texture", info.texture)?;
    d.set_item("light", info.light)?;
    d.set_item("speed_px_s", info.speed_px_s)?;
    d.set_item("angle_deg", info.angle_deg)?;
    d.set_item("theta_on", info.theta_on)?;
    d.set_item("theta_off", info.theta_off)?;
    d.set_item("lum_per_rate", info.lum_per_rate)?;
    d.set_item("event_count", info.events)?;
    d.set_item("complex", info.complex)?;
    Ok(d)
}

impl Samples {
    /// Python indices (negative from the end) as sample numbers.
    fn numbers(&self, indices: &[isize]) -> PyResult<Vec<usize>> {
        let len = self.set.len();
        indices
            .iter()
            .map(|&index| {
                if index < 0 {
                    len.checked_sub(index.unsigned_abs())
                } else {
                    Some(index as usize)
                }
                .filter(|&i| i < len)
                .ok_or_else(|| PyIndexError::new_err(format!("sample {index} of a set of {len}")))
            })
            .collect()
    }

    fn made(&self, py: Python<'_>, indices: &[usize]) -> PyResult<Vec<Sample>> {
        let set = &self.set;
        threads::run(py, || {
            use rayon::prelude::*;
            indices
                .par_iter()
                .map(|&i| set.get(i))
                .collect::<eyre::Result<Vec<_>>>()
        })?
        .map_err(|e| errors::config(format!("{e:#}")))
    }
}

/// Stacks one array of every sample.
fn stack<D: ndarray::Dimension>(
    py: Python<'_>,
    items: Vec<ndarray::Array<f32, D>>,
) -> PyResult<Bound<'_, PyAny>> {
    let views: Vec<_> = items.iter().map(|a| a.view()).collect();
    to_numpy(py, crate::values::stack_on_pool(py, &views)?)
}

#[pymethods]
impl Samples {
    #[new]
    #[pyo3(signature = (split = "train", **options))]
    fn new(py: Python<'_>, split: &str, options: Option<&Bound<'_, PyDict>>) -> PyResult<Samples> {
        let mut words = vec!["--out=-".to_owned(), format!("--split={split}")];
        let randomise_given = match options {
            Some(o) => o.contains("randomise_camera")?,
            None => false,
        };
        if !randomise_given {
            words.push("--randomise-camera".into());
        }
        words.extend(flags::<Options>("samples", options)?);
        let parsed: Options = parse("samples", &words)?;
        let set = Set::new(parsed.set).map_err(|e| errors::config(format!("{e:#}")))?;
        let kept = match options {
            Some(o) => o.copy()?,
            None => PyDict::new(py),
        };
        Ok(Samples {
            set,
            split: split.to_owned(),
            options: kept.unbind(),
        })
    }

    /// What pickling needs to make the same set in another process (a spawned worker).
    fn __getnewargs_ex__<'py>(
        &self,
        py: Python<'py>,
    ) -> PyResult<(Bound<'py, PyTuple>, Bound<'py, PyDict>)> {
        Ok((
            PyTuple::new(py, [self.split.as_str()])?,
            self.options.bind(py).copy()?,
        ))
    }

    fn __len__(&self) -> usize {
        self.set.len()
    }

    fn __getitem__<'py>(&self, py: Python<'py>, index: isize) -> PyResult<Bound<'py, PyDict>> {
        let i = self.numbers(&[index])?;
        let mut made = self.made(py, &i)?;
        let s = made.pop().ok_or_else(|| errors::config("no sample made"))?;
        sample_dict(py, &self.set, s)
    }

    /// Samples ``indices`` made side by side on the package's threads, stacked: ``spike`` and
    /// ``events`` ``[B, C, S, S]``, ``truth``, ``tfp``, ``tfi`` ``[B, S, S]``, the ``also``
    /// kinds, and each scalar as an array ``[B]`` (``texture`` a list).
    fn batch<'py>(&self, py: Python<'py>, indices: Vec<isize>) -> PyResult<Bound<'py, PyDict>> {
        if indices.is_empty() {
            return Err(errors::input("indices: none given"));
        }
        let indices = self.numbers(&indices)?;
        let made = self.made(py, &indices)?;
        let d = PyDict::new(py);
        let kinds = self.set.options().also.clone();
        let mut also: Vec<Vec<ndarray::Array3<f32>>> = vec![Vec::new(); kinds.len()];
        let (mut spike, mut events, mut truth, mut tfp, mut tfi) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut texture = Vec::new();
        let n = made.len();
        let mut scalars: [Vec<f64>; 7] = Default::default();
        let mut complex = Vec::with_capacity(n);
        for s in made {
            spike.push(s.spike);
            events.push(s.events);
            truth.push(s.truth);
            tfp.push(s.tfp);
            tfi.push(s.tfi);
            for (k, a) in s.also.into_iter().enumerate() {
                also[k].push(a);
            }
            let f = s.info;
            for (v, x) in scalars.iter_mut().zip([
                f.light,
                f.speed_px_s,
                f.angle_deg,
                f.theta_on,
                f.theta_off,
                f.lum_per_rate,
                f.events as f64,
            ]) {
                v.push(x);
            }
            complex.push(f.complex);
            texture.push(f.texture);
        }
        d.set_item("spike", stack(py, spike)?)?;
        d.set_item("events", stack(py, events)?)?;
        d.set_item("truth", stack(py, truth)?)?;
        d.set_item("tfp", stack(py, tfp)?)?;
        d.set_item("tfi", stack(py, tfi)?)?;
        let also_d = PyDict::new(py);
        for (kind, arrays) in kinds.iter().zip(also) {
            also_d.set_item(kind.name(), stack(py, arrays)?)?;
        }
        d.set_item("also", also_d)?;
        d.set_item("texture", texture)?;
        for (name, v) in [
            "light",
            "speed_px_s",
            "angle_deg",
            "theta_on",
            "theta_off",
            "lum_per_rate",
        ]
        .into_iter()
        .zip(&scalars)
        {
            d.set_item(name, to_numpy(py, Array1::from(v.clone()))?)?;
        }
        let counts: Vec<i64> = scalars[6].iter().map(|&c| c as i64).collect();
        d.set_item("event_count", to_numpy(py, Array1::from(counts))?)?;
        d.set_item("complex", to_numpy(py, Array1::from(complex))?)?;
        Ok(d)
    }

    /// The side of a sample, pixels.
    #[getter]
    fn size(&self) -> usize {
        self.set.options().size
    }

    /// Whether each sample's spike camera is drawn at random.
    #[getter]
    fn randomise_camera(&self) -> bool {
        self.set.options().randomise_camera
    }

    /// Channels of the spike and event representations.
    #[getter]
    fn channels(&self) -> usize {
        self.set.options().channels
    }

    fn __repr__(&self) -> String {
        let o = self.set.options();
        format!(
            "Samples({} {} samples of {}x{}, {} channels, seed {}{})",
            self.set.len(),
            self.split,
            o.size,
            o.size,
            o.channels,
            o.seed,
            if o.randomise_camera {
                ", cameras drawn"
            } else {
                ""
            }
        )
    }
}
